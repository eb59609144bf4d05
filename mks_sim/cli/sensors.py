"""`mks-sim sensors`: list the logical sensors, or check one sensor file.

``mks-sim sensors`` lists every logical sensor of the installed ``sensors/`` folder (or
``--dir``) with its inputs, program, characteristic output vector and ordered alternates, and
the declared devices; ``--json`` prints the same as JSON. ``mks-sim sensors --check FILE``
loads FILE together with the installed devices and sensors (so that its inputs resolve; an
installed file with the same file name is replaced by FILE) and prints ``ok`` (exit 0) or the
error naming file, sensor and field (exit 2).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from mks_sim.errors import MksError
from mks_sim.resources import data_dir
from mks_sim.sensing import SensorGraph, SensorSpec, load_file, program_names

HELP = "list the logical sensors (inputs, program, output vector, alternates) or check a file"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "names", nargs="*", metavar="SENSOR", help="show only these sensors (default: all)"
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of text")
    parser.add_argument(
        "--check",
        metavar="FILE",
        type=Path,
        help="validate one sensor file against the installed devices and sensors",
    )
    parser.add_argument(
        "--programs",
        action="store_true",
        help="list the programs and acceptance tests with the params each accepts",
    )
    parser.add_argument(
        "--models",
        metavar="DIR",
        action="append",
        default=[],
        help="also check that the model files of DIR (with the built-in ones and "
        "MKS_SIM_MODELS; always with --check) name only existing logical sensors",
    )
    parser.add_argument(
        "--dir",
        metavar="DIR",
        type=Path,
        default=None,
        help="sensors folder (default: the installed sensors/)",
    )


def _params(params: Any) -> str:
    if not params:
        return ""
    return " {" + ", ".join(f"{k} = {_plain(v)!r}" for k, v in params.items()) + "}"


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if hasattr(value, "items"):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _format_sensor(spec: SensorSpec) -> list[str]:
    lines = [f"{spec.name}  ({spec.file or 'code'})"]
    if spec.description:
        lines.append(f"  {spec.description}")
    lines.append(f"  inputs:     {', '.join(spec.inputs) or '(none)'}")
    lines.append(f"  program:    {spec.program}{_params(spec.params)}")
    lines.append("  output:")
    rows = [
        (
            f"[{i}]",
            f.name,
            f"{f.low:g}:{f.high:g}",
            f.unit or "-",
            f.policy,
            "" if f.resolution is None else f"step {f.resolution:g}",
        )
        for i, f in enumerate(spec.output)
    ]
    widths = [max(len(r[c]) for r in rows) for c in range(6)]
    for row in rows:
        lines.append("    " + "  ".join(v.ljust(w) for v, w in zip(row, widths)).rstrip())
    if spec.acceptance is not None:
        acc = spec.acceptance
        lines.append(f"  acceptance: {acc.test}{_params(acc.params)}")
    if spec.alternates:
        lines.append("  alternates (in order):")
        for k, alt in enumerate(spec.alternates, start=1):
            acc_text = ""
            if alt.acceptance is not None:
                acc_text = f"; acceptance {alt.acceptance.test}{_params(alt.acceptance.params)}"
            lines.append(
                f"    {k}. {alt.name}: {', '.join(alt.inputs)} -> "
                f"{alt.program}{_params(alt.params)}{acc_text}"
            )
    return lines


def _list(args: argparse.Namespace) -> int:
    graph = SensorGraph.from_dir(args.dir)
    specs = [graph.sensor(n) for n in args.names] if args.names else list(graph)
    if args.json:
        doc = {
            "sensors": [s.to_dict() for s in specs],
            "devices": [d.to_dict() for d in graph.devices.values()],
            "programs": program_names(),
        }
        print(json.dumps(doc, indent=2))
        return 0
    blocks = ["\n".join(_format_sensor(s)) for s in specs]
    if not specs:
        blocks.append("no logical sensors defined")
    devices = ", ".join(
        f"{d.name} ({d.kind})" if d.kind else d.name for d in graph.devices.values()
    )
    blocks.append(f"devices: {devices or '(none)'}")
    print("\n\n".join(blocks))
    return 0


def _check(args: argparse.Namespace) -> int:
    target: Path = args.check
    folder = data_dir("sensors") if args.dir is None else args.dir
    try:
        loaded = load_file(target)  # its own errors first, with its own name
        others = [
            p
            for p in sorted(folder.glob("*.toml"))
            if p.name != target.name and p.resolve() != target.resolve()
        ]
        graph = SensorGraph.from_files([*others, target])
        # the model database is checked against the installed sensors (or with --models)
        n_refs = _check_models(graph, args.models) if args.dir is None or args.models else None
    except MksError as exc:
        if args.json:
            print(json.dumps({"ok": False, "file": str(target), "error": str(exc)}))
            return 2
        raise
    names = [s.name for s in loaded.sensors]
    if args.json:
        print(
            json.dumps(
                {
                    "ok": True,
                    "file": str(target),
                    "sensors": names,
                    "devices": [d.name for d in loaded.devices],
                    "graph_sensors": len(graph),
                }
            )
        )
        return 0
    print(
        f"ok: {target}: {len(names)} sensor(s)"
        + (f" ({', '.join(names)})" if names else "")
        + f", {len(loaded.devices)} device(s); checked with {len(graph)} sensor(s) and "
        f"{len(graph.device_names)} device(s) from {folder}"
        + ("" if n_refs is None else f"; {n_refs} model sensor reference(s) ok")
    )
    return 0


def _check_models(graph: SensorGraph, extra: list[Path] | list[str]) -> int:
    """Check the model files (built-in, ``--models``, ``MKS_SIM_MODELS``) against ``graph``."""
    from mks_sim.models.objects import models_dirs

    files = [f for folder in models_dirs(extra) for f in sorted(folder.glob("*.toml"))]
    return graph.check_model_files(files)


def program_params() -> dict[str, dict[str, dict[str, Any]]]:
    """Every program and acceptance test -> its params schema (``{}``: takes none; None: not
    declared, so not checked)."""
    from mks_sim.sensing.registry import ACCEPTANCE, PROGRAMS, params_type
    from mks_sim.specs import params_schema

    out: dict[str, Any] = {}
    for kind, table in (("program", PROGRAMS), ("acceptance", ACCEPTANCE)):
        for name in table.names():
            cls = params_type(table.get(name))
            out[f"{kind} {name}"] = None if cls is None else params_schema(cls)
    return out


def _limits(info: dict[str, Any]) -> str:
    parts = []
    if "low" in info:
        parts.append(f"{'>' if info.get('low_open') else '>='} {info['low']:g}")
    if "high" in info:
        parts.append(f"<= {info['high']:g}")
    for key, value in info.items():
        if key not in ("type", "default", "required", "low", "high", "low_open"):
            parts.append(f"{key} {value!r}")
    return ", ".join(parts)


def _programs(args: argparse.Namespace) -> int:
    schema = program_params()
    if args.json:
        print(json.dumps(schema, indent=2))
        return 0
    lines: list[str] = []
    for name, fields in schema.items():
        if fields is None:
            lines.append(f"{name}: params not declared (not checked)")
            continue
        lines.append(f"{name}:" + ("" if fields else " no params"))
        for field, info in fields.items():
            default = "required" if info.get("required") else f"default {info['default']!r}"
            limits = _limits(info)
            lines.append(
                f"  {field}: {info['type']}, {default}" + (f", {limits}" if limits else "")
            )
    print("\n".join(lines))
    return 0


def run(args: argparse.Namespace) -> int:
    if args.programs:
        return _programs(args)
    if args.check is not None:
        return _check(args)
    if args.models:
        _check_models(SensorGraph.from_dir(args.dir), args.models)
    return _list(args)
