"""Mesh files: PLY (with faces), STL (ascii and binary), OBJ.

Polygons are triangulated as fans; STL's unshared corners are welded by exact coordinate
equality. A malformed or truncated file raises :class:`~mks_sim.errors.DataError` naming it.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from mks_sim.errors import DataError, NotFound
from mks_sim.geometry.meshes import Mesh
from mks_sim.io import _ply

__all__ = ["read_mesh", "write_mesh", "write_obj", "write_ply_mesh", "write_stl"]


def _err(path: Path, msg: str) -> DataError:
    return DataError(f"{path.name}: {msg}")


def read_mesh(path: str | Path) -> Mesh:
    """Read a triangle mesh from .ply, .stl or .obj.

    Raises:
        NotFound: the file does not exist.
        DataError: malformed, truncated, no faces, or an index out of range.
    """
    path = Path(path)
    if not path.is_file():
        raise NotFound(f"mesh file not found: {path}")
    ext = path.suffix.lower()
    if ext == ".ply":
        v, f = _read_ply(path)
    elif ext == ".stl":
        v, f = _read_stl(path)
    elif ext == ".obj":
        v, f = _read_obj(path)
    else:
        raise _err(path, f"unknown mesh type {ext!r}; expected .ply, .stl or .obj")
    if len(f) == 0:
        raise _err(path, "the file holds no faces")
    if f.min() < 0 or f.max() >= len(v):
        raise _err(path, f"face index out of range [0, {len(v) - 1}]: got {f.min()}..{f.max()}")
    if not np.all(np.isfinite(v)):
        raise _err(path, "vertex coordinates contain NaN or inf")
    return Mesh(v, f)


def _fan(polys: list[np.ndarray] | np.ndarray) -> np.ndarray:
    if isinstance(polys, np.ndarray):
        if polys.shape[1] == 3:
            return polys.astype(np.int64)
        polys = list(polys)
    tris = [np.stack([np.full(len(p) - 2, p[0]), p[1:-1], p[2:]], 1) for p in polys if len(p) >= 3]
    return np.concatenate(tris).astype(np.int64) if tris else np.zeros((0, 3), np.int64)


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    data = _ply.read_ply(path)
    v = data.get("vertex")
    if not isinstance(v, dict) or not all(k in v for k in "xyz"):
        raise _err(path, "PLY has no vertex element with x, y, z properties")
    verts = np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64)
    face = data.get("face")
    if not isinstance(face, dict):
        raise _err(path, "PLY has no face element (is it a point cloud? use read_point_cloud)")
    key = "vertex_indices" if "vertex_indices" in face else "vertex_index"
    if key not in face:
        raise _err(path, "PLY face element has no vertex_indices list")
    return verts, _fan(face[key])


def _read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    raw = path.read_bytes()
    if len(raw) >= 84:
        (n,) = struct.unpack("<I", raw[80:84])
        if len(raw) == 84 + 50 * n:
            dt = np.dtype([("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])
            tri = np.frombuffer(raw, dtype=dt, count=n, offset=84)["v"].astype(np.float64)
            return _weld(tri)
    head = raw[:1024].lstrip().lower()
    if not head.startswith(b"solid"):
        if len(raw) >= 84:
            (n,) = struct.unpack("<I", raw[80:84])
            raise _err(
                path,
                f"binary STL header says {n} triangles ({84 + 50 * n} bytes) but the file has "
                f"{len(raw)} bytes",
            )
        raise _err(path, f"not an STL file ({len(raw)} bytes, no 'solid' header)")
    text = raw.decode("ascii", "replace")
    verts = []
    for lineno, line in enumerate(text.splitlines(), 1):
        tok = line.split()
        if tok and tok[0] == "vertex":
            try:
                verts.append([float(t) for t in tok[1:4]])
                if len(tok) < 4:
                    raise ValueError("fewer than 3 coordinates")
            except ValueError as exc:
                raise _err(path, f"line {lineno}: bad vertex {line.strip()!r} ({exc})") from exc
    if len(verts) % 3:
        raise _err(path, f"ascii STL holds {len(verts)} vertices, not a multiple of 3 (truncated?)")
    if "endsolid" not in text:
        raise _err(path, "ascii STL has no 'endsolid' (truncated?)")
    return _weld(np.array(verts, dtype=np.float64).reshape(-1, 3, 3))


def _weld(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    uniq, inv = np.unique(tri.reshape(-1, 3), axis=0, return_inverse=True)
    return uniq, inv.reshape(-1, 3).astype(np.int64)


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    verts: list[list[float]] = []
    polys: list[np.ndarray] = []
    text = path.read_bytes().decode("utf-8", "replace")
    for lineno, line in enumerate(text.splitlines(), 1):
        tok = line.split()
        if not tok:
            continue
        try:
            if tok[0] == "v":
                if len(tok) < 4:
                    raise ValueError("fewer than 3 coordinates")
                verts.append([float(t) for t in tok[1:4]])
            elif tok[0] == "f":
                idx = np.array([int(t.split("/")[0]) for t in tok[1:]], dtype=np.int64)
                if len(idx) < 3:
                    raise ValueError("a face needs at least 3 vertices")
                # 1-based; negative = relative to the vertices read so far.
                idx = np.where(idx < 0, len(verts) + idx, idx - 1)
                polys.append(idx)
        except ValueError as exc:
            raise _err(
                path, f"line {lineno}: bad {tok[0]!r} entry {line.strip()!r} ({exc})"
            ) from exc
    return np.array(verts, dtype=np.float64).reshape(-1, 3), _fan(polys)


def write_stl(path: str | Path, mesh: Mesh) -> None:
    """Write a binary STL (float32)."""
    tri = mesh.triangles.astype("<f4")
    dt = np.dtype([("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec = np.zeros(len(tri), dt)
    rec["n"] = mesh.normals
    rec["v"] = tri
    with open(path, "wb") as fh:
        fh.write(b"mks_sim binary STL".ljust(80, b" "))
        fh.write(struct.pack("<I", len(tri)))
        fh.write(rec.tobytes())


def write_obj(path: str | Path, mesh: Mesh) -> None:
    """Write a Wavefront OBJ (v and f lines only)."""
    with open(path, "w") as fh:
        fh.write("# written by mks_sim\n")
        np.savetxt(fh, mesh.vertices, fmt="v %.17g %.17g %.17g")
        np.savetxt(fh, mesh.faces + 1, fmt="f %d %d %d")


def write_ply_mesh(path: str | Path, mesh: Mesh, *, binary: bool = True) -> None:
    """Write a PLY with vertices (float32) and triangle faces."""
    v = mesh.vertices
    _ply.write_ply(Path(path), [("x", v[:, 0]), ("y", v[:, 1]), ("z", v[:, 2])], mesh.faces, binary)


def write_mesh(path: str | Path, mesh: Mesh) -> None:
    """Write by extension: .stl (binary), .obj, .ply (binary)."""
    ext = Path(path).suffix.lower()
    if ext == ".stl":
        write_stl(path, mesh)
    elif ext == ".obj":
        write_obj(path, mesh)
    elif ext == ".ply":
        write_ply_mesh(path, mesh)
    else:
        raise DataError(
            f"{Path(path).name}: unknown mesh type {ext!r}; expected .stl, .obj or .ply"
        )
