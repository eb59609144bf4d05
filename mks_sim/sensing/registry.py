"""Logical-sensor programs and acceptance tests, looked up by name (never eval).

A sensor file names its program (``program = "range_points"``). :data:`PROGRAMS` and
:data:`ACCEPTANCE` are :class:`~mks_sim.registry.Registry` tables ``name ->
"module:callable"``: the whole registration is the table below, nothing is registered by
importing a module, and a program module is imported the first time one of its names is used.

A program declares its ``params`` as a frozen dataclass with :func:`takes_params`; the sensor
graph validates every sensor's TOML ``params`` against it when the files are loaded (unknown
keys, wrong types and constraints such as ``m >= 1`` are errors at ``mks-sim sensors
--check``). Programs are still called ``program(inputs, params)`` with the validated,
read-only mapping (only the keys the file gave); :func:`params_of` turns it into the
dataclass instance for programs that want attributes and defaults.

Programs and tests built in code (tests, plugins) are added with :func:`register_program` /
:func:`register_acceptance`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np

from mks_sim.errors import SpecError
from mks_sim.fields import Stream
from mks_sim.registry import Registry
from mks_sim.specs import Where, parse_dataclass

__all__ = [
    "ACCEPTANCE",
    "PROGRAMS",
    "AcceptanceTest",
    "Program",
    "acceptance_names",
    "get_acceptance",
    "get_program",
    "params_of",
    "params_type",
    "program_names",
    "register_acceptance",
    "register_program",
    "takes_params",
]

#: ``program(inputs, params) -> (N, n) array | Stream``; ``inputs`` maps each name of the
#: sensor's ``inputs`` list to a device reading (a device) or a :class:`Stream` (a sensor).
Program = Callable[[Mapping[str, Any], Mapping[str, Any]], "np.ndarray | Stream"]
#: ``test(stream, params) -> reason to reject | None``.
AcceptanceTest = Callable[[Stream, Mapping[str, Any]], "str | None"]

_KERNEL = "mks_sim.sensing.programs.kernel"
_VISION = "mks_sim.sensing.programs.vision"
_POINTS = "mks_sim.sensing.programs.points"
_VIEWS = "mks_sim.sensing.programs.views"

#: Every built-in program: name -> "module:callable".
PROGRAMS: Registry[Program] = Registry(
    "program",
    {
        "passthrough": f"{_KERNEL}:passthrough",
        "select_fields": f"{_KERNEL}:select_fields",
        "concat": f"{_KERNEL}:concat",
        "merge": f"{_KERNEL}:merge",
        "constant": f"{_KERNEL}:constant",
        "circle_detector": f"{_VISION}:circle_detector",
        "corner_holes_detector": f"{_VISION}:corner_holes_detector",
        "range_points": f"{_POINTS}:range_points",
        "stereo_points": f"{_POINTS}:stereo_points",
        "depth_points": f"{_POINTS}:depth_points",
        "surface_curvature": f"{_POINTS}:surface_curvature",
        "vertex_detector": f"{_POINTS}:vertex_detector",
        "control_point_detector": f"{_POINTS}:control_point_detector",
        "sphere_detector": f"{_POINTS}:sphere_detector",
        "touch_contacts": f"{_POINTS}:touch_contacts",
        "fuse_views": f"{_VIEWS}:fuse_views",
    },
)

#: Every built-in acceptance test: name -> "module:callable".
ACCEPTANCE: Registry[AcceptanceTest] = Registry(
    "acceptance test",
    {
        name: f"{_KERNEL}:{name}"
        for name in (
            "min_rows",
            "max_rows",
            "max_nan_fraction",
            "max_flagged_fraction",
            "max_dropped_fraction",
        )
    },
)

F = TypeVar("F", bound=Callable[..., Any])
D = TypeVar("D")

_PARAMS_ATTR = "params_type"


def takes_params(cls: type) -> Callable[[F], F]:
    """Decorator: declare the frozen dataclass a program's (or test's) ``params`` must fit.

    Only sets an attribute on the function; registration is the table above.
    """

    def decorator(func: F) -> F:
        setattr(func, _PARAMS_ATTR, cls)
        return func

    return decorator


def params_type(func: Callable[..., Any]) -> type | None:
    """The params dataclass declared by :func:`takes_params`, or None (params not checked)."""
    cls = getattr(func, _PARAMS_ATTR, None)
    return cls if isinstance(cls, type) else None


def params_of(cls: type[D], params: Mapping[str, Any] | D, program: str) -> D:
    """``params`` as the dataclass ``cls`` (validated when given as a mapping).

    Raises:
        SpecError: ``program 'name': field 'params.x': expected ..., got ...``.
    """
    if isinstance(params, cls):
        return params
    return parse_dataclass(cls, params, Where(None, "program", program))


def _register(registry: Registry[Any], name: str, params: type | None) -> Callable[[F], F]:
    if not isinstance(name, str) or not name:
        raise SpecError(f"register {registry.kind}: expected a non-empty name, got {name!r}")

    def decorator(func: F) -> F:
        if params is not None:
            setattr(func, _PARAMS_ATTR, params)
        registry.add(name, func)
        return func

    return decorator


def register_program(name: str, params: type | None = None) -> Callable[[F], F]:
    """Decorator: add a program built in code under ``name`` (optionally with its params
    dataclass). Built-in programs are listed in :data:`PROGRAMS` instead.

    The program is called ``program(inputs, params)`` and returns an (N, n) float array in
    output-vector order, or a :class:`~mks_sim.fields.Stream`; it raises
    :class:`~mks_sim.errors.SensorFailure` when it cannot produce output.

    Raises:
        SpecError: another callable is already registered under ``name``.
    """
    return _register(PROGRAMS, name, params)


def register_acceptance(name: str, params: type | None = None) -> Callable[[F], F]:
    """Decorator: add an acceptance test ``test(stream, params) -> str | None`` built in code.

    The test returns the reason to reject the stream, or None to accept it.
    """
    return _register(ACCEPTANCE, name, params)


def program_names() -> list[str]:
    """Every program name, sorted (nothing is imported)."""
    return PROGRAMS.names()


def acceptance_names() -> list[str]:
    """Every acceptance-test name, sorted (nothing is imported)."""
    return ACCEPTANCE.names()


def get_program(name: str) -> Program:
    """The program named ``name`` (its module is imported on first use).

    Raises:
        NotFound: no such program (the message lists the known ones).
    """
    return PROGRAMS.get(name)


def get_acceptance(name: str) -> AcceptanceTest:
    """The acceptance test named ``name``.

    Raises:
        NotFound: no such test (the message lists the known ones).
    """
    return ACCEPTANCE.get(name)
