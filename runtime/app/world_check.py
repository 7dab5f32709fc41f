"""What an Objective names in the world, checked against the world before anything moves.

A port declared with ``names=Names(kind)`` (``runtime.tree.ports``) names a frame, a planning-scene
object, a joint group or joint, a waypoint, a controller, a service or an action.
``check_names`` reads every such port whose value is known before the first tick (a literal, or a
blackboard entry a SubTree port or ``--set`` filled) and says, for each, what the world does not
have, as a ``SetupError`` at the node's ``file:line`` (and the line of each SubTree call it is
inside). The runner calls it once the world has started (so a typo ends the run as ERROR before
the first tick), and ``objective validate --world`` reports every problem of a file. Values a
script computes are known only when the node reads them; behaviors raise a ``SetupError`` for
them then.
"""
from __future__ import annotations

import contextlib
import difflib
from dataclasses import dataclass, field, replace
from typing import Any, Iterable, Iterator

from runtime.io.bus import ServedListing, capability
from runtime.tree import node_info
from runtime.tree.behavior import RunContext
from runtime.tree.resources import WAYPOINTS
from runtime.errors import ObjectiveError, PortError, SetupError
from runtime.tree.ports import Direction, NameKind, Names, PortType

WORLD_FRAMES = frozenset({"world"})


@dataclass(frozen=True)
class WorldFacts:
    """The names a started world knows. A set left None is not known here and not checked
    (e.g. the services of a ROS 2 graph, which may still be starting)."""

    frames: frozenset[str] | None = None
    objects: frozenset[str] | None = None
    groups: frozenset[str] | None = None
    joints: frozenset[str] | None = None
    waypoints: frozenset[str] | None = None
    services: dict[str, type] | None = None
    actions: dict[str, type] | None = None
    controllers: frozenset[str] | None = None
    active_controllers: frozenset[str] | None = None
    """The controllers active when the world starts."""
    topics: dict[str, type] | None = None
    listed_frames: tuple[str, ...] = field(default=())
    """The frames a message lists: objects, world, robot links (the model's other frames are not listed)."""

    @classmethod
    def from_context(cls, context: RunContext) -> WorldFacts:
        """What ``context`` knows: its planning scene, waypoints, and the services and actions of an in-process bus."""
        facts: dict[str, Any] = {}
        scene = context.scene
        if scene is not None:
            robot = scene.robot
            objects = frozenset(scene.objects) | {a.name for a in scene.attachments}
            facts.update(
                objects=frozenset(objects),
                groups=frozenset(robot.group_names),
                joints=frozenset(robot.movable_joints),
                frames=frozenset(n for n in (*robot.link_names, *_model_frames(robot))) | objects | WORLD_FRAMES,
                listed_frames=(*sorted(objects), "world", *robot.link_names),
            )
        waypoints = context.resources.get(WAYPOINTS)
        if waypoints is not None:
            facts["waypoints"] = frozenset(waypoints)
        listing = capability(context.bus, ServedListing)  # None: the graph serves elsewhere (ROS 2), nothing is checked
        if listing is not None:
            states = _controller_states(listing)
            facts.update(services=listing.served(), actions=listing.action_servers(), topics=listing.published(),
                         controllers=None if states is None else frozenset(states),
                         active_controllers=None if states is None else frozenset(n for n, s in states.items() if s == "active"))
        return cls(**facts)

    def problem(self, names: Names, value: str) -> str | None:
        """Why ``value`` is not a name of this kind in the world, or None (also when not known here)."""
        kind = names.kind
        if kind in (NameKind.SERVICE, NameKind.ACTION, NameKind.TOPIC):
            offered = {NameKind.SERVICE: self.services, NameKind.ACTION: self.actions, NameKind.TOPIC: self.topics}[kind]
            if offered is None:
                return None
            if value not in offered:
                return f"no {kind.value} '{value}'{_hint(value, offered)} ({kind.value}s: {_listing(sorted(offered))})"
            allowed = names.interfaces
            if allowed and offered[value] not in allowed:
                return (f"{kind.value} '{value}' is a {_type_name(offered[value])}, not a "
                        f"{' or a '.join(_type_name(t) for t in allowed)}")
            return None
        known = {
            NameKind.FRAME: self.frames, NameKind.OBJECT: self.objects, NameKind.JOINT_GROUP: self.groups,
            NameKind.JOINT: self.joints, NameKind.WAYPOINT: self.waypoints, NameKind.CONTROLLER: self.controllers,
        }[kind]
        if known is None or value in known:
            return None
        listed = self.listed_frames if kind is NameKind.FRAME else sorted(known)
        return f"unknown {kind.value} '{value}'{_hint(value, known)} ({kind.value}s: {_listing(listed)})"


def check_names(nodes: Iterable[Any], facts: WorldFacts, whole_tree: bool = True) -> list[SetupError]:
    """A ``SetupError`` for each name a node's port gives that the world does not have; for a
    ``whole_tree``, also for each action of a controller not active when its node runs.

    ``nodes`` are the loader's ``LoadedNode`` records (node, xml_id, location, callers).
    """
    named = list(_named(nodes))
    created = frozenset(value for _, _, names, value in named if names.creates)
    if created and facts.objects is not None:  # objects the tree itself adds may be named before they exist
        facts = replace(facts, objects=facts.objects | created, frames=(facts.frames or frozenset()) | created)
    errors: list[SetupError] = []
    for record, port, names, value in named:
        problem = None if names.creates else facts.problem(names, value)
        if problem is not None:
            errors.append(record.error(SetupError(f"port '{port}': {problem}")))
    for record, port, problem in inactive_controller_actions(named, facts) if whole_tree else ():
        errors.append(record.error(SetupError(f"port '{port}': {problem}")))
    return errors


def inactive_controller_actions(named: list[tuple[Any, str, Names, str]], facts: WorldFacts) -> list[tuple[Any, str, str]]:
    """(record, port, why) for each action of a controller that is not active when its node runs:
    the controllers active at the start, switched by the SwitchControllers written before it
    (``Names.activates``, in the order the nodes are written)."""
    if facts.controllers is None or facts.active_controllers is None:
        return []
    active = set(facts.active_controllers)
    found = []
    for record, port, names, value in named:
        if names.kind is NameKind.CONTROLLER and names.activates is not None:
            (active.add if names.activates else active.discard)(value)
            continue
        controller = value.strip("/").split("/")[0]
        if names.kind is NameKind.ACTION and controller in facts.controllers and controller not in active:
            found.append((record, port, f"action '{value}' is served by controller '{controller}', which is not active "
                                        f"when this node runs: activate it before (SwitchController "
                                        f"activate_controllers=\"{controller}\"; active: {', '.join(sorted(active))})"))
    return found


def _named(nodes: Iterable[Any]) -> Iterator[tuple[Any, str, Names, str]]:
    """(record, port, what it names, value) for each name a port gives before the first tick."""
    for record in nodes:
        node = record.node
        lenient = node.lenient_names() if callable(getattr(node, "lenient_names", None)) else ()
        for port, binding in node_info.bindings(node).items():
            names = binding.info.names
            if names is None or binding.info.direction is Direction.OUTPUT or port in lenient:
                continue
            try:
                value = node.get_input(port)
            except PortError:  # an entry nobody wrote yet: known only when the node runs
                continue
            for item in value if binding.info.type is PortType.STRING_LIST else [value]:
                if item not in (None, ""):
                    yield record, port, names, str(item)


def declared_interfaces(nodes: Iterable[Any]) -> list[type]:
    """The ROS 2 service and action types the ports of ``nodes`` declare (``Names.interface``),
    each once, in the order first declared: what the run may create clients of."""
    seen: dict[type, None] = {}
    for node in nodes:
        for binding in node_info.bindings(node).values():
            names = binding.info.names
            for kind in () if names is None else names.interfaces:
                seen.setdefault(kind, None)
    return list(seen)


def named_links(records: Iterable[Any]) -> list[tuple[str, NameKind, tuple[type, ...]]]:
    """(name, SERVICE or ACTION, the types it may have) for each service and action a port names
    before the first tick (a literal value), each name once: the clients the tree will create."""
    links: dict[tuple[str, NameKind], tuple[type, ...]] = {}
    for _, _, names, value in _named(records):
        if names.kind in (NameKind.SERVICE, NameKind.ACTION) and names.interfaces:
            links.setdefault((value, names.kind), names.interfaces)
    return [(name, kind, types) for (name, kind), types in links.items()]


def check_tree(loaded: Any, context: RunContext) -> None:
    """Raise a ``SetupError`` when ``loaded`` names what the world started on ``context`` does not
    have: the first problem, with how many more there are (the runner, before the first tick)."""
    errors = check_names(loaded.nodes, WorldFacts.from_context(context))
    if len(errors) > 1:
        errors[0].args = (f"{errors[0]} (and {len(errors) - 1} more such problems: "
                          "`objective validate FILE --world NAME` lists every one)",)
    if errors:
        raise errors[0]


@dataclass
class StartedWorld:
    """A world started on its own in-process context, for checking trees against it."""

    context: RunContext
    facts: WorldFacts

    def check(self, records: list[Any], whole_tree: bool = True) -> list[SetupError]:
        """The problems of the loader's node ``records`` (a tree, and nodes the loader left out);
        ``whole_tree`` False for a SubTree, whose callers may switch its controllers. The tree's
        scripts run first (``evaluate_scripts``), so a name a script computes is checked too."""
        evaluate_scripts(records)
        return check_names(records, self.facts, whole_tree)


def evaluate_scripts(records: Iterable[Any]) -> None:
    """Run each Script of ``records`` once, in the order written, on the blackboard of the tree
    being validated (a throwaway one: nothing of a run's): ``top_cube := 'cube_' .. top_color``
    then gives the name a later port reads. A script that reads what only a run writes is skipped."""
    from runtime.tree import script as scripting
    from runtime.tree.script_nodes import Script

    for record in records:
        if isinstance(record.node, Script):
            with contextlib.suppress(scripting.ScriptError, ObjectiveError):
                record.node.script.evaluate(record.node.blackboard)


@contextlib.contextmanager
def started_world(name: str, options: dict[str, Any]) -> Iterator[StartedWorld]:
    """The world ``name`` (``--world-option`` ``options``) started on a simulated clock and an
    in-process bus, closed on exit: what ``objective validate --world`` checks against."""
    from runtime.tree.loader import throwaway_context
    from .world import create_world

    context = throwaway_context()
    world = create_world(name, {"seed": 0, "realtime": False, **options})
    try:
        world.start(context)
        yield StartedWorld(context, WorldFacts.from_context(context))
    finally:
        try:
            world.close()
        finally:
            context.bus.close()


def _controller_states(listing: ServedListing) -> dict[str, str] | None:
    """Each controller an in-process controller manager lists, with its state (None when none is served)."""
    listers = [name for name, srv_type in listing.served().items() if srv_type.__name__ == "ListControllers"]
    if len(listers) != 1:
        return None
    srv_type: Any = listing.served()[listers[0]]  # a generated service class (untyped)
    return {c.name: c.state for c in listing.call_now(listers[0], srv_type.Request()).controller}


def _model_frames(robot: Any) -> Iterable[str]:
    model = getattr(robot, "model", None)
    frames = getattr(model, "frames", None)
    return [frame.name for frame in frames] if frames is not None else []


def _hint(value: str, known: Iterable[str]) -> str:
    close = difflib.get_close_matches(value, sorted(known), n=1, cutoff=0.75)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _listing(names: Iterable[str], most: int = 12) -> str:
    names = list(names)
    shown = ", ".join(names[:most])
    return (shown + f", ... ({len(names) - most} more)") if len(names) > most else (shown or "none")


def _type_name(interface: type) -> str:
    """``control_msgs/action/GripperCommand``: the package, the kind of interface and the name."""
    module = interface.__module__.split(".")
    return f"{module[0]}/{module[1]}/{interface.__name__}" if len(module) > 2 else interface.__name__
