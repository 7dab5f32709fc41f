"""The numbers of `objective eval` (evaluation.stats, evaluation.progress): pure functions."""
from __future__ import annotations

import pytest

from evaluation.episode import EpisodeRecord, EpisodeStatus
from evaluation.progress import eta_seconds, progress_text
from evaluation.stats import percentiles, summarise, wilson_interval


def test_wilson_interval_matches_the_published_values():
    # Newcombe (1998), Statistics in Medicine 17: 81/263 -> 0.2553 to 0.3662; 0/10 -> 0 to 0.2775.
    low, high = wilson_interval(81, 263)
    assert (round(low, 4), round(high, 4)) == (0.2553, 0.3662)
    low, high = wilson_interval(0, 10)
    assert low == 0.0 and round(high, 4) == 0.2775
    low, high = wilson_interval(10, 10)
    assert round(low, 4) == 0.7225 and high == 1.0
    assert wilson_interval(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError, match="within 0..3"):
        wilson_interval(4, 3)


def record(seed: int, status: str, reason: str = "", node: str | None = None, stall: float = 0.0,
           kind: str | None = None) -> EpisodeRecord:
    return EpisodeRecord(seed=seed, status=EpisodeStatus(status), reason=reason, failing_node=node, failure_kind=kind,
                         sim_seconds=30.0 + seed,
                         run={"execute_policy": {"stall_seconds": stall, "latency_p95_s": 0.1}, "world": {"peak_force_n": 10.0 * seed}})


def test_summary_counts_groups_and_percentiles():
    records = [
        record(0, "SUCCESS", stall=0.0),
        record(1, "FAILURE", "chunk 6 rejected: 5.3 rad/s²", "ExecutePolicy", stall=1.0, kind="acceleration limit"),
        record(2, "FAILURE", "chunk 9 rejected: 6.1 rad/s²", "ExecutePolicy", stall=2.0, kind="acceleration limit"),
        record(3, "FAILURE", "cube 0.02 m off", "top cube on bottom cube", stall=3.0),
        EpisodeRecord.error(4, "its worker died (signal SIGABRT); 2 attempts, each lost its worker"),
    ]
    summary = summarise(records, requested=6)
    assert (summary["episodes"], summary["successes"], summary["failures"], summary["errors"]) == (5, 1, 3, 1)
    assert summary["success_rate"] == 0.2 and not summary["complete"]
    assert summary["success_rate_ci95"] == [round(v, 6) for v in wilson_interval(1, 5)]
    top = summary["failure_groups"][0]
    assert (top["count"], top["failing_node"], top["seeds"], top["reason"]) == (2, "ExecutePolicy", [1, 2], "acceleration limit")
    assert top["example"] == "chunk 6 rejected: 5.3 rad/s²"
    assert [g["status"] for g in summary["failure_groups"]].count("ERROR") == 1
    stall = summary["percentiles"]["stall_seconds"]
    assert (stall["p50"], stall["max"], stall["n"]) == (1.5, 3.0, 4)  # the ERROR episode reports nothing
    assert summary["percentiles"]["peak_force"]["from"] == "world.peak_force_n"
    assert summary["percentiles"]["episode_sim_seconds"]["min"] == 30.0


def test_percentiles_interpolate_and_ignore_empty_input():
    assert percentiles([]) is None
    p = percentiles([1, 2, 3, 4])
    assert (p["p50"], p["p90"], p["min"], p["max"]) == (2.5, 3.7, 1.0, 4.0)


def test_progress_line_shows_successes_and_eta():
    assert eta_seconds(0, 10, 5.0) is None
    assert eta_seconds(2, 10, 10.0) == 40.0
    text = progress_text(5, 10, 4, 1, 65.0)
    assert "5/10 episodes, 4 successes (80%), 1 errors, ETA 01:05" in text
    assert text.startswith("[############............]")
