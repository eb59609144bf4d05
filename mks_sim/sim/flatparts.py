"""Flat parts: plates lying on a tray, for 2-D silhouette analysis (scene 1, paper Figure 4-1).

What the parts are lives in the scene file (``worlds/scene1.toml``: ``[tray]``,
``[flat_parts]`` defaults and one ``[[flat_part]]`` per part, schema in ``docs/worlds.md``);
this module only turns shapes into MJCF. A part is an outline extruded by its thickness:

- ``disc``: a cylinder primitive (``radius_mm``), or with ``hole_radius_mm`` a washer mesh;
- ``boxes``: a union of axis-aligned boxes (``boxes_mm``: centre x, y, half x, y in mm), one
  box geom each, the body origin at the outline's area centroid;
- ``polygon``: a regular ``sides``-gon (``apothem_mm``, corners on the x axis) with an
  optional centred round hole, a mesh.

Meshes (parts with a hole, polygons) are inlined in the MJCF; they render and ray cast with
their hole and collide by their convex hull (irrelevant for a part lying flat).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from dm_control import mjcf

from mks_sim.errors import SpecError
from mks_sim.sim import names
from mks_sim.sim.objects import ObjectSpec

SHAPES = ("disc", "boxes", "polygon")
_MM = 0.001
_OUTLINE_SAMPLES = 48  # samples of a round or polygonal outline (a multiple of 4 and 6)
_DEFAULT_KEYS = {"thickness_mm", "rgb", "density", "friction", "pixel_mm", "origin_px"}
_PART_KEYS = {
    "name", "kind", "at_px", "corners", "holes", "paper_index", "shape", "radius_mm",
    "hole_radius_mm", "boxes_mm", "sides", "apothem_mm",
}  # fmt: skip
_TRAY_KEYS = {"size", "rgb"}


@dataclass(frozen=True)
class FlatPart:
    """One flat part of a scene file: what it is, its shape, where the default layout puts it.

    Attributes:
        name: body name (``flat_01`` ...).
        kind: what it is (``disc``, ``l_plate``, ``hex_nut``, ...; ground truth only).
        default_xy: world (x, y) of the centroid in the default layout, metres.
        uv_px: the centroid in the paper's pixel units (Tables 4-1, 4-3).
        corners: number of silhouette corners (Table 4-3 convention; a concave corner counts).
        holes: number of through holes.
        shape: ``disc`` | ``boxes`` | ``polygon``.
        radius_m: outer radius of a disc, else 0.
        hole_radius_m: radius of the centred hole, else 0.
        boxes_m: (centre x, centre y, half x, half y) per box of a ``boxes`` part, metres.
        sides: corners of a ``polygon`` part's outline.
        apothem_m: centre-to-side distance of a ``polygon`` part, metres.
        thickness_m: extrusion, metres.
        rgba: colour.
        density: kg/m^3.
        friction: MuJoCo (sliding, torsional, rolling).
        paper_index: row of Tables 4-1/4-3 (0 = not in the paper).
        origin_px: the paper pixel at the world origin (``[flat_parts] origin_px``).
        pixel_m: metres per paper pixel on the tray (``[flat_parts] pixel_mm``).
    """

    name: str
    kind: str
    default_xy: tuple[float, float]
    uv_px: tuple[float, float]
    corners: int
    holes: int
    shape: str
    radius_m: float = 0.0
    hole_radius_m: float = 0.0
    boxes_m: tuple[tuple[float, float, float, float], ...] = ()
    sides: int = 0
    apothem_m: float = 0.0
    thickness_m: float = 0.004
    rgba: tuple[float, float, float, float] = (0.12, 0.12, 0.13, 1.0)
    density: float = 2000.0
    friction: tuple[float, float, float] = (0.8, 0.01, 0.0002)
    paper_index: int = 0
    origin_px: tuple[float, float] = (0.0, 0.0)
    pixel_m: float = 0.001

    def uv(self, x: float, y: float) -> tuple[float, float]:
        """The paper pixel of world (x, y) (metres): image v grows downwards, world y up."""
        return (self.origin_px[0] + x / self.pixel_m, self.origin_px[1] - y / self.pixel_m)

    def outline(self) -> np.ndarray:
        """(N, 2) outer outline of a disc or polygon, sampled at the angles ``2 pi k / N``
        around the body origin (metres)."""
        if self.shape == "polygon":
            return polygon_outline(self.sides, self.apothem_m, _OUTLINE_SAMPLES)
        return polygon_outline(0, self.radius_m, _OUTLINE_SAMPLES)


def _num(entry: Mapping[str, Any], key: str, where: str, *, low: float = 0.0) -> float:
    v = entry.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= low:
        raise SpecError(f"{where}: field {key!r}: expected a number > {low:g}, got {v!r}")
    return float(v)


def _count(entry: Mapping[str, Any], key: str, where: str) -> int:
    v = entry.get(key, 0)
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise SpecError(f"{where}: field {key!r}: expected an integer >= 0, got {v!r}")
    return v


def _floats(v: Any, n: int, where: str, key: str) -> tuple[float, ...]:
    if (
        not isinstance(v, list)
        or len(v) != n
        or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        or not all(math.isfinite(x) for x in v)
    ):
        raise SpecError(f"{where}: field {key!r}: expected {n} finite numbers, got {v!r}")
    return tuple(float(x) for x in v)


def _unknown(entry: Any, allowed: set[str], where: str) -> Mapping[str, Any]:
    if not isinstance(entry, Mapping):
        raise SpecError(f"{where}: expected a table, got {entry!r}")
    extra = set(entry) - allowed
    if extra:
        raise SpecError(f"{where}: unknown field(s) {sorted(extra)}; allowed: {sorted(allowed)}")
    return entry


def parse_flat_parts(doc: Mapping[str, Any], path: str) -> tuple[FlatPart, ...]:
    """The ``[[flat_part]]`` entries of a scene file (with its ``[flat_parts]`` defaults).

    Raises:
        SpecError: a malformed entry (one line: file, entry, field, expected, got).
    """
    defaults = _unknown(doc.get("flat_parts", {}), _DEFAULT_KEYS, f"{path}: [flat_parts]")
    dwhere = f"{path}: [flat_parts]"
    thickness = _num({"t": defaults.get("thickness_mm", 4.0)}, "t", dwhere) * _MM
    r, g, b = _floats(defaults.get("rgb", [0.12, 0.12, 0.13]), 3, dwhere, "rgb")
    density = _num({"density": defaults.get("density", 2000.0)}, "density", dwhere)
    f0, f1, f2 = _floats(defaults.get("friction", [0.8, 0.01, 0.0002]), 3, dwhere, "friction")
    pixel = _num({"pixel_mm": defaults.get("pixel_mm", 1.0)}, "pixel_mm", dwhere) * _MM
    o = _floats(defaults.get("origin_px", [0.0, 0.0]), 2, dwhere, "origin_px")
    origin = (o[0], o[1])
    entries = doc.get("flat_part", [])
    if not isinstance(entries, list):
        raise SpecError(f"{path}: 'flat_part': expected [[flat_part]] tables, got {entries!r}")
    parts: list[FlatPart] = []
    for i, raw in enumerate(entries):
        name = raw.get("name") if isinstance(raw, Mapping) else None
        where = f"{path}: flat_part {name!r}" if name else f"{path}: flat_part {i}"
        entry = _unknown(raw, _PART_KEYS, where)
        if not isinstance(name, str) or not name:
            raise SpecError(f"{where}: field 'name': expected a body name, got {name!r}")
        if any(p.name == name for p in parts):
            raise SpecError(f"{where}: field 'name': expected a unique name, got a duplicate")
        kind = entry.get("kind")
        if not isinstance(kind, str) or not kind:
            raise SpecError(f"{where}: field 'kind': expected a string, got {kind!r}")
        u, v = _floats(entry.get("at_px"), 2, where, "at_px")
        xy = ((u - origin[0]) * pixel, (origin[1] - v) * pixel)
        shape = entry.get("shape")
        if shape not in SHAPES:
            raise SpecError(f"{where}: field 'shape': expected one of {list(SHAPES)}, got {shape!r}")
        geo: dict[str, Any] = {}
        if shape == "disc":
            geo["radius_m"] = _num(entry, "radius_mm", where) * _MM
        elif shape == "polygon":
            sides = entry.get("sides")
            if isinstance(sides, bool) or not isinstance(sides, int) or sides < 3:
                raise SpecError(f"{where}: field 'sides': expected an integer >= 3, got {sides!r}")
            if _OUTLINE_SAMPLES % sides:
                raise SpecError(
                    f"{where}: field 'sides': expected a divisor of {_OUTLINE_SAMPLES}, got {sides}"
                )
            geo["sides"] = sides
            geo["apothem_m"] = _num(entry, "apothem_mm", where) * _MM
        else:
            boxes = entry.get("boxes_mm")
            if not isinstance(boxes, list) or not boxes:
                raise SpecError(f"{where}: field 'boxes_mm': expected [[cx, cy, hx, hy], ...], got {boxes!r}")  # fmt: skip
            geo["boxes_m"] = tuple(
                tuple(x * _MM for x in _floats(b, 4, where, "boxes_mm")) for b in boxes
            )
            if any(b[2] <= 0 or b[3] <= 0 for b in geo["boxes_m"]):
                raise SpecError(f"{where}: field 'boxes_mm': expected half extents > 0, got {boxes}")
        if "hole_radius_mm" in entry:
            if shape == "boxes":
                raise SpecError(f"{where}: field 'hole_radius_mm': expected no hole in a 'boxes' part")
            geo["hole_radius_m"] = _num(entry, "hole_radius_mm", where) * _MM
        paper_index = _count(entry, "paper_index", where)
        parts.append(
            FlatPart(
                name=name, kind=kind, default_xy=xy, uv_px=(u, v),
                corners=_count(entry, "corners", where), holes=_count(entry, "holes", where),
                shape=shape, thickness_m=thickness, rgba=(r, g, b, 1.0), density=density,
                friction=(f0, f1, f2), paper_index=paper_index, origin_px=origin, pixel_m=pixel,
                **geo,  # type: ignore[arg-type]
            )
        )  # fmt: skip
        part = parts[-1]
        if part.hole_radius_m and part.hole_radius_m >= float(np.min(np.hypot(*part.outline().T))):
            raise SpecError(f"{where}: field 'hole_radius_mm': expected a hole inside the outline, got {part.hole_radius_m / _MM:g} mm")  # fmt: skip
    return tuple(parts)


def annular_prism(
    outer_xy: np.ndarray, hole_radius: float, thickness: float
) -> tuple[np.ndarray, np.ndarray]:
    """Closed mesh of a flat part with one centred round hole.

    Args:
        outer_xy: (N, 2) outline sampled at the angles ``2 pi k / N`` around the origin
            (star-shaped outline), metres.
        hole_radius: radius of the hole, metres.
        thickness: metres; the prism spans z in [-thickness/2, thickness/2].

    Returns:
        vertices (4N, 3), faces (4N * 2, 3) counter-clockwise seen from outside.
    """
    n = len(outer_xy)
    ang = 2 * np.pi * np.arange(n) / n
    inner = hole_radius * np.column_stack([np.cos(ang), np.sin(ang)])
    h = thickness / 2
    verts = np.vstack(
        [
            np.column_stack([outer_xy, np.full(n, h)]),  # 0: top outer
            np.column_stack([inner, np.full(n, h)]),  # n: top inner
            np.column_stack([outer_xy, np.full(n, -h)]),  # 2n: bottom outer
            np.column_stack([inner, np.full(n, -h)]),  # 3n: bottom inner
        ]
    )
    i = np.arange(n)
    j = (i + 1) % n
    to, ti, bo, bi = i, i + n, i + 2 * n, i + 3 * n
    to1, ti1, bo1, bi1 = j, j + n, j + 2 * n, j + 3 * n
    faces = np.vstack(
        [
            np.column_stack([to, to1, ti1]),
            np.column_stack([to, ti1, ti]),  # top ring, normal +z
            np.column_stack([bo, bi1, bo1]),
            np.column_stack([bo, bi, bi1]),  # bottom ring, normal -z
            np.column_stack([bo, bo1, to1]),
            np.column_stack([bo, to1, to]),  # outer wall, normal outwards
            np.column_stack([bi, ti1, bi1]),
            np.column_stack([bi, ti, ti1]),  # hole wall, normal towards the axis
        ]
    )
    return verts, faces


def prism(outer_xy: np.ndarray, thickness: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed mesh of a star-shaped outline (no hole) extruded by ``thickness`` (fan caps)."""
    n = len(outer_xy)
    h = thickness / 2
    verts = np.vstack(
        [
            np.column_stack([outer_xy, np.full(n, h)]),
            np.column_stack([outer_xy, np.full(n, -h)]),
            [[0.0, 0.0, h], [0.0, 0.0, -h]],
        ]
    )
    i = np.arange(n)
    j = (i + 1) % n
    top, bottom = np.full(n, 2 * n), np.full(n, 2 * n + 1)
    faces = np.vstack(
        [
            np.column_stack([top, i, j]),
            np.column_stack([bottom, j + n, i + n]),
            np.column_stack([i + n, j + n, j]),
            np.column_stack([i + n, j, i]),
        ]
    )
    return verts, faces


def polygon_outline(corners: int, apothem: float, n: int = _OUTLINE_SAMPLES) -> np.ndarray:
    """(n, 2) regular ``corners``-gon (apothem = centre-to-side distance) sampled at the
    angles ``2 pi k / n``; ``n`` must be a multiple of ``corners`` so corners are samples.
    ``corners = 0`` gives a circle of radius ``apothem``."""
    ang = 2 * np.pi * np.arange(n) / n
    if corners == 0:
        r = np.full(n, apothem)
    else:
        sector = 2 * np.pi / corners
        # Corners at k * sector (a sample); face normals half-way between.
        rel = np.mod(ang, sector) - sector / 2
        r = apothem / np.cos(rel)
    return np.column_stack([r * np.cos(ang), r * np.sin(ang)])


def parse_tray(doc: Mapping[str, Any], path: str) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:  # fmt: skip
    """(half extents, rgba) of a scene file's ``[tray]``.

    Raises:
        SpecError: missing or malformed ``[tray]``.
    """
    where = f"{path}: [tray]"
    tray = _unknown(doc.get("tray"), _TRAY_KEYS, where)
    size = _floats(tray.get("size"), 3, where, "size")
    if min(size) <= 0:
        raise SpecError(f"{where}: field 'size': expected 3 half extents > 0, got {list(size)}")
    rgb = _floats(tray.get("rgb", [0.88, 0.88, 0.85]), 3, where, "rgb")
    return (size[0], size[1], size[2]), (*rgb, 1.0)  # type: ignore[return-value]


def add_tray(
    root: mjcf.RootElement,
    half: tuple[float, float, float],
    rgba: tuple[float, float, float, float],
) -> float:
    """The tray under the flat parts (static body ``names.TRAY`` on the table); returns the
    world z of its top."""
    tray = root.worldbody.add("body", name=names.TRAY, pos=(0.0, 0.0, names.TABLE_TOP_Z))
    tray.add("geom", name="tray_geom", type="box", size=half, pos=(0, 0, half[2]), rgba=rgba)
    return names.TABLE_TOP_Z + 2 * half[2]


def add_flat_part(root: mjcf.RootElement, part: FlatPart, support_z: float) -> ObjectSpec:
    """Add one flat part at its default position, lying on the support at ``support_z``."""
    x, y = part.default_xy
    h = part.thickness_m / 2
    body = root.worldbody.add("body", name=part.name, pos=(x, y, support_z + h))
    body.add("freejoint", name=names.free_joint(part.name))
    common = dict(rgba=part.rgba, density=part.density, friction=part.friction)
    if part.shape == "disc" and not part.hole_radius_m:
        body.add(
            "geom", name=f"{part.name}_geom", type="cylinder", size=(part.radius_m, h), **common
        )
        return ObjectSpec(part.name, part.kind, h, part.radius_m)
    if part.shape == "boxes":
        boxes = np.array(part.boxes_m, dtype=float)
        areas = 4 * boxes[:, 2] * boxes[:, 3]
        centroid = (boxes[:, :2] * areas[:, None]).sum(0) / areas.sum()
        reach = 0.0
        for k, (cx, cy, hx, hy) in enumerate(boxes):
            px, py = cx - centroid[0], cy - centroid[1]
            body.add(
                "geom",
                name=f"{part.name}_geom" if len(boxes) == 1 else f"{part.name}_geom_{k}",
                type="box",
                size=(hx, hy, h),
                pos=(px, py, 0.0),
                **common,
            )
            reach = max(reach, float(np.hypot(abs(px) + hx, abs(py) + hy)))
        return ObjectSpec(part.name, part.kind, h, reach)
    outline = part.outline()
    if part.hole_radius_m:
        verts, faces = annular_prism(outline, part.hole_radius_m, part.thickness_m)
    else:
        verts, faces = prism(outline, part.thickness_m)
    mesh = root.asset.add(
        "mesh", name=f"{part.name}_mesh", vertex=verts.ravel(), face=faces.ravel()
    )
    body.add("geom", name=f"{part.name}_geom", type="mesh", mesh=mesh, **common)
    return ObjectSpec(part.name, part.kind, h, float(np.max(np.hypot(*outline.T))))
