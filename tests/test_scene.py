"""Planning scene: model fidelity against MuJoCo, collision rules, attachments, limits, IK."""
from __future__ import annotations

import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402
import pytest  # noqa: E402

from runtime.motion.scene import (  # noqa: E402
    Box,
    GroupError,
    PlanningScene,
    RobotModel,
    frame_pose,
    load_joint_limits,
    parse_srdf,
    pose_matrix,
    IkSolver,
    solve_ik,
)
from sim.mjcf import robot_model_from_mjcf  # noqa: E402
from sim.robot_model import (  # noqa: E402
    ARM_JOINTS,
    GRIPPER_DRIVER_JOINT,
    JOINT_LIMITS_PATH,
    TCP_SITE,
    build_robot_spec,
    load_waypoints,
    planning_robot_model,
)

DOWN = np.diag([1.0, -1.0, -1.0])  # TCP z along -world z


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    return planning_robot_model()


@pytest.fixture(scope="module")
def mj():
    model = build_robot_spec().compile()
    return model, mujoco.MjData(model)


@pytest.fixture(scope="module")
def home() -> np.ndarray:
    wp = load_waypoints()["Home"]
    return np.array([wp[j] for j in ARM_JOINTS])


@pytest.fixture()
def scene(robot) -> PlanningScene:
    return PlanningScene(robot, "manipulator", GRIPPER_DRIVER_JOINT)


def _random_q(robot: RobotModel, rng: np.random.Generator) -> np.ndarray:
    """A full configuration with every joint (gripper linkage included) drawn in its range."""
    lo = np.maximum(robot.model.lowerPositionLimit, -np.pi)
    hi = np.minimum(robot.model.upperPositionLimit, np.pi)
    return rng.uniform(lo, hi)


def _mujoco_at(mj, robot: RobotModel, q: np.ndarray):
    model, data = mj
    for joint in robot.movable_joints:
        data.qpos[model.joint(joint).qposadr[0]] = q[robot.joint_q_index(joint)]
    mujoco.mj_kinematics(model, data)
    return model, data


def _se3(pos, quat) -> pin.SE3:
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, quat)
    return pin.SE3(rot.reshape(3, 3), np.asarray(pos, float))


def test_fk_matches_mujoco(robot, mj):
    rng = np.random.default_rng(0)
    links = ["base", "upper_arm_link", "wrist_3_link", "gripper_base", "gripper_left_pad", "gripper_right_follower"]
    for _ in range(10):
        q = _random_q(robot, rng)
        model, data = _mujoco_at(mj, robot, q)
        for link in links:
            pose = frame_pose(robot, q, link)
            body = model.body(link).id
            assert np.abs(pose[:3, 3] - data.xpos[body]).max() < 1e-9, link
            assert np.abs(pose[:3, :3] - data.xmat[body].reshape(3, 3)).max() < 1e-9, link
        tcp = frame_pose(robot, q, TCP_SITE)
        assert np.abs(tcp[:3, 3] - data.site_xpos[model.site(TCP_SITE).id]).max() < 1e-9


def test_collision_geometry_placement_matches_mujoco(robot, mj):
    rng = np.random.default_rng(1)
    geometry = robot.collision_model
    gdata = pin.GeometryData(geometry)
    pdata = robot.model.createData()
    n_mujoco_collision = sum(
        1 for g in range(mj[0].ngeom) if mj[0].geom_contype[g] or mj[0].geom_conaffinity[g]
    )
    assert len(geometry.geometryObjects) == n_mujoco_collision == 23
    for _ in range(5):
        q = _random_q(robot, rng)
        model, data = _mujoco_at(mj, robot, q)
        pin.updateGeometryPlacements(robot.model, pdata, geometry, gdata, q)
        for k, go in enumerate(geometry.geometryObjects):
            body = model.body(robot.geometry_links[k]).id
            name = go.name
            gid = model.body_geomadr[body] + int(name.split("Geom_")[1]) if "Geom_" in name else model.geom(name).id
            placement = gdata.oMg[k]
            if model.geom_type[gid] == mujoco.mjtGeom.mjGEOM_MESH:
                mesh = model.geom_dataid[gid]  # MuJoCo re-centres meshes; compare the same frame
                placement = placement * _se3(model.mesh_pos[mesh], model.mesh_quat[mesh])
            assert np.abs(placement.translation - data.geom_xpos[gid]).max() < 1e-6, name
            assert np.abs(placement.rotation - data.geom_xmat[gid].reshape(3, 3)).max() < 1e-6, name


def test_gripper_joints_follow_the_driver(robot, scene, home):
    q = scene.full_configuration(home, 0.5)
    value = {j: q[robot.joint_q_index(j)] for j in robot.movable_joints}
    assert value[GRIPPER_DRIVER_JOINT] == 0.5
    assert value["gripper_right_driver_joint"] == 0.5
    assert value["gripper_left_follower_joint"] == pytest.approx(-0.9645 * 0.5 + 0.0012)
    assert value["gripper_right_coupler_joint"] == 0.0
    assert value["shoulder_pan_joint"] == home[0]


def test_self_collision_folded_but_not_home(scene, home):
    assert scene.check_state(np.r_[home, 0.0], padding=0.01) is None
    assert scene.check_state(np.r_[home, 0.8], padding=0.01) is None  # closed on nothing: fingers may touch
    folded = home.copy()
    folded[2] = 3.0  # elbow folds the wrist back onto the shoulder
    hit = scene.check_state(folded, padding=0.01)
    assert hit is not None and hit.kind == "self"
    assert {hit.first, hit.second} == {"shoulder_link", "wrist_1_link"}
    assert hit.distance < 0 and hit.padding == 0.0
    assert "self collision" in str(hit) and "penetration" in str(hit)


def _probe_below_gripper(scene: PlanningScene, q: np.ndarray, gap: float) -> float:
    """Place a plate under the fingertips so its clearance is about ``gap``; return it."""
    tcp = scene.link_pose(q, TCP_SITE)
    pose = pose_matrix(tcp[:3, 3] - [0.0, 0.0, 0.06])
    scene.add_object("probe", Box((0.2, 0.2, 0.02)), pose)
    for _ in range(5):  # converge: distance is linear in the box height near the fingertips
        d = scene.min_distance(q, kind="world").distance
        pose[2, 3] += d - gap
        scene.move_object("probe", pose)
    return scene.min_distance(q, kind="world").distance


def test_a_distance_just_under_the_padding_reads_below_it():
    from runtime.motion.scene.collision import CollisionResult, millimetres_apart

    assert millimetres_apart(6.5, 10.0) == ("6.5", "10.0")
    assert millimetres_apart(9.96, 10.0) == ("9.96", "10.00")
    assert millimetres_apart(9.9996, 10.0) == ("9.999", "10.000")  # under a micrometre: cut down at three decimals
    hit = CollisionResult("world", "gripper_left_pad", "table", 0.00996, 0.01, step=55, time=6.59)
    assert str(hit) == "step 55 (t=6.590 s): world collision gripper_left_pad vs table: distance 9.96 mm < padding 10.00 mm"


def test_world_collision_respects_padding_and_rules(scene, home):
    q = np.r_[home, 0.0]
    gap = _probe_below_gripper(scene, q, 0.005)
    assert gap == pytest.approx(0.005, abs=2e-4)
    hit = scene.check_state(q, padding=0.01)
    assert hit is not None and hit.kind == "world" and hit.second == "probe"
    assert hit.first.startswith("gripper_") and hit.padding == 0.01
    assert hit.distance == pytest.approx(gap, abs=2e-4)
    assert "< padding 10.0 mm" in str(hit)
    assert scene.check_state(q, padding=0.004) is None

    scene.allow("probe", "gripper")
    assert scene.check_state(q, padding=0.01) is None
    scene.disallow("probe", "gripper")
    assert scene.check_state(q, padding=0.01) is not None
    scene.allow("*", "*")
    assert scene.check_state(q, padding=0.01) is not None  # the explicit disallow beats the wildcard
    scene.allow("probe", "gripper")
    assert scene.check_state(q, padding=0.01) is None
    scene.disallow("*", "*")
    scene.disallow("probe", "gripper")

    far = _probe_below_gripper(scene, q, 0.015)
    assert far == pytest.approx(0.015, abs=2e-4)
    assert scene.check_state(q, padding=0.01) is None


def test_check_path_reports_step_time_and_pair(robot, scene, home):
    scene.add_object("table", Box((1.2, 0.8, 0.04)), pose_matrix([0.0, 0.45, -0.02]))
    scene.allow("table", ["base", "shoulder_link"])
    # From Home (TCP 30 cm up) down to the table top: the fingertips enter the padding on the way.
    low = solve_ik(robot, "manipulator", pose_matrix([0.0, 0.45, 0.0], DOWN @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])),
                   seeds=[home], frame=TCP_SITE)
    assert low.success
    n = 200
    s = np.linspace(0.0, 1.0, n)[:, None]
    Q = np.column_stack([(1 - s) * home + s * low.positions, np.zeros(n)])
    times = np.arange(n) * 0.005
    first = scene.check_path(Q, times, padding=0.01)
    assert first is not None and first.kind == "world" and first.second == "table"
    assert 0 < first.step < n and first.time == pytest.approx(times[first.step])
    assert scene.check_path(Q[: first.step], times[: first.step], padding=0.01) is None
    every = scene.check_path(Q, times, padding=0.01, stop_at_first=False)
    assert [h.step for h in every] == list(range(first.step, n))


def test_path_check_timing(scene, home):
    scene.add_object("table", Box((1.2, 0.8, 0.04)), pose_matrix([0.0, 0.45, -0.02]))
    for i, name in enumerate(["cube_red", "cube_green", "cube_blue"]):
        scene.add_object(name, Box((0.03, 0.03, 0.03)), pose_matrix([-0.1 + 0.1 * i, 0.5, 0.015]))
    scene.allow("table", ["base", "shoulder_link"])
    Q = np.tile(np.r_[home, 0.0], (200, 1))
    Q[:, 0] += np.linspace(0.0, 0.3, 200)
    Q[:, 6] = np.linspace(0.0, 0.6, 200)
    assert scene.check_path(Q, padding=0.01) is None  # warm: compiles the checker
    best = min(_timed(lambda: scene.check_path(Q, padding=0.01)) for _ in range(5))
    print(f"\n200-point path check: {best * 1e3:.2f} ms ({best / 200 * 1e6:.1f} us per point)")


def _timed(f) -> float:
    t = time.perf_counter()
    f()
    return time.perf_counter() - t


def test_attached_object_moves_with_link_and_collides_with_world(scene, home):
    q = np.r_[home, 0.4]
    tcp = scene.link_pose(q, TCP_SITE)
    scene.add_object("cube_red", Box((0.03, 0.03, 0.03)), tcp)
    scene.allow("cube_red", "gripper")  # the cube sits between the fingers
    scene.attach("cube_red", "gripper_base", q=q, touch_links=["gripper"])
    assert "cube_red" not in scene.objects
    assert scene.check_state(q, padding=0.01) is None

    moved = q.copy()
    moved[0] += 0.3
    expected = scene.link_pose(moved, TCP_SITE)
    assert np.allclose(scene.object_world_pose("cube_red", moved), expected, atol=1e-12)

    scene.add_object("obstacle", Box((0.05, 0.05, 0.05)), pose_matrix(expected[:3, 3] - [0.0, 0.0, 0.04]))
    scene.allow("obstacle", ["manipulator", "gripper"])  # the robot may touch it; the carried cube may not
    hit = scene.check_state(moved, padding=0.01)
    assert hit is not None and (hit.first, hit.second, hit.kind) == ("attached:cube_red", "obstacle", "world")
    scene.allow("obstacle", "cube_red")
    assert scene.check_state(moved, padding=0.01) is None

    scene.detach("cube_red", q=moved)
    assert np.allclose(scene.object_pose("cube_red"), expected, atol=1e-12)


def test_snapshot_freezes_rules_but_not_world(scene, home):
    q = np.r_[home, 0.0]
    _probe_below_gripper(scene, q, 0.005)
    snap = scene.snapshot()
    scene.allow("probe", "*")
    assert scene.check_state(q, padding=0.01) is None
    assert scene.check_state(q, padding=0.01, snapshot=snap) is not None  # the rule came later
    scene.move_object("probe", pose_matrix([2.0, 0.0, 0.0]))
    assert scene.check_state(q, padding=0.01, snapshot=snap) is None  # world geometry is live


def test_checks_follow_every_object_that_moved_whatever_checker_answers(scene, home):
    """Each cached checker (one per padding here) is brought up to date with the objects that
    moved since it last answered, however many moves and other checks came between."""
    q = np.r_[home, 0.0]
    tcp = scene.link_pose(q, TCP_SITE)[:3, 3]
    at_tcp, far = pose_matrix(tcp), pose_matrix([2.0, 0.0, 0.0])
    scene.add_object("a", Box((0.1, 0.1, 0.02)), far)
    scene.add_object("b", Box((0.1, 0.1, 0.02)), pose_matrix([-2.0, 0.0, 0.0]))
    assert scene.check_state(q, padding=0.01) is None and scene.check_state(q, padding=0.02) is None
    scene.move_object("a", at_tcp)
    assert scene.check_state(q, padding=0.01).second == "a"
    scene.move_object("b", at_tcp)
    scene.move_object("a", far)
    assert scene.check_state(q, padding=0.02).second == "b"  # this checker missed both earlier moves
    assert scene.check_state(q, padding=0.01).second == "b"
    scene.move_object("b", far)
    assert scene.check_state(q, padding=0.01) is None and scene.check_state(q, padding=0.02) is None


def test_group_with_two_tips_is_an_error(robot):
    srdf = parse_srdf(
        '<robot name="x"><group name="fingers">'
        '<joint name="robotiq_85_left_knuckle_joint"/><joint name="gripper_right_driver_joint"/>'
        "</group></robot>"
    )
    other = RobotModel(robot.model, robot.collision_model, srdf=srdf)
    with pytest.raises(GroupError) as err:
        other.group("fingers").tip_link
    assert str(err.value) == (
        "joint group 'fingers' must resolve to exactly one tip link; found 2: gripper_right_driver, gripper_left_driver"
    )
    assert robot.group("manipulator").tip_link == "gripper_base"
    assert robot.group("manipulator").joints == ARM_JOINTS
    with pytest.raises(GroupError, match="unknown joint group 'arm' \\(groups: manipulator, gripper\\)"):
        robot.group("arm")


def test_gripper_inside_group_is_rejected(robot):
    with pytest.raises(GroupError, match="is part of group"):
        PlanningScene(robot, "manipulator", "wrist_3_joint")


def test_joint_limits_from_yaml_and_model(robot):
    position = dict(zip(ARM_JOINTS + (GRIPPER_DRIVER_JOINT,),
                        zip(*robot.position_limits(ARM_JOINTS + (GRIPPER_DRIVER_JOINT,)))))
    limits = load_joint_limits(JOINT_LIMITS_PATH, position)
    assert limits["elbow_joint"].upper == pytest.approx(3.1415)
    assert limits["shoulder_pan_joint"].max_velocity == pytest.approx(np.pi)
    assert limits["wrist_3_joint"].max_acceleration == 5.0
    assert limits[GRIPPER_DRIVER_JOINT].upper == pytest.approx(0.8)

    n = 10
    Q = np.zeros((n, 7))
    V = np.zeros((n, 7))
    V[6, 2] = 3.5
    Q[8, 6] = 0.9
    violation = limits.check(Q, V, np.zeros((n, 7)), times=np.arange(n) * 0.01)
    assert str(violation) == (
        "step 6 (t=0.060 s): joint elbow_joint velocity 3.5000 rad/s exceeds the limit 3.1416 rad/s"
    )
    Q[3, 0] = -7.0
    violation = limits.check(Q, V)
    assert (violation.step, violation.joint, violation.quantity) == (3, "shoulder_pan_joint", "position")
    assert str(violation) == "step 3: joint shoulder_pan_joint position -7.0000 rad below the limit -6.2832 rad"


def test_ik_reaches_pose_above_table(robot, home):
    target = pose_matrix([0.15, 0.5, 0.12], DOWN)
    result = solve_ik(robot, "manipulator", target, seeds=[home], frame=TCP_SITE)
    assert result.success
    layout = robot.configuration_map("manipulator", None)
    reached = frame_pose(robot, layout(result.positions), TCP_SITE)
    assert np.linalg.norm(reached[:3, 3] - target[:3, 3]) < 1e-3
    assert np.allclose(reached[:3, :3], target[:3, :3], atol=2e-3)
    lower, upper = robot.position_limits(ARM_JOINTS)
    assert np.all(result.positions >= lower) and np.all(result.positions <= upper)


def test_a_reused_ik_solver_answers_as_a_fresh_one(robot, home):
    """One ``IkSolver`` solving one target after another gives, bit for bit, what ``solve_ik``
    (a fresh solver per call) gives, also after targets it could not reach."""
    solver = IkSolver(robot, "manipulator", TCP_SITE)
    rng = np.random.default_rng(5)
    targets = [pose_matrix([x, y, z], DOWN) for x, y, z in rng.uniform([-0.3, 0.3, 0.02], [0.3, 0.7, 0.4], (12, 3))]
    targets.insert(4, pose_matrix([0.0, 3.0, 0.1], DOWN))  # out of reach
    outcomes = []
    for target in targets:
        for restarts in (0, 2):
            fresh = solve_ik(robot, "manipulator", target, seeds=[home], frame=TCP_SITE, random_restarts=restarts, max_iterations=60)
            reused = solver.solve(target, seeds=[home], random_restarts=restarts, max_iterations=60)
            assert reused.positions.tobytes() == fresh.positions.tobytes()
            assert (reused.success, reused.position_error, reused.orientation_error, reused.iterations) == \
                (fresh.success, fresh.position_error, fresh.orientation_error, fresh.iterations)
            outcomes.append(fresh.success)
    assert True in outcomes and False in outcomes


def test_home_waypoint_looks_down_above_the_table(robot, home):
    tcp = frame_pose(robot, robot.configuration_map("manipulator", None)(home), TCP_SITE)
    assert np.allclose(tcp[:3, 2], [0.0, 0.0, -1.0], atol=1e-3)
    assert np.allclose(tcp[:3, 3], [0.0, 0.45, 0.30], atol=1e-3)


URDF = """<?xml version="1.0"?>
<robot name="two_link">
  <link name="base"><collision><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>
  <link name="arm"><collision><origin xyz="0 0 0.25"/><geometry><cylinder radius="0.03" length="0.5"/></geometry></collision></link>
  <link name="finger_a"/>
  <link name="finger_b"/>
  <link name="tool"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0 0 0.05"/>
    <axis xyz="1 0 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="arm"/><child link="tool"/><origin xyz="0 0 0.5"/></joint>
  <joint name="fa" type="prismatic"><parent link="tool"/><child link="finger_a"/>
    <axis xyz="0 1 0"/><limit lower="0" upper="0.04" effort="1" velocity="1"/></joint>
  <joint name="fb" type="prismatic"><parent link="tool"/><child link="finger_b"/>
    <axis xyz="0 1 0"/><limit lower="-0.04" upper="0" effort="1" velocity="1"/><mimic joint="fa" multiplier="-1"/></joint>
</robot>
"""

SRDF = """<robot name="two_link">
  <group name="arm"><chain base_link="base" tip_link="tool"/></group>
  <group name="hand"><link name="finger_a"/><link name="finger_b"/></group>
  <disable_collisions link1="base" link2="arm" reason="Adjacent"/>
</robot>
"""


def test_urdf_srdf_robot(tmp_path):
    (tmp_path / "robot.urdf").write_text(URDF)
    (tmp_path / "robot.srdf").write_text(SRDF)
    robot = RobotModel.from_urdf(tmp_path / "robot.urdf", tmp_path / "robot.srdf")
    assert robot.group("arm").joints == ("j1",) and robot.group("arm").tip_link == "tool"
    assert robot.group("hand").tips == ("finger_a", "finger_b")
    scene = PlanningScene(robot, "arm", "fa")
    q = scene.full_configuration([0.0], 0.03)
    assert q[robot.joint_q_index("fb")] == pytest.approx(-0.03)  # URDF <mimic>
    assert np.allclose(scene.link_pose([0.0], "tool")[:3, 3], [0, 0, 0.55])
    scene.add_object("wall", Box((0.1, 0.1, 0.1)), pose_matrix([0.0, -0.3, 0.3]))
    assert scene.check_state([0.0], padding=0.01) is None
    hit = scene.check_state([0.88], padding=0.01)  # the arm swings towards -y into the wall
    assert hit is not None and (hit.first, hit.second) == ("arm", "wall")


def test_srdf_disabled_pairs(robot):
    disabled = robot.srdf.disabled_keys()
    assert frozenset(("gripper_left_pad", "gripper_right_pad")) in disabled
    assert frozenset(("shoulder_link", "wrist_1_link")) not in disabled


def test_robot_from_a_cell_mjcf_with_other_bodies(robot, scene):
    spec = build_robot_spec()
    cube = spec.worldbody.add_body(name="cube", pos=[0.3, 0.4, 0.1])
    cube.add_freejoint()
    cube.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.015] * 3)
    with pytest.raises(ValueError, match=r"MJCF has 2 top-level bodies \(base, cube\); pass root_body="):
        robot_model_from_mjcf(spec)
    cell_robot = robot_model_from_mjcf(spec.to_xml(), root_body="base")
    assert cell_robot.model.nq == robot.model.nq == 14
    q = _random_q(robot, np.random.default_rng(5))
    assert np.allclose(frame_pose(cell_robot, q, TCP_SITE), frame_pose(robot, q, TCP_SITE), atol=1e-12)


def test_bad_rows_are_named(scene):
    with pytest.raises(ValueError, match=r"expected 7 or 6 \(without the gripper\): shoulder_pan_joint, .*robotiq_85_left_knuckle_joint"):
        scene.check_state(np.zeros(5))
    with pytest.raises(ValueError, match="row 0 column 2 is not finite"):
        scene.check_state(np.array([0, 0, np.nan, 0, 0, 0]))


def test_the_planning_scene_is_the_scene_a_run_context_names(scene):
    """``RunContext.scene`` is typed by the tree's ``Scene`` protocol (the tree imports nothing of
    the motion room): the planning scene has every member the protocol names, its methods with the
    same parameters."""
    import inspect

    from runtime.tree.world import Scene

    members = {name for name in vars(Scene) if not name.startswith("_")} | set(Scene.__annotations__)
    assert {"robot", "layout", "check_path", "attachments"} <= members
    for name in sorted(members):
        assert hasattr(scene, name), f"PlanningScene has no '{name}'"
        promised = vars(Scene).get(name)
        if inspect.isfunction(promised):
            assert (list(inspect.signature(getattr(PlanningScene, name)).parameters)
                    == list(inspect.signature(promised).parameters)), name
        elif isinstance(promised, property):
            assert isinstance(inspect.getattr_static(PlanningScene, name), property), name
