"""The recording worker's ``/tf`` (``recording.tf_model``) against pinocchio's forward
kinematics: every kind of one-axis joint, coupled joints, fixed links, names a joint state
leaves out, and the planning robot itself."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from rclpy.serialization import deserialize_message
from tf2_msgs.msg import TFMessage

from recording.cdr import JointStateEncoder, joint_state_arrays
from recording.scene_view import LinkTree, tf_model
from recording.tf_model import TfModel, TfWriter
from runtime.motion.scene.model import JointCoupling, RobotModel


def _se3(seed: int) -> pin.SE3:
    rng = np.random.default_rng(seed)
    return pin.SE3(pin.Quaternion(*rng.normal(size=4)).normalized().matrix(), rng.normal(size=3))


def _toy_robot() -> RobotModel:
    """One joint of each kind the worker knows, a coupled joint and a link fixed to its parent."""
    model = pin.Model()
    model.name = "toy"
    frames = {"universe": 0}
    joints = [
        ("j_rz", pin.JointModelRZ(), "universe", "l_rz"),
        ("j_prismatic", pin.JointModelPrismaticUnaligned(np.array([1.0, 1.0, 0.0]) / np.sqrt(2)), "l_rz", "l_prismatic"),
        ("j_unaligned", pin.JointModelRevoluteUnaligned(np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])),
         "l_prismatic", "l_unaligned"),
        ("j_unbounded", pin.JointModelRUBX(), "l_unaligned", "l_unbounded"),
        ("j_px", pin.JointModelPX(), "l_unbounded", "l_px"),
        ("j_follower", pin.JointModelRY(), "l_rz", "l_follower"),
    ]
    joint_ids = {"universe": 0}
    for k, (name, joint, parent_link, link) in enumerate(joints):
        parent_joint = model.frames[frames[parent_link]].parentJoint
        jid = model.addJoint(parent_joint, joint, _se3(k), name)
        model.appendBodyToJoint(jid, pin.Inertia.Random(), pin.SE3.Identity())
        joint_frame = model.addJointFrame(jid, frames[parent_link])
        frames[link] = model.addBodyFrame(link, jid, _se3(100 + k), joint_frame)
        joint_ids[link] = jid
    model.addBodyFrame("l_tool", joint_ids["l_px"], _se3(200), frames["l_px"])  # fixed to l_px
    return RobotModel(model, pin.GeometryModel(), couplings=[JointCoupling("j_follower", "j_unaligned", -2.0, 0.1)])


def _relative_poses(robot: RobotModel, q: np.ndarray, links: list[tuple[str, str]]) -> list[pin.SE3]:
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    pose = {name: data.oMf[robot.frame_id(name)] for name in robot.link_names}
    pose["world"] = pin.SE3.Identity()
    return [pose[parent].actInv(pose[child]) for parent, child in links]


def _decoded(data: bytes) -> list[tuple[str, str, pin.SE3]]:
    out = []
    for t in deserialize_message(data, TFMessage).transforms:
        r, p = t.transform.rotation, t.transform.translation
        out.append((t.header.frame_id, t.child_frame_id, pin.SE3(pin.Quaternion(r.w, r.x, r.y, r.z).matrix(), np.array([p.x, p.y, p.z]))))
    return out


def _check(robot: RobotModel, names: tuple[str, ...], positions: np.ndarray) -> None:
    model = tf_model(robot, LinkTree.of(robot))
    assert model is not None
    model = TfModel.from_json(model.to_json())  # as the worker gets it
    writer = TfWriter(model)
    q = robot.configuration(dict(zip(names, positions)))
    tf, later = writer.tf(names, [positions, positions], [1_700_000_000_123_456_789, 1_800_000_000_000_000_001])
    assert deserialize_message(later, TFMessage).transforms[0].header.stamp.sec == 1_800_000_000  # each its own stamp
    for data, links in ((tf, model.moving),
                        (writer.tf_static(1_700_000_000_123_456_789), model.fixed)):
        decoded = _decoded(data)
        frames = [(link.parent, link.child) for link in links]
        assert [(parent, child) for parent, child, _ in decoded] == frames
        for (_, child, got), expected in zip(decoded, _relative_poses(robot, q, frames)):
            np.testing.assert_allclose(got.homogeneous, expected.homogeneous, atol=1e-12, err_msg=child)
        stamp = deserialize_message(data, TFMessage).transforms[0].header.stamp
        assert (stamp.sec, stamp.nanosec) == (1_700_000_000, 123_456_789)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_one_axis_joint_kind_matches_pinocchio(seed):
    robot = _toy_robot()
    names = ("j_rz", "j_prismatic", "j_unaligned", "j_unbounded", "j_px")
    _check(robot, names, np.random.default_rng(seed).uniform(-3.0, 3.0, len(names)))


def test_a_joint_the_joint_state_leaves_out_stays_neutral_and_names_come_in_any_order():
    robot = _toy_robot()
    _check(robot, ("j_unbounded", "j_rz"), np.array([2.5, -1.0]))
    _check(robot, (), np.array([]))


def test_the_planning_robot_and_its_coupled_gripper_match_pinocchio():
    from sim.robot_model import planning_robot_model

    robot = planning_robot_model()
    followers = {c.joint for c in robot.couplings}
    names = tuple(j for j in robot.movable_joints if j not in followers)
    _check(robot, names, np.random.default_rng(3).uniform(-1.0, 1.0, len(names)))
    assert {link.child for link in tf_model(robot, LinkTree.of(robot)).fixed} >= {"base", "gripper_base"}


def test_a_link_two_joints_below_its_parent_link_is_left_to_the_run():
    model = pin.Model()
    j1 = model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "j1")
    j2 = model.addJoint(j1, pin.JointModelRY(), _se3(1), "j2")  # no link between j1 and j2
    model.addBodyFrame("tip", j2, pin.SE3.Identity(), model.addJointFrame(j2, 0))
    assert tf_model(RobotModel(model, pin.GeometryModel()), LinkTree.of(RobotModel(model, pin.GeometryModel()))) is None


def test_joint_state_arrays_reads_what_the_hand_encoder_and_rclpy_write():
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    msg = JointState(name=["a", "bb", "ccc"], position=[0.5, -1.25, 3.0], velocity=[1.0, 2.0, 3.0])
    msg.header.frame_id = "base"
    for data in (JointStateEncoder().encode(msg), serialize_message(msg)):
        assert joint_state_arrays(data) == (("a", "bb", "ccc"), (0.5, -1.25, 3.0), (1.0, 2.0, 3.0))
    msg.velocity = []
    assert joint_state_arrays(serialize_message(msg)).velocity == ()
    with pytest.raises(ValueError, match="truncated"):
        joint_state_arrays(serialize_message(msg)[:30])


@pytest.mark.parametrize("cache", ["fresh", "off"])
def test_the_robot_markers_from_the_disk_cache_are_the_markers_stamped_anew(tmp_path, monkeypatch, cache):
    from rclpy.serialization import serialize_message
    from visualization_msgs.msg import MarkerArray

    from recording.scene_view import robot_markers, robot_markers_cdr, stamp_of
    from sim.robot_model import planning_robot_model

    monkeypatch.setenv("OBJECTIVE_CACHE_DIR", str(tmp_path))
    if cache == "off":
        monkeypatch.setenv("OBJECTIVE_CACHE", "off")
    robot = planning_robot_model()
    for stamp_ns in (1_700_000_000_123_456_789, 1_700_000_042_000_000_001):  # a miss, then a hit
        stamp = stamp_of(stamp_ns)
        got = deserialize_message(robot_markers_cdr(robot, stamp).data, MarkerArray)
        assert got == deserialize_message(serialize_message(robot_markers(robot, stamp)), MarkerArray)  # (float32 colours)
        assert {(m.header.stamp.sec, m.header.stamp.nanosec) for m in got.markers} == {divmod(stamp_ns, 10**9)}
    assert len(list(tmp_path.glob("robot_markers/*"))) == (0 if cache == "off" else 1)
