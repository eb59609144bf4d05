"""Registry of logical-sensor programs and acceptance tests, looked up by name (never eval).

A sensor file names its program (``program = "range_points"``); the program is a Python
callable registered under that name with :func:`register_program`. Program modules are imported
lazily, the first time a name is looked up, from :data:`PROGRAM_MODULES`.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np

from mks_sim.errors import NotFound, SpecError
from mks_sim.fields import Stream

__all__ = [
    "PROGRAM_MODULES",
    "AcceptanceTest",
    "Program",
    "acceptance_names",
    "get_acceptance",
    "get_program",
    "load_program_modules",
    "program_names",
    "register_acceptance",
    "register_program",
]

log = logging.getLogger(__name__)

#: Modules holding registered programs, imported on first lookup. A listed module that does
#: not exist (yet) is skipped; any other import error propagates.
PROGRAM_MODULES: tuple[str, ...] = (
    "mks_sim.sensing.programs.kernel",
    "mks_sim.sensing.programs.vision",
    "mks_sim.sensing.programs.points",
)

#: ``program(inputs, params) -> (N, n) array | Stream``; ``inputs`` maps each name of the
#: sensor's ``inputs`` list to a device reading (a device) or a :class:`Stream` (a sensor).
Program = Callable[[Mapping[str, Any], Mapping[str, Any]], "np.ndarray | Stream"]
#: ``test(stream, params) -> reason to reject | None``.
AcceptanceTest = Callable[[Stream, Mapping[str, Any]], "str | None"]

_PROGRAMS: dict[str, Program] = {}
_ACCEPTANCE: dict[str, AcceptanceTest] = {}
_loaded = False

F = TypeVar("F", bound=Callable[..., Any])


def _register(table: dict[str, Any], kind: str, name: str) -> Callable[[F], F]:
    if not isinstance(name, str) or not name:
        raise SpecError(f"register_{kind}: expected a non-empty name, got {name!r}")

    def decorator(func: F) -> F:
        old = table.get(name)
        if old is not None and (old.__module__, old.__qualname__) != (
            func.__module__,
            func.__qualname__,
        ):
            raise SpecError(
                f"{kind} {name!r} is registered twice: {old.__module__}.{old.__qualname__} "
                f"and {func.__module__}.{func.__qualname__}"
            )
        table[name] = func
        return func

    return decorator


def register_program(name: str) -> Callable[[F], F]:
    """Decorator: register a logical-sensor program under ``name``.

    The program is called ``program(inputs, params)`` and returns an (N, n) float array in
    output-vector order, or a :class:`~mks_sim.fields.Stream`; it raises
    :class:`~mks_sim.errors.SensorFailure` when it cannot produce output.

    Raises:
        SpecError: another callable is already registered under ``name``.
    """
    return _register(_PROGRAMS, "program", name)


def register_acceptance(name: str) -> Callable[[F], F]:
    """Decorator: register an acceptance test ``test(stream, params) -> str | None``.

    The test returns the reason to reject the stream, or None to accept it.
    """
    return _register(_ACCEPTANCE, "acceptance", name)


def load_program_modules() -> None:
    """Import every module of :data:`PROGRAM_MODULES` (once); skip those that do not exist."""
    global _loaded
    if _loaded:
        return
    for module in PROGRAM_MODULES:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            log.debug("program module %s does not exist; skipped", module)
    _loaded = True


def program_names() -> list[str]:
    """Every registered program name, sorted."""
    load_program_modules()
    return sorted(_PROGRAMS)


def acceptance_names() -> list[str]:
    """Every registered acceptance-test name, sorted."""
    load_program_modules()
    return sorted(_ACCEPTANCE)


def get_program(name: str) -> Program:
    """The program registered as ``name``.

    Raises:
        NotFound: no such program (the message lists the known ones).
    """
    load_program_modules()
    try:
        return _PROGRAMS[name]
    except KeyError:
        raise NotFound(
            f"unknown program {name!r}; registered programs: {sorted(_PROGRAMS)}"
        ) from None


def get_acceptance(name: str) -> AcceptanceTest:
    """The acceptance test registered as ``name``.

    Raises:
        NotFound: no such test (the message lists the known ones).
    """
    load_program_modules()
    try:
        return _ACCEPTANCE[name]
    except KeyError:
        raise NotFound(
            f"unknown acceptance test {name!r}; registered tests: {sorted(_ACCEPTANCE)}"
        ) from None
