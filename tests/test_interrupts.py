"""SIGINT, SIGTERM and SIGKILL against real `objective run` processes.

Each test starts the installed console script, waits until the tree is where it should be
(a LogMessage line on stderr), sends a real signal, and checks what a user gets: the exit code,
the --json summary (INTERRUPTED, where it stopped), stderr without a traceback, and a recording
that `objective report` reads (partial after SIGKILL). Every wait is bounded.
"""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.test_ros_run import finish  # communicate within a bound, or kill and fail

REPO = Path(__file__).resolve().parent.parent
EXE = Path(sys.executable).parent / "objective"
GRIPPER = 'gripper_command_action_name="/robotiq_gripper_controller/gripper_cmd"'
BOUND_S = 60.0

pytestmark = pytest.mark.skipif(not EXE.exists(), reason="the project is not installed (pip install -e .)")


def env() -> dict[str, str]:
    return {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "MUJOCO_GL": "egl"}


def close_then_wait(tmp_path: Path) -> Path:
    """Close the gripper, say so, then wait far longer than any test lasts."""
    path = tmp_path / "hold.xml"
    path.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Hold"><Sequence>'
        f'<MoveGripperAction {GRIPPER} position="0.5"/>'
        '<LogMessage message="holding"/>'
        '<Wait name="hold" seconds="100000"/>'
        f'<MoveGripperAction {GRIPPER} position="0.0"/>'
        "</Sequence></BehaviorTree></root>"
    )
    return path


def start(*args: str, new_session: bool = False) -> subprocess.Popen:
    return subprocess.Popen([str(EXE), "run", *args], cwd=REPO, env=env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=new_session)


def wait_for_line(proc: subprocess.Popen, needle: str, timeout: float = BOUND_S) -> str:
    """Read stderr until a line contains ``needle``; everything read so far is returned."""
    seen = ""
    deadline = time.monotonic() + timeout
    assert proc.stderr is not None
    while needle not in seen:
        left = deadline - time.monotonic()
        if left <= 0 or proc.poll() is not None:
            proc.kill()
            raise AssertionError(f"no {needle!r} on stderr within {timeout} s; stderr so far:\n{seen}")
        ready, _, _ = select.select([proc.stderr], [], [], min(left, 0.5))
        if ready:
            seen += proc.stderr.readline()
    return seen


def report(directory: Path) -> tuple[int, str]:
    proc = subprocess.run([str(EXE), "report", str(directory)], cwd=REPO, env=env(), capture_output=True,
                          text=True, timeout=BOUND_S)
    assert "Traceback" not in proc.stderr
    return proc.returncode, proc.stderr


def events(directory: Path) -> list[dict]:
    return [json.loads(line) for line in (directory / "events.jsonl").read_text().splitlines()]


@pytest.mark.timeout(3 * BOUND_S)
def test_sigterm_of_a_recorded_headless_run_halts_records_and_summarises(tmp_path):
    record = tmp_path / "rec"
    proc = start(str(close_then_wait(tmp_path)), "--world", "kinematic", "--json", "--record", str(record))
    before = wait_for_line(proc, "[INFO] holding")
    proc.send_signal(signal.SIGTERM)
    code, out, err = finish(proc, timeout=BOUND_S)
    err = before + err
    assert code == 143, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert (summary["status"], summary["signal"], summary["running_nodes"]) == ("INTERRUPTED", "SIGTERM", ["hold"])
    assert summary["ticks"] > 0 and summary["sim_seconds"] == pytest.approx(summary["ticks"] * 0.01)
    assert summary["reason"].startswith(f"interrupted by SIGTERM at {summary['sim_seconds']:.2f} s; halted 'hold' (")
    assert "Traceback" not in err
    assert f"INTERRUPTED after {summary['sim_seconds']:.2f} s ({summary['ticks']} ticks)" in err
    # the recording is whole: the halt is in it, the summary last, the report rendered
    records = events(record)
    assert records[-1]["kind"] == "run_summary" and records[-1]["data"]["status"] == "INTERRUPTED"
    halted = [r["data"] for r in records if r["kind"] == "node_status" and r["source"] == "hold"]
    assert (halted[-1]["status"], halted[-1]["message"]) == ("INVALID", "halted")
    assert (record / "report.html").exists() and "INTERRUPTED" in (record / "report.html").read_text()
    code, report_err = report(record)
    assert code == 0 and "partial" not in report_err


@pytest.mark.timeout(3 * BOUND_S)
def test_ctrl_c_of_a_recorded_realtime_run_reaches_only_the_run_not_its_report_worker(tmp_path):
    """Ctrl-C at a terminal signals the whole foreground process group."""
    record = tmp_path / "rec"
    proc = start(str(close_then_wait(tmp_path)), "--world", "kinematic", "--realtime", "--json", "--record", str(record),
                 new_session=True)
    before = wait_for_line(proc, "[INFO] holding")
    os.killpg(proc.pid, signal.SIGINT)
    code, out, err = finish(proc, timeout=BOUND_S)
    err = before + err
    assert code == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    summary = json.loads(out.strip().splitlines()[-1])
    assert (summary["status"], summary["signal"], summary["running_nodes"]) == ("INTERRUPTED", "SIGINT", ["hold"])
    assert summary["pacing"]["period_s"] == 0.01  # it was a wall-clock run
    assert events(record)[-1]["data"]["status"] == "INTERRUPTED"
    assert (record / "report.html").exists()


def test_an_interrupted_run_cancels_the_moving_gripper(tmp_path):
    """In process, on the simulated clock: the stop lands while the gripper is half way."""
    from runtime.io.interrupt import StopRequest
    from runtime.tree.registry import Registry
    from runtime.app.observer import RunObserver
    from runtime.app.runner import RunOptions, run_file

    path = tmp_path / "close.xml"
    path.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Close">'
        f'<MoveGripperAction name="close" {GRIPPER} position="0.8"/>'
        "</BehaviorTree></root>"
    )
    stop = StopRequest()

    class SignalAtTick20(RunObserver):
        ticks = 0

        def ticked(self, now_s: float, visited: list) -> None:
            self.ticks += 1
            if self.ticks == 20:
                stop.on_signal(signal.SIGINT)

    result = run_file(path, Registry.from_entry_points(), RunOptions(world="kinematic"),
                      observers=[SignalAtTick20()], stop=stop)
    assert (result.status, result.exit_code, result.ticks, result.running_nodes) == ("INTERRUPTED", 130, 20, ["close"])
    assert 0.1 < result.extra["world"]["gripper"] < 0.5  # 1.6 rad/s for about 0.2 s: stopped on the way


@pytest.mark.timeout(3 * BOUND_S)
def test_sigint_of_a_headless_run_without_a_recording_prints_the_summary(tmp_path):
    proc = start(str(close_then_wait(tmp_path)), "--world", "kinematic", "--json")
    before = wait_for_line(proc, "[INFO] holding")
    proc.send_signal(signal.SIGINT)
    code, out, err = finish(proc, timeout=BOUND_S)
    assert code == 130, before + err
    summary = json.loads(out.strip().splitlines()[-1])
    assert (summary["status"], summary["running_nodes"]) == ("INTERRUPTED", ["hold"])
    assert "Traceback" not in err


@pytest.mark.timeout(3 * BOUND_S)
def test_a_recording_killed_with_sigkill_opens_as_partial(tmp_path):
    record = tmp_path / "rec"
    proc = start(str(close_then_wait(tmp_path)), "--world", "kinematic", "--record", str(record))
    wait_for_line(proc, "[INFO] holding")
    time.sleep(1.5)  # past the MCAP flush interval: the gripper's motion is in a closed chunk
    proc.kill()
    proc.communicate(timeout=BOUND_S)
    records = events(record)
    assert records[0]["kind"] == "tree" and not any(r["kind"] == "run_summary" for r in records)
    assert any(r["kind"] == "log" and r["data"]["message"] == "holding" for r in records)
    code, err = report(record)
    assert code == 0
    assert "partial recording: events.jsonl has no run summary: the run was killed before it finished" in err
    page = (record / "report.html").read_text()
    assert "Partial recording" in page and (record / "joints.svg").exists()

    from recording.report import load_recording

    recording = load_recording(record)
    assert recording.joints is not None and recording.joints.times[-1] > 0.5


def test_a_second_sigint_while_the_recording_finishes_keeps_its_summary_and_end(tmp_path, monkeypatch, capsys):
    """Ctrl-C stops the run; a second one arrives while the recording is being finished: it waits
    until the summary and the recording's end are written, then only stops the report."""
    from runtime.app import runner
    from runtime.app.cli import main
    from recording import Recorder

    tree = tmp_path / "wait.xml"
    tree.write_text('<root BTCPP_format="4"><BehaviorTree ID="Wait"><Wait name="hold" seconds="100000"/>'
                    "</BehaviorTree></root>")
    run_tree, finish_recording = runner.run_tree, Recorder.finish

    def run_after_ctrl_c(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)  # the first: the run stops before its first tick
        return run_tree(*args, **kwargs)

    def finish_after_ctrl_c(self, summary):
        os.kill(os.getpid(), signal.SIGINT)  # the second, as the recording finishes
        finish_recording(self, summary)

    monkeypatch.setattr(runner, "run_tree", run_after_ctrl_c)
    monkeypatch.setattr(Recorder, "finish", finish_after_ctrl_c)
    record = tmp_path / "rec"
    code = main(["run", str(tree), "--record", str(record), "--json"])
    out, err = capsys.readouterr()
    assert code == 130, err
    assert json.loads(out.strip().splitlines()[-1])["status"] == "INTERRUPTED"
    assert "the report was not rendered (interrupted)" in err and "Traceback" not in err
    assert events(record)[-1]["kind"] == "run_summary" and events(record)[-1]["data"]["status"] == "INTERRUPTED"
    assert (record / "metadata.yaml").is_file()  # the worker wrote the recording's end
    code, report_err = report(record)
    assert code == 0 and "partial" not in report_err


HUNG_POLICY = '''
import sys
import threading


class Hung:
    name = "hung"

    def load(self):
        pass

    def warmup(self, request):
        pass

    def infer(self, request):
        print("policy called", file=sys.stderr, flush=True)
        threading.Event().wait(120)  # hung, within the test's bound
        raise RuntimeError("the policy was waited for past its hang")


def make(options):
    return Hung()
'''


def test_sigterm_stops_a_run_whose_in_process_policy_hangs(tmp_path):
    """The policy's call has 600 s to answer: only the signal can end the run, at once."""
    (tmp_path / "hung.py").write_text(HUNG_POLICY)
    objective = tmp_path / "stack.xml"
    objective.write_text((REPO / "objectives" / "stack_cubes.xml").read_text()
                         .replace('policy_call_timeout="10.0"', 'policy_call_timeout="600"'))
    proc = start(str(objective), "--world", "kinematic", "--policy", f"{tmp_path / 'hung.py'}:make", "--json")
    before = wait_for_line(proc, "policy called")
    proc.send_signal(signal.SIGTERM)
    code, out, err = finish(proc, timeout=BOUND_S)
    assert code == 143, before + err
    summary = json.loads(out.strip().splitlines()[-1])
    assert (summary["status"], summary["signal"], summary["running_nodes"]) == ("INTERRUPTED", "SIGTERM", ["ExecutePolicy"])
    assert "service '/get_action_chunk': stopped waiting for its handler, which still runs; its answer is dropped" in err
    assert "Traceback" not in err
