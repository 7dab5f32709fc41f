"""A recording to a disk that fills up: the run goes on to its own end, the recording stops where
the disk filled and is marked incomplete with the reason, in the run's summary and for
`objective report` (never "the run was killed").

The disk is a real filesystem: a tmpfs of a few hundred KiB mounted for the test (as root), which
the cube-stacking recording (about 1 MB of `run.mcap`) fills at the start, in the middle or near
the end. Where mounting is not allowed, the same run is recorded with every write past a point
failing with ENOSPC at the writer (this process writing the recording).
"""
from __future__ import annotations

import errno
import json
import os
import subprocess
from pathlib import Path

import pytest

from evaluation.config import RecordMode, WorkerSpec
from evaluation.episode import EpisodeStatus
from evaluation.policies import parse_policy
from evaluation.worker import EpisodeWorker
from runtime.app.cli import main
from recording.mcap_writer import McapRos2Writer
from recording.report.worker import ReportWorker

ROOT = Path(__file__).resolve().parent.parent
STACK = ROOT / "objectives" / "stack_cubes.xml"
ENOSPC_TEXT = "No space left on device (ENOSPC) writing "


@pytest.fixture
def small_disk(tmp_path):
    """Mount a tmpfs of ``size`` at a fresh directory; unmounted after the test."""
    mounted: list[Path] = []

    def mount(size: str) -> Path:
        if os.geteuid() != 0:
            pytest.skip("mounting a size-limited tmpfs needs root (the ENOSPC injection test runs anywhere)")
        where = tmp_path / f"disk-{size}"
        where.mkdir()
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                              capture_output=True, text=True, timeout=30)
        if done.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
        mounted.append(where)
        return where

    yield mount
    for where in mounted:
        subprocess.run(["umount", "-l", str(where)], capture_output=True, timeout=30)


def run_recorded(capsys, record: Path) -> tuple[int, dict, str]:
    code = main(["run", str(STACK), "--world", "kinematic", "--record", str(record), "--json"])
    out, err = capsys.readouterr()
    return code, json.loads(out.strip().splitlines()[-1]), err


def assert_recorded_incomplete(capsys, code: int, summary: dict, err: str, record: Path) -> None:
    """The run stacked the cubes; the recording says it is incomplete and why, everywhere."""
    assert code == 0, err
    assert summary["status"] == "SUCCESS" and summary["execute_policy"]["steps_executed"] == 300
    assert summary["stack_check"]["stacked"] is True
    assert ENOSPC_TEXT in summary["recording_incomplete"], summary.get("recording_incomplete")
    assert "the recording stops there, the run went on" in summary["recording_incomplete"]
    assert f"partial recording: the recording is incomplete: {ENOSPC_TEXT}" in err and "Traceback" not in err
    last = json.loads((record / "events.jsonl").read_text().splitlines()[-1])
    assert last["kind"] == "run_summary" and last["data"]["status"] == "SUCCESS"
    assert last["data"]["recording_incomplete"].startswith(ENOSPC_TEXT)
    assert main(["report", str(record)]) == 0
    report_err = capsys.readouterr().err
    assert f"partial recording: the recording is incomplete: {ENOSPC_TEXT}" in report_err
    assert "was killed" not in report_err and "Traceback" not in report_err


@pytest.mark.parametrize("size", ["300k", "700k", "1000k"])
def test_a_disk_that_fills_stops_the_recording_never_the_run(small_disk, capsys, size):
    """With the room kept for the summary (256 KiB), 300k fills at the first chunk, 700k in the
    middle of the run, 1000k near its end."""
    record = small_disk(size) / "rec"
    code, summary, err = run_recorded(capsys, record)
    assert_recorded_incomplete(capsys, code, summary, err, record)


def test_a_full_disk_under_this_process_writing_the_recording_stops_the_recording_never_the_run(
        tmp_path, capsys, monkeypatch):
    """No recording worker (it could not start): this process writes the recording, and from the
    2,000th message on every write fails as on a full disk."""
    monkeypatch.setattr(ReportWorker, "start", lambda self: None)
    write_cdr = McapRos2Writer.write_cdr
    written = [0]

    def fill_up(self, channel, data, log_time_ns):
        written[0] += 1
        if written[0] >= 2000:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        write_cdr(self, channel, data, log_time_ns)

    monkeypatch.setattr(McapRos2Writer, "write_cdr", fill_up)
    record = tmp_path / "rec"
    code, summary, err = run_recorded(capsys, record)
    assert_recorded_incomplete(capsys, code, summary, err, record)


def test_an_evaluated_episode_on_a_full_disk_keeps_its_outcome_and_notes_the_incomplete_recording(small_disk):
    spec = WorkerSpec(objective=STACK, world="kinematic", policy=parse_policy("oracle"), record=RecordMode.ALL)
    worker = EpisodeWorker(spec, "w", small_disk("700k") / "recordings")
    worker.warm_up()
    try:
        record = worker.run(0)
    finally:
        worker.close()
    assert record.status is EpisodeStatus.SUCCESS, record.reason
    assert record.recording == "recordings/seed-0"
    assert record.run["recording_incomplete"].startswith(f"the recording is incomplete: {ENOSPC_TEXT}")
