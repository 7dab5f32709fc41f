"""Per-run objects that plug-ins share, each under a typed key.

A ``Resource[T]`` names one shared object and says its type; ``Resources`` holds the objects of
one run (``RunContext.resources``). The module that owns an object defines its key, and every
reader and writer imports that key, so the type is checked where the object is read:

    WAYPOINTS: Resource[Mapping[str, Mapping[str, float]]] = Resource("waypoints")
    context.resources.set(WAYPOINTS, {"Home": {...}})
    home = (context.resources.get(WAYPOINTS) or {}).get("Home")
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Callable, Generic, TypeVar, cast

T = TypeVar("T")


class Resource(Generic[T]):
    """The key of one per-run shared object of type ``T``; ``name`` is unique within a run."""

    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name

    def __repr__(self) -> str:
        return f"Resource({self.name!r})"


class Resources:
    """The shared objects of one run, by ``Resource`` key."""

    def __init__(self) -> None:
        self._values: dict[str, object] = {}

    def get(self, key: Resource[T]) -> T | None:
        """The object under ``key``; None when nothing was set."""
        return cast("T | None", self._values.get(key.name))

    def set(self, key: Resource[T], value: T) -> None:
        self._values[key.name] = value

    def setdefault(self, key: Resource[T], make: Callable[[], T]) -> T:
        """The object under ``key``, made by ``make()`` and set first when there is none."""
        if key.name not in self._values:
            self._values[key.name] = make()
        return cast(T, self._values[key.name])

    def __contains__(self, key: Resource[Any]) -> bool:
        return key.name in self._values


WAYPOINTS: Resource[Mapping[str, Mapping[str, float]]] = Resource("waypoints")
"""The world's named joint positions, ``{name: {joint: position}}`` (set by the world in ``start``)."""
