"""`mks-sim objects`: the objects of the model database — add a mesh, list, show.

Examples::

    mks-sim objects add bracket.stl --name bracket --units mm --out my_models/
    mks-sim objects list --models my_models/
    mks-sim objects show bracket --models my_models/ --out pictures/

``add`` writes ``DIR/NAME.toml`` and its assets (``mks_sim.models.importer``): the mesh in
metres with the body origin at the centre of mass, convex collision parts (CoACD; the convex
hull for a convex mesh), the detected (or declared) symmetry, and the free-form localization
tables for a mostly curved surface. ``show`` draws the mesh, its vertexes (or free-form
keypoints), its stable resting poses and, when grasp synthesis is available, grasp candidates.
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from mks_sim.cli import finite_float, output_dir

HELP = "model-database objects: add a mesh file (STL/OBJ/PLY), list them, show one as a picture"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    add = sub.add_parser("add", help="add a mesh file as an object (writes DIR/NAME.toml + assets)")
    add.add_argument("mesh", help="mesh file: .stl, .obj or .ply")
    add.add_argument("--name", required=True, help="object name (letters, digits, _)")
    units = add.add_mutually_exclusive_group()
    units.add_argument("--units", choices=("mm", "cm", "m", "in"), help="units of the file")
    units.add_argument("--scale", type=finite_float, help="file units -> metres factor")
    phys = add.add_mutually_exclusive_group()
    phys.add_argument("--density", type=finite_float, help="kg/m^3 (default 600, wood)")
    phys.add_argument("--mass", type=finite_float, help="kg")
    add.add_argument(
        "--symmetry", default="detect",
        help="detect (default) | none | cube | spherical | AXIS:ORDER[:flip] (e.g. z:4, z:0:flip)",
    )  # fmt: skip
    add.add_argument(
        "--kind", default="auto", choices=("auto", "polyhedral", "freeform"),
        help="localization kind (auto: polyhedral when mostly flat faces)",
    )  # fmt: skip
    add.add_argument(
        "--coacd-timeout", type=finite_float, default=60.0,
        help="seconds CoACD may take (then the convex hull)",
    )  # fmt: skip
    add.add_argument("--out", default=".", help="model folder to write into (default: .)")
    add.add_argument("--json", action="store_true", help="print one JSON object")
    lst = sub.add_parser("list", help="list the objects (name, kinds, source)")
    _models(lst)
    lst.add_argument("--json", action="store_true", help="print JSON")
    show = sub.add_parser("show", help="a picture of one object (mesh, vertexes, resting poses)")
    show.add_argument("name", help="object name")
    _models(show)
    show.add_argument("--out", default=".", help="folder for NAME.png (default: .)")


def _models(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--models", action="append", default=[], metavar="DIR",
        help="extra model-database folder (repeatable; also MKS_SIM_MODELS)",
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    return {"add": _add, "list": _list, "show": _show}[args.action](args)


def _add(args: argparse.Namespace) -> int:
    from mks_sim.models.importer import add_object

    out = output_dir(args.out)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rep = add_object(
            args.mesh, args.name, out, units=args.units, scale=args.scale,
            density=args.density, mass=args.mass, symmetry=args.symmetry,
            coacd_timeout_s=args.coacd_timeout, kind=args.kind,
        )  # fmt: skip
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    record: dict[str, Any] = {
        "name": args.name,
        "toml": str(rep.toml),
        "files": [str(f) for f in rep.files],
        "kinds": list(rep.kinds),
        "symmetry": rep.symmetry,
        "symmetries": rep.n_symmetries,
        "collision_parts": rep.collision_parts,
        "extent_m": [round(x, 6) for x in rep.extent_m],
        "mass_kg": round(rep.mass_kg, 6),
        "warnings": list(rep.warnings),
    }
    if args.json:
        print(json.dumps(record))
    else:
        ext = " x ".join(f"{x * 1000:.1f}" for x in rep.extent_m)
        print(f"added {args.name}: {ext} mm, {rep.mass_kg * 1000:.1f} g, kinds {list(rep.kinds)}")
        print(f"symmetry: {rep.symmetry} ({rep.n_symmetries} transforms)")
        print(f"collision: {rep.collision_parts} convex part(s)")
        print(f"wrote: {', '.join(f.name for f in rep.files)} in {out}")
        print(f"use it: mks-sim localize --object {args.name} --models {out}")
    return 0


def _list(args: argparse.Namespace) -> int:
    from mks_sim.models.objects import load_objects

    objs = load_objects(args.models)
    rows = [
        {"name": o.name, "kinds": list(o.kinds), "source": str(o.source)}
        for o in sorted(objs.values(), key=lambda o: o.name)
    ]
    if args.json:
        print(json.dumps(rows))
    else:
        width = max(len(r["name"]) for r in rows)
        for r in rows:
            print(f"{r['name']:<{width}}  {','.join(r['kinds']):<28}  {r['source']}")
    return 0


def _show(args: argparse.Namespace) -> int:
    from mks_sim.models.objects import load_object

    obj = load_object(args.name, models=args.models)
    out = output_dir(args.out)
    path = out / f"{obj.name}.png"
    draw_object(obj, path)
    print(f"wrote {path}")
    return 0


def draw_object(obj: Any, path: Path) -> None:
    """PNG of ``obj``: the mesh with its vertexes or keypoints, its stable resting poses and,
    when ``mks_sim.tasks.grasp.synthesize_grasps`` exists, grasp candidates."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from mks_sim.models.importer import stable_poses

    mesh = obj.mesh
    poses = stable_poses(mesh)[:4]
    n = 1 + len(poses)
    fig = plt.figure(figsize=(3.2 * n, 3.6))

    def draw(ax: Any, V: np.ndarray, title: str) -> None:
        ax.add_collection3d(
            Poly3DCollection(V[mesh.faces], facecolor=(*obj.rgb, 0.35), edgecolor=(0, 0, 0, 0.1), lw=0.2)
        )
        lo, hi = V.min(axis=0), V.max(axis=0)
        c, r = (lo + hi) / 2, float(np.max(hi - lo)) / 2
        ax.set_xlim(c[0] - r, c[0] + r)
        ax.set_ylim(c[1] - r, c[1] + r)
        ax.set_zlim(c[2] - r, c[2] + r)
        ax.set_title(title, fontsize=8)
        ax.tick_params(labelsize=5)

    ax = fig.add_subplot(1, n, 1, projection="3d")
    draw(ax, mesh.vertices, f"{obj.name}: {', '.join(obj.kinds)}; {obj.symmetry} symmetry")
    pts, label = _feature_points(obj)
    ax.scatter(*pts.T, s=6, c="crimson", depthshade=False, label=label)
    grasps = _grasp_points(obj)
    if grasps is not None:
        for k, (a, b) in enumerate(grasps):
            ax.plot(
                *np.stack([a, b]).T, c="green", lw=0.8, label="grasp contacts" if k == 0 else None
            )
            ax.scatter(*np.stack([a, b]).T, s=10, c="green", depthshade=False)
    ax.legend(fontsize=6, loc="upper left")
    for i, (T, area) in enumerate(poses):
        V = mesh.vertices @ T[:3, :3].T + T[:3, 3]
        axp = fig.add_subplot(1, n, i + 2, projection="3d")
        draw(axp, V, f"resting pose {i + 1}: support {area * 1e4:.1f} cm^2")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _feature_points(obj: Any) -> tuple[np.ndarray, str]:
    if "freeform" in obj.models:
        try:
            model = obj.model("freeform")
            kp = getattr(model, "keypoints", None)
            if kp is not None:
                return np.asarray(kp, float).reshape(-1, 3), "free-form keypoints"
        except Exception:  # noqa: BLE001 - a picture without keypoints is still useful
            pass
    from scipy.spatial import ConvexHull

    v = obj.mesh.vertices
    if len(v) > 400:
        return v[ConvexHull(v).vertices], "hull vertexes"
    return v, "vertexes"


def _grasp_points(obj: Any) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Contact pairs of synthesised grasps at the object's first resting pose, body frame."""
    try:
        from mks_sim.tasks.grasp import synthesize_grasps
    except ImportError:
        return None
    try:
        from mks_sim.models.importer import stable_poses

        T = stable_poses(obj.mesh)[0][0]
        cands = synthesize_grasps(obj, T, table_z=0.0, obstacles=None, rng=np.random.default_rng(0))
    except Exception:  # noqa: BLE001 - the grasp room's API may still change
        return None
    out = []
    Tinv = np.linalg.inv(T)
    for c in cands[:12]:
        pair = getattr(c, "contacts_world", None)
        if pair is None:
            continue
        a, b = (Tinv[:3, :3] @ np.asarray(p) + Tinv[:3, 3] for p in pair)
        out.append((a, b))
    return out or None
