"""MoveIt Pro's vector and pose-building nodes (behaviors/vectors.py) and the message port types.

Trees are written as MoveIt Pro's Objectives write them and run with no world (none of these
nodes needs one), on the simulated clock.
"""
from __future__ import annotations

from pathlib import Path

import pytest
from geometry_msgs.msg import PoseStamped

from behaviors.vectors import CreatePoseStamped, element_at, pose_stamped
from runtime.tree.behavior import Status
from runtime.tree.blackboard import Blackboard
from runtime.errors import PortError
from runtime.tree.ports import ConversionError, PortType, convert
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, run_file
from tests.test_scene_behaviors import make_context, make_node, tick


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


def run_xml(registry: Registry, tmp_path: Path, body: str, max_seconds: float = 5.0):
    path = tmp_path / "tree.xml"
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">{body}</BehaviorTree></root>')
    return run_file(path, registry, RunOptions(max_seconds=max_seconds))


# -- CreatePoseStamped ----------------------------------------------------------------------------
def test_pose_stamped_normalises_the_quaternion_and_names_bad_ports():
    msg = pose_stamped("base_link", [0.1, 0.2, 0.3], [0.707, 0.707, 0.0, 0.0], 1.5)
    assert msg.header.frame_id == "base_link"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_000)
    o = msg.pose.orientation
    assert (o.x, o.y, o.z, o.w) == pytest.approx((2 ** -0.5, 2 ** -0.5, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"position_xyz needs 3 values \(x;y;z\), got 2"):
        pose_stamped("world", [0.1, 0.2], [0, 0, 0, 1], 0.0)
    with pytest.raises(ValueError, match="orientation_xyzw .* is not a rotation"):
        pose_stamped("world", [0, 0, 0], [0, 0, 0, 0], 0.0)


def test_create_pose_stamped_writes_to_pose_stamped_by_default():
    # MoveIt Pro Objectives often leave pose_stamped unset and read {pose_stamped} afterwards.
    context, blackboard = make_context(None), Blackboard()
    node = make_node(CreatePoseStamped, context, blackboard, reference_frame="tcp", position_xyz="0;0;0.1")
    assert tick(node) is Status.SUCCESS
    pose = blackboard.get("pose_stamped")
    assert isinstance(pose, PoseStamped) and pose.header.frame_id == "tcp"
    assert (pose.pose.position.z, pose.pose.orientation.w) == (0.1, 1.0)


def test_create_pose_stamped_with_a_wrong_length_fails_naming_the_port():
    node = make_node(CreatePoseStamped, make_context(None), Blackboard(), orientation_xyzw="0;0;1")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "orientation_xyzw needs 4 values (x;y;z;w), got 3"


# -- message port types ---------------------------------------------------------------------------
def test_a_literal_for_a_pose_port_is_a_load_error_naming_file_line_and_port(registry, tmp_path):
    path = tmp_path / "bad.xml"
    path.write_text('<root BTCPP_format="4"><BehaviorTree ID="Main">\n<VisualizePose pose="0;0;0"/>\n</BehaviorTree></root>')
    from runtime.tree.loader import validate

    with pytest.raises(PortError) as err:
        validate(path, registry).trees_or_raise()
    assert str(err.value).endswith(
        "bad.xml:2: VisualizePose: port 'pose' expects a geometry_msgs/PoseStamped from the blackboard, got '0;0;0'"
    )


def test_message_ports_accept_their_type_only():
    pose = PoseStamped()
    assert convert(pose, PortType.POSE_STAMPED) is pose
    with pytest.raises(ConversionError) as err:
        convert(pose, PortType.TWIST_STAMPED)
    assert str(err.value) == "expects a geometry_msgs/TwistStamped from the blackboard, got a geometry_msgs/PoseStamped"
    assert convert([pose], PortType.POSE_STAMPED_LIST) == [pose]
    with pytest.raises(ConversionError):
        convert([pose, 3.0], PortType.POSE_STAMPED_LIST)
    assert convert("", PortType.ANY_LIST) == []


# -- vectors --------------------------------------------------------------------------------------
def test_push_back_builds_a_vector_and_leaves_the_old_list_alone(registry, tmp_path):
    result = run_xml(registry, tmp_path, """<Sequence>
      <CreatePoseStamped position_xyz="1;0;0" pose_stamped="{a}"/>
      <CreatePoseStamped position_xyz="2;0;0" pose_stamped="{b}"/>
      <ResetPoseStampedVector vector="{poses}"/>
      <PushBackVector input_vector="{poses}" element="{a}" output_vector="{first}"/>
      <PushBackVector input_vector="{first}" element="{b}" output_vector="{both}"/>
      <GetSizeOfVector vector_in="{first}" vector_size="{n_first}"/>
      <GetSizeOfVector vector_in="{both}" vector_size="{n_both}"/>
      <GetElementOfVector vector_in="{both}" index="1" element="{second}"/>
      <ScriptCondition code="n_first == 1 &amp;&amp; n_both == 2"/>
    </Sequence>""")
    assert (result.status, result.reason) == ("SUCCESS", "")


def test_push_back_refuses_an_element_of_another_type(registry, tmp_path):
    result = run_xml(registry, tmp_path, """<Sequence>
      <CreatePoseStamped pose_stamped="{a}"/>
      <ResetVector vector="{v}"/>
      <PushBackVector input_vector="{v}" element="{a}" output_vector="{v}"/>
      <CreateTwistStamped twist_stamped="{t}"/>
      <PushBackVector name="mixed" input_vector="{v}" element="{t}" output_vector="{v}"/>
    </Sequence>""")
    assert (result.status, result.failing_node) == ("FAILURE", "mixed")
    assert result.reason == "element is a TwistStamped but input_vector holds PoseStamped elements"


def test_get_element_outside_the_vector_gives_the_size():
    assert element_at([1, 2], 1) == 2
    with pytest.raises(IndexError, match=r"index 2 is outside the vector \(size 2\)"):
        element_at([1, 2], 2)


# -- ForEach --------------------------------------------------------------------------------------
FOREACH = """<Sequence>
  <Script code="total := 0; visits := 0"/>
  <ResetVector vector="{v}"/>
  {pushes}
  <ForEach vector_in="{v}" out="{x}" index="{i}">
    <Script code="total += x * (i + 1); visits += 1"/>
  </ForEach>
</Sequence>"""


def pushes(values: list[float]) -> str:
    return "".join(
        f'<Script code="e := {v}"/><PushBackVector input_vector="{{v}}" element="{{e}}" output_vector="{{v}}"/>' for v in values
    )


def test_for_each_visits_every_element_with_its_index(registry, tmp_path):
    result = run_xml(registry, tmp_path, FOREACH.replace("{pushes}", pushes([10, 20, 30])))
    assert result.status == "SUCCESS"
    assert result.blackboard["total"] == 10 * 1 + 20 * 2 + 30 * 3
    assert result.blackboard["visits"] == 3
    assert (result.blackboard["x"], result.blackboard["i"]) == (30, 2)  # the last element stays set
    assert result.ticks == 3  # one element per tick


def test_for_each_over_an_empty_vector_succeeds_without_ticking_the_child(registry, tmp_path):
    result = run_xml(registry, tmp_path, FOREACH.replace("{pushes}", ""))
    assert (result.status, result.blackboard["visits"]) == ("SUCCESS", 0)


def test_for_each_stops_at_the_first_failing_element(registry, tmp_path):
    result = run_xml(registry, tmp_path, """<Sequence>
      <Script code="seen := 0"/>
      <ResetVector vector="{v}"/>
      """ + pushes([1, 2, 3]) + """
      <ForEach vector_in="{v}" out="{x}">
        <Sequence><Script code="seen += 1"/><ScriptCondition name="small" code="x &lt; 2"/></Sequence>
      </ForEach>
    </Sequence>""")
    assert (result.status, result.failing_node) == ("FAILURE", "small")
    assert result.blackboard["seen"] == 2
