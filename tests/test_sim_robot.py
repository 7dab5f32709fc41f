"""The cell as a robot on the graph: four processes, as on a real arm.

    objective sim-robot                       the simulated cell alone on ROS 2 (+ /clock)
    objective serve --backend oracle          HTTP inference server
    objective adapter --infer-url URL         /get_action_chunk -> POST /infer
    objective run FILE --ros --use-sim-time --world robot --world-option mjcf=...   the runtime

The runtime hosts no cell: it loads the robot's description (``objective sim-robot --describe``)
as its planning scene and drives the robot's controllers over ROS 2, its clock taken from the
robot's ``/clock``. The kinematic cell keeps the default run short on a shared machine.
"""
from __future__ import annotations

import json
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from runtime.app.cli import main
from sim.robot_node import describe
from tests.test_ros_e2e import ONE_CHUNK, env, policy, read_line, start, stop  # noqa: F401 (fixtures)

pytestmark = [pytest.mark.ros, pytest.mark.timeout(240)]

REPO = Path(__file__).resolve().parent.parent


@dataclass
class SimRobot:
    process: subprocess.Popen
    world_options: list[str]
    """``--world-option`` values of ``--world robot`` for this robot's description."""

    def finish(self) -> dict:
        """Stop the robot (SIGTERM) and return its JSON summary."""
        out, err = stop(self.process)
        assert self.process.returncode == 0, err
        return json.loads(out.strip().splitlines()[-1])


def start_robot(env: dict[str, str], description: Path, world: str = "kinematic", seed: int = 0) -> SimRobot:
    process = start("sim-robot", "--world", world, "--seed", str(seed), env=env)
    read_line(process, r"serving on ROS 2 as node /sim_robot", timeout=90)
    return SimRobot(process, describe(description))


@pytest.fixture(scope="module")
def robot(env, tmp_path_factory):  # noqa: F811
    running = start_robot(env, tmp_path_factory.mktemp("cell"))
    yield running
    if running.process.poll() is None:
        stop(running.process)


def run_on_robot(path: Path | str, env: dict[str, str], robot: SimRobot, timeout: float) -> dict:  # noqa: F811
    options = [arg for option in robot.world_options for arg in ("--world-option", option)]
    runner = start("run", str(path), "--ros", "--use-sim-time", "--world", "robot", *options, "--json", env=env)
    try:
        out, err = runner.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        _, err = stop(runner)
        raise AssertionError(f"{path} did not finish within {timeout} s; stderr:\n{err}")
    assert runner.returncode == 0, err
    return json.loads(out.strip().splitlines()[-1])


def test_one_chunk_drives_the_simulated_robot_from_another_process(env, policy, robot, tmp_path):  # noqa: F811
    path = tmp_path / "one_chunk.xml"
    path.write_text(ONE_CHUNK)
    summary = run_on_robot(path, env, robot, timeout=120)
    assert summary["status"] == "SUCCESS", summary["reason"]
    assert summary["world"]["robot"].endswith("robot.xml")  # the runtime hosted no cell
    result = summary["execute_policy"]
    assert result["steps_executed"] == 10 and result["chunks"] == 1 and result["rejections"] == 0
    # The run's clock started at the robot's /clock, which had been running since the robot started.
    assert summary["sim_seconds"] > summary["wall_seconds"]


@pytest.mark.slow
@pytest.mark.parametrize("objective, world", [("objectives/stack_cubes.xml", "kinematic"),
                                              ("objectives/stack_cubes_jtc.xml", "kinematic"),
                                              ("objectives/stack_cubes_jtc.xml", "vla_sim")])
def test_four_processes_stack_the_cubes(env, policy, tmp_path, objective, world):  # noqa: F811
    """On the admittance controller, and through the robot's stock joint_trajectory_controller
    (with its force_torque_sensor_broadcaster watched by ExecutePolicy), the MuJoCo cell too."""
    robot = start_robot(env, tmp_path / "cell", world=world)
    try:
        # The robot world's scene holds the robot alone: the check reads cube poses it does not
        # hold, and the collision rules name cubes it does not have.
        stack = tmp_path / "stack.xml"
        stack.write_text("\n".join(line for line in (REPO / objective).read_text().splitlines()
                                   if 'SubTree ID="Check if One Cube Is on Another"' not in line
                                   and "<SetCollisionRule " not in line))
        summary = run_on_robot(stack, env, robot, timeout=180)
    finally:
        robot_summary = robot.finish()
    assert summary["status"] == "SUCCESS", summary["reason"]
    assert summary["execute_policy"]["steps_executed"] == 300
    blue, green = robot_summary["world"]["cubes"]["blue"], robot_summary["world"]["cubes"]["green"]
    assert abs(blue[0] - green[0]) < 0.015 and abs(blue[1] - green[1]) < 0.015
    assert abs(blue[2] - green[2] - 0.03) < 0.01


def test_use_sim_time_needs_ros(capsys):
    code = main(["run", "objectives/cell/open_gripper.xml", "--use-sim-time", "--world", "kinematic"])
    assert code == 2
    assert "--use-sim-time follows the ROS graph's /clock: it needs --ros" in capsys.readouterr().err


def test_use_sim_time_without_a_clock_on_the_graph_names_what_to_start():
    from runtime.io.clock import WallClock
    from runtime.errors import ObjectiveError
    from runtime.io.ros import RosBus
    from runtime.io.ros.run import follow_graph_clock

    clock = WallClock()
    with RosBus(clock, node_name="no_clock_here") as bus:
        with pytest.raises(ObjectiveError, match=r"nothing published /clock within 0.3 s \(start the simulated robot first"):
            follow_graph_clock(bus, clock, timeout_s=0.3)


def test_use_sim_time_moves_forward_to_a_fresher_clock_reading_never_back():
    # The first reading is old (the robot's process was starved when it published): a fresher
    # one moves the run's clock forward to it; an older one after that leaves it where it is.
    from rosgraph_msgs.msg import Clock

    from runtime.io.clock import WallClock
    from runtime.io.ros import RosBus
    from runtime.io.ros.run import CLOCK_TOPIC, follow_graph_clock
    from runtime.io.timestamps import time_msg

    def publish_until(publisher, stamp_s: float, done) -> None:
        deadline = time.monotonic() + 5.0
        while not done() and time.monotonic() < deadline:
            publisher.publish(Clock(clock=time_msg(stamp_s)))
            time.sleep(0.01)

    clock = WallClock()
    with RosBus(WallClock(), node_name="robot_clock") as robot, RosBus(clock, node_name="follower") as follower:
        publisher = robot.create_publisher(CLOCK_TOPIC, Clock)
        first: list[float] = []
        source = threading.Thread(target=publish_until, args=(publisher, 100.0, lambda: bool(first)))
        source.start()
        first.append(follow_graph_clock(follower, clock))
        source.join()
        assert first == [100.0] and 100.0 <= clock.now() < 101.0

        def caught_up() -> bool:
            follower.spin_once()
            return clock.now() >= 1000.0
        publish_until(publisher, 1000.0, caught_up)
        assert 1000.0 <= clock.now() < 1001.0

        ahead_s = clock.now()
        stale_seen = follower.create_subscription(CLOCK_TOPIC, Clock, reliable=False)
        publish_until(publisher, 900.0, lambda: stale_seen.latest is not None and stale_seen.latest.clock.sec == 900)
        follower.spin_once()
        assert clock.now() >= ahead_s  # never back


def test_sim_robot_bad_world_options_are_bad_input(capsys):
    code = main(["sim-robot", "--world", "kinematic", "--world-option", "camera_rate_hz=-1"])
    assert code == 2
    assert "error: world 'kinematic': camera_rate_hz must be > 0, got -1.0" in capsys.readouterr().err


def test_sim_robot_describe_writes_what_the_robot_world_loads(tmp_path, capsys):
    assert main(["sim-robot", "--describe", str(tmp_path)]) == 0
    options = capsys.readouterr().out.split()
    assert options[0] == "--world-option" and f"mjcf={tmp_path / 'robot.xml'}" in options
    from runtime.app.robot_world import create

    world = create(dict(option.split("=", 1) for option in options if option != "--world-option"))
    assert world.limits is not None and world.gripper_joint == "robotiq_85_left_knuckle_joint"
    assert set(world.waypoints) == {"Home", "Observe", "Ready"}
    assert world.envelope is not None and world.envelope.max_tcp_speed_m_s == 1.0  # the cell's Cartesian envelope
