"""The protective stop and the deadman: in process on the simulated clock (the stop lands, the
tree is not ticked again, the controller goal is cancelled in the same tick, the run ends
FAILURE) and over ROS 2 (a `objective run --ros` process stopped by a message on its topic); and
`objective eval`'s, heard in its own process and forwarded to its workers' episodes."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from runtime.errors import ObjectiveError
from runtime.app.protective_stop import StopInputs
from runtime.app.runner import RunOptions
from tests.test_objective_server import client, library, registry, serve  # noqa: F401  (fixtures)
from tests.test_ros_run import observer, ros_env  # noqa: F401  (fixtures)
from tests.test_safety_properties import CONTROLLER, READY, RecordingWorld, run_chunks

SMOOTH = {"kind": "smooth", "steps": 40, "velocity": [0.2] * 6, "joint": 0, "at": 0.5, "size": 0.0,
          "bad": float("nan"), "names": "permuted", "width": 0, "seed": 0}


class CancelRecordingWorld(RecordingWorld):
    """The recording controller, noting when each cancel request reaches it (clock time), and a
    hook that runs at every world step (what an operator does at that instant)."""

    def __init__(self, initial: np.ndarray, at_step: Any = None) -> None:
        super().__init__(initial)
        self.cancels: list[float] = []
        self.at_step = at_step

    def start(self, context: Any) -> None:
        super().start(context)
        server = context.bus._action_servers[CONTROLLER]

        def on_cancel(goal: Any) -> bool:
            self.cancels.append(context.clock.now())
            return True

        server.on_cancel = on_cancel

    def step_to(self, t: float) -> None:
        super().step_to(t)
        if self.at_step is not None:
            self.at_step(self.context, t)


def run_policy(at_step: Any, stop: StopInputs | None = StopInputs()) -> tuple[Any, CancelRecordingWorld]:
    """ExecutePolicy streaming smooth chunks for 20 steps of 0.1 s against the recording controller."""
    world = CancelRecordingWorld(READY, at_step)
    return run_chunks([SMOOTH], READY, 0.1, 50, world=world, protective_stop=stop), world


def publish_at(t_s: float, topic: str, value: bool = True) -> Any:
    publishers: dict[str, Any] = {}

    def step(context: Any, t: float) -> None:
        if topic not in publishers:
            publishers[topic] = context.bus.create_publisher(topic, Bool)
        if abs(t - t_s) < 1e-9:
            publishers[topic].publish(Bool(data=value))

    return step


def test_a_stop_on_the_topic_halts_the_run_and_cancels_the_goal_in_the_same_tick():
    out, world = run_policy(publish_at(1.0, "/protective_stop"))
    assert out.status == "FAILURE"
    assert out.reason.startswith("protective stop: '/protective_stop' is true at 1.00 s; halted 'ExecutePolicy'")
    assert len(out.goals) >= 1 and world.cancels == [pytest.approx(1.0)]  # the tick that received it cancelled it
    assert world.active.is_cancel_requested


def test_without_a_stop_the_same_run_succeeds():
    out, world = run_policy(None)
    assert out.status == "SUCCESS", out.reason
    assert world.cancels == []


def test_the_trigger_service_stops_the_run():
    def call(context: Any, t: float) -> None:
        if abs(t - 0.5) < 1e-9:
            context.bus.create_client("/protective_stop", Trigger).call_async(Trigger.Request())

    out, world = run_policy(call)
    assert out.status == "FAILURE" and out.reason.startswith("protective stop: '/protective_stop' was called at 0.50 s")
    assert world.cancels == [pytest.approx(0.5)]


def test_the_deadman_stops_a_policy_whose_heartbeat_stops_and_keeps_one_that_keeps_coming():
    deadman = StopInputs(deadman_topic="/deadman", deadman_period_s=0.3)

    def heartbeat_until(last_s: float, then: bool | None = None) -> Any:
        """True at every step up to ``last_s``; ``then`` once at the next step (None: silence)."""
        publishers: dict[str, Any] = {}

        def step(context: Any, t: float) -> None:
            if "p" not in publishers:
                publishers["p"] = context.bus.create_publisher("/deadman", Bool)
            if t <= last_s + 1e-9:
                publishers["p"].publish(Bool(data=True))
            elif then is not None and t <= last_s + 0.01 + 1e-9:
                publishers["p"].publish(Bool(data=then))

        return step

    out, world = run_policy(heartbeat_until(100.0), deadman)
    assert out.status == "SUCCESS", out.reason
    out, world = run_policy(heartbeat_until(1.0), deadman)
    assert out.status == "FAILURE"
    assert out.reason.startswith("protective stop: no heartbeat on the deadman '/deadman' for 0.31 s (period 0.3 s) "
                                 "while a policy ran at 1.31 s; halted 'ExecutePolicy'")
    assert world.cancels == [pytest.approx(1.31)]
    out, world = run_policy(heartbeat_until(0.8, then=False), deadman)  # released: at once
    assert out.status == "FAILURE" and out.reason.startswith("protective stop: the deadman '/deadman' was released (false) at 0.81 s")


@pytest.mark.parametrize("objective", ["objectives/stack_cubes.xml", "objectives/stack_cubes_jtc.xml"])
def test_a_stop_brings_the_arm_to_rest_within_the_controllers_stop_time(objective):
    """The cell's own controllers, both kinds: stopped while the oracle's policy moves the arm,
    the run ends FAILURE at that instant and the controller that had the goal brings the arm to
    rest within its stop time (plus one control step)."""
    from runtime.io.bus import FixedLatency
    from runtime.tree.loader import load_tree
    from runtime.tree.registry import Registry
    from runtime.app.runner import make_context, run_tree
    from sim.controllers.base import ControllersConfig
    from sim.kinematic import KinematicWorld

    stop_s, control_step_s = 8.0, 0.01
    options = RunOptions(seed=0, max_seconds=60.0, world="kinematic")
    context = make_context(options)
    world = KinematicWorld({"seed": 0})
    loaded = load_tree(objective, Registry.from_entry_points(), context)
    context.bus.set_latency("/get_action_chunk", FixedLatency(0.1))  # the oracle's calls: the same run every time
    stop = context.bus.create_publisher("/protective_stop", Bool)
    step_to = world.step_to

    def step_and_stop(t: float) -> None:
        step_to(t)
        if abs(t - stop_s) < 1e-9:
            stop.publish(Bool(data=True))

    world.step_to = step_and_stop
    result = run_tree(loaded, context, options, world=world)
    assert (result.status, result.failure_kind) == ("FAILURE", "protective stop")
    assert result.reason.startswith(f"protective stop: '/protective_stop' is true at {stop_s:.2f} s; halted 'ExecutePolicy'")
    assert np.abs(world.cell.arm_velocity()).max() > 0.5  # moving (0.6 rad/s) when it was stopped
    rest_s = ControllersConfig().stop_time + control_step_s
    for k in range(1, round(rest_s / control_step_s) + 1):
        step_to(result.sim_seconds + k * control_step_s)
    assert np.abs(world.cell.arm_velocity()).max() == 0.0


def test_a_deadman_period_that_is_not_positive_or_a_name_ros_refuses_is_an_error_before_the_run():
    with pytest.raises(ObjectiveError, match="--deadman-period must be a positive number of seconds, got 0"):
        RunOptions(protective_stop=StopInputs(deadman_topic="/deadman", deadman_period_s=0.0)).check()
    with pytest.raises(ObjectiveError, match=r"^--protective-stop 'bad name' is not a ROS 2 name: "):
        RunOptions(protective_stop=StopInputs("bad name", "bad name")).check()
    with pytest.raises(ObjectiveError, match=r"^--deadman-topic '/1st' is not a ROS 2 name: "):
        RunOptions(protective_stop=StopInputs(deadman_topic="/1st")).check()
    RunOptions(protective_stop=StopInputs("/cell_7/e_stop", "stop", "/operator/deadman")).check()


@pytest.mark.ros
@pytest.mark.timeout(90)
def test_a_stop_published_to_a_running_objective_run_ros_process_ends_it_as_failure(ros_env, observer, tmp_path):
    """Over ROS 2: `objective run --ros` holds the gripper in a long Wait; a Bool on
    /protective_stop from another node ends it FAILURE (exit 1) within seconds."""
    from tests.test_ros_run import close_wait_open, finish, objective, wait_for
    from sensor_msgs.msg import JointState

    joint_states = observer.create_subscription("/joint_states", JointState)
    stop = observer.create_publisher("/protective_stop", Bool)
    runner = objective("run", str(close_wait_open(tmp_path, 60.0)), "--ros", "--world", "kinematic", "--json", env=ros_env)
    try:
        wait_for(lambda: joint_states.count >= 1 and joint_states.latest.position[-1] > 0.05, observer, timeout=30.0,
                 what="the gripper closing")
        wait_for(lambda: stop._publisher.get_subscription_count() > 0, observer, timeout=10.0, what="the runner's stop subscription")
        stop.publish(Bool(data=True))
        code, out, err = finish(runner, timeout=15.0)
    finally:
        if runner.poll() is None:
            runner.kill()
    assert code == 1, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["status"] == "FAILURE" and summary["reason"].startswith("protective stop: '/protective_stop' is true at ")
    assert summary["failure_kind"] == "protective stop" and summary["running_nodes"]  # what it was doing
    assert " ticks): protective stop: '/protective_stop' is true at " in err and "Traceback" not in err


@pytest.mark.ros
@pytest.mark.timeout(90)
@pytest.mark.parametrize("ros", [False, True], ids=["in-process run", "ros run"])
def test_the_objective_server_ends_a_running_objective_as_failure_on_a_protective_stop(serve, client, library, ros):
    """The server's node serves the stop, whether its runs are in process or on ROS 2 themselves."""
    from action_msgs.msg import GoalStatus
    from tests.test_objective_server import wait_for as wait_until

    serve(library, realtime=True, ros=ros, world="kinematic")
    c = client()
    handle = c.send("Long Wait")
    wait_until(lambda: c.feedback, what="feedback")
    answer = c.call(c.node.create_client(Trigger, "/protective_stop"), Trigger.Request())
    assert (answer.success, answer.message) == (True, "protective stop: the run halts at its next tick")
    status, result = c.result(handle)
    assert status == GoalStatus.STATUS_ABORTED
    assert result.status == "FAILURE" and result.reason.startswith("protective stop: '/protective_stop' was called at ")
    handle = c.send("Long Wait")  # the next run starts afresh
    wait_until(lambda: len(c.feedback) > 3, what="feedback of the next run")
    c.node.create_publisher(Bool, "/protective_stop", 10).publish(Bool(data=True))
    status, result = c.result(handle)
    assert result.status == "FAILURE" and result.reason.startswith("protective stop: '/protective_stop' is true at ")


def test_a_stop_forwarded_to_an_eval_worker_ends_its_episode_in_that_tick_and_brings_the_arm_to_rest():
    """`objective eval`'s path: the parent engages the SharedStop (here at 8 s of the episode's
    clock, while the oracle's policy moves the arm); the worker's episode ends FAILURE at that tick
    with the reason the parent heard, and the arm comes to rest within the controllers' stop time."""
    from evaluation.config import WorkerSpec
    from evaluation.executors import CONTEXT
    from evaluation.policies import parse_policy
    from evaluation.worker import EpisodeWorker
    from runtime.app.protective_stop import SharedStop
    from sim.controllers.base import ControllersConfig

    stop_s, control_step_s = 8.0, 0.01
    shared = SharedStop(CONTEXT)
    spec = WorkerSpec(objective=Path("objectives/stack_cubes.xml").resolve(), world="kinematic",
                      policy=parse_policy("oracle"), policy_latency="0.1", max_seconds=60.0)
    worker = EpisodeWorker(spec, "worker-0", None, shared)
    worker.warm_up()
    try:
        world = worker.world  # kept between episodes: the one the episode steps
        step_to = world.step_to

        def step_and_engage(t: float) -> None:
            step_to(t)
            if abs(t - stop_s) < 1e-9:
                shared.engage("'/protective_stop' is true")

        world.step_to = step_and_engage
        record = worker.run(0)
        assert (record.status.value, record.failure_kind) == ("FAILURE", "protective stop")
        assert record.reason.startswith(f"protective stop: '/protective_stop' is true at {stop_s:.2f} s; halted 'ExecutePolicy'")
        assert record.sim_seconds == pytest.approx(stop_s)
        assert np.abs(world.cell.arm_velocity()).max() > 0.5  # moving when it was stopped
        rest_s = ControllersConfig().stop_time + control_step_s
        for k in range(1, round(rest_s / control_step_s) + 1):
            step_to(record.sim_seconds + k * control_step_s)
        assert np.abs(world.cell.arm_velocity()).max() == 0.0
        later = worker.run(1)  # still engaged: a later episode ends at its first tick, the tree never ticked
        assert (later.reason, later.ticks) == ("protective stop: '/protective_stop' is true at 0.01 s", 0)
    finally:
        worker.close()


class OneSlot:
    """An executor of one slot whose episodes end SUCCESS when the scheduler next waits."""

    workers = 1

    def __init__(self) -> None:
        self.submitted: list[int] = []
        self.seed: int | None = None

    def idle_slots(self) -> int:
        return 0 if self.seed is not None else 1

    def running(self) -> int:
        return 0 if self.seed is None else 1

    def submit(self, seed: int) -> None:
        self.submitted.append(seed)
        self.seed = seed

    def wait(self, timeout_s: float) -> list[Any]:
        from evaluation.episode import EpisodeRecord, EpisodeStatus
        from evaluation.executors import Event, EventKind

        seed, self.seed = self.seed, None
        return [Event(EventKind.DONE, seed, EpisodeRecord(seed, EpisodeStatus.SUCCESS))] if seed is not None else []

    def close(self) -> None:
        pass


def test_the_evaluation_starts_no_episode_after_the_protective_stop_and_its_summary_says_so(tmp_path):
    from evaluation.cli import summary_lines
    from evaluation.config import EvalConfig, WorkerSpec
    from evaluation.scheduler import run_episodes
    from evaluation.stats import summarise
    from evaluation.store import EvalStore

    config = EvalConfig(spec=WorkerSpec(objective=tmp_path / "t.xml"), out=tmp_path / "out", episodes=5)
    executor, store = OneSlot(), EvalStore(config.out, {"objective": "t"})
    asked: list[bool] = []

    def heard(running: bool) -> str | None:
        asked.append(running)
        return "'/protective_stop' was called" if len(executor.submitted) >= 2 else None

    try:
        loop = run_episodes(config, executor, store, protective_stop=heard)
    finally:
        store.close()
    assert executor.submitted == [0, 1] and sorted(store.records) == [0, 1]
    assert loop.protective_stop == "'/protective_stop' was called" and asked == [False, False, False]
    summary = {**summarise(list(store.records.values()), 5), "failure_groups": [], "protective_stop": loop.protective_stop}
    assert summary_lines(summary, config.out)[1] == (
        "stopped by the protective stop ('/protective_stop' was called): no episode started after it, "
        "the running ones ended FAILURE; run the same command again to run the rest")


@pytest.mark.ros
@pytest.mark.timeout(120)
def test_a_stop_published_to_a_running_objective_eval_ends_its_episode_and_the_evaluation(ros_env, observer, tmp_path):
    """`objective eval` listens in its own process: a Bool on /protective_stop while seed 0 runs
    (a Wait far longer than the test) ends that episode FAILURE, starts no other, and the summary
    says the protective stop stopped it (exit 1)."""
    from tests.test_ros_run import finish, objective, wait_for

    tree = tmp_path / "long_wait.xml"
    tree.write_text('<root BTCPP_format="4"><BehaviorTree ID="T"><Wait seconds="100000"/></BehaviorTree></root>')
    out = tmp_path / "out"
    stop = observer.create_publisher("/protective_stop", Bool)
    proc = objective("eval", str(tree), "--episodes", "3", "--out", str(out), "--world", "kinematic", "--record", "none",
                     "--episode-timeout", "100", "--json", env=ros_env)
    try:
        wait_for(lambda: stop._publisher.get_subscription_count() > 0, observer, timeout=30.0, what="eval's stop subscription")
        log = out / "logs" / "worker-0.log"
        wait_for(lambda: log.is_file() and "seed 0 started" in log.read_text(), timeout=60.0, what="seed 0 starting")
        stop.publish(Bool(data=True))
        code, stdout, err = finish(proc, timeout=30.0)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert code == 1, err
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert (summary["episodes"], summary["failures"], summary["complete"]) == (1, 1, False)
    assert summary["protective_stop"] == "'/protective_stop' is true"
    episode = json.loads((out / "episodes.jsonl").read_text().splitlines()[0])
    assert (episode["seed"], episode["status"], episode["failure_kind"]) == (0, "FAILURE", "protective stop")
    assert episode["reason"].startswith("protective stop: '/protective_stop' is true at ") and "halted 'Wait'" in episode["reason"]
    assert ("stopped by the protective stop ('/protective_stop' is true): no episode started after it, "
            "the running ones ended FAILURE; run the same command again to run the rest") in err
    assert "Traceback" not in err


def test_eval_without_rclpy_says_the_stop_is_not_listened_for_only_when_one_was_asked_for(monkeypatch, capsys):
    import argparse
    import sys

    from evaluation.cli import add_arguments, stop_listener

    monkeypatch.delitem(sys.modules, "runtime.app.stop_listener", raising=False)
    monkeypatch.setitem(sys.modules, "rclpy", None)  # as where rclpy is not installed
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    base = ["t.xml", "--episodes", "1", "--out", "out"]
    assert stop_listener(parser.parse_args(base)) is None
    assert capsys.readouterr().err == ""  # by default an evaluation does not need ROS 2
    for given in (["--protective-stop", "/cell/stop"], ["--deadman-topic", "/deadman"]):
        assert stop_listener(parser.parse_args(base + given)) is None
        assert capsys.readouterr().err == ("warning: the protective stop is not listened for: rclpy does not import "
                                           "(the [ros] extra or a sourced ROS 2)\n")
    assert stop_listener(parser.parse_args(base + ["--protective-stop", ""])) is None
    with pytest.raises(ObjectiveError, match=r"^--deadman-topic '/1st' is not a ROS 2 name: "):
        stop_listener(parser.parse_args(base + ["--deadman-topic", "/1st"]))


@pytest.mark.ros
@pytest.mark.timeout(120)
def test_objective_eval_s_deadman_stops_it_once_an_episode_runs_without_a_heartbeat(ros_env, tmp_path):
    """The deadman of `objective eval` is watched in its own process on the wall clock while an
    episode runs: no heartbeat at all ends the running episode and the evaluation."""
    from tests.test_ros_run import finish, objective

    tree = tmp_path / "long_wait.xml"
    tree.write_text('<root BTCPP_format="4"><BehaviorTree ID="T"><Wait seconds="100000"/></BehaviorTree></root>')
    out = tmp_path / "out"
    proc = objective("eval", str(tree), "--episodes", "2", "--out", str(out), "--world", "kinematic", "--record", "none",
                     "--episode-timeout", "100", "--deadman-topic", "/deadman", "--deadman-period", "1", "--json", env=ros_env)
    code, stdout, err = finish(proc, timeout=90.0)
    assert code == 1, err
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["protective_stop"].startswith("no heartbeat on the deadman '/deadman' for ")
    assert (summary["episodes"], summary["failures"]) == (1, 1)
    episode = json.loads((out / "episodes.jsonl").read_text().splitlines()[0])
    assert (episode["status"], episode["failure_kind"]) == ("FAILURE", "protective stop")
    assert episode["reason"].startswith("protective stop: no heartbeat on the deadman '/deadman' for ")
