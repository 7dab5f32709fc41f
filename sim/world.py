"""The worlds that host the cell in a run: ``vla_sim`` (MuJoCo physics) and ``kinematic``.

Both put the same things on the bus, with ROS names: ``/joint_states`` (the six arm joints, then
``robotiq_85_left_knuckle_joint``), the three cameras (rendered lazily: a frame is produced when
someone reads it), ``/cube_poses/cube_<color>``, the controller manager and its controllers,
and the embedded policy on ``/get_action_chunk`` (``--policy``). They fill the run's planning
scene (robot, table, cubes; cubes follow the simulation every tick) and its waypoints. They
differ only in the cell behind them: a ``MujocoCell`` or a ``KinematicCell``.
"""
from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any, Callable, Protocol, cast

import numpy as np
from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import Image, JointState

from policy.images import rgb_to_image
from runtime.tree.behavior import RunContext
from runtime.tree.resources import WAYPOINTS
from runtime.motion.joint_states import joint_state
from runtime.io.timestamps import time_msg
from runtime.errors import OptionError

from .cell_model import CAMERA_NAMES, CUBE_COLORS, CellOptions, image_size_problem
from .controllers import JTC_CONTROLLER, TRAJECTORY_CONTROLLER, ControllersConfig, JtcParams, make_controllers
from .embedded_policy import make_backend, serve_embedded_policy
from .hardware import Hardware
from .planning import CubeContact, make_cell_scene, sync_cubes
from .oracle_remote import CUBE_POSE_TOPIC, cube_pose_msg

if TYPE_CHECKING:
    from runtime.motion.scene import PlanningScene
from .robot_model import ARM_JOINTS, GRIPPER_DRIVER_JOINT, load_waypoints
from .sim_boxes import PlacedBoxes

CONTROL_PERIOD = 0.002
CAMERA_TOPICS = {name: f"/{name}_camera/color" for name in CAMERA_NAMES}
JOINT_STATE_NAMES = (*ARM_JOINTS, GRIPPER_DRIVER_JOINT)


class Cell(Hardware, Protocol):
    t: float

    def cube_pose(self, color: str) -> tuple[np.ndarray, np.ndarray]: ...

    def cube_poses(self) -> dict[str, tuple[np.ndarray, np.ndarray]]: ...

    def step(self, dt: float) -> None: ...

    def reset(self, seed: int, arm: np.ndarray) -> None: ...

    def render(self, camera: str) -> np.ndarray: ...

    def snapshot(self) -> Any:
        """A copy of the state now, which ``render_snapshot`` draws on another thread."""
        ...

    def render_snapshot(self, snapshot: Any, camera: str) -> np.ndarray: ...

    def close_snapshot_renderer(self) -> None:
        """Release what ``render_snapshot`` set up (called on the thread that rendered)."""
        ...

    def place_box(self, name: str, size_m: np.ndarray, position_m: np.ndarray, quat_wxyz: np.ndarray) -> None: ...

    def remove_box(self, name: str) -> None: ...

    def close(self) -> None: ...


COMMON_OPTIONS = ("seed", "realtime", "policy_latency", "record_dir", "policy", "start", "joint_states_reliable",
                  "image_size", "encoding", "camera_rate_hz", "cube_contact", "allow_trajectory_replacement")


def option_flag(options: dict[str, Any], name: str, default: bool) -> bool:
    """A yes/no world option: a bool, or "true"/"false" as ``--world-option NAME=VALUE`` gives it."""
    value = options.get(name, default)
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("true", "1", "yes"):
        return True
    if text in ("false", "0", "no"):
        return False
    raise OptionError(f"option '{name}' must be true or false, got '{value}'")


def number_option(options: dict[str, Any], key: str, default: float, kind: type = float) -> Any:
    """The option ``key`` as a number of type ``kind`` (``--world-option`` gives text); OptionError if it is not one."""
    value = options.get(key)
    if value is None or value == "":
        return kind(default)
    try:
        return kind(value)
    except (TypeError, ValueError):
        raise OptionError(f"option '{key}' must be {'a whole number' if kind is int else 'a number'}, got {value!r}") from None


def image_size_option(options: dict[str, Any], default: int) -> int:
    """``--world-option image_size=N``: the cameras' width and height in pixels; OptionError outside
    the sizes a cell renders (``cell_model.IMAGE_SIZES_PX``)."""
    size = number_option(options, "image_size", default, int)
    problem = image_size_problem(size)
    if problem is not None:
        raise OptionError(f"option 'image_size' {problem}")
    return int(size)


class CellClock:
    """The simulated robot's own clock: the time of the cell's next control step.

    The controllers read it when a goal, a command or a switch arrives, so whatever arrives is
    applied at the next control step, on the robot's time. With ``--realtime`` the runtime clock
    (wall time) runs ahead of the cell between two world steps, by however long the tick's work
    took; a goal stamped "now" on the wall clock would otherwise start, and be trimmed, at an
    instant the control loop has not reached, and the steps in between would jump the command.
    On a ``SimClock`` the two agree after every world step.
    """

    def __init__(self, cell: Cell) -> None:
        self.cell = cell

    def now(self) -> float:
        return self.cell.t

    def advance(self, dt: float) -> None:
        raise RuntimeError("the cell's clock moves only when the world steps the cell (CellWorld.step_to)")


class CellWorld:
    """A cell's services on the bus, stepped at 500 Hz of the runtime clock; its controllers
    run on the cell's own clock (``CellClock``). A ``runtime.tree.world.World``, and
    ``KeepsEpisodes`` and ``PlacesBoxes`` besides."""

    def __init__(self, name: str, options: dict[str, Any], make_cell: Callable[[np.ndarray, int], Cell]) -> None:
        unknown = sorted(set(options) - set(COMMON_OPTIONS))
        if unknown:
            raise OptionError(f"unknown options {', '.join(unknown)} (known: {', '.join(COMMON_OPTIONS[4:])})")
        self.name = name
        self.options = options
        self.seed = int(options.get("seed") or 0)
        self.encoding = str(options.get("encoding") or "rgb8")
        if self.encoding not in ("rgb8", "bgr8"):
            raise OptionError(f"encoding must be rgb8 or bgr8, got '{self.encoding}'")
        self.waypoints = load_waypoints()
        start = str(options.get("start") or "Ready")
        if start not in self.waypoints:
            raise OptionError(f"unknown start waypoint '{start}' (waypoints: {', '.join(self.waypoints)})")
        self.start_arm = np.array([self.waypoints[start][j] for j in ARM_JOINTS])
        self.cube_contact = CubeContact.parse(options.get("cube_contact") or CubeContact.GRIPPER)
        # The cell's JTC streams from what it commands (interpolate_from_desired_state), as a JTC
        # that plays streamed goals should; the replacement mode is a world option.
        replacement = option_flag(options, "allow_trajectory_replacement", True)
        self.controllers_config = ControllersConfig(
            joint_trajectory=JtcParams(allow_trajectory_replacement=replacement, interpolate_from_desired_state=True))
        self.cell = make_cell(self.start_arm, self.seed)
        self.boxes = PlacedBoxes()

    # -- World -------------------------------------------------------------------------------
    def start(self, context: RunContext) -> None:
        self.context = context
        bus = context.bus
        self.controllers = make_controllers(bus, self.cell, CellClock(self.cell), self.controllers_config)
        reliable = option_flag(self.options, "joint_states_reliable", True)
        self.joint_states = bus.create_publisher("/joint_states", JointState, reliable=reliable)
        rate = number_option(self.options, "camera_rate_hz", 10.0)  # used on real ROS only
        self.camera_thread = None
        if bus.produces_on_read:  # in process: a frame is rendered when it is read
            for name, topic in CAMERA_TOPICS.items():
                bus.create_lazy_publisher(topic, Image, functools.partial(self._camera_frame, name), rate_hz=rate)
            if self.options.get("realtime"):  # a first frame makes the renderer (GL context, meshes): not in a tick
                for name in CAMERA_TOPICS:
                    self.cell.render(name)
        else:  # pushed at a rate (ROS 2): rendered off the tick's thread
            from .camera_thread import CameraThread

            publishers = {name: bus.create_publisher(topic, Image) for name, topic in CAMERA_TOPICS.items()}
            self.camera_thread = CameraThread(self.cell, publishers, rate, self._frame_message)
        from .sensor_topics import SensorTopics  # camera infos

        self.sensor_topics = SensorTopics(bus, self.cell, rate)
        for color in CUBE_COLORS:  # the remote oracle's privileged view
            bus.create_lazy_publisher(
                CUBE_POSE_TOPIC.format(color=color), TransformStamped, functools.partial(self._cube_pose, color), rate_hz=50.0
            )
        context.scene = make_cell_scene(self.cell.cube_poses(), cube_contact=self.cube_contact)
        self.synced_cubes = sync_cubes(context.scene, self.cell.cube_poses())
        context.resources.set(WAYPOINTS, self.waypoints)
        context.world = self
        self.adapter = serve_embedded_policy(bus, self.options.get("policy"), self.cell, self.options.get("policy_latency"), self.seed)
        self._publish()

    @property
    def _scene(self) -> PlanningScene:
        return cast("PlanningScene", self.context.scene)  # the cell's own, which start() made

    def step_to(self, t: float) -> None:
        times, now = [], self.cell.t
        while now + CONTROL_PERIOD <= t + 1e-9:  # the cell's own clock arithmetic (t += dt per step)
            times.append(now)
            now += CONTROL_PERIOD
        self.controllers.advance(times, CONTROL_PERIOD, self.cell.step)
        self._publish()
        if self.camera_thread is not None:
            self.camera_thread.offer(self.cell.t)
        self.synced_cubes = sync_cubes(self._scene, self.cell.cube_poses(), self.synced_cubes)

    def reset(self, seed: int) -> None:
        self.seed = seed
        self.cell.reset(seed, self.start_arm)
        self.boxes.forget(self._scene)
        self.controllers.reset()
        self.synced_cubes = sync_cubes(self._scene, self.cell.cube_poses())
        self._publish()

    def place_box(self, name: str, size_m: Any, pose: Any, mirror: bool = True) -> None:
        """Make a fixed box appear in the cell at ``pose`` (4x4, world frame), or move it there,
        mirrored into the planning scene unless ``mirror`` is False. ValueError says why not."""
        self.boxes.place(self.cell, self._scene, name, size_m, pose, mirror)

    def remove_box(self, name: str) -> None:
        self.boxes.remove(self.cell, self._scene, name)

    def begin_episode(self, seed: int) -> None:
        """Before ``start`` with a new run's context: the cell as a newly created world with
        ``seed`` would have it (layout of ``seed``, arm at the start waypoint, time 0). Lets an
        evaluation keep one world (its compiled model and renderer) for many episodes."""
        self.seed = seed
        self.options = {**self.options, "seed": seed}
        self.cell.reset(seed, self.start_arm)
        self.cell.t = 0.0
        self.boxes = PlacedBoxes()  # the cell's reset parked every placed box

    def policy_backend(self, spec: Any) -> Any:
        """The embedded policy ``spec`` names, built for this cell (``embedded_policy.make_backend``)."""
        return make_backend(spec, self.cell)

    def summary(self) -> dict[str, Any]:
        summary: dict[str, Any] = {
            "seed": self.seed,
            "cubes": {c: [round(float(v), 4) for v in self.cell.cube_pose(c)[0]] for c in CUBE_COLORS},
            "gripper": round(self.cell.gripper_position(), 4),
        }
        if self.boxes.boxes:
            summary["boxes"] = self.boxes.summary()
        frames = getattr(self, "camera_thread", None)
        if frames is not None:  # on ROS 2: frame sets published, and due sets the renderer could not keep up with
            summary["camera_sets"] = {"published": frames.sets_published, "skipped": frames.sets_skipped}
        controllers = getattr(self, "controllers", None)  # absent when the world never started
        if controllers is not None:  # what the F/T thresholds were compared with, on either trajectory controller
            arms = (controllers[TRAJECTORY_CONTROLLER], controllers[JTC_CONTROLLER])
            summary["peak_force_n"] = round(max(c.peak_force_n for c in arms), 2)
            summary["peak_torque_nm"] = round(max(c.peak_torque_nm for c in arms), 3)
        return summary

    def close(self) -> None:
        camera_thread = getattr(self, "camera_thread", None)
        if camera_thread is not None:
            camera_thread.close()
        self.cell.close()

    # -- publishing --------------------------------------------------------------------------
    def _publish(self) -> None:
        cell = self.cell
        self.joint_states.publish(joint_state(
            cell.t, JOINT_STATE_NAMES,
            cell.arm_position().tolist() + [cell.gripper_position()],
            cell.arm_velocity().tolist() + [cell.gripper_velocity()],
        ))

    def _cube_pose(self, color: str) -> TransformStamped:
        position, quat = self.cell.cube_pose(color)
        return cube_pose_msg(color, position, quat, self.cell.t)

    def _camera_frame(self, camera: str) -> Image:
        return self._frame_message(camera, self.cell.render(camera), self.cell.t)

    def _frame_message(self, camera: str, pixels: np.ndarray, t: float) -> Image:
        if self.encoding == "bgr8":
            pixels = np.ascontiguousarray(pixels[..., ::-1])
        image = rgb_to_image(pixels, encoding=self.encoding, frame_id=f"{camera}_camera")
        image.header.stamp = time_msg(t)
        return image


def create_vla_sim(options: dict[str, Any]) -> CellWorld:
    """World ``vla_sim``: the MuJoCo cell."""
    from .mujoco_cell import MujocoCell

    size = image_size_option(options, 224)
    cell_options = CellOptions(image_width=size, image_height=size)
    return CellWorld("vla_sim", options, lambda arm, seed: MujocoCell(cell_options, arm, seed))
