"""`mks-sim scene`: scenes as data — list them, export one as MJCF.

Examples::

    mks-sim scene list
    mks-sim scene export scene2 --out /tmp/scene2/scene2.xml
    python -m mujoco.viewer --mjcf=/tmp/scene2/scene2.xml

A scene is ``worlds/<name>.toml`` or any scene file (schema in ``docs/worlds.md``);
``--object NAME`` without a scene exports the default scene (the object alone on the table).
The XML inlines the object meshes and their convex collision parts; the Jaco's mesh files are
written beside it.
"""

from __future__ import annotations

import argparse
import json

from mks_sim.cli import output_file
from mks_sim.errors import SpecError

HELP = "scenes (worlds/*.toml): list them, export one as MJCF for MuJoCo's viewer"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    lst = sub.add_parser("list", help="the shipped scenes and their objects")
    lst.add_argument("--json", action="store_true", help="print JSON")
    exp = sub.add_parser("export", help="write a scene as MJCF (+ mesh files beside it)")
    exp.add_argument("scene", nargs="?", default=None, help="scene name or scene file")
    exp.add_argument("--object", action="append", default=[], metavar="NAME",
                     help="without a scene: the default scene of these objects (repeatable)")  # fmt: skip
    exp.add_argument(
        "--models", action="append", default=[], metavar="DIR",
        help="extra model-database folder (repeatable; also MKS_SIM_MODELS)",
    )  # fmt: skip
    exp.add_argument("--out", required=True, help="the MJCF file to write (.xml)")


def run(args: argparse.Namespace) -> int:
    from mks_sim.sim import scenes

    if args.action == "list":
        rows = [{"name": n, "objects": scenes.scene_objects(n)} for n in scenes.scene_names()]
        if args.json:
            print(json.dumps(rows))
        else:
            for r in rows:
                print(f"{r['name']:<10} {', '.join(r['objects']) or '(no database objects)'}")
        return 0
    out = output_file(args.out, "--out", (".xml",))
    if args.scene is None and not args.object:
        raise SpecError("scene export: expected a scene name/file or --object NAME, got neither")
    if args.scene is not None:
        spec = scenes.build_scene(args.scene, models=args.models)
    else:
        spec = scenes.default_scene(args.object, models=args.models)
    from dm_control import mjcf

    mjcf.export_with_assets(spec.root, str(out.absolute().parent), out_file_name=out.name)
    print(f"wrote {out} (scene {spec.name})")
    return 0
