"""``RosBus``: the bus API of ``runtime.io.bus`` on a real ROS 2 graph, through rclpy.

Behaviors and worlds code against ``runtime.io.bus.Bus``; this binding makes the same code talk
to real ROS 2 nodes (a policy adapter, a real controller) instead of in-process handlers.

Threads, and why:
- Each ``RosBus`` owns one rclpy ``Context`` (so several buses, and tests, live in one process
  without sharing global rclpy state), one node, and a ``MultiThreadedExecutor`` spinning in a
  background thread. rclpy only delivers anything (replies, messages, goal requests) while an
  executor spins, and our API never blocks: behaviors poll ``future.done()`` at 100 Hz. A
  multi-threaded executor is needed because an accepted action goal keeps one executor thread
  waiting until its owner finishes it (see below); size ``num_threads`` for the number of goals
  that may be active at once, plus a few for everything else. A node that serves nothing
  (``serves=False``: clients, subscriptions, publishers only, as the runtime driving a robot
  in another process) spins rclpy's ``EventsExecutor`` instead: one thread and a tenth or less
  of the CPU per message (``benchmarks/bench_executors.py``); its callbacks never block.
- The executor threads only move data: ``latest``/``count`` of subscriptions and ``done()`` of
  futures change as soon as something arrives. Callbacks you hand to the bus
  (subscription callbacks, ``feedback_callback``, ``Future.add_done_callback``) run inside
  ``spin_once()``, on the thread that calls it, as they do with ``InProcessBus``; so behavior
  code never runs on two threads.
- Server callbacks (service handlers, ``on_goal``, ``on_cancel``, ``produce`` of lazy
  publishers) run on executor threads by default, so a server answers even when nobody calls
  ``spin_once`` (a standalone policy adapter). A server whose state is also touched by another
  thread (a simulated controller stepped by the world) passes ``serve_in_spin_once=True``: its
  callbacks then run inside ``spin_once()`` on the owner's thread, and a request waits for it.
  A service created with ``own_thread=True`` (a hosted policy, whose inference may take a
  second) is the exception there: its handler runs on a ``ServiceWorker`` of its own, one
  request at a time, so the owner's tick never waits for it.

ROS has no error channel for services: when a handler raises, the error is logged and the
client receives a default-constructed response (for GetActionChunk that is status UNKNOWN,
which callers treat as a failure).
"""
from __future__ import annotations

import collections
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import rclpy
from action_msgs.srv import CancelGoal
from rclpy.action import ActionClient as _RclpyActionClient
from rclpy.action import ActionServer as _RclpyActionServer
from rclpy.action import CancelResponse, GoalResponse, get_action_names_and_types
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, ShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy

from runtime.io.bus import (
    STATUS_ACCEPTED,
    STATUS_ABORTED,
    STATUS_CANCELED,
    STATUS_CANCELING,
    STATUS_EXECUTING,
    STATUS_SUCCEEDED,
    ActionResult,
    ClientGoalHandle,
    Future,
    Subscription,
)
from runtime.io.clock import Clock, next_due
from runtime.errors import OptionError
from runtime.io.service_worker import ServiceWorker

_SPIN_PERIOD_S = 0.1  # how often the spin thread looks at its stop flag when the graph is idle
_QUEUE_DEPTH = 10
CANCEL_DELIVERY_S = 2.0
"""Bound on how long ``close()`` waits for the cancels in flight to be served and answered."""


def _events_executor(context: rclpy.Context) -> Any:
    """rclpy's EventsExecutor. It enables ``faulthandler`` on ``sys.stderr``, which fails where
    that is no file (a captured stream): then on the process's own stderr."""
    from rclpy.experimental import EventsExecutor

    try:
        sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        captured, sys.stderr = sys.stderr, sys.__stderr__
        try:
            return EventsExecutor(context=context)
        finally:
            sys.stderr = captured
    return EventsExecutor(context=context)


class BusClosed(RuntimeError):
    """The bus was closed while a request was waiting for its owner to serve it."""


def _qos(reliable: bool) -> QoSProfile:
    return QoSProfile(
        depth=_QUEUE_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
    )


def _compatible(publisher_reliable: bool, subscriber_reliable: bool) -> bool:
    """ROS QoS: a reliable subscription never connects to a best-effort publisher."""
    return publisher_reliable or not subscriber_reliable


# --------------------------------------------------------------------------------------------
# Futures and the owner-thread queue
# --------------------------------------------------------------------------------------------
class RosFuture(Future[Any]):
    """A ``runtime.io.bus.Future`` completed from an executor thread.

    ``done()``/``result()`` behave as in ``runtime.io.bus.Future``; ``ready_at`` is the runtime
    clock's time when the answer arrived; done-callbacks run inside the bus's ``spin_once()``.
    """

    def __init__(self, bus: RosBus, on_cancel: Callable[[], None] | None = None) -> None:
        super().__init__()
        self._bus = bus
        self._lock = threading.Lock()
        self._on_cancel = on_cancel

    def set_result(self, value: Any) -> None:
        self._complete(value, None)

    def set_exception(self, exc: BaseException) -> None:
        self._complete(None, exc)

    def _complete(self, value: Any, exc: BaseException | None) -> None:
        with self._lock:
            if self._has_value or self._cancelled:
                return
            self._ready_at = self._bus.clock.now()
            self._value, self._exception = value, exc
            self._has_value = True
            callbacks, self._callbacks = self._callbacks, []
        for cb in callbacks:
            self._bus._post(cb, self)

    def add_done_callback(self, cb: Callable[[Future[Any]], None]) -> None:
        with self._lock:
            if not self.done():
                self._callbacks.append(cb)
                return
        cb(self)

    def cancel(self) -> None:
        with self._lock:
            if self._has_value:
                return
            self._cancelled = True
            self._callbacks.clear()
        if self._on_cancel is not None:
            self._on_cancel()


def _bridge(ros_future: rclpy.task.Future, future: RosFuture, convert: Callable[[Any], Any]) -> None:
    """Complete ``future`` with ``convert(result)`` when the rclpy future completes."""

    def done(rf: rclpy.task.Future) -> None:
        if rf.cancelled():
            future.set_exception(BusClosed("the request was dropped before an answer arrived"))
            return
        exc = rf.exception()
        if exc is not None:
            future.set_exception(exc)
            return
        try:
            future.set_result(convert(rf.result()))
        except Exception as err:  # a conversion bug must reach the caller, not kill the executor
            future.set_exception(err)

    ros_future.add_done_callback(done)


@dataclass
class _OwnerCall:
    """A server callback waiting for ``spin_once()`` to run it on the owner's thread."""

    fn: Callable[..., Any]
    args: tuple[Any, ...]
    event: threading.Event = field(default_factory=threading.Event)
    value: Any = None
    error: BaseException | None = None

    def run(self) -> None:
        try:
            self.value = self.fn(*self.args)
        except BaseException as exc:  # handed back to the waiting executor thread
            self.error = exc
        finally:
            self.event.set()


# --------------------------------------------------------------------------------------------
# Services
# --------------------------------------------------------------------------------------------
class _RosClient:
    def __init__(self, bus: RosBus, name: str, srv_type: type) -> None:
        self.bus, self.name = bus, name
        self.srv_type: Any = srv_type  # a generated service class (untyped): Request, Response
        self._client = bus.node.create_client(srv_type, name, callback_group=bus._group)

    def service_is_ready(self) -> bool:
        return self._client.service_is_ready()

    def call_async(self, request: Any, timeout_s: float | None = None) -> Future[Any]:
        """``timeout_s`` is the caller's (it gives up on its clock); the call itself is not bounded."""
        if not isinstance(request, self.srv_type.Request):
            raise TypeError(f"service '{self.name}' takes {self.srv_type.__name__}.Request, got {type(request).__name__}")
        if not self._client.service_is_ready():
            raise RuntimeError(f"service '{self.name}' is not available")
        ros_future = self._client.call_async(request)
        future = RosFuture(self.bus, on_cancel=lambda: self._client.remove_pending_request(ros_future))
        _bridge(ros_future, future, lambda response: response)
        return future


# --------------------------------------------------------------------------------------------
# Topics
# --------------------------------------------------------------------------------------------
class _RosPublisher:
    def __init__(self, bus: RosBus, name: str, msg_type: type, reliable: bool) -> None:
        self.bus, self.name, self.msg_type, self.reliable = bus, name, msg_type, reliable
        self._publisher = bus.node.create_publisher(msg_type, name, _qos(reliable))

    def publish(self, msg: Any) -> None:
        if not isinstance(msg, self.msg_type):
            raise TypeError(f"topic '{self.name}' carries {self.msg_type.__name__}, got {type(msg).__name__}")
        self._publisher.publish(msg)

    def subscriber_count(self) -> int:
        return self._publisher.get_subscription_count()


class _RosSubscription:
    def __init__(
        self,
        bus: RosBus,
        name: str,
        msg_type: type,
        callback: Callable[[Any], None] | None,
        reliable: bool,
    ) -> None:
        self.bus, self.name, self.msg_type = bus, name, msg_type
        self.callback, self.reliable = callback, reliable
        self.latest: Any = None
        self.count = 0
        self.received_at: float | None = None
        """Runtime clock seconds when ``latest`` arrived."""
        # Its own mutually exclusive group: deliveries to one subscription never overlap, so
        # ``count`` needs no lock.
        self._subscription = bus.node.create_subscription(
            msg_type, name, self._deliver, _qos(reliable), callback_group=MutuallyExclusiveCallbackGroup()
        )

    def _deliver(self, msg: Any) -> None:
        self.received_at = self.bus.clock.now()  # (before ``latest``: a reader never takes a new message for an old one)
        self.latest = msg
        self.count += 1
        if self.callback is not None:
            self.bus._post(self.callback, msg)

    def has_publishers(self) -> bool:
        topic = self.bus.node.resolve_topic_name(self.name)
        return any(
            _compatible(info.qos_profile.reliability == ReliabilityPolicy.RELIABLE, self.reliable)
            for info in self.bus.node.get_publishers_info_by_topic(topic)
        )


class _LazyPublisher:
    """A topic published from a timer, but only while someone subscribes (frames are costly)."""

    def __init__(
        self, bus: RosBus, name: str, msg_type: type, produce: Callable[[], Any], reliable: bool, rate_hz: float
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"lazy publisher '{name}': rate_hz must be > 0, got {rate_hz}")
        self.bus, self.name, self.produce = bus, name, produce
        self.publisher = _RosPublisher(bus, name, msg_type, reliable)
        self.period_s = 1.0 / rate_hz
        self._busy = threading.Lock()  # skip a tick rather than queue frames behind a slow produce()
        self._timer = self._start_timer()

    def _start_timer(self) -> Any:
        return self.bus.node.create_timer(self.period_s, self._tick, callback_group=MutuallyExclusiveCallbackGroup())

    def _tick(self) -> None:
        if self.publisher.subscriber_count() == 0 or not self._busy.acquire(blocking=False):
            return
        try:
            msg = self.bus._serve(self.produce)
            if msg is not None:
                self.publisher.publish(msg)
        except BusClosed:  # closing while the owner had not served this frame: nothing to publish
            pass
        finally:
            self._busy.release()

    def destroy(self) -> None:
        if self._timer is not None:
            self.bus.node.destroy_timer(self._timer)
        self.bus.node.destroy_publisher(self.publisher._publisher)


class _OwnerLazyPublisher(_LazyPublisher):
    """A lazy publisher of a ``serve_in_spin_once`` bus: published by the owner in ``spin_once``
    when due, with no executor timer (``produce`` must run on the owner's thread anyway, so a
    timer would only wake an executor thread to wait for the owner)."""

    due_at_s = 0.0
    """``time.monotonic()`` from which the next message is due."""
    cost_s = 0.0
    """Wall time the last ``produce()`` took: what publishing this one costs a spin."""

    def _start_timer(self) -> None:
        return None

    def publish(self, now_s: float) -> None:
        """Publish one message (when someone subscribes) and schedule the next, never a burst."""
        self.due_at_s = next_due(self.due_at_s, self.period_s, now_s)
        if self.publisher.subscriber_count() == 0:
            return
        started = time.monotonic()
        msg = self.produce()
        self.cost_s = time.monotonic() - started
        if msg is not None:
            self.publisher.publish(msg)


LAZY_BUDGET_S = 0.004
"""Wall time one ``spin_once`` may spend on lazy topics beyond the most overdue one, which is
always published: the others that would overrun it wait for the next spin (a camera frame costs
more than a tick has to spare on a CPU renderer, so frames of several cameras go one per tick)."""


# --------------------------------------------------------------------------------------------
# Actions: server side
# --------------------------------------------------------------------------------------------
class RosServerGoalHandle:
    """What ``on_goal`` receives; the owner finishes it later, from any thread.

    rclpy creates its own goal handle only after ``on_goal`` accepted, and its execute callback
    must return the result; so this handle records the outcome, and the execute callback (an
    executor thread waiting on ``_finished``) reports it to rclpy. For the same reason
    ``goal_id`` is empty inside ``on_goal`` (rclpy does not pass the goal's UUID there); it is
    set as soon as the goal is accepted. Feedback published before then is sent right after.
    """

    def __init__(self, server: _RosActionServer, request: Any) -> None:
        self.server = server
        self.request = request
        self.goal_id = ""
        self.status = STATUS_ACCEPTED
        self._result: Any = None
        self._cancel_requested = False
        self._ros_handle: Any = None
        self._early_feedback: list[Any] = []
        self._lock = threading.Lock()
        self._finished = threading.Event()

    @property
    def is_active(self) -> bool:
        return self.status in (STATUS_ACCEPTED, STATUS_EXECUTING, STATUS_CANCELING)

    @property
    def is_cancel_requested(self) -> bool:
        return self._cancel_requested

    def publish_feedback(self, feedback: Any) -> None:
        if not isinstance(feedback, self.server.action_type.Feedback):
            raise TypeError(
                f"action '{self.server.name}' feedback is {self.server.action_type.__name__}.Feedback, "
                f"got {type(feedback).__name__}"
            )
        with self._lock:
            if not self.is_active:
                return
            if self._ros_handle is None:  # accepted, but rclpy has not made its handle yet
                self._early_feedback.append(feedback)
                return
            ros_handle = self._ros_handle
        ros_handle.publish_feedback(feedback)

    def _finish(self, status: int, result: Any) -> None:
        if not isinstance(result, self.server.action_type.Result):
            raise TypeError(
                f"action '{self.server.name}' result is {self.server.action_type.__name__}.Result, "
                f"got {type(result).__name__}"
            )
        with self._lock:
            if not self.is_active:
                raise RuntimeError(f"goal {self.goal_id[:8]} on '{self.server.name}' has already finished")
            self.status, self._result = status, result
        self._finished.set()

    def succeed(self, result: Any) -> None:
        self._finish(STATUS_SUCCEEDED, result)

    def abort(self, result: Any) -> None:
        self._finish(STATUS_ABORTED, result)

    def canceled(self, result: Any) -> None:
        self._finish(STATUS_CANCELED, result)

    def _bind(self, ros_handle: Any) -> None:
        with self._lock:
            self._ros_handle = ros_handle
            self.goal_id = bytes(ros_handle.goal_id.uuid).hex()
            if self.status == STATUS_ACCEPTED:
                self.status = STATUS_EXECUTING
            early, self._early_feedback = self._early_feedback, []
        for feedback in early:
            ros_handle.publish_feedback(feedback)


class _RosActionServer:
    def __init__(
        self,
        bus: RosBus,
        name: str,
        action_type: type,
        on_goal: Callable[[Any], bool],
        on_cancel: Callable[[Any], bool] | None,
    ) -> None:
        self.bus, self.name = bus, name
        self.action_type: Any = action_type  # a generated action class (untyped): Goal, Result, Feedback
        self.on_goal, self.on_cancel = on_goal, on_cancel
        # rclpy hands the same goal message object to goal_callback and to the goal handle it
        # creates after acceptance; that identity pairs our handle with rclpy's.
        self._pending: dict[int, RosServerGoalHandle] = {}
        self._by_uuid: dict[bytes, RosServerGoalHandle] = {}
        self._lock = threading.Lock()
        self._server = _RclpyActionServer(
            bus.node,
            action_type,
            name,
            execute_callback=self._execute,
            goal_callback=self._goal,
            handle_accepted_callback=self._accepted,
            cancel_callback=self._cancel,
            callback_group=bus._group,
        )

    def _goal(self, request: Any) -> GoalResponse:
        handle = RosServerGoalHandle(self, request)
        try:
            accepted = bool(self.bus._serve(self.on_goal, handle))
        except BusClosed:
            return GoalResponse.REJECT
        except Exception as exc:
            self.bus.node.get_logger().error(f"action '{self.name}': on_goal raised {exc!r}; rejecting the goal")
            return GoalResponse.REJECT
        if not accepted:
            return GoalResponse.REJECT
        with self._lock:
            self._pending[id(request)] = handle
        return GoalResponse.ACCEPT

    def _accepted(self, ros_handle: Any) -> None:
        with self._lock:
            handle = self._pending.pop(id(ros_handle.request))
            self._by_uuid[bytes(ros_handle.goal_id.uuid)] = handle
        handle._bind(ros_handle)
        ros_handle.execute()

    def _cancel(self, ros_handle: Any) -> CancelResponse:
        with self._lock:
            handle = self._by_uuid.get(bytes(ros_handle.goal_id.uuid))
        if handle is None or not handle.is_active:
            return CancelResponse.REJECT
        handle._cancel_requested = True
        if self.on_cancel is None:
            accepted = True
        else:
            try:
                accepted = bool(self.bus._serve(self.on_cancel, handle, cancel=True))
            except Exception as exc:
                self.bus.node.get_logger().error(f"action '{self.name}': on_cancel raised {exc!r}; rejecting")
                accepted = False
        with handle._lock:
            if accepted and handle.status == STATUS_EXECUTING:
                handle.status = STATUS_CANCELING
        return CancelResponse.ACCEPT if accepted else CancelResponse.REJECT

    def _execute(self, ros_handle: Any) -> Any:
        """Wait (on this executor thread) until the owner finishes the goal, then report it."""
        uuid = bytes(ros_handle.goal_id.uuid)
        with self._lock:
            handle = self._by_uuid[uuid]
        try:
            while not handle._finished.wait(_SPIN_PERIOD_S):
                if self.bus._closing.is_set():
                    ros_handle.abort()
                    return self.action_type.Result()
            if handle.status == STATUS_SUCCEEDED:
                ros_handle.succeed()
            elif handle.status == STATUS_ABORTED:
                ros_handle.abort()
            else:
                if not ros_handle.is_cancel_requested:
                    # The owner reported CANCELED without a cancel request (the in-process bus
                    # allows it); ROS only reaches CANCELED through CANCELING, so pass through it
                    # the way rclpy's own cancel handling does.
                    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

                    ros_handle._update_state(_rclpy.GoalEvent.CANCEL_GOAL)
                ros_handle.canceled()
            return handle._result
        finally:
            with self._lock:
                self._by_uuid.pop(uuid, None)

    def destroy(self) -> None:
        self._server.destroy()


# --------------------------------------------------------------------------------------------
# Actions: client side
# --------------------------------------------------------------------------------------------
class RosClientGoalHandle:
    """What ``send_goal_async`` yields: ``accepted``, ``goal_id``, result and cancel futures."""

    def __init__(self, client: _RosActionClient, ros_handle: Any) -> None:
        self._client = client
        self._ros_handle = ros_handle
        self.accepted = bool(ros_handle.accepted)
        self.goal_id = bytes(ros_handle.goal_id.uuid).hex()
        self._result_future: RosFuture | None = None

    def get_result_async(self) -> Future[ActionResult]:
        if not self.accepted:
            raise RuntimeError("the goal was rejected; it has no result")
        if self._result_future is None:  # one result request per goal, however often polled
            self._result_future = RosFuture(self._client.bus)
            _bridge(
                self._ros_handle.get_result_async(),
                self._result_future,
                lambda response: ActionResult(int(response.status), response.result),
            )
        return self._result_future

    def cancel_goal_async(self) -> Future[bool]:
        future = RosFuture(self._client.bus)
        if not self.accepted:
            future.set_result(False)
            return future
        _bridge(
            self._ros_handle.cancel_goal_async(),
            future,
            lambda response: response.return_code == CancelGoal.Response.ERROR_NONE
            and len(response.goals_canceling) > 0,
        )
        self._client.bus._sent_cancels.append(future)
        return future


class _RosActionClient:
    def __init__(self, bus: RosBus, name: str, action_type: type) -> None:
        self.bus, self.name = bus, name
        self.action_type: Any = action_type  # a generated action class (untyped): Goal, Result, Feedback
        self._client = _RclpyActionClient(bus.node, action_type, name, callback_group=bus._group)

    def server_is_ready(self) -> bool:
        ready: bool = self._client.server_is_ready()
        return ready

    def send_goal_async(
        self, goal: Any, feedback_callback: Callable[[Any], None] | None = None
    ) -> Future[ClientGoalHandle]:
        if not isinstance(goal, self.action_type.Goal):
            raise TypeError(f"action '{self.name}' takes {self.action_type.__name__}.Goal, got {type(goal).__name__}")
        if not self._client.server_is_ready():
            raise RuntimeError(f"action server '{self.name}' is not available")
        on_feedback: Callable[[Any], None] | None = None
        if feedback_callback is not None:
            on_feedback = lambda message: self.bus._post(feedback_callback, message.feedback)  # noqa: E731

        future = RosFuture(self.bus)
        _bridge(
            self._client.send_goal_async(goal, feedback_callback=on_feedback),
            future,
            lambda ros_handle: RosClientGoalHandle(self, ros_handle),
        )
        return future

    def destroy(self) -> None:
        self._client.destroy()


# --------------------------------------------------------------------------------------------
# The bus
# --------------------------------------------------------------------------------------------
MAX_DOMAIN_ID = 232
"""The highest ROS_DOMAIN_ID ROS 2 takes (0-101 are safe on every machine)."""


def domain_id_problem(text: str | None) -> str | None:
    """What is wrong with ``text`` as ``ROS_DOMAIN_ID`` (None or empty: the default, 0), or None."""
    if not text:
        return None
    if not (text.isascii() and text.isdigit()) or int(text) > MAX_DOMAIN_ID:
        return f"ROS_DOMAIN_ID={text!r} must be a whole number from 0 to {MAX_DOMAIN_ID} (0-101 are safe everywhere)"
    return None


def init_context(domain_id: int | None = None) -> Any:
    """A new rclpy context, initialised; OptionError for a ``ROS_DOMAIN_ID`` rclpy would refuse
    with a bare RCLError (when ``domain_id`` does not override it)."""
    problem = None if domain_id is not None else domain_id_problem(os.environ.get("ROS_DOMAIN_ID"))
    if problem is not None:
        raise OptionError(problem)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    return context


def spin_on_thread(executor: Any, name: str) -> threading.Thread:
    """``executor`` spinning on a daemon thread of its own until its context is shut down."""
    def spin() -> None:
        try:
            executor.spin()
        except Exception:  # the context was shut down under the executor: its node is closing
            pass

    thread = threading.Thread(target=spin, name=name, daemon=True)
    thread.start()
    return thread


class RosBus:
    """``runtime.io.bus.Bus`` over rclpy: one context, one node, one executor thread pool.

    ``clock`` is the runtime clock (``WallClock`` on a real ROS graph); it stamps ``ready_at``
    of futures. ROS timers (lazy publishers) run on wall time.
    """

    clock: Clock
    produces_on_read = False
    serves: bool

    def __init__(
        self,
        clock: Clock,
        node_name: str = "objective_runtime",
        *,
        namespace: str | None = None,
        domain_id: int | None = None,
        serve_in_spin_once: bool = False,
        num_threads: int = 8,
        serves: bool = True,
    ) -> None:
        if num_threads < 2:
            raise ValueError(f"RosBus needs num_threads >= 2 (an active goal holds one), got {num_threads}")
        self.clock = clock
        self.serve_in_spin_once = serve_in_spin_once
        self.serves = serves
        self._queue: collections.deque[Callable[[], None]] = collections.deque()
        self._cancel_calls: collections.deque[Callable[[], None]] = collections.deque()
        """Cancel requests to this node's action servers, waiting for the owner (``_serve``)."""
        self._sent_cancels: list[RosFuture] = []
        """Cancel requests this node's action clients sent; ``close()`` waits for their answers."""
        self._closing = threading.Event()
        self._closed = False
        self.context = init_context(domain_id)
        try:
            self.node = rclpy.create_node(node_name, namespace=namespace, context=self.context)
            self._group = ReentrantCallbackGroup()
            if serves:
                self._executor = MultiThreadedExecutor(num_threads=num_threads, context=self.context)
            else:
                self._executor = _events_executor(self.context)
            self._executor.add_node(self.node)
        except Exception:
            rclpy.try_shutdown(context=self.context)
            raise
        self._services: dict[str, Any] = {}
        self._workers: dict[str, ServiceWorker] = {}
        self._publishers: dict[str, list[_RosPublisher]] = {}
        self._lazy: dict[str, _LazyPublisher] = {}
        self._subscriptions: list[_RosSubscription] = []
        self._clients: list[_RosClient] = []
        self._action_servers: dict[str, _RosActionServer] = {}
        self._action_clients: list[_RosActionClient] = []
        self.spin_errors: list[BaseException] = []
        self._thread = threading.Thread(target=self._spin, name=f"RosBus[{node_name}]", daemon=True)
        self._thread.start()

    # -- threads ---
    def _spin(self) -> None:
        while not self._closing.is_set() and self.context.ok():
            try:
                self._executor.spin_once(timeout_sec=_SPIN_PERIOD_S)
            except (ExternalShutdownException, ShutdownException):
                break
            except Exception as exc:  # a callback bug must not stop delivery for everyone else
                self.spin_errors.append(exc)
                self.node.get_logger().error(f"callback raised {exc!r}")

    def _post(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` in the next ``spin_once()`` on the owner's thread."""
        self._queue.append(lambda: fn(*args))

    def _serve(self, fn: Callable[..., Any], *args: Any, cancel: bool = False, worker: ServiceWorker | None = None) -> Any:
        """Run a server callback: here, or on the owner's thread when ``serve_in_spin_once``
        (on ``worker``'s thread when one is given).

        ``cancel``: a cancel request, which ``close()`` still serves (nothing else is)."""
        if not self.serve_in_spin_once:
            return fn(*args)
        call = _OwnerCall(fn, args)
        if worker is not None:
            worker.submit(call.run)
        else:
            (self._cancel_calls if cancel else self._queue).append(call.run)
        while not call.event.wait(_SPIN_PERIOD_S):
            if self._closing.is_set():
                raise BusClosed("the bus closed before its owner served the request")
        if call.error is not None:
            raise call.error
        return call.value

    # -- services ---
    def _check_serves(self, what: str) -> None:
        if not self.serves:
            raise ValueError(f"{what}: this node was made to serve nothing (RosBus(serves=False): an events "
                             "executor, whose one thread a server's waiting callback would block)")

    def create_service(self, name: str, srv_type: type, handler: Callable[[Any], Any], own_thread: bool = False) -> Any:
        """Serve ``name``; ``own_thread`` (see ``runtime.io.bus.Bus.create_service``) matters with
        ``serve_in_spin_once``, where the handler would otherwise run on the owner's thread."""
        self._check_serves(f"service '{name}'")
        if name in self._services:
            raise ValueError(f"service '{name}' is already served")
        worker = ServiceWorker(name) if own_thread and self.serve_in_spin_once else None
        if worker is not None:
            self._workers[name] = worker

        def serve(request: Any, response: Any) -> Any:
            try:
                answer = self._serve(handler, request, worker=worker)
            except BusClosed:
                self.node.get_logger().warning(f"service '{name}': the node closed before the answer; answering a default response")
                return response
            except Exception as exc:
                self.node.get_logger().error(f"service '{name}': handler raised {exc!r}; answering a default response")
                return response
            response_class: type = getattr(srv_type, "Response")  # the generated service class's
            if not isinstance(answer, response_class):
                self.node.get_logger().error(
                    f"service '{name}': handler returned {type(answer).__name__}, not "
                    f"{srv_type.__name__}.Response; answering a default response"
                )
                return response
            return answer

        self._services[name] = self.node.create_service(srv_type, name, serve, callback_group=self._group)
        return name

    def destroy_service(self, name: str) -> None:
        service = self._services.pop(name, None)
        if service is not None:
            self.node.destroy_service(service)
        worker = self._workers.pop(name, None)
        if worker is not None:
            worker.close()

    def create_client(self, name: str, srv_type: type) -> _RosClient:
        """The node's client of service ``name``: created once per name and type, then shared
        (creating one costs milliseconds; a behavior that starts again asks again)."""
        for client in self._clients:
            if client.name == name and client.srv_type is srv_type:
                return client
        client = _RosClient(self, name, srv_type)
        self._clients.append(client)
        return client

    # -- topics ---
    def create_publisher(self, name: str, msg_type: type, reliable: bool = True) -> _RosPublisher:
        pub = _RosPublisher(self, name, msg_type, reliable)
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
        """Publish ``produce()`` at ``rate_hz`` while the topic has subscribers.

        On ROS nobody can read a topic lazily, so a camera publishes at its frame rate; ticks
        with no subscriber (or while the previous ``produce()`` still runs) are skipped.
        ``produce`` may return None to publish nothing this tick. With ``serve_in_spin_once``
        the owner publishes what is due in ``spin_once`` (within ``LAZY_BUDGET_S``), else a
        timer on an executor thread does.
        """
        if name in self._lazy:
            raise ValueError(f"lazy publisher '{name}' already exists")
        kind = _OwnerLazyPublisher if self.serve_in_spin_once else _LazyPublisher
        self._lazy[name] = kind(self, name, msg_type, produce, reliable, rate_hz)

    def destroy_publisher(self, name: str) -> None:
        for pub in self._publishers.pop(name, []):
            self.node.destroy_publisher(pub._publisher)
        lazy = self._lazy.pop(name, None)
        if lazy is not None:
            lazy.destroy()

    def create_subscription(
        self,
        name: str,
        msg_type: type,
        callback: Callable[[Any], None] | None = None,
        reliable: bool = True,
    ) -> _RosSubscription:
        sub = _RosSubscription(self, name, msg_type, callback, reliable)
        self._subscriptions.append(sub)
        return sub

    def destroy_subscription(self, sub: Subscription) -> None:
        if isinstance(sub, _RosSubscription) and sub in self._subscriptions:
            self._subscriptions.remove(sub)
            self.node.destroy_subscription(sub._subscription)

    # -- actions ---
    def create_action_server(
        self,
        name: str,
        action_type: type,
        on_goal: Callable[[RosServerGoalHandle], bool],
        on_cancel: Callable[[RosServerGoalHandle], bool] | None = None,
    ) -> Any:
        self._check_serves(f"action server '{name}'")
        if name in self._action_servers:
            raise ValueError(f"action server '{name}' already exists")
        self._action_servers[name] = _RosActionServer(self, name, action_type, on_goal, on_cancel)
        return name

    def action_types(self, name: str) -> list[str]:
        """The types the ROS graph serves under action ``name`` (empty: none seen yet)."""
        qualified = name if name.startswith("/") else f"/{name}"
        return [t for found, types in get_action_names_and_types(self.node) if found == qualified for t in types]

    def destroy_action_server(self, name: str) -> None:
        server = self._action_servers.pop(name, None)
        if server is not None:
            server.destroy()

    def create_action_client(self, name: str, action_type: type) -> _RosActionClient:
        """The node's client of action ``name``: created once per name and type, then shared
        (its feedback callbacks are per goal)."""
        for client in self._action_clients:
            if client.name == name and client.action_type is action_type:
                return client
        client = _RosActionClient(self, name, action_type)
        self._action_clients.append(client)
        return client

    # -- delivery ---
    def spin_once(self) -> None:
        """Run the callbacks that arrived since the last call (and waiting server callbacks)."""
        for _ in range(len(self._queue)):
            self._queue.popleft()()
        self.serve_cancels()
        if self.serve_in_spin_once:
            self._publish_due()

    def _publish_due(self) -> None:
        """Publish the owner's lazy topics that are due, most overdue first, within ``LAZY_BUDGET_S``."""
        now = time.monotonic()
        due = sorted((p for p in self._lazy.values() if isinstance(p, _OwnerLazyPublisher) and p.due_at_s <= now),
                     key=lambda p: p.due_at_s)
        budget_end = now + LAZY_BUDGET_S
        for k, publisher in enumerate(due):
            if k and time.monotonic() + publisher.cost_s > budget_end:
                return
            publisher.publish(now)

    def serve_cancels(self) -> None:
        """Serve the cancel requests to this node's action servers that wait for the owner."""
        for _ in range(len(self._cancel_calls)):
            self._cancel_calls.popleft()()

    def cancels_in_flight(self) -> int:
        """Cancel requests sent and not yet answered, plus received ones not yet served."""
        self._sent_cancels = [f for f in self._sent_cancels if not f.done()]
        return len(self._sent_cancels) + len(self._cancel_calls)

    def deliver_cancels(self, timeout_s: float | None = None) -> bool:
        """Serve and wait until no cancel is in flight, at most ``timeout_s`` (default
        ``CANCEL_DELIVERY_S``); False if some
        still were (the graph went away, or a remote server never answered).

        Call it on the owner's thread: with ``serve_in_spin_once`` it serves this node's own
        action servers' cancel callbacks (a hosted controller cancelled by a behavior of the same
        node), and only those: everything else waiting for the owner stays unserved.
        """
        deadline = time.monotonic() + (CANCEL_DELIVERY_S if timeout_s is None else timeout_s)
        while self.context.ok():
            self.serve_cancels()
            if not self.cancels_in_flight():
                return True
            if time.monotonic() >= deadline:
                break
            time.sleep(0.005)
        self.node.get_logger().warning(f"{self.cancels_in_flight()} cancel request(s) still in flight on leaving the graph")
        return False

    def close(self) -> None:
        """Deliver the cancels in flight (``deliver_cancels``), stop the executor thread, destroy
        the node and shut the context down. Idempotent.

        However the owner's work ended (a behavior that failed after cancelling its goal, a
        halted tree, an exception), a cancel it sent reaches its action server, and a cancel its
        own servers received is served, before the node leaves the graph."""
        if self._closed:
            return
        self.deliver_cancels()
        self._closed = True
        self._closing.set()  # releases execute callbacks and requests waiting for spin_once or a service's worker
        self._thread.join()  # nothing new is handed to the worker pool after this
        for worker in self._workers.values():
            worker.close()
        self._workers.clear()
        # Drain rclpy's worker pool before shutting the executor down: the executor's own
        # shutdown() neither waits for running callbacks (they may still schedule work on it) nor
        # stops its ThreadPoolExecutor, whose threads would otherwise live until interpreter exit.
        pool = getattr(self._executor, "_executor", None)
        if pool is not None:
            pool.shutdown(wait=True)
        self._executor.shutdown(timeout_sec=0)
        for server in self._action_servers.values():
            server.destroy()
        for client in self._action_clients:
            client.destroy()
        for lazy in self._lazy.values():
            lazy.destroy()
        self._action_servers.clear()
        self._action_clients.clear()
        self._lazy.clear()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._queue.clear()
        self._cancel_calls.clear()

    def __enter__(self) -> RosBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"RosBus(node={self.node.get_fully_qualified_name()!r}, closed={self._closed})"
