"""Scene 1: dark flat parts on a light tray, for 2-D silhouette analysis (paper Figure 4-1).

The catalogue follows the paper's Tables 4-1 and 4-3 (objects 1..11: centroid in pixels,
radius, corners, holes) plus a washer. A paper pixel is laid out as 1 mm on the tray:
world ``x = (u - 256) mm``, ``y = (256 - v) mm`` (image v grows downwards, world y upwards),
so the default layout reproduces the paper's arrangement. The paper's radii 1, 2, 3, 5 are
our disc radii in cm (the circle model's reference radius 2 is the 2 cm disc).

Parts are 4 mm thick. Plates without holes are built from box/cylinder geoms; parts with a
hole (nuts, washer) are meshes (an annular prism, inlined in the MJCF) that render and ray
cast with their hole and collide by their convex hull (irrelevant for a part lying flat).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from dm_control import mjcf

from mks_sim.sim import names
from mks_sim.sim.objects import ObjectSpec

THICKNESS_M = 0.004
TRAY_HALF = (0.24, 0.21, 0.003)  # m
TRAY_TOP_Z = names.TABLE_TOP_Z + 2 * TRAY_HALF[2]
PART_RGBA = (0.12, 0.12, 0.13, 1.0)  # dark parts ...
TRAY_RGBA = (0.88, 0.88, 0.85, 1.0)  # ... on a light tray, for thresholding
_MM = 0.001


@dataclass(frozen=True)
class FlatPart:
    """One scene-1 part: what it is and where the paper's layout puts it.

    Attributes:
        name: body name (``flat_01`` ... ``flat_12``).
        kind: ``disc``, ``square_plate``, ``l_plate``, ``t_plate``, ``u_plate``,
            ``square_nut``, ``hex_nut``, ``washer``.
        u_px, v_px: paper pixel coordinates of the centroid (Tables 4-1, 4-3).
        corners: number of silhouette corners (Table 4-3 convention; a concave corner counts).
        holes: number of through holes.
        radius_m: outer radius of a round part (disc, washer), else 0.
        hole_radius_m: radius of the hole, else 0.
        paper_index: row of Tables 4-1/4-3 (0 = not in the paper).
    """

    name: str
    kind: str
    u_px: float
    v_px: float
    corners: int
    holes: int
    radius_m: float = 0.0
    hole_radius_m: float = 0.0
    paper_index: int = 0

    @property
    def default_xy(self) -> tuple[float, float]:
        """World (x, y) of the centroid in the default layout, metres."""
        return ((self.u_px - 256.0) * _MM, (256.0 - self.v_px) * _MM)


CATALOGUE: tuple[FlatPart, ...] = (
    FlatPart("flat_01", "l_plate", 256, 86, corners=6, holes=0, paper_index=1),
    FlatPart("flat_02", "square_plate", 371, 137, corners=4, holes=0, paper_index=2),
    FlatPart("flat_03", "t_plate", 269, 171, corners=8, holes=0, paper_index=3),
    FlatPart("flat_04", "disc", 397, 223, 0, 0, radius_m=0.010, paper_index=4),
    FlatPart("flat_05", "disc", 320, 224, 0, 0, radius_m=0.020, paper_index=5),
    FlatPart("flat_06", "disc", 128, 240, 0, 0, radius_m=0.030, paper_index=6),
    FlatPart("flat_07", "disc", 230, 257, 0, 0, radius_m=0.050, paper_index=7),
    FlatPart("flat_08", "square_nut", 358, 309, 4, 1, hole_radius_m=0.005, paper_index=8),
    FlatPart("flat_09", "hex_nut", 333, 343, 6, 1, hole_radius_m=0.005, paper_index=9),
    FlatPart("flat_10", "u_plate", 256, 429, corners=8, holes=0, paper_index=10),
    FlatPart("flat_11", "hex_nut", 384, 429, 6, 1, hole_radius_m=0.005, paper_index=11),
    FlatPart("flat_12", "washer", 150, 390, 0, 1, radius_m=0.015, hole_radius_m=0.006),
)
SQUARE_NUT_SIDE_M = 0.024
HEX_NUT_ACROSS_FLATS_M = 0.024
SQUARE_PLATE_SIDE_M = 0.028

# Plates as (centre x, centre y, half x, half y) boxes in mm, before centring on the centroid.
_PLATE_BOXES: dict[str, tuple[tuple[float, float, float, float], ...]] = {
    "l_plate": ((20, 7, 20, 7), (7, 27, 7, 13)),  # 40 x 40 mm, arms 14 mm wide
    "t_plate": ((22, 36, 22, 6), (22, 15, 7, 15)),  # bar 44 x 12, stem 14 x 30
    "u_plate": ((20, 6, 20, 6), (6, 24, 6, 12), (34, 24, 6, 12)),  # 40 x 36, 12 mm walls
}


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


def polygon_outline(corners: int, apothem: float, n: int = 48) -> np.ndarray:
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


def _outline(part: FlatPart) -> np.ndarray:
    if part.kind == "square_nut":
        # Corners at k * 90 degrees: a diamond in the object frame (the yaw turns it).
        return polygon_outline(4, SQUARE_NUT_SIDE_M / 2)
    if part.kind == "hex_nut":
        return polygon_outline(6, HEX_NUT_ACROSS_FLATS_M / 2)
    return polygon_outline(0, part.radius_m)


def add_tray(root: mjcf.RootElement) -> None:
    """The light tray under the flat parts (static body ``names.TRAY``)."""
    tray = root.worldbody.add("body", name=names.TRAY, pos=(0.0, 0.0, names.TABLE_TOP_Z))
    tray.add(
        "geom",
        name="tray_geom",
        type="box",
        size=TRAY_HALF,
        pos=(0, 0, TRAY_HALF[2]),
        rgba=TRAY_RGBA,
    )


def add_flat_part(root: mjcf.RootElement, part: FlatPart) -> ObjectSpec:
    """Add one flat part at its default (paper) position, resting on the tray."""
    x, y = part.default_xy
    h = THICKNESS_M / 2
    body = root.worldbody.add("body", name=part.name, pos=(x, y, TRAY_TOP_Z + h))
    body.add("freejoint", name=names.free_joint(part.name))
    common = dict(rgba=PART_RGBA, density=2000.0, friction=(0.8, 0.01, 0.0002))
    if part.kind == "disc":
        body.add(
            "geom", name=f"{part.name}_geom", type="cylinder", size=(part.radius_m, h), **common
        )
        return ObjectSpec(part.name, part.kind, h, part.radius_m)
    if part.kind == "square_plate":
        half = SQUARE_PLATE_SIDE_M / 2
        body.add("geom", name=f"{part.name}_geom", type="box", size=(half, half, h), **common)
        return ObjectSpec(part.name, part.kind, h, half * np.sqrt(2))
    if part.kind in _PLATE_BOXES:
        boxes = np.array(_PLATE_BOXES[part.kind], dtype=float) * _MM
        areas = 4 * boxes[:, 2] * boxes[:, 3]
        centroid = (boxes[:, :2] * areas[:, None]).sum(0) / areas.sum()
        reach = 0.0
        for k, (cx, cy, hx, hy) in enumerate(boxes):
            px, py = cx - centroid[0], cy - centroid[1]
            body.add(
                "geom",
                name=f"{part.name}_geom_{k}",
                type="box",
                size=(hx, hy, h),
                pos=(px, py, 0.0),
                **common,
            )
            reach = max(reach, float(np.hypot(abs(px) + hx, abs(py) + hy)))
        return ObjectSpec(part.name, part.kind, h, reach)
    outline = _outline(part)
    verts, faces = annular_prism(outline, part.hole_radius_m, THICKNESS_M)
    mesh = root.asset.add(
        "mesh", name=f"{part.name}_mesh", vertex=verts.ravel(), face=faces.ravel()
    )
    body.add("geom", name=f"{part.name}_geom", type="mesh", mesh=mesh, **common)
    return ObjectSpec(part.name, part.kind, h, float(np.max(np.hypot(*outline.T))))


def flat_part(name: str) -> FlatPart:
    """Catalogue entry of ``name``."""
    for part in CATALOGUE:
        if part.name == name:
            return part
    from mks_sim.errors import NotFound

    raise NotFound(f"no flat part {name!r}; expected one of {[p.name for p in CATALOGUE]}")
