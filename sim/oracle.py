"""The scripted oracle policy: stacks one cube on another, answering GetActionChunk like a 10 Hz VLA.

It is the embedded default policy of the worked example. Unlike a learned policy it cheats on
purpose: through an ``OraclePeek`` it reads the cube poses and the clock straight from the
simulator and uses the planning scene's inverse kinematics, so it succeeds from any seeded
layout and lets every other piece (ExecutePolicy, the controllers, the checks) be exercised
without a GPU.

How it answers (``OracleBackend.infer``):

1. The prompt names the cubes: "stack the blue cube on the green cube", "put the red cube on
   top of the blue cube" (case-insensitive, colors red/green/blue). Anything else answers ERROR
   saying the prompt cannot be read.
2. On ``new_episode`` (and whenever it has no plan, the prompt changed or the clock went back),
   it plans the whole task from the observed joint state: pre-grasp above the top cube (gripper
   pointing down, opening it on the way), descend, close, lift, move above the bottom cube,
   descend, open, retreat. The plan is a function of time (``TaskPlan``).
3. Each answer is ``chunk_size`` steps of that function at ``control_period`` (10 Hz), starting
   at the request instant: ``plan(now - plan.start + k * period)``, columns in the request's
   ``robot_state.name`` order (arm joints, then the gripper joint: 0.0 open .. 0.8 closed).
4. After the plan ends it keeps answering the final pose (a hold), never NO_MORE_ACTIONS: the
   Objective's ``total_action_steps`` bounds the run and the success check after it decides.
5. If the grasped cube is seen to have left the gripper while being carried, it re-plans from
   the current state (up to ``max_replans`` times per episode), so a slipped grasp is retried.

Real-time chunking: each answer also carries its actions as ``policy_actions`` (its action
space is the request's columns), so an Objective with ``policy_uses_real_time_chunking="true"``
(the guide's example ports, MoveIt Pro's own Objective) gets the carryover it expects. The oracle
needs no guidance towards that carryover: every chunk samples the same plan, so a chunk already
agrees with the one before it (a re-plan after a slipped grasp starts from the observed state).

Motion design. Every segment is a geometric path ``q(s)``, ``s`` in [0, 1], timed by the
minimum-jerk profile ``s(t) = 10 tau^3 - 15 tau^4 + 6 tau^5`` (zero velocity and acceleration at
both ends, so segments join smoothly). Free moves interpolate linearly in joint space; the
vertical moves (descend, lift, place, retreat) are straight lines of the TCP, sampled every
centimetre through IK and splined in ``s``. Each segment's duration is the shortest that keeps
every joint below ``max_joint_velocity`` and ``max_joint_acceleration`` (both well below the
UR5e's limits, because ExecutePolicy rejects chunks over the limits) and the TCP below
``max_linear_speed``.

Grasp geometry (2F-85, measured on the composed model): with the fingers closed on a 30 mm cube
the pad tips reach 17.3 mm beyond the TCP. The grasp puts the TCP ``grasp_height`` (18 mm) above
the cube's centre, so the pads hold the cube's upper part and the fingertips stay about 16 mm
above the table: outside the 10 mm ``link_padding`` the planning scene puts around the robot.
The fingers close along the TCP's y axis; the wrist yaw is the cube's yaw modulo 90 degrees
closest to the current wrist yaw, so the pads meet two faces squarely with the least wrist turn.
"""
from __future__ import annotations

import math
import re
import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Protocol, Sequence

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from runtime.motion.scene.model import RobotModel

from policy.backend import PolicyRequest, PolicyResponse
from policy.stack_keypoints import StackGeometry, stack_poses, tcp_yaw, top_down_pose, wrap_quarter
from runtime.errors import ObjectiveError

COLORS = ("red", "green", "blue")

# ---------------------------------------------------------------------------------------------
# What the oracle peeks at
# ---------------------------------------------------------------------------------------------


class ArmKinematics(Protocol):
    """Forward and inverse kinematics of the arm's tool centre point (TCP), world frame."""

    @property
    def joint_names(self) -> Sequence[str]:
        """The arm joints, in the order ``q`` uses."""
        ...

    def tcp_pose(self, q: np.ndarray) -> np.ndarray:
        """4 x 4 homogeneous pose of the TCP (z axis pointing out of the gripper) at ``q``."""
        ...

    def solve_ik(self, target: np.ndarray, seed: np.ndarray) -> np.ndarray:
        """Joint positions reaching the 4 x 4 TCP ``target``, near ``seed``; raises ``ValueError`` if none."""
        ...


class OraclePeek(Protocol):
    """Privileged access to the simulation, which a real policy would not have."""

    kinematics: ArmKinematics

    def cube_pose(self, color: str) -> tuple[np.ndarray, np.ndarray]:
        """World position (3,) and orientation quaternion (w, x, y, z) of the ``color`` cube."""
        ...

    def time(self) -> float:
        """Simulation time, seconds (the clock ExecutePolicy's requests are made on)."""
        ...


# ---------------------------------------------------------------------------------------------
# Prompt
# ---------------------------------------------------------------------------------------------
class PromptError(ObjectiveError, ValueError):
    """The prompt does not say which cube goes on which."""


_PROMPT = re.compile(
    r"^\s*(?:please\s+)?(?:stack|put|place)\s+(?:the\s+)?(\w+)\s+cube\s+(?:on\s+top\s+of|onto|on)\s+"
    r"(?:the\s+)?(\w+)\s+cube\s*[.!]?\s*$",
    re.IGNORECASE,
)


def parse_prompt(prompt: str) -> tuple[str, str]:
    """``(top, bottom)`` colors from "stack the <color> cube on the <color> cube" and variants."""
    expected = f"cannot read the prompt '{prompt}': expected 'stack the <color> cube on the <color> cube'"
    match = _PROMPT.match(prompt)
    if not match:
        raise PromptError(expected)
    top, bottom = (c.lower() for c in match.groups())
    if top not in COLORS or bottom not in COLORS:
        raise PromptError(f"{expected} with colors {', '.join(COLORS)}")
    if top == bottom:
        raise PromptError(f"{expected}: the two cubes must have different colors")
    return top, bottom


# ---------------------------------------------------------------------------------------------
# Poses (pure)
# ---------------------------------------------------------------------------------------------
def quat_to_matrix(quat_wxyz: Sequence[float] | NDArray[np.float64]) -> np.ndarray:
    w, x, y, z = np.asarray(quat_wxyz, dtype=float) / np.linalg.norm(quat_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def cube_yaw(quat_wxyz: Sequence[float] | NDArray[np.float64]) -> float:
    """Heading of the cube's side faces in [-pi/4, pi/4): a cube repeats every quarter turn.

    Whichever face is up, the two cube axes that lie (nearly) horizontal give the face normals.
    """
    rotation = quat_to_matrix(quat_wxyz)
    up_axis = int(np.argmax(np.abs(rotation[2, :])))
    side = rotation[:, (up_axis + 1) % 3]
    return wrap_quarter(math.atan2(side[1], side[0]))


# ---------------------------------------------------------------------------------------------
# Timing (pure)
# ---------------------------------------------------------------------------------------------
MIN_JERK_PEAK_VELOCITY = 1.875
"""max ds/dtau of the minimum-jerk profile."""
MIN_JERK_PEAK_ACCELERATION = 10.0 / math.sqrt(3.0)
"""max |d2s/dtau2| of the minimum-jerk profile (about 5.77)."""


def min_jerk(tau: np.ndarray | float) -> np.ndarray:
    """``s(tau)`` for tau in [0, 1] (clipped outside)."""
    t = np.clip(tau, 0.0, 1.0)
    return t**3 * (10.0 - 15.0 * t + 6.0 * t * t)


def segment_duration(
    path: Callable[[np.ndarray], np.ndarray],
    max_velocity: float,
    max_acceleration: float,
    min_duration: float,
    tcp_length: float = 0.0,
    max_linear_speed: float = math.inf,
) -> float:
    """Shortest min-jerk duration keeping joints under the limits and the TCP under its speed.

    The path's derivatives ``q'(s)``, ``q''(s)`` are estimated on a dense grid; with the profile
    ``q(t) = q(s(t))``, velocity is ``q' s'`` and acceleration ``q'' s'^2 + q' s''``.
    """
    s = np.linspace(0.0, 1.0, 201)
    q = path(s)
    d1 = np.gradient(q, s, axis=0)
    d2 = np.gradient(d1, s, axis=0)
    v1 = float(np.max(np.abs(d1))) if q.size else 0.0
    a2 = float(np.max(np.abs(d2))) if q.size else 0.0
    candidates = [min_duration, MIN_JERK_PEAK_VELOCITY * v1 / max_velocity]
    # acceleration <= a2 (1.875/T)^2 + v1 5.77/T^2 (a bound: both peaks taken together)
    candidates.append(math.sqrt((a2 * MIN_JERK_PEAK_VELOCITY**2 + v1 * MIN_JERK_PEAK_ACCELERATION) / max_acceleration))
    if tcp_length > 0 and math.isfinite(max_linear_speed):
        candidates.append(MIN_JERK_PEAK_VELOCITY * tcp_length / max_linear_speed)
    return max(candidates)


# ---------------------------------------------------------------------------------------------
# The plan (pure data + evaluation)
# ---------------------------------------------------------------------------------------------
@dataclass
class Segment:
    """One move: arm path ``q(s)`` and a gripper ramp, timed by the min-jerk profile."""

    label: str
    duration: float
    arm: Callable[[np.ndarray], np.ndarray]
    """s array (n,) -> arm positions (n, J)."""
    gripper_start: float
    gripper_end: float

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = min_jerk(np.asarray(t, dtype=float) / self.duration)
        arm = self.arm(s)
        gripper = self.gripper_start + (self.gripper_end - self.gripper_start) * s
        return arm, gripper


def linear_path(q_start: np.ndarray, q_end: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    a, b = np.asarray(q_start, dtype=float), np.asarray(q_end, dtype=float)
    return lambda s: a + np.asarray(s, dtype=float)[:, None] * (b - a)


def hold_path(q: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    fixed = np.asarray(q, dtype=float)
    return lambda s: np.repeat(fixed[None, :], len(np.atleast_1d(s)), axis=0)


def spline_path(samples: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """A C2 path through IK samples equally spaced in ``s``."""
    from scipy.interpolate import CubicSpline  # scipy.interpolate: ~0.3 s, imported when the oracle first plans

    spline = CubicSpline(np.linspace(0.0, 1.0, len(samples)), samples, axis=0)
    return lambda s: spline(np.clip(s, 0.0, 1.0))


@dataclass
class TaskPlan:
    """The whole task as a function of time since ``start`` (sim seconds)."""

    start: float
    segments: list[Segment]
    prompt: str = ""
    top: str = ""
    bottom: str = ""
    grasp_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Top cube centre in the TCP frame while it is held (as planned)."""

    @property
    def duration(self) -> float:
        return sum(seg.duration for seg in self.segments)

    def boundaries(self) -> dict[str, tuple[float, float]]:
        """Segment label -> (start, end) in plan time."""
        out, t = {}, 0.0
        for seg in self.segments:
            out[seg.label] = (t, t + seg.duration)
            t += seg.duration
        return out

    def sample(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arm positions (n, J) and gripper commands (n,) at plan times ``times``.

        Before 0 the plan holds its first point, after ``duration`` its last one (the hold).
        """
        times = np.atleast_1d(np.asarray(times, dtype=float))
        joints = self.segments[0].sample(np.zeros(1))[0].shape[1]
        arm = np.empty((len(times), joints))
        gripper = np.empty(len(times))
        offset = 0.0
        remaining = np.ones(len(times), dtype=bool)
        for index, seg in enumerate(self.segments):
            last = index == len(self.segments) - 1
            mask = remaining & ((times < offset + seg.duration) | last)
            if mask.any():
                a, g = seg.sample(times[mask] - offset)
                arm[mask], gripper[mask] = a, g
                remaining &= ~mask
            offset += seg.duration
        return arm, gripper


# ---------------------------------------------------------------------------------------------
# Planning (needs kinematics)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OracleConfig:
    chunk_size: int = 50
    control_period: float = 0.1
    """Seconds per step, reported as ``native_control_period`` (a 10 Hz policy)."""
    approach_height: float = 0.10
    """How far above the grasp / place pose the gripper approaches and retreats (m)."""
    grasp_height: float = 0.018
    """TCP above the cube centre when grasping: pads on the upper part, fingertips ~16 mm above the table."""
    cube_size: float = 0.03
    place_clearance: float = 0.002
    """Gap left under the top cube when it is released."""
    gripper_open: float = 0.0
    gripper_closed: float = 0.8
    """Commanded past the cube's width: the fingers stall on the cube and hold it by friction."""
    close_time: float = 1.2
    open_time: float = 1.0
    max_gripper_velocity: float = 1.0
    """rad/s of the gripper column; sim/config/joint_limits.yaml allows 2."""
    max_joint_velocity: float = 0.8
    """rad/s; the UR5e allows pi."""
    max_joint_acceleration: float = 1.2
    """rad/s^2; below every joint's limit in sim/config/joint_limits.yaml."""
    max_linear_speed: float = 0.12
    """m/s of the TCP on the straight vertical moves."""
    min_segment_time: float = 0.6
    cartesian_step: float = 0.01
    """Spacing of IK samples on straight TCP lines (m)."""
    max_ik_jump: float = 0.35
    """Largest joint change between neighbouring IK samples before the line is declared broken (rad)."""
    slip_tolerance: float = 0.03
    """Carried cube farther than this from where the grasp put it: re-plan (m)."""
    max_replans: int = 3

    def __post_init__(self) -> None:
        if self.chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {self.chunk_size}")
        for name in ("control_period", "max_joint_velocity", "max_joint_acceleration", "max_linear_speed",
                     "cartesian_step", "max_gripper_velocity"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


class PlanError(ObjectiveError, ValueError):
    """The task cannot be planned from here (unreachable pose, broken IK line)."""


def plan_stack(
    kinematics: ArmKinematics,
    q_start: np.ndarray,
    gripper_start: float,
    top_pose: tuple[np.ndarray, np.ndarray],
    bottom_pose: tuple[np.ndarray, np.ndarray],
    config: OracleConfig,
    start_time: float = 0.0,
) -> TaskPlan:
    """Plan pick (top cube) and place (on the bottom cube) from ``q_start``; raises ``PlanError``."""
    top_pos, top_quat = (np.asarray(v, dtype=float) for v in top_pose)
    bottom_pos, bottom_quat = (np.asarray(v, dtype=float) for v in bottom_pose)
    q_start = np.asarray(q_start, dtype=float)
    poses = stack_poses(top_pos, cube_yaw(top_quat), bottom_pos, cube_yaw(bottom_quat),
                        tcp_yaw(kinematics.tcp_pose(q_start)), StackGeometry(
                            config.grasp_height, config.approach_height, config.cube_size, config.place_clearance))
    grasp_yaw, place_yaw = poses.grasp_yaw_rad, poses.place_yaw_rad
    grasp, place = poses.grasp[:3, 3], poses.place[:3, 3]
    up = np.array([0.0, 0.0, config.approach_height])

    def ik(position: np.ndarray, yaw: float, seed: np.ndarray, what: str) -> np.ndarray:
        try:
            return np.asarray(kinematics.solve_ik(top_down_pose(position, yaw), seed), dtype=float)
        except ValueError as exc:
            raise PlanError(f"no IK solution for the {what} pose at {np.round(position, 3).tolist()}: {exc}") from None

    def line(a: np.ndarray, b: np.ndarray, yaw: float, seed: np.ndarray, what: str) -> np.ndarray:
        count = max(2, int(math.ceil(np.linalg.norm(b - a) / config.cartesian_step)) + 1)
        rows, q = [], seed
        for s in np.linspace(0.0, 1.0, count):
            q = ik(a + s * (b - a), yaw, q, what)
            rows.append(q)
        samples = np.asarray(rows)
        jumps = np.max(np.abs(np.diff(samples, axis=0)))
        if jumps > config.max_ik_jump:
            raise PlanError(f"the {what} line is not continuous in joint space (jump of {jumps:.2f} rad)")
        return samples

    pre_grasp_q = ik(grasp + up, grasp_yaw, q_start, "pre-grasp")
    descend = line(grasp + up, grasp, grasp_yaw, pre_grasp_q, "grasp descent")
    lift = line(grasp, grasp + up, grasp_yaw, descend[-1], "lift")
    pre_place_q = ik(place + up, place_yaw, lift[-1], "pre-place")
    lower = line(place + up, place, place_yaw, pre_place_q, "place descent")
    retreat = line(place, place + up, place_yaw, lower[-1], "retreat")

    g_open, g_closed = config.gripper_open, config.gripper_closed

    def free(label: str, a: np.ndarray, b: np.ndarray, g0: float, g1: float) -> Segment:
        path = linear_path(a, b)
        return Segment(label, _duration(path, config, gripper_change=abs(g1 - g0)), path, g0, g1)

    def straight(label: str, samples: np.ndarray, g: float) -> Segment:
        path = spline_path(samples)
        return Segment(label, _duration(path, config, config.approach_height), path, g, g)

    def hold(label: str, q: np.ndarray, duration: float, g0: float, g1: float) -> Segment:
        duration = max(duration, _duration(hold_path(q), config, gripper_change=abs(g1 - g0)))
        return Segment(label, duration, hold_path(q), g0, g1)

    segments = [
        free("pre_grasp", q_start, pre_grasp_q, gripper_start, g_open),
        straight("descend", descend, g_open),
        hold("close", descend[-1], config.close_time, g_open, g_closed),
        straight("lift", lift, g_closed),
        free("transfer", lift[-1], pre_place_q, g_closed, g_closed),
        straight("place", lower, g_closed),
        hold("open", lower[-1], config.open_time, g_closed, g_open),
        straight("retreat", retreat, g_open),
    ]
    grasp_tcp = top_down_pose(grasp, grasp_yaw)
    offset = grasp_tcp[:3, :3].T @ (top_pos - grasp)
    return TaskPlan(start_time, segments, grasp_offset=offset)


def _duration(
    path: Callable[[np.ndarray], np.ndarray], config: OracleConfig, tcp_length: float = 0.0, gripper_change: float = 0.0
) -> float:
    raw = segment_duration(
        path,
        config.max_joint_velocity,
        config.max_joint_acceleration,
        config.min_segment_time,
        tcp_length,
        config.max_linear_speed,
    )
    raw = max(raw, MIN_JERK_PEAK_VELOCITY * gripper_change / config.max_gripper_velocity)
    # Whole control periods, so segment boundaries fall on policy steps.
    return math.ceil(raw / config.control_period - 1e-9) * config.control_period


# ---------------------------------------------------------------------------------------------
# The backend
# ---------------------------------------------------------------------------------------------
class OracleBackend:
    """The scripted stacking policy as a ``PolicyBackend`` (see the module docstring)."""

    name = "oracle"

    def __init__(self, peek: OraclePeek, config: OracleConfig | None = None) -> None:
        self.peek = peek
        self.config = config or OracleConfig()
        self.plan: TaskPlan | None = None
        self.plans_made = 0
        """Plans computed since construction (new episodes and re-plans)."""
        self.replans = 0
        """Re-plans after a slipped grasp in the current episode."""

    def load(self) -> None:
        """Nothing to load: the oracle's knowledge is the simulator itself."""

    def warmup(self, example_request: PolicyRequest) -> None:
        """Nothing to compile; plans are made per episode (tens of milliseconds)."""

    def infer(self, request: PolicyRequest) -> PolicyResponse:
        try:
            top, bottom = parse_prompt(request.prompt)
        except PromptError as exc:
            return PolicyResponse.error(str(exc))
        columns = self._columns(request.joint_names)
        if isinstance(columns, str):
            return PolicyResponse.error(columns)
        arm_columns, gripper_column = columns
        q_now = request.joint_positions[arm_columns]
        gripper_now = float(request.joint_positions[gripper_column])
        now = float(self.peek.time())

        reason = self._replan_reason(request, now, q_now)
        if reason is not None:
            if reason == "slip":
                self.replans += 1
            elif request.new_episode:
                self.replans = 0
            try:
                self.plan = plan_stack(
                    self.peek.kinematics,
                    q_now,
                    gripper_now,
                    self.peek.cube_pose(top),
                    self.peek.cube_pose(bottom),
                    self.config,
                    start_time=now,
                )
            except (PlanError, KeyError) as exc:
                self.plan = None
                return PolicyResponse.error(f"oracle cannot plan '{request.prompt}': {exc}")
            self.plan.prompt, self.plan.top, self.plan.bottom = request.prompt, top, bottom
            self.plans_made += 1

        assert self.plan is not None
        period = self.config.control_period
        times = now - self.plan.start + period * np.arange(self.config.chunk_size)
        arm, gripper = self.plan.sample(times)
        actions = np.empty((len(times), len(request.joint_names)))
        actions[:, arm_columns] = arm
        actions[:, gripper_column] = gripper
        return PolicyResponse.chunk(actions, period, actions)

    def _columns(self, names: Sequence[str]) -> tuple[list[int], int] | str:
        """Request columns of the arm joints (kinematics order) and of the gripper, or an error."""
        arm_names = list(self.peek.kinematics.joint_names)
        missing = [j for j in arm_names if j not in names]
        if missing:
            return f"oracle needs the arm joints [{', '.join(arm_names)}] in robot_state; missing [{', '.join(missing)}]"
        extra = [n for n in names if n not in arm_names]
        if len(extra) != 1:
            return (
                f"oracle needs exactly one gripper joint after the arm joints in robot_state "
                f"(set gripper_joint_name on ExecutePolicy); got extra joints [{', '.join(extra)}]"
            )
        return [list(names).index(j) for j in arm_names], list(names).index(extra[0])

    def _replan_reason(self, request: PolicyRequest, now: float, q_now: np.ndarray) -> str | None:
        plan = self.plan
        if request.new_episode:
            return "new episode"
        if plan is None:
            return "no plan"
        if plan.prompt != request.prompt:
            return "new prompt"
        if now < plan.start:
            return "clock went back"
        if self.replans < self.config.max_replans and self._slipped(plan, now - plan.start, q_now):
            return "slip"
        return None

    def _slipped(self, plan: TaskPlan, t: float, q_now: np.ndarray) -> bool:
        """While carrying, is the top cube far from where the grasp holds it?"""
        bounds = plan.boundaries()
        carrying = bounds["lift"][0] + 0.5 <= t <= bounds["place"][1]
        if not carrying:
            return False
        tcp = self.peek.kinematics.tcp_pose(q_now)
        expected = tcp[:3, :3] @ plan.grasp_offset + tcp[:3, 3]
        actual = np.asarray(self.peek.cube_pose(plan.top)[0], dtype=float)
        return bool(np.linalg.norm(actual - expected) > self.config.slip_tolerance)


# ---------------------------------------------------------------------------------------------
# Kinematics from the planning scene
# ---------------------------------------------------------------------------------------------
class SceneKinematics:
    """``ArmKinematics`` over the planning scene's robot model (pinocchio FK, DLS IK).

    IK starts from the seed only (no random restarts): the oracle chains IK solutions along
    its paths, and a solution in another arm configuration would make the path jump.
    """

    def __init__(self, robot: RobotModel, group: str = "manipulator", tcp_frame: str = "tcp") -> None:
        from runtime.motion.scene.kinematics import IkSolver, frame_pose

        self._frame_pose = frame_pose
        self.robot, self.group, self.tcp_frame = robot, group, tcp_frame
        self._layout = robot.configuration_map(group, None)
        self.joint_names: tuple[str, ...] = tuple(self._layout.group.joints)
        self._ik = IkSolver(robot, group, tcp_frame)  # fails now on an unknown frame
        self._ik_lock = threading.Lock()

    def tcp_pose(self, q: np.ndarray) -> np.ndarray:
        return self._frame_pose(self.robot, self._layout(np.asarray(q, dtype=float)), self.tcp_frame)

    def solve_ik(self, target: np.ndarray, seed: np.ndarray) -> np.ndarray:
        with self._ik_lock:  # one solver, one caller at a time
            result = self._ik.solve(target, seeds=[np.asarray(seed, dtype=float)], random_restarts=0, max_iterations=200)
        if not result.success:
            raise ValueError(
                f"IK did not converge from the seed (position error {result.position_error * 1000:.1f} mm, "
                f"orientation error {result.orientation_error:.3f} rad)"
            )
        return np.asarray(result.positions, dtype=float)


@dataclass
class CellPeek:
    """``OraclePeek`` over the simulated cell (anything with ``cube_pose(color)`` and ``time()``)."""

    cell: object
    kinematics: ArmKinematics

    def cube_pose(self, color: str) -> tuple[np.ndarray, np.ndarray]:
        position, quat = self.cell.cube_pose(color)  # type: ignore[attr-defined]
        return np.asarray(position, dtype=float), np.asarray(quat, dtype=float)

    def time(self) -> float:
        return float(self.cell.time())  # type: ignore[attr-defined]


def oracle_for_cell(cell: object, robot: RobotModel | None = None, config: OracleConfig | None = None) -> OracleBackend:
    """The oracle peeking at ``cell``, with IK on ``robot`` (default: the cell's planning model)."""
    if robot is None:
        from sim.robot_model import planning_robot_model

        robot = planning_robot_model()
    return OracleBackend(CellPeek(cell, SceneKinematics(robot)), config)
