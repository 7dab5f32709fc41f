"""Finding and creating worlds, and what only some worlds do.

A world is a ``runtime.tree.world.World``. Worlds are found through the ``objective.worlds``
entry-point group: each names ``create(options) -> World``.
"""
from __future__ import annotations

from importlib.metadata import entry_points
from typing import Any, Protocol, runtime_checkable

from runtime.errors import ObjectiveError
from runtime.extras import load_entry_point
from runtime.tree.registry import WORLD_GROUP
from runtime.tree.world import World


@runtime_checkable
class KeepsEpisodes(Protocol):
    """A world that one evaluation worker keeps for many episodes (``sim.world``'s cells): put
    back to a seed before each run's ``start``. An evaluation creates any other world anew for
    every episode."""

    def begin_episode(self, seed: int) -> None:
        """Before ``start`` with a new run's context: the world as a newly created one with
        ``seed`` would have it."""
        ...

    def policy_backend(self, spec: Any) -> Any:
        """The backend this world serves as its embedded policy for ``spec`` (a
        ``policy.specs.PolicySpec``; None for ``none``), built for this world: what
        ``objective run --policy`` serves on it. ObjectiveError for a spec it cannot serve."""
        ...


@runtime_checkable
class PlacesBoxes(Protocol):
    """A simulated world that boxes appear in and leave mid-run (PlaceSimBox, RemoveSimBox)."""

    def place_box(self, name: str, size_m: Any, pose: Any, mirror: bool = True) -> None:
        """Make a fixed box appear at ``pose`` (4x4, world frame), or move it there, mirrored
        into the planning scene unless ``mirror`` is False. ValueError says why not."""
        ...

    def remove_box(self, name: str) -> None:
        """Take a placed box out (and out of the planning scene). ValueError says why not."""
        ...


def world_hosts_servers(name: str) -> bool:
    """Whether the world registered as ``name`` serves anything on the run's bus (services,
    actions: a simulated cell does); its factory says otherwise with ``hosts_servers = False``.
    True for a name nobody registered (``create_world`` reports that)."""
    available = {ep.name: ep for ep in entry_points(group=WORLD_GROUP)}
    if name not in available:
        return True
    try:
        factory = available[name].load()
    except ImportError:  # a world of an extra that is not installed: ``create_world`` says so if the tree needs it
        return True
    return bool(getattr(factory, "hosts_servers", True))


def create_world(name: str, options: dict[str, Any]) -> World:
    """The world registered as ``name`` in the ``objective.worlds`` entry-point group."""
    available = {ep.name: ep for ep in entry_points(group=WORLD_GROUP)}
    if name not in available:
        known = ", ".join(sorted(available)) or "none installed"
        raise ObjectiveError(f"no world named '{name}' (worlds: {known})")
    create = load_entry_point(available[name], f"world '{name}' cannot start")  # a world of an extra may be missing
    try:
        world: World = create(options)
        return world
    except ObjectiveError as err:  # a world refuses the user's options with an ObjectiveError (OptionError)
        raise err.within(f"world '{name}'") from None
