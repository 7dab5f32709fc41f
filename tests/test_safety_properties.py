"""Property: whatever chunks a policy sends, nothing unsafe reaches the controller.

Random chunks (values near and beyond the joint limits, NaN/inf, wrong shapes, lengths up to and
beyond ``MAX_CHUNK_STEPS``, wrong/permuted/duplicated names, huge steps, motions into the table,
arms starting next to a limit) go through
the real ExecutePolicy (loaded from XML, ticked by the real runner) on an in-process bus, against
a recording controller. Checked on every run:

- every gripper goal that reached the gripper controller is within the gripper joint's position
  limits (runs with a gripper configured carry a gripper column: in range, beyond it, non-finite,
  held, ramped or alternating step by step), and no two goals ask the gripper for more than its
  velocity limit over the policy steps between them;
- every point of every goal that reached the controller is within the position limits and its
  stated velocity and acceleration are within the velocity and acceleration limits (the motion
  *between* densified points is not checked, which is why samples are never more than 10 ms
  apart whatever ``num_interpolation_points`` says: see the last test);
- no such point is in self-collision or in world collision (with the run's link_padding), per
  the cell's planning scene;
- no point the controller plays is outside the run's Cartesian envelope (the cell's
  ``sim/config/cartesian_limits.yaml``, or narrowed by ExecutePolicy's ports): the goal's points and
  the controller's own quintic interpolation between them (``ENVELOPE_SUBSTEPS`` instants per
  piece), each computed here from forward kinematics and the Jacobian, independently of the check;
- the run ends SUCCESS or FAILURE, never with an exception; a FAILURE caused by a chunk says why
  (``rejection_reason`` is set, and names what was wrong).

The default run draws 30 examples; ``-m slow`` runs the 2,000-example profile.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from control_msgs.action import GripperCommand
from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance as FollowTrajectory
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from behaviors.execute_policy.chunk import MAX_CHUNK_STEPS
from runtime.motion.samples import Samples
from behaviors.safety import make_safety
from runtime.io.bus import FixedLatency
from runtime.tree.loader import load_tree
from runtime.app.protective_stop import StopInputs
from runtime.tree.registry import Registry
from runtime.motion.scene.kinematics import frame_jacobian, frame_poses
from runtime.app.runner import RunOptions, make_context, run_tree
from runtime.io.timestamps import time_msg
from sim.layouts import layout
from sim.planning import CUBE_SIZE, make_cell_scene
from sim.controllers.trajectory import quintic_coefficients, quintic_powers
from sim.robot_model import ARM_JOINTS, GRIPPER_DRIVER_JOINT, load_waypoints

R = GetActionChunk.Response
SERVICE = "/get_action_chunk"
CONTROLLER = "/joint_trajectory_admittance_controller/follow_joint_trajectory"
GRIPPER_ACTION = "/robotiq_gripper_controller/gripper_cmd"
PADDING = 0.01
READY = np.array([load_waypoints()["Ready"][j] for j in ARM_JOINTS])
CUBES = {c: (np.array([x, y, CUBE_SIZE / 2]), np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])) for c, (x, y, yaw) in layout(0).items()}
_REGISTRY: list[Registry] = []


def registry() -> Registry:
    if not _REGISTRY:
        _REGISTRY.append(Registry.from_entry_points())
    return _REGISTRY[0]


# --------------------------------------------------------------------------------------------
# A recording controller and a world that is nothing but it, the joint states and the scene
# --------------------------------------------------------------------------------------------
@dataclass
class Goal:
    seam: float
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    names: list[str]


@dataclass
class RecordingWorld:
    """Accepts every goal, records it, "executes" it perfectly (the joint states follow the
    newest goal from its seam on), succeeds it at its end, and cancels superseded goals."""

    initial: np.ndarray
    name: str = "recording"
    goals: list[Goal] = field(default_factory=list)
    gripper_goals: list[float] = field(default_factory=list)
    gripper_goal_times: list[float] = field(default_factory=list)

    envelope: bool = True

    def start(self, context: Any) -> None:
        self.context = context
        context.scene = make_cell_scene(CUBES)
        if not self.envelope:
            context.scene.envelope = None
        self.active: Any = None
        self.active_end = 0.0
        bus = context.bus
        bus.create_action_server(CONTROLLER, FollowTrajectory, self._on_goal, lambda goal: True)
        bus.create_action_server(GRIPPER_ACTION, GripperCommand, self._on_gripper_goal, lambda goal: True)
        self.joint_states = bus.create_publisher("/joint_states", JointState)
        self._publish(0.0)

    def _on_goal(self, handle: Any) -> bool:
        traj = handle.request.joint_trajectory
        seam = traj.header.stamp.sec + traj.header.stamp.nanosec * 1e-9
        pts = traj.points
        offsets = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in pts])
        self.goals.append(Goal(
            seam,
            seam + offsets,
            np.array([list(p.positions) for p in pts], dtype=float),
            np.array([list(p.velocities) for p in pts], dtype=float),
            np.array([list(p.accelerations) for p in pts], dtype=float),
            list(traj.joint_names),
        ))
        if self.active is not None and self.active.is_active:
            self.active.canceled(FollowTrajectory.Result(error_code=FollowTrajectory.Result.SUPERSEDED, error_string="superseded"))
        self.active, self.active_end = handle, float(seam + offsets[-1]) if len(offsets) else seam
        return True

    def _on_gripper_goal(self, handle: Any) -> bool:
        position = float(handle.request.command.position)
        self.gripper_goals.append(position)
        self.gripper_goal_times.append(self.context.clock.now())
        handle.succeed(GripperCommand.Result(position=position, reached_goal=True))
        return True

    def position_at(self, t: float) -> np.ndarray:
        q = self.initial
        for goal in self.goals:
            if len(goal.times) and t >= goal.seam:
                q = np.array([np.interp(t, goal.times, goal.positions[:, j]) for j in range(goal.positions.shape[1])])
        return q

    def step_to(self, t: float) -> None:
        if self.active is not None and self.active.is_active:
            if self.active.is_cancel_requested:
                self.active.canceled(FollowTrajectory.Result(error_code=0, error_string="cancelled"))
            elif t >= self.active_end:
                self.active.succeed(FollowTrajectory.Result(error_code=0, error_string=""))
        self._publish(t)

    def _publish(self, t: float) -> None:
        msg = JointState(name=list(ARM_JOINTS) + [GRIPPER_DRIVER_JOINT], position=self.position_at(t).tolist() + [0.0])
        msg.header.stamp = time_msg(t)
        self.joint_states.publish(msg)

    def summary(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


# --------------------------------------------------------------------------------------------
# Random chunks
# --------------------------------------------------------------------------------------------
LIMITS = make_safety(make_cell_scene(CUBES), "manipulator", None).limits
KINDS = ("smooth", "near_limit", "beyond_limit", "nonfinite", "jump", "into_table", "names", "width", "empty")


@st.composite
def chunk_spec(draw: Any) -> dict[str, Any]:
    """A recipe for one chunk; built against the observed state when the policy is called."""
    return {
        "kind": draw(st.sampled_from(KINDS)),
        "steps": draw(st.one_of(st.integers(1, 60), st.sampled_from([0, 1, 2, 3, 50, 1000, MAX_CHUNK_STEPS + 1]))),
        "velocity": draw(st.lists(st.floats(-2.0, 2.0), min_size=6, max_size=6)),
        "joint": draw(st.integers(0, 5)),
        "at": draw(st.floats(0.0, 1.0)),
        "size": draw(st.floats(-4.0, 4.0)),
        "bad": draw(st.sampled_from([float("nan"), float("inf"), float("-inf")])),
        "names": draw(st.sampled_from(["permuted", "renamed", "duplicated", "missing", "extra", "gripper"])),
        "width": draw(st.sampled_from([0, 5, 7, 12])),
        "seed": draw(st.integers(0, 2**16)),
        "gripper": draw(st.one_of(st.floats(0.0, 0.8), st.floats(-1.0, 2.0),
                                  st.sampled_from([80.0, 50.0, 1.2, 0.8 + 1e-6, -1e-6, -0.5, float("nan"), float("inf")]))),
        "gripper_ramp": draw(st.booleans()),
        "gripper_alternate": draw(st.one_of(st.just(0.0), st.floats(0.0, 0.8))),
    }


def build_chunk(spec: dict[str, Any], observed: np.ndarray, dt: float, gripper: bool = False) -> tuple[list[str], list[list[float]]]:
    """The chunk's names and rows; with ``gripper`` the arm part plus a gripper column that holds
    ``spec["gripper"]`` (or ramps to it from open), every other step moved by
    ``spec["gripper_alternate"]`` (up to 16 rad/s at dt 0.05)."""
    names, rows = _arm_chunk(spec, observed[:6], dt)
    if not gripper or not rows:
        return names, rows
    steps = len(rows)
    value = spec.get("gripper", 0.0)
    column = np.linspace(0.0, value, steps) if spec.get("gripper_ramp") and np.isfinite(value) else np.full(steps, value)
    column = column - spec.get("gripper_alternate", 0.0) * (np.arange(steps) % 2)
    return names + [GRIPPER_DRIVER_JOINT], [list(r) + [float(g)] for r, g in zip(rows, column)]


def _arm_chunk(spec: dict[str, Any], observed: np.ndarray, dt: float) -> tuple[list[str], list[list[float]]]:
    names = list(ARM_JOINTS)
    steps, j = spec["steps"], spec["joint"]
    at = min(int(spec["at"] * steps), max(steps - 1, 0))
    velocity = np.array(spec["velocity"])
    kind = spec["kind"]
    if kind == "smooth":
        velocity = velocity / 4  # within +-0.5 rad/s: mostly feasible from rest
    rows = observed[None, :] + np.outer(np.arange(steps) * dt, velocity)
    if kind == "near_limit":  # head for a limit and stop a hair before or after it
        bound = LIMITS.upper[j] if spec["size"] >= 0 else LIMITS.lower[j]
        target = bound - np.sign(spec["size"]) * (abs(spec["size"]) % 0.02 - 0.01)
        rows[:, j] = np.linspace(observed[j], target, max(steps, 1))[:steps]
    elif kind == "beyond_limit" and steps:
        rows[at:, j] = (LIMITS.upper[j] if spec["size"] >= 0 else LIMITS.lower[j]) + spec["size"]
    elif kind == "nonfinite" and steps:
        rows[at, j] = spec["bad"]
    elif kind == "jump" and steps:
        rows[at:, j] += spec["size"]
    elif kind == "into_table":  # shoulder_lift and elbow fold the arm down onto the table
        rows = observed[None, :] + np.outer(np.arange(steps) * dt, [0.0, 0.4 + abs(spec["size"]) / 4, 0.3, 0.0, 0.0, 0.0])
    elif kind == "names":
        rng = np.random.default_rng(spec["seed"])
        change = spec["names"]
        if change == "permuted":
            order = rng.permutation(6) if not np.array_equal(rng.permutation(6), np.arange(6)) else np.array([1, 0, 2, 3, 4, 5])
            names = [names[i] for i in order]
            rows = rows[:, order]
        elif change == "renamed":
            names[j] = names[j] + "_x"
        elif change == "duplicated":
            names[j] = names[(j + 1) % 6]
        elif change == "missing":
            names = names[:-1]
            rows = rows[:, :-1]
        elif change == "extra":
            names = names + ["finger_joint"]
            rows = np.hstack([rows, np.zeros((steps, 1))])
        else:  # a gripper column the run did not configure
            names = names + [GRIPPER_DRIVER_JOINT]
            rows = np.hstack([rows, np.zeros((steps, 1))])
    elif kind == "width" and steps:
        values = [list(r) for r in rows]
        values[at] = (list(values[at]) * 3)[: spec["width"]]
        return names, values
    elif kind == "empty":
        return names, []
    return names, [list(r) for r in rows]


# --------------------------------------------------------------------------------------------
# One run and the property
# --------------------------------------------------------------------------------------------
@dataclass
class Outcome:
    status: str
    reason: str
    rejection: str
    goals: list[Goal]
    snapshot_scene: Any
    dt: float
    gripper_goals: list[float] = field(default_factory=list)
    gripper_goal_times: list[float] = field(default_factory=list)
    max_tcp_speed: float = 0.0


def run_chunks(specs: list[dict[str, Any]], start: np.ndarray, dt: float, points: int, gripper: bool = False,
               max_tcp_speed: float = 0.0, envelope: bool = True, world: RecordingWorld | None = None,
               protective_stop: StopInputs | None = StopInputs()) -> Outcome:
    """``max_tcp_speed``: ExecutePolicy's port (0: the cell's); ``envelope`` False: a scene without
    one; ``world``: a recording world of the caller's (else one starting at ``start``);
    ``protective_stop``: the run's stop inputs."""
    ports = (f'total_action_steps="20" dt="{dt}" committed_action_steps="10" num_interpolation_points="{points}" '
             f'link_padding="{PADDING}" goal_path_tolerance="0.3" policy_call_timeout="2.0" max_tcp_speed="{max_tcp_speed}"')
    if gripper:
        ports += f' gripper_command_action_name="{GRIPPER_ACTION}" gripper_joint_name="{GRIPPER_DRIVER_JOINT}"'
    xml = (f'<root BTCPP_format="4"><BehaviorTree ID="T"><ExecutePolicy policy_service_name="{SERVICE}" '
           f'joint_group_name="manipulator" {ports} rejection_reason="{{rejection}}"/></BehaviorTree></root>')
    options = RunOptions(seed=0, max_seconds=20.0, protective_stop=protective_stop)
    context = make_context(options)
    world = world if world is not None else RecordingWorld(start, envelope=envelope)
    loaded = load_tree(xml, registry(), context)
    calls = {"n": 0}

    def serve(request: Any) -> Any:
        index, calls["n"] = calls["n"], calls["n"] + 1
        observed = np.array(request.robot_state.position)
        spec = specs[min(index - 1, len(specs) - 1)] if index > 0 else {**specs[0], "kind": "smooth", "steps": 30}
        names, rows = build_chunk(spec, observed, dt, gripper)
        response = R(status=R.CHUNK_PRODUCED, native_control_period=dt)
        response.chunk = JointTrajectory(joint_names=names, points=[JointTrajectoryPoint(positions=[float(v) for v in r]) for r in rows])
        return response

    context.bus.create_service(SERVICE, GetActionChunk, serve)
    context.bus.set_latency(SERVICE, FixedLatency(0.05))
    result = run_tree(loaded, context, options, world=world)
    return Outcome(result.status, result.reason, result.blackboard.get("rejection", ""), world.goals, context.scene, dt,
                   world.gripper_goals, world.gripper_goal_times, max_tcp_speed)


def assert_nothing_unsafe_reached_the_controller(out: Outcome) -> None:
    safety = make_safety(out.snapshot_scene, "manipulator", None)
    snapshot = safety.snapshot()
    lower, upper = LIMITS.lower, LIMITS.upper
    vmax, amax = LIMITS.max_velocity, LIMITS.max_acceleration
    tol = 1e-9
    for g in out.goals:
        assert g.names == list(ARM_JOINTS)
        assert np.isfinite(g.positions).all() and np.isfinite(g.velocities).all() and np.isfinite(g.accelerations).all()
        assert (g.positions >= lower - tol).all() and (g.positions <= upper + tol).all(), "a position beyond a limit reached the controller"
        assert (np.abs(g.velocities) <= vmax + tol).all(), "a velocity beyond its limit reached the controller"
        assert (np.abs(g.accelerations) <= amax + tol).all(), "an acceleration beyond its limit reached the controller"
        samples = Samples(g.times, g.positions, g.velocities, g.accelerations)
        hit = safety.first_collision(snapshot, samples, PADDING, 0.0)
        assert hit is None, f"a point in collision reached the controller: {hit}"
        # A goal ends at rest: a stock JTC refuses one that does not, and nothing else would
        # carry the arm on if the next chunk were late.
        assert np.allclose(g.velocities[-1], 0.0, atol=1e-6), f"a goal ending at {g.velocities[-1]} rad/s reached the controller"
        assert_within_the_envelope(out, g)
    gripper = out.snapshot_scene.limits[GRIPPER_DRIVER_JOINT]
    for position in out.gripper_goals:
        assert gripper.lower - tol <= position <= gripper.upper + tol, f"gripper goal {position} reached the gripper controller"
    for (t0, g0), (t1, g1) in zip(zip(out.gripper_goal_times, out.gripper_goals), zip(out.gripper_goal_times[1:], out.gripper_goals[1:])):
        steps = max(round((t1 - t0) / out.dt), 1)  # goals go out at the first tick after their step's time
        assert abs(g1 - g0) <= gripper.max_velocity * steps * out.dt + 1e-6, (
            f"gripper goals {g0} then {g1} {steps} step(s) apart: faster than {gripper.max_velocity} rad/s")
    assert out.status in ("SUCCESS", "FAILURE")
    if out.status == "FAILURE" and "rejected" in out.reason:
        assert out.rejection == out.reason and len(out.rejection) > len("chunk 1 rejected: ")


ENVELOPE_SUBSTEPS = 4
"""Instants inside each piece between two goal points at which the controller's interpolation is
checked against the envelope (besides the points themselves)."""
BETWEEN_POINTS_TOLERANCE = {"m": 2e-4, "deg": 0.05, "m/s": 2e-3, "rad/s": 0.01}
"""What the controller's quintic between two checked points (at most 10 ms apart) may add to a
value at its points: half a piece of the frame's acceleration (at most a few m/s^2, rad/s^2) times
(5 ms)^2 for positions and angles; for speeds, the jerk's share. The samples are what the check
sees; these bound the motion between them, as the joint limits' mean-velocity test does."""


def controller_interpolation(g: Goal) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities of the controller's quintic Hermite pieces through the goal's points
    (what both simulated controllers play): the points and ``ENVELOPE_SUBSTEPS`` instants inside each piece."""
    if len(g.times) < 2:
        return g.positions, g.velocities
    h = np.diff(g.times)
    coefficients = quintic_coefficients(h, g.positions[:-1], g.velocities[:-1], g.accelerations[:-1],
                                        g.positions[1:], g.velocities[1:], g.accelerations[1:])
    positions, velocities = [g.positions], [g.velocities]
    for f in (np.arange(1, ENVELOPE_SUBSTEPS + 1) / (ENVELOPE_SUBSTEPS + 1)):
        tau = f * h
        powers = np.stack([quintic_powers(t) for t in tau])  # (S, 3, 6)
        state = np.einsum("sik,skj->sij", powers, coefficients)
        positions.append(state[:, 0]), velocities.append(state[:, 1])
    return np.vstack(positions), np.vstack(velocities)


def assert_within_the_envelope(out: Outcome, g: Goal) -> None:
    """Every point the controller plays of goal ``g`` against the run's envelope: the cell's,
    with ExecutePolicy's ``max_tcp_speed`` port when set. Positions, axis and twist come from the
    scene's forward kinematics and the frame Jacobian, not from the check under test."""
    envelope = out.snapshot_scene.envelope
    if envelope is None:
        return
    speed_limit = out.max_tcp_speed or envelope.max_tcp_speed_m_s
    robot, layout = out.snapshot_scene.robot, out.snapshot_scene.layout("manipulator", None)
    tol = BETWEEN_POINTS_TOLERANCE
    positions, velocities = controller_interpolation(g)
    for q, v in zip(positions, velocities):
        q_full = layout(q)
        poses = frame_poses(robot, q_full, list(envelope.frames))
        for box in envelope.keep_in_boxes:
            for frame in box.frames:
                p = poses[frame][:3, 3]
                assert (p >= np.array(box.min_m) - tol["m"]).all() and (p <= np.array(box.max_m) + tol["m"]).all(), (
                    f"{frame} at {p} outside keep-in box {box.name} reached the controller")
        cone = envelope.tool_cone
        axis = poses[cone.frame][:3, :3] @ np.array(cone.axis)
        angle = np.degrees(np.arccos(np.clip(axis @ np.array(cone.direction), -1, 1)))
        assert angle <= cone.max_angle_deg + tol["deg"], f"a tool axis {angle:.3f} deg from {cone.direction} reached the controller"
        twist = frame_jacobian(robot, q_full, envelope.tcp_frame, ARM_JOINTS) @ v
        assert np.linalg.norm(twist[:3]) <= speed_limit + tol["m/s"], f"a TCP speed {np.linalg.norm(twist[:3]):.4f} m/s reached the controller"
        assert np.linalg.norm(twist[3:]) <= envelope.max_tcp_angular_speed_rad_s + tol["rad/s"], (
            f"a TCP angular speed {np.linalg.norm(twist[3:]):.4f} rad/s reached the controller")


starts = st.one_of(
    st.just(READY),
    st.tuples(st.integers(0, 5), st.booleans(), st.floats(0.0, 0.05)).map(
        lambda t: np.where(np.arange(6) == t[0], (LIMITS.upper if t[1] else LIMITS.lower)[t[0]] - (1 if t[1] else -1) * t[2], READY)
    ),
)
# Half the examples start with a well-behaved chunk, so the random one arrives while the arm is
# moving and has to be blended into the committed motion at a seam.
smooth_chunk = chunk_spec().map(lambda d: {**d, "kind": "smooth", "steps": max(d["steps"], 30)})
smooth_first = st.tuples(smooth_chunk, chunk_spec()).map(list)
# And some where the arm is well-behaved throughout, so that the gripper column (with a
# gripper configured) is what the run has to get right.
smooth_arm = st.lists(smooth_chunk, min_size=1, max_size=2)
examples = dict(
    specs=st.one_of(st.lists(chunk_spec(), min_size=1, max_size=2), smooth_first, smooth_arm),
    start=starts,
    dt=st.sampled_from([0.05, 0.1]),
    points=st.sampled_from([2, 10, 50, 100]),
    gripper=st.booleans(),
    max_tcp_speed=st.sampled_from([0.0, 0.25]),
)
common = dict(deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@settings(max_examples=30, **common)
@given(**examples)
def test_no_unsafe_point_reaches_the_controller(specs, start, dt, points, gripper, max_tcp_speed):
    assert_nothing_unsafe_reached_the_controller(run_chunks(specs, start, dt, points, gripper, max_tcp_speed))


def _classify(out: Outcome) -> None:
    """Label the example for ``--hypothesis-show-statistics``: how far did the chunks get?"""
    event(f"{out.status}, {len(out.goals)} goal(s) reached the controller")
    if out.status == "FAILURE":
        event("rejected: " + out.reason.split(":")[1].strip().split(" ")[0] if "rejected" in out.reason else "failed: " + out.reason[:40])


@pytest.mark.slow
@pytest.mark.timeout(3600)
@settings(max_examples=2000, **common)
@given(**examples)
def test_no_unsafe_point_reaches_the_controller_2000_examples(specs, start, dt, points, gripper, max_tcp_speed):
    out = run_chunks(specs, start, dt, points, gripper, max_tcp_speed)
    _classify(out)
    assert_nothing_unsafe_reached_the_controller(out)


# -- the property's own sanity: the harness does reach the controller and does reject -------------
def test_a_smooth_chunk_reaches_the_controller_and_a_nan_is_rejected_with_a_reason():
    smooth = {"kind": "smooth", "steps": 40, "velocity": [0.2] * 6, "joint": 0, "at": 0.5, "size": 0.0,
              "bad": float("nan"), "names": "permuted", "width": 0, "seed": 0}
    out = run_chunks([smooth], READY, 0.1, 50)
    assert out.status == "SUCCESS", out.reason
    # num_interpolation_points is a floor: samples are never more than 10 ms apart.
    assert len(out.goals) == 2 and all(len(g.times) >= 50 and np.diff(g.times).max() <= 0.01 + 1e-9 for g in out.goals)
    assert_nothing_unsafe_reached_the_controller(out)
    out = run_chunks([smooth, {**smooth, "kind": "nonfinite", "joint": 2}], READY, 0.1, 50)
    assert out.status == "FAILURE" and len(out.goals) == 1
    assert out.rejection == "chunk 2 rejected: step 20 joint 'elbow_joint' is not finite (nan)"


def test_a_chunk_into_the_table_never_reaches_the_controller():
    down = {"kind": "into_table", "steps": 50, "velocity": [0.0] * 6, "joint": 0, "at": 0.0, "size": 0.0,
            "bad": float("nan"), "names": "permuted", "width": 0, "seed": 0}
    out = run_chunks([down], READY, 0.1, 100, envelope=False)  # the envelope's tool cone refuses it first
    assert out.status == "FAILURE"
    assert "world collision" in out.rejection and "vs table" in out.rejection
    assert_nothing_unsafe_reached_the_controller(out)  # the windows before the table went through


def test_motion_between_sparse_densified_points_stays_within_the_velocity_limit():
    fast = {"kind": "jump", "steps": 3, "velocity": [0.0, 0.0, 0.0, 0.0, 0.0, 2.0], "joint": 0, "at": 0.0,
            "size": 0.0, "bad": float("nan"), "names": "permuted", "width": 0, "seed": 0}
    out = run_chunks([fast], READY, 0.1, 2)
    assert_nothing_unsafe_reached_the_controller(out)
    for g in out.goals:
        speed = np.abs(np.diff(g.positions, axis=0)) / np.diff(g.times)[:, None]
        assert (speed <= LIMITS.max_velocity + 1e-6).all(), f"{speed.max():.2f} rad/s between consecutive points"


def test_a_gripper_column_out_of_range_never_reaches_the_gripper_controller():
    """The property's gripper half can fail: an in-range column does reach the gripper, and one
    100 times too large is rejected with the gripper joint named, never streamed."""
    smooth = {"kind": "smooth", "steps": 40, "velocity": [0.2] * 6, "joint": 0, "at": 0.5, "size": 0.0,
              "bad": float("nan"), "names": "permuted", "width": 0, "seed": 0, "gripper": 0.5, "gripper_ramp": True}
    out = run_chunks([smooth], READY, 0.1, 50, gripper=True)
    assert out.status == "SUCCESS", out.reason
    assert out.gripper_goals and max(out.gripper_goals) <= 0.5 + 1e-9
    assert_nothing_unsafe_reached_the_controller(out)
    out = run_chunks([{**smooth, "gripper": 50.0}], READY, 0.1, 50, gripper=True)
    assert out.status == "FAILURE" and out.gripper_goals == [] and out.goals == []
    # The column ramps from open to 50 rad: its step 1 (1.2821 rad) is the first beyond 0.8 rad.
    assert out.rejection == (f"chunk 1 rejected: step 1: joint {GRIPPER_DRIVER_JOINT} position 1.2821 rad exceeds "
                             "the limit 0.8000 rad (policy step 2 of the run)")


def test_a_gripper_column_faster_than_the_gripper_never_reaches_it_and_a_seam_joins_at_its_speed():
    """The property's rate half can fail: open and closed every step (8 rad/s) is rejected before
    any goal reaches the gripper (on main every one was streamed); a chunk that holds 0.8 rad
    after one that held 0.0 is taken over at the gripper's 2 rad/s, 0.2 rad a step."""
    smooth = {"kind": "smooth", "steps": 40, "velocity": [0.2] * 6, "joint": 0, "at": 0.5, "size": 0.0,
              "bad": float("nan"), "names": "permuted", "width": 0, "seed": 0, "gripper": 0.8, "gripper_ramp": False,
              "gripper_alternate": 0.8}
    out = run_chunks([smooth], READY, 0.1, 50, gripper=True)
    assert out.status == "FAILURE" and out.gripper_goals == [] and out.goals == []
    assert out.rejection == (f"chunk 1 rejected: step 1: joint {GRIPPER_DRIVER_JOINT} velocity -8.0000 rad/s exceeds "
                             "the limit -2.0000 rad/s (policy step 2 of the run)")
    held = {**smooth, "gripper_alternate": 0.0}
    out = run_chunks([{**held, "gripper": 0.0}, held], READY, 0.1, 50, gripper=True)
    assert out.status == "SUCCESS", out.reason
    assert out.gripper_goals[:5] == pytest.approx([0.0, 0.2, 0.4, 0.6, 0.8])
    assert_nothing_unsafe_reached_the_controller(out)


def test_a_chunk_faster_than_the_tcp_speed_port_never_reaches_the_controller():
    """The property's envelope half can fail: ExecutePolicy's max_tcp_speed narrows the cell's 1 m/s
    for the run, and a chunk over it is refused naming the point, the link, the speed and the
    limit; a port above the cell's limit is a setup ERROR, never a wider envelope."""
    smooth = {"kind": "smooth", "steps": 40, "velocity": [0.2] * 6, "joint": 0, "at": 0.5, "size": 0.0,
              "bad": float("nan"), "names": "permuted", "width": 0, "seed": 0}
    out = run_chunks([smooth], READY, 0.1, 50, max_tcp_speed=0.05)
    assert out.status == "FAILURE" and out.goals == []
    assert out.rejection == ("chunk 1 rejected: densified step 0 (t=0.160 s): link tcp linear speed 0.0700 m/s exceeds "
                             "the limit 0.0500 m/s (policy step 1 of the run)")
    out = run_chunks([smooth], READY, 0.1, 50, max_tcp_speed=5.0)
    assert out.status == "ERROR" and out.goals == []
    assert out.reason.endswith("ExecutePolicy: max_tcp_speed 5 m/s is above the limit 1 m/s of the cell's envelope: "
                               "a port may only tighten the Cartesian envelope")
