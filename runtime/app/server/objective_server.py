"""``objective server DIR``: a ROS 2 node that runs the Objectives of a library on request.

The node ``/objective_server`` serves, as MoveIt Pro's Objective server does:

- ``/do_objective`` (action ``objective_server_msgs/action/DoObjective``): run one Objective by
  name, with port and blackboard overrides, which reach only the ports the Objective declares
  (``runtime.app.objective_library.override_entries``: never a node's inside it). Feedback, at most
  every ``FEEDBACK_PERIOD_S`` of wall time: the RUNNING leaves, the clock, the ticks, and what
  running nodes report so far (ExecutePolicy: chunks, stalls, ...). Result: the status, the reason, the failing node and
  the ``objective run --json`` summary. A cancelled goal halts the tree as SIGINT halts
  ``objective run`` (goals cancelled, the arm stopped) and ends CANCELED with status INTERRUPTED.
- ``/execute_objective`` (``objective_server_msgs/srv/ExecuteObjective``): start one the same
  way and answer at once (the end is logged).
- ``/cancel_objective`` (``std_srvs/srv/Trigger``): cancel whatever runs.
- ``/protective_stop`` (``std_msgs/msg/Bool`` topic and ``std_srvs/srv/Trigger`` service, names from
  the run options' ``protective_stop``) and the deadman's heartbeat, on this node: they end
  whatever runs as FAILURE ("protective stop: ...", ``runtime.app.protective_stop``).
- ``/list_objectives`` (``objective_server_msgs/srv/ListObjectives``): every Objective of the
  library with its description and ports, and the one running now.

One Objective at a time: a goal that arrives while another runs is rejected, and
``/execute_objective`` answers ``success: false`` (the server logs which one runs;
``/list_objectives`` says it too). A goal whose name, overrides or Objective
are wrong is accepted and aborted at once with status ERROR and the reason, so the client
learns what is wrong. Each run is a run of ``runtime.app.runner`` with the server's options (world,
``--ros``, ``--realtime``, ...): exactly what ``objective run FILE`` with those options does.

Discovery stays on this machine (``runtime.io.ros.run.set_discovery_range``) unless the environment
or ``--discovery-range`` opens it. ``close()`` (SIGINT/SIGTERM) halts the running Objective, ends
its goal ABORTED ("the Objective server is shutting down ...") and leaves the graph only once that
result is on its way to the client.
"""
from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import rclpy
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from std_srvs.srv import Trigger

from objective_server_msgs.action import DoObjective
from objective_server_msgs.msg import ObjectiveInfo, ObjectivePort
from objective_server_msgs.srv import ExecuteObjective, ListObjectives
from runtime.tree import node_info
from runtime.tree.behavior import SummarisesRun
from runtime.tree.controls import Visit
from runtime.tree.crash import describe_crash, write_traceback
from runtime.errors import ObjectiveError
from runtime.io.ros.bus import init_context, spin_on_thread
from runtime.io.interrupt import StopRequest
from runtime.tree.loader import LoadedTree, default_objectives_dir, load_tree
from runtime.app.objective_library import Library, PortOverride, override_entries
from runtime.app.protective_stop import ProtectiveStop, StopInputs
from runtime.tree.registry import Registry
from runtime.io.ros.run import set_discovery_range
from runtime.app.observer import RunObserver
from runtime.app.runner import RunEnd, RunOptions, RunResult, make_context, run_loaded, running_leaves

NODE_NAME = "objective_server"
ACTION_NAME = "/do_objective"
EXECUTE_SERVICE = "/execute_objective"
CANCEL_SERVICE = "/cancel_objective"
LIST_SERVICE = "/list_objectives"
FEEDBACK_PERIOD_S = 0.1
CANCELLED = f"cancelled by a client of {ACTION_NAME}"
CANCELLED_BY_SERVICE = f"cancelled through {CANCEL_SERVICE}"
SHUTDOWN = "the Objective server is shutting down"
RESULT_GRACE_S = 0.25
"""Wall time the server keeps serving after a goal ended before it leaves the graph, so the
result reaches the clients waiting for it (rclpy sends it from the executor's next wake)."""
_log = logging.getLogger("objective")


@dataclass
class ServerOptions:
    library: Path
    run: RunOptions = field(default_factory=RunOptions)
    """What every run uses (world, --ros, --realtime, ...); a request adds its blackboard overrides."""
    search_paths: list[Path] = field(default_factory=list)
    """More directories to find SubTrees in, after the library itself (the shipped ``objectives/``
    is searched after them, as ``objective run`` does)."""
    groot2: Any = None
    """A ``runtime.app.groot2.Groot2Server`` every run is shown on, or None."""


@dataclass
class Outcome:
    """What a DoObjective goal ends with (its result message's fields)."""

    status: str
    reason: str = ""
    failing_node: str = ""
    failing_location: str = ""
    summary: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, result: RunResult) -> "Outcome":
        return cls(result.status, result.reason, result.failing_node or "", result.failing_location or "",
                   result.to_json())

    @classmethod
    def error(cls, reason: str) -> "Outcome":
        return cls(RunEnd.ERROR.value, reason, summary={"status": RunEnd.ERROR.value, "reason": reason})


class FeedbackObserver(RunObserver):
    """Publishes DoObjective feedback while a run goes."""

    def __init__(self, publish: Callable[[Any], None], period_s: float = FEEDBACK_PERIOD_S) -> None:
        self.publish, self.period_s = publish, period_s
        self.root: Any = None
        self.ticks = 0
        self.last_sent = -float("inf")

    def started(self, loaded: LoadedTree) -> None:
        self.root = loaded.root

    def ticked(self, now_s: float, visited: list[Visit]) -> None:
        self.ticks += 1
        wall = time.monotonic()
        if wall - self.last_sent < self.period_s:
            return
        self.last_sent = wall
        self.publish(feedback(self.root, now_s, self.ticks))


def feedback(root: Any, now_s: float, ticks: int) -> Any:
    """The feedback message for the tree ``root`` now."""
    message = DoObjective.Feedback()
    leaves = running_leaves(root)
    message.running_nodes = [f"{n.name} ({node_info.xml_id(n)})" for n in leaves]
    message.clock_s = float(now_s)
    message.ticks = ticks
    progress: dict[str, Any] = {}
    for node in leaves:
        if isinstance(node, SummarisesRun):
            progress.update(node.run_summary() or {})
    message.progress_json = json.dumps(progress, default=str)
    return message


def subtree_search_paths(options: ServerOptions) -> list[Path]:
    """Where a run's SubTrees are searched after the library: ``search_paths``, then the shipped
    ``objectives/`` (the library ``objective run`` searches), unless the library is that one."""
    shipped = default_objectives_dir()
    listed = [options.library, *options.search_paths]
    return [*options.search_paths, *([] if any(p.resolve() == shipped for p in listed) else [shipped])]


class ObjectiveServer:
    """The node, its executor thread and the one run it may hold. ``close()`` cancels that run."""

    def __init__(self, options: ServerOptions, registry: Registry, node_name: str = NODE_NAME) -> None:
        self.options, self.registry = options, registry
        self.library = Library(options.library, registry, subtree_search_paths(options))
        options.run.check()
        self._lock = threading.Lock()
        self._running: str | None = None
        """The name of the Objective whose goal was accepted and has not ended."""
        self._stop: StopRequest | None = None
        self._idle = threading.Event()
        """Set while no run holds the slot and no goal is being finished."""
        self._idle.set()
        self._goal_ended_at = -float("inf")
        """``time.monotonic()`` when the last DoObjective goal ended (its result on its way)."""
        set_discovery_range()
        self.context = init_context()
        self.node = rclpy.create_node(node_name, context=self.context)
        group = ReentrantCallbackGroup()
        self._action = ActionServer(
            self.node, DoObjective, ACTION_NAME, execute_callback=self._execute, goal_callback=self._on_goal,
            cancel_callback=self._on_cancel, callback_group=group,
        )
        self.node.create_service(ExecuteObjective, EXECUTE_SERVICE, self._execute_service, callback_group=group)
        self.node.create_service(Trigger, CANCEL_SERVICE, self._cancel_service, callback_group=group)
        self.node.create_service(ListObjectives, LIST_SERVICE, self._list_service, callback_group=group)
        self.guard = self._listen_for_protective_stop(options.run.protective_stop, group)
        self.executor = MultiThreadedExecutor(num_threads=4, context=self.context)
        self.executor.add_node(self.node)
        self._spinner = spin_on_thread(self.executor, "objective_server")

    def _listen_for_protective_stop(self, inputs: StopInputs | None, group: Any) -> ProtectiveStop | None:
        """The protective stop's inputs on the server's node (not on each run's): whatever runs
        then, and however (``--ros`` or not), a stop ends it."""
        if inputs is None:
            return None
        guard = ProtectiveStop(inputs)
        guard.serve_on_node(self.node, group)
        return guard

    # -- requests ----------------------------------------------------------------------------
    def _reserve(self, name: str) -> str | None:
        """Take the one run slot for ``name`` and return None; when another Objective holds it,
        return that one's name."""
        with self._lock:
            if self._running is not None:
                _log.warning("refused to start '%s': '%s' is running (one Objective at a time)", name, self._running)
                return self._running
            self._running = name
            self._idle.clear()
        return None

    def _run_reserved(self, request: Any, publish: Callable[[Any], None]) -> Outcome:
        """Run what ``request`` (a DoObjective goal or an ExecuteObjective request) asks for in the
        slot ``_reserve`` took; the caller frees the slot (``_release``)."""
        with self._lock:
            stop = self._stop = self._stop or StopRequest()
        outcome = self.run(request.objective_name,
                           [PortOverride(o.node, o.port, o.value) for o in request.port_overrides],
                           {e.key: e.value for e in request.blackboard_overrides}, stop, publish)
        _log.info("%s: %s%s", request.objective_name, outcome.status, f": {outcome.reason}" if outcome.reason else "")
        return outcome

    def _release(self) -> None:
        with self._lock:
            self._running, self._stop = None, None
            self._idle.set()

    def _on_goal(self, request: Any) -> GoalResponse:
        return GoalResponse.REJECT if self._reserve(request.objective_name) else GoalResponse.ACCEPT

    def _on_cancel(self, goal_handle: Any) -> CancelResponse:
        return CancelResponse.ACCEPT if self.cancel(CANCELLED) else CancelResponse.REJECT

    def cancel(self, cause: str) -> bool:
        """Halt the running Objective (True), or say nothing runs (False)."""
        with self._lock:
            if self._running is None:
                return False
            if self._stop is not None:
                self._stop.cancel(cause)
            else:  # accepted, not started yet: the run stops before its first tick
                self._stop = StopRequest()
                self._stop.cancel(cause)
            return True

    def _execute(self, goal_handle: Any) -> Any:
        """Run the goal's Objective and end the goal; the slot is freed only once the goal has
        ended, so ``close()`` (a SIGTERM) never leaves the graph under a goal it has not answered."""
        try:
            outcome = self._run_reserved(goal_handle.request, goal_handle.publish_feedback)
            if outcome.status == RunEnd.INTERRUPTED.value and goal_handle.is_cancel_requested:
                goal_handle.canceled()
            elif outcome.status in (RunEnd.SUCCESS.value, RunEnd.SKIPPED.value):
                goal_handle.succeed()
            else:
                goal_handle.abort()
        finally:
            self._goal_ended_at = time.monotonic()
            self._release()
        return DoObjective.Result(status=outcome.status, reason=outcome.reason, failing_node=outcome.failing_node,
                                  failing_location=outcome.failing_location,
                                  summary_json=json.dumps(outcome.summary, default=str))

    def run(self, name: str, port_overrides: list[PortOverride], blackboard: dict[str, str], stop: StopRequest,
            publish: Callable[[Any], None]) -> Outcome:
        """Run the Objective ``name`` to its end (or until ``stop``); bad requests end as ERROR."""
        _log.info("running '%s'", name)
        try:
            objective = self.library.find(name)
            entries = override_entries(objective, port_overrides, blackboard)
            options = replace(self.options.run, sets={**objective.defaults(), **self.options.run.sets, **entries})
            options.check()
        except ObjectiveError as err:
            return Outcome.error(str(err))
        context = make_context(options)
        try:
            loaded = load_tree(objective.file, self.registry, context, None, self.library.search_paths,
                               self.library.directory)
        except ObjectiveError as err:
            context.bus.close()
            return Outcome.error(str(err))
        except Exception as err:  # a bug in a node's class while loading: one paragraph, traceback in a file
            context.bus.close()
            return Outcome.error(str(describe_crash(err, None, write_traceback(err, options.log_dir),
                                                    consequence=f"'{name}' was not run")))
        observers: list[RunObserver] = [FeedbackObserver(publish)]
        if self.options.groot2 is not None:
            observers.append(self.options.groot2.observer())
        if self.guard is not None:
            self.guard.reset()
        try:
            return Outcome.of(run_loaded(loaded, context, options, observers, stop, self.guard))
        except ObjectiveError as err:  # e.g. no such world: nothing ran
            return Outcome.error(str(err))

    # -- services ----------------------------------------------------------------------------
    def _execute_service(self, request: Any, response: Any) -> Any:
        running = self._reserve(request.objective_name)
        if running is not None:
            response.success, response.message = False, f"'{running}' is running: cancel it first"
            return response
        try:
            self.library.find(request.objective_name)
        except ObjectiveError as err:
            self._release()
            response.success, response.message = False, str(err)
            return response
        threading.Thread(target=self._run_in_background, args=(request,),
                         name=f"objective {request.objective_name}", daemon=True).start()
        response.success, response.message = True, f"started '{request.objective_name}'"
        return response

    def _run_in_background(self, request: Any) -> None:
        """An ``/execute_objective`` run: nobody waits for its result (it is logged)."""
        try:
            self._run_reserved(request, lambda feedback: None)
        finally:
            self._release()

    def _cancel_service(self, request: Any, response: Any) -> Any:
        response.success = self.cancel(CANCELLED_BY_SERVICE)
        response.message = "cancelled" if response.success else "no Objective is running"
        return response

    def _list_service(self, request: Any, response: Any) -> Any:
        for objective in self.library.objectives():
            response.objectives.append(ObjectiveInfo(
                name=objective.name, file=objective.relative, description=objective.description,
                ports=[ObjectivePort(name=p.name, direction=p.direction, type=p.type, default_value=p.default)
                       for p in objective.ports],
                error=objective.error,
            ))
        with self._lock:
            response.running = self._running or ""
        return response

    # -- life ----------------------------------------------------------------------------------
    def close(self, timeout_s: float = 10.0) -> None:
        """Cancel the running Objective (its goal ends ABORTED: "the Objective server is shutting
        down ..."), wait for its halt (up to ``timeout_s``) and for its result to leave, then
        leave the graph."""
        self.cancel(SHUTDOWN)
        self._idle.wait(timeout_s)
        time.sleep(max(0.0, self._goal_ended_at + RESULT_GRACE_S - time.monotonic()))
        self._action.destroy()
        self.node.destroy_node()
        self.executor.shutdown(timeout_sec=1.0)
        try:
            self.context.try_shutdown()
        finally:
            self._spinner.join(timeout=2.0)
