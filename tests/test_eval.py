"""`objective eval` with the local executor: the command, determinism per seed, resume, and an
episode that crashes its worker, one that hangs and one that raises.

The fault episodes come from a behavior plug-in (tests/eval_plugin: an `objective.behaviors`
entry point, found by the worker processes through PYTHONPATH) on a tree without a world, so
they cost only worker start-ups; the stacking episodes run on the kinematic world.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import recording.report.worker as report_worker
from evaluation.config import RecordMode, WorkerSpec
from evaluation.episode import EpisodeStatus
from evaluation.policies import parse_policy
from evaluation.worker import EpisodeWorker
from runtime.app.cli import main

ROOT = Path(__file__).resolve().parent.parent
STACK = ROOT / "objectives" / "stack_cubes.xml"
PLUGIN = Path(__file__).resolve().parent / "eval_plugin"

FAULTS_XML = """<?xml version="1.0"?>
<root BTCPP_format="4" main_tree_to_execute="Faults">
  <BehaviorTree ID="Faults">
    <Sequence>
      <FaultBySeed crash_seed="{crash}" hang_seed="{hang}" raise_seed="{raise_}" fail_seed="{fail}"/>
      <AlwaysSuccess/>
    </Sequence>
  </BehaviorTree>
</root>
"""


@pytest.fixture
def fault_plugin(monkeypatch):
    """The plug-in on this process's path and on the workers' PYTHONPATH."""
    monkeypatch.syspath_prepend(str(PLUGIN))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(PLUGIN), os.environ.get("PYTHONPATH")])))


def faults_objective(tmp_path: Path, crash: int = -1, hang: int = -1, raise_: int = -1, fail: int = -1) -> Path:
    path = tmp_path / "faults.xml"
    path.write_text(FAULTS_XML.format(crash=crash, hang=hang, raise_=raise_, fail=fail))
    return path


def eval_cli(capsys, *argv: str) -> tuple[int, dict, str]:
    code = main(["eval", *map(str, argv), "--json"])
    out, err = capsys.readouterr()
    return code, json.loads(out.strip().splitlines()[-1]), err


def episodes(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]


def test_stacking_cut_short_on_two_workers(tmp_path, capsys):
    """Two seeds on two workers, each cut at 8 s of the 31 s episode (the full run is the slow test below)."""
    out = tmp_path / "eval"
    code, summary, err = eval_cli(capsys, STACK, "--episodes", 2, "--seed-start", 5, "--workers", 2, "--max-seconds", 8,
                                  "--world", "kinematic", "--record", "none", "--out", out)
    assert code == 0, err
    assert (summary["episodes"], summary["failures"], summary["errors"], summary["seeds"]) == (2, 2, 0, [5, 6])
    assert summary["success_rate"] == 0.0 and summary["success_rate_ci95"][1] == pytest.approx(0.6576, abs=1e-4)
    assert summary["deterministic"] and summary["policy_latency"] == "0.1"
    (group,) = summary["failure_groups"]
    assert (group["count"], group["failing_node"], group["seeds"]) == (2, "ExecutePolicy", [5, 6])
    assert (group["reason"], group["failure_kind"]) == ("timeout", "timeout")
    assert group["example"] == "stopped after --max-seconds 8 s of clock time while 'ExecutePolicy' was RUNNING"
    lines = episodes(out)
    assert sorted(line["seed"] for line in lines) == [5, 6]
    assert {line["worker"] for line in lines} <= {"worker-0", "worker-1"}
    for line in lines:
        assert line["failing_location"] == "objectives/stack_cubes.xml:12"
        assert line["run"]["execute_policy"]["latency_p50_s"] == 0.1  # the fixed latency model
        assert line["run"]["world"]["seed"] == line["seed"]
    assert json.loads((out / "summary.json").read_text())["failures"] == 2
    page = (out / "report.html").read_text()
    assert "success rate" in page and "<svg" in page and "id='seed-6'" in page
    assert "2 episodes: 0 successes (0.0 %" in err


@pytest.mark.slow
def test_stacking_over_three_seeds_on_two_workers(tmp_path, capsys):
    out = tmp_path / "eval"
    code, summary, err = eval_cli(capsys, STACK, "--episodes", 3, "--seed-start", 5, "--workers", 2,
                                  "--world", "kinematic", "--record", "none", "--out", out)
    assert code == 0, err
    assert (summary["episodes"], summary["successes"], summary["errors"], summary["seeds"]) == (3, 3, 0, [5, 7])
    assert summary["success_rate"] == 1.0 and summary["success_rate_ci95"][0] == pytest.approx(0.4385, abs=1e-4)
    for line in episodes(out):
        assert line["status"] == "SUCCESS" and line["sim_seconds"] > 20
        assert line["run"]["execute_policy"]["steps_executed"] == 300
        assert line["blackboard"]["steps_executed"] == 300


def kept_and_fresh(spec: WorkerSpec, before: int, seed: int) -> tuple:
    """``seed``'s episode in a worker that ran ``before`` first, and in a fresh worker."""
    records = []
    for first in (before, None):
        worker = EpisodeWorker(spec, "kept" if first is not None else "fresh")
        worker.warm_up()
        try:
            if first is not None:
                worker.run(first)
            records.append(worker.run(seed))
        finally:
            worker.close()
    return records[0], records[1]


def test_a_seed_gives_the_same_episode_in_any_worker_and_order():
    """A kept world put back to a seed runs the episode a fresh worker runs, random latency included.

    Cut at 9 s of the 31 s episode (mid-stream: the arm carrying the cube) to keep the test short."""
    spec = WorkerSpec(objective=STACK, world="kinematic", policy=parse_policy("oracle"),
                      policy_latency="lognormal:0.3,0.15", max_seconds=9.0)
    a3, b3 = kept_and_fresh(spec, before=4, seed=3)
    assert a3.reason == "stopped after --max-seconds 9 s of clock time while 'ExecutePolicy' was RUNNING"
    policy = a3.run["execute_policy"]
    assert policy["chunks"] >= 3 and policy["latency_max_s"] > policy["latency_p50_s"]  # random, seeded
    assert a3.seeded_view() == b3.seeded_view()
    red = a3.run["world"]["cubes"]["red"]  # untouched by the stacking: still where seed 3 put it, not seed 4
    assert red[:2] == pytest.approx(layout_xy(3)["red"], abs=1e-3)
    assert red[:2] != pytest.approx(layout_xy(4)["red"], abs=1e-3)


@pytest.mark.slow
def test_a_kept_physics_world_runs_a_seed_as_a_fresh_one():
    """The MuJoCo cell put back to a seed (model, data and renderer kept) runs the same episode."""
    spec = WorkerSpec(objective=STACK, world="vla_sim", policy=parse_policy("oracle"), max_seconds=9.0)
    a, b = kept_and_fresh(spec, before=1, seed=0)
    assert a.run["execute_policy"]["chunks"] >= 3
    assert a.seeded_view() == b.seeded_view()


def recording_workers() -> list[int]:
    """The pids of this process's children that are recording workers."""
    children = []
    for task in Path("/proc/self/task").iterdir():
        children += (task / "children").read_text().split()
    return [int(pid) for pid in children
            if b"recording.report.worker" in Path(f"/proc/{pid}/cmdline").read_bytes()]


@pytest.fixture
def slow_recording_worker(monkeypatch):
    """Recording workers that start 2 s late: the run is over long before they wrote run.mcap."""
    popen = subprocess.Popen

    def late(args, **kwargs):
        if list(args[1:]) == ["-m", "recording.report.worker"]:
            args = [args[0], "-c", "import runpy, time; time.sleep(2); "
                    "runpy.run_module('recording.report.worker', run_name='__main__', alter_sys=True)"]
        return popen(args, **kwargs)

    monkeypatch.setattr(report_worker.subprocess, "Popen", late)


def test_a_failed_episode_keeps_its_reason_and_a_whole_recording_however_late_the_recording_worker(
        tmp_path, slow_recording_worker):
    """``--record failures``: the report is rendered only once the worker wrote the recording, so a
    failing episode stays a FAILURE with its reason, its recording moved out of ``.partial-*``; a
    successful episode's recording is removed and its worker stopped."""
    spec = WorkerSpec(objective=STACK, world="kinematic", policy=parse_policy("oracle"), max_seconds=2.0,
                      record=RecordMode.FAILURES)
    worker = EpisodeWorker(spec, "w", tmp_path / "recordings")
    worker.warm_up()
    try:
        record = worker.run(0)
    finally:
        worker.close()
    assert record.status is EpisodeStatus.FAILURE, record.reason
    assert record.reason.startswith("stopped after --max-seconds 2 s of clock time while ")
    assert record.recording == "recordings/seed-0" and "recording_errors" not in record.run
    kept = tmp_path / "recordings" / "seed-0"
    assert (kept / "run.mcap").stat().st_size > 0 and (kept / "report.html").is_file()
    summary = json.loads((kept / "events.jsonl").read_text().splitlines()[-1])
    assert summary["kind"] == "run_summary" and summary["data"]["status"] == "FAILURE"
    assert sorted(p.name for p in (tmp_path / "recordings").iterdir()) == ["seed-0"]
    assert recording_workers() == []


def test_a_successful_episode_leaves_no_recording_and_no_recording_worker(tmp_path, fault_plugin):
    spec = WorkerSpec(objective=faults_objective(tmp_path), policy=parse_policy("oracle"), record=RecordMode.FAILURES)
    worker = EpisodeWorker(spec, "w", tmp_path / "recordings")
    worker.warm_up()
    try:
        records = [worker.run(seed) for seed in (0, 1)]
    finally:
        worker.close()
    assert [r.status for r in records] == [EpisodeStatus.SUCCESS] * 2
    assert [r.recording for r in records] == [None, None]
    assert list((tmp_path / "recordings").iterdir()) == []
    assert recording_workers() == []


def layout_xy(seed: int) -> dict:
    from sim.layouts import layout

    return {color: [x, y] for color, (x, y, _) in layout(seed).items()}


def test_crashed_hung_and_raising_episodes_are_errors_and_the_evaluation_goes_on(tmp_path, capsys, fault_plugin):
    objective = faults_objective(tmp_path, crash=1, hang=2, raise_=3, fail=4)
    out = tmp_path / "eval"
    code, summary, err = eval_cli(capsys, objective, "--episodes", 6, "--workers", 2, "--episode-timeout", 5,
                                  "--record", "none", "--out", out)
    assert code == 1, err  # some episodes ended ERROR
    by_seed = {line["seed"]: line for line in episodes(out)}
    assert sorted(by_seed) == [0, 1, 2, 3, 4, 5]
    assert [by_seed[s]["status"] for s in range(6)] == ["SUCCESS", "ERROR", "ERROR", "ERROR", "FAILURE", "SUCCESS"]
    crash = by_seed[1]
    assert "its worker died (signal SIGABRT; see logs/worker-" in crash["reason"]
    assert crash["reason"].endswith("2 attempts, each lost its worker") and crash["attempts"] == 2
    assert by_seed[2]["reason"].startswith("no result within 5 s of wall time (--episode-timeout): the episode hung")
    # An exception in a behavior ends the episode as the runner ends any run: ERROR, one paragraph.
    assert "FaultBySeed: an unexpected RuntimeError in " in by_seed[3]["reason"]
    assert "eval_faults.py:" in by_seed[3]["reason"] and "fault injected for seed 3" in by_seed[3]["reason"]
    assert by_seed[4]["failing_node"] == "FaultBySeed" and by_seed[4]["reason"] == "check missed by 0.043 m on seed 4"
    assert (summary["successes"], summary["failures"], summary["errors"]) == (2, 1, 3)
    assert summary["success_rate"] == pytest.approx(2 / 6, abs=1e-6)
    groups = {g["seeds"][0]: g for g in summary["failure_groups"]}
    assert groups[4]["reason"] == "check missed by 0.043 m on seed 4"  # a node that names no kind: by its reason
    assert [groups[seed]["failure_kind"] for seed in (1, 2, 3, 4)] == ["worker lost", "episode timeout", "internal", None]


def test_the_recording_of_a_hung_episode_is_kept_marked_partial(tmp_path, capsys, fault_plugin):
    """On main it stayed in recordings/.partial-seed-1, which nothing read or removed."""
    objective = faults_objective(tmp_path, hang=1)
    kept, everything = tmp_path / "kept", tmp_path / "all"
    code, summary, err = eval_cli(capsys, objective, "--episodes", 2, "--episode-timeout", 5, "--out", kept)
    assert code == 1, err
    hung = {line["seed"]: line for line in episodes(kept)}[1]
    assert hung["status"] == "ERROR" and hung["recording"] == "recordings/seed-1"
    assert hung["run"]["recording_incomplete"].startswith("its worker was stopped mid-episode: the recording ends at its last flush")
    assert sorted(p.name for p in (kept / "recordings").iterdir()) == ["seed-1"]
    code, summary, err = eval_cli(capsys, objective, "--episodes", 2, "--episode-timeout", 5, "--record", "all",
                                  "--out", everything)
    assert sorted(p.name for p in (everything / "recordings").iterdir()) == ["seed-0", "seed-1"]


def test_resume_skips_finished_seeds_and_refuses_another_objective_or_policy(tmp_path, capsys, fault_plugin):
    objective = faults_objective(tmp_path, fail=1)
    out = tmp_path / "eval"
    code, summary, _ = eval_cli(capsys, objective, "--episodes", 2, "--record", "none", "--out", out)
    assert code == 0 and summary["episodes"] == 2 and summary["resumed"] == 0
    with open(out / "episodes.jsonl", "a") as f:
        f.write('{"seed": 2, "status": "SUCC')  # a line cut off when the machine stopped
    code, summary, _ = eval_cli(capsys, objective, "--episodes", 4, "--record", "none", "--out", out)
    assert code == 0 and summary["resumed"] == 2 and summary["episodes"] == 4
    lines = episodes(out)
    assert [line["seed"] for line in lines] == [0, 1, 2, 3]  # each once; the cut-off line is gone
    assert summary["failures"] == 1 and summary["failure_groups"][0]["seeds"] == [1]

    code, err = main(["eval", str(objective), "--episodes", "4", "--out", str(out), "--policy", "none"]), capsys.readouterr().err
    assert code == 2
    assert f"error: --out {out} was made by a different policy: 'oracle', now 'none'" in err
    faults_objective(tmp_path, fail=2)  # the same file, another content
    code, err = main(["eval", str(objective), "--episodes", "4", "--out", str(out)]), capsys.readouterr().err
    assert code == 2 and "was made by a different Objective (its file's content differs)" in err
    assert len(episodes(out)) == 4


def test_resume_refuses_an_objective_whose_subtree_file_was_edited(tmp_path, capsys):
    """The resume check covers every file the Objective is built from, its SubTrees' too: seeds
    run before and after an edit of a SubTree never land in one summary."""
    library = tmp_path / "library"
    library.mkdir()
    inner = library / "inner.xml"
    inner.write_text('<root BTCPP_format="4"><BehaviorTree ID="Inner"><AlwaysSuccess/></BehaviorTree></root>')
    objective = tmp_path / "outer.xml"
    objective.write_text('<root BTCPP_format="4"><BehaviorTree ID="Outer"><SubTree ID="Inner"/></BehaviorTree></root>')
    out = tmp_path / "eval"
    args = ("--record", "none", "--out", out, "--path", library)
    code, summary, err = eval_cli(capsys, objective, "--episodes", 2, *args)
    assert code == 0 and summary["successes"] == 2, err
    assert summary["identity"]["objective_files"].keys() == {str(objective.resolve()), str(inner.resolve())}
    inner.write_text('<root BTCPP_format="4"><BehaviorTree ID="Inner"><AlwaysFailure/></BehaviorTree></root>')
    code = main(["eval", str(objective), "--episodes", "4", *map(str, args)])
    assert code == 2
    assert (f"error: --out {out} was made by a different Objective: {inner.resolve()} (edited)"
            in capsys.readouterr().err)
    assert len(episodes(out)) == 2


def test_bad_input_is_refused_before_any_worker_starts(tmp_path, capsys):
    broken = tmp_path / "broken.xml"
    broken.write_text('<root BTCPP_format="4"><BehaviorTree ID="T"><NoSuchNode/></BehaviorTree></root>')
    code, summary, err = eval_cli(capsys, broken, "--episodes", 2, "--out", tmp_path / "a")
    assert code == 2 and summary["status"] == "ERROR"
    assert f"{broken}:1" in err and "NoSuchNode" in err
    code = main(["eval", str(STACK), "--episodes", "2", "--out", str(tmp_path / "b"), "--policy", "lerobot:/no/such"])
    assert code == 2 and "--policy 'lerobot:/no/such': no such checkpoint directory" in capsys.readouterr().err
    code = main(["eval", str(STACK), "--episodes", "0", "--out", str(tmp_path / "c")])
    assert code == 2 and "--episodes must be at least 1, got 0" in capsys.readouterr().err
    code = main(["eval", str(STACK), "--episodes", "2", "--out", str(tmp_path / "c"), "--workers", "100000"])
    assert code == 2 and "--workers must be 1 to 64 (each worker is a process with a world of its own), got 100000" in capsys.readouterr().err
    code = main(["eval", str(STACK), "--episodes", "2", "--out", str(tmp_path / "c"), "--seed-start", "-5"])
    assert code == 2 and "--seed-start must be 0 to 4294967294 (seeds are 0 to 4294967295), got -5" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()  # refused before any episode
    code = main(["eval", str(STACK), "--episodes", "1", "--out", str(tmp_path / "d"), "--policy-latency", "soon"])
    assert code == 2 and "--policy-latency: latency 'soon'" in capsys.readouterr().err


def test_a_running_inference_server_serves_every_worker_with_its_key_from_the_environment(tmp_path, capsys, monkeypatch):
    """--policy http://...: the workers call the server (a replay holding the arm at Home, then
    NO_MORE_ACTIONS); the stack check then fails, as it should with a policy that does nothing."""
    import numpy as np

    from policy.replay import RecordedChunk, ReplayBackend, write_replay
    from policy.server import InferenceServer, ServerConfig
    from sim.robot_model import ARM_JOINTS, GRIPPER_DRIVER_JOINT, load_waypoints

    home = load_waypoints()["Home"]
    names = list(ARM_JOINTS) + [GRIPPER_DRIVER_JOINT]
    hold = np.array([[home[j] for j in ARM_JOINTS] + [0.0]] * 30)
    write_replay(tmp_path / "hold.jsonl", [RecordedChunk(names, hold, 0.1)] * 2)
    key = "eval-test-key-" + "k" * 20
    server = InferenceServer(ReplayBackend(tmp_path / "hold.jsonl"), ServerConfig(key=key)).start()
    try:
        assert server.ready.wait(10)
        monkeypatch.setenv("POLICY_SERVER_KEY", key)
        code, summary, err = eval_cli(capsys, STACK, "--episodes", 1, "--world", "kinematic", "--policy", server.url,
                                      "--record", "none", "--out", tmp_path / "eval")
    finally:
        server.stop()
    assert code == 0, err
    assert summary["failures"] == 1 and not summary["deterministic"]
    line = episodes(tmp_path / "eval")[0]
    assert line["run"]["execute_policy"]["chunks"] == 2
    assert line["failing_node"] == "top cube on bottom cube"


# -- signals and concurrent evaluations ---------------------------------------------------------
EXE = Path(sys.executable).parent / "objective"
BOUND_S = 120.0


def start_eval(objective: Path, out: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen([str(EXE), "eval", str(objective), "--record", "none", "--out", str(out), *args],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for_episodes(out: Path, count: int, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + BOUND_S
    while not ((out / "episodes.jsonl").exists() and len(episodes(out)) >= count):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"no {count} episodes within {BOUND_S} s: {proc.communicate()[1]}")
        time.sleep(0.1)


def ended(proc: subprocess.Popen) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=BOUND_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError(f"`objective eval` did not end within {BOUND_S} s: {proc.communicate()[1]}") from None
    return proc.returncode, out, err


def test_a_second_evaluation_of_a_busy_out_is_refused_and_sigterm_keeps_the_episodes_so_far(tmp_path, capsys, fault_plugin):
    objective = faults_objective(tmp_path, hang=1)  # seed 0 succeeds, seed 1 hangs until stopped
    out = tmp_path / "eval"
    first = start_eval(objective, out, "--episodes", "4", "--episode-timeout", "600", "--json")
    wait_for_episodes(out, 1, first)
    code = main(["eval", str(objective), "--episodes", "4", "--record", "none", "--episode-timeout", "5", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert f"--out {out} is in use by another evaluation (pid {first.pid}); wait for it to end, or use another --out" in err
    first.send_signal(signal.SIGTERM)
    code, stdout, err = ended(first)
    assert code == 143, err
    assert "interrupted by SIGTERM: the finished episodes are kept; run the same command again to resume" in err
    assert "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["interrupted"], summary["episodes"], summary["requested"], summary["complete"]) == ("SIGTERM", 1, 4, False)
    assert json.loads(stdout.strip().splitlines()[-1]) == summary
    assert [line["seed"] for line in episodes(out)] == [0]


def test_evaluations_started_together_on_one_out_run_each_seed_once(tmp_path, fault_plugin):
    """Three `objective eval` of the same DIR at once: one runs the seeds, the others are refused
    (or, started after it ended, find every seed done)."""
    objective = faults_objective(tmp_path, fail=2)
    out = tmp_path / "eval"
    procs = [start_eval(objective, out, "--episodes", "4") for _ in range(3)]
    results = [ended(proc) for proc in procs]
    codes = sorted(code for code, _, _ in results)
    assert all(code in (0, 2) for code in codes) and codes.count(0) >= 1, results
    for code, _, err in results:
        assert "Traceback" not in err
        if code == 2:
            assert "is in use by another evaluation (pid " in err
    assert sorted(line["seed"] for line in episodes(out)) == [0, 1, 2, 3]


def test_a_setup_error_before_the_first_tick_stops_the_evaluation_and_the_summary_shows_it(tmp_path, capsys):
    """Every episode ran to "2 x ERROR 'MoveToWaypoint': SetupError", the message only in episodes.jsonl."""
    objective = tmp_path / "typo.xml"
    objective.write_text('<root BTCPP_format="4"><BehaviorTree ID="T"><MoveToWaypoint waypoint_name="home"/></BehaviorTree></root>')
    out = tmp_path / "eval"
    code, summary, err = eval_cli(capsys, objective, "--episodes", 6, "--record", "none", "--world", "kinematic", "--out", out)
    assert code == 1
    message = f"{objective}:1: MoveToWaypoint: port 'waypoint_name': unknown waypoint 'home' (did you mean 'Home'?)"
    assert [line["seed"] for line in episodes(out)] == [0]
    assert summary["stopped"]["seed"] == 0 and summary["stopped"]["reason"].startswith(message)
    assert summary["complete"] is False
    lines = err.splitlines()
    assert lines[1].startswith(f"     1 x ERROR 'MoveToWaypoint': SetupError: {message}"), lines
    assert lines[2] == ("stopped after seed 0: a mistake of the setup, found before the first tick, that every seed "
                        "would repeat: fix it, then evaluate again")



def test_run_and_eval_default_to_the_same_fixed_policy_latency(tmp_path, capsys):
    """run measured the policy's wall time by default, eval simulated 0.1 s."""
    assert main(["run", str(STACK), "--world", "kinematic", "--json"]) == 0
    run_policy = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["execute_policy"]
    code, summary, _ = eval_cli(capsys, STACK, "--episodes", 1, "--record", "none", "--world", "kinematic", "--out", tmp_path / "e")
    assert code == 0 and summary["policy_latency"] == "0.1"
    assert run_policy["latency_p50_s"] == run_policy["latency_max_s"] == pytest.approx(0.1, abs=0.011)  # ticks of 0.01 s
