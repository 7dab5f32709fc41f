"""The project's generated ROS 2 interfaces: constants, fields, and a CDR round trip."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.timeout(60)]

from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402



def round_trip(msg):
    return deserialize_message(serialize_message(msg), type(msg))


def test_get_action_chunk_constants_and_fields_survive_the_wire():
    from moveit_pro_ml_msgs.srv import GetActionChunk
    from sensor_msgs.msg import Image, JointState
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension
    from trajectory_msgs.msg import JointTrajectoryPoint

    R = GetActionChunk.Response
    assert (R.UNKNOWN, R.CHUNK_PRODUCED, R.NO_MORE_ACTIONS, R.ERROR) == (0, 1, 2, 3)
    assert R().status == R.UNKNOWN  # the default must read as a failure

    request = GetActionChunk.Request(
        prompt="stack the cubes",
        robot_state=JointState(name=["a", "b"], position=[0.1, -0.2]),
        images=[Image(height=2, width=3, encoding="rgb8", step=9, data=bytes(range(18)))],
        image_names=["scene"],
        new_episode=True,
        previous_action_chunk=Float64MultiArray(
            layout=_layout([("steps", 2, 4), ("actions", 2, 2)], MultiArrayDimension), data=[1.0, 2.0, 3.0, 4.0]
        ),
        previous_anchor_state=JointState(name=["a", "b"], position=[0.0, 0.5]),
        frozen_prefix_steps=3,
        guidance_horizon=7,
    )
    back = round_trip(request)
    assert back.prompt == "stack the cubes"
    assert list(back.robot_state.position) == [0.1, -0.2]
    assert bytes(back.images[0].data) == bytes(range(18)) and back.image_names == ["scene"]
    assert back.new_episode is True
    assert list(back.previous_action_chunk.data) == [1.0, 2.0, 3.0, 4.0]
    assert back.previous_action_chunk.layout.dim[0].label == "steps"
    assert back.previous_anchor_state.position[1] == 0.5
    assert (back.frozen_prefix_steps, back.guidance_horizon) == (3, 7)

    response = R(status=R.CHUNK_PRODUCED, message="ok", native_control_period=1 / 30)
    response.chunk.joint_names = ["a", "b"]
    response.chunk.points = [JointTrajectoryPoint(positions=[0.1, 0.2]), JointTrajectoryPoint(positions=[0.3, 0.4])]
    response.policy_action_chunk.data = [0.5, -0.5]
    back = round_trip(response)
    assert back.status == R.CHUNK_PRODUCED and back.message == "ok"
    assert [list(p.positions) for p in back.chunk.points] == [[0.1, 0.2], [0.3, 0.4]]
    assert back.native_control_period == pytest.approx(1 / 30)
    assert list(back.policy_action_chunk.data) == [0.5, -0.5]


def _layout(dims, Dim):
    from std_msgs.msg import MultiArrayLayout

    return MultiArrayLayout(dim=[Dim(label=l, size=s, stride=st) for l, s, st in dims], data_offset=0)


def test_get_action_chunk_field_types_are_the_contract():
    from moveit_pro_ml_msgs.srv import GetActionChunk

    assert GetActionChunk.Request.get_fields_and_field_types() == {
        "prompt": "string",
        "robot_state": "sensor_msgs/JointState",
        "images": "sequence<sensor_msgs/Image>",
        "image_names": "sequence<string>",
        "new_episode": "boolean",
        "previous_action_chunk": "std_msgs/Float64MultiArray",
        "previous_anchor_state": "sensor_msgs/JointState",
        "frozen_prefix_steps": "uint32",
        "guidance_horizon": "uint32",
    }
    assert GetActionChunk.Response.get_fields_and_field_types() == {
        "status": "uint8",
        "message": "string",
        "chunk": "trajectory_msgs/JointTrajectory",
        "native_control_period": "double",
        "policy_action_chunk": "std_msgs/Float64MultiArray",
    }


def test_admittance_action_constants_and_fields():
    from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance as A

    R = A.Result
    codes = [R.SUCCESSFUL, R.INVALID_GOAL, R.INVALID_JOINTS, R.OLD_HEADER_TIMESTAMP, R.PATH_TOLERANCE_VIOLATED,
             R.GOAL_TOLERANCE_VIOLATED, R.FORCE_TORQUE_THRESHOLD_EXCEEDED, R.CANCELED, R.SUPERSEDED,
             R.SEAM_AFTER_TRAJECTORY_END]
    assert codes == [0, -1, -2, -3, -4, -5, -6, -7, -8, -9]
    assert R.get_fields_and_field_types() == {"error_code": "int32", "error_string": "string"}

    goal = A.Goal(path_tolerance=0.05, goal_time_tolerance=0.5, absolute_force_torque_threshold=[30.0] * 3 + [3.0] * 3,
                  admittance_stiffness=[500.0] * 6, admittance_damping=[50.0] * 6)
    goal.joint_trajectory.header.stamp.sec = 12
    goal.joint_trajectory.joint_names = ["shoulder_pan_joint"]
    back = round_trip(goal)
    assert back.joint_trajectory.header.stamp.sec == 12 and back.path_tolerance == 0.05
    assert list(back.absolute_force_torque_threshold) == [30.0, 30.0, 30.0, 3.0, 3.0, 3.0]
    assert len(back.admittance_stiffness) == 6 and len(back.admittance_damping) == 6

    assert A.Feedback.get_fields_and_field_types() == {
        "header": "std_msgs/Header",
        "joint_names": "sequence<string>",
        "desired": "trajectory_msgs/JointTrajectoryPoint",
        "actual": "trajectory_msgs/JointTrajectoryPoint",
        "error": "trajectory_msgs/JointTrajectoryPoint",
        "wrench": "geometry_msgs/Wrench",
    }


def test_gripper_command_matches_upstream_control_msgs():
    from control_msgs.action import GripperCommand
    from control_msgs.msg import GripperCommand as Command

    assert Command.get_fields_and_field_types() == {"position": "double", "max_effort": "double"}
    assert GripperCommand.Goal.get_fields_and_field_types() == {"command": "control_msgs/GripperCommand"}
    expected = {"position": "double", "effort": "double", "stalled": "boolean", "reached_goal": "boolean"}
    assert GripperCommand.Result.get_fields_and_field_types() == expected
    assert GripperCommand.Feedback.get_fields_and_field_types() == expected
    back = round_trip(GripperCommand.Goal(command=Command(position=0.04, max_effort=20.0)))
    assert (back.command.position, back.command.max_effort) == (0.04, 20.0)


CONTROL_MSGS_JAZZY = {
    "action": ["ExecuteMotionPrimitiveSequence", "FollowJointTrajectory", "GripperCommand", "JointTrajectory",
               "ParallelGripperCommand", "PointHead", "SingleJointPosition"],
    "msg": ["AdmittanceControllerState", "BatteryStateArray", "DynamicInterfaceGroupValues", "DynamicInterfaceValues",
            "DynamicJointState", "Float64Values", "GripperCommand", "InterfaceValue", "JointComponentTolerance",
            "JointControllerState", "JointJog", "JointTolerance", "JointTrajectoryControllerState", "Keys",
            "MecanumDriveControllerState", "MotionArgument", "MotionPrimitive", "MotionPrimitiveSequence", "MultiDOFCommand",
            "MultiDOFStateStamped", "PidState", "SingleDOFState", "SingleDOFStateStamped", "SpeedScalingFactor",
            "SteeringControllerStatus", "VDA5050SafetyState"],
    "srv": ["QueryCalibrationState", "QueryTrajectoryState", "SetOdometry"],
}
"""Every interface of ros-controls/control_msgs 5.8.0, the ROS 2 Jazzy release."""


def test_control_msgs_is_the_whole_jazzy_release():
    import importlib

    for kind, names in CONTROL_MSGS_JAZZY.items():
        module = importlib.import_module(f"control_msgs.{kind}")
        for name in names:
            assert hasattr(module, name), f"control_msgs/{kind}/{name} is missing"
    package = Path(__file__).resolve().parent.parent / "runtime" / "io" / "ros" / "interfaces" / "control_msgs"
    shipped = {kind: sorted(f.stem for f in (package / kind).iterdir()) for kind in CONTROL_MSGS_JAZZY}
    assert shipped == CONTROL_MSGS_JAZZY


def test_follow_joint_trajectory_matches_upstream_control_msgs():
    from builtin_interfaces.msg import Duration
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import JointComponentTolerance, JointTolerance
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    assert FollowJointTrajectory.Goal.get_fields_and_field_types() == {
        "trajectory": "trajectory_msgs/JointTrajectory",
        "multi_dof_trajectory": "trajectory_msgs/MultiDOFJointTrajectory",
        "path_tolerance": "sequence<control_msgs/JointTolerance>",
        "component_path_tolerance": "sequence<control_msgs/JointComponentTolerance>",
        "goal_tolerance": "sequence<control_msgs/JointTolerance>",
        "component_goal_tolerance": "sequence<control_msgs/JointComponentTolerance>",
        "goal_time_tolerance": "builtin_interfaces/Duration",
    }
    R = FollowJointTrajectory.Result
    assert (R.SUCCESSFUL, R.INVALID_GOAL, R.INVALID_JOINTS, R.OLD_HEADER_TIMESTAMP, R.PATH_TOLERANCE_VIOLATED,
            R.GOAL_TOLERANCE_VIOLATED) == (0, -1, -2, -3, -4, -5)
    assert R.get_fields_and_field_types() == {"error_code": "int32", "error_string": "string"}
    assert list(FollowJointTrajectory.Feedback.get_fields_and_field_types()) == [
        "header", "joint_names", "desired", "actual", "error",
        "multi_dof_joint_names", "multi_dof_desired", "multi_dof_actual", "multi_dof_error",
    ]
    assert JointTolerance.get_fields_and_field_types() == {
        "name": "string", "position": "double", "velocity": "double", "acceleration": "double"}
    assert (JointComponentTolerance.X_AXIS, JointComponentTolerance.ROTATION) == (1, 5)
    goal = FollowJointTrajectory.Goal(
        trajectory=JointTrajectory(joint_names=["a"], points=[JointTrajectoryPoint(positions=[0.5], velocities=[0.0])]),
        path_tolerance=[JointTolerance(name="a", position=0.3)], goal_time_tolerance=Duration(sec=1))
    back = round_trip(goal)
    assert back.trajectory.points[0].positions[0] == 0.5 and back.path_tolerance[0].position == 0.3
    assert back.goal_time_tolerance.sec == 1


def test_control_msgs_constants_and_defaults_match_upstream():
    from control_msgs.msg import MotionPrimitive, VDA5050SafetyState

    assert (MotionPrimitive.UNKNOWN, MotionPrimitive.LINEAR_JOINT, MotionPrimitive.CIRCULAR_CARTESIAN) == (-1, 0, 51)
    assert MotionPrimitive().type == -1
    assert VDA5050SafetyState.AUTO_ACK == "autoAck"


def test_controller_manager_interfaces_match_upstream_jazzy():
    from controller_manager_msgs.msg import ChainConnection, ControllerState
    from controller_manager_msgs.srv import ListControllers, SwitchController

    Req = SwitchController.Request
    assert (Req.BEST_EFFORT, Req.STRICT) == (1, 2)
    assert Req.get_fields_and_field_types() == {
        "activate_controllers": "sequence<string>",
        "deactivate_controllers": "sequence<string>",
        "strictness": "int32",
        "activate_asap": "boolean",
        "timeout": "builtin_interfaces/Duration",
    }
    assert SwitchController.Response.get_fields_and_field_types() == {"ok": "boolean", "message": "string"}
    assert list(ControllerState.get_fields_and_field_types()) == [
        "name", "state", "type", "claimed_interfaces", "required_command_interfaces", "required_state_interfaces",
        "is_chainable", "is_chained", "exported_state_interfaces", "reference_interfaces", "chain_connections",
    ]
    assert ListControllers.Response.get_fields_and_field_types() == {
        "controller": "sequence<controller_manager_msgs/ControllerState>"
    }
    state = ControllerState(name="joint_trajectory_admittance_controller", state="active",
                            chain_connections=[ChainConnection(name="x", reference_interfaces=["a/position"])])
    back = round_trip(ListControllers.Response(controller=[state]))
    assert back.controller[0].state == "active"
    assert back.controller[0].chain_connections[0].reference_interfaces == ["a/position"]


# --------------------------------------------------------------------------------------------
# runtime/app/build_interfaces.py (`objective build-interfaces`)
# --------------------------------------------------------------------------------------------
def _load_build_tool():
    import runtime.app.build_interfaces

    return runtime.app.build_interfaces


def test_wheel_include_paths_are_rewritten_and_the_rewrite_is_idempotent():
    tool = _load_build_tool()
    text = ('INTERFACE_INCLUDE_DIRECTORIES "/opt/python/cp311-cp311/include/python3.11;'
            '/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"')
    once = tool.rewrite_wheel_paths(text, "/py/include", "/venv/numpy/include")
    assert once == 'INTERFACE_INCLUDE_DIRECTORIES "/py/include;/venv/numpy/include"'
    assert tool.rewrite_wheel_paths(once, "/py/include", "/venv/numpy/include") == once


def test_the_venv_has_no_wheel_build_paths_left():
    leftovers = [str(f) for f in (Path(sys.prefix) / "share").rglob("*.cmake") if "/opt/python/" in f.read_text()]
    assert leftovers == []


def test_packages_build_in_dependency_order(tmp_path):
    tool = _load_build_tool()
    pkgs = [tool.Package("b", tmp_path, {"a", "std_msgs"}), tool.Package("a", tmp_path, set()),
            tool.Package("c", tmp_path, {"b"})]
    assert [p.name for p in tool.dependency_order(pkgs)] == ["a", "b", "c"]
    with pytest.raises(tool.BuildError, match="dependency cycle between interface packages: a -> b -> a"):
        tool.dependency_order([tool.Package("a", tmp_path, {"b"}), tool.Package("b", tmp_path, {"a"})])


def test_every_interface_package_is_described_by_its_manifest():
    tool = _load_build_tool()
    names = sorted(tool.read_package(d).name for d in tool.INTERFACES_DIR.iterdir() if (d / "package.xml").is_file())
    assert names == ["control_msgs", "controller_manager_msgs", "moveit_pro_controllers_msgs", "moveit_pro_ml_msgs",
                     "objective_server_msgs", "tf2_msgs"]


def test_only_what_python_uses_is_built_into_the_venv():
    tool = _load_build_tool()
    for name in ["control_msgs", "controller_manager_msgs", "moveit_pro_controllers_msgs", "moveit_pro_ml_msgs",
                 "objective_server_msgs", "tf2_msgs"]:
        files = tool.read_marker(Path(sys.prefix), name).get("files")
        assert files, f"{name}: no {tool.MARKER} in this venv (make setup installs one)"
        assert f"lib/lib{name}__rosidl_typesupport_fastrtps_c.so" in files
        assert f"lib/lib{name}__rosidl_generator_py.so" in files
        assert [f for f in files if "cpp" in f] == [], f"{name}: C++ generator output installed"
