"""MoveIt Pro's camera nodes: GetImage and GetCameraInfo read the next message on a camera topic.

The cell's cameras publish ``sensor_msgs/Image`` on ``/<name>_camera/color`` and
``sensor_msgs/CameraInfo`` on ``/<name>_camera/camera_info`` (``scene``, ``wrist``, ``overview``).
Both nodes wait first for the topic to have a publisher (``publisher_timeout_sec``), then for a
message (``message_timeout_sec``), and fail naming the topic when either does not come.
"""
from __future__ import annotations

import enum
from typing import Any, ClassVar

from sensor_msgs.msg import CameraInfo, Image

from runtime.tree.behavior import Behavior, Status
from runtime.tree.ports import InputPort, OutputPort, PortInfo, PortType, Range

from .waiting import Deadline, release_subscription


class Wait(enum.Enum):
    PUBLISHER = 1
    MESSAGE = 2


class _GetMessage(Behavior):
    """Wait for a publisher, then for a message, on ``topic_name``; write it to ``message_out``."""

    needs_world = True
    msg_type: ClassVar[type]

    @classmethod
    def make_ports(cls, port_type: PortType, example: str) -> tuple[PortInfo, ...]:
        return (
            InputPort("topic_name", PortType.STRING, description=f"The topic, e.g. {example}."),
            InputPort("message_timeout_sec", PortType.FLOAT, 5.0, "Seconds to wait for a message once the topic has a publisher.", valid=Range(0, 3600, "s")),
            InputPort("publisher_timeout_sec", PortType.FLOAT, 5.0, "Seconds to wait for the topic to have a publisher.", valid=Range(0, 3600, "s")),
            OutputPort("message_out", port_type, "The message."),
        )

    def initialise(self) -> None:
        self.topic = self.get_input("topic_name")
        self.subscription = self.context.bus.create_subscription(self.topic, self.msg_type, reliable=False)
        self.wait = Wait.PUBLISHER
        self.deadline = Deadline(self, self.get_input("publisher_timeout_sec"))

    def update(self) -> Status:
        if self.wait is Wait.PUBLISHER:
            if not self.subscription.has_publishers():
                if self.deadline.expired:
                    return self.fail(f"no publisher on '{self.topic}' after {self.deadline.seconds:g} s")
                return Status.RUNNING
            self.wait = Wait.MESSAGE
            self.deadline = Deadline(self, self.get_input("message_timeout_sec"))
        message: Any = self.subscription.latest
        if message is None:
            if self.deadline.expired:
                return self.fail(f"no message on '{self.topic}' after {self.deadline.seconds:g} s")
            return Status.RUNNING
        self.set_output("message_out", message)
        return Status.SUCCESS

    def terminate(self, new_status: Status) -> None:
        release_subscription(self)


class GetImage(_GetMessage):
    """MoveIt Pro's GetImage."""

    msg_type = Image
    description: ClassVar[str] = "Wait for the next sensor_msgs/Image on a camera topic (e.g. /wrist_camera/color) and write it."
    ports = _GetMessage.make_ports(PortType.IMAGE, "/wrist_camera/color")


class GetCameraInfo(_GetMessage):
    """MoveIt Pro's GetCameraInfo."""

    msg_type = CameraInfo
    description: ClassVar[str] = "Wait for the next sensor_msgs/CameraInfo on a topic (e.g. /wrist_camera/camera_info) and write it."
    ports = _GetMessage.make_ports(PortType.CAMERA_INFO, "/wrist_camera/camera_info")


NODES = (GetImage, GetCameraInfo)
