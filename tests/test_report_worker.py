"""The report worker: a second process renders the report after a recorded run (the video
encoded while the run goes on); whatever goes wrong there, the report still comes out (rendered
in process), and a worker never outlives its run."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from recording.report import render_report
from runtime.errors import ObjectiveError
from recording.report.worker import ReportWorker

from .test_recording import record_run

ARTIFACTS = {"joints": "joints.svg", "latency": "latency.svg", "tree": "tree.svg", "video": "cameras.mp4", "html": "report.html"}


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    code, rec = record_run(tmp_path_factory.mktemp("worker"))
    assert code == 0
    return rec


def fresh_copy(recording: Path, tmp_path: Path) -> Path:
    target = tmp_path / "rec"
    target.mkdir()
    for name in ("events.jsonl", "run.mcap"):
        shutil.copy(recording / name, target / name)
    return target


def test_the_worker_renders_every_artifact(recording, tmp_path):
    target = fresh_copy(recording, tmp_path)
    worker = ReportWorker()
    worker.start()
    report = worker.render(target)
    assert report.errors == {}
    assert {k: p.name for k, p in report.files.items()} == ARTIFACTS
    assert all((target / name).stat().st_size > 0 for name in ARTIFACTS.values())
    assert worker.process is None


def test_a_dead_worker_means_the_report_is_rendered_in_process(recording, tmp_path):
    target = fresh_copy(recording, tmp_path)
    worker = ReportWorker()
    worker.start()
    worker.process.kill()
    worker.process.wait()
    report = worker.render(target)
    assert report.errors == {} and set(report.files) == set(ARTIFACTS)
    assert (target / "joints.svg").stat().st_size > 0


def test_a_worker_that_is_not_asked_is_stopped(tmp_path):
    worker = ReportWorker()
    worker.start()
    process = worker.process
    worker.close()
    assert process.poll() is not None and worker.process is None


def test_the_report_rendered_here_removes_what_a_killed_worker_left_of_the_video(recording, tmp_path):
    target = fresh_copy(recording, tmp_path)
    (target / "cameras.4242.part.mp4").write_bytes(b"half a video")  # a worker killed while encoding
    report = render_report(target)
    assert report.errors == {} and report.files["video"] == target / "cameras.mp4"
    assert not (target / "cameras.4242.part.mp4").exists()


def test_a_failing_joint_plot_is_reported_and_the_rest_written(recording, tmp_path, monkeypatch):
    target = fresh_copy(recording, tmp_path)

    def broken(*args, **kwargs):
        raise RuntimeError("no joints today")

    import recording.report.plots as plots

    monkeypatch.setattr(plots, "joints_plot", broken)
    report = render_report(target)
    assert report.errors == {"joints": "RuntimeError: no joints today"}
    assert set(report.files) == set(ARTIFACTS) - {"joints"}
    assert not (target / "joints.svg").exists()
    assert "no joint plot" in (target / "report.html").read_text()


def test_an_unreadable_recording_is_one_clear_error_not_a_traceback(tmp_path, capfd):
    target = tmp_path / "rec"
    target.mkdir()
    (target / "events.jsonl").write_text("")
    (target / "run.mcap").write_bytes(b"not an mcap file")
    worker = ReportWorker()
    worker.start()
    with pytest.raises(ObjectiveError, match="run.mcap: cannot read the recording"):
        worker.render(target)
    assert "Traceback" not in capfd.readouterr().err


def test_sigint_sent_to_the_worker_itself_is_ignored_from_its_start(recording, tmp_path, capfd, monkeypatch):
    """Ctrl-C never reaches it (its own process group); a SIGINT sent to its pid does nothing either."""
    import signal
    import time

    from recording.report import worker as worker_module

    def fallback(*args, **kwargs):
        raise AssertionError("the worker died: the report was rendered in process")

    monkeypatch.setattr(worker_module, "render_report", fallback)
    target = fresh_copy(recording, tmp_path)
    worker = ReportWorker()
    worker.start()
    assert worker.process is not None and os.getpgid(worker.process.pid) == worker.process.pid
    for _ in range(10):  # during its interpreter start and its imports
        worker.process.send_signal(signal.SIGINT)
        time.sleep(0.05)
    pid = worker.process.pid
    report = worker.render(target)
    assert report.errors == {} and set(report.files) == set(ARTIFACTS)
    err = capfd.readouterr().err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)  # it answered and left
