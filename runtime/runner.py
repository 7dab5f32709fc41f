"""The tick loop: advance the clock, step the world, deliver bus traffic, tick the tree.

One tick per ``1 / tick_hz`` seconds of clock time (100 Hz by default):

    clock.advance(period); world.step_to(clock.now()); bus.spin_once(); tick the root once

until the root returns SUCCESS or FAILURE (or ``max_seconds`` of clock time pass). On a
``SimClock`` this runs as fast as the CPU allows and is deterministic; on a ``WallClock``
(``--realtime``) ``advance`` sleeps to keep the rate. Whatever happens, the tree is halted
(RUNNING nodes get ``terminate(INVALID)``, so a moving robot is stopped) and the world and the
bus are closed.

A world (the simulated cell) is started only when some node of the tree has
``needs_world = True``; worlds are found by name in the ``objective.worlds`` entry-point group.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable

import py_trees

from .behavior import RunContext, Status
from .bus import InProcessBus, parse_latency
from .clock import SimClock, WallClock
from .controls import SKIPPED, Visit, is_skipped, tick_tree
from .errors import ObjectiveError

if TYPE_CHECKING:
    from .recording.live import LiveOptions
from .events import EventLog
from .loader import LoadedTree, load_tree
from .registry import WORLD_GROUP, Registry, default_world_name

Progress = Callable[[float, int, str], None]
"""Called after every tick with (clock seconds, ticks so far, name of the running node)."""


@dataclass
class RunOptions:
    seed: int = 0
    realtime: bool = False
    tick_hz: float = 100.0
    max_seconds: float | None = None
    """Stop (FAILURE) after this much clock time; None runs until the tree finishes."""
    world: str | None = None
    """World to start when the tree needs one; None means the installation's default
    (the one entry of the ``objective.default_world`` entry-point group)."""
    sets: dict[str, str] = field(default_factory=dict)
    """Root blackboard entries set before the first tick (``--set name=value``), as strings."""
    policy_latency: str | None = None
    """Latency model of policy service calls (``runtime.bus.parse_latency`` syntax), for the world."""
    record_dir: Path | None = None
    live: "LiveOptions | None" = None
    """Serve the run's topics to Foxglove while it runs (``--live``); see ``runtime.recording.live``."""
    world_options: dict[str, Any] = field(default_factory=dict)
    ros: bool = False
    """Run on real ROS 2 (``runtime.ros.run``): a RosBus node, paced by a WallClock (implies
    ``realtime``); the world serves no policy of its own unless ``world_options`` names one."""
    ros_node_name: str = "objective_runtime"

    @property
    def paced(self) -> bool:
        """True when the run follows wall-clock time (``--realtime``, or ``--ros``)."""
        return self.realtime or self.ros

    def check(self) -> None:
        """Raise ObjectiveError for options that cannot work (before anything starts)."""
        if not (self.tick_hz > 0 and math.isfinite(self.tick_hz)):
            raise ObjectiveError(f"tick rate must be a positive number of Hz, got {self.tick_hz}")
        if self.max_seconds is not None and not self.max_seconds > 0:
            raise ObjectiveError(f"--max-seconds must be positive, got {self.max_seconds}")
        if self.policy_latency is not None:
            try:
                parse_latency(self.policy_latency, self.seed)
            except ValueError as err:
                raise ObjectiveError(f"--policy-latency: {err}") from None
        for name in self.sets:
            if not name or name.strip() != name:
                raise ObjectiveError(f"--set needs name=value with a non-empty name, got {name!r}")
        if self.ros and self.policy_latency is not None:
            raise ObjectiveError(
                "--policy-latency models latency on the in-process bus; with --ros the policy's latency is real"
            )


@dataclass
class RunResult:
    status: str
    """"SUCCESS", "FAILURE" or "SKIPPED" (every child of the root was skipped: nothing ran)."""
    failing_node: str | None
    reason: str
    sim_seconds: float
    wall_seconds: float
    ticks: int
    blackboard: dict[str, Any]
    extra: dict[str, Any] = field(default_factory=dict)
    failing_location: str | None = None

    @property
    def exit_code(self) -> int:
        """0 for SUCCESS and SKIPPED (nothing failed), 1 for FAILURE."""
        return 1 if self.status == "FAILURE" else 0

    def to_json(self) -> dict[str, Any]:
        """The summary object ``objective run --json`` prints (extras merged at the top level)."""
        summary: dict[str, Any] = {
            "status": self.status,
            "failing_node": self.failing_node,
            "reason": self.reason,
            "sim_seconds": round(self.sim_seconds, 6),
            "wall_seconds": round(self.wall_seconds, 3),
            "ticks": self.ticks,
            "blackboard": self.blackboard,
        }
        for key, value in self.extra.items():
            summary.setdefault(key, value)
        return summary


def make_context(options: RunOptions) -> RunContext:
    """Clock, bus and event log for one run: in-process, or a RosBus node with ``options.ros``."""
    if options.ros:
        from .ros.run import make_ros_bus  # rclpy is imported only for ROS runs

        wall = WallClock()
        return RunContext(clock=wall, bus=make_ros_bus(wall, options.ros_node_name), events=EventLog(wall), seed=options.seed)
    clock = WallClock() if options.realtime else SimClock()
    bus = InProcessBus(clock)
    return RunContext(clock=clock, bus=bus, events=EventLog(clock), seed=options.seed)


def create_world(name: str, options: dict[str, Any]) -> Any:
    """The world registered as ``name`` in the ``objective.worlds`` entry-point group."""
    available = {ep.name: ep for ep in entry_points(group=WORLD_GROUP)}
    if name not in available:
        known = ", ".join(sorted(available)) or "none installed"
        raise ObjectiveError(f"no world named '{name}' (worlds: {known})")
    create = available[name].load()
    try:
        return create(options)
    except ValueError as err:  # a world refuses bad options with ValueError: that is bad input
        raise ObjectiveError(f"world '{name}': {err}") from None


def json_entries(board_items: Iterable[tuple[str, Any]]) -> dict[str, Any]:
    """The entries that JSON can carry (numpy values as lists/numbers); others are left out."""
    out: dict[str, Any] = {}
    for key, value in board_items:
        if hasattr(value, "tolist"):
            value = value.tolist()
        try:
            json.dumps(value, allow_nan=False)
        except (TypeError, ValueError):
            continue
        out[key] = value
    return out


def _unwrap(node: py_trees.behaviour.Behaviour) -> py_trees.behaviour.Behaviour:
    """The node a transparent wrapper (a condition guard) stands for."""
    while getattr(node, "transparent", False) and len(node.children) == 1:
        node = node.children[0]
    return node


def _failing(root: py_trees.behaviour.Behaviour, visited: list[Visit]) -> tuple[py_trees.behaviour.Behaviour, str] | None:
    """The node to blame for the root's FAILURE in this tick, with its reason.

    Follow the failure down from the root: at each node, go to the child that reported FAILURE
    most recently in this tick; stop at a node none of whose children failed (a leaf that
    failed, or a Timeout/Inverter that turned its child's result into a failure). A failure a
    ForceSuccess forgave is therefore never blamed.
    """
    last: dict[int, tuple[int, Status, str]] = {}
    for order, (node, status, message) in enumerate(visited):
        last[id(node)] = (order, status, message)

    def failed_at(node: py_trees.behaviour.Behaviour) -> int | None:
        record = last.get(id(node))
        return record[0] if record is not None and record[1] is Status.FAILURE else None

    if failed_at(root) is None:
        return None
    node = root
    while True:
        failing = [(failed_at(c), c) for c in node.children if failed_at(c) is not None]
        if not failing:
            break
        node = max(failing, key=lambda item: item[0])[1]
    message = last[id(node)][2]
    inner = _unwrap(node)
    return inner, message or inner.feedback_message


class StatusEvents:
    """Emits a ``node_status`` event each time a node reports a status different from its last one.

    ``node`` in the event is the node's index in ``root.iterate()`` order (names are not
    unique); a recording stores the tree in the same order. A RUNNING node that a parent halted
    (it was not ticked again and is idle now) is reported once as ``INVALID`` with "halted".
    """

    def __init__(self, events: EventLog, nodes: list[py_trees.behaviour.Behaviour]) -> None:
        self.events, self.nodes = events, nodes
        self.index = {id(node): i for i, node in enumerate(nodes)}
        self.last: dict[int, str] = {}

    def _emit(self, i: int, status: str, message: str) -> None:
        if self.last.get(i) != status:
            self.last[i] = status
            self.events.emit("node_status", self.nodes[i].name, node=i, status=status, message=message)

    def update(self, visited: list[Visit]) -> None:
        seen = set()
        for node, status, message in visited:
            i = self.index.get(id(node))
            if i is not None:
                seen.add(i)
                self._emit(i, "SKIPPED" if status is SKIPPED and is_skipped(node) else status.value, message)
        self.halted(seen)

    def halted(self, seen: set[int] = frozenset()) -> None:
        for i, last in list(self.last.items()):
            if last == Status.RUNNING.value and i not in seen and self.nodes[i].status is Status.INVALID:
                self._emit(i, Status.INVALID.value, "halted")


def _halt(root: py_trees.behaviour.Behaviour) -> bool:
    """Halt the RUNNING branch; True when something was running."""
    if any(node.status is Status.RUNNING for node in root.iterate()):
        root.stop(Status.INVALID)
        return True
    return False


@dataclass
class Pacing:
    """How well a wall-clock run kept its tick rate: ticks whose work took longer than a period.

    The clock never makes up for lost ticks (``WallClock.advance``), so a late tick only delays
    that tick; these numbers say whether the world or the tree was too slow for real time.
    """

    period: float
    late_ticks: int = 0
    worst_tick_s: float = 0.0

    def record(self, seconds: float) -> None:
        self.worst_tick_s = max(self.worst_tick_s, seconds)
        if seconds > self.period:
            self.late_ticks += 1

    def as_dict(self) -> dict[str, Any]:
        return {"late_ticks": self.late_ticks, "worst_tick_s": round(self.worst_tick_s, 4), "period_s": self.period}


def outcome(status: Status, timed_out: bool) -> str:
    """How a run ended, from the root's last result: SUCCESS, FAILURE or SKIPPED (as in BT.CPP)."""
    if status is Status.FAILURE or timed_out:
        return "FAILURE"
    return "SKIPPED" if status is SKIPPED else "SUCCESS"


def run_tree(
    loaded: LoadedTree,
    context: RunContext,
    options: RunOptions,
    progress: Progress | None = None,
    world: Any = None,
) -> RunResult:
    """Tick ``loaded`` (bound to ``context``) to completion and summarise the run.

    Starts the world named by ``options.world`` when the tree needs one (unless ``world`` is
    given). Raises ObjectiveError for bad input found while running (e.g. a port reading a
    blackboard entry nobody wrote); the tree is halted and everything closed either way.
    """
    options.check()
    root = loaded.root
    nodes = list(root.iterate())
    for key, value in options.sets.items():
        loaded.blackboard.set(key, value)
    if world is None and any(getattr(type(n), "needs_world", False) for n in nodes):
        world_options = {
            "seed": options.seed,
            "realtime": options.paced,
            "policy_latency": options.policy_latency,
            "record_dir": options.record_dir,
            **options.world_options,
        }
        if options.ros:  # the policy comes from the ROS graph (an adapter), not from the world
            world_options.setdefault("policy", "none")
        world = create_world(options.world or default_world_name(), world_options)
    period = 1.0 / options.tick_hz
    clock, bus = context.clock, context.bus
    ticks = 0
    blame: tuple[py_trees.behaviour.Behaviour, str] | None = None
    status = Status.INVALID
    timed_out = False
    statuses = StatusEvents(context.events, nodes)
    if callable(getattr(progress, "attach", None)):
        progress.attach(root)  # type: ignore[union-attr]
    pacing = Pacing(period) if options.paced else None
    wall_start = time.monotonic()
    try:
        if world is not None:
            context.world = world
            try:
                world.start(context)
            except ValueError as err:
                raise ObjectiveError(f"world '{getattr(world, 'name', '?')}': {err}") from None
        for node in nodes:
            node.setup()
        context.events.emit("run_started", loaded.tree_id, seed=options.seed)
        while True:
            if options.max_seconds is not None and clock.now() + period > options.max_seconds + 1e-9:
                timed_out = True
                break
            clock.advance(period)
            tick_start = time.monotonic()
            if world is not None:
                world.step_to(clock.now())
            bus.spin_once()
            tick = tick_tree(root)
            status, visited = tick.status, tick.visited
            statuses.update(visited)
            ticks += 1
            if pacing is not None:
                pacing.record(time.monotonic() - tick_start)
            if progress is not None:
                tip = root.tip()
                progress(clock.now(), ticks, tip.name if tip is not None else "")
            if status is not Status.RUNNING:
                if status is Status.FAILURE:
                    blame = _failing(root, visited)
                break
        if timed_out:
            tip = root.tip()
            running = f" while '{tip.name}' was RUNNING" if tip is not None else ""
            reason = f"stopped after --max-seconds {options.max_seconds:g} s of clock time{running}"
            blame = (tip if tip is not None else root, reason)
        context.events.emit("run_finished", loaded.tree_id, status=outcome(status, timed_out))
    finally:
        summary_world = None
        try:
            if _halt(root) and options.ros:
                from .ros.run import deliver_pending

                deliver_pending(bus)  # let the cancels of a halted run reach the graph
        finally:
            try:
                statuses.halted()
                if world is not None:
                    try:
                        summary_world = world.summary()
                    finally:
                        world.close()
            finally:
                bus.close()
    wall_seconds = time.monotonic() - wall_start

    extra: dict[str, Any] = {}
    for node in nodes:
        summarise = getattr(node, "run_summary", None)
        if callable(summarise):
            extra.update(summarise() or {})
    if summary_world:
        extra["world"] = summary_world
    if pacing is not None:
        extra["pacing"] = pacing.as_dict()

    failing_node = reason = location = None
    if blame is not None:
        node, reason = blame
        failing_node = node.name
        info = loaded.info(node)
        location = str(info.location) if info is not None else None
    return RunResult(
        status=outcome(status, timed_out),
        failing_node=failing_node,
        reason=reason or "",
        sim_seconds=clock.now(),
        wall_seconds=wall_seconds,
        ticks=ticks,
        blackboard=json_entries(loaded.blackboard.items()),
        extra=extra,
        failing_location=location,
    )


def run_file(
    source: Path | str,
    registry: Registry,
    options: RunOptions,
    tree_id: str | None = None,
    search_paths: Iterable[Path] = (),
    objectives_dir: Path | None = None,
    progress: Progress | None = None,
) -> RunResult:
    """Load ``source`` and run it: what ``objective run`` does."""
    options.check()
    context = make_context(options)
    loaded = load_tree(source, registry, context, tree_id, search_paths, objectives_dir)
    if options.record_dir is None and options.live is None:
        return run_tree(loaded, context, options, progress)
    return _run_recorded(loaded, context, options, progress)


def _run_recorded(loaded: LoadedTree, context: RunContext, options: RunOptions, progress: Progress | None) -> RunResult:
    """``run_tree`` with a ``Recorder`` on the bus (into ``options.record_dir`` and/or served live),
    then the report rendered into ``options.record_dir``."""
    from .recording import Recorder
    from .report.worker import ReportWorker

    recorder = Recorder(options.record_dir, context, list(loaded.root.iterate()), loaded, live=options.live)
    if recorder.live is not None:
        context.logger.info("live view: in Foxglove, open a Foxglove WebSocket connection to %s", recorder.live.url)
    if options.record_dir is None:
        try:
            return run_tree(loaded, context, options, progress)
        finally:
            recorder.close()
    worker = ReportWorker()
    worker.start()  # imports the report's libraries while the run goes on
    try:
        result = run_tree(loaded, context, options, progress)
    except BaseException:
        recorder.close()
        worker.close()
        raise
    recorder.finish(result.to_json())
    try:
        worker.render(options.record_dir, context.logger)
    except Exception as err:  # the run itself is over and recorded: its result stands
        context.logger.warning("recording %s: the report could not be rendered: %s", options.record_dir, err)
    finally:
        worker.close()
    return result
