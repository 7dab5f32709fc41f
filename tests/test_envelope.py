"""The Cartesian envelope: its YAML, its check (messages naming the point, the link, the value and
the limit), ports that may only tighten it, and the motion behaviors refusing a motion outside it
before the controller sees it. ExecutePolicy's side is in test_safety_properties.py."""
from __future__ import annotations


import numpy as np
import pytest

from behaviors.execute_policy.failure import FailureKind
from runtime.motion.samples import Samples
from behaviors.motion import plan_point_to_point
from behaviors.safety import SafetyError, make_safety
from behaviors.trajectories import check_motion
from runtime.errors import OptionError
from runtime.tree.loader import load_tree
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, make_context, run_tree
from runtime.motion.scene import CartesianEnvelope, EnvelopeOverrides, KeepInBox, load_envelope, narrowed
from sim.kinematic import KinematicWorld
from sim.planning import make_cell_scene
from sim.robot_model import ARM_JOINTS, CARTESIAN_LIMITS_PATH, JOINT_LIMITS_PATH, load_waypoints
from tests.test_safety_properties import CUBES

HOME = np.array([load_waypoints()["Home"][j] for j in ARM_JOINTS])


@pytest.fixture(scope="module")
def scene():
    return make_cell_scene(CUBES)


def motion_to(scene, goal: np.ndarray, scale: float = 0.5) -> Samples:
    limits = make_safety(scene, "manipulator", None).limits
    return plan_point_to_point(HOME, goal, limits, scale, scale)


def test_the_cells_envelope_is_loaded_from_beside_joint_limits(scene):
    assert CARTESIAN_LIMITS_PATH == JOINT_LIMITS_PATH.parent / "cartesian_limits.yaml"
    envelope = scene.envelope
    assert envelope.tcp_frame == "tcp" and envelope.max_tcp_speed_m_s == 1.0 and envelope.max_tcp_angular_speed_rad_s == 3.0
    assert envelope.keep_in_boxes == (KeepInBox("table_workspace", ("tcp", "wrist_3_link", "wrist_2_link", "wrist_1_link"),
                                                (-0.6, -0.25, 0.0), (0.6, 0.85, 1.2)),)
    assert envelope.tool_cone.max_angle_deg == 45 and envelope.tool_cone.direction == (0.0, 0.0, -1.0)


def test_a_motion_that_tilts_the_tool_is_refused_at_its_first_point_past_the_cone(scene):
    safety = make_safety(scene, "manipulator", None)
    tilted = HOME + np.array([0, 0, 0, 0, 1.2, 0])  # wrist_2 by 1.2 rad: the gripper axis 69 deg from down
    outside = safety.first_limit_violation(motion_to(scene, tilted))
    assert outside.family == "Cartesian limit" and outside.link == "tcp" and outside.quantity == "tool axis"
    assert FailureKind.of_limit(outside.quantity) is FailureKind.TOOL_AXIS_LIMIT
    assert 45.0 < outside.value < 46.0 and outside.limit == 45.0
    assert str(outside) == (f"step {outside.step} (t={outside.time:.3f} s): link tcp tool axis {outside.value:.4f} deg "
                            "from (0, 0, -1) exceeds the limit 45.0000 deg")
    # Ports left at 0 keep the cell's envelope as it is.
    assert make_safety(scene, "manipulator", None).narrowed(EnvelopeOverrides()).envelope == scene.envelope


def test_a_wrist_below_the_table_top_names_the_link_the_axis_and_the_box(scene):
    envelope = CartesianEnvelope("tcp", keep_in_boxes=(KeepInBox("high", ("wrist_3_link",), (-1, -1, 0.6), (1, 1, 2)),))
    safety = make_safety(scene, "manipulator", None)
    safety = type(safety)(**{**safety.__dict__, "envelope": envelope})
    outside = safety.first_limit_violation(Samples.at_rest(HOME))  # Home: wrist_3_link at z 0.556 m
    assert str(outside) == "step 0 (t=0.000 s): link wrist_3_link z 0.5558 m below the limit 0.6000 m of keep-in box 'high'"
    assert FailureKind.of_limit(outside.quantity) is FailureKind.WORKSPACE_LIMIT


def test_a_joint_limit_at_the_same_point_is_reported_first_and_speeds_after_positions(scene):
    safety = make_safety(scene, "manipulator", None).narrowed(EnvelopeOverrides(max_tcp_speed_m_s=0.01, max_tcp_angular_speed_rad_s=0.01))
    q = np.vstack([HOME, HOME])
    v = np.array([[0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 9.0]])  # wrist_3 at 9 rad/s: over pi, and a spin of the tool
    outside = safety.first_limit_violation(Samples(np.array([0.0, 0.1]), q, v, np.zeros_like(q)))
    assert str(outside) == "step 1 (t=0.100 s): joint wrist_3_joint velocity 9.0000 rad/s exceeds the limit 3.1416 rad/s"
    v[1] = [0, 0, 0, 0, 0, 0.5]
    outside = safety.first_limit_violation(Samples(np.array([0.0, 0.1]), q, v, np.zeros_like(q)))
    assert str(outside) == "step 1 (t=0.100 s): link tcp angular speed 0.5000 rad/s exceeds the limit 0.0100 rad/s"
    assert FailureKind.of_limit(outside.quantity) is FailureKind.ANGULAR_SPEED_LIMIT


def test_a_planned_trajectory_faster_than_the_tcp_limit_is_refused_naming_the_point(scene):
    safety = make_safety(scene, "manipulator", None).narrowed(EnvelopeOverrides(max_tcp_speed_m_s=0.25))
    samples = motion_to(scene, HOME + np.array([0.6, 0, 0, 0, 0, 0]), scale=1.0)
    problem = check_motion(safety, samples, 0.01, 0.05)
    assert problem.startswith("breaks a Cartesian limit at point ") and "link tcp linear speed" in problem
    assert problem.endswith("exceeds the limit 0.2500 m/s")
    # Positions alone (ExecuteTrajectory without velocities): the mean over an interval counts.
    still = Samples(samples.times, samples.positions, np.zeros_like(samples.positions), np.zeros_like(samples.positions))
    problem = check_motion(safety, still, 0.01, 0.05)
    assert problem.startswith("moves faster than a Cartesian limit from point ") and problem.endswith("(the mean over that interval)")
    assert check_motion(make_safety(scene, "manipulator", None), samples, 0.01, 0.05) is None  # within the cell's 1 m/s


def test_ports_may_only_tighten_the_envelope(scene):
    safety = make_safety(scene, "manipulator", None)
    assert safety.narrowed(EnvelopeOverrides(max_tcp_speed_m_s=0.25)).envelope.max_tcp_speed_m_s == 0.25
    with pytest.raises(SafetyError, match=r"^max_tcp_speed 2 m/s is above the limit 1 m/s of the cell's envelope: "
                                          r"a port may only tighten the Cartesian envelope$"):
        safety.narrowed(EnvelopeOverrides(max_tcp_speed_m_s=2.0))
    with pytest.raises(SafetyError, match="tool_axis_max_angle 60 deg is above the limit 45 deg"):
        safety.narrowed(EnvelopeOverrides(tool_axis_max_angle_deg=60))
    boxed = safety.narrowed(EnvelopeOverrides(tcp_keep_in_box_m=(-0.1, 0.3, 0.1, 0.1, 0.6, 0.5)))
    assert boxed.envelope.keep_in_boxes[-1] == KeepInBox("tcp_keep_in_box", ("tcp",), (-0.1, 0.3, 0.1), (0.1, 0.6, 0.5))
    with pytest.raises(SafetyError, match="tcp_keep_in_box needs 6 values"):
        safety.narrowed(EnvelopeOverrides(tcp_keep_in_box_m=(0.1, 0.3, 0.1, -0.1, 0.6, 0.5)))
    # Without a cell envelope a port makes one around the tip; a tool cone then points straight down.
    bare = CartesianEnvelope("tcp")
    cone = narrowed(bare, EnvelopeOverrides(tool_axis_max_angle_deg=30), "an unlimited envelope").tool_cone
    assert (cone.frame, cone.axis, cone.direction, cone.max_angle_deg) == ("tcp", (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), 30)


@pytest.mark.parametrize("text, message", [
    ("cartesian_limits: [1]", "'cartesian_limits' must be a mapping"),
    ("cartesian_limits: {max_tcp_sped_m_s: 1}", "has unknown keys ['max_tcp_sped_m_s']"),
    ("cartesian_limits: {max_tcp_speed_m_s: -1}", "cartesian_limits.max_tcp_speed_m_s must be positive, got -1"),
    ("cartesian_limits: {max_tcp_speed_m_s: fast}", "cartesian_limits.max_tcp_speed_m_s is not a number: 'fast'"),
    ("cartesian_limits: {tcp_frame: tool0}", "cartesian_limits.tcp_frame: 'tool0' is not a link or frame of the robot model"),
    ("cartesian_limits: {keep_in_boxes: {a: {frames: [tcp], min_m: [0, 0, 1], max_m: [1, 1, 0]}}}",
     "keep_in_boxes.a: min_m [0.0, 0.0, 1.0] must be below max_m [1.0, 1.0, 0.0] on every axis"),
    ("cartesian_limits: {keep_in_boxes: {a: {min_m: [0, 0, 0], max_m: [1, 1, 1]}}}", "keep_in_boxes.a needs 'frames'"),
    ("cartesian_limits: {tool_axis_cone: {axis: [0, 0, 0], direction: [0, 0, -1], max_angle_deg: 10}}",
     "tool_axis_cone.axis must not be the zero vector"),
    ("cartesian_limits: {tool_axis_cone: {axis: [0, 0, 1], direction: [0, 0, -1], max_angle_deg: 0}}",
     "tool_axis_cone.max_angle_deg must be in (0, 180], got 0"),
    ("cartesian_limits: {max_tcp_speed_m_s: 1", "not YAML"),
])
def test_a_mistake_in_the_yaml_is_an_option_error_naming_the_file_and_key(scene, tmp_path, text, message):
    path = tmp_path / "cartesian_limits.yaml"
    path.write_text(text)
    with pytest.raises(OptionError) as err:
        load_envelope(path, scene.robot, "tcp")
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value)


@pytest.mark.parametrize("controller", ["joint_trajectory_admittance_controller", "joint_trajectory_controller"])
def test_move_to_joint_state_refuses_a_motion_outside_the_envelope_before_the_controller_sees_it(controller):
    registry = Registry.from_entry_points()
    tilted = ";".join(f"{v:.6f}" for v in HOME + np.array([0, 0, 0, 0, 1.2, 0]))
    xml = ('<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>'
           f'<SwitchController activate_controllers="{controller}" deactivate_controllers="velocity_force_controller"/>'
           f'<MoveToJointState joint_group_name="manipulator" joint_positions="{tilted}" '
           f'controller_action_name="/{controller}/follow_joint_trajectory"/>'
           '</Sequence></BehaviorTree></root>')
    options = RunOptions(seed=0, max_seconds=10.0, world="kinematic")
    context = make_context(options)
    world = KinematicWorld({"seed": 0, "policy": "none"})
    result = run_tree(load_tree(xml, registry, context), context, options, world=world)
    assert result.status == "FAILURE"
    assert result.reason.startswith("the motion is outside the Cartesian limits: step ")
    assert result.reason.endswith("deg from (0, 0, -1) exceeds the limit 45.0000 deg") and ": link tcp tool axis 45." in result.reason
    assert world.cell.arm_position() == pytest.approx(world.start_arm, abs=1e-3)  # nothing reached the controller


def test_the_planners_pose_check_agrees_with_the_envelope_check_and_keeps_its_margin(scene):
    """The planner's per-state check (``PoseCheck``) answers as ``check_envelope`` does for one
    configuration, and ``MotionSafety.pose_check`` keeps 1 degree inside the tool cone."""
    from runtime.motion.scene import PoseCheck, check_envelope

    safety = make_safety(scene, "manipulator", scene.gripper_joint)
    layout = scene.layout(safety.group, None)
    exact = PoseCheck(safety.envelope, scene.robot, layout)
    home = np.array([load_waypoints()["Home"][j] for j in ARM_JOINTS])
    rng = np.random.default_rng(0)
    states = home + rng.normal(0.0, 0.8, (300, 6))
    inside = [check_envelope(safety.envelope, scene.robot, layout, q[None]) is None for q in states]
    assert [exact(q) for q in states] == inside
    assert 30 < sum(inside) < 270  # both answers occur
    # wrist_2 tilts the tool: the first angle the envelope refuses, then one a little inside it
    tilt = home.copy()
    edge = next(a for a in np.arange(0.0, 1.2, 0.001)
                if check_envelope(safety.envelope, scene.robot, layout, (home + [0, 0, 0, 0, a, 0])[None]) is not None)
    tilt[4] += edge - 0.005
    assert exact(tilt) and not safety.pose_check()(tilt)


def test_batched_kinematics_equals_pinocchio_on_the_cell_and_on_every_joint_kind_it_covers(scene):
    """``BatchKinematics`` (the envelope's forward kinematics over a whole motion) gives the poses
    pinocchio gives (``oMf``) and the frame velocities (``getFrameVelocity``, world-aligned), on the
    cell's UR5e + gripper and on a chain of every joint kind it covers; a chain with another kind
    (a spherical joint) is marked unsupported, and the envelope then answers through pinocchio
    point by point, with the same violation."""
    import pinocchio as pin

    from runtime.motion.scene.batch_kinematics import BatchKinematics
    from runtime.motion.scene.envelope import _frame_states, _frame_states_per_point

    def compare(model: pin.Model, frame_ids: list[int], q: np.ndarray, v: np.ndarray) -> None:
        kinematics = BatchKinematics(model, frame_ids)
        assert kinematics.supported
        states = kinematics.states(q)
        assert states.twist is None
        data = model.createData()
        for i in range(len(q)):
            pin.forwardKinematics(model, data, q[i], v[i])
            for k, fid in enumerate(frame_ids):
                placement = pin.updateFramePlacement(model, data, fid)
                assert states.positions[i, k] == pytest.approx(placement.translation, abs=1e-12)
                assert states.rotations(k)[i] == pytest.approx(placement.rotation, abs=1e-12)
                assert states.axis(k, np.array([0.3, -0.2, 0.9]))[i] == pytest.approx(placement.rotation @ [0.3, -0.2, 0.9], abs=1e-12)
                velocity = pin.getFrameVelocity(model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).vector
                assert kinematics.states(q[i:i + 1], v[i:i + 1], k).twist[0] == pytest.approx(velocity, abs=1e-12)

    rng = np.random.default_rng(3)
    robot = scene.robot
    names = ["tcp", "wrist_3_link", "wrist_1_link", "base"] + [n for n in robot.link_names if "pad" in n]
    q = np.array([pin.randomConfiguration(robot.model, -np.ones(robot.model.nq) * 3, np.ones(robot.model.nq) * 3) for _ in range(40)])
    compare(robot.model, [robot.frame_id(n) for n in names], q, rng.normal(0.0, 1.0, (40, robot.model.nv)))

    chain = pin.Model()
    parent = 0
    kinds = [pin.JointModelRX(), pin.JointModelRUBZ(), pin.JointModelPY(), pin.JointModelRevoluteUnaligned(0.3, -0.5, 0.8),
             pin.JointModelPrismaticUnaligned(np.array([0.6, 0.0, 0.8])), pin.JointModelRZ()]
    for k, kind in enumerate(kinds):
        placement = pin.SE3(pin.rpy.rpyToMatrix(*rng.normal(0, 1, 3)), rng.normal(0, 0.3, 3))
        parent = chain.addJoint(parent, kind, placement, f"j{k}")
        chain.addJointFrame(parent)
    tip = chain.addFrame(pin.Frame("tip", parent, pin.SE3(np.eye(3), np.array([0.1, 0.0, 0.2])), pin.FrameType.OP_FRAME))
    q = np.array([pin.randomConfiguration(chain, -np.ones(chain.nq), np.ones(chain.nq)) for _ in range(20)])
    compare(chain, [tip, tip - 1], q, rng.normal(0.0, 1.0, (20, chain.nv)))

    ball = pin.Model()
    ball_frame = ball.addJointFrame(ball.addJoint(0, pin.JointModelSpherical(), pin.SE3.Identity(), "ball"))
    assert not BatchKinematics(ball, [ball_frame]).supported

    # The envelope's two ways to its frame states agree on a motion of the cell's arm.
    safety = make_safety(scene, "manipulator", None)
    motion = motion_to(scene, HOME + np.array([0.8, -0.4, 0.6, 0.3, 1.2, -0.7]))
    full = safety.scene.layout(safety.group, None)(motion.positions)
    model = robot.model
    v_full = np.zeros((len(full), model.nv))
    v_full[:, [int(model.idx_vs[model.getJointId(j)]) for j in ARM_JOINTS]] = motion.velocities
    batched = _frame_states(safety.envelope, robot, safety.scene.layout(safety.group, None), full, motion.velocities)
    per_point = _frame_states_per_point(safety.envelope, robot, full, v_full)
    assert batched.positions == pytest.approx(per_point.positions, abs=1e-12)
    assert batched.axes == pytest.approx(per_point.axes, abs=1e-12)
    assert batched.twists == pytest.approx(per_point.twists, abs=1e-12)
