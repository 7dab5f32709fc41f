"""The scripted oracle: prompt reading, grasp geometry, plan timing within limits, chunk serving."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from policy.backend import PolicyRequest, PolicyStatus
from sim.oracle import (
    MIN_JERK_PEAK_ACCELERATION,
    MIN_JERK_PEAK_VELOCITY,
    OracleBackend,
    OracleConfig,
    PromptError,
    SceneKinematics,
    cube_yaw,
    linear_path,
    min_jerk,
    parse_prompt,
    plan_stack,
    segment_duration,
)
from policy.stack_keypoints import aligned_yaw, tcp_yaw, top_down_pose
from sim.robot_model import GRIPPER_DRIVER_JOINT

HOME = np.array([-1.5708, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])
GRIPPER = GRIPPER_DRIVER_JOINT  # as published on /joint_states
PROMPT = "stack the blue cube on the green cube"


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


# ---------------------------------------------------------------------------------------------
# Prompt
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "prompt, cubes",
    [
        ("stack the blue cube on the green cube", ("blue", "green")),
        ("Put the RED cube on top of the blue cube.", ("red", "blue")),
        ("  place green cube onto the red cube ", ("green", "red")),
    ],
)
def test_prompt_names_top_and_bottom_cube(prompt, cubes):
    assert parse_prompt(prompt) == cubes


@pytest.mark.parametrize(
    "prompt, detail",
    [
        ("pick up the blue cube", ""),
        ("", ""),
        ("stack the purple cube on the green cube", " with colors red, green, blue"),
        ("stack the blue cube on the blue cube", ": the two cubes must have different colors"),
    ],
)
def test_unreadable_prompts_say_what_is_expected(prompt, detail):
    with pytest.raises(PromptError) as err:
        parse_prompt(prompt)
    assert str(err.value) == (
        f"cannot read the prompt '{prompt}': expected 'stack the <color> cube on the <color> cube'{detail}"
    )


# ---------------------------------------------------------------------------------------------
# Pure geometry and timing
# ---------------------------------------------------------------------------------------------
def test_cube_yaw_repeats_every_quarter_turn():
    assert cube_yaw(yaw_quat(0.3)) == pytest.approx(0.3)
    assert cube_yaw(yaw_quat(0.3 + math.pi / 2)) == pytest.approx(0.3)
    assert cube_yaw(yaw_quat(-1.2)) == pytest.approx(-1.2 + math.pi / 2)
    # A cube lying on a side face: its vertical axis is y, the side faces still give the yaw.
    tipped = np.array([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])  # 90 deg about x
    assert cube_yaw(tipped) == pytest.approx(0.0, abs=1e-9)


def test_aligned_yaw_picks_the_closest_quarter_turn():
    assert aligned_yaw(0.2, 1.5708) == pytest.approx(0.2 + math.pi / 2)
    assert aligned_yaw(-0.7, 0.0) == pytest.approx(-0.7)
    assert aligned_yaw(0.7, -3.0) == pytest.approx(0.7 - math.pi)


def test_top_down_pose_points_down_with_the_fingers_across_the_yaw():
    pose = top_down_pose([0.1, 0.4, 0.2], 0.5)
    assert np.allclose(pose[:3, 2], [0, 0, -1])
    assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3)) and np.linalg.det(pose[:3, :3]) == pytest.approx(1)
    assert tcp_yaw(pose) == pytest.approx(0.5)


def test_min_jerk_profile_and_duration_bound():
    tau = np.linspace(0, 1, 10001)
    s = min_jerk(tau)
    assert (s[0], s[-1]) == (0.0, 1.0)
    v = np.gradient(s, tau)
    a = np.gradient(v, tau)
    assert v.max() == pytest.approx(MIN_JERK_PEAK_VELOCITY, rel=1e-3)
    assert np.abs(a).max() == pytest.approx(MIN_JERK_PEAK_ACCELERATION, rel=1e-2)
    # 1 rad at 0.5 rad/s peak: 1.875 * 1 / 0.5 = 3.75 s
    path = linear_path(np.zeros(2), np.array([1.0, -0.5]))
    assert segment_duration(path, 0.5, 100.0, 0.1) == pytest.approx(3.75, rel=1e-3)
    assert segment_duration(path, 100.0, 1.0, 0.1) == pytest.approx(math.sqrt(MIN_JERK_PEAK_ACCELERATION), rel=1e-3)


# ---------------------------------------------------------------------------------------------
# Plans on the real robot model
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def kinematics():
    from sim.robot_model import planning_robot_model

    return SceneKinematics(planning_robot_model())


@pytest.fixture(scope="module")
def limits():
    from sim.robot_model import JOINT_LIMITS_PATH

    table = yaml.safe_load(JOINT_LIMITS_PATH.read_text())["joint_limits"]
    return table


LAYOUTS = [
    # (top xyz, top yaw, bottom xyz, bottom yaw)
    ((0.10, 0.45, 0.015), 0.3, (-0.12, 0.50, 0.015), -0.6),
    ((-0.20, 0.35, 0.015), -0.7, (0.15, 0.55, 0.015), 0.1),
    ((0.0, 0.58, 0.015), 0.0, (0.05, 0.38, 0.015), 0.75),
]


def make_plan(kinematics, case, config=None):
    top, top_yaw, bottom, bottom_yaw = case
    return plan_stack(
        kinematics, HOME, 0.0, (np.array(top), yaw_quat(top_yaw)), (np.array(bottom), yaw_quat(bottom_yaw)),
        config or OracleConfig(),
    )


@pytest.mark.parametrize("case", LAYOUTS)
def test_plan_reaches_pre_grasp_and_grasp_poses(kinematics, case):
    config = OracleConfig()
    plan = make_plan(kinematics, case, config)
    bounds = plan.boundaries()
    top = np.array(case[0])
    pre_grasp = kinematics.tcp_pose(plan.sample([bounds["pre_grasp"][1]])[0][0])
    expected = top + [0, 0, config.grasp_height + config.approach_height]
    assert np.linalg.norm(pre_grasp[:3, 3] - expected) < 1e-3
    assert pre_grasp[:3, 2] == pytest.approx([0, 0, -1], abs=1e-3)
    # Yaw aligned with the cube faces, the quarter turn nearest the start wrist yaw.
    start_yaw = tcp_yaw(kinematics.tcp_pose(HOME))
    assert math.remainder(tcp_yaw(pre_grasp) - aligned_yaw(case[1], start_yaw), 2 * math.pi) == pytest.approx(0, abs=2e-3)
    assert math.remainder(tcp_yaw(pre_grasp) - case[1], math.pi / 2) == pytest.approx(0, abs=2e-3)

    arm, gripper = plan.sample([bounds["close"][0], bounds["close"][1]])
    grasp = kinematics.tcp_pose(arm[0])
    assert np.linalg.norm(grasp[:3, 3] - (top + [0, 0, config.grasp_height])) < 1e-3
    # Closed on the cube the pad tips reach 17.3 mm past the TCP: keep them 15 mm over the table.
    assert grasp[2, 3] - 0.0173 >= 0.015
    assert gripper.tolist() == pytest.approx([config.gripper_open, config.gripper_closed])


@pytest.mark.parametrize("case", LAYOUTS)
def test_release_puts_the_top_cube_30_mm_plus_clearance_above_the_bottom_one(kinematics, case):
    config = OracleConfig()
    plan = make_plan(kinematics, case, config)
    arm, gripper = plan.sample([plan.boundaries()["open"][0]])
    tcp = kinematics.tcp_pose(arm[0])
    held_cube = tcp[:3, :3] @ plan.grasp_offset + tcp[:3, 3]
    bottom = np.array(case[2])
    assert held_cube[:2] == pytest.approx(bottom[:2], abs=1e-3)
    assert held_cube[2] - bottom[2] == pytest.approx(0.030 + config.place_clearance, abs=1e-3)
    # Rotated onto the bottom cube's faces.
    assert math.remainder(tcp_yaw(tcp) - case[3], math.pi / 2) == pytest.approx(0, abs=2e-3)


@pytest.mark.parametrize("case", LAYOUTS)
def test_plan_at_10_hz_stays_within_joint_limits(kinematics, limits, case):
    plan = make_plan(kinematics, case)
    dt = 0.1
    times = np.arange(0.0, plan.duration + 1.0, dt)
    arm, gripper = plan.sample(times)
    positions = np.column_stack([arm, gripper])
    names = list(kinematics.joint_names) + [GRIPPER_DRIVER_JOINT]
    velocity = np.abs(np.diff(positions, axis=0)) / dt
    acceleration = np.abs(np.diff(positions, 2, axis=0)) / dt**2
    for column, name in enumerate(names):
        # Well below the limits: ExecutePolicy's smoothing and blending add a little on top.
        assert velocity[:, column].max() <= 0.5 * limits[name]["max_velocity"], name
        assert acceleration[:, column].max() <= 0.5 * limits[name]["max_acceleration"], name
    # The plan starts where the robot is, at rest.
    assert positions[0, :6] == pytest.approx(HOME)
    assert np.abs(positions[1, :6] - positions[0, :6]).max() < 0.01


@pytest.mark.slow  # wall-clock time
def test_plan_is_fast_enough_to_make_per_episode(kinematics):
    import time

    start = time.perf_counter()
    make_plan(kinematics, LAYOUTS[0])
    assert time.perf_counter() - start < 1.0


# ---------------------------------------------------------------------------------------------
# The backend
# ---------------------------------------------------------------------------------------------
class FakePeek:
    """Cube poses and a clock the test sets; real kinematics."""

    def __init__(self, kinematics, case):
        top, top_yaw, bottom, bottom_yaw = case
        self.kinematics = kinematics
        self.cubes = {
            "blue": (np.array(top), yaw_quat(top_yaw)),
            "green": (np.array(bottom), yaw_quat(bottom_yaw)),
            "red": (np.array([0.2, 0.6, 0.015]), yaw_quat(0.0)),
        }
        self.now = 10.0

    def cube_pose(self, color):
        return self.cubes[color]

    def time(self):
        return self.now


def observe(positions, prompt=PROMPT, new_episode=False, names=None):
    names = names or ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
                      "wrist_2_joint", "wrist_3_joint", GRIPPER]
    return PolicyRequest(prompt, names, np.asarray(positions, dtype=float), new_episode=new_episode)


@pytest.fixture
def oracle(kinematics):
    return OracleBackend(FakePeek(kinematics, LAYOUTS[0]))


def test_chunk_is_50_steps_at_10_hz_from_the_request_instant(oracle):
    first = oracle.infer(observe(np.r_[HOME, 0.0], new_episode=True))
    assert first.status is PolicyStatus.CHUNK
    assert first.actions.shape == (50, 7)
    assert first.native_control_period == 0.1
    assert first.policy_actions == pytest.approx(first.actions)  # its action space: the request's columns
    assert first.actions[0, :6] == pytest.approx(HOME)
    oracle.peek.now += 2.0  # 20 steps later, same plan
    second = oracle.infer(observe(first.actions[20]))
    assert second.actions[0] == pytest.approx(first.actions[20])
    assert second.actions[:30] == pytest.approx(first.actions[20:])
    assert oracle.plans_made == 1


def test_columns_follow_the_request_order(oracle):
    names = [GRIPPER, "wrist_3_joint", "wrist_2_joint", "wrist_1_joint", "elbow_joint",
             "shoulder_lift_joint", "shoulder_pan_joint"]
    answer = oracle.infer(observe(np.r_[0.0, HOME[::-1]], names=names, new_episode=True))
    assert answer.actions[0] == pytest.approx(np.r_[0.0, HOME[::-1]])


def test_after_the_plan_ends_it_holds_the_final_pose(oracle):
    first = oracle.infer(observe(np.r_[HOME, 0.0], new_episode=True))
    oracle.peek.now += oracle.plan.duration + 5.0
    late = oracle.infer(observe(first.actions[-1]))
    assert late.status is PolicyStatus.CHUNK
    assert np.ptp(late.actions, axis=0) == pytest.approx(np.zeros(7))
    assert late.actions[0, 6] == OracleConfig().gripper_open


def test_new_episode_replans_from_the_observed_state(oracle):
    oracle.infer(observe(np.r_[HOME, 0.0], new_episode=True))
    start = HOME + 0.05
    oracle.peek.now += 1.0
    answer = oracle.infer(observe(np.r_[start, 0.4], new_episode=True))
    assert oracle.plans_made == 2
    assert answer.actions[0] == pytest.approx(np.r_[start, 0.4])


def test_slipped_cube_triggers_a_replan(oracle):
    first = oracle.infer(observe(np.r_[HOME, 0.0], new_episode=True))
    bounds = oracle.plan.boundaries()
    t_carry = (bounds["transfer"][0] + bounds["transfer"][1]) / 2
    oracle.peek.now = oracle.plan.start + t_carry
    arm, gripper = oracle.plan.sample([t_carry])
    tcp = oracle.peek.kinematics.tcp_pose(arm[0])
    held = tcp[:3, :3] @ oracle.plan.grasp_offset + tcp[:3, 3]
    oracle.peek.cubes["blue"] = (held + [0.01, 0.0, 0.0], yaw_quat(0.3))  # in the gripper, 1 cm off: fine
    oracle.infer(observe(np.r_[arm[0], 0.5]))
    assert oracle.plans_made == 1
    oracle.peek.cubes["blue"] = (np.array([0.0, 0.4, 0.015]), yaw_quat(0.0))  # dropped
    answer = oracle.infer(observe(np.r_[arm[0], 0.5]))
    assert (oracle.plans_made, oracle.replans) == (2, 1)
    assert answer.actions[0, :6] == pytest.approx(arm[0])
    assert first.status is answer.status is PolicyStatus.CHUNK


@pytest.mark.parametrize(
    "request_args, message",
    [
        (dict(prompt="dance"), "cannot read the prompt 'dance': expected 'stack the <color> cube on the <color> cube'"),
        (dict(names=["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"],
              positions=HOME),
         "oracle needs exactly one gripper joint after the arm joints in robot_state (set gripper_joint_name on "
         "ExecutePolicy); got extra joints []"),
        (dict(names=["a", "b"], positions=[0.0, 0.0]),
         "oracle needs the arm joints [shoulder_pan_joint, shoulder_lift_joint, elbow_joint, wrist_1_joint, "
         "wrist_2_joint, wrist_3_joint] in robot_state; missing [shoulder_pan_joint, shoulder_lift_joint, "
         "elbow_joint, wrist_1_joint, wrist_2_joint, wrist_3_joint]"),
    ],
)
def test_bad_requests_answer_error(oracle, request_args, message):
    positions = request_args.pop("positions", np.r_[HOME, 0.0])
    answer = oracle.infer(observe(positions, new_episode=True, **request_args))
    assert answer.status is PolicyStatus.ERROR
    assert answer.message == message


def test_unreachable_cube_answers_error(oracle):
    oracle.peek.cubes["blue"] = (np.array([3.0, 0.0, 0.015]), yaw_quat(0.0))
    answer = oracle.infer(observe(np.r_[HOME, 0.0], new_episode=True))
    assert answer.status is PolicyStatus.ERROR
    assert answer.message.startswith(
        f"oracle cannot plan '{PROMPT}': no IK solution for the pre-grasp pose at [3.0, 0.0, 0.133]"
    )


def test_scene_tcp_is_where_mujoco_puts_the_tcp_site(kinematics):
    """The oracle aims the scene's "tcp" frame; it must be the simulator's tcp site."""
    import mujoco

    from sim.robot_model import ARM_JOINTS, TCP_SITE, build_robot_spec

    model = build_robot_spec().compile()
    data = mujoco.MjData(model)
    columns = [model.joint(name).qposadr[0] for name in ARM_JOINTS]
    assert tuple(kinematics.joint_names) == ARM_JOINTS
    for q in np.random.default_rng(3).uniform(-2.5, 2.5, (5, 6)):
        data.qpos[columns] = q
        mujoco.mj_kinematics(model, data)
        pose = kinematics.tcp_pose(q)
        assert pose[:3, 3] == pytest.approx(data.site(TCP_SITE).xpos, abs=1e-6)
        assert pose[:3, :3].ravel() == pytest.approx(data.site(TCP_SITE).xmat, abs=1e-6)


@pytest.mark.parametrize("seed", range(5))
def test_plans_for_seeded_layouts_pass_the_collision_check_executepolicy_makes(kinematics, seed):
    """Table and cubes in the scene, 10 mm padding; only gripper contact with the top cube is allowed
    (what the stacking Objective's SetCollisionRule allows)."""
    from runtime.motion.scene.collision import Box
    from runtime.motion.scene.scene import PlanningScene
    from sim.layouts import layout

    robot = kinematics.robot
    scene = PlanningScene(robot, "manipulator", GRIPPER_DRIVER_JOINT)
    scene.add_object("table", Box((1.2, 1.1, 0.04)), _pose((0.0, 0.3, -0.02), 0.0))
    scene.allow("table", ["base", "shoulder_link"])  # the robot stands on the table
    cubes = layout(seed)
    for color, (x, y, yaw) in cubes.items():
        scene.add_object(f"cube_{color}", Box((0.03, 0.03, 0.03)), _pose((x, y, 0.015), yaw))
    scene.allow("cube_blue", list(robot.group("gripper").links))
    top, bottom = cubes["blue"], cubes["green"]
    case = ((top[0], top[1], 0.015), top[2], (bottom[0], bottom[1], 0.015), bottom[2])
    plan = make_plan(kinematics, case)
    times = np.arange(0.0, plan.duration, 0.02)
    arm, gripper = plan.sample(times)
    assert scene.check_path(np.column_stack([arm, gripper]), times, padding=0.01) is None


def _pose(position, yaw):
    pose = np.eye(4)
    pose[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    pose[:3, 3] = position
    return pose
