"""``benchmarks/bench_success_under_latency.py``: its rows from episode records, its delays, a
tiny run (two executors, two delays, one kinematic episode each) through ``objective eval``
with the benchmark executors' plug-in, down to the table, the JSON rows and the plot, and (slow)
a short run of every executor with the oracle."""
from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path

import pytest

from evaluation.episode import EpisodeRecord, EpisodeStatus
from evaluation.stats import wilson_interval

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def bench(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    return importlib.import_module("bench_success_under_latency")


def test_a_cells_row_counts_the_seeds_asked_for(bench):
    records = {
        100: EpisodeRecord(100, EpisodeStatus.SUCCESS, sim_seconds=30.0, run={"unsafe_points": {"count": 4, "probed": 3000}}),
        101: EpisodeRecord(101, EpisodeStatus.SUCCESS, sim_seconds=40.0, run={"unsafe_points": {"count": 0, "probed": 3000}}),
        102: EpisodeRecord(102, EpisodeStatus.FAILURE, reason="the blue cube is not on the green cube",
                           run={"unsafe_points": {"count": 7, "probed": 2000}}),
        103: EpisodeRecord(103, EpisodeStatus.ERROR, reason="its worker died"),
        104: EpisodeRecord(104, EpisodeStatus.SUCCESS, sim_seconds=31.0),
        200: EpisodeRecord(200, EpisodeStatus.SUCCESS, sim_seconds=1.0),  # another run's seed
    }
    cell = bench.Cell(bench.Executor.LEROBOT, "lognormal:0.5,0.5")
    row = bench.cell_row(cell, records, range(100, 106))
    low, high = wilson_interval(3, 5)
    assert row == {
        "bench": "success_under_latency", "executor": "lerobot", "label": "LeRobot queue", "delay": "lognormal:0.5,0.5",
        "delay_mean_s": 0.5, "episodes": 5, "requested": 6, "successes": 3, "rate": 0.6,
        "ci95_low": round(low, 4), "ci95_high": round(high, 4), "time_to_success_s": 31.0, "errors": 1,
        "unsafe_points": 11, "unsafe_episodes": 2,  # the ERROR never ran the probe: none
    }
    assert cell.folder == "lerobot/lognormal-0.5_0.5"
    empty = bench.cell_row(bench.Cell(bench.Executor.RTC, "2"), {}, range(100, 150))
    assert (empty["episodes"], empty["rate"], empty["ci95_low"], empty["ci95_high"], empty["time_to_success_s"]) == (0, None, 0.0, 1.0, None)


def test_a_checkpoint_is_titled_by_its_folder_and_low_rates_get_an_axis_of_their_own(bench):
    assert bench.policy_label("lerobot:/work/policies/tiny_smolvla") == "lerobot:tiny_smolvla"
    assert bench.policy_label("replay:build/demos/run.mcap") == "replay:run.mcap"
    assert [bench.policy_label(s) for s in ("oracle", "http://127.0.0.1:8000", "my_policy.py:make")] == [
        "oracle", "http://127.0.0.1:8000", "my_policy.py:make"]
    row = {"executor": "rtc", "delay": "0", "delay_mean_s": 0.0, "rate": 0.02, "ci95_low": 0.0035, "ci95_high": 0.105}
    assert bench.rate_axis([row]) == (-0.02, pytest.approx(0.126))
    assert bench.rate_axis([row, {**row, "rate": 0.5, "ci95_low": 0.37, "ci95_high": 0.63}]) == (-0.02, 1.02)


def test_delays_are_fixed_seconds_or_lognormal(bench):
    assert [bench.check_delay(d) for d in ("0", "0.2", "lognormal:0.5,0.25")] == ["0", "0.2", "lognormal:0.5,0.25"]
    assert bench.DEFAULT_DELAYS == ("0", "0.1", "0.2", "0.5", "1", "2", "lognormal:0.5,0.5")
    for bad in ("measured", "-1", "lognormal:0.5", "fast"):
        with pytest.raises(argparse.ArgumentTypeError, match="a delay is seconds >= 0 or lognormal:MEAN,SD"):
            bench.check_delay(bad)
    assert bench.delay_mean_s("lognormal:0.5,0.25") == 0.5 and bench.delay_mean_s("2") == 2.0


def test_a_tiny_run_prints_the_table_and_writes_the_rows_and_the_plot(bench, tmp_path, capsys):
    out, plot = tmp_path / "bench", tmp_path / "success.png"
    code = bench.main(["--policy", "oracle", "--episodes", "1", "--delays", "0", "1", "--executors", "rtc", "jtc_upsampling",
                       "--world", "kinematic", "--workers", "1", "--out", str(out), "--plot", str(plot)])
    assert code == 0
    stdout = capsys.readouterr().out
    rows = [json.loads(line) for line in (out / "rows.jsonl").read_text().splitlines()]
    assert [(r["executor"], r["delay"], r["episodes"]) for r in rows] == [("rtc", "0", 1), ("rtc", "1", 1),
                                                                          ("jtc_upsampling", "0", 1), ("jtc_upsampling", "1", 1)]
    assert all(r["successes"] == 1 and r["time_to_success_s"] > 25 for r in rows)  # the oracle stacks seed 100 each time
    assert [r["unsafe_points"] for r in rows[:2]] == [0, 0]  # ExecutePolicy sends no unsafe point
    assert "executor  delay  episodes  successes" in stdout and "unsafe_points  unsafe_episodes" in stdout
    assert [json.loads(line) for line in stdout.splitlines() if line.startswith("{")] == rows
    assert (out / "rtc" / "1" / "episodes.jsonl").is_file() and (out / "objectives" / "jtc_upsampling.xml").is_file()
    assert plot.read_bytes()[:4] == b"\x89PNG"


def test_an_evaluation_that_cannot_run_stops_the_bench_with_its_reason(bench, tmp_path, capsys):
    code = bench.main(["--policy", "replay:/no/such/file.npz", "--episodes", "1", "--delays", "0", "--executors", "sync",
                       "--world", "kinematic", "--out", str(tmp_path / "bench")])
    assert code == 2
    err = capsys.readouterr().err
    assert "objective eval of sync at delay 0 exited 2" in err and "/no/such/file.npz" in err


@pytest.mark.slow
@pytest.mark.timeout(1800)  # 14 cells of 2 kinematic episodes: about 10 min on 2 shared cores
def test_a_short_run_of_every_executor_with_the_oracle_prints_success_time_and_unsafe_points(bench, tmp_path, capsys):
    out = tmp_path / "bench"
    code = bench.main(["--policy", "oracle", "--episodes", "2", "--delays", "0", "1", "--world", "kinematic", "--out", str(out)])
    assert code == 0
    stdout = capsys.readouterr().out
    rows = [json.loads(line) for line in (out / "rows.jsonl").read_text().splitlines()]
    assert [(r["executor"], r["delay"]) for r in rows] == [(e.value, d) for e in bench.Executor for d in ("0", "1")]
    assert all(r["episodes"] == 2 and r["errors"] == 0 for r in rows)
    assert "time_to_success_s  errors  unsafe_points  unsafe_episodes" in stdout
    by_cell = {(r["executor"], r["delay"]): r for r in rows}
    for delay in ("0", "1"):  # ExecutePolicy, with and without RTC, and the synchronous executor send none
        assert [by_cell[(e, delay)]["unsafe_points"] for e in ("rtc", "no_rtc", "sync")] == [0, 0, 0]
        assert by_cell[("rtc", delay)]["successes"] == 2
