"""One small registry: named items in registration order, as dm_control's ``TaggedTasks`` holds its tasks.

The project's four registries are instances: agent kinds (:mod:`apac_mj.kinds`), the rules' parameter
tables (:mod:`apac_mj.rules`), tasks registered at run time (:mod:`apac_mj.suite.task_spec`) and the
report's figures (:mod:`apac_mj.report.figures`). Each module keeps its own functions (``register``,
``get``, ...) with their checks and wording, and leaves the bookkeeping here::

    figures = Registry("figure")
    figures.register("fig3.png", spec)          # a taken name: ValueError, unless replace=True
    figures.get("fig9.png")                     # KeyError: "no figure 'fig9.png' is registered; registered: fig3.png"

This module is the lowest layer: it imports nothing from the package.
"""
from __future__ import annotations

from collections.abc import Iterator
from typing import Generic, TypeVar

T = TypeVar("T")


class Registry(Generic[T]):
    """Items of type ``T`` by name, in registration order (a name that is replaced keeps its place).

    ``what`` names an item in the error messages. ``unknown`` and ``duplicate`` are the messages for a
    name that is not registered and for one that is taken, as ``str.format`` templates with the fields
    ``what``, ``name``, ``names`` (the registered names, comma-separated, or "none") and, for
    ``duplicate``, ``item`` (the one registered). ``error`` is the exception an unknown name raises (a
    KeyError, or a subclass of it); a taken name raises ValueError.
    """

    def __init__(self, what: str, *, unknown: str = "no {what} {name!r} is registered; registered: {names}",
                 duplicate: str = "{what} {name!r} is already registered (pass replace=True to redefine it)",
                 error: type[KeyError] = KeyError) -> None:
        if not issubclass(error, KeyError):
            raise TypeError(f"a registry's error for an unknown name must be a KeyError, got {error!r}")
        self.what = what
        self._unknown, self._duplicate, self._error = unknown, duplicate, error
        self._items: dict[str, T] = {}

    def register(self, name: str, item: T, replace: bool = False) -> T:
        """Add ``item`` as ``name``, after those registered; a taken name is a ValueError unless ``replace``
        (then ``item`` takes the old one's place in the order). Returns ``item``."""
        if not replace:
            self.check_new(name)
        self._items[name] = item
        return item

    def replace(self, name: str, item: T) -> T:
        """``register(name, item, replace=True)``: ``item`` in the place of the one registered as ``name``
        (or after the others, if none is)."""
        return self.register(name, item, replace=True)

    def check_new(self, name: str) -> None:
        """Raise the ValueError of a taken name if ``name`` is registered (before work that registering
        would otherwise undo)."""
        if name in self._items:
            raise ValueError(self._duplicate.format(what=self.what, name=name, names=self._names(),
                                                    item=self._items[name]))

    def unregister(self, name: str) -> T:
        """Remove ``name``; an unknown name raises as :meth:`get` does. Returns the item removed."""
        self.get(name)
        return self._items.pop(name)

    def get(self, name: str) -> T:
        """The item registered as ``name``; an unknown (or unhashable) name raises ``error``, listing the
        registered names."""
        try:
            return self._items[name]
        except (KeyError, TypeError):
            raise self.unknown(name) from None

    def unknown(self, name: object) -> KeyError:
        """The error for ``name``, which is not registered (it lists the registered names)."""
        return self._error(self._unknown.format(what=self.what, name=name, names=self._names()))

    def names(self) -> tuple[str, ...]:
        """Every registered name, in registration order."""
        return tuple(self._items)

    def items(self) -> list[tuple[str, T]]:
        """Every (name, item), in registration order."""
        return list(self._items.items())

    def values(self) -> list[T]:
        """Every item, in registration order."""
        return list(self._items.values())

    def _names(self) -> str:
        return ", ".join(self._items) or "none"

    def __contains__(self, name: object) -> bool:
        return name in self._items

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"Registry({self.what!r}: {', '.join(self._items)})"
