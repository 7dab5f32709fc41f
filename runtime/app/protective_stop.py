"""The protective stop: one input on the run's bus that halts the running tree.

Every run listens on ``StopInputs.topic`` (``std_msgs/Bool``: ``true`` stops) and serves
``StopInputs.service`` (``std_srvs/Trigger``), both ``/protective_stop`` by default: on its own
bus (``objective run``, each ``eval`` episode; a ROS 2 node with ``--ros``), or, for the Objectives
the server runs, on the server's node. The runner asks ``ProtectiveStop.reason`` after the bus
delivered what is due and before the tree ticks; once it answers, the tree is not ticked again: it is halted (every RUNNING node's ``terminate``: controller goals cancelled, the
controllers stop the arm within their stop time) and the run ends FAILURE, "protective stop: ...".

The optional deadman: with ``StopInputs.deadman_topic`` set, while a node that needs a heartbeat
(``needs_heartbeat``: ExecutePolicy) is RUNNING, a ``std_msgs/Bool`` ``true`` must arrive on it at
least every ``deadman_period_s`` seconds of the run's clock (counted from when the node started
running); silence longer than that, or a ``false``, is a protective stop.

``objective eval`` runs its episodes in worker processes, on buses nobody outside can reach: its
own process listens (``runtime.app.stop_listener``) and forwards a stop through a ``SharedStop``,
which each episode's guard asks at every tick (``forwarded``).
"""
from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from typing import Any, Callable

from runtime.errors import ObjectiveError

_log = logging.getLogger("objective")

DEFAULT_STOP_NAME = "/protective_stop"
ROS_NAME = re.compile(r"/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")
"""A topic or service name ROS 2 accepts (absolute or relative; no substitutions)."""
PROTECTIVE_STOP = "protective stop"
"""The failure kind of a run the protective stop ended."""


@dataclass(frozen=True)
class StopInputs:
    """Where a run listens for a protective stop (an empty name: not listened on)."""

    topic: str = DEFAULT_STOP_NAME
    service: str = DEFAULT_STOP_NAME
    deadman_topic: str = ""
    deadman_period_s: float = 0.5

    def check(self) -> None:
        """ObjectiveError naming the option for a name ROS 2 would refuse or a period that is not positive."""
        for option, name in (("--protective-stop", self.topic), ("--protective-stop", self.service),
                             ("--deadman-topic", self.deadman_topic)):
            if name and not ROS_NAME.fullmatch(name):
                raise ObjectiveError(f"{option} {name!r} is not a ROS 2 name: words of letters, digits and '_' "
                                     "(not starting with a digit) between '/', such as /protective_stop")
        if not (self.deadman_period_s > 0 and math.isfinite(self.deadman_period_s)):
            raise ObjectiveError(f"--deadman-period must be a positive number of seconds, got {self.deadman_period_s}")


def needs_heartbeat(node: Any) -> bool:
    """Whether ``node`` drives the arm from outside the Objective (a policy): the deadman watches it."""
    return bool(getattr(type(node), "needs_heartbeat", False))


class ProtectiveStop:
    """Whether the stop inputs asked for a stop (``reason``). ``listen`` puts the inputs on a run's
    bus; the Objective server feeds ``on_stop``, ``on_trigger`` and ``on_heartbeat`` from its own
    node instead (``serve_on_node``), and ``reset``s it before each run. The callbacks may run on
    another thread. ``forwarded``: asked at every ``reason``, a stop another process heard (its
    reason, or None: ``SharedStop.reason``)."""

    def __init__(self, inputs: StopInputs, forwarded: Callable[[], str | None] | None = None) -> None:
        self.inputs = inputs
        self.forwarded = forwarded
        self.reset()

    def reset(self) -> None:
        """Forget a stop and the heartbeats: a new run starts."""
        self.engaged: str | None = None
        self.heartbeats = 0
        self._heartbeats_seen = 0
        self._heartbeat_at_s: float | None = None
        self._watched_since_s: float | None = None

    @property
    def watches_heartbeat(self) -> bool:
        """Whether ``reason`` asks whether a node that needs a heartbeat runs (a deadman topic is set)."""
        return bool(self.inputs.deadman_topic)

    def listen(self, bus: Any) -> None:
        """Subscribe to the topics and serve the service on ``bus`` (a service only where the bus serves)."""
        from std_msgs.msg import Bool  # the ROS interfaces, only once a run listens (a sourced ROS 2 or the [ros] extra)
        from std_srvs.srv import Trigger

        inputs = self.inputs
        if inputs.topic:
            bus.create_subscription(inputs.topic, Bool, self.on_stop)
        if inputs.service:
            if bus.serves:
                bus.create_service(inputs.service, Trigger, self.on_trigger)
            else:  # a run against a real robot's graph serves nothing (``RosBus(serves=False)``)
                _log.warning("protective stop: this run serves no services; stop it on the topic '%s'", inputs.topic)
        if inputs.deadman_topic:
            bus.create_subscription(inputs.deadman_topic, Bool, self.on_heartbeat)

    def serve_on_node(self, node: Any, group: Any = None) -> None:
        """The same inputs on an rclpy ``node`` of the caller's (the Objective server's, ``objective eval``'s)."""
        from std_msgs.msg import Bool
        from std_srvs.srv import Trigger

        inputs = self.inputs
        if inputs.topic:
            node.create_subscription(Bool, inputs.topic, self.on_stop, 10, callback_group=group)
        if inputs.service:
            node.create_service(Trigger, inputs.service, self.on_trigger, callback_group=group)
        if inputs.deadman_topic:
            node.create_subscription(Bool, inputs.deadman_topic, self.on_heartbeat, 10, callback_group=group)

    def on_stop(self, msg: Any) -> None:
        """A ``std_msgs/Bool`` on the stop topic: ``true`` stops."""
        if msg.data and self.engaged is None:
            self.engaged = f"'{self.inputs.topic}' is true"

    def on_trigger(self, request: Any, response: Any = None) -> Any:
        """A call of the ``std_srvs/Trigger`` service: stops, and says so."""
        from std_srvs.srv import Trigger

        if self.engaged is None:
            self.engaged = f"'{self.inputs.service}' was called"
        return Trigger.Response(success=True, message="protective stop: the run halts at its next tick")

    def on_heartbeat(self, msg: Any) -> None:
        """A ``std_msgs/Bool`` on the deadman topic: ``true`` is a heartbeat, ``false`` a release."""
        if msg.data:
            self.heartbeats += 1
        elif self.engaged is None:
            self.engaged = f"the deadman '{self.inputs.deadman_topic}' was released (false)"

    def reason(self, now_s: float, policy_running: bool) -> str | None:
        """Why the run must stop now, or None. ``now_s``: the run's clock (a heartbeat counts as
        arriving at the first check that sees it); ``policy_running``: a node that needs a
        heartbeat was RUNNING after the last tick."""
        if self.engaged is None and self.forwarded is not None:
            self.engaged = self.forwarded()
        if self.engaged is not None or not self.inputs.deadman_topic:
            return self.engaged
        if self.heartbeats != self._heartbeats_seen:
            self._heartbeats_seen, self._heartbeat_at_s = self.heartbeats, now_s
        if not policy_running:
            self._watched_since_s = None
            return None
        if self._watched_since_s is None:
            self._watched_since_s = now_s
        since = max(self._watched_since_s, self._heartbeat_at_s if self._heartbeat_at_s is not None else -math.inf)
        if now_s - since > self.inputs.deadman_period_s + 1e-9:
            self.engaged = (f"no heartbeat on the deadman '{self.inputs.deadman_topic}' for {now_s - since:.2f} s "
                            f"(period {self.inputs.deadman_period_s:g} s) while a policy ran")
        return self.engaged


STOP_REASON_BYTES = 1024


class SharedStop:
    """A protective stop one process heard, for the runs of the processes it started (``spawn``:
    pass it to them when they start): ``engage`` once there, ``reason`` at every tick here."""

    def __init__(self, context: Any) -> None:
        """``context``: the ``multiprocessing`` context the other processes are started with."""
        self._engaged = context.Event()
        self._reason = context.Array("c", STOP_REASON_BYTES)

    def engage(self, reason: str) -> None:
        if not self._engaged.is_set():
            self._reason.value = reason.encode()[:STOP_REASON_BYTES - 1]
            self._engaged.set()

    def reason(self) -> str | None:
        """Why the stop was engaged, or None while it is not."""
        return self._reason.value.decode(errors="replace") if self._engaged.is_set() else None
