"""PLY parsing and writing shared by point-cloud and mesh I/O (ascii, binary LE/BE)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mks_sim.errors import DataError

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


@dataclass
class _Element:
    name: str
    count: int
    props: list[tuple[str, str, str | None]] = field(default_factory=list)  # name, type, count type


def _err(path: Path, msg: str) -> DataError:
    return DataError(f"{path.name}: {msg}")


def has_element(path: Path, name: str) -> bool:
    """Whether the PLY header of ``path`` declares ``element name`` (only the header is read).

    Raises:
        DataError: not a PLY file or no ``end_header`` within the first 64 KiB.
    """
    with open(path, "rb") as fh:
        head = fh.read(65536)
    if not head.startswith(b"ply"):
        raise _err(path, "not a PLY file (expected the magic line 'ply')")
    end = head.find(b"end_header")
    if end < 0:
        raise _err(path, "PLY header has no 'end_header' line")
    for line in head[:end].decode("ascii", "replace").splitlines():
        tok = line.split()
        if len(tok) >= 2 and tok[0] == "element" and tok[1] == name:
            return True
    return False


def read_ply(path: Path) -> dict[str, dict[str, np.ndarray] | list[np.ndarray]]:
    """Parse a PLY file into {element: {scalar property: (count,) array}} (lists as lists).

    A list property becomes a (count, k) int array when every row has k entries, else a list of
    arrays (key ``"<prop>"``).
    """
    raw = path.read_bytes()
    if not raw.startswith(b"ply"):
        raise _err(path, "not a PLY file (expected the magic line 'ply')")
    end = raw.find(b"end_header")
    if end < 0:
        raise _err(path, "PLY header has no 'end_header' line")
    nl = raw.find(b"\n", end)
    body = raw[nl + 1 :] if nl >= 0 else b""
    fmt = None
    elements: list[_Element] = []
    for lineno, line in enumerate(raw[:end].decode("ascii", "replace").splitlines(), 1):
        tok = line.split()
        if not tok or tok[0] in ("ply", "comment", "obj_info"):
            continue
        try:
            if tok[0] == "format":
                fmt = tok[1]
            elif tok[0] == "element":
                count = int(tok[2])
                if count < 0:
                    raise ValueError(f"expected a row count >= 0, got {count}")
                elements.append(_Element(tok[1], count))
            elif tok[0] == "property":
                if not elements:
                    raise ValueError("property before any element")
                if tok[1] == "list":
                    elements[-1].props.append((tok[4], _TYPES[tok[3]], _TYPES[tok[2]]))
                else:
                    elements[-1].props.append((tok[2], _TYPES[tok[1]], None))
            else:
                raise ValueError(f"unknown header keyword {tok[0]!r}")
        except (IndexError, KeyError, ValueError) as exc:
            raise _err(path, f"bad PLY header line {lineno}: {line.strip()!r} ({exc})") from exc
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise _err(path, f"PLY format must be ascii or binary_*_endian, got {fmt!r}")
    with np.errstate(all="ignore"):  # hostile bytes (signalling NaN, overflow) must not warn
        if fmt == "ascii":
            return _read_ascii(path, body, elements)
        return _read_binary(path, body, elements, "<" if fmt == "binary_little_endian" else ">")


def _read_ascii(path: Path, body: bytes, elements: list[_Element]) -> dict:
    lines = body.decode("ascii", "replace").splitlines()
    lines = [ln for ln in lines if ln.strip()]
    out: dict = {}
    pos = 0
    for el in elements:
        rows = lines[pos : pos + el.count]
        if len(rows) < el.count:
            raise _err(
                path,
                f"header says element {el.name} has {el.count} rows but the data holds {len(rows)}",
            )
        pos += el.count
        data: dict = {}
        if all(cnt is None for _, _, cnt in el.props):
            try:
                arr = np.array(" ".join(rows).split(), dtype=np.float64)
            except ValueError as exc:
                raise _err(path, f"non-numeric value in element {el.name}: {exc}") from exc
            if arr.size != el.count * len(el.props):
                raise _err(
                    path,
                    f"element {el.name}: expected {len(el.props)} values per row, "
                    f"got {arr.size} values in {el.count} rows",
                )
            arr = arr.reshape(el.count, len(el.props))
            for k, (name, typ, _) in enumerate(el.props):
                data[name] = arr[:, k].astype(typ)
        else:
            cols: dict[str, list] = {name: [] for name, _, _ in el.props}
            for r, row in enumerate(rows):
                tok = row.split()
                i = 0
                try:
                    for name, _typ, cnt in el.props:
                        if cnt is None:
                            cols[name].append(float(tok[i]))
                            i += 1
                        else:
                            k = int(tok[i])
                            cols[name].append(np.array(tok[i + 1 : i + 1 + k], dtype=np.int64))
                            if len(cols[name][-1]) != k:
                                raise IndexError
                            i += 1 + k
                except (IndexError, ValueError) as exc:
                    raise _err(path, f"element {el.name} row {r}: malformed {row!r}") from exc
            for name, typ, cnt in el.props:
                data[name] = np.array(cols[name], dtype=typ) if cnt is None else _lists(cols[name])
        out[el.name] = data
    if pos < len(lines):
        last = elements[-1] if elements else None
        raise _err(
            path,
            f"the data holds {len(lines) - pos} more row(s) than the header declares"
            + (f" (element {last.name} {last.count})" if last else " (no elements)"),
        )
    return out


def _lists(rows: list[np.ndarray]) -> np.ndarray | list[np.ndarray]:
    if rows and len({len(r) for r in rows}) == 1:
        return np.stack(rows).astype(np.int64)
    if not rows:
        return np.zeros((0, 3), np.int64)
    return rows


def _read_binary(path: Path, body: bytes, elements: list[_Element], endian: str) -> dict:
    out: dict = {}
    pos = 0
    for el in elements:
        data: dict = {}
        if all(cnt is None for _, _, cnt in el.props):
            dt = np.dtype([(n, endian + t) for n, t, _ in el.props])
            need = dt.itemsize * el.count
            if pos + need > len(body):
                have = (len(body) - pos) // max(dt.itemsize, 1)
                raise _err(
                    path,
                    f"header says element {el.name} has {el.count} rows but the data holds {have}",
                )
            rec = np.frombuffer(body, dtype=dt, count=el.count, offset=pos)
            pos += need
            for n, _, _ in el.props:
                data[n] = rec[n].copy()
        else:
            data, pos = _read_binary_lists(path, body, pos, el, endian)
        out[el.name] = data
    if body[pos:].strip(b" \t\r\n\x00"):
        last = elements[-1] if elements else None
        raise _err(
            path,
            f"the data holds {len(body) - pos} more byte(s) than the header declares"
            + (f" (element {last.name} {last.count})" if last else " (no elements)"),
        )
    return out


def _read_binary_lists(path: Path, body: bytes, pos: int, el: _Element, endian: str):
    # Fast path: every list has the length of the first one (triangle meshes).
    fields: list[tuple] = []
    try:
        p = pos
        for n, t, cnt in el.props:
            if cnt is None:
                fields.append((n, endian + t))
                p += np.dtype(t).itemsize
            else:
                k = int(np.frombuffer(body, endian + cnt, 1, p)[0])
                fields.append((n + "__n", endian + cnt))
                fields.append((n, endian + t, (k,)))
                p += np.dtype(cnt).itemsize + k * np.dtype(t).itemsize
        dt = np.dtype(fields)
        if el.count == 0:
            return {n: np.zeros((0, 3), np.int64) for n, _, _ in el.props}, pos
        if pos + dt.itemsize * el.count <= len(body):
            rec = np.frombuffer(body, dtype=dt, count=el.count, offset=pos)
            ok = all(np.all(rec[n + "__n"] == rec.dtype[n].shape[0]) for n, _, c in el.props if c)
            if ok:
                data: dict = {
                    n: (rec[n].astype(np.int64) if c else rec[n].copy()) for n, _, c in el.props
                }
                return data, pos + dt.itemsize * el.count
    except (ValueError, IndexError):
        pass
    # General path: variable-length lists, one row at a time.
    cols: dict[str, list] = {n: [] for n, _, _ in el.props}
    p = pos
    try:
        for _ in range(el.count):
            for n, t, cnt in el.props:
                if cnt is None:
                    cols[n].append(np.frombuffer(body, endian + t, 1, p)[0])
                    p += np.dtype(t).itemsize
                else:
                    k = int(np.frombuffer(body, endian + cnt, 1, p)[0])
                    p += np.dtype(cnt).itemsize
                    cols[n].append(np.frombuffer(body, endian + t, k, p).astype(np.int64))
                    p += k * np.dtype(t).itemsize
    except ValueError as exc:
        raise _err(
            path, f"element {el.name}: data ends early (header says {el.count} rows)"
        ) from exc
    data = {
        n: (np.array(cols[n], dtype=t) if c is None else _lists(cols[n])) for n, t, c in el.props
    }
    return data, p


def write_ply(
    path: Path,
    vertex_props: list[tuple[str, np.ndarray]],
    faces: np.ndarray | None = None,
    binary: bool = True,
) -> None:
    """Write a PLY with float32 vertex properties and optional triangle faces."""
    n = len(vertex_props[0][1]) if vertex_props else 0
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0"]
    head.append("comment written by mks_sim")
    head.append(f"element vertex {n}")
    head += [f"property float {name}" for name, _ in vertex_props]
    if faces is not None:
        head.append(f"element face {len(faces)}")
        head.append("property list uchar int vertex_indices")
    head.append("end_header")
    cols = np.column_stack([c for _, c in vertex_props]) if vertex_props else np.zeros((0, 0))
    with open(path, "wb") as fh:
        fh.write(("\n".join(head) + "\n").encode("ascii"))
        if binary:
            fh.write(cols.astype("<f4").tobytes())
            if faces is not None:
                dt = np.dtype([("n", "u1"), ("v", "<i4", (3,))])
                rec = np.empty(len(faces), dt)
                rec["n"] = 3
                rec["v"] = faces
                fh.write(rec.tobytes())
        else:
            if len(cols):
                np.savetxt(fh, cols, fmt="%.9g")
            if faces is not None and len(faces):
                np.savetxt(fh, np.column_stack([np.full(len(faces), 3), faces]), fmt="%d")
