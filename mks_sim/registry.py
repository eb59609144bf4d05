"""One registry type: a name maps to a ``"module:callable"`` string, resolved on first use.

Like Gymnasium's ``entry_point``: a table of strings is the whole registration, so nothing is
registered as a side effect of importing a module, modules are imported only when one of their
names is asked for, and there is no import circle between a registry and its entries.

Example::

    PROGRAMS = Registry("program", {"passthrough": "mks_sim.sensing.programs.kernel:passthrough"})
    PROGRAMS.get("passthrough")        # imports the module once, returns the callable
    PROGRAMS.get("nope")               # NotFound: unknown program 'nope'; known programs: [...]

Objects built in code (tests, plugins) may be added directly with :meth:`Registry.add`.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Iterator, Mapping
from typing import Any, Generic, TypeVar

from mks_sim.errors import NotFound, SpecError

__all__ = ["Registry", "resolve_entry_point"]

T = TypeVar("T")

_ENTRY = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_][\w.]*$")


def resolve_entry_point(entry_point: str, *, where: str = "entry point") -> Any:
    """Import ``"package.module:attr.path"`` and return the attribute.

    Raises:
        SpecError: malformed string, the module does not exist, or it has no such attribute.
            An ImportError raised *inside* an existing module (a missing dependency)
            propagates unchanged, so its real cause stays visible.
    """
    if not isinstance(entry_point, str) or not _ENTRY.match(entry_point):
        raise SpecError(f"{where}: expected 'package.module:callable', got {entry_point!r}")
    module_name, _, attr = entry_point.partition(":")
    try:
        obj: Any = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and module_name.startswith(exc.name):
            raise SpecError(
                f"{where}: expected an importable module, got {module_name!r} (not found)"
            ) from None
        raise
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise SpecError(
                f"{where}: expected module {module_name!r} to define {attr!r}, got no such name"
            ) from None
    return obj


class Registry(Generic[T]):
    """Names of one kind (``"program"``, ``"model kind"`` ...) -> lazily resolved objects.

    Args:
        kind: what the names are, used in messages (``unknown program 'x'; known programs``).
        entries: initial table ``name -> "module:callable"``.
    """

    def __init__(self, kind: str, entries: Mapping[str, str] | None = None) -> None:
        self.kind = kind
        self._targets: dict[str, str | T] = {}
        self._resolved: dict[str, T] = {}
        for name, target in (entries or {}).items():
            self.add(name, target)

    def add(self, name: str, target: str | T, *, replace: bool = False) -> None:
        """Add ``name`` -> ``target`` (a ``"module:callable"`` string or the object itself).

        Raises:
            SpecError: empty name, malformed entry-point string, or ``name`` already maps to a
                different target and ``replace`` is false.
        """
        if not isinstance(name, str) or not name.strip():
            raise SpecError(f"{self.kind} registry: expected a non-empty name, got {name!r}")
        if isinstance(target, str) and not _ENTRY.match(target):
            raise SpecError(
                f"{self.kind} {name!r}: expected 'package.module:callable', got {target!r}"
            )
        old = self._targets.get(name)
        if old is not None and not replace and not _same(old, target):
            raise SpecError(
                f"{self.kind} {name!r} is registered twice: {_show(old)} and {_show(target)}"
            )
        self._targets[name] = target
        self._resolved.pop(name, None)
        if not isinstance(target, str):
            self._resolved[name] = target

    def remove(self, name: str) -> None:
        """Forget ``name`` (no error when absent)."""
        self._targets.pop(name, None)
        self._resolved.pop(name, None)

    def get(self, name: str) -> T:
        """The object registered as ``name``, importing its module on first use.

        Raises:
            NotFound: unknown name (the message lists the known ones).
            SpecError: the entry point cannot be resolved.
        """
        if isinstance(name, str) and name in self._resolved:
            return self._resolved[name]
        if not isinstance(name, str) or name not in self._targets:
            raise NotFound(f"unknown {self.kind} {name!r}; known {self.kind}s: {self.names()}")
        target = self._targets[name]
        obj: T = (
            resolve_entry_point(target, where=f"{self.kind} {name!r}")
            if isinstance(target, str)
            else target
        )
        self._resolved[name] = obj
        return obj

    def entry_point(self, name: str) -> str:
        """The ``"module:callable"`` string of ``name`` (``module:qualname`` for objects)."""
        if name not in self:
            raise NotFound(f"unknown {self.kind} {name!r}; known {self.kind}s: {self.names()}")
        return _show(self._targets[name])

    def names(self) -> list[str]:
        """Every registered name, sorted (nothing is imported)."""
        return sorted(self._targets)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self._targets

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._targets)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, {len(self)} entries)"


def _show(target: Any) -> str:
    if isinstance(target, str):
        return target
    module = getattr(target, "__module__", "?")
    qualname = getattr(target, "__qualname__", type(target).__qualname__)
    return f"{module}:{qualname}"


def _same(a: Any, b: Any) -> bool:
    return a is b or _show(a) == _show(b)
