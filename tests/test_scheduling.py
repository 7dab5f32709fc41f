"""The tick thread's real-time priority (``runtime.io.scheduling``, ``--realtime-priority``)."""
from __future__ import annotations

import errno
import logging
import os

import pytest

from runtime.errors import ObjectiveError
from runtime.app.runner import RunOptions
from runtime.io.scheduling import realtime_priority


def test_no_priority_leaves_the_thread_as_it_is():
    before = os.sched_getscheduler(0)
    with realtime_priority(None) as scheduling:
        assert scheduling == "default"
        assert os.sched_getscheduler(0) == before


@pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO needs root (or an rtprio limit) here")
def test_the_thread_ticks_at_fifo_priority_inside_and_goes_back_after():
    before = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
    with realtime_priority(50) as scheduling:
        assert scheduling == "SCHED_FIFO 50"
        assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == (os.SCHED_FIFO, 50)
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before


def test_a_refused_priority_is_one_warning_and_the_run_goes_on(monkeypatch, caplog):
    def refuse(pid, policy, param):
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with caplog.at_level(logging.WARNING, logger="objective.scheduling"):
        with realtime_priority(50) as scheduling:
            assert scheduling == "default (SCHED_FIFO 50 refused: Operation not permitted)"
    assert len(caplog.records) == 1
    assert "could not tick at real-time priority 50 (SCHED_FIFO): Operation not permitted" in caplog.text
    assert "rtprio" in caplog.text  # says how to set the machine up


@pytest.mark.parametrize("priority", [0, 100, -1, True, 2.5])
def test_a_priority_outside_1_to_99_is_refused(priority):
    with pytest.raises(ValueError, match="integer from 1 to 99"):
        with realtime_priority(priority):
            pass


@pytest.mark.parametrize("options, message", [
    (RunOptions(realtime_priority=50), "needs --realtime or --ros"),
    (RunOptions(realtime=True, realtime_priority=0), "--realtime-priority: a real-time priority must be an integer from 1 to 99, got 0"),
])
def test_run_options_name_a_priority_that_cannot_work(options, message):
    with pytest.raises(ObjectiveError, match=message):
        options.check()


@pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO needs root (or an rtprio limit) here")
def test_a_paced_run_reports_what_its_ticks_ran_at(tmp_path, capsys):
    import json

    from runtime.app.cli import main

    tree = tmp_path / "wait.xml"
    tree.write_text('<root BTCPP_format="4"><BehaviorTree ID="Main"><Sleep msec="30"/></BehaviorTree></root>')
    before = os.sched_getscheduler(0)
    assert main(["run", str(tree), "--realtime", "--realtime-priority", "40", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert summary["pacing"]["scheduling"] == "SCHED_FIFO 40"
    assert os.sched_getscheduler(0) == before  # given back when the run ended
