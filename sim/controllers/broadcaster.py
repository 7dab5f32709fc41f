"""``force_torque_sensor_broadcaster``: the wrist sensor's wrench on a topic, as ros2_controllers'
``force_torque_sensor_broadcaster`` publishes it.

Publishes ``geometry_msgs/WrenchStamped`` on ``/force_torque_sensor_broadcaster/wrench`` (reliable,
as the broadcaster's default QoS) while active: the wrench the environment applies to the tool,
about the sensor, in world axes (frame ``world``), the gripper's weight removed. Like the cameras it
is a lazy topic: a reading is produced when someone reads it in process, and at
``WRENCH_RATE_HZ`` on real ROS 2. It claims no command interface, so it runs beside any other
controller.
"""
from __future__ import annotations

from geometry_msgs.msg import WrenchStamped

from runtime.io.bus import Bus
from runtime.io.clock import Clock
from runtime.io.timestamps import time_msg

from ..hardware import Hardware
from .base import FT_STATE_INTERFACES, Controller, ControllersConfig

WRENCH_RATE_HZ = 100.0


class ForceTorqueSensorBroadcaster(Controller):
    type_name = "force_torque_sensor_broadcaster/ForceTorqueSensorBroadcaster"

    def __init__(self, name: str, bus: Bus, hardware: Hardware, clock: Clock, config: ControllersConfig) -> None:
        super().__init__(name, hardware, clock, config)
        self.topic = f"/{name}/wrench"
        bus.create_lazy_publisher(self.topic, WrenchStamped, self.reading, rate_hz=WRENCH_RATE_HZ)

    @property
    def state_interfaces(self) -> tuple[str, ...]:
        return FT_STATE_INTERFACES

    def reading(self) -> WrenchStamped | None:
        """The sensor's wrench now (None while inactive: nothing is published)."""
        if not self.active:
            return None
        fx, fy, fz, tx, ty, tz = (float(v) for v in self.hardware.wrench())
        msg = WrenchStamped()
        msg.header.frame_id = "world"
        msg.header.stamp = time_msg(self.hardware.time())
        msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = fx, fy, fz
        msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = tx, ty, tz
        return msg
