"""ROS 2 side of the runtime: ``RosBus`` (rclpy binding of ``runtime.io.bus``) and the project's
interface packages (``interfaces/``, built into the venv by ``runtime.app.build_interfaces``)."""
from .bus import RosBus, RosClientGoalHandle, RosFuture, RosServerGoalHandle

__all__ = ["RosBus", "RosClientGoalHandle", "RosFuture", "RosServerGoalHandle"]
