"""``RecordingBus``: a ``runtime.io.bus.Bus`` that records what passes through it, then forwards.

Why a proxy: behaviors and worlds only ever talk through ``context.bus``, so wrapping it sees
every service call, action goal, feedback and result of a run without the runtime knowing the
world (in-process cell or a real ROS 2 graph) or the behaviors knowing they are recorded. The
runner installs it when ``--record DIR`` is given; without it nothing is wrapped and nothing is
paid.

What lands in the MCAP file (topic names as ``ros2 bag`` users expect them):

- joint states: the recorder subscribes to ``/joint_states`` and to every JointState topic a
  behavior subscribes to, at most ``joint_states_hz`` messages per second of clock time;
- camera frames: the frames a policy actually consumed, taken from each GetActionChunk request
  and recorded on the camera topic the behavior read them from (no extra frames are rendered);
- policy calls: ``<service>/request`` and ``<service>/response`` as ``std_msgs/String`` JSON
  summaries (the images are on the camera topics, not repeated) and ``<service>/chunk``, the
  chunk as the policy sent it; other services' requests and responses as their own types;
- actions: every goal on ``<action>/goal``, feedback on ``<action>/feedback`` (at most
  ``FEEDBACK_HZ`` per action), results on
  ``<action>/result``; a goal's ``joint_trajectory`` also on ``<controller>/joint_trajectory``
  (the commanded motion) and a feedback's wrench on ``/force_torque_sensor_broadcaster/wrench``
  as ``geometry_msgs/WrenchStamped``.

Every callback here runs on the thread that spins the bus (both buses guarantee it), so the
writer needs no lock.
"""
from __future__ import annotations

import json
from typing import Any, Callable, Protocol

from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import String

from runtime.io.bus import Bus, Publisher, ServerGoalHandle
from runtime.io.clock import Clock

from .mcap_writer import SENSOR_DATA_QOS

WRENCH_TOPIC = "/force_torque_sensor_broadcaster/wrench"
JOINT_STATES_TOPIC = "/joint_states"
FEEDBACK_HZ = 25.0
"""Action feedback (and the wrench it carries) is recorded at most this often per action: the
simulated controllers publish it at 20 Hz; a controller publishing at 50 Hz made it half of a
recording's messages."""
JOINT_STATES_HZ = 50.0
"""Joint states are recorded at most this often (per second of clock time): twice the rate of
any policy step this project runs (dt >= 0.05 s), and it keeps recording within its budget."""
STATUS_NAMES = {0: "UNKNOWN", 1: "CHUNK_PRODUCED", 2: "NO_MORE_ACTIONS", 3: "ERROR"}


def is_policy_request(request: Any) -> bool:
    """A GetActionChunk request (anything carrying camera frames with their names)."""
    return hasattr(request, "images") and hasattr(request, "image_names")


def controller_namespace(action_name: str) -> str:
    """``/jtac/follow_joint_trajectory`` -> ``/jtac``: where a controller's topics live."""
    head, _, _ = action_name.rstrip("/").rpartition("/")
    return head


def _rows(array_msg: Any) -> int:
    dims = getattr(getattr(array_msg, "layout", None), "dim", None)
    return int(dims[0].size) if dims else 0


def request_summary(index: int, sent_at: float, request: Any, topics: list[str]) -> dict[str, Any]:
    """What a policy was asked, without the pixels (those are on the camera topics)."""
    state = request.robot_state
    return {
        "request": index,
        "time": sent_at,
        "prompt": request.prompt,
        "new_episode": bool(request.new_episode),
        "frozen_prefix_steps": int(request.frozen_prefix_steps),
        "guidance_horizon": int(request.guidance_horizon),
        "joint_names": list(state.name),
        "positions": [float(p) for p in state.position],
        "images": [
            {"name": name, "topic": topic, "width": int(img.width), "height": int(img.height), "encoding": img.encoding}
            for name, topic, img in zip(request.image_names, topics, request.images)
        ],
        "previous_action_chunk_steps": _rows(request.previous_action_chunk),
    }


def response_summary(index: int, sent_at: float, answered_at: float, response: Any, error: BaseException | None) -> dict[str, Any]:
    """How the policy answered: status, message, chunk size, and the round trip on the clock."""
    summary: dict[str, Any] = {"request": index, "time": answered_at, "sent_at": sent_at, "latency": answered_at - sent_at}
    if error is not None:
        summary.update(status=None, status_name="EXCEPTION", message=f"{type(error).__name__}: {error}")
        return summary
    chunk = response.chunk
    summary.update(
        status=int(response.status),
        status_name=STATUS_NAMES.get(int(response.status), str(response.status)),
        message=response.message,
        chunk_steps=len(chunk.points),
        joint_names=list(chunk.joint_names),
        native_control_period=float(response.native_control_period),
        policy_action_chunk_steps=_rows(response.policy_action_chunk),
    )
    return summary


def _json_msg(data: dict[str, Any]) -> String:
    return String(data=json.dumps(data, default=str))


class _FrameTap:
    """A camera subscription that remembers the frame it last handed out (to name its topic later)."""

    def __init__(self, inner: Any, frames: dict[str, Any]) -> None:
        self._recording_inner = inner
        self._frames = frames

    @property
    def latest(self) -> Any:
        msg = self._recording_inner.latest
        if msg is not None:
            self._frames[self._recording_inner.name] = msg
        return msg

    def __getattr__(self, name: str) -> Any:
        return getattr(self._recording_inner, name)


class _RecordingClient:
    def __init__(self, inner: Any, bus: RecordingBus) -> None:
        self._recording_inner = inner
        self._bus = bus

    def call_async(self, request: Any, timeout_s: float | None = None) -> Any:
        future = self._recording_inner.call_async(request, timeout_s=timeout_s)
        self._bus._service_call(self._recording_inner.name, request, future)
        return future

    def __getattr__(self, name: str) -> Any:
        return getattr(self._recording_inner, name)


class _RecordingActionClient:
    def __init__(self, inner: Any, bus: RecordingBus) -> None:
        self._recording_inner = inner
        self._bus = bus

    def send_goal_async(self, goal: Any, feedback_callback: Callable[[Any], None] | None = None) -> Any:
        name = self._recording_inner.name

        def on_feedback(feedback: Any) -> None:
            self._bus._feedback(name, feedback)
            if feedback_callback is not None:
                feedback_callback(feedback)

        future = self._recording_inner.send_goal_async(goal, on_feedback)
        self._bus._goal(name, goal, future)
        return future

    def __getattr__(self, name: str) -> Any:
        return getattr(self._recording_inner, name)


class MessageWriter(Protocol):
    """Where a ``RecordingBus`` writes: an ``McapRos2Writer``, or the recorder's ``Tee`` of sinks."""

    @property
    def qos(self) -> dict[str, Any]: ...

    def write(self, topic: str, msg: Any, seconds: float) -> None: ...

    def flush_if_due(self) -> None: ...


class RecordingBus:
    """A ``runtime.io.bus.Bus`` that forwards every call to ``inner`` and records the traffic into
    ``writer`` (see the module doc); a ``BusWrapper`` too, so what only ``inner`` can do is found
    with ``runtime.io.bus.capability``."""

    clock: Clock

    def __init__(self, inner: Bus, writer: MessageWriter, joint_states_hz: float = JOINT_STATES_HZ) -> None:
        self.inner = inner
        self.clock = inner.clock
        self.writer = writer
        self.joint_states_hz = joint_states_hz
        self._frames: dict[str, Any] = {}
        self._recorded_topics: dict[str, Any] = {}
        self._last_recorded: dict[str, float] = {}
        self._policy_requests = 0
        self.joint_state_listeners: list[Callable[[Any, float], None]] = []
        """Called with each recorded ``/joint_states`` message and its time (e.g. to send ``/tf``)."""
        self.record_topic(JOINT_STATES_TOPIC, JointState, joint_states_hz)

    @property
    def produces_on_read(self) -> bool:
        return self.inner.produces_on_read

    @property
    def serves(self) -> bool:
        return self.inner.serves

    def spin_once(self) -> None:
        self.inner.spin_once()
        self.writer.flush_if_due()

    def close(self) -> None:
        self.inner.close()

    # -- topics ---
    def record_topic(self, name: str, msg_type: type, max_hz: float | None = None) -> None:
        """Record every message on ``name`` (at most ``max_hz`` per second of clock time)."""
        if name in self._recorded_topics:
            return

        listeners = self.joint_state_listeners if name == JOINT_STATES_TOPIC else []

        def record(msg: Any) -> None:
            now = self.clock.now()
            if self._due(name, now, max_hz):
                for listener in listeners:  # first: what they send may be needed to read the message (/tf)
                    listener(msg, now)
                self.writer.write(name, msg, now)

        # Best effort connects to reliable and best-effort publishers alike.
        self._recorded_topics[name] = self.inner.create_subscription(name, msg_type, record, reliable=False)

    def create_publisher(self, name: str, msg_type: type, reliable: bool = True) -> Publisher:
        return self.inner.create_publisher(name, msg_type, reliable)

    def create_lazy_publisher(
        self,
        name: str,
        msg_type: type,
        produce: Callable[[], Any],
        reliable: bool = True,
        rate_hz: float = 30.0,
    ) -> None:
        self.inner.create_lazy_publisher(name, msg_type, produce, reliable, rate_hz)

    def destroy_publisher(self, name: str) -> None:
        self.inner.destroy_publisher(name)

    def create_subscription(self, name: str, msg_type: type, callback: Callable[[Any], None] | None = None, reliable: bool = True) -> Any:
        sub = self.inner.create_subscription(name, msg_type, callback, reliable)
        if msg_type is JointState:
            self.record_topic(name, JointState, self.joint_states_hz)
        if msg_type is Image:
            self.writer.qos.setdefault(name, SENSOR_DATA_QOS)  # what camera drivers offer
            return _FrameTap(sub, self._frames)
        return sub

    def destroy_subscription(self, sub: Any) -> None:
        self.inner.destroy_subscription(sub._recording_inner if isinstance(sub, _FrameTap) else sub)

    # -- services ---
    def create_service(self, name: str, srv_type: type, handler: Callable[[Any], Any], own_thread: bool = False) -> Any:
        return self.inner.create_service(name, srv_type, handler, own_thread)

    def destroy_service(self, name: str) -> None:
        self.inner.destroy_service(name)

    def create_client(self, name: str, srv_type: type) -> Any:
        return _RecordingClient(self.inner.create_client(name, srv_type), self)

    def _service_call(self, name: str, request: Any, future: Any) -> None:
        sent_at = self.clock.now()
        if is_policy_request(request):
            self._policy_call(name, request, future, sent_at)
            return
        self.writer.write(f"{name}/request", request, sent_at)

        def answered(f: Any) -> None:
            if f.exception() is None and not f.cancelled():
                self.writer.write(f"{name}/response", f.result(), self.clock.now())

        future.add_done_callback(answered)

    def _policy_call(self, name: str, request: Any, future: Any, sent_at: float) -> None:
        self._policy_requests += 1
        index = self._policy_requests
        topics = []
        for image_name, image in zip(request.image_names, request.images):
            topic = next((t for t, frame in self._frames.items() if frame is image), f"{name}/images/{image_name}")
            topics.append(topic)
            self.writer.write(topic, image, sent_at)
        self.writer.write(f"{name}/request", _json_msg(request_summary(index, sent_at, request, topics)), sent_at)

        def answered(f: Any) -> None:
            if f.cancelled():
                return
            now = self.clock.now()
            error = f.exception()
            response = None if error is not None else f.result()
            self.writer.write(f"{name}/response", _json_msg(response_summary(index, sent_at, now, response, error)), now)
            if response is not None and response.chunk.points:
                self.writer.write(f"{name}/chunk", response.chunk, now)

        future.add_done_callback(answered)

    # -- actions ---
    def create_action_server(
        self,
        name: str,
        action_type: type,
        on_goal: Callable[[ServerGoalHandle], bool],
        on_cancel: Callable[[ServerGoalHandle], bool] | None = None,
    ) -> Any:
        return self.inner.create_action_server(name, action_type, on_goal, on_cancel)

    def destroy_action_server(self, name: str) -> None:
        self.inner.destroy_action_server(name)

    def create_action_client(self, name: str, action_type: type) -> Any:
        return _RecordingActionClient(self.inner.create_action_client(name, action_type), self)

    def action_types(self, name: str) -> list[str]:
        return self.inner.action_types(name)

    def _goal(self, name: str, goal: Any, future: Any) -> None:
        now = self.clock.now()
        # the admittance goal's joint_trajectory, control_msgs FollowJointTrajectory's trajectory
        trajectory = getattr(goal, "joint_trajectory", None) or getattr(goal, "trajectory", None)
        if trajectory is not None:  # (first: the goal's CDR reuses its bytes)
            self.writer.write(f"{controller_namespace(name)}/joint_trajectory", trajectory, now)
        self.writer.write(f"{name}/goal", goal, now)

        def sent(f: Any) -> None:
            if f.cancelled() or f.exception() is not None:
                return
            handle = f.result()
            if handle.accepted:
                handle.get_result_async().add_done_callback(finished)

        def finished(f: Any) -> None:
            if not f.cancelled() and f.exception() is None:
                self.writer.write(f"{name}/result", f.result().result, self.clock.now())

        future.add_done_callback(sent)

    def _due(self, topic: str, now: float, max_hz: float | None) -> bool:
        """Whether ``topic`` may be recorded at ``now`` under its ``max_hz`` (None: always); if
        so, ``now`` becomes its last recording time."""
        last = self._last_recorded.get(topic)
        if max_hz and last is not None and now - last < 1.0 / max_hz - 1e-9:
            return False
        self._last_recorded[topic] = now
        return True

    def _feedback(self, name: str, feedback: Any) -> None:
        now = self.clock.now()
        if not self._due(f"{name}/feedback", now, FEEDBACK_HZ):
            return
        self.writer.write(f"{name}/feedback", feedback, now)
        wrench = getattr(feedback, "wrench", None)
        if wrench is not None:
            self.writer.write(WRENCH_TOPIC, WrenchStamped(header=feedback.header, wrench=wrench), now)
