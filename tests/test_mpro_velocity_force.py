"""PublishVelocityForceCommand and ForceExceedsThreshold (behaviors/velocity_force.py), and the
push-until-contact example on the MuJoCo cell, where the table pushes back."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import Twist, Wrench, WrenchStamped
from std_msgs.msg import Float64MultiArray

from behaviors.velocity_force import ForceExceedsThreshold, PublishVelocityForceCommand, check_axes, commands_topic, joint_velocities
from runtime.tree.behavior import Status
from runtime.tree.blackboard import Blackboard
from runtime.tree.registry import Registry
from runtime.app.runner import RunOptions, run_file
from runtime.motion.scene.kinematics import frame_jacobian, frame_pose
from sim.robot_model import ARM_JOINTS
from tests.test_mpro_trajectories import cell_scene
from tests.test_scene_behaviors import HOME, make_context, make_node, publish_joint_states, tick

OBJECTIVES = Path(__file__).resolve().parent.parent / "objectives"


def test_joint_velocities_move_the_tip_with_the_twist_in_its_own_axes():
    scene = cell_scene()
    layout = scene.layout("manipulator", None)
    q = layout(np.array(HOME))
    jacobian = frame_jacobian(scene.robot, q, "tcp", ARM_JOINTS)
    rotation = frame_pose(scene.robot, q, "tcp")[:3, :3]
    qdot = joint_velocities(jacobian, rotation, np.array([0.0, 0.0, 0.05, 0.0, 0.0, 0.0]))
    # at Home the TCP's z points down: 5 cm/s along it is 5 cm/s down in the world
    np.testing.assert_allclose(jacobian @ qdot, [0.0, 0.0, -0.05, 0.0, 0.0, 0.0], atol=2e-4)  # damped: within 0.4 %
    # the same Jacobian, checked by finite differences of the TCP position
    step = 1e-6
    moved = frame_pose(scene.robot, layout(np.array(HOME) + step * qdot), "tcp")[:3, 3]
    np.testing.assert_allclose((moved - frame_pose(scene.robot, q, "tcp")[:3, 3]) / step, [0.0, 0.0, -0.05], atol=1e-4)


def test_axes_and_topics_are_checked():
    assert check_axes([0, 0, 1, 0, 0, 0], [0] * 6) is None
    assert check_axes([1, 1, 1], [0] * 6) == "velocity_controlled_axes needs six 0/1 values (x;y;z;rx;ry;rz), got [1, 1, 1]"
    assert check_axes([1] * 6, [0, 0, 1, 0, 0, 0]).startswith("force control is not available")
    assert commands_topic("/velocity_force_controller/command") == "/velocity_force_controller/commands"
    assert commands_topic("/velocity_force_controller") == "/velocity_force_controller/commands"


def velocity_node(context, **ports: str):
    blackboard = Blackboard()
    blackboard.set("twist", Twist())
    blackboard.set("wrench", Wrench())
    return make_node(PublishVelocityForceCommand, context, blackboard, twist="{twist}", wrench="{wrench}", **ports)


def test_publish_velocity_force_command_publishes_joint_velocities_at_its_rate_and_stops_when_halted():
    context = make_context(cell_scene())
    commands: list[Float64MultiArray] = []
    context.bus.create_subscription("/velocity_force_controller/commands", Float64MultiArray, commands.append)
    node = velocity_node(context, publish_rate="25")
    publish_joint_states(context, HOME)
    for _ in range(20):  # 0.2 s of 10 ms ticks
        assert tick(node) is Status.RUNNING
        context.clock.advance(0.01)
    assert len(commands) == 5 and all(len(c.data) == 6 for c in commands)
    node.stop(Status.INVALID)  # halted
    assert list(commands[-1].data) == [0.0] * 6


def test_force_control_is_refused():
    context = make_context(cell_scene())
    node = velocity_node(context, force_controlled_axes="0;0;1;0;0;0")
    assert tick(node) is Status.FAILURE
    assert node.feedback_message.startswith("force control is not available: the cell's velocity_force_controller takes joint velocities only")


def wrench(fz: float) -> WrenchStamped:
    msg = WrenchStamped()
    msg.wrench.force.z = fz
    return msg


def test_force_exceeds_threshold_needs_consecutive_readings():
    context = make_context(None)
    publisher = context.bus.create_publisher("/ft", WrenchStamped)
    node = make_node(ForceExceedsThreshold, context, wrench_topic_name="/ft", force_threshold="20", minimum_consecutive_wrench_values="3")
    statuses = []
    for fz in (-25.0, -25.0, -5.0, -25.0, -25.0, -25.0):
        publisher.publish(wrench(fz))
        statuses.append(tick(node))
    assert statuses == [Status.RUNNING] * 5 + [Status.SUCCESS]
    assert node.feedback_message == "force above 20 N in 3 readings in a row"


def test_force_exceeds_threshold_fails_without_a_publisher():
    context = make_context(None)
    node = make_node(ForceExceedsThreshold, context, wrench_topic_name="/nothing", force_threshold="20")
    status = tick(node)
    while status is Status.RUNNING:
        context.clock.advance(0.1)
        status = tick(node)
    assert (status, node.feedback_message) == (Status.FAILURE, "no publisher on '/nothing' after 5 s")
    assert context.clock.now() == pytest.approx(5.0)


def test_push_until_contact_stops_on_the_table_and_returns_home():
    result = run_file(OBJECTIVES / "examples" / "push_until_contact.xml", Registry.from_entry_points(), RunOptions(world="vla_sim", max_seconds=30.0))
    assert (result.status, result.reason) == ("SUCCESS", "")
    # Home is 30 cm up; at 5 cm/s the fingertips reach the table in well under 8 s
    assert 4.0 < result.sim_seconds < 12.0


def test_zero_fts_tares_the_wrist_sensor_through_call_trigger_service():
    from behaviors.messages import CallTriggerService
    from runtime.tree.behavior import RunContext
    from runtime.io.bus import InProcessBus
    from runtime.io.clock import SimClock
    from runtime.tree.events import EventLog
    from sim.controllers import WRENCH_TOPIC
    from sim.kinematic import create_kinematic

    clock = SimClock()
    context = RunContext(clock=clock, bus=InProcessBus(clock), events=EventLog(clock))
    world = create_kinematic({"policy": "none"})
    world.start(context)
    try:
        readings = context.bus.create_subscription(WRENCH_TOPIC, WrenchStamped, reliable=False)
        world.cell.external_wrench = np.array([0.0, 0.0, -12.0, 0.1, 0.0, 0.0])
        assert readings.latest.wrench.force.z == -12.0
        node = make_node(CallTriggerService, context, service_name="/velocity_force_controller/zero_fts")
        status = tick(node)
        while status is Status.RUNNING:
            clock.advance(0.01)
            world.step_to(clock.now())
            context.bus.spin_once()
            status = tick(node)
        assert (status, node.feedback_message) == (Status.SUCCESS, "force-torque sensor zeroed")
        assert readings.latest.wrench.force.z == 0.0
        world.cell.external_wrench = np.array([0.0, 0.0, -20.0, 0.1, 0.0, 0.0])
        assert readings.latest.wrench.force.z == -8.0  # later readings are relative to the zero
    finally:
        world.close()
