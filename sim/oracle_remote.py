"""The scripted oracle in its own process (``objective serve --backend oracle``).

The oracle is a cheat by design: it plans from where the cubes really are, which no learned
policy could know. In the headless runtime it reads them straight from the simulated cell
(``sim.oracle.CellPeek``). Behind the HTTP server it lives in another process, so its
privileged view comes over ROS 2 instead:

- **Cube poses**: the world publishes one ``geometry_msgs/TransformStamped`` per cube on
  ``/cube_poses/cube_<color>`` (frame ``world``, child ``cube_<color>``). ``RosCubePeek`` keeps
  the latest of each, from its own rclpy context and node (``RosBus``), on loopback
  (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless the environment says otherwise).
- **Sim time**: the request's ``robot_state.header.stamp``, which the adapter forwards on the
  wire (``PolicyRequest.stamp``). The oracle's plan is a function of time; the stamp of the
  observed joint state is the robot's clock at the request instant, whichever process asks.

Nothing here is part of the GetActionChunk contract: a real policy sees only the request.
``cube_pose_msg`` and ``CUBE_POSE_TOPIC`` are what a world uses to publish the poses.
"""
from __future__ import annotations

import logging
import os
import time
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
from numpy.typing import NDArray
from geometry_msgs.msg import TransformStamped

from policy.backend import PolicyRequest, PolicyResponse

if TYPE_CHECKING:
    from runtime.motion.scene.model import RobotModel
from runtime.io.timestamps import time_msg

from .oracle import COLORS, ArmKinematics, OracleBackend, OracleConfig

CUBE_POSE_TOPIC = "/cube_poses/cube_{color}"
CUBE_POSE_WAIT_S = 6.0
"""How long a request waits for the first pose of a cube it needs before answering ERROR. A world
that starts after the oracle is usually discovered within 0.3 s, but a missed first announcement
waits for Fast DDS's next periodic one (measured: 3.8 s on a loaded machine), so the first request
of a run (its warmup) may wait that long; give that call a ``policy_call_timeout`` above it."""

log = logging.getLogger("objective.oracle_remote")


def cube_pose_msg(color: str, position: Sequence[float] | NDArray[np.float64], quat_wxyz: Sequence[float] | NDArray[np.float64],
                  stamp: float) -> TransformStamped:
    """The message a world publishes on ``CUBE_POSE_TOPIC`` for one cube (world frame)."""
    msg = TransformStamped()
    msg.header.stamp = time_msg(stamp)
    msg.header.frame_id = "world"
    msg.child_frame_id = f"cube_{color}"
    t, r = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = (float(v) for v in position)
    r.w, r.x, r.y, r.z = (float(v) for v in quat_wxyz)
    return msg


def pose_from_msg(msg: TransformStamped) -> tuple[np.ndarray, np.ndarray]:
    """Position (3,) and quaternion (w, x, y, z) of a ``cube_pose_msg``."""
    t, r = msg.transform.translation, msg.transform.rotation
    return np.array([t.x, t.y, t.z]), np.array([r.w, r.x, r.y, r.z])


class RosCubePeek:
    """``OraclePeek`` over ROS 2 topics (cube poses) and the current request (time)."""

    def __init__(self, kinematics: ArmKinematics, bus: Any, wait_s: float = CUBE_POSE_WAIT_S) -> None:
        """``bus`` is a ``runtime.io.ros.RosBus`` (or any bus whose subscriptions keep ``latest``)."""
        self.kinematics = kinematics
        self.bus = bus
        self.wait_s = wait_s
        self.now = 0.0
        """The current request's stamp; ``RemoteOracleBackend`` sets it before each inference."""
        self.topics = {color: CUBE_POSE_TOPIC.format(color=color) for color in COLORS}
        self.subscriptions = {color: bus.create_subscription(topic, TransformStamped) for color, topic in self.topics.items()}

    def missing(self, colors: Sequence[str]) -> list[str]:
        """Topics of ``colors`` that have delivered nothing, after waiting up to ``wait_s`` for them."""
        deadline = time.monotonic() + self.wait_s
        while True:
            absent = [self.topics[c] for c in colors if self.subscriptions[c].latest is None]
            if not absent or time.monotonic() >= deadline:
                return absent
            time.sleep(0.01)

    def cube_pose(self, color: str) -> tuple[np.ndarray, np.ndarray]:
        msg = self.subscriptions[color].latest
        if msg is None:
            raise KeyError(f"no pose received on {self.topics[color]}")
        return pose_from_msg(msg)

    def time(self) -> float:
        return self.now


class RemoteOracleBackend:
    """The oracle as a server backend: ``load()`` builds the robot model and joins the ROS graph."""

    name = "oracle"

    def __init__(self, config: OracleConfig | None = None, wait_s: float = CUBE_POSE_WAIT_S,
                 robot: RobotModel | None = None, node_name: str = "oracle_peek") -> None:
        self.config = config
        self.wait_s = wait_s
        self.robot = robot
        self.node_name = node_name
        self.peek: RosCubePeek | None = None
        self.oracle: OracleBackend | None = None
        self._bus: Any = None

    def load(self) -> None:
        os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        from runtime.io.clock import WallClock
        from runtime.io.ros import RosBus

        from .oracle import SceneKinematics

        robot = self.robot
        if robot is None:
            from sim.robot_model import planning_robot_model

            robot = planning_robot_model()
        kinematics = SceneKinematics(robot)
        self._bus = RosBus(WallClock(), node_name=self.node_name, num_threads=2)
        self.peek = RosCubePeek(kinematics, self._bus, self.wait_s)
        self.oracle = OracleBackend(self.peek, self.config)
        log.info("oracle peeks at cube poses on %s", ", ".join(self.peek.topics.values()))

    def warmup(self, example_request: PolicyRequest) -> None:
        """Nothing to compile (plans take tens of milliseconds); the model was built in ``load``."""
        if self.oracle is None:
            raise RuntimeError("the remote oracle is not loaded: call load() first")

    def infer(self, request: PolicyRequest) -> PolicyResponse:
        if self.oracle is None or self.peek is None:
            raise RuntimeError("the remote oracle is not loaded: call load() first")
        absent = self.peek.missing(COLORS)
        if absent:
            return PolicyResponse.error(
                f"the oracle has no cube pose on {', '.join(absent)} after {self.wait_s:.1f} s: the world must "
                "publish geometry_msgs/TransformStamped there (the oracle's privileged view of the sim)"
            )
        self.peek.now = float(request.stamp)
        return self.oracle.infer(request)

    def close(self) -> None:
        if self._bus is not None:
            self._bus.close()
            self._bus = None


def serve_backend(options: Any) -> RemoteOracleBackend:
    """``objective serve --backend oracle`` (the ``objective.policy_backends`` entry point); it
    takes none of the server's backend options."""
    return RemoteOracleBackend()
