"""The policy connected the way a user connects theirs: three processes on a real ROS 2 graph.

    objective serve --backend oracle          HTTP inference server (bearer key from the env)
    objective adapter --infer-url URL         rclpy node serving /get_action_chunk -> POST /infer
    objective run stack_cubes.xml --ros       the runtime + the simulated cell, on ROS 2

The runner serves no policy of its own: every chunk comes through the adapter and the server,
and the oracle (in the server's process) reads the cube poses the cell publishes on ROS 2.
Everything stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) in a ROS domain of the
module's own. The server and the adapter start once for the module.

The full stacking run is real time: about 33 s of robot time, 35-45 s
of wall time. A late tick on a loaded machine makes the robot pause at a chunk boundary rather
than fail (ExecutePolicy waits for the motion to end, and re-plans a goal that reached the
controller after its seam), so it is part of the default run.
"""
from __future__ import annotations

import json
import os
import random
import re
import secrets
import selectors
import signal
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.timeout(180)]

REPO = Path(__file__).resolve().parent.parent
OBJECTIVE = [sys.executable, "-m", "runtime.app.cli"]
WORLD = "kinematic"
"""The MuJoCo cell (``vla_sim``) renders three cameras at 30 Hz on top of physics; on a shared
2-core machine that does not keep real time, so the pipeline test runs on the kinematic cell,
which serves the same controllers, cameras, joint states and cube poses."""


@pytest.fixture(scope="module")
def env() -> dict[str, str]:
    env = dict(os.environ)
    env.update(
        ROS_DOMAIN_ID=str(random.randint(100, 199)),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        POLICY_SERVER_KEY=secrets.token_urlsafe(24),
        PYTHONUNBUFFERED="1",
    )
    return env


def start(*args: str, env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen([*OBJECTIVE, *args], cwd=REPO, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def stop(proc: subprocess.Popen, grace: float = 10.0) -> tuple[str, str]:
    """SIGTERM, wait up to ``grace`` s, then SIGKILL; returns what is left of stdout and stderr."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        return proc.communicate(timeout=grace)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.communicate()


def read_line(proc: subprocess.Popen, pattern: str, timeout: float) -> re.Match:
    """The first stdout line of ``proc`` matching ``pattern``, within ``timeout`` seconds."""
    selector = selectors.DefaultSelector()
    selector.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout
    seen = []
    try:
        while time.monotonic() < deadline:
            if not selector.select(timeout=max(0.0, deadline - time.monotonic())):
                continue
            line = proc.stdout.readline()
            if not line:
                break  # the process exited
            seen.append(line)
            match = re.search(pattern, line)
            if match:
                return match
    finally:
        selector.close()
    _, err = stop(proc)
    raise AssertionError(f"no line matching {pattern!r} within {timeout} s; stdout: {''.join(seen)!r}\nstderr:\n{err}")


def wait_ready(health_url: str, timeout: float) -> dict:
    deadline = time.monotonic() + timeout
    health: dict = {}
    while time.monotonic() < deadline:
        with urllib.request.urlopen(health_url, timeout=2.0) as reply:
            health = json.load(reply)
        if health["status"] == "ready":
            return health
        assert health["status"] == "loading", health
        time.sleep(0.2)
    raise AssertionError(f"the server was not ready within {timeout} s: {health}")


@dataclass
class Policy:
    """The server and the adapter, running; ``stop()`` stops both and returns their logs (stderr)."""

    server: subprocess.Popen
    adapter: subprocess.Popen
    url: str

    def stop(self) -> tuple[str, str]:
        _, adapter_log = stop(self.adapter)
        _, server_log = stop(self.server)
        return adapter_log, server_log


@pytest.fixture(scope="module")
def policy(env):
    """``objective serve --backend oracle`` and ``objective adapter`` as separate processes, ready."""
    server = start("serve", "--backend", "oracle", "--port", "0", env=env)
    adapter = None
    try:
        url = read_line(server, r"listening on (http://127\.0\.0\.1:\d+)", timeout=60).group(1)
        assert wait_ready(f"{url}/health", timeout=60)["backend"] == "oracle"
        # The oracle may wait seconds for DDS to discover each new run's cube poses (see
        # sim.oracle_remote.CUBE_POSE_WAIT_S): the HTTP deadline and the call timeout cover it.
        adapter = start("adapter", "--infer-url", url, "--timeout", "8", env=env)
        read_line(adapter, r"serving /get_action_chunk -> ", timeout=30)
        running = Policy(server, adapter, url)
        yield running
    finally:
        for proc in (adapter, server):
            if proc is not None:
                stop(proc)


def run_objective(path: str, env: dict[str, str], timeout: float) -> dict:
    """``objective run PATH --ros --realtime --world WORLD --json`` as a process; its JSON summary."""
    runner = start("run", path, "--ros", "--realtime", "--world", WORLD, "--json", env=env)
    try:
        out, err = runner.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        _, err = stop(runner)
        raise AssertionError(f"{path} did not finish within {timeout} s; stderr:\n{err}")
    finally:
        if runner.poll() is None:
            stop(runner)
    assert runner.returncode == 0, err
    return json.loads(out.strip().splitlines()[-1])


ONE_CHUNK = """<root BTCPP_format="4" main_tree_to_execute="One Chunk">
  <BehaviorTree ID="One Chunk">
    <Sequence>
      <SwitchController activate_controllers="joint_trajectory_admittance_controller"
                        deactivate_controllers="velocity_force_controller"/>
      <ExecutePolicy policy_service_name="/get_action_chunk" joint_group_name="manipulator"
          prompt="stack the blue cube on the green cube" total_action_steps="10" dt="0.1"
          committed_action_steps="10" goal_path_tolerance="0.3" policy_uses_real_time_chunking="true"
          policy_call_timeout="10.0"
          image_topics="/scene_camera/color;/wrist_camera/color;/overview_camera/color" image_names="scene;wrist;overview"
          gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd"
          gripper_joint_name="robotiq_85_left_knuckle_joint"/>
    </Sequence>
  </BehaviorTree>
</root>
"""


def test_one_chunk_through_server_and_adapter(env, policy, tmp_path):
    """The wiring, fast: one chunk (no seam between chunks) from the oracle across three processes."""
    path = tmp_path / "one_chunk.xml"
    path.write_text(ONE_CHUNK)
    summary = run_objective(str(path), env, timeout=90)
    assert summary["status"] == "SUCCESS"
    result = summary["execute_policy"]
    assert result["steps_executed"] == 10 and result["chunks"] == 1 and result["message"] == "executed 10 steps"
    assert result["latency_p50_s"] > 0.0  # a ROS 2 + HTTP round trip, measured on the wall clock


def test_stack_cubes_over_ros_with_the_oracle_behind_server_and_adapter(env, policy):
    """The end-to-end run: objectives/stack_cubes.xml, about 33 s of real time."""
    wall_start = time.monotonic()
    summary = run_objective("objectives/stack_cubes.xml", env, timeout=150)
    assert summary["status"] == "SUCCESS"
    assert summary["stack_check"]["top"] == "cube_blue" and summary["stack_check"]["bottom"] == "cube_green"
    assert summary["stack_check"]["stacked"] is True, summary["stack_check"]["reason"]
    result = summary["execute_policy"]
    assert result["steps_executed"] == 300 and result["rejections"] == 0 and result["message"] == "executed 300 steps"
    assert 0.0 < result["latency_p50_s"] < 1.0
    assert summary["sim_seconds"] > 30.0 and summary["wall_seconds"] > 30.0  # real time: wall ~ robot time
    print(f"\nstack_cubes over ROS 2: run {summary['wall_seconds']} s wall ({time.monotonic() - wall_start:.1f} s "
          f"with start-up), latency p50 {result['latency_p50_s']} s max {result['latency_max_s']} s, "
          f"stall {result['stall_seconds']} s, pacing {summary['pacing']}")


def test_every_call_went_through_the_adapter_and_the_server(env, policy):
    """Last in the module: stop both processes and check their counts against the runs above."""
    adapter_log, server_log = policy.stop()
    served = re.search(r"stopped: served (\d+) chunks, answered (\d+) errors in (\d+) calls", adapter_log)
    assert served is not None, adapter_log
    chunks, errors, calls = map(int, served.groups())
    assert errors == 0 and chunks == calls and calls >= 2  # each run: a warmup plus one call per chunk
    assert len(re.findall(r"POST /infer 200 ", server_log)) == calls, server_log
