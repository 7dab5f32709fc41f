"""The tick loop: advance the clock, step the world, deliver bus traffic, tick the tree.

One tick per ``1 / tick_hz`` seconds of clock time (100 Hz by default):

    clock.advance(period); world.step_to(clock.now()); bus.spin_once(); tick the root once

until the root returns SUCCESS or FAILURE (or ``max_seconds`` of clock time pass). On a
``SimClock`` this runs as fast as the CPU allows and is deterministic; on a ``WallClock``
(``--realtime``) ``advance`` sleeps to keep the rate. Whatever happens, the tree is halted
(RUNNING nodes get ``terminate(INVALID)``, so a moving robot is stopped) and the world and the
bus are closed.

How the run ended is a ``RunEnd``: SUCCESS, FAILURE, INTERRUPTED (SIGINT/SIGTERM, see
``runtime.io.interrupt``: the tree is halted as a preemption) or ERROR (bad input found while
running, or an unexpected exception, told in one paragraph by ``runtime.tree.crash`` with its
traceback in a log file). Each has its exit code (``RunResult.exit_code``).

A world (the simulated cell) is started only when some node of the tree has
``needs_world = True``; worlds are found by name in the ``objective.worlds`` entry-point group.

``RunLoop`` is the loop (``start``, ``tick``, ``close``) and tells the run's observers
(``runtime.app.observer.RunObserver``) of each step; ``run_tree`` drives it, ``run_loaded`` adds
the observers the options ask for (the recording), ``run_file`` loads the tree first.
"""
from __future__ import annotations

import contextlib
import enum
import json
import math
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import AbstractSet, Any, Callable, Iterable, Sequence

import py_trees

from runtime.tree import node_info
from runtime.tree.behavior import NodeMixin, RunContext, Status, SummarisesRun
from runtime.io.bus import InProcessBus, InterruptibleWaits, capability, parse_latency
from runtime.io.clock import Clock, SimClock, WallClock
from runtime.tree.controls import SKIPPED, Visit, tick_tree
from runtime.tree.crash import CRASH_LOG, culprit, describe_crash, write_traceback
from runtime.errors import ObjectiveError, ObjectiveRuntimeError, OptionError, error_kind
from runtime.tree.events import EventLog
from runtime.io.heap import PacedHeap
from runtime.io.interrupt import Interrupted, StopRequest, exit_code_for, signal_name
from runtime.tree.loader import LoadedTree, load_tree
from runtime.tree.ports import NameKind
from .observer import RunObserver, attach_observers
from .protective_stop import PROTECTIVE_STOP, ProtectiveStop, StopInputs, needs_heartbeat
from runtime.tree.registry import Registry, default_world_name
from runtime.tree.world import World
from runtime.io.scheduling import check_priority, realtime_priority
from .world import create_world, world_hosts_servers
from .world_check import check_tree, declared_interfaces, named_links

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
    """Latency model of policy service calls (``runtime.io.bus.parse_latency`` syntax), for the world."""
    record_dir: Path | None = None
    """Record the run into this directory (``--record``): done by a run observer (``runtime.app.observer``)."""
    live_port: int | None = None
    """Serve the run's topics to Foxglove on this port while it runs (``--live``; 0: any free
    port): done by a run observer (``runtime.app.observer``)."""
    world_options: dict[str, Any] = field(default_factory=dict)
    ros: bool = False
    """Run on real ROS 2 (``runtime.io.ros.run``): a RosBus node, paced by a WallClock (implies
    ``realtime``); the world serves no policy of its own unless ``world_options`` names one."""
    ros_node_name: str = "objective_runtime"
    use_sim_time: bool = False
    """With ``ros``: start the clock at the time the graph's ``/clock`` reads (a simulated robot's
    own clock, ``objective sim-robot``), so the stamps sent to its controllers are on its time."""
    realtime_priority: int | None = None
    """In a paced run: tick at this SCHED_FIFO priority (1-99, ``runtime.io.scheduling``); None:
    the default priority."""
    protective_stop: StopInputs | None = field(default_factory=StopInputs)
    """Where the run listens for a protective stop and a deadman's heartbeat
    (``runtime.app.protective_stop``); None: nowhere."""
    log_dir: Path | None = None
    """Where the traceback of an unexpected exception goes: the recording directory when
    recording, else this (None: ``build/logs/`` under the working directory)."""

    @property
    def observed(self) -> bool:
        """True when a run observer has work (``--record`` or ``--live``)."""
        return self.record_dir is not None or self.live_port is not None

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
            except OptionError as err:
                raise ObjectiveError(f"--policy-latency: {err}") from None
        for name in self.sets:
            if not name or name.strip() != name:
                raise ObjectiveError(f"--set needs name=value with a non-empty name, got {name!r}")
        if self.protective_stop is not None:
            self.protective_stop.check()
        if self.realtime_priority is not None:
            if not self.paced:
                raise ObjectiveError("--realtime-priority sets the priority of a paced run's ticks: it needs --realtime or --ros")
            problem = check_priority(self.realtime_priority)
            if problem is not None:
                raise ObjectiveError(f"--realtime-priority: {problem}")
        if self.use_sim_time and not self.ros:
            raise ObjectiveError("--use-sim-time follows the ROS graph's /clock: it needs --ros")
        if self.ros and self.policy_latency is not None:
            raise ObjectiveError(
                "--policy-latency models latency on the in-process bus; with --ros the policy's latency is real"
            )


TIMEOUT = "timeout"
"""The failure kind of a run stopped by ``--max-seconds``."""


class RunEnd(enum.Enum):
    """How a run ended."""

    SUCCESS = "SUCCESS"
    FAILURE = "FAILURE"
    SKIPPED = "SKIPPED"
    """Every child of the root was skipped: nothing ran, nothing failed (exit 0, as BT.CPP's SKIPPED)."""
    INTERRUPTED = "INTERRUPTED"
    """SIGINT or SIGTERM: the tree was halted as a preemption (goals cancelled, robot stopped)."""
    ERROR = "ERROR"
    """Bad input found while running (e.g. a port value out of range) or an unexpected exception."""


@dataclass
class RunResult:
    status: str
    """A ``RunEnd`` value: "SUCCESS", "FAILURE", "SKIPPED" (every child of the root was skipped:
    nothing ran), "INTERRUPTED" or "ERROR"."""
    failing_node: str | None
    reason: str
    sim_seconds: float
    wall_seconds: float
    ticks: int
    blackboard: dict[str, Any]
    extra: dict[str, Any] = field(default_factory=dict)
    failing_location: str | None = None
    signum: int | None = None
    """The signal that interrupted the run (INTERRUPTED only)."""
    stopped_by: str | None = None
    """Who stopped the run when no signal did (``StopRequest.cancel``; INTERRUPTED only)."""
    running_nodes: list[str] = field(default_factory=list)
    """Leaves that were RUNNING when the run was interrupted or broke off, halted since."""
    log_file: str | None = None
    """The full traceback of an unexpected exception (ERROR only)."""
    failure_kind: str | None = None
    """What kind of ending a FAILURE or ERROR was, for grouping runs: the failing node's kind
    (``Behavior.failure_kind``, e.g. ``velocity limit``; ``timeout`` for ``--max-seconds``), a user
    error's class name (``SetupError``) or ``internal`` (a bug); None when nobody says."""

    @property
    def exit_code(self) -> int:
        """0 SUCCESS and SKIPPED (nothing failed), 1 FAILURE, 2 ERROR, 128 + the signal's number
        when INTERRUPTED (130, 143)."""
        if self.status == RunEnd.INTERRUPTED.value:
            return exit_code_for(self.signum or signal.SIGINT)
        return {RunEnd.SUCCESS.value: 0, RunEnd.SKIPPED.value: 0, RunEnd.FAILURE.value: 1}.get(self.status, 2)

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
        if self.failure_kind is not None:
            summary["failure_kind"] = self.failure_kind
        if self.stopped_by is not None:
            summary["stopped_by"] = self.stopped_by
        elif self.status == RunEnd.INTERRUPTED.value:
            summary["signal"] = signal_name(self.signum or signal.SIGINT)
        if self.status in (RunEnd.INTERRUPTED.value, RunEnd.ERROR.value) or self.failure_kind == PROTECTIVE_STOP:
            summary["running_nodes"] = list(self.running_nodes)
        if self.log_file is not None:
            summary["log_file"] = self.log_file
        for key, value in self.extra.items():
            summary.setdefault(key, value)
        return summary


def make_context(options: RunOptions) -> RunContext:
    """Clock, bus and event log for one run: in-process, or a RosBus node with ``options.ros``."""
    if options.ros:
        from runtime.io.ros.run import follow_graph_clock, make_ros_bus  # rclpy is imported only for ROS runs

        wall = WallClock()
        bus = make_ros_bus(wall, options.ros_node_name, serves=world_hosts_servers(options.world or default_world_name()))
        stamp_offset_s = 0.0
        if options.use_sim_time:
            try:
                follow_graph_clock(bus, wall)
            except BaseException:
                bus.close()
                raise
        elif not world_hosts_servers(options.world or default_world_name()):
            stamp_offset_s = robot_time_offset_s(wall)  # a real robot's controllers stamp with ROS time
        return RunContext(clock=wall, bus=bus, events=EventLog(wall), seed=options.seed, stamp_offset_s=stamp_offset_s)
    clock = WallClock() if options.realtime else SimClock()
    bus = InProcessBus(clock, paced=options.realtime)
    return RunContext(clock=clock, bus=bus, events=EventLog(clock), seed=options.seed)


def robot_time_offset_s(clock: Clock) -> float:
    """What to add to ``clock``'s time for the ROS time of a robot without ``/clock``: the system
    clock, which ROS 2 nodes read when ``use_sim_time`` is off (a controller that reads a goal's
    stamp as an instant, such as joint_trajectory_controller, compares it with that)."""
    return time.time() - clock.now()


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
    while node_info.is_transparent(node) and len(node.children) == 1:
        node = node.children[0]
    return node


def _failing(root: py_trees.behaviour.Behaviour, visited: list[Visit]) -> tuple[py_trees.behaviour.Behaviour, str, str | None] | None:
    """The node to blame for the root's FAILURE in this tick, with its reason and failure kind.

    Follow the failure down from the root: at each node, go to the child that reported FAILURE
    most recently in this tick and gives a reason (the most recent one when none does); stop at a
    node none of whose children failed (a leaf that failed, or a Timeout/Inverter that turned its
    child's result into a failure). A failure a ForceSuccess forgave is therefore never blamed.
    """
    last: dict[int, tuple[int, Status, str]] = {}
    for order, (node, status, message) in enumerate(visited):
        last[id(node)] = (order, status, message)

    def failed_at(node: py_trees.behaviour.Behaviour) -> int | None:
        record = last.get(id(node))
        return record[0] if record is not None and record[1] is Status.FAILURE else None

    def reason(node: py_trees.behaviour.Behaviour) -> str:
        return last[id(node)][2] or _unwrap(node).feedback_message

    def blame(node: py_trees.behaviour.Behaviour) -> py_trees.behaviour.Behaviour:
        """The failing leaf under ``node``: the most recent failure that gives a reason, so a
        Fallback's closing AlwaysFailure (no reason) blames the check that failed before it."""
        failing = sorted((c for c in node.children if failed_at(c) is not None), key=lambda c: failed_at(c) or 0, reverse=True)
        leaves = [blame(child) for child in failing]
        return next((leaf for leaf in leaves if reason(leaf)), leaves[0]) if leaves else node

    if failed_at(root) is None:
        return None
    node = blame(root)
    inner = _unwrap(node)
    return inner, reason(node), node_info.failure_kind(inner)


_RUNNING = Status.RUNNING.value


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
        self.running: set[int] = set()
        """The nodes whose last reported status is RUNNING: the only ones that can be halted."""

    def _emit(self, i: int, status: str, message: str) -> None:
        if self.last.get(i) != status:
            self.last[i] = status
            if status == _RUNNING:
                self.running.add(i)
            else:
                self.running.discard(i)
            self.events.emit("node_status", self.nodes[i].name, node=i, status=status, message=message)

    def update(self, visited: list[Visit]) -> None:
        index, last, seen = self.index, self.last, set()
        for node, status, message in visited:
            i = index.get(id(node))
            if i is not None:
                seen.add(i)
                name = "SKIPPED" if status is SKIPPED and node_info.is_skipped(node) else status._value_  # .value is a slow property
                if last.get(i) != name:
                    self._emit(i, name, message)
        self.halted(seen)

    def halted(self, seen: AbstractSet[int] = frozenset()) -> None:
        if self.running.issubset(seen):  # every RUNNING node reported again in this tick
            return
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
    """How well a wall-clock run kept its tick rate: ticks whose work took longer than a period,
    and the wall time between the starts of consecutive ticks.

    The clock never makes up for lost ticks (``WallClock.advance``), so a late tick only delays
    that tick; these numbers say whether the world or the tree was too slow for real time.
    """

    period: float
    late_ticks: int = 0
    worst_tick_s: float = 0.0
    scheduling: str = "default"
    """What the tick thread ran at (``runtime.io.scheduling.realtime_priority``)."""
    intervals_s: list[float] = field(default_factory=list)
    _last_start: float | None = None

    def record(self, started_s: float, ended_s: float) -> None:
        """One tick's work, from ``started_s`` to ``ended_s`` (``time.monotonic()``)."""
        seconds = ended_s - started_s
        self.worst_tick_s = max(self.worst_tick_s, seconds)
        if seconds > self.period:
            self.late_ticks += 1
        if self._last_start is not None:
            self.intervals_s.append(started_s - self._last_start)
        self._last_start = started_s

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"late_ticks": self.late_ticks, "worst_tick_s": round(self.worst_tick_s, 4), "period_s": self.period,
                               "scheduling": self.scheduling}
        if self.intervals_s:
            ordered = sorted(self.intervals_s)
            for name, q in (("p50", 0.5), ("p99", 0.99)):
                out[f"interval_{name}_s"] = round(ordered[min(int(q * len(ordered)), len(ordered) - 1)], 4)
            out["interval_max_s"] = round(ordered[-1], 4)
        return out


def outcome(status: Status, timed_out: bool) -> RunEnd:
    """How a finished run ended, from the root's last result: SUCCESS, FAILURE or SKIPPED (as in BT.CPP)."""
    if status is Status.FAILURE or timed_out:
        return RunEnd.FAILURE
    return RunEnd.SKIPPED if status is SKIPPED else RunEnd.SUCCESS


@dataclass
class Breakoff:
    """Why the tick loop stopped before the tree finished: a signal or an exception."""

    signum: int | None = None
    error: BaseException | None = None
    cause: str | None = None
    """Who asked to stop, when it was not a signal (``StopRequest.cancel``)."""
    protective_stop: str | None = None
    """Why the protective stop was engaged (``runtime.app.protective_stop``): the run ends FAILURE."""

    @property
    def end(self) -> RunEnd:
        if self.protective_stop is not None:
            return RunEnd.FAILURE
        return RunEnd.INTERRUPTED if self.signum is not None else RunEnd.ERROR


def running_leaves(root: py_trees.behaviour.Behaviour) -> list[py_trees.behaviour.Behaviour]:
    """The RUNNING nodes with no RUNNING child: what the tree was doing."""
    return [
        node for node in root.iterate()
        if node.status is Status.RUNNING and not any(c.status is Status.RUNNING for c in node.children)
    ]


class RunLoop:
    """One run of a loaded tree: ``start()``, then ``tick()`` while it says to go on, then ``close()``.

    ``start`` starts the world named by ``options.world`` when the tree needs one (unless ``world``
    is given), listens for the protective stop and sets every node up. Each ``tick`` first looks
    at ``stop`` (set by ``runtime.io.interrupt`` on SIGINT or SIGTERM) and ``--max-seconds``, then
    advances the clock, steps the world, delivers the bus traffic that is due, asks ``guard`` (the
    protective stop: by default one listening on the run's bus per ``options.protective_stop``; it
    ends the run FAILURE) and ticks the tree once. ``close`` halts the tree, closes the world and
    the bus and says how the run ended.

    Bad input found while running (e.g. a port reading a blackboard entry nobody wrote), an
    unexpected exception or a signal ends the run (``start`` or ``tick`` returns False) as ERROR or
    INTERRUPTED; ``close`` is still what halts and summarises. Anything else raised from ``start`` or
    ``tick`` (a ``SystemExit``) halts and closes everything before it goes on.

    Every step tells the ``observers`` (``runtime.app.observer.RunObserver``) what happened:
    ``started``, ``ticked``, then ``finished`` from ``close``, or ``aborted`` from whichever step
    raised.
    """

    def __init__(self, loaded: LoadedTree, context: RunContext, options: RunOptions,
                 observers: Sequence[RunObserver] = (), world: World | None = None, stop: StopRequest | None = None,
                 guard: ProtectiveStop | None = None) -> None:
        self.loaded, self.context, self.options = loaded, context, options
        self.observers, self.world, self.stop, self.guard = tuple(observers), world, stop, guard
        self.root = loaded.root
        self.nodes = list(self.root.iterate())
        self.clock, self.bus = context.clock, context.bus
        self.statuses = StatusEvents(context.events, self.nodes)
        self.period = 0.0
        """Clock seconds between two ticks (``1 / tick_hz``, once the options are checked)."""
        self.pacing: Pacing | None = None
        self.ticks = 0
        self.status = Status.INVALID
        """The root's status after the last tick."""
        self.timed_out = False
        self.breakoff: Breakoff | None = None
        self.blame: tuple[py_trees.behaviour.Behaviour, str, str | None] | None = None
        self.running: list[py_trees.behaviour.Behaviour] = []
        """The leaves that were RUNNING when the run ended (halted since)."""
        self.policy_running = False
        """Whether a node that needs a heartbeat was RUNNING after the last tick (kept only while
        the guard watches a deadman: ``heartbeat_watched``)."""
        self.heartbeat_watched = False
        self.wall_start = time.monotonic()
        self.ticking = contextlib.ExitStack()
        """What holds while the tree ticks: the paced heap, the real-time priority."""
        self.heap = PacedHeap(False)
        """The paced heap while the tree ticks (collecting between ticks); one that does nothing before."""

    # -- the three steps -----------------------------------------------------------------------
    def start(self) -> bool:
        """Start the world and set the nodes up; False when the run ended before its first tick."""
        try:
            self._prepare()
        except BaseException as err:  # nothing started: nothing to close
            self._tell_aborted(err)
            raise
        return self._step(self._start)

    def tick(self) -> bool:
        """One tick of the tree (unless the run stops first); True while the tree is RUNNING."""
        return self._step(self._tick)

    def close(self) -> RunResult:
        """Halt the tree, close the world and the bus, say how the run ended and tell the observers."""
        try:
            try:
                self._end()
            finally:
                summary_world = self._shut_down()
            result = self._result(summary_world, time.monotonic() - self.wall_start)
        except BaseException as err:
            self._tell_aborted(err)
            raise
        for observer in self.observers:
            observer.finished(result, self.stop)
        return result

    # -- inside the steps ----------------------------------------------------------------------
    def _prepare(self) -> None:
        """What comes before anything starts; what it raises ends the run with nothing to close."""
        options = self.options
        options.check()
        for key, value in options.sets.items():
            self.loaded.blackboard.set(key, value)
        stopping = self.stop is not None and self.stop.requested  # a signal while loading: no world to start and close
        if self.world is None and not stopping and any(isinstance(n, NodeMixin) and n.needs_world for n in self.nodes):
            world_options = {
                "seed": options.seed,
                "realtime": options.paced,
                "policy_latency": options.policy_latency,
                "record_dir": options.record_dir,
                **options.world_options,
            }
            if options.ros:  # the policy comes from the ROS graph (an adapter), not from the world
                world_options.setdefault("policy", "none")
            self.world = create_world(options.world or default_world_name(), world_options)
        self.period = self.context.tick_period_s = 1.0 / options.tick_hz  # the run's nodes read it from the context
        waits = capability(self.bus, InterruptibleWaits)
        stop = self.stop
        if stop is not None and waits is not None:
            waits.stop_waiting_when(lambda: stop.requested)  # a hung in-process policy never holds a signal back
        self.pacing = Pacing(self.period) if options.paced else None
        self.wall_start = time.monotonic()

    def _step(self, step: Callable[[], bool]) -> bool:
        """``step()``; a signal or an exception ends the run instead (False). Whatever else is
        raised (a ``SystemExit``) halts the tree and closes everything on its way out."""
        try:
            return step()
        except Interrupted as err:  # a second signal: stop now, still halting and summarising
            self.breakoff = Breakoff(signum=err.signum)
        except Exception as err:  # ObjectiveError (bad input) or a bug: the run ends as ERROR
            self.breakoff = Breakoff(error=err)
        except BaseException as err:
            try:
                self.ticking.close()
                self._shut_down()
            except BaseException as later:  # raised on in place of ``err``
                self._tell_aborted(later)
                raise
            self._tell_aborted(err)
            raise
        return False

    def _tell_aborted(self, error: BaseException) -> None:
        for observer in self.observers:
            observer.aborted(error, self.stop)

    def _start(self) -> bool:
        context, options, loaded = self.context, self.options, self.loaded
        if self.guard is None and options.protective_stop is not None:  # listening from the start
            self.guard = ProtectiveStop(options.protective_stop)
            self.guard.listen(self.bus)
        self.heartbeat_watched = self.guard is not None and self.guard.watches_heartbeat
        if self.world is not None:
            context.world = self.world
            try:
                self.world.start(context)
            except ObjectiveError as err:
                raise err.within(f"world '{self.world.name}'") from None
            check_tree(loaded, context)  # a name the world does not have: ERROR before anything moves
        for node in self.nodes:
            node.setup()
        if options.ros:  # the clients the behaviors create while they run then cost no late tick
            from runtime.io.ros.run import prepare_links

            links = named_links(loaded.nodes)
            prepare_links(self.bus, declared_interfaces(self.nodes),
                          services=[(name, types[0]) for name, kind, types in links if kind is NameKind.SERVICE],
                          actions=[(name, types) for name, kind, types in links if kind is NameKind.ACTION])
        context.events.emit("run_started", loaded.tree_id, seed=options.seed)
        for observer in self.observers:
            observer.started(loaded)
        self.heap = self.ticking.enter_context(PacedHeap(self.pacing is not None))
        # options.check() allows a priority only in a paced run
        scheduling = self.ticking.enter_context(realtime_priority(options.realtime_priority))
        if self.pacing is not None:
            self.pacing.scheduling = scheduling
        return True

    def _tick(self) -> bool:
        clock, stop, max_seconds = self.clock, self.stop, self.options.max_seconds
        if stop is not None and stop.signum is not None:
            self.breakoff = Breakoff(signum=stop.signum, cause=stop.cause)
            return False
        if max_seconds is not None and clock.now() + self.period > max_seconds + 1e-9:
            self.timed_out = True
            return False
        clock.advance(self.period)
        tick_start = time.monotonic()
        if self.world is not None:
            self.world.step_to(clock.now())
        self.bus.spin_once()
        why = self.guard.reason(clock.now(), self.policy_running) if self.guard is not None else None
        if why is not None:  # the tree is not ticked again: halted by close(), its goals cancelled
            self.breakoff = Breakoff(protective_stop=why)
            self.context.events.emit("protective_stop", self.loaded.tree_id, reason=why)
            return False
        self.ticks += 1  # counted before it runs: a tick that raised was still ticked
        tick = tick_tree(self.root)
        self.status, visited = tick.status, tick.visited
        if self.heartbeat_watched:
            self.policy_running = any(seen is Status.RUNNING and needs_heartbeat(n) for n, seen, _ in visited)
        self.statuses.update(visited)
        if self.pacing is not None:
            self.pacing.record(tick_start, time.monotonic())
        for observer in self.observers:
            observer.ticked(clock.now(), visited)
        if self.pacing is not None:  # the heap is managed in a paced run only
            self.heap.between_ticks()
        if self.status is Status.RUNNING:
            return True
        if self.status is Status.FAILURE:
            self.blame = _failing(self.root, visited)
        return False

    def _end(self) -> None:
        """What the tree was doing when the run ended, who is to blame for a timeout; the
        ``run_finished`` event."""
        self.ticking.close()
        self.running = running_leaves(self.root)
        if self.timed_out:
            tip = self.root.tip()
            where = f" while '{tip.name}' was RUNNING" if tip is not None else ""
            reason = f"stopped after --max-seconds {self.options.max_seconds:g} s of clock time{where}"
            self.blame = (tip if tip is not None else self.root, reason, TIMEOUT)
        end = self.breakoff.end if self.breakoff is not None else outcome(self.status, self.timed_out)
        self.context.events.emit("run_finished", self.loaded.tree_id, status=end.value)

    def _shut_down(self) -> dict[str, Any] | None:
        """Halt the tree, then close the world and the bus (each even when what came before it
        raised); the world's summary."""
        world, summary_world = self.world, None
        try:
            if _halt(self.root) and self.options.ros:
                from runtime.io.ros.run import deliver_pending

                # let the cancels of a halted run reach the graph, and the hosted controllers act on them
                deliver_pending(self.bus, None if world is None else lambda: world.step_to(self.clock.now()))
        except Exception as err:  # a node's terminate() broke: still close the world and the bus
            self.breakoff = self.breakoff or Breakoff(error=err)
        finally:
            try:
                self.statuses.halted()
                if world is not None:
                    try:
                        summary_world = world.summary()
                    finally:
                        world.close()
            finally:
                self.bus.close()
        return summary_world

    def _result(self, summary_world: dict[str, Any] | None, wall_seconds: float) -> RunResult:
        extra: dict[str, Any] = {}
        for node in self.nodes:
            if isinstance(node, SummarisesRun):
                extra.update(node.run_summary() or {})
        if summary_world:
            extra["world"] = summary_world
        if self.pacing is not None:
            extra["pacing"] = self.pacing.as_dict()
        result = RunResult(
            status=outcome(self.status, self.timed_out).value,
            failing_node=None,
            reason="",
            sim_seconds=self.clock.now(),
            wall_seconds=wall_seconds,
            ticks=self.ticks,
            blackboard=json_entries(self.loaded.blackboard.items()),
            extra=extra,
            running_nodes=[node.name for node in self.running],
        )
        if self.breakoff is not None:
            _describe_breakoff(result, self.breakoff, self.running, self.loaded, self.nodes, self.options)
        elif self.blame is not None:
            node, reason, result.failure_kind = self.blame
            info = self.loaded.info(node)
            result.failing_node, result.reason = node.name, reason or ""
            result.failing_location = str(info.location) if info is not None else None
        return result


def run_tree(
    loaded: LoadedTree,
    context: RunContext,
    options: RunOptions,
    observers: Sequence[RunObserver] = (),
    world: World | None = None,
    stop: StopRequest | None = None,
    guard: ProtectiveStop | None = None,
) -> RunResult:
    """Tick ``loaded`` (bound to ``context``) to completion and summarise the run (``RunLoop``)."""
    loop = RunLoop(loaded, context, options, observers, world, stop, guard)
    if loop.start():
        while loop.tick():
            pass
    return loop.close()


def _describe_breakoff(result: RunResult, breakoff: Breakoff, running: list[py_trees.behaviour.Behaviour],
                       loaded: LoadedTree, nodes: list[py_trees.behaviour.Behaviour], options: RunOptions) -> None:
    """Fill ``result`` for a run a signal or an exception ended (status, node, reason, log file)."""
    result.status = breakoff.end.value
    where = ", ".join(f"'{n.name}'" + _at(loaded, n) for n in running)
    halted = f"; halted {where} (RUNNING)" if where else ""
    if breakoff.protective_stop is not None:
        result.reason = f"protective stop: {breakoff.protective_stop} at {result.sim_seconds:.2f} s{halted}"
        result.failure_kind = PROTECTIVE_STOP
        return
    if breakoff.signum is not None:
        result.signum = int(breakoff.signum)
        result.stopped_by = breakoff.cause
        cause = breakoff.cause or f"interrupted by {signal_name(breakoff.signum)}"
        result.reason = f"{cause} at {result.sim_seconds:.2f} s{halted}"
        return
    error, culprit_name = breakoff.error, None
    assert error is not None
    result.failure_kind = error_kind(error)
    if isinstance(error, ObjectiveRuntimeError) and not error.callers:
        node = culprit(error, nodes)  # the node that raised it: its place, and the SubTree calls it is inside
        info = loaded.info(node) if node is not None else None
        if info is not None and error.location in (None, info.location):
            error = info.error(error)
    if not isinstance(error, ObjectiveRuntimeError):
        node = culprit(error, nodes)
        culprit_name = node.name if node is not None else None
        directory = options.record_dir or options.log_dir
        log_file = write_traceback(error, directory, CRASH_LOG if options.record_dir is not None else None)
        result.log_file = str(log_file) if log_file is not None else None
        info = loaded.info(node) if node is not None else None
        error = describe_crash(error, node, log_file, info.location if info is not None else None)
    result.reason = str(error)
    result.failing_node = culprit_name or error.node
    result.failing_location = str(error.location) if error.location else None


def _at(loaded: LoadedTree, node: py_trees.behaviour.Behaviour) -> str:
    info = loaded.info(node)
    return f" ({info.location})" if info is not None else ""


def run_file(
    source: Path | str,
    registry: Registry,
    options: RunOptions,
    tree_id: str | None = None,
    search_paths: Iterable[Path] = (),
    objectives_dir: Path | None = None,
    observers: Sequence[RunObserver] = (),
    stop: StopRequest | None = None,
) -> RunResult:
    """Load ``source`` and run it: what ``objective run`` does (``stop``: see ``runtime.io.interrupt``)."""
    options.check()
    context = make_context(options)
    loaded = load_tree(source, registry, context, tree_id, search_paths, objectives_dir)
    return run_loaded(loaded, context, options, observers, stop)


def run_loaded(loaded: LoadedTree, context: RunContext, options: RunOptions, observers: Sequence[RunObserver] = (),
               stop: StopRequest | None = None, guard: ProtectiveStop | None = None) -> RunResult:
    """Run a loaded tree (``run_file`` after the loading) with ``observers``, and after them the run
    observers the options ask for (``runtime.app.observer``: the recording, the live view)."""
    if options.observed:
        observers = [*observers, *attach_observers(loaded, context, options)]
    return run_tree(loaded, context, options, observers, stop=stop, guard=guard)
