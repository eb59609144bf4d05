"""Point-cloud files: PLY, PCD (ascii, binary, binary_compressed), NPY, NPZ.

``read_point_cloud(path)`` returns a :class:`PointCloud`. Points with a NaN (or infinite)
coordinate — the "no return" pixels of an organised Kinect-style cloud — are dropped, counted in
``dropped_nan`` and logged as a warning; ``pixel_index`` keeps where each surviving point sat
in the organised grid so the grid can be rebuilt (:meth:`PointCloud.organized`).

A malformed or truncated file raises :class:`~mks_sim.errors.DataError` whose message starts
with the file name and says what is wrong.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from mks_sim.errors import DataError, MksError, NotFound
from mks_sim.io import _ply
from mks_sim.io.lzf import LZFError, lzf_compress, lzf_decompress

__all__ = [
    "PointCloud",
    "check_input_file",
    "read_point_cloud",
    "write_npy",
    "write_npz",
    "write_pcd",
    "write_ply",
    "write_point_cloud",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PointCloud:
    """A point cloud read from a file.

    Attributes:
        points: (N, 3) float64, the file's units (usually metres), NaN rows removed.
        normals: (N, 3) float64 or None.
        organized_shape: (H, W) for an organised cloud (height > 1), else None.
        dropped_nan: number of points dropped for NaN/inf coordinates.
        pixel_index: (N,) int flat index of each point in the organised grid, or None.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    organized_shape: tuple[int, int] | None = None
    dropped_nan: int = 0
    pixel_index: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    def organized(self) -> np.ndarray:
        """(H, W, 3) the organised grid with NaN where points were missing."""
        if self.organized_shape is None or self.pixel_index is None:
            raise DataError("organized(): this cloud is not organised")
        h, w = self.organized_shape
        grid = np.full((h * w, 3), np.nan)
        grid[self.pixel_index] = self.points
        return grid.reshape(h, w, 3)


def _err(path: Path, msg: str) -> DataError:
    return DataError(f"{path.name}: {msg}")


def _finish(
    path: Path,
    xyz: np.ndarray,
    normals: np.ndarray | None,
    shape: tuple[int, int] | None,
) -> PointCloud:
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    ok = np.all(np.isfinite(xyz), axis=1)
    dropped = int(len(ok) - ok.sum())
    if dropped:
        log.warning(
            "%s: dropped %d of %d points with NaN/inf coordinates", path.name, dropped, len(ok)
        )
    idx = np.flatnonzero(ok) if shape is not None else None
    pts = xyz[ok]
    nrm = None
    if normals is not None:
        nrm = normals[ok]
        if not np.all(np.isfinite(nrm)):
            log.warning("%s: some normals are NaN; normals discarded", path.name)
            nrm = None
    return PointCloud(pts, nrm, shape, dropped, idx)


def check_input_file(path: Path, what: str) -> None:
    """``path`` is an existing regular file (not a folder, a device or a pipe).

    Raises:
        NotFound: nothing at ``path``.
        DataError: ``path`` exists but is not a regular file.
    """
    if not path.exists():
        raise NotFound(f"{what} file not found: {path}")
    if path.is_dir():
        raise DataError(f"{path}: expected a {what} file, got a folder")
    if not path.is_file():
        raise DataError(f"{path}: expected a {what} file, got a special file (device or pipe)")


def read_point_cloud(path: str | Path) -> PointCloud:
    """Read a point cloud by extension: .ply, .pcd, .npy, .npz.

    NPY holds (N, 3), (N, 6) (xyz + normals) or (H, W, 3) (organised); NPZ holds ``points``
    (same shapes) and optionally ``normals``. PLY reads vertex x y z and nx ny nz if present
    (other properties ignored).

    Raises:
        NotFound: the file does not exist.
        DataError: the file is malformed, truncated or of an unknown type.
    """
    path = Path(path)
    check_input_file(path, "point cloud")
    ext = path.suffix.lower()
    # Casts of hostile bytes (signalling NaN, overflow) must not warn: non-finite values are
    # counted and dropped by _finish.
    with np.errstate(all="ignore"):
        if ext == ".ply":
            return _read_ply_cloud(path)
        if ext == ".pcd":
            return _read_pcd(path)
        if ext in (".npy", ".npz"):
            return _read_numpy(path)
    raise _err(path, f"unknown point-cloud type {ext!r}; expected .ply, .pcd, .npy or .npz")


def _read_ply_cloud(path: Path) -> PointCloud:
    data = _ply.read_ply(path)
    v = data.get("vertex")
    if not isinstance(v, dict) or not all(k in v for k in "xyz"):
        raise _err(path, "PLY has no vertex element with x, y, z properties")
    xyz = np.column_stack([v["x"], v["y"], v["z"]])
    nrm = None
    if all(k in v for k in ("nx", "ny", "nz")):
        nrm = np.column_stack([v["nx"], v["ny"], v["nz"]])
    return _finish(path, xyz, nrm, None)


def _read_numpy(path: Path) -> PointCloud:
    normals = None
    try:
        if path.suffix.lower() == ".npy":
            arr = np.load(path, allow_pickle=False)
        else:
            with np.load(path, allow_pickle=False) as z:
                if "points" in z:
                    arr = z["points"]
                    normals = z["normals"] if "normals" in z else None
                elif len(z.files) == 1:
                    arr = z[z.files[0]]
                else:
                    raise _err(path, f"NPZ needs a 'points' array, has {sorted(z.files)}")
    except MksError:
        raise
    except Exception as exc:  # noqa: BLE001 - numpy's header parser raises anything
        # (ValueError, EOFError, SyntaxError, tokenize.TokenError ...) on a corrupt file
        msg = " ".join(str(exc).split())
        raise _err(path, f"not a readable NumPy file ({type(exc).__name__}: {msg})") from None
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise _err(path, f"expected a real (integer or float) array, got dtype {arr.dtype}")
    shape = None
    if arr.ndim == 3 and arr.shape[2] == 3:
        shape = (arr.shape[0], arr.shape[1])
    elif arr.ndim == 2 and arr.shape[1] == 6 and normals is None:
        arr, normals = arr[:, :3], arr[:, 3:]
    elif not (arr.ndim == 2 and arr.shape[1] == 3):
        raise _err(path, f"expected an array of shape (N, 3), (N, 6) or (H, W, 3), got {arr.shape}")
    if (
        normals is not None
        and np.asarray(normals).reshape(-1, 3).shape[0] != arr.reshape(-1, 3).shape[0]
    ):
        raise _err(path, "normals and points have different lengths")
    return _finish(path, arr, normals, shape)


# --- PCD ---------------------------------------------------------------------------------

_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4",
              ("I", 8): "i8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}  # fmt: skip


def _read_pcd(path: Path) -> PointCloud:
    raw = path.read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        nl = raw.find(b"\n", pos)
        if nl < 0:
            raise _err(path, "PCD header has no DATA line")
        line = raw[pos:nl].decode("ascii", "replace").strip()
        pos = nl + 1
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        header[tok[0].upper()] = tok[1:]
        if tok[0].upper() == "DATA":
            break
    try:
        fields = header["FIELDS"]
        n_f = len(fields)
        sizes = [int(s) for s in header.get("SIZE", ["4"] * n_f)]
        types = header.get("TYPE", ["F"] * n_f)
        counts = [int(c) for c in header.get("COUNT", ["1"] * n_f)]
        width = int(header["WIDTH"][0])
        height = int(header.get("HEIGHT", ["1"])[0])
        n_points = int(header.get("POINTS", [str(width * height)])[0])
        mode = header["DATA"][0].lower()
    except (KeyError, IndexError, ValueError) as exc:
        raise _err(path, f"bad PCD header ({type(exc).__name__}: {exc})") from exc
    if not (len(sizes) == len(types) == len(counts) == n_f):
        raise _err(path, f"PCD header: FIELDS has {n_f} entries but SIZE/TYPE/COUNT differ")
    if any(c < 1 for c in counts):
        raise _err(path, f"PCD header: expected every COUNT >= 1, got {counts}")
    for key, value in (("WIDTH", width), ("HEIGHT", height), ("POINTS", n_points)):
        if value < 0:
            raise _err(path, f"PCD header: expected {key} >= 0, got {value}")
    if width * height != n_points:
        raise _err(path, f"PCD header: WIDTH {width} x HEIGHT {height} != POINTS {n_points}")
    if not all(f in fields for f in "xyz"):
        raise _err(path, f"PCD has no x, y, z fields (FIELDS {' '.join(fields)})")
    try:
        dts = [np.dtype(_PCD_TYPES[(t.upper(), s)]) for t, s in zip(types, sizes)]
    except KeyError as exc:
        raise _err(path, f"PCD: unsupported TYPE/SIZE {exc}") from exc
    body = raw[pos:]
    cols: dict[str, np.ndarray] = {}
    if mode == "ascii":
        vals = body.decode("ascii", "replace").split()
        per = sum(counts)
        if len(vals) != per * n_points:
            got = len(vals) // per if per else 0
            raise _err(path, f"header says POINTS {n_points} but the data holds {got}")
        try:
            arr = np.array([float(v) for v in vals], dtype=np.float64).reshape(n_points, per)
        except ValueError as exc:
            raise _err(path, f"non-numeric value in ascii PCD data ({exc})") from exc
        c = 0
        for f, k in zip(fields, counts):
            cols[f] = arr[:, c : c + k]
            c += k
    elif mode == "binary":
        dt = np.dtype(
            [(f"f{i}", "<" + d.str[1:], (k,)) for i, (d, k) in enumerate(zip(dts, counts))]
        )
        have = len(body) // dt.itemsize if dt.itemsize else 0
        if have != n_points:
            raise _err(path, f"header says POINTS {n_points} but the data holds {have}")
        rec = np.frombuffer(body, dtype=dt, count=n_points)
        for i, f in enumerate(fields):
            cols[f] = rec[f"f{i}"].astype(np.float64)
    elif mode == "binary_compressed":
        if len(body) < 8:
            raise _err(path, "binary_compressed PCD: missing the compressed/uncompressed sizes")
        csize, usize = struct.unpack("<II", body[:8])
        if body[8 + csize :].strip(b" \t\r\n\x00"):
            raise _err(
                path,
                f"binary_compressed PCD: {len(body) - 8 - csize} bytes after the "
                f"{csize} compressed bytes the header declares",
            )
        if 8 + csize > len(body):
            raise _err(
                path,
                f"binary_compressed PCD: header says {csize} compressed bytes, file holds {len(body) - 8}",
            )
        expected = sum(d.itemsize * k for d, k in zip(dts, counts)) * n_points
        if usize != expected:
            raise _err(
                path,
                f"binary_compressed PCD: uncompressed size {usize} != {expected} for POINTS {n_points}",
            )
        try:
            dec = lzf_decompress(body[8 : 8 + csize], usize)
        except LZFError as exc:
            raise _err(path, f"binary_compressed PCD: bad LZF data ({exc})") from exc
        off = 0
        for f, d, k in zip(fields, dts, counts):  # field-major layout
            nb = d.itemsize * k * n_points
            cols[f] = (
                np.frombuffer(dec, dtype="<" + d.str[1:], count=k * n_points, offset=off)
                .reshape(n_points, k)
                .astype(np.float64)
            )
            off += nb
    else:
        raise _err(path, f"PCD DATA must be ascii, binary or binary_compressed, got {mode!r}")
    xyz = np.column_stack([cols["x"][:, 0], cols["y"][:, 0], cols["z"][:, 0]])
    nrm = None
    if all(f in cols for f in ("normal_x", "normal_y", "normal_z")):
        nrm = np.column_stack(
            [cols["normal_x"][:, 0], cols["normal_y"][:, 0], cols["normal_z"][:, 0]]
        )
    shape = (height, width) if height > 1 else None
    return _finish(path, xyz, nrm, shape)


# --- writers -----------------------------------------------------------------------------


def _check_points(
    points: ArrayLike, normals: ArrayLike | None
) -> tuple[np.ndarray, np.ndarray | None]:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim == 3 and p.shape[2] == 3:
        p = p.reshape(-1, 3)
    if p.ndim != 2 or p.shape[1] != 3:
        raise DataError(f"points: expected shape (N, 3) or (H, W, 3), got {p.shape}")
    n = None
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        if len(n) != len(p):
            raise DataError(f"normals: expected {len(p)} rows like points, got {len(n)}")
    return p, n


def write_ply(
    path: str | Path, points: ArrayLike, normals: ArrayLike | None = None, *, binary: bool = True
) -> None:
    """Write points (and normals) as a PLY point cloud (float32, binary little-endian or ascii)."""
    p, n = _check_points(points, normals)
    props = [("x", p[:, 0]), ("y", p[:, 1]), ("z", p[:, 2])]
    if n is not None:
        props += [("nx", n[:, 0]), ("ny", n[:, 1]), ("nz", n[:, 2])]
    _ply.write_ply(Path(path), props, None, binary)


def write_pcd(
    path: str | Path,
    points: ArrayLike,
    normals: ArrayLike | None = None,
    *,
    data: str = "binary",
    organized_shape: tuple[int, int] | None = None,
) -> None:
    """Write a PCD v0.7 file (float32 fields x y z [normal_x normal_y normal_z]).

    Args:
        points: (N, 3) or (H, W, 3) (organised; NaN allowed for missing points).
        data: "ascii", "binary" or "binary_compressed" (LZF; slow pure-Python compressor).
        organized_shape: (H, W) with H * W == N, or taken from an (H, W, 3) array.
    """
    arr = np.asarray(points)
    if organized_shape is None and arr.ndim == 3:
        organized_shape = (arr.shape[0], arr.shape[1])
    p, n = _check_points(points, normals)
    h, w = organized_shape if organized_shape is not None else (1, len(p))
    if h * w != len(p):
        raise DataError(
            f"write_pcd: organized_shape {organized_shape} does not hold {len(p)} points"
        )
    cols = p if n is None else np.column_stack([p, n])
    names = ["x", "y", "z"] + ([] if n is None else ["normal_x", "normal_y", "normal_z"])
    k = len(names)
    head = (
        "# .PCD v0.7 - Point Cloud Data file format (written by mks_sim)\nVERSION 0.7\n"
        f"FIELDS {' '.join(names)}\nSIZE {' '.join(['4'] * k)}\nTYPE {' '.join(['F'] * k)}\n"
        f"COUNT {' '.join(['1'] * k)}\nWIDTH {w}\nHEIGHT {h}\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {len(p)}\nDATA {data}\n"
    )
    c32 = cols.astype("<f4")
    with open(path, "wb") as fh:
        fh.write(head.encode("ascii"))
        if data == "ascii":
            np.savetxt(fh, c32, fmt="%.9g")
        elif data == "binary":
            fh.write(c32.tobytes())
        elif data == "binary_compressed":
            raw = np.ascontiguousarray(c32.T).tobytes()  # field-major
            comp = lzf_compress(raw)
            fh.write(struct.pack("<II", len(comp), len(raw)) + comp)
        else:
            raise DataError(
                f"write_pcd: data must be ascii, binary or binary_compressed, got {data!r}"
            )


def write_npy(path: str | Path, points: ArrayLike) -> None:
    """Write (N, 3) or (H, W, 3) points as .npy (float64)."""
    p = np.asarray(points, dtype=np.float64)
    if p.shape[-1] != 3 or p.ndim not in (2, 3):
        raise DataError(f"write_npy: expected (N, 3) or (H, W, 3), got {p.shape}")
    np.save(path, p)


def write_npz(path: str | Path, points: ArrayLike, normals: ArrayLike | None = None) -> None:
    """Write points (and normals) as .npz with keys ``points`` and ``normals``."""
    p = np.asarray(points, dtype=np.float64)
    if p.shape[-1] != 3 or p.ndim not in (2, 3):
        raise DataError(f"write_npz: expected (N, 3) or (H, W, 3), got {p.shape}")
    if normals is None:
        np.savez(path, points=p)
    else:
        np.savez(path, points=p, normals=np.asarray(normals, dtype=np.float64))


def write_point_cloud(
    path: str | Path, points: ArrayLike, normals: ArrayLike | None = None
) -> None:
    """Write by extension: .ply (binary), .pcd (binary), .npy, .npz."""
    ext = Path(path).suffix.lower()
    if ext == ".ply":
        write_ply(path, points, normals)
    elif ext == ".pcd":
        write_pcd(path, points, normals)
    elif ext == ".npy":
        write_npy(path, points)
    elif ext == ".npz":
        write_npz(path, points, normals)
    else:
        raise DataError(
            f"{Path(path).name}: unknown point-cloud type {ext!r}; expected .ply, .pcd, .npy or .npz"
        )
