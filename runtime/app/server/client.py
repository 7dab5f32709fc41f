"""``objective client``: drive an Objective server (``objective server DIR``) without a ``ros2`` install.

- ``objective client list``: every Objective of the server's library (``/list_objectives``) with
  its description, ports and load error, and the one running now.
- ``objective client start NAME [--override PORT=VALUE] [--set KEY=VALUE]``: a
  ``/do_objective`` goal; prints the running nodes as they change (the goal's feedback), then the
  line ``objective run`` ends with, and exits as ``objective run`` does (0, 1, 2, 130). SIGINT or
  SIGTERM cancels the goal: the server halts the tree (goals cancelled, the arm stopped).
- ``objective client cancel``: ``/cancel_objective``, whoever started the run.

The client is a node of its own (``/objective_client``) on the same ROS domain as the server
(``ROS_DOMAIN_ID``; ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless the environment says
otherwise).
"""
from __future__ import annotations

import builtins  # the class's method ``list`` hides the builtin in its annotations
import json
import os
import time
from dataclasses import dataclass
from typing import Any, Callable

import rclpy
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import Trigger

from objective_server_msgs.action import DoObjective
from objective_server_msgs.msg import KeyValue
from objective_server_msgs.msg import PortOverride as PortOverrideMsg
from objective_server_msgs.srv import ListObjectives
from runtime.errors import ObjectiveError
from runtime.io.interrupt import StopRequest
from runtime.app.objective_library import PortOverride
from runtime.app.runner import RunResult
from runtime.io.ros.bus import spin_on_thread

from .objective_server import ACTION_NAME, CANCEL_SERVICE, LIST_SERVICE

CLIENT_NODE_NAME = "objective_client"
POLL_S = 0.02
CANCEL_WAIT_S = 30.0
"""How long a cancelled goal's result is waited for: the server halts the tree and stops the arm first."""


class ServerUnavailable(ObjectiveError):
    """No Objective server answered within the client's wait."""


def result_of(message: Any) -> RunResult:
    """A DoObjective result as the ``RunResult`` ``objective run`` would have printed."""
    summary = json.loads(message.summary_json or "{}")
    return RunResult(
        status=message.status, failing_node=message.failing_node or None, reason=message.reason,
        sim_seconds=float(summary.get("sim_seconds", 0.0)), wall_seconds=float(summary.get("wall_seconds", 0.0)),
        ticks=int(summary.get("ticks", 0)), blackboard=summary.get("blackboard", {}),
        failing_location=message.failing_location or None, failure_kind=summary.get("failure_kind"),
        stopped_by=summary.get("stopped_by"),
    )


def feedback_line(feedback: Any) -> str:
    """One feedback message as the client prints it: the running nodes at the run's clock."""
    running = ", ".join(feedback.running_nodes) or "nothing"
    return f"{feedback.clock_s:8.2f} s  running: {running}"


@dataclass
class StartOutcome:
    result: RunResult
    goal_status: int
    """``action_msgs/GoalStatus`` of the goal (SUCCEEDED, ABORTED, CANCELED)."""


class ObjectiveClient:
    """A node with the Objective server's action and services, spun on a thread of its own."""

    def __init__(self, wait_s: float = 10.0, node_name: str = CLIENT_NODE_NAME) -> None:
        os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        self.wait_s = wait_s
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(node_name, context=self.context)
        self.action = ActionClient(self.node, DoObjective, ACTION_NAME)
        self.lister = self.node.create_client(ListObjectives, LIST_SERVICE)
        self.canceller = self.node.create_client(Trigger, CANCEL_SERVICE)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._spinner = spin_on_thread(self.executor, node_name)

    def _unavailable(self, name: str) -> ServerUnavailable:
        return ServerUnavailable(
            f"no Objective server answered on {name} within {self.wait_s:g} s (start one with `objective server DIR`, "
            f"on the same ROS_DOMAIN_ID: {os.environ.get('ROS_DOMAIN_ID', '0')} here)")

    def _call(self, client: Any, name: str, request: Any) -> Any:
        if not client.wait_for_service(timeout_sec=self.wait_s):
            raise self._unavailable(name)
        return wait(client.call_async(request), self.wait_s, f"the answer of {name}")

    def list(self) -> Any:
        """The ``/list_objectives`` response."""
        return self._call(self.lister, LIST_SERVICE, ListObjectives.Request())

    def cancel(self) -> Any:
        """The ``/cancel_objective`` response (``success`` false: nothing was running)."""
        return self._call(self.canceller, CANCEL_SERVICE, Trigger.Request())

    def start(self, name: str, overrides: builtins.list[PortOverride], blackboard: dict[str, str],
              on_feedback: Callable[[Any], None], stop: StopRequest) -> StartOutcome:
        """Run ``name`` on the server to its end; ``stop`` (a signal) cancels the goal."""
        if not self.action.wait_for_server(timeout_sec=self.wait_s):
            raise self._unavailable(ACTION_NAME)
        goal = DoObjective.Goal(objective_name=name)
        goal.port_overrides = [PortOverrideMsg(node=o.node, port=o.port, value=o.value) for o in overrides]
        goal.blackboard_overrides = [KeyValue(key=k, value=v) for k, v in blackboard.items()]
        handle = wait(self.action.send_goal_async(goal, feedback_callback=lambda m: on_feedback(m.feedback)),
                      self.wait_s, f"the answer of {ACTION_NAME}")
        if not handle.accepted:
            running = self.list().running
            raise ObjectiveError(f"the server refused '{name}': '{running or 'another Objective'}' is running "
                                 "(one at a time: `objective client cancel` stops it)")
        result = handle.get_result_async()
        cancelled_at: float | None = None
        while not result.done():
            if stop.requested and cancelled_at is None:
                handle.cancel_goal_async()
                cancelled_at = time.monotonic()
            if cancelled_at is not None and time.monotonic() - cancelled_at > CANCEL_WAIT_S:
                raise ObjectiveError(f"'{name}' was cancelled, but the server sent no result within {CANCEL_WAIT_S:g} s")
            time.sleep(POLL_S)
        response = result.result()
        return StartOutcome(result_of(response.result), response.status)

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()
        self._spinner.join(timeout=2.0)


def wait(future: Any, timeout_s: float, what: str) -> Any:
    """``future``'s result, or ServerUnavailable after ``timeout_s`` of wall time."""
    deadline = time.monotonic() + timeout_s
    while not future.done():
        if time.monotonic() > deadline:
            raise ServerUnavailable(f"no answer within {timeout_s:g} s waiting for {what}")
        time.sleep(POLL_S)
    return future.result()


def list_lines(response: Any) -> list[str]:
    """``objective client list``'s output: one block per Objective, then what runs."""
    lines = []
    for objective in response.objectives:
        lines.append(f"{objective.name}  ({objective.file})" + (f": {objective.description}" if objective.description else ""))
        for port in objective.ports:
            default = f" = {port.default_value}" if port.default_value else ""
            lines.append(f"    {port.direction} {port.name} ({port.type or 'any'}){default}")
        if objective.error:
            lines.append(f"    error: {objective.error}")
    lines.append(f"running: {response.running or 'nothing'}")
    return lines

