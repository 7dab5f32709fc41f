"""RosBus: the runtime.io.bus API over real rclpy, two buses (nodes) in one process on loopback."""
from __future__ import annotations

import threading
import time
import uuid
from typing import Callable

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.timeout(30)]

from control_msgs.action import GripperCommand  # noqa: E402
from control_msgs.msg import GripperCommand as Command  # noqa: E402
from moveit_pro_ml_msgs.srv import GetActionChunk  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from runtime.io.bus import STATUS_ABORTED, STATUS_CANCELED, STATUS_SUCCEEDED  # noqa: E402
from runtime.io.clock import WallClock  # noqa: E402
from runtime.io.ros import RosBus  # noqa: E402


def wait_for(condition: Callable[[], bool], *buses: RosBus, timeout: float = 5.0, what: str = "condition") -> None:
    """Poll like a 100 Hz runner: spin every bus, then check."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for bus in buses:
            bus.spin_once()
        if condition():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


@pytest.fixture
def names():
    """Unique ROS names per test, so concurrent test runs on one domain cannot cross-talk."""
    tag = uuid.uuid4().hex[:8]
    return lambda base: f"/t{tag}/{base}"


@pytest.fixture
def buses():
    threads_before = set(threading.enumerate())
    made: list[RosBus] = []

    def make(name: str, **kwargs) -> RosBus:
        bus = RosBus(WallClock(), node_name=name, **kwargs)
        made.append(bus)
        return bus

    yield make
    for bus in made:
        bus.close()
    leaked = [t.name for t in set(threading.enumerate()) - threads_before if t.is_alive()]
    assert leaked == [], f"RosBus.close() left threads running: {leaked}"


# --------------------------------------------------------------------------------------------
# Services
# --------------------------------------------------------------------------------------------
def test_get_action_chunk_call_between_two_buses(buses, names):
    server, client_bus = buses("policy_adapter"), buses("runtime")
    seen_threads = []

    def echo(request):
        seen_threads.append(threading.current_thread().name)
        response = GetActionChunk.Response(status=GetActionChunk.Response.CHUNK_PRODUCED, message=request.prompt)
        response.chunk.joint_names = list(request.robot_state.name)
        return response

    server.create_service(names("get_action_chunk"), GetActionChunk, echo)
    client = client_bus.create_client(names("get_action_chunk"), GetActionChunk)
    wait_for(client.service_is_ready, timeout=5, what="the service to be discovered")

    request = GetActionChunk.Request(prompt="stack red on blue", new_episode=True)
    request.robot_state.name = ["shoulder_pan_joint", "robotiq_85_left_knuckle_joint"]
    before = client_bus.clock.now()
    future = client.call_async(request)
    delivered = []
    future.add_done_callback(lambda f: delivered.append(threading.current_thread()))
    wait_for(future.done, client_bus, what="the response")

    response = future.result()
    assert response.status == GetActionChunk.Response.CHUNK_PRODUCED
    assert response.message == "stack red on blue"
    assert response.chunk.joint_names == ["shoulder_pan_joint", "robotiq_85_left_knuckle_joint"]
    assert before <= future.ready_at <= client_bus.clock.now()
    # by default a server runs its handler on an executor thread (it answers without a runner)
    assert seen_threads and seen_threads[0] != threading.main_thread().name
    wait_for(lambda: delivered, client_bus, what="the done callback")
    assert delivered == [threading.main_thread()]  # done callbacks run in spin_once


def test_a_failing_handler_answers_a_default_response(buses, names):
    server, client_bus = buses("broken_adapter"), buses("runtime")

    def broken(request):
        raise ValueError("model still loading")

    server.create_service(names("get_action_chunk"), GetActionChunk, broken)
    client = client_bus.create_client(names("get_action_chunk"), GetActionChunk)
    wait_for(client.service_is_ready, what="the service")
    future = client.call_async(GetActionChunk.Request())
    wait_for(future.done, client_bus, what="the response")
    assert future.result().status == GetActionChunk.Response.UNKNOWN


def test_calling_an_absent_service_or_with_the_wrong_type_fails_at_once(buses, names):
    bus = buses("runtime")
    client = bus.create_client(names("nobody_serves_this"), GetActionChunk)
    assert client.service_is_ready() is False
    with pytest.raises(RuntimeError, match=r"service '/t\w+/nobody_serves_this' is not available"):
        client.call_async(GetActionChunk.Request())
    with pytest.raises(TypeError, match="takes GetActionChunk.Request, got GetActionChunk_Response"):
        client.call_async(GetActionChunk.Response())


# --------------------------------------------------------------------------------------------
# Topics
# --------------------------------------------------------------------------------------------
def test_reliable_topic_is_delivered_and_callbacks_run_in_spin_once(buses, names):
    pub_bus, sub_bus = buses("world"), buses("runtime")
    pub = pub_bus.create_publisher(names("joint_states"), String, reliable=True)
    callback_threads = []
    sub = sub_bus.create_subscription(
        names("joint_states"), String, callback=lambda m: callback_threads.append(threading.current_thread()),
        reliable=True,
    )
    wait_for(sub.has_publishers, what="the publisher to be discovered")
    wait_for(lambda: pub.subscriber_count() > 0, what="the subscription to be discovered")

    for i in range(3):
        pub.publish(String(data=f"m{i}"))
    wait_for(lambda: sub.count == 3, what="three messages")
    assert sub.latest.data == "m2"
    wait_for(lambda: len(callback_threads) == 3, sub_bus, what="three callbacks")
    assert set(callback_threads) == {threading.main_thread()}
    with pytest.raises(TypeError, match="carries String, got int"):
        pub.publish(3)


def test_best_effort_publisher_never_reaches_a_reliable_subscription(buses, names):
    pub_bus, sub_bus = buses("camera"), buses("runtime")
    best_effort = pub_bus.create_publisher(names("image"), String, reliable=False)
    reliable_sub = sub_bus.create_subscription(names("image"), String, reliable=True)
    best_effort_sub = sub_bus.create_subscription(names("image"), String, reliable=False)
    wait_for(best_effort_sub.has_publishers, what="the publisher to be discovered")
    assert reliable_sub.has_publishers() is False  # QoS-incompatible publishers do not count

    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline and best_effort_sub.count < 5:
        best_effort.publish(String(data="frame"))
        time.sleep(0.02)
    assert best_effort_sub.count >= 1 and best_effort_sub.latest.data == "frame"
    assert reliable_sub.count == 0 and reliable_sub.latest is None


def test_lazy_publisher_publishes_at_its_rate_only_while_subscribed(buses, names):
    pub_bus, sub_bus = buses("camera"), buses("runtime")
    produced = []

    def produce():
        produced.append(time.monotonic())
        return String(data=f"frame{len(produced)}")

    pub_bus.create_lazy_publisher(names("color"), String, produce, reliable=False, rate_hz=50.0)
    time.sleep(0.2)
    assert produced == []  # nobody subscribed: nothing rendered
    sub = sub_bus.create_subscription(names("color"), String, reliable=False)
    wait_for(lambda: sub.count >= 3, timeout=5, what="three frames")
    assert sub.latest.data.startswith("frame")


def test_an_owner_served_lazy_publisher_publishes_in_spin_once_at_its_rate(buses, names):
    """With serve_in_spin_once no executor thread produces frames: the owner does, when due, on
    its own thread; subscribed or not, a spin between two due times produces nothing."""
    pub_bus, sub_bus = buses("cell", serve_in_spin_once=True), buses("runtime")
    produced = []

    def produce():
        produced.append(threading.current_thread())
        return String(data=f"frame{len(produced)}")

    pub_bus.create_lazy_publisher(names("color"), String, produce, reliable=False, rate_hz=5.0)
    sub = sub_bus.create_subscription(names("color"), String, reliable=False)
    time.sleep(0.5)
    assert produced == []  # nobody spun the owner: nothing produced, whoever subscribes
    wait_for(lambda: sub.count >= 2, pub_bus, timeout=5, what="two frames")
    assert set(produced) == {threading.main_thread()}
    before = len(produced)
    pub_bus.spin_once()
    pub_bus.spin_once()
    assert len(produced) == before  # 200 ms apart at 5 Hz: not due again yet


# --------------------------------------------------------------------------------------------
# Actions
# --------------------------------------------------------------------------------------------
class Gripper:
    """A toy action server owner: accepts goals with max_effort > 0 and is finished by the test."""

    def __init__(self) -> None:
        self.goals = []
        self.cancel_requests = 0

    def on_goal(self, handle) -> bool:
        if handle.request.command.max_effort <= 0:
            return False
        self.goals.append(handle)
        return True

    def on_cancel(self, handle) -> bool:
        self.cancel_requests += 1
        return True


def _gripper_pair(buses, names, **server_kwargs):
    server_bus, client_bus = buses("gripper", **server_kwargs), buses("runtime")
    gripper = Gripper()
    server_bus.create_action_server(names("gripper_cmd"), GripperCommand, gripper.on_goal, gripper.on_cancel)
    client = client_bus.create_action_client(names("gripper_cmd"), GripperCommand)
    wait_for(client.server_is_ready, what="the action server")
    return server_bus, client_bus, gripper, client


def test_goal_accepted_then_feedback_then_succeeded(buses, names):
    server_bus, client_bus, gripper, client = _gripper_pair(buses, names)
    feedback = []
    sent = client.send_goal_async(GripperCommand.Goal(command=Command(position=0.02, max_effort=40.0)),
                                  feedback_callback=feedback.append)
    wait_for(sent.done, client_bus, what="the goal response")
    goal = sent.result()
    assert goal.accepted is True and len(goal.goal_id) == 32

    server_goal = gripper.goals[0]
    wait_for(lambda: server_goal.goal_id == goal.goal_id, what="the server to bind the goal")
    assert server_goal.is_active and not server_goal.is_cancel_requested
    result_future = goal.get_result_async()
    assert goal.get_result_async() is result_future  # polling does not send more requests

    # from another thread, as a controller stepped by the world would
    def finish():
        server_goal.publish_feedback(GripperCommand.Feedback(position=0.01, effort=5.0))
        time.sleep(0.2)
        server_goal.succeed(GripperCommand.Result(position=0.02, effort=12.0, reached_goal=True))

    worker = threading.Thread(target=finish)
    worker.start()
    wait_for(result_future.done, client_bus, what="the result")
    worker.join()
    outcome = result_future.result()
    assert outcome.status == STATUS_SUCCEEDED
    assert (outcome.result.position, outcome.result.reached_goal) == (0.02, True)
    assert [f.position for f in feedback] == [0.01]
    assert server_goal.is_active is False
    with pytest.raises(RuntimeError, match="has already finished"):
        server_goal.abort(GripperCommand.Result())


def test_rejected_goal_has_no_result(buses, names):
    _, client_bus, gripper, client = _gripper_pair(buses, names)
    sent = client.send_goal_async(GripperCommand.Goal(command=Command(position=0.02, max_effort=0.0)))
    wait_for(sent.done, client_bus, what="the goal response")
    goal = sent.result()
    assert goal.accepted is False and gripper.goals == []
    with pytest.raises(RuntimeError, match="the goal was rejected; it has no result"):
        goal.get_result_async()


def test_cancel_reaches_the_owner_which_reports_canceled(buses, names):
    _, client_bus, gripper, client = _gripper_pair(buses, names)
    sent = client.send_goal_async(GripperCommand.Goal(command=Command(position=0.0, max_effort=10.0)))
    wait_for(sent.done, client_bus, what="the goal response")
    goal = sent.result()
    server_goal = gripper.goals[0]
    result_future = goal.get_result_async()

    cancel = goal.cancel_goal_async()
    wait_for(cancel.done, client_bus, what="the cancel response")
    assert cancel.result() is True
    assert server_goal.is_cancel_requested and gripper.cancel_requests == 1
    server_goal.canceled(GripperCommand.Result(position=0.005, stalled=True))
    wait_for(result_future.done, client_bus, what="the result")
    assert result_future.result().status == STATUS_CANCELED
    assert result_future.result().result.stalled is True


def test_owner_may_abort_and_report_canceled_without_a_cancel_request(buses, names):
    _, client_bus, gripper, client = _gripper_pair(buses, names)
    futures = []
    for _ in range(2):
        sent = client.send_goal_async(GripperCommand.Goal(command=Command(position=0.0, max_effort=10.0)))
        wait_for(sent.done, client_bus, what="the goal response")
        futures.append(sent.result().get_result_async())
    wait_for(lambda: all(g.goal_id for g in gripper.goals), what="both goals bound")
    gripper.goals[0].abort(GripperCommand.Result(stalled=True))
    gripper.goals[1].canceled(GripperCommand.Result())  # e.g. superseded: the in-process bus allows it
    wait_for(lambda: all(f.done() for f in futures), client_bus, what="both results")
    assert [f.result().status for f in futures] == [STATUS_ABORTED, STATUS_CANCELED]


def test_serve_in_spin_once_runs_server_callbacks_on_the_owner_thread(buses, names):
    server_bus, client_bus, gripper, client = _gripper_pair(buses, names, serve_in_spin_once=True)
    owner_threads = []
    original = gripper.on_goal
    gripper.on_goal = lambda handle: owner_threads.append(threading.current_thread()) or original(handle)
    server_bus.destroy_action_server(names("gripper_cmd"))
    server_bus.create_action_server(names("gripper_cmd"), GripperCommand, gripper.on_goal, gripper.on_cancel)
    wait_for(client.server_is_ready, what="the recreated action server")

    sent = client.send_goal_async(GripperCommand.Goal(command=Command(position=0.0, max_effort=10.0)))
    time.sleep(0.3)
    assert not sent.done()  # the goal waits for the owner's spin_once
    wait_for(sent.done, server_bus, client_bus, what="the goal response")
    assert sent.result().accepted is True
    assert owner_threads == [threading.main_thread()]


def test_a_cancel_sent_just_before_close_is_served_by_the_node_s_own_server(buses, names):
    """A behavior cancels the goal of a controller hosted on the same node (served in
    spin_once), and the owner closes at once: the cancel is served before the node leaves."""
    bus = buses("runner", serve_in_spin_once=True)
    gripper = Gripper()
    bus.create_action_server(names("gripper_cmd"), GripperCommand, gripper.on_goal, gripper.on_cancel)
    client = bus.create_action_client(names("gripper_cmd"), GripperCommand)
    wait_for(client.server_is_ready, bus, what="the action server")
    sent = client.send_goal_async(GripperCommand.Goal(command=Command(position=0.0, max_effort=10.0)))
    wait_for(sent.done, bus, what="the goal response")
    wait_for(lambda: gripper.goals and gripper.goals[0].goal_id, bus, what="the goal bound")
    cancel = sent.result().cancel_goal_async()
    assert bus.cancels_in_flight() == 1
    bus.close()
    assert gripper.cancel_requests == 1 and gripper.goals[0].is_cancel_requested
    assert cancel.done() and cancel.result() is True


@pytest.mark.slow  # wall-clock time
def test_close_waits_for_an_unanswered_cancel_only_so_long(buses, names, monkeypatch):
    """A server that never serves the cancel (its owner stopped spinning) delays close() by at
    most CANCEL_DELIVERY_S."""
    import runtime.io.ros.bus as ros_bus

    monkeypatch.setattr(ros_bus, "CANCEL_DELIVERY_S", 0.5)
    server_bus, client_bus, gripper, client = _gripper_pair(buses, names, serve_in_spin_once=True)
    sent = client.send_goal_async(GripperCommand.Goal(command=Command(position=0.0, max_effort=10.0)))
    wait_for(sent.done, server_bus, client_bus, what="the goal response")
    cancel = sent.result().cancel_goal_async()
    start = time.monotonic()
    client_bus.close()  # server_bus's owner never spins again: the cancel is not served
    elapsed = time.monotonic() - start
    assert not cancel.done() and gripper.cancel_requests == 0
    assert 0.5 <= elapsed < 1.5


@pytest.mark.slow  # wall-clock time
def test_close_is_idempotent_and_releases_waiting_goals(buses, names):
    server_bus, client_bus, gripper, client = _gripper_pair(buses, names)
    sent = client.send_goal_async(GripperCommand.Goal(command=Command(position=0.0, max_effort=10.0)))
    wait_for(sent.done, client_bus, what="the goal response")
    start = time.monotonic()
    server_bus.close()  # an unfinished goal must not keep the executor thread waiting
    server_bus.close()
    assert time.monotonic() - start < 2.0


def test_a_goal_finished_inside_on_goal_reaches_the_client(buses, names):
    server_bus, client_bus = buses("inactive_gripper"), buses("runtime")

    def on_goal(handle) -> bool:  # an inactive controller accepts, then aborts at once
        handle.abort(GripperCommand.Result(position=0.03))
        return True

    server_bus.create_action_server(names("gripper_cmd"), GripperCommand, on_goal)
    client = client_bus.create_action_client(names("gripper_cmd"), GripperCommand)
    wait_for(client.server_is_ready, what="the action server")
    sent = client.send_goal_async(GripperCommand.Goal(command=Command(position=0.0, max_effort=10.0)))
    wait_for(sent.done, client_bus, what="the goal response")
    assert sent.result().accepted is True
    result = sent.result().get_result_async()
    wait_for(result.done, client_bus, what="the result")
    assert result.result().status == STATUS_ABORTED and result.result().result.position == 0.03


def test_the_action_type_served_under_a_name_is_read_from_the_graph(buses, names):
    from control_msgs.action import FollowJointTrajectory

    server, client = buses("type_server"), buses("type_reader")
    jtc, gripper = names("jtc/follow_joint_trajectory"), names("gripper_cmd")
    server.create_action_server(jtc, FollowJointTrajectory, lambda handle: False)
    server.create_action_server(gripper, GripperCommand, lambda handle: False)
    wait_for(lambda: client.action_types(jtc) != [] and client.action_types(gripper) != [], client, what="both actions on the graph")
    assert client.action_types(jtc) == ["control_msgs/action/FollowJointTrajectory"]
    assert client.action_types(gripper) == ["control_msgs/action/GripperCommand"]
    assert client.action_types(names("nobody")) == []


@pytest.mark.parametrize("reliable", [True, False])
def test_the_wrench_watch_hears_reliable_and_best_effort_publishers_over_ros(buses, names, reliable):
    from geometry_msgs.msg import WrenchStamped

    from behaviors.wrench_watch import WrenchWatch

    sensor, runtime_bus = buses("ft_sensor"), buses("ft_watcher")
    topic = names("force_torque_sensor_broadcaster/wrench")
    publisher = sensor.create_publisher(topic, WrenchStamped, reliable=reliable)
    watch = WrenchWatch(runtime_bus, topic, (45.0, 45.0, 45.0, 10.0, 10.0, 10.0))
    calm, push = WrenchStamped(), WrenchStamped()
    push.wrench.force.z = -61.2

    def published_and_heard(msg: WrenchStamped) -> Callable[[], bool]:
        def check() -> bool:
            publisher.publish(msg)
            return watch.has_reading
        return check

    wait_for(published_and_heard(calm), runtime_bus, what="a reading through the QoS match")
    assert watch.crossing() is None
    publisher.publish(push)
    wait_for(lambda: watch.crossing() is not None, runtime_bus, what="the push")
    assert watch.crossing() == "Fz = -61.20 N exceeds the absolute threshold 45.00 N"


def test_the_cell_s_jtc_and_broadcaster_serve_over_ros(buses, names):
    """The simulated joint_trajectory_controller and force_torque_sensor_broadcaster on a RosBus
    node (as a process hosting the cell serves them): a goal from another node plays and succeeds,
    the wrench is published, and the controller manager lists both."""
    import numpy as np
    from control_msgs.action import FollowJointTrajectory
    from controller_manager_msgs.srv import ListControllers
    from geometry_msgs.msg import WrenchStamped
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from runtime.io.timestamps import duration_msg
    from sim.controllers import JTC_ACTION, JTC_CONTROLLER, LIST_SERVICE, VELOCITY_CONTROLLER, WRENCH_TOPIC, make_controllers
    from tests.test_controllers import ARM, HOME, FakeHardware

    cell_bus, client_bus = buses("cell"), buses("runtime")
    clock = cell_bus.clock
    hardware = FakeHardware(clock)
    manager = make_controllers(cell_bus, hardware, clock)
    manager.switch([JTC_CONTROLLER], [VELOCITY_CONTROLLER])
    hardware.external_wrench = np.array([0.0, 0.0, -3.0, 0.0, 0.0, 0.0])
    client = client_bus.create_action_client(JTC_ACTION, FollowJointTrajectory)
    wrench = client_bus.create_subscription(WRENCH_TOPIC, WrenchStamped, reliable=False)
    lister = client_bus.create_client(LIST_SERVICE, ListControllers)
    wait_for(lambda: client.server_is_ready() and lister.service_is_ready(), client_bus, what="the cell's endpoints")
    target = HOME + 0.05
    goal = FollowJointTrajectory.Goal(trajectory=JointTrajectory(joint_names=list(ARM), points=[
        JointTrajectoryPoint(positions=target.tolist(), velocities=[0.0] * 6, time_from_start=duration_msg(0.2))]))
    sent = client.send_goal_async(goal)

    def step() -> None:  # the cell's control loop, on the wall clock
        t = clock.now()
        manager.update(t, 0.002)
        hardware.step(0.002)

    def stepping(condition: Callable[[], bool]) -> Callable[[], bool]:
        def check() -> bool:
            step()
            cell_bus.spin_once()
            return condition()
        return check

    wait_for(stepping(sent.done), client_bus, what="the goal accepted")
    result = sent.result().get_result_async()
    wait_for(stepping(result.done), client_bus, what="the goal's result")
    assert result.result().result.error_string == "Goal successfully reached!"
    np.testing.assert_allclose(hardware.q, target, atol=1e-6)
    wait_for(stepping(lambda: wrench.latest is not None), client_bus, what="a wrench reading")
    assert wrench.latest.wrench.force.z == -3.0
    listed = lister.call_async(ListControllers.Request())
    wait_for(stepping(listed.done), client_bus, what="list_controllers")
    states = {c.name: c.state for c in listed.result().controller}
    assert states["joint_trajectory_controller"] == "active" and states["force_torque_sensor_broadcaster"] == "active"
def test_a_node_that_serves_nothing_spins_the_events_executor_and_refuses_servers(buses, names):
    client_bus, server_bus = buses("runtime", serves=False), buses("policy")
    assert type(client_bus._executor).__name__ == "EventsExecutor"
    server_bus.create_service(names("get_action_chunk"), GetActionChunk, lambda request: GetActionChunk.Response(status=1))
    client = client_bus.create_client(names("get_action_chunk"), GetActionChunk)
    wait_for(client.service_is_ready, what="the service")
    future = client.call_async(GetActionChunk.Request())
    wait_for(future.done, client_bus, what="the answer")
    assert future.result().status == 1
    with pytest.raises(ValueError, match=r"service '.*': this node was made to serve nothing \(RosBus\(serves=False\)"):
        client_bus.create_service(names("other"), GetActionChunk, lambda request: request)
    with pytest.raises(ValueError, match=r"action server '.*': this node was made to serve nothing"):
        client_bus.create_action_server(names("gripper_cmd"), GripperCommand, lambda handle: True)
