"""The Objective server over real ROS 2: run by name with overrides, feedback, cancel, one at a time.

Each test starts an ``ObjectiveServer`` in this process (its node has an rclpy context of its
own) and talks to it from a client node of the test's own, as another process would.
"""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.timeout(120)]

import rclpy  # noqa: E402
from action_msgs.msg import GoalStatus, GoalStatusArray  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from objective_server_msgs.action import DoObjective  # noqa: E402
from objective_server_msgs.msg import KeyValue, PortOverride  # noqa: E402
from objective_server_msgs.srv import ExecuteObjective, ListObjectives  # noqa: E402
from runtime.tree.registry import Registry  # noqa: E402
from runtime.app.server.objective_server import ObjectiveServer, ServerOptions  # noqa: E402
from runtime.app.runner import RunOptions  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
CONTROLLER_STATUS = "/joint_trajectory_admittance_controller/follow_joint_trajectory/_action/status"
ARM = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]

WAIT = """<root BTCPP_format="4" main_tree_to_execute="Wait and Greet">
  <BehaviorTree ID="Wait and Greet" _description="Waits, then copies the greeting">
    <Sequence>
      <Wait name="wait" seconds="{seconds}"/>
      <Script code="said := greeting"/>
    </Sequence>
  </BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Wait and Greet">
      <input_port name="greeting" type="std::string" default="hello"/>
      <input_port name="seconds" type="double" default="0.2"/>
    </SubTree>
  </TreeNodesModel>
</root>"""

LONG = """<root BTCPP_format="4">
  <BehaviorTree ID="Long Wait"><Wait seconds="30"/></BehaviorTree>
</root>"""


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_entry_points()


@pytest.fixture
def ros_env(monkeypatch) -> None:
    monkeypatch.setenv("ROS_DOMAIN_ID", str(random.randint(100, 199)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


@pytest.fixture
def library(tmp_path) -> Path:
    (tmp_path / "wait.xml").write_text(WAIT)
    (tmp_path / "more").mkdir()
    (tmp_path / "more" / "long.xml").write_text(LONG)
    (tmp_path / "broken.xml").write_text("<root BTCPP_format='4'><BehaviorTree ID='X'>")
    return tmp_path


@pytest.fixture
def serve(ros_env, registry):
    servers: list[ObjectiveServer] = []

    def start(library: Path, **run: Any) -> ObjectiveServer:
        server = ObjectiveServer(ServerOptions(library, RunOptions(**run)), registry)
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.close()


class Client:
    """A node of the test's own with the server's action and services, spun on a thread."""

    def __init__(self, name: str = "client") -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.action = ActionClient(self.node, DoObjective, "/do_objective")
        self.list = self.node.create_client(ListObjectives, "/list_objectives")
        self.cancel_all = self.node.create_client(Trigger, "/cancel_objective")
        self.feedback: list[Any] = []
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()
        assert self.action.wait_for_server(timeout_sec=10.0), "no /do_objective server"

    def send(self, name: str, ports: list[tuple[str, str, str]] = (), board: dict[str, str] | None = None) -> Any:
        goal = DoObjective.Goal(objective_name=name)
        goal.port_overrides = [PortOverride(node=n, port=p, value=v) for n, p, v in ports]
        goal.blackboard_overrides = [KeyValue(key=k, value=v) for k, v in (board or {}).items()]
        future = self.action.send_goal_async(goal, feedback_callback=lambda m: self.feedback.append(m.feedback))
        return wait(future, what="the goal response")

    def result(self, handle: Any, timeout: float = 60.0) -> tuple[int, Any]:
        response = wait(handle.get_result_async(), timeout=timeout, what="the result")
        return response.status, response.result

    def run(self, name: str, **kwargs: Any) -> tuple[int, Any]:
        handle = self.send(name, **kwargs)
        assert handle.accepted
        return self.result(handle)

    def call(self, client: Any, request: Any) -> Any:
        assert client.wait_for_service(timeout_sec=10.0)
        return wait(client.call_async(request), what="the service")

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()
        self.thread.join(timeout=2.0)


def wait(future: Any, timeout: float = 20.0, what: str = "it") -> Any:
    deadline = time.monotonic() + timeout
    while not future.done():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)
    return future.result()


def wait_for(condition: Callable[[], Any], timeout: float = 30.0, what: str = "it") -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


@pytest.fixture
def client(ros_env):
    clients: list[Client] = []

    def make(name: str = "client") -> Client:
        clients.append(Client(name))
        return clients[-1]

    yield make
    for c in clients:
        c.close()


def test_an_objective_runs_by_name_with_feedback_and_overrides(serve, client, library):
    serve(library)
    c = client()
    status, result = c.run("Wait and Greet", ports=[("", "seconds", "0.5")], board={"greeting": "bonjour"})
    assert status == GoalStatus.STATUS_SUCCEEDED
    assert (result.status, result.reason) == ("SUCCESS", "")
    summary = json.loads(result.summary_json)
    assert summary["blackboard"] == {"greeting": "bonjour", "seconds": "0.5", "said": "bonjour"}
    assert summary["sim_seconds"] == pytest.approx(0.51)  # the port override: 0.5 s, not 0.2 s
    first = c.feedback[0]
    assert list(first.running_nodes) == ["wait (Wait)"] and first.ticks == 1 and first.clock_s == pytest.approx(0.01)


def test_the_list_gives_every_objective_with_its_description_ports_and_errors(serve, client, library):
    serve(library)
    response = client().call(client().list, ListObjectives.Request())
    by_file = {o.file: o for o in response.objectives}
    assert sorted(by_file) == ["broken.xml", "more/long.xml", "wait.xml"]
    wait_and_greet = by_file["wait.xml"]
    assert (wait_and_greet.name, wait_and_greet.description) == ("Wait and Greet", "Waits, then copies the greeting")
    assert [(p.name, p.direction, p.type, p.default_value) for p in wait_and_greet.ports] == [
        ("greeting", "input_port", "std::string", "hello"), ("seconds", "input_port", "double", "0.2")]
    assert by_file["more/long.xml"].name == "Long Wait" and by_file["more/long.xml"].error == ""
    assert "broken.xml" in by_file["broken.xml"].error
    assert response.running == ""


DECLARED = "its ports: greeting, seconds"


@pytest.mark.parametrize("name, ports, board, reason", [
    ("Nope", [], {}, "no Objective named 'Nope' in {lib} (Objectives: Long Wait, Wait and Greet)"),
    ("broken", [], {}, "Objective 'broken' cannot run: "),
    ("Wait and Greet", [("", "greting", "x")], {},
     f"port override greting='x': 'greting' is not a port Objective 'Wait and Greet' declares; did you mean "
     f"'greeting'? ({DECLARED}); overrides reach only the Objective's own ports"),
    ("Wait and Greet", [("", "secs", "1")], {},
     f"port override secs='1': 'secs' is not a port Objective 'Wait and Greet' declares; did you mean 'seconds'? ({DECLARED}); "
     "overrides reach only the Objective's own ports"),
    # a port of a node inside the Objective is out of reach: a client cannot rewrite a Script
    # or widen a collision rule
    ("Wait and Greet", [("wait", "seconds", "1")], {},
     "port override wait.seconds='1': 'wait' is not Objective 'Wait and Greet'; overrides reach only the "
     f"Objective's own ports, never a node's inside it ({DECLARED})"),
    ("Wait and Greet", [("Script", "code", "said := 'pwned'")], {},
     "port override Script.code=\"said := 'pwned'\": 'Script' is not Objective 'Wait and Greet'; "),
    ("Wait and Greet", [], {"said": "x"},
     f"blackboard override said='x': 'said' is not a port Objective 'Wait and Greet' declares ({DECLARED}); "),
    ("Long Wait", [("Long Wait", "seconds", "0")], {},
     "port override Long Wait.seconds='0': 'seconds' is not a port Objective 'Long Wait' declares "
     "(it declares none); "),
])
def test_a_bad_request_ends_as_error_saying_what_is_wrong(serve, client, library, name, ports, board, reason):
    serve(library)
    status, result = client().run(name, ports=ports, board=board)
    assert status == GoalStatus.STATUS_ABORTED
    assert result.status == "ERROR"
    assert result.reason.startswith(reason.format(lib=library)), result.reason
    assert json.loads(result.summary_json) == {"status": "ERROR", "reason": result.reason}


def test_one_objective_at_a_time_a_second_client_is_rejected_and_cancel_halts(serve, client, library):
    serve(library, realtime=True)
    first, second = client("first"), client("second")
    handle = first.send("Long Wait")
    assert handle.accepted
    wait_for(lambda: first.feedback, what="feedback of the long wait")
    assert not second.send("Wait and Greet").accepted
    assert first.call(first.list, ListObjectives.Request()).running == "Long Wait"
    wait(handle.cancel_goal_async(), what="the cancel response")
    status, result = first.result(handle)
    assert status == GoalStatus.STATUS_CANCELED
    assert result.status == "INTERRUPTED"
    assert result.reason.startswith("cancelled by a client of /do_objective at ")
    assert "halted 'Wait'" in result.reason
    summary = json.loads(result.summary_json)
    assert summary["running_nodes"] == ["Wait"]
    assert summary["stopped_by"] == "cancelled by a client of /do_objective" and "signal" not in summary
    # the server is free again: the second client's goal runs
    status, result = second.run("Wait and Greet")
    assert (status, result.status) == (GoalStatus.STATUS_SUCCEEDED, "SUCCESS")
    assert json.loads(result.summary_json)["blackboard"]["said"] == "hello"  # the Objective's port default
    # /cancel_objective with nothing running says so
    answer = second.call(second.cancel_all, Trigger.Request())
    assert (answer.success, answer.message) == (False, "no Objective is running")


def test_two_goals_sent_at_once_one_runs(serve, client, library):
    serve(library, realtime=True)
    a, b = client("a"), client("b")
    futures = [c.action.send_goal_async(DoObjective.Goal(objective_name="Long Wait")) for c in (a, b)]
    handles = [wait(f, what="the goal responses") for f in futures]
    assert sorted(h.accepted for h in handles) == [False, True]
    accepted = next(h for h in handles if h.accepted)
    wait(accepted.cancel_goal_async(), what="the cancel response")
    assert wait(accepted.get_result_async(), what="the result").status == GoalStatus.STATUS_CANCELED


def test_cancel_objective_service_halts_the_running_objective(serve, client, library):
    serve(library, realtime=True)
    c = client()
    handle = c.send("Long Wait")
    wait_for(lambda: c.feedback, what="feedback")
    answer = c.call(c.cancel_all, Trigger.Request())
    assert (answer.success, answer.message) == (True, "cancelled")
    status, result = c.result(handle)
    assert status == GoalStatus.STATUS_ABORTED  # cancelled by the server, not by this goal's client
    assert result.status == "INTERRUPTED" and result.reason.startswith("cancelled through /cancel_objective at ")


def test_cancel_mid_policy_stops_the_arm(serve, client):
    """Stack Cubes on the kinematic cell over ROS 2; cancelled while ExecutePolicy moves the arm:
    the run is halted, the controller's goal ends CANCELED and the arm comes to rest."""
    serve(REPO / "objectives", ros=True, realtime=True, world="kinematic", world_options={"policy": "oracle"})
    c = client()
    states: list[JointState] = []
    c.node.create_subscription(JointState, "/joint_states", states.append, 10)
    controller: list[GoalStatusArray] = []
    c.node.create_subscription(GoalStatusArray, CONTROLLER_STATUS, controller.append, 10)
    handle = c.send("Stack Cubes")
    assert handle.accepted

    def arm_speed(state: JointState) -> float:
        return max(abs(state.velocity[state.name.index(j)]) for j in ARM)

    def streaming() -> bool:
        fb = c.feedback[-1] if c.feedback else None
        return bool(fb and "ExecutePolicy (ExecutePolicy)" in fb.running_nodes
                    and "execute_policy" in json.loads(fb.progress_json) and states and arm_speed(states[-1]) > 1e-3)

    wait_for(streaming, timeout=60.0, what="ExecutePolicy to move the arm")
    seen = len(controller)
    wait(handle.cancel_goal_async(), what="the cancel response")
    status, result = c.result(handle)
    assert status == GoalStatus.STATUS_CANCELED and result.status == "INTERRUPTED"
    assert "halted 'ExecutePolicy'" in result.reason, result.reason
    assert json.loads(result.summary_json)["running_nodes"] == ["ExecutePolicy"]
    # the controller's trajectory goal, moving the arm when the cancel came, ended on the graph: no
    # goal of the controller is left active (CANCELED when the cancel reached it while it played,
    # SUCCEEDED when it had just played out), and none had been cancelled before
    active = (GoalStatus.STATUS_ACCEPTED, GoalStatus.STATUS_EXECUTING, GoalStatus.STATUS_CANCELING)
    wait_for(lambda: len(controller) > seen and all(s.status not in active for s in controller[-1].status_list),
             timeout=10.0, what="the controller's goals to end")
    assert not any(s.status == GoalStatus.STATUS_CANCELED for m in controller[:seen] for s in m.status_list)
    assert arm_speed(states[-1]) < 1e-6, list(states[-1].velocity)  # the last state the cell published: at rest


def test_groot2_on_the_server_shows_each_run(ros_env, registry, client, library):
    from runtime.app.groot2 import Groot2Options, Groot2Server
    from tests.test_groot2 import Client as GrootClient, header

    with Groot2Server(Groot2Options(port=0)) as groot2:
        server = ObjectiveServer(ServerOptions(library, RunOptions(), groot2=groot2), registry)
        groot = GrootClient(groot2.port)
        try:
            assert groot.ask(header("T")) == [b"error", b"no tree is running yet"]
            status, _ = client().run("Wait and Greet")
            assert status == GoalStatus.STATUS_SUCCEEDED
            tree = groot.ask(header("T"))[1].decode()
            assert '<BehaviorTree ID="Wait and Greet" _fullpath="">' in tree and '<Wait name="wait" _uid="2"' in tree
            statuses = groot.ask(header("S"))[1]
            assert statuses == bytes.fromhex("01000c" "02000c" "03000c")  # all idle after SUCCESS
        finally:
            groot.close()
            server.close()


def test_execute_objective_starts_one_and_answers_at_once(serve, client, library):
    serve(library, realtime=True)
    c = client()
    execute = c.node.create_client(ExecuteObjective, "/execute_objective")
    answer = c.call(execute, ExecuteObjective.Request(objective_name="Nope"))
    assert not answer.success and answer.message.startswith("no Objective named 'Nope'")
    answer = c.call(execute, ExecuteObjective.Request(objective_name="Long Wait"))
    assert (answer.success, answer.message) == (True, "started 'Long Wait'")
    assert c.call(c.list, ListObjectives.Request()).running == "Long Wait"
    answer = c.call(execute, ExecuteObjective.Request(objective_name="Wait and Greet"))
    assert (answer.success, answer.message) == (False, "'Long Wait' is running: cancel it first")
    assert not c.send("Wait and Greet").accepted
    assert c.call(c.cancel_all, Trigger.Request()).success
    wait_for(lambda: c.call(c.list, ListObjectives.Request()).running == "", what="the run to end")


def test_the_command_serves_until_sigterm(ros_env, library):
    env = {k: v for k, v in os.environ.items() if k != "ROS_AUTOMATIC_DISCOVERY_RANGE"}  # localhost all the same
    proc = subprocess.Popen([sys.executable, "-m", "runtime.app.cli", "server", str(library)], cwd=REPO, env=env,
                            stderr=subprocess.PIPE, text=True)
    c = None
    try:
        c = Client()
        status, result = c.run("Wait and Greet")
        assert (status, result.status) == (GoalStatus.STATUS_SUCCEEDED, "SUCCESS")
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
    finally:
        if c is not None:
            c.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert f"serving 3 Objectives of {library} on ROS 2 as node /objective_server" in err
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)" in err
    assert "Traceback" not in err


def test_the_server_keeps_discovery_on_this_machine(serve, monkeypatch, library):
    """Unless the environment or ``--discovery-range`` opens it, the server's node is discoverable
    from this machine only."""
    monkeypatch.delenv("ROS_AUTOMATIC_DISCOVERY_RANGE")
    serve(library)
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"


def test_a_goal_running_when_the_server_is_stopped_gets_its_result(ros_env, library):
    """SIGTERM to `objective server` mid-goal: the run is halted, the goal ends ABORTED with the
    reason, its client receives the result, and the server exits 0 without a stray exception."""
    proc = subprocess.Popen([sys.executable, "-m", "runtime.app.cli", "server", str(library), "--realtime"], cwd=REPO,
                            env=dict(os.environ), stderr=subprocess.PIPE, text=True)
    c = None
    try:
        c = Client()
        handle = c.send("Long Wait")
        assert handle.accepted
        wait_for(lambda: c.feedback, what="feedback of the long wait")
        result_future = handle.get_result_async()
        proc.send_signal(signal.SIGTERM)
        response = wait(result_future, timeout=20.0, what="the result of the goal the server was stopped in")
        _, err = proc.communicate(timeout=20)
    finally:
        if c is not None:
            c.close()
        if proc.poll() is None:
            proc.kill()
    assert response.status == GoalStatus.STATUS_ABORTED
    assert response.result.status == "INTERRUPTED"
    assert response.result.reason.startswith("the Objective server is shutting down at "), response.result.reason
    assert "halted 'Wait'" in response.result.reason
    assert proc.returncode == 0, err
    assert "exception" not in err.lower() and "Traceback" not in err, err


def test_the_middleware_here_has_no_dds_security(ros_env, tmp_path):
    """What docs/operating.md says of SROS2 with the PyPI wheels: a node asked to enforce DDS
    security is refused, the Fast DDS library having no security plugins."""
    enclave = tmp_path / "keystore" / "enclaves" / "objective_server"
    enclave.mkdir(parents=True)
    for name in ("identity_ca.cert.pem", "cert.pem", "key.pem", "permissions_ca.cert.pem", "governance.p7s",
                 "permissions.p7s"):
        (enclave / name).write_text("placeholder")
    env = {**os.environ, "ROS_SECURITY_ENABLE": "true", "ROS_SECURITY_STRATEGY": "Enforce",
           "ROS_SECURITY_KEYSTORE": str(tmp_path / "keystore")}
    code = ("import rclpy\n"
            "c = rclpy.Context()\n"
            "rclpy.init(context=c, args=['--ros-args', '--enclave', '/objective_server'])\n"
            "rclpy.create_node('probe', context=c)\n")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode != 0
    assert "This Fast DDS version doesn't have the security libraries" in done.stderr, done.stderr


HOME = """<root BTCPP_format="4" main_tree_to_execute="My Home">
  <BehaviorTree ID="My Home"><SubTree ID="Move to Waypoint" waypoint_name="Home"/></BehaviorTree>
</root>"""


def test_an_objective_finds_the_shipped_subtree_library_as_run_does(serve, client, tmp_path):
    """It ended ERROR "undefined SubTree 'Move to Waypoint' (searched DIR/my_home.xml, then DIR/*.xml)"."""
    (tmp_path / "my_home.xml").write_text(HOME)
    serve(tmp_path, world="kinematic")
    c = client()
    assert [o.error for o in c.call(c.list, ListObjectives.Request()).objectives] == [""]
    status, result = c.run("My Home")
    assert (status, result.status, result.reason) == (GoalStatus.STATUS_SUCCEEDED, "SUCCESS", "")


def test_the_list_gives_a_file_s_load_error(serve, client, tmp_path):
    """A missing required port was listed with an empty error; the run then ended ERROR."""
    (tmp_path / "gripper.xml").write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Grip"><MoveGripperAction/></BehaviorTree></root>')
    serve(tmp_path)
    c = client()
    (listed,) = c.call(c.list, ListObjectives.Request()).objectives
    assert (listed.name, listed.error) == ("Grip", f"{tmp_path}/gripper.xml:1: MoveGripperAction: missing required port 'position'")


# -- objective client: the server driven from the project's own CLI -----------------------------------
def client_cli(capsys, *argv: str) -> tuple[int, str, str]:
    from runtime.app.cli import main

    code = main(["client", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_the_client_lists_starts_with_overrides_and_cancels(serve, library, capsys):
    serve(library)
    code, out, _ = client_cli(capsys, "list")
    assert code == 0
    lines = out.splitlines()
    assert lines[0].startswith("broken  (broken.xml)") and lines[1].startswith("    error: ")
    assert lines[2:] == ["Long Wait  (more/long.xml)",
                         "Wait and Greet  (wait.xml): Waits, then copies the greeting",
                         "    input_port greeting (std::string) = hello",
                         "    input_port seconds (double) = 0.2",
                         "running: nothing"]
    code, out, err = client_cli(capsys, "start", "Wait and Greet", "--override", "seconds=0.5",
                                "--set", "greeting=bonjour", "--json")
    assert code == 0, err
    client_lines = [line for line in err.splitlines() if not line.startswith("[INFO]")]  # the server's log: same process
    assert client_lines == ["    0.01 s  running: wait (Wait)", "SUCCESS after 0.51 s (51 ticks)"]
    summary = json.loads(out.splitlines()[-1])
    assert summary["blackboard"] == {"greeting": "bonjour", "seconds": "0.5", "said": "bonjour"}
    code, _, err = client_cli(capsys, "start", "Wait and Greet", "--override", "wait.seconds=1")
    assert code == 2
    assert err.strip().endswith("'wait' is not Objective 'Wait and Greet'; overrides reach only the Objective's own "
                                "ports, never a node's inside it (its ports: greeting, seconds)")
    code, _, err = client_cli(capsys, "cancel")
    assert (code, err.splitlines()[-1]) == (1, "no Objective is running")


def test_a_client_s_sigint_cancels_its_goal_and_exits_130(serve, library):
    serve(library, realtime=True)
    proc = subprocess.Popen([sys.executable, "-m", "runtime.app.cli", "client", "start", "Long Wait"], cwd=REPO,
                            env=dict(os.environ), stderr=subprocess.PIPE, text=True)
    c = Client()
    try:
        wait_for(lambda: c.call(c.list, ListObjectives.Request()).running == "Long Wait", what="the run to start")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        c.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert err.splitlines()[-1].startswith("INTERRUPTED after ")
    assert "cancelled by a client of /do_objective" in err and "Traceback" not in err


def test_a_client_without_a_server_says_how_to_start_one(ros_env, capsys):
    code, _, err = client_cli(capsys, "--wait", "0.5", "list")
    assert code == 2
    assert err == ("error: no Objective server answered on /list_objectives within 0.5 s (start one with "
                   f"`objective server DIR`, on the same ROS_DOMAIN_ID: {os.environ['ROS_DOMAIN_ID']} here)\n")

