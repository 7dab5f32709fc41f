"""MoveIt Pro's message, service and time nodes: build and unpack twists and wrenches, publish an
empty message, call a Trigger service, wait for a duration."""
from __future__ import annotations

import enum
from typing import Any, ClassVar

from geometry_msgs.msg import TwistStamped, Vector3, WrenchStamped
from std_msgs.msg import Empty
from std_srvs.srv import Trigger

from runtime.tree.behavior import Behavior, Status
from runtime.tree.decorators import elapsed
from runtime.tree.ports import InputPort, OutputPort, PortType, Range
from runtime.io.timestamps import time_msg

from .waiting import Deadline, when_ready


def vector3(values: list[float], port: str) -> Vector3:
    """A Vector3 from a port's x;y;z; ValueError naming the port otherwise."""
    if len(values) != 3:
        raise ValueError(f"{port} needs 3 values (x;y;z), got {len(values)}")
    return Vector3(x=float(values[0]), y=float(values[1]), z=float(values[2]))


class _CreateStamped(Behavior):
    """Build ``msg_type`` (a ...Stamped message): ``body`` gets one Vector3 per ``parts`` port."""

    msg_type: ClassVar[type]
    body: ClassVar[str]
    parts: ClassVar[tuple[tuple[str, str], ...]]
    """(port, field of the body) pairs."""
    output: ClassVar[str]

    def update(self) -> Status:
        msg = self.msg_type()
        msg.header.frame_id = self.get_input("reference_frame")
        msg.header.stamp = time_msg(self.context.clock.now())
        try:
            for port, field in self.parts:
                setattr(getattr(msg, self.body), field, vector3(self.get_input(port), port))
        except ValueError as err:
            return self.fail(str(err))
        self.set_output(self.output, msg)
        return Status.SUCCESS


class _Unpack(Behavior):
    """Write a ...Stamped message's header and body to two ports."""

    stamped: ClassVar[str]
    body: ClassVar[str]

    def update(self) -> Status:
        msg = self.get_input(self.stamped)
        self.set_output("header", msg.header)
        self.set_output(self.body, getattr(msg, self.body))
        return Status.SUCCESS


class CreateTwistStamped(_CreateStamped):
    """MoveIt Pro's CreateTwistStamped."""

    msg_type, body, output = TwistStamped, "twist", "twist_stamped"
    parts = (("linear_velocity_xyz", "linear"), ("angular_velocity_xyz", "angular"))
    description: ClassVar[str] = "Create a geometry_msgs/TwistStamped from a frame, a linear and an angular velocity."
    ports = (
        InputPort("reference_frame", PortType.STRING, "world", "Frame the twist is expressed in."),
        InputPort("linear_velocity_xyz", PortType.FLOAT_LIST, "0;0;0", "Linear velocity x;y;z (m/s).", valid=Range(-10, 10, "m/s")),
        InputPort("angular_velocity_xyz", PortType.FLOAT_LIST, "0;0;0", "Angular velocity x;y;z (rad/s).", valid=Range(-10, 10, "rad/s")),
        OutputPort("twist_stamped", PortType.TWIST_STAMPED, "The twist."),
    )


class UnpackTwistStampedMessage(_Unpack):
    """MoveIt Pro's UnpackTwistStampedMessage."""

    stamped, body = "twist_stamped", "twist"
    description: ClassVar[str] = "Split a TwistStamped into its header and its twist."
    ports = (
        InputPort("twist_stamped", PortType.TWIST_STAMPED, description="The twist to unpack."),
        OutputPort("header", PortType.HEADER, "Its std_msgs/Header."),
        OutputPort("twist", PortType.TWIST, "Its geometry_msgs/Twist."),
    )


class CreateWrenchStamped(_CreateStamped):
    """MoveIt Pro's CreateWrenchStamped."""

    msg_type, body, output = WrenchStamped, "wrench", "wrench_stamped"
    parts = (("force_xyz", "force"), ("torque_xyz", "torque"))
    description: ClassVar[str] = "Create a geometry_msgs/WrenchStamped from a frame, a force and a torque."
    ports = (
        InputPort("reference_frame", PortType.STRING, "world", "Frame the wrench is expressed in."),
        InputPort("force_xyz", PortType.FLOAT_LIST, "0;0;0", "Force x;y;z (N).", valid=Range(-10000, 10000, "N")),
        InputPort("torque_xyz", PortType.FLOAT_LIST, "0;0;0", "Torque x;y;z (N m).", valid=Range(-1000, 1000, "N m")),
        OutputPort("wrench_stamped", PortType.WRENCH_STAMPED, "The wrench."),
    )


class UnpackWrenchStampedMessage(_Unpack):
    """MoveIt Pro's UnpackWrenchStampedMessage."""

    stamped, body = "wrench_stamped", "wrench"
    description: ClassVar[str] = "Split a WrenchStamped into its header and its wrench."
    ports = (
        InputPort("wrench_stamped", PortType.WRENCH_STAMPED, description="The wrench to unpack."),
        OutputPort("header", PortType.HEADER, "Its std_msgs/Header."),
        OutputPort("wrench", PortType.WRENCH, "Its geometry_msgs/Wrench."),
    )


class PublishEmpty(Behavior):
    """MoveIt Pro's PublishEmpty: one std_msgs/Empty on a topic."""

    description: ClassVar[str] = "Publish one std_msgs/Empty message on a topic."
    ports = (
        InputPort("topic", PortType.STRING, description="Topic to publish on."),
        InputPort("queue_size", PortType.UINT, 1, "Publisher queue depth (kept for compatibility; messages are not queued here).", valid=Range(1, 1000)),
        InputPort("use_best_effort", PortType.BOOL, False, "Best-effort QoS instead of reliable."),
    )

    def update(self) -> Status:
        topic = self.get_input("topic").strip()
        if not topic:
            return self.fail("topic is empty")
        publisher = self.context.bus.create_publisher(topic, Empty, reliable=not self.get_input("use_best_effort"))
        publisher.publish(Empty())
        self.feedback_message = f"published std_msgs/Empty on {topic}"
        return Status.SUCCESS


class CallPhase(enum.Enum):
    WAIT_FOR_SERVER = 1
    WAIT_FOR_RESPONSE = 2


class CallTriggerService(Behavior):
    """MoveIt Pro's CallTriggerService: succeeds when the service answers success=true."""

    description: ClassVar[str] = (
        "Call a std_srvs/Trigger service; SUCCESS when it answers success=true, FAILURE with its message otherwise "
        "or when it does not answer in time; ERROR (the run stops) when the service is not available."
    )
    ports = (
        InputPort("service_name", PortType.STRING, description="The Trigger service."),
        InputPort("wait_for_server_available_timeout", PortType.FLOAT, 3.0, "Seconds to wait for the service to be available.", valid=Range(0, 3600, "s")),
        InputPort("response_timeout", PortType.FLOAT, 3.0, "Seconds to wait for the answer.", valid=Range(0, 3600, "s")),
    )

    def initialise(self) -> None:
        self.service = self.get_input("service_name")
        self.client = self.context.bus.create_client(self.service, Trigger)
        self.phase = CallPhase.WAIT_FOR_SERVER
        self.deadline = Deadline(self, self.get_input("wait_for_server_available_timeout"))
        self.future: Any = None

    def update(self) -> Status:
        if self.phase is CallPhase.WAIT_FOR_SERVER:
            ready = when_ready(self.client.service_is_ready, self.deadline, f"service '{self.service}'")
            if ready is not True:
                return self.fail(ready) if isinstance(ready, str) else Status.RUNNING
            self.future = self.client.call_async(Trigger.Request())
            self.deadline = Deadline(self, self.get_input("response_timeout"))
            self.phase = CallPhase.WAIT_FOR_RESPONSE
        if not self.future.done():
            if self.deadline.expired:
                return self.fail(f"service '{self.service}' did not answer within {self.deadline.seconds:g} s")
            return Status.RUNNING
        response = self.future.result()
        if not response.success:
            return self.fail(f"service '{self.service}' answered failure: {response.message or 'no message'}")
        self.feedback_message = response.message
        return Status.SUCCESS

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID and getattr(self, "future", None) is not None:
            self.future.cancel()


class WaitForDuration(Behavior):
    """MoveIt Pro's WaitForDuration, on the run's clock."""

    description: ClassVar[str] = "RUNNING for delay_duration seconds of run-clock time, then SUCCESS."
    ports = (InputPort("delay_duration", PortType.FLOAT, description="Seconds to wait (>= 0).", valid=Range(0, 86400, "s")),)

    def initialise(self) -> None:
        self.started_s = self.context.clock.now()

    def update(self) -> Status:
        seconds = self.get_input("delay_duration")
        if not seconds >= 0:
            return self.fail(f"delay_duration must be >= 0 seconds, got {seconds}")
        if elapsed(self.started_s, self.context.clock.now(), seconds * 1000.0):
            return Status.SUCCESS
        return Status.RUNNING


NODES = (
    CreateTwistStamped,
    UnpackTwistStampedMessage,
    CreateWrenchStamped,
    UnpackWrenchStampedMessage,
    PublishEmpty,
    CallTriggerService,
    WaitForDuration,
)
