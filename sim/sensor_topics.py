"""The cell's sensor topics besides joint states, camera frames and the wrench (which the
``force_torque_sensor_broadcaster`` controller publishes): each camera's ``sensor_msgs/CameraInfo``.

They are lazy topics, like the camera frames: a message is produced when someone reads it (in
process) or at ``rate_hz`` (on real ROS 2).
"""
from __future__ import annotations

import functools
import math
from typing import Any

from sensor_msgs.msg import CameraInfo

from runtime.io.timestamps import time_msg

from .cell_model import CAMERA_FOVY_DEG, CAMERA_NAMES

CAMERA_INFO_TOPICS = {name: f"/{name}_camera/camera_info" for name in CAMERA_NAMES}


def pinhole_camera_info(frame_id: str, width: int, height: int, fovy_deg: float) -> CameraInfo:
    """CameraInfo of an ideal pinhole camera (MuJoCo's: square pixels, no distortion, centred)."""
    f = (height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    info = CameraInfo(width=width, height=height, distortion_model="plumb_bob")
    info.header.frame_id = frame_id
    info.d = [0.0] * 5
    info.k = [f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0]
    info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    info.p = [f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return info


class SensorTopics:
    """Serves the camera infos of ``cell`` (a ``sim.world.Cell``) on ``bus``."""

    def __init__(self, bus: Any, cell: Any, camera_rate_hz: float) -> None:
        self.cell = cell
        self.frame_shapes: dict[str, tuple[int, int]] = {}
        for name, topic in CAMERA_INFO_TOPICS.items():
            bus.create_lazy_publisher(topic, CameraInfo, functools.partial(self.camera_info, name), rate_hz=camera_rate_hz)

    def camera_info(self, camera: str) -> CameraInfo:
        if camera not in self.frame_shapes:  # the size of the frames the cell renders
            self.frame_shapes[camera] = self.cell.render(camera).shape[:2]
        height, width = self.frame_shapes[camera]
        info = pinhole_camera_info(f"{camera}_camera", width, height, CAMERA_FOVY_DEG[camera])
        info.header.stamp = time_msg(self.cell.t)
        return info
