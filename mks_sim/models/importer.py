"""``mks-sim objects add``: a mesh file becomes a model-database object (issue 10 section 2).

:func:`add_object` reads a mesh (STL, OBJ, PLY via trimesh), converts it to metres, checks it
(empty, degenerate, non-watertight, absurd size for the Jaco hand, walls thinner than its
pads: :func:`pinch_fraction`), puts the body origin at
its centre of mass, and writes into ``out_dir``:

- ``NAME.obj``: the surface (metres, body frame);
- ``NAME_collision_NN.obj``: the convex collision parts, by CoACD (parameters in the TOML;
  its time is bounded by running it in a child process with a timeout; the convex hull when
  the mesh is convex or CoACD times out);
- ``NAME_freeform.npz``: the free-form localization tables, for a mostly curved surface (a
  mostly flat-faced one is localized as a polyhedron and needs no tables);
- ``NAME.toml``: the ``[[object]]`` entry (and its ``[[model]]`` entry when free-form), with
  the symmetry detected (or declared) and trimesh's mass properties for reference.
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mks_sim.errors import DataError, NotFound, SpecError
from mks_sim.geometry.meshes import Mesh

__all__ = [
    "COACD_PARAMS",
    "ImportReport",
    "add_object",
    "check_mesh",
    "pinch_fraction",
    "planar_fraction",
    "stable_poses",
]

log = logging.getLogger(__name__)

#: CoACD parameters (a few seconds for a part of ~20 features); written into the TOML.
COACD_PARAMS: Mapping[str, Any] = {
    "threshold": 0.1,
    "max_convex_hull": 8,
    "preprocess_mode": "auto",
    "preprocess_resolution": 30,
    "resolution": 500,
    "mcts_iterations": 30,
    "mcts_max_depth": 2,
    "mcts_nodes": 8,
    "seed": 0,
}
COACD_TIMEOUT_S = 60.0
#: The Jaco hand grasps objects of about this size (largest side, metres): outside, a warning.
HAND_RANGE_M = (0.005, 0.15)
#: Outside this the units are surely wrong: an error suggesting --units.
ABSURD_RANGE_M = (0.001, 1.0)
#: A surface with at least this fraction of its area in large planar facets is polyhedral.
PLANAR_FRACTION = 0.8


@dataclass(frozen=True)
class ImportReport:
    """What :func:`add_object` wrote and found.

    Attributes:
        toml: the written ``NAME.toml``.
        files: every file written (TOML, mesh, collision parts, tables).
        kinds: localization kinds chosen.
        symmetry: ``"none"``, ``"declared"``, ``"axial"``, ``"cube"``, ``"detected"`` ...
        n_symmetries: number of symmetry transforms.
        collision_parts: number of convex collision parts.
        extent_m: bounding-box sides (metres).
        mass_kg: from the mesh volume and density.
        warnings: problems found that did not stop the import.
    """

    toml: Path
    files: tuple[Path, ...]
    kinds: tuple[str, ...]
    symmetry: str
    n_symmetries: int
    collision_parts: int
    extent_m: tuple[float, float, float]
    mass_kg: float
    warnings: tuple[str, ...] = field(default=())


def _load_trimesh(path: Path) -> Any:
    import trimesh

    if not path.is_file():
        raise NotFound(f"mesh file not found: {path}")
    if path.suffix.lower() not in (".stl", ".obj", ".ply"):
        raise DataError(f"{path.name}: expected a .stl, .obj or .ply mesh, got {path.suffix!r}")
    try:
        tm = trimesh.load(str(path), force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types on malformed files
        raise DataError(f"{path.name}: cannot read the mesh: {exc}") from exc
    if not isinstance(tm, trimesh.Trimesh) or len(tm.faces) == 0:
        raise DataError(f"{path.name}: the file holds no triangles (empty mesh)")
    return tm


def check_mesh(tm: Any, where: str) -> tuple[Any, list[str]]:
    """Repair what is safe (degenerate faces, duplicate vertices, inside-out winding), reject
    what is not.

    Returns:
        (the mesh, warnings).

    Raises:
        DataError: empty, non-finite, zero volume, not watertight after merging duplicate
            vertices and filling small holes, or an absurd size.
    """
    import trimesh

    notes: list[str] = []
    if not np.all(np.isfinite(tm.vertices)):
        raise DataError(f"{where}: vertex coordinates contain NaN or inf")
    areas = tm.area_faces
    degenerate = int(np.sum(areas <= 1e-12 * max(float(areas.max()), 1e-30)))
    if degenerate:
        tm.update_faces(areas > 1e-12 * float(areas.max()))
        tm.remove_unreferenced_vertices()
        notes.append(f"{degenerate} degenerate (zero-area) faces removed")
    if len(tm.faces) < 4:
        raise DataError(f"{where}: degenerate mesh: {len(tm.faces)} faces cannot enclose a volume")
    if not tm.is_watertight:
        tm.merge_vertices()
        if not tm.is_watertight:
            open_edges = len(trimesh.grouping.group_rows(tm.edges_sorted, require_count=1))
            raise DataError(
                f"{where}: not watertight ({open_edges} open edges): volume, inertia and "
                "collision shape are undefined; close the mesh in a CAD tool first"
            )
        notes.append("duplicate vertices merged to make the mesh watertight")
    if tm.volume < 0:
        tm.invert()
        notes.append("faces were inside-out (negative volume): inverted")
    if not tm.volume > 0:
        raise DataError(f"{where}: degenerate mesh: zero volume (flat or collapsed)")
    extent = float(np.max(tm.extents))
    lo, hi = ABSURD_RANGE_M
    if not lo <= extent <= hi:
        raise DataError(
            f"{where}: absurd size: largest side {extent:g} m after unit conversion "
            f"(expected {lo:g}..{hi:g} m); wrong --units/--scale? (mm files: --units mm)"
        )
    lo, hi = HAND_RANGE_M
    if not lo <= extent <= hi:
        notes.append(
            f"largest side {extent * 100:.2f} cm is outside what the Jaco hand grasps "
            f"({lo * 100:g}..{hi * 100:g} cm)"
        )
    return tm, notes


def _ray_depths(v: np.ndarray, f: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(R,) distance along each ray to the nearest triangle it meets (inf: none); Moller-
    Trumbore, rays against every triangle (import time only)."""
    a = v[f[:, 0]]
    e1, e2 = v[f[:, 1]] - a, v[f[:, 2]] - a  # (F, 3)
    out = np.full(len(origins), np.inf)
    for i, (o, d) in enumerate(zip(origins, dirs, strict=True)):
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-15
        inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
        s = o - a
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        w = (q @ d) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 1e-9)
        if hit.any():
            out[i] = float(t[hit].min())
    return out


def pinch_fraction(mesh: Mesh, n: int = 300, rng: np.random.Generator | None = None) -> float:
    """Fraction of surface samples where the Jaco hand could pinch: straight through the
    object (along the inward normal) the opposite surface is a width it closes on
    (``tasks.grasp.MIN_WIDTH_M`` .. ``MAX_WIDTH_M``) and a pad-sized disc (radius
    ``PAD_HALF_WIDTH_M``) lies flat on the surface around both contacts. 0 for walls thinner
    than the pads (an L-bracket of 10 mm walls: its wide pairs end on 10 mm faces).
    """
    from scipy.spatial import cKDTree

    from mks_sim.geometry.meshes import sample_surface
    from mks_sim.tasks.grasp import MAX_WIDTH_M, MIN_WIDTH_M, PAD_HALF_WIDTH_M, PROBE_NORMAL_COS

    rng = np.random.default_rng(0) if rng is None else rng
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    pts, nrm = sample_surface(mesh, n, rng=rng)  # (n, 3) each, outward normals
    width = _ray_depths(v, f, pts - 1e-7 * nrm, -nrm)
    far = pts - width[:, None] * nrm  # the opposite contact (inf rows where no hit)
    ok = (width >= MIN_WIDTH_M) & (width <= MAX_WIDTH_M)
    dense, dense_n = sample_surface(
        mesh, int(np.clip(mesh.area / 0.0007**2, 2000, 80000)), rng=np.random.default_rng(1)
    )
    tree = cKDTree(dense)
    far_n = dense_n[tree.query(np.where(np.isfinite(far), far, 0.0))[1]]
    ang = np.arange(8) * np.pi / 4
    for end, end_n in ((pts, nrm), (far, far_n)):
        idx = np.flatnonzero(ok)
        if not len(idx):
            break
        # 8 points on the pad's rim in the contact's tangent plane; each must have the
        # surface, facing the same way, within 1.2 mm (a curved face's sag under a 13 mm
        # pad is less; a pad overhanging an edge finds the side face or nothing)
        nn = end_n[idx]
        u = np.cross(nn, np.where(np.abs(nn[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        w = np.cross(nn, u)
        rim = PAD_HALF_WIDTH_M * (
            np.cos(ang)[None, :, None] * u[:, None] + np.sin(ang)[None, :, None] * w[:, None]
        )  # (k, 8, 3)
        dist, j = tree.query((end[idx, None] + rim).reshape(-1, 3))
        cos = np.einsum("ij,ij->i", dense_n[j], np.repeat(nn, 8, axis=0))
        flat = (dist <= 0.0012) & (cos >= PROBE_NORMAL_COS)
        ok[idx] = flat.reshape(len(idx), 8).all(axis=1)
    return float(ok.mean())


def planar_fraction(mesh: Mesh, min_facet_fraction: float = 0.02) -> float:
    """Fraction of the surface area lying in planar facets of at least
    ``min_facet_fraction`` of the area each (coplanar faces grouped by plane)."""
    n = mesh.normals
    a = mesh.face_areas
    d = np.einsum("ij,ij->i", n, mesh.vertices[mesh.faces[:, 0]])
    scale = float(np.max(mesh.bounds[1] - mesh.bounds[0]))
    keys = np.column_stack([np.round(n, 3), np.round(d / scale, 3)])
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    area = np.bincount(inv.ravel(), weights=a)
    big = area >= min_facet_fraction * a.sum()
    return float(area[big].sum() / a.sum())


def stable_poses(mesh: Mesh, min_margin: float = 1e-4) -> list[tuple[np.ndarray, float]]:
    """Stable resting poses on a horizontal plane: hull facets whose support polygon holds
    the centre of mass's projection (quasi-static).

    Returns:
        ``[(T, area), ...]`` largest facet first: ``T`` (4, 4) places the object (body frame)
        on the plane z = 0 resting on that facet; ``area`` its support area (m^2).
    """
    from scipy.spatial import ConvexHull

    c = np.asarray(mesh.centroid)
    hull = ConvexHull(mesh.vertices)
    eq = hull.equations  # n . x + d = 0, n outward
    keys = np.round(eq, 6)
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    out: list[tuple[np.ndarray, float]] = []
    for k in range(inv.max() + 1):
        idx = np.flatnonzero(inv.ravel() == k)
        n = eq[idx[0], :3]
        tris = mesh.vertices[0:0]
        tris = hull.points[hull.simplices[idx]]  # (t, 3, 3)
        p = c - (np.dot(n, c) + eq[idx[0], 3]) * n  # COM projected onto the facet plane
        inside = False
        for t in tris:
            # barycentric test in the plane
            v0, v1, v2 = t[1] - t[0], t[2] - t[0], p - t[0]
            d00, d01, d11 = v0 @ v0, v0 @ v1, v1 @ v1
            d20, d21 = v2 @ v0, v2 @ v1
            den = d00 * d11 - d01 * d01
            if den <= 0:
                continue
            v = (d11 * d20 - d01 * d21) / den
            w = (d00 * d21 - d01 * d20) / den
            if v >= -min_margin and w >= -min_margin and v + w <= 1 + min_margin:
                inside = True
                break
        if not inside:
            continue
        area = float(
            0.5
            * np.linalg.norm(
                np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1
            ).sum()
        )
        R = _rotation_to(n, np.array([0.0, 0.0, -1.0]))
        T = np.eye(4)
        T[:3, :3] = R
        T[2, 3] = -float(np.min((mesh.vertices @ R.T)[:, 2]))
        out.append((T, area))
    out.sort(key=lambda x: -x[1])
    return out


def _rotation_to(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` to ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if c < -1 + 1e-9:
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def _coacd_main() -> None:
    """Child process: ``python -c '...; _coacd_main()' IN.npz OUT.npz PARAMS_JSON``."""
    import json
    import sys

    import coacd

    coacd.set_log_level("error")
    data = np.load(sys.argv[1])
    parts = coacd.run_coacd(coacd.Mesh(data["v"], data["f"]), **json.loads(sys.argv[3]))
    arrays: dict[str, Any] = {}
    for i, (pv, pf) in enumerate(parts):
        arrays[f"v{i}"], arrays[f"f{i}"] = np.asarray(pv), np.asarray(pf)
    np.savez(sys.argv[2], **arrays)


def convex_parts(
    mesh: Mesh, params: Mapping[str, Any] = COACD_PARAMS, timeout_s: float = COACD_TIMEOUT_S
) -> list[tuple[np.ndarray, np.ndarray]] | str:
    """CoACD's convex decomposition, run in a child process bounded by ``timeout_s``.

    Returns:
        The parts ``[(vertices, faces), ...]``, or a one-line reason when CoACD timed out or
        failed (the caller falls back to the convex hull).
    """
    import json
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(src, v=mesh.vertices, f=mesh.faces)
        code = "from mks_sim.models.importer import _coacd_main; _coacd_main()"
        cmd = [sys.executable, "-c", code, str(src), str(dst), json.dumps(dict(params))]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return f"CoACD did not finish within {timeout_s:g} s"
        if proc.returncode != 0 or not dst.is_file():
            last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
            return f"CoACD failed ({last})"
        data = np.load(dst)
        n = len(data.files) // 2
        return [(data[f"v{i}"], data[f"f{i}"]) for i in range(n)]


def _symmetry_toml(S: np.ndarray, name: str) -> str:
    """A TOML value for the symmetry transforms ``S`` (identity first)."""
    from scipy.spatial.transform import Rotation

    if len(S) == 1:
        return '"none"'
    if len(S) >= 360:  # continuous about an axis (maybe with flips)
        rv = Rotation.from_matrix(S[1, :3, :3]).as_rotvec()
        axis = rv / np.linalg.norm(rv)
        flip = len(S) >= 720
        ax = ", ".join(f"{x:.6f}" for x in axis)
        return f"{{ axis = [{ax}], order = 0, flip = {'true' if flip else 'false'} }}"
    rows = []
    for T in S[1:]:
        rv = Rotation.from_matrix(T[:3, :3]).as_rotvec()
        ang = float(np.linalg.norm(rv))
        axis = rv / ang
        rows.append(f"[{axis[0]:.6f}, {axis[1]:.6f}, {axis[2]:.6f}, {math.degrees(ang):.4f}]")
    del name
    return "[\n  " + ",\n  ".join(rows) + ",\n]"


def _parse_symmetry_option(value: str) -> Any:
    """``--symmetry``: none | cube | spherical | detect | AXIS:ORDER[:flip] (AXIS x, y, z or
    ax,ay,az; ORDER 0 = continuous)."""
    if value in ("none", "cube", "spherical", "detect"):
        return value
    parts = value.split(":")
    axes = {"x": [1.0, 0.0, 0.0], "y": [0.0, 1.0, 0.0], "z": [0.0, 0.0, 1.0]}
    try:
        axis = axes[parts[0]] if parts[0] in axes else [float(x) for x in parts[0].split(",")]
        order = int(parts[1])
        flip = len(parts) > 2 and parts[2] == "flip"
        if len(axis) != 3 or order < 0 or len(parts) > 3 or (len(parts) == 3 and not flip):
            raise ValueError
    except (ValueError, IndexError):
        raise SpecError(
            "--symmetry: expected none | cube | spherical | detect | AXIS:ORDER[:flip] "
            f"(e.g. z:4, z:0:flip, 0,0,1:2), got {value!r}"
        ) from None
    return {"axis": axis, "order": order, "flip": flip}


def add_object(
    mesh_path: str | Path,
    name: str,
    out_dir: str | Path,
    *,
    units: str | None = None,
    scale: float | None = None,
    density: float | None = None,
    mass: float | None = None,
    symmetry: str = "detect",
    friction: tuple[float, float, float] = (1.0, 0.01, 0.0002),
    coacd_params: Mapping[str, Any] = COACD_PARAMS,
    coacd_timeout_s: float = COACD_TIMEOUT_S,
    kind: str = "auto",
) -> ImportReport:
    """Turn a mesh file into a database object in ``out_dir`` (see the module docstring).

    Args:
        mesh_path: .stl, .obj or .ply.
        name: object name (letters, digits, _).
        out_dir: folder to write into (a ``--models`` folder).
        units: file units (``mm``, ``cm``, ``m``, ``in``); or ``scale`` (file units -> m).
            Default metres.
        density: kg/m^3 (default 600, wood); or ``mass`` (kg).
        symmetry: ``detect`` (default), ``none``, ``cube``, ``spherical`` or
            ``AXIS:ORDER[:flip]``.
        friction: MuJoCo (sliding, torsional, rolling).
        coacd_params: CoACD's parameters.
        coacd_timeout_s: bound on CoACD's time; the convex hull beyond it (with a warning).
        kind: ``auto`` (polyhedral when mostly flat faces, else freeform), ``polyhedral``
            or ``freeform``.

    Raises:
        SpecError: bad name or options.
        NotFound: the mesh file does not exist.
        DataError: an unusable mesh (empty, degenerate, not watertight, absurd size).
    """
    from mks_sim.io.mesh import write_obj
    from mks_sim.models.objects import UNITS, parse_symmetry

    mesh_path = Path(mesh_path)
    out = Path(out_dir)
    if not name or not name.replace("_", "").isalnum():
        raise SpecError(f"--name: expected letters, digits and _, got {name!r}")
    if units is not None and scale is not None:
        raise SpecError("--units and --scale: give one, not both")
    if units is not None and units not in UNITS:
        raise SpecError(f"--units: expected one of {list(UNITS)}, got {units!r}")
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        raise SpecError(f"--scale: expected a number > 0, got {scale!r}")
    if density is not None and mass is not None:
        raise SpecError("--density and --mass: give one, not both")
    for opt, v in (("--density", density), ("--mass", mass)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise SpecError(f"{opt}: expected a number > 0, got {v!r}")
    if kind not in ("auto", "polyhedral", "freeform"):
        raise SpecError(f"--kind: expected auto, polyhedral or freeform, got {kind!r}")
    from mks_sim.models.objects import load_objects

    existing = load_objects().get(name)  # the built-in folder and MKS_SIM_MODELS
    if existing is not None and existing.source != (out / f"{name}.toml").resolve():
        raise SpecError(
            f"--name: object {name!r} already exists in {existing.source}; choose another name"
        )
    sym_value = _parse_symmetry_option(symmetry)
    s = UNITS[units] if units is not None else (scale if scale is not None else 1.0)
    tm = _load_trimesh(mesh_path)
    tm.apply_scale(s)
    tm, notes = check_mesh(tm, mesh_path.name)
    tm.apply_translation(-tm.center_mass)  # body origin at the centre of mass
    mesh = Mesh(np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64))
    if pinch_fraction(mesh) == 0.0:
        from mks_sim.tasks.grasp import MIN_WIDTH_M, PAD_HALF_WIDTH_M

        notes.append(
            f"walls thinner than the pads: no two opposite faces {MIN_WIDTH_M * 1000:.0f} mm "
            f"or more apart both hold a {2 * PAD_HALF_WIDTH_M * 1000:.0f} mm pad (300 "
            "surface samples); the Jaco hand is unlikely to hold it"
        )
    for note in notes:
        warnings.warn(f"{mesh_path.name}: {note}", stacklevel=2)
    out.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    mesh_file = out / f"{name}.obj"
    write_obj(mesh_file, mesh)
    files.append(mesh_file)
    # --- collision
    coacd_used: Mapping[str, Any] | None = None
    if tm.is_convex:
        collision_value = '"mesh"'
        n_parts = 1
    else:
        parts = convex_parts(mesh, coacd_params, coacd_timeout_s)
        if isinstance(parts, str):
            note = (
                f"{parts}: the convex hull is the collision shape (raise --coacd-timeout "
                "or coarsen the mesh)"
            )
            warnings.warn(f"{mesh_path.name}: {note}", stacklevel=2)
            notes.append(note)
            collision_value = '"mesh"'
            n_parts = 1
        else:
            coacd_used = coacd_params
            names = []
            for i, (part_v, part_f) in enumerate(parts):
                f = out / f"{name}_collision_{i:02d}.obj"
                write_obj(f, Mesh(part_v, part_f))
                files.append(f)
                names.append(f'"{f.name}"')
            collision_value = "[" + ", ".join(names) + "]"
            n_parts = len(parts)
    # --- symmetry
    sym_name, S = parse_symmetry(sym_value, mesh, f"{mesh_path.name}: symmetry")
    if sym_name == "detected" and len(S) == 1:
        sym_name = "none"
    if sym_value == "detect":
        sym_toml = _symmetry_toml(S, name)
    elif isinstance(sym_value, dict):
        ax = ", ".join(f"{x:g}" for x in sym_value["axis"])
        sym_toml = (
            f"{{ axis = [{ax}], order = {sym_value['order']}, "
            f"flip = {'true' if sym_value['flip'] else 'false'} }}"
        )
    else:
        sym_toml = f'"{sym_value}"'
    # --- kinds, tables
    pf = planar_fraction(mesh)
    chosen = kind if kind != "auto" else ("polyhedral" if pf >= PLANAR_FRACTION else "freeform")
    model_block = ""
    if chosen == "freeform":
        from mks_sim.models.freeform import FreeformModel, axial_symmetries

        axial = len(S) >= 360
        fm = FreeformModel.from_mesh(
            mesh, f"{name}_freeform", None, axial_symmetries() if axial else None
        )
        tables = out / f"{name}_freeform.npz"
        fm.save(tables)
        files.append(tables)
        model_block = (
            "\n# The free-form localization model (tables built by `mks-sim objects add`).\n"
            f'[[model]]\nname = "{name}_freeform"\nkind = "freeform"\n'
            f'mesh = "{mesh_file.name}"\ntables = "{tables.name}"\n'
            f'symmetry = "{"axial" if axial else "none"}"\n'
        )
    kinds = [chosen]
    # --- physics and the TOML
    rho = density if density is not None else (mass / tm.volume if mass is not None else 600.0)
    tm.density = rho
    inertia = np.asarray(tm.moment_inertia)
    mass_kg = float(tm.mass)
    phys = f"density = {rho:g}" if mass is None else f"mass = {mass:g}"
    ext = tuple(float(x) for x in tm.extents)
    lines = [
        f"# {name}: added by `mks-sim objects add {mesh_path.name}` "
        f"({'units ' + units if units else f'scale {s:g}'}; body origin at the centre of mass).",
        f"# Size {ext[0] * 1000:.1f} x {ext[1] * 1000:.1f} x {ext[2] * 1000:.1f} mm; "
        f"planar fraction {pf:.2f}; mass {mass_kg * 1000:.1f} g.",
    ]
    lines += [f"# warning: {n}" for n in notes]
    lines += [
        "[[object]]",
        f'name = "{name}"',
        f'description = "added from {mesh_path.name}"',
        f'mesh = "{mesh_file.name}"',
        'units = "m"',
        f"symmetry = {sym_toml}",
        f"kinds = {kinds!r}".replace("'", '"'),
    ]
    if chosen == "freeform":
        lines.append(f'models = {{ freeform = "{name}_freeform" }}')
    lines += [
        phys,
        f"friction = [{friction[0]:g}, {friction[1]:g}, {friction[2]:g}]",
        "condim = 4",
        f"collision = {collision_value}",
        "rgb = [0.55, 0.58, 0.62]",
        "dots = [0.15, 0.15, 0.18]",
    ]
    if coacd_used is not None:
        kv = ", ".join(
            f'{k} = "{v}"' if isinstance(v, str) else f"{k} = {v!r}" for k, v in coacd_used.items()
        )
        lines.append(f'decomposition = {{ method = "coacd", {kv} }}')
    diag = ", ".join(f"{x:.6g}" for x in np.diag(inertia))
    lines.append(f"# trimesh mass properties: {mass_kg:.6g} kg, inertia diagonal [{diag}] kg m^2")
    toml_file = out / f"{name}.toml"
    toml_file.write_text("\n".join(lines) + "\n" + model_block, encoding="utf-8")
    files.insert(0, toml_file)
    return ImportReport(
        toml=toml_file,
        files=tuple(files),
        kinds=tuple(kinds),
        symmetry=sym_name,
        n_symmetries=len(S),
        collision_parts=n_parts,
        extent_m=ext,  # type: ignore[arg-type]
        mass_kg=mass_kg,
        warnings=tuple(notes),
    )
