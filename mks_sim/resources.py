"""Where the data folders (``worlds/``, ``sensors/``, ``tasks/``) are.

In a checkout (and an editable install) they sit beside the package; in a wheel they are
package data under ``mks_sim/_data/``. ``MKS_SIM_DATA`` overrides both (a folder holding
``worlds/``, ``sensors/`` and ``tasks/``).
"""

from __future__ import annotations

import os
from pathlib import Path

from mks_sim.errors import NotFound

DATA_FOLDERS = ("worlds", "sensors", "tasks")
_PACKAGE_DIR = Path(__file__).resolve().parent


def data_dir(name: str) -> Path:
    """Return the folder ``name`` (one of ``worlds``, ``sensors``, ``tasks``).

    Raises:
        NotFound: the name is not a data folder, or the folder is missing from the install.
    """
    if name not in DATA_FOLDERS:
        raise NotFound(f"unknown data folder {name!r}; expected one of {DATA_FOLDERS}")
    candidates = []
    if override := os.environ.get("MKS_SIM_DATA"):
        candidates.append(Path(override) / name)
    candidates += [_PACKAGE_DIR / "_data" / name, _PACKAGE_DIR.parent / name]
    for path in candidates:
        if path.is_dir():
            return path
    raise NotFound(
        f"data folder {name!r} not found (looked in {', '.join(map(str, candidates))}); "
        "reinstall mks-sim or set MKS_SIM_DATA"
    )
