"""`mks-sim paper`: the paper's case studies recomputed beside the paper's printed numbers.

Sections come from the modules named in :data:`SECTIONS`; each exposes
``report() -> (text: str, json: dict)``. The text sections are printed one after the other;
``--json`` prints one JSON object, the union of the sections' dicts (keys must not collide).
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from typing import Any

from mks_sim.errors import MksError

HELP = "recompute the paper's case-study tables and print them beside the paper's"

# Modules with report() -> (text, dict); other rooms append theirs.
SECTIONS: tuple[str, ...] = ("mks_sim.paper.tables", "mks_sim.paper.hough_cases")


def section_names() -> dict[str, str]:
    """The fixed ``--section`` choices: short name (``tables``) -> module (the full module
    name of :data:`SECTIONS` is accepted too); nothing else is ever imported."""
    names = {module.rsplit(".", 1)[-1]: module for module in SECTIONS}
    names.update({module: module for module in SECTIONS})
    return names


def _section(text: str) -> str:
    names = section_names()
    if text not in names:
        short = [n for n in names if "." not in n]
        raise argparse.ArgumentTypeError(f"expected one of {short}, got {text!r}")
    return names[text]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    short = [n for n in section_names() if "." not in n]
    parser.add_argument(
        "--section",
        action="append",
        type=_section,
        metavar="NAME",
        help=f"only these sections (repeatable; one of {', '.join(short)}; default: all)",
    )


def assemble(sections: tuple[str, ...] | list[str] = SECTIONS) -> tuple[str, dict[str, Any]]:
    """Run every section's ``report()``; return the joined text and the merged dict."""
    texts: list[str] = []
    merged: dict[str, Any] = {}
    for name in sections:
        try:
            module = importlib.import_module(name)
        except ImportError as exc:
            raise MksError(f"paper section {name!r} cannot be imported: {exc}") from exc
        report = getattr(module, "report", None)
        if not callable(report):
            raise MksError(f"paper section {name!r} has no report() -> (text, dict)")
        text, data = report()
        clash = sorted(set(merged) & set(data))
        if clash:
            raise MksError(f"paper section {name!r} repeats JSON key(s) {clash}")
        texts.append(text.rstrip())
        merged.update(data)
    return "\n\n".join(texts), merged


def run(args: argparse.Namespace) -> int:
    sections = tuple(args.section) if args.section else SECTIONS
    text, data = assemble(sections)
    if args.json:
        json.dump(data, sys.stdout, indent=2, sort_keys=False)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(text + "\n")
    return 0
