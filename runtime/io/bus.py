"""The bus: services, actions and topics addressed by ROS names, carrying ROS 2 message classes.

Behaviors see only this API, so the same Objective runs on the simulated cell (``InProcessBus``,
direct calls on the sim clock) or on a real ROS 2 graph (``runtime.io.ros.RosBus``, rclpy). The API
mirrors rclpy's so the ROS binding stays thin, and it never blocks: behaviors are ticked at
100 Hz and poll futures (``done()``) instead of waiting.

In-process service calls run the handler at once, but the answer is delivered on the clock
after a latency given by a ``LatencyModel`` (by default the handler's measured wall time), so a
slow policy is exercised deterministically while the robot keeps moving. On a bus paced by the
wall clock (``InProcessBus(paced=True)``, ``--realtime``), a service created with
``own_thread=True`` (a policy) runs its handler on a ``ServiceWorker`` instead, so the tick
never waits for it; its answer is delivered in the first ``spin_once`` after both the handler
finished and the latency model's delay since the call passed.

On a simulated clock such a handler also runs on its ``ServiceWorker``, and the call waits for
it with the clock standing still (as if it ran at the call: deterministic), but for at most the
caller's ``timeout_s`` of wall time: its wall time is its latency, so a handler still running
then could not be answered in time anyway. The call then leaves its future unanswered (the
caller's own timeout ends the wait on the clock) and the handler's late answer is dropped. The
wait also ends when ``stop_waiting_when``'s condition holds (a SIGINT or SIGTERM asked the run
to stop), so a hung policy never holds a run.
"""
from __future__ import annotations

import collections
import itertools
import logging
import math
import random
import threading
import time
import uuid
from dataclasses import dataclass
from typing import Any, Callable, Generic, Protocol, TypeVar, cast, runtime_checkable

from .clock import Clock
from runtime.errors import OptionError
from .interrupt import describe_error, raised_by_code
from .service_worker import ServiceWorker

T = TypeVar("T")

WAIT_SLICE_S = 0.05
"""How often a call waiting for its handler on a simulated clock looks whether to stop waiting."""

log = logging.getLogger("objective")


# --------------------------------------------------------------------------------------------
# Futures
# --------------------------------------------------------------------------------------------
class Future(Generic[T]):
    """A result that becomes available later (on the clock, for the in-process bus)."""

    def __init__(self, clock: Clock | None = None, ready_at: float = 0.0) -> None:
        self._clock = clock
        self._ready_at = ready_at
        self._has_value = False
        self._value: T | None = None
        self._exception: BaseException | None = None
        self._callbacks: list[Callable[[Future[T]], None]] = []
        self._cancelled = False

    # -- producer side ---
    def set_result(self, value: T) -> None:
        self._value, self._has_value = value, True
        self._fire_if_done()

    def set_exception(self, exc: BaseException) -> None:
        self._exception, self._has_value = exc, True
        self._fire_if_done()

    def _fire_if_done(self) -> None:
        if self.done():
            callbacks, self._callbacks = self._callbacks, []
            for cb in callbacks:
                cb(self)

    # -- consumer side ---
    @property
    def ready_at(self) -> float:
        return self._ready_at

    def done(self) -> bool:
        if self._cancelled:
            return True
        if not self._has_value:
            return False
        return self._clock is None or self._clock.now() >= self._ready_at - 1e-12

    def cancelled(self) -> bool:
        return self._cancelled

    def cancel(self) -> None:
        """Stop caring about the answer (it is dropped when it arrives)."""
        self._cancelled = True
        self._callbacks.clear()

    def result(self) -> T:
        if not self.done():
            raise RuntimeError("future is not done yet")
        if self._exception is not None:
            raise self._exception
        return cast(T, self._value)  # set with _has_value (a T, which may be None itself)

    def exception(self) -> BaseException | None:
        return self._exception if self.done() else None

    def add_done_callback(self, cb: Callable[[Future[T]], None]) -> None:
        if self.done():
            cb(self)
        else:
            self._callbacks.append(cb)


# --------------------------------------------------------------------------------------------
# The interface behaviors code against
# --------------------------------------------------------------------------------------------
class ServiceClient(Protocol):
    name: str

    def service_is_ready(self) -> bool: ...

    def call_async(self, request: Any, timeout_s: float | None = None) -> Future[Any]:
        """Call the service; ``timeout_s``: the caller gives up after that long (on the clock),
        so an in-process handler on a simulated clock is waited for that long at most (wall)."""
        ...


class Publisher(Protocol):
    name: str

    def publish(self, msg: Any) -> None: ...


class Subscription(Protocol):
    name: str
    count: int
    received_at: float | None
    """Runtime clock seconds when ``latest`` arrived (None before the first message): its age is
    ``clock.now() - received_at``, whatever clock its publisher stamped it with."""

    @property
    def latest(self) -> Any: ...

    def has_publishers(self) -> bool: ...


class ServerGoalHandle(Protocol):
    goal_id: str
    request: Any

    @property
    def is_active(self) -> bool: ...

    @property
    def is_cancel_requested(self) -> bool: ...

    def publish_feedback(self, feedback: Any) -> None: ...

    def succeed(self, result: Any) -> None: ...

    def abort(self, result: Any) -> None: ...

    def canceled(self, result: Any) -> None: ...


class ClientGoalHandle(Protocol):
    accepted: bool
    goal_id: str

    def get_result_async(self) -> Future[ActionResult]: ...

    def cancel_goal_async(self) -> Future[bool]: ...


class ActionClient(Protocol):
    name: str

    def server_is_ready(self) -> bool: ...

    def send_goal_async(
        self, goal: Any, feedback_callback: Callable[[Any], None] | None = None
    ) -> Future[ClientGoalHandle]: ...


@runtime_checkable
class Bus(Protocol):
    """What behaviors and worlds use to talk: every bus has all of it (``InProcessBus``,
    ``runtime.io.ros.RosBus``, ``runtime.io.ros.run.HostingBus``, ``recording.bus.RecordingBus``;
    ``tests/test_bus_protocol.py`` holds each to it). What only some buses can do is a protocol
    of its own below (``ServedListing``, ``SimulatedLatency``, ``InterruptibleWaits``,
    ``RecordsTopics``), found with ``capability``."""

    @property
    def clock(self) -> Clock:
        """The runtime clock: it stamps ``ready_at`` of futures and ``received_at`` of messages."""
        ...

    produces_on_read: bool
    """True when a lazy topic's message is produced as a subscriber reads it (in process); False
    when topics are pushed at a rate to readers elsewhere (ROS 2), so a frame costs whether or
    not it is read."""
    serves: bool
    """False when the bus may serve nothing (a run against a real robot's graph, whose drivers
    serve: ``RosBus(serves=False)``); ``create_service`` and ``create_action_server`` then raise."""

    def create_service(self, name: str, srv_type: type, handler: Callable[[Any], Any], own_thread: bool = False) -> Any:
        """Serve ``name`` with ``handler(request) -> response``. ``own_thread``: a slow handler
        (a policy's inference) that must never run on the thread that ticks the tree; it runs on
        a ``ServiceWorker`` of its own, one request at a time (on a simulated clock the call
        waits for it, see the module's docstring)."""
        ...

    def destroy_service(self, name: str) -> None:
        """Stop serving ``name`` (nothing when it is not served)."""
        ...

    def create_client(self, name: str, srv_type: type) -> ServiceClient:
        """A client of service ``name``."""
        ...

    def create_publisher(self, name: str, msg_type: type, reliable: bool = True) -> Publisher:
        """A publisher on topic ``name``; ``reliable``: ROS's reliable QoS, else best effort."""
        ...

    def create_lazy_publisher(
        self,
        name: str,
        msg_type: type,
        produce: Callable[[], Any],
        reliable: bool = True,
        rate_hz: float = 30.0,
    ) -> None:
        """Serve topic ``name`` with ``produce()`` (None: nothing this time): when a subscriber
        reads it where ``produces_on_read``, else at ``rate_hz`` while the topic has subscribers."""
        ...

    def destroy_publisher(self, name: str) -> None:
        """Stop publishing on ``name``: its publishers and its lazy publisher."""
        ...

    def create_subscription(
        self,
        name: str,
        msg_type: type,
        callback: Callable[[Any], None] | None = None,
        reliable: bool = True,
    ) -> Subscription:
        """A subscription to topic ``name``: ``callback(msg)`` on each message (in ``spin_once``),
        the newest in ``latest``."""
        ...

    def destroy_subscription(self, sub: Subscription) -> None:
        """Stop delivering to ``sub`` (nothing when it is not subscribed)."""
        ...

    def create_action_server(
        self,
        name: str,
        action_type: type,
        on_goal: Callable[[ServerGoalHandle], bool],
        on_cancel: Callable[[ServerGoalHandle], bool] | None = None,
    ) -> Any:
        """Serve action ``name``: ``on_goal(handle)`` accepts a goal (True) or rejects it;
        ``on_cancel(handle)`` accepts a cancel request (None: every one is accepted)."""
        ...

    def destroy_action_server(self, name: str) -> None:
        """Stop serving action ``name`` (nothing when it is not served)."""
        ...

    def create_action_client(self, name: str, action_type: type) -> ActionClient:
        """A client of action ``name``."""
        ...

    def action_types(self, name: str) -> list[str]:
        """The types served under action ``name``, as ``pkg/action/Type`` (empty: not served)."""
        ...

    def spin_once(self) -> None:
        """Deliver what is due now (callbacks of matured futures, queued messages)."""
        ...

    def close(self) -> None:
        """Stop serving and delivering; release what the bus holds (threads, nodes)."""
        ...


# --------------------------------------------------------------------------------------------
# What only some buses can do
# --------------------------------------------------------------------------------------------
@runtime_checkable
class ServedListing(Protocol):
    """A bus that knows every service, action and topic served on it, and can call a service at
    once: the in-process bus, where everything is served in this process (on ROS 2 the graph's
    servers live elsewhere)."""

    def served(self) -> dict[str, type]:
        """Every service served on this bus now, with its type."""
        ...

    def action_servers(self) -> dict[str, type]:
        """Every action served on this bus now, with its type."""
        ...

    def published(self) -> dict[str, type]:
        """Every topic published on this bus now, with its message type."""
        ...

    def call_now(self, name: str, request: Any) -> Any:
        """The answer of service ``name`` to ``request``, at once and without a latency."""
        ...


@runtime_checkable
class SimulatedLatency(Protocol):
    """A bus whose service answers arrive after a modelled latency (the in-process bus)."""

    default_latency: LatencyModel
    """The latency of every service without a model of its own."""

    def set_latency(self, service_name: str, model: LatencyModel) -> None:
        """Answer ``service_name`` after ``model``'s latency."""
        ...

    def latency_for(self, service_name: str) -> LatencyModel:
        """The latency model of ``service_name``."""
        ...


@runtime_checkable
class InterruptibleWaits(Protocol):
    """A bus whose service calls may wait for their handler (the in-process bus on a simulated
    clock), and stop waiting when told to."""

    def stop_waiting_when(self, condition: Callable[[], bool]) -> None:
        """A call waiting for its handler gives up as soon as ``condition()`` holds."""
        ...


@runtime_checkable
class RecordsTopics(Protocol):
    """A bus that records its traffic (``recording.bus.RecordingBus``)."""

    def record_topic(self, name: str, msg_type: type, max_hz: float | None = None) -> None:
        """Record every message on ``name`` (at most ``max_hz`` per second of clock time)."""
        ...


@runtime_checkable
class BusWrapper(Protocol):
    """A bus that forwards to another (``recording.bus.RecordingBus``): what only some buses can
    do is looked for in ``inner`` too (``capability``)."""

    inner: Bus


C = TypeVar("C")


def capability(bus: Bus, kind: type[C]) -> C | None:
    """``bus`` as a ``kind`` (one of the protocols above), or the bus it wraps
    (``BusWrapper.inner``, as deep as it goes) when that one is; None when none of them is."""
    found: Any = bus
    while not isinstance(found, kind):
        if not isinstance(found, BusWrapper):
            return None
        found = found.inner
    return found


def interface_type_name(interface: type, kind: str) -> str:
    """ROS's name of a generated interface class: ``pkg/<kind>/Type`` (e.g. ``control_msgs/action/GripperCommand``)."""
    return f"{interface.__module__.split('.')[0]}/{kind}/{interface.__name__}"


# Action goal states, as in action_msgs/GoalStatus.
STATUS_ACCEPTED, STATUS_EXECUTING, STATUS_CANCELING = 1, 2, 3
STATUS_SUCCEEDED, STATUS_CANCELED, STATUS_ABORTED = 4, 5, 6


@dataclass
class ActionResult:
    """What ``get_result_async`` yields: the terminal goal status and the result message."""

    status: int
    result: Any


# --------------------------------------------------------------------------------------------
# Latency models for in-process service calls
# --------------------------------------------------------------------------------------------
class LatencyModel(Protocol):
    def delay(self, measured_wall_s: float) -> float:
        """Seconds of clock time between the call and its answer."""
        ...


class MeasuredLatency:
    """Deliver after exactly the wall time the handler took (the default)."""

    def delay(self, measured_wall_s: float) -> float:
        return measured_wall_s

    def __repr__(self) -> str:
        return "measured"


@dataclass
class FixedLatency:
    seconds: float

    def delay(self, measured_wall_s: float) -> float:
        return self.seconds


class LognormalLatency:
    """Heavy-tailed latency with the given mean and standard deviation (seconds), seeded."""

    def __init__(self, mean: float, sd: float, seed: int = 0) -> None:
        if not (0 < mean < math.inf and 0 <= sd < math.inf):
            raise ValueError(f"lognormal latency needs mean > 0 and sd >= 0, got mean={mean}, sd={sd}")
        self.mean, self.sd = mean, sd
        sigma2 = math.log(1.0 + (sd / mean) ** 2)
        self._mu = math.log(mean) - sigma2 / 2.0
        self._sigma = math.sqrt(sigma2)
        self._rng = random.Random(seed)

    def delay(self, measured_wall_s: float) -> float:
        return self._rng.lognormvariate(self._mu, self._sigma)

    def __repr__(self) -> str:
        return f"lognormal:{self.mean},{self.sd}"


class TraceLatency:
    """Latencies replayed from a trace: call ``i`` (the warmup is call 0) takes ``seconds[i]``,
    and every call after the last takes the last value."""

    def __init__(self, seconds: list[float], source: str = "trace") -> None:
        if not seconds:
            raise ValueError(f"{source}: the trace has no latencies")
        self.seconds, self.source, self.calls = list(seconds), source, 0

    def delay(self, measured_wall_s: float) -> float:
        index, self.calls = min(self.calls, len(self.seconds) - 1), self.calls + 1
        return self.seconds[index]

    def __repr__(self) -> str:
        return f"trace:{self.source}"


MAX_TRACE_CHARS = 10_000_000
"""The most a latency trace holds (a million calls' latencies take about 8 MB)."""


def read_latency_trace(path: str) -> TraceLatency:
    """A trace file: one latency in seconds per line (finite, not negative); blank lines and
    ``#`` comments are skipped; at most ``MAX_TRACE_CHARS`` are read (``/dev/zero`` is refused).
    Raises OptionError naming ``file:line`` and what is wrong."""
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read(MAX_TRACE_CHARS + 1)
    except (OSError, UnicodeDecodeError) as err:
        reason = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
        raise OptionError(f"latency trace '{path}' cannot be read: {reason}") from None
    if len(text) > MAX_TRACE_CHARS:
        raise OptionError(f"latency trace '{path}' holds more than {MAX_TRACE_CHARS:,} characters "
                          "(one latency in seconds per line)")
    lines = text.splitlines()
    seconds = []
    for number, line in enumerate(lines, 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        try:
            value = float(text)
        except ValueError:
            raise OptionError(f"{path}:{number}: '{text}' is not a number of seconds") from None
        if not math.isfinite(value) or value < 0:
            raise OptionError(f"{path}:{number}: a latency must be a finite number of seconds >= 0, got '{text}'")
        seconds.append(value)
    if not seconds:
        raise OptionError(f"latency trace '{path}' is empty: it needs one latency in seconds per line")
    return TraceLatency(seconds, path)


DEFAULT_POLICY_LATENCY = "0.1"
"""The policy latency of a headless run and of an evaluation's episodes when none is given: a
fixed 0.1 s, so a seed gives the same run on any machine (``measured`` follows the wall clock)."""


def parse_latency(spec: str, seed: int = 0) -> LatencyModel:
    """``measured``, ``0.3`` (fixed seconds), ``lognormal:MEAN,SD`` or ``trace:FILE``."""
    if spec.strip().lower().startswith("trace:"):
        return read_latency_trace(spec.strip()[len("trace:"):])
    text = spec.strip().lower()
    if text == "measured":
        return MeasuredLatency()
    if text.startswith("lognormal:"):
        try:
            mean, sd = (float(v) for v in text.split(":", 1)[1].split(","))
        except ValueError:
            raise OptionError(f"latency '{spec}': expected lognormal:MEAN,SD in seconds, e.g. lognormal:0.3,0.1") from None
        return LognormalLatency(mean, sd, seed)
    try:
        seconds = float(text)
    except ValueError:
        raise OptionError(f"latency '{spec}': expected seconds (e.g. 0.3), 'measured', lognormal:MEAN,SD or trace:FILE") from None
    if not seconds >= 0:
        raise OptionError(f"latency '{spec}': must be a number of seconds >= 0")
    return FixedLatency(seconds)


# --------------------------------------------------------------------------------------------
# The in-process bus
# --------------------------------------------------------------------------------------------
class _InProcessClient:
    def __init__(self, bus: InProcessBus, name: str, srv_type: type) -> None:
        self.bus, self.name, self.srv_type = bus, name, srv_type

    def service_is_ready(self) -> bool:
        return self.name in self.bus._services

    def call_async(self, request: Any, timeout_s: float | None = None) -> Future[Any]:
        entry = self.bus._services.get(self.name)
        if entry is None:
            raise RuntimeError(f"service '{self.name}' is not available")
        srv_type, handler = entry
        future: Future[Any] = Future(self.bus.clock)
        called_s = self.bus.clock.now()
        worker = self.bus._workers.get(self.name)

        def run() -> _Answer:
            return _run_handler(self.name, handler, request, future, called_s, self.bus.clock)

        if worker is None:
            self.bus._deliver(run())
        elif self.bus.paced:  # answered on the worker's thread, delivered in a later spin_once
            worker.submit(lambda: self.bus._answered.append(run()))
        else:
            self.bus._wait_for(worker, run, timeout_s)
        return future


@dataclass
class _Answer:
    """A handler's outcome, waiting to be delivered to the caller's future."""

    service_name: str
    future: Future[Any]
    called_s: float
    finished_s: float
    wall_s: float
    response: Any
    error: BaseException | None


def _run_handler(name: str, handler: Callable[[Any], Any], request: Any, future: Future[Any], called_s: float,
                 clock: Clock) -> _Answer:
    """Run ``handler`` on ``request``, timing it; an exception is the answer (the caller sees it
    through the future), a ``sys.exit`` or ``KeyboardInterrupt`` of the handler's own too
    (``raised_by_code``)."""
    start = time.perf_counter()
    try:
        response = handler(request)
        error: BaseException | None = None
    except BaseException as exc:
        if not raised_by_code(exc):
            raise
        response = None
        error = exc if isinstance(exc, Exception) else RuntimeError(f"its handler raised {describe_error(exc)}")
    wall = time.perf_counter() - start
    return _Answer(name, future, called_s, clock.now(), wall, response, error)


class _InProcessPublisher:
    def __init__(self, bus: InProcessBus, name: str, msg_type: type, reliable: bool) -> None:
        self.bus, self.name, self.msg_type, self.reliable = bus, name, msg_type, reliable

    def publish(self, msg: Any) -> None:
        if not isinstance(msg, self.msg_type):
            raise TypeError(f"topic '{self.name}' carries {self.msg_type.__name__}, got {type(msg).__name__}")
        subs = self.bus._subscriptions.get(self.name)
        if not subs:
            return
        now_s = self.bus.clock.now()
        for sub in list(subs):  # a callback may subscribe or unsubscribe
            if _compatible(self.reliable, sub.reliable):
                sub._deliver(msg, now_s)


class _LazyTopic:
    """A topic whose message is produced only when a subscriber reads it (camera frames)."""

    def __init__(self, name: str, msg_type: type, produce: Callable[[], Any], reliable: bool) -> None:
        self.name, self.msg_type, self.produce, self.reliable = name, msg_type, produce, reliable


def _compatible(publisher_reliable: bool, subscriber_reliable: bool) -> bool:
    """ROS QoS: a reliable subscription never connects to a best-effort publisher."""
    return publisher_reliable or not subscriber_reliable


class _InProcessSubscription:
    def __init__(
        self,
        bus: InProcessBus,
        name: str,
        msg_type: type,
        callback: Callable[[Any], None] | None,
        reliable: bool,
    ) -> None:
        self.bus, self.name, self.msg_type = bus, name, msg_type
        self.callback, self.reliable = callback, reliable
        self._latest: Any = None
        self.count = 0
        self.received_at: float | None = None

    def _deliver(self, msg: Any, now_s: float) -> None:
        self._latest = msg
        self.received_at = now_s
        self.count += 1
        if self.callback is not None:
            self.callback(msg)

    @property
    def latest(self) -> Any:
        lazy = self.bus._lazy.get(self.name)
        if lazy is not None and _compatible(lazy.reliable, self.reliable):
            msg = lazy.produce()
            if msg is not None:
                self._latest = msg
                self.received_at = self.bus.clock.now()
                self.count += 1
        return self._latest

    def has_publishers(self) -> bool:
        lazy = self.bus._lazy.get(self.name)
        if lazy is not None and _compatible(lazy.reliable, self.reliable):
            return True
        return any(_compatible(p.reliable, self.reliable) for p in self.bus._publishers.get(self.name, []))


class _InProcessServerGoal:
    def __init__(self, server: _InProcessActionServer, request: Any) -> None:
        self.server = server
        self.request = request
        self.goal_id = uuid.uuid4().hex
        self.status = STATUS_ACCEPTED
        self.result_future: Future[ActionResult] = Future()
        self.feedback_callback: Callable[[Any], None] | None = None
        self.is_cancel_requested = False
        """Whether the client asked to cancel the goal (a plain attribute: the simulated
        controllers read it at every control step)."""

    @property
    def is_active(self) -> bool:
        return self.status in (STATUS_ACCEPTED, STATUS_EXECUTING, STATUS_CANCELING)

    def publish_feedback(self, feedback: Any) -> None:
        if self.feedback_callback is not None and self.is_active:
            self.feedback_callback(feedback)

    def _finish(self, status: int, result: Any) -> None:
        if not self.is_active:
            raise RuntimeError(f"goal {self.goal_id[:8]} on '{self.server.name}' has already finished")
        self.status = status
        self.result_future.set_result(ActionResult(status, result))

    def succeed(self, result: Any) -> None:
        self._finish(STATUS_SUCCEEDED, result)

    def abort(self, result: Any) -> None:
        self._finish(STATUS_ABORTED, result)

    def canceled(self, result: Any) -> None:
        self._finish(STATUS_CANCELED, result)


class _InProcessClientGoal:
    def __init__(self, server_goal: _InProcessServerGoal | None, accepted: bool) -> None:
        self._server_goal = server_goal
        self.accepted = accepted
        self.goal_id = server_goal.goal_id if server_goal else ""

    def get_result_async(self) -> Future[ActionResult]:
        if self._server_goal is None:
            raise RuntimeError("the goal was rejected; it has no result")
        return self._server_goal.result_future

    def cancel_goal_async(self) -> Future[bool]:
        future: Future[bool] = Future()
        goal = self._server_goal
        if goal is None or not goal.is_active:
            future.set_result(False)
            return future
        goal.is_cancel_requested = True
        on_cancel = goal.server.on_cancel
        accepted = bool(on_cancel(goal)) if on_cancel is not None else True
        if accepted and goal.is_active and goal.status != STATUS_CANCELING:
            goal.status = STATUS_CANCELING
        future.set_result(accepted)
        return future


class _InProcessActionServer:
    def __init__(
        self,
        name: str,
        action_type: type,
        on_goal: Callable[[Any], bool],
        on_cancel: Callable[[Any], bool] | None,
    ) -> None:
        self.name, self.action_type = name, action_type
        self.on_goal, self.on_cancel = on_goal, on_cancel


class _InProcessActionClient:
    def __init__(self, bus: InProcessBus, name: str, action_type: type) -> None:
        self.bus, self.name, self.action_type = bus, name, action_type

    def server_is_ready(self) -> bool:
        return self.name in self.bus._action_servers

    def send_goal_async(
        self, goal: Any, feedback_callback: Callable[[Any], None] | None = None
    ) -> Future[ClientGoalHandle]:
        server = self.bus._action_servers.get(self.name)
        if server is None:
            raise RuntimeError(f"action server '{self.name}' is not available")
        expected: type = getattr(server.action_type, "Goal")  # the action class's goal message class
        if not isinstance(goal, expected):
            raise TypeError(f"action '{self.name}' takes {expected.__name__}, got {type(goal).__name__}")
        server_goal = _InProcessServerGoal(server, goal)
        server_goal.feedback_callback = feedback_callback
        accepted = bool(server.on_goal(server_goal))
        if accepted and server_goal.status == STATUS_ACCEPTED:
            server_goal.status = STATUS_EXECUTING
        future: Future[ClientGoalHandle] = Future(self.bus.clock, self.bus.clock.now())  # accepted at once
        future.set_result(_InProcessClientGoal(server_goal if accepted else None, accepted))
        return future


class InProcessBus:
    """Everything in one process, on one clock. Deterministic given the latency models. A
    ``Bus``, and a ``ServedListing``, ``SimulatedLatency`` and ``InterruptibleWaits`` besides."""

    clock: Clock
    produces_on_read = True
    serves = True

    def __init__(self, clock: Clock, default_latency: LatencyModel | None = None, paced: bool = False) -> None:
        self.clock = clock
        self.paced = paced
        """The clock follows the wall (``--realtime``): ``own_thread`` services answer from a
        ``ServiceWorker``. On a simulated clock every handler runs at the call (deterministic)."""
        self.default_latency: LatencyModel = default_latency or MeasuredLatency()
        self._latency: dict[str, LatencyModel] = {}
        self._services: dict[str, tuple[type, Callable[[Any], Any]]] = {}
        self._publishers: dict[str, list[_InProcessPublisher]] = {}
        self._subscriptions: dict[str, list[_InProcessSubscription]] = {}
        self._lazy: dict[str, _LazyTopic] = {}
        self._action_servers: dict[str, _InProcessActionServer] = {}
        self._pending: list[Future[Any]] = []
        self._workers: dict[str, ServiceWorker] = {}
        self._answered: collections.deque[_Answer] = collections.deque()
        """Answers the workers finished, for ``spin_once`` to deliver on the owner's thread."""
        self._ids = itertools.count()
        self._stop_waiting: Callable[[], bool] = lambda: False

    def stop_waiting_when(self, condition: Callable[[], bool]) -> None:
        """A call waiting for its handler on a simulated clock gives up as soon as ``condition()``
        holds (the run was asked to stop), leaving its future unanswered."""
        self._stop_waiting = condition

    # -- configuration ---
    def set_latency(self, service_name: str, model: LatencyModel) -> None:
        self._latency[service_name] = model

    def latency_for(self, service_name: str) -> LatencyModel:
        return self._latency.get(service_name, self.default_latency)

    # -- services ---
    def create_service(self, name: str, srv_type: type, handler: Callable[[Any], Any], own_thread: bool = False) -> Any:
        if name in self._services:
            raise ValueError(f"service '{name}' is already served")
        self._services[name] = (srv_type, handler)
        if own_thread:
            self._workers[name] = ServiceWorker(name)
        return name

    def destroy_service(self, name: str) -> None:
        self._services.pop(name, None)
        worker = self._workers.pop(name, None)
        if worker is not None:
            worker.close()

    def create_client(self, name: str, srv_type: type) -> ServiceClient:
        return _InProcessClient(self, name, srv_type)

    def served(self) -> dict[str, type]:
        """Every service served on this bus now, with its type."""
        return {name: srv_type for name, (srv_type, _) in self._services.items()}

    def call_now(self, name: str, request: Any) -> Any:
        """The answer of service ``name`` to ``request``, at once and without a latency: for
        looking at the world before the clock starts (``runtime.app.world_check``)."""
        return self._services[name][1](request)

    # -- topics ---
    def published(self) -> dict[str, type]:
        """Every topic published on this bus now, with its message type."""
        topics = {name: pubs[0].msg_type for name, pubs in self._publishers.items() if pubs}
        return {**topics, **{name: lazy.msg_type for name, lazy in self._lazy.items()}}

    def create_publisher(self, name: str, msg_type: type, reliable: bool = True) -> Publisher:
        pub = _InProcessPublisher(self, name, msg_type, reliable)
        self._publishers.setdefault(name, []).append(pub)
        return pub

    def create_lazy_publisher(
        self,
        name: str,
        msg_type: type,
        produce: Callable[[], Any],
        reliable: bool = True,
        rate_hz: float = 30.0,
    ) -> None:
        """Serve ``name`` by calling ``produce()`` whenever a subscriber reads ``latest``.

        ``rate_hz`` is for ``RosBus`` (which publishes from a timer); here frames are produced
        on read, so it is ignored.
        """
        self._lazy[name] = _LazyTopic(name, msg_type, produce, reliable)

    def destroy_publisher(self, name: str) -> None:
        self._publishers.pop(name, None)
        self._lazy.pop(name, None)

    def create_subscription(
        self,
        name: str,
        msg_type: type,
        callback: Callable[[Any], None] | None = None,
        reliable: bool = True,
    ) -> Subscription:
        sub = _InProcessSubscription(self, name, msg_type, callback, reliable)
        self._subscriptions.setdefault(name, []).append(sub)
        return sub

    def destroy_subscription(self, sub: Subscription) -> None:
        subs = self._subscriptions.get(sub.name, [])
        if sub in subs:
            subs.remove(sub)

    # -- actions ---
    def create_action_server(
        self,
        name: str,
        action_type: type,
        on_goal: Callable[[Any], bool],
        on_cancel: Callable[[Any], bool] | None = None,
    ) -> Any:
        if name in self._action_servers:
            raise ValueError(f"action server '{name}' already exists")
        self._action_servers[name] = _InProcessActionServer(name, action_type, on_goal, on_cancel)
        return name

    def destroy_action_server(self, name: str) -> None:
        self._action_servers.pop(name, None)

    def create_action_client(self, name: str, action_type: type) -> ActionClient:
        return _InProcessActionClient(self, name, action_type)

    def action_servers(self) -> dict[str, type]:
        """Every action served on this bus now, with its type."""
        return {name: server.action_type for name, server in self._action_servers.items()}

    def action_types(self, name: str) -> list[str]:
        server = self._action_servers.get(name)
        return [] if server is None else [interface_type_name(server.action_type, "action")]

    # -- delivery ---
    def _wait_for(self, worker: ServiceWorker, run: Callable[[], _Answer], timeout_s: float | None) -> None:
        """On a simulated clock: ``run`` on ``worker`` and deliver its answer as if it ran here,
        waiting at most ``timeout_s`` of wall time (None: no bound) and only while the run is not
        asked to stop; a later answer is dropped (see the module's docstring)."""
        done = threading.Event()
        answers: list[_Answer] = []

        def call() -> None:
            answers.append(run())
            done.set()

        worker.submit(call)
        deadline_s = math.inf if timeout_s is None else time.monotonic() + timeout_s
        while not done.wait(min(WAIT_SLICE_S, max(0.0, deadline_s - time.monotonic()))):
            if self._stop_waiting():
                log.warning("service '%s': stopped waiting for its handler, which still runs; its answer is dropped",
                            worker.service_name)
                return
            if time.monotonic() >= deadline_s:
                log.warning("service '%s': its handler still runs after %g s of wall time (the caller's timeout); "
                            "its answer is dropped", worker.service_name, timeout_s)
                return
        self._deliver(answers[0])

    def _deliver(self, answer: _Answer) -> None:
        """Complete the caller's future, due when the handler finished and the latency model's
        delay since the call passed (on a simulated clock the two instants are one)."""
        delay = self.latency_for(answer.service_name).delay(answer.wall_s)
        future = answer.future
        future._ready_at = max(answer.finished_s, answer.called_s + max(0.0, delay))
        if answer.error is not None:
            future.set_exception(answer.error)
        else:
            future.set_result(answer.response)
        self._pending.append(future)

    def spin_once(self) -> None:
        while self._answered:
            self._deliver(self._answered.popleft())
        if not self._pending:
            return
        still: list[Future[Any]] = []
        for future in self._pending:
            if future.done():
                future._fire_if_done()
            else:
                still.append(future)
        self._pending = still

    def close(self) -> None:
        """Close the services' workers (each waits at most ``STOP_WAIT_S`` for a call in
        progress) and forget everything."""
        for worker in self._workers.values():
            worker.close()
        self._workers.clear()
        self._answered.clear()
        self._services.clear()
        self._publishers.clear()
        self._subscriptions.clear()
        self._lazy.clear()
        self._action_servers.clear()
        self._pending.clear()
