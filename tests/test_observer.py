"""Run observers (``runtime.app.observer``): what ``--record``/``--live`` attach to the runner through the
``objective.run_observers`` entry-point group, told how each run ended."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import pytest

import runtime.app.observer
from runtime.app.observer import RunObserver
from runtime.errors import ObjectiveError
from runtime.app.runner import RunOptions, run_file
from tests.data.nodes import make_registry

WAIT = '<root BTCPP_format="4"><BehaviorTree ID="W"><Wait seconds="0.05"/></BehaviorTree></root>'


@dataclass
class Watcher(RunObserver):
    """An observer that notes how the run ended."""

    told: list[tuple[str, Any]] = field(default_factory=list)

    def finished(self, result: Any, stop: Any) -> None:
        self.told.append(("finished", result.status))

    def aborted(self, error: BaseException, stop: Any) -> None:
        self.told.append(("aborted", str(error)))


@dataclass
class EntryPoint:
    name: str
    load: Any


def installed(monkeypatch, *points: EntryPoint) -> None:
    monkeypatch.setattr(runtime.app.observer, "entry_points", lambda group: list(points) if group == "objective.run_observers" else [])


@pytest.fixture
def wait_tree(tmp_path):
    path = tmp_path / "wait.xml"
    path.write_text(WAIT)
    return path


def test_an_observed_run_is_watched_from_start_to_result(monkeypatch, wait_tree, tmp_path):
    watcher, seen = Watcher(), []

    def attach(loaded, context, options):
        seen.append((loaded.tree_id, options.record_dir))
        return watcher

    installed(monkeypatch, EntryPoint("watch", lambda: attach))
    result = run_file(wait_tree, make_registry(), RunOptions(record_dir=tmp_path / "rec"))
    assert result.status == "SUCCESS"
    assert seen == [("W", tmp_path / "rec")] and watcher.told == [("finished", "SUCCESS")]


def test_a_plain_run_asks_no_observer(monkeypatch, wait_tree):
    installed(monkeypatch, EntryPoint("watch", lambda: pytest.fail("a run without --record/--live loaded an observer")))
    assert run_file(wait_tree, make_registry(), RunOptions()).status == "SUCCESS"


def test_a_run_that_cannot_start_is_told_to_the_observer(monkeypatch, tmp_path):
    watcher = Watcher()
    installed(monkeypatch, EntryPoint("watch", lambda: lambda loaded, context, options: watcher))
    path = tmp_path / "robot.xml"
    path.write_text('<root BTCPP_format="4"><BehaviorTree ID="R"><Robot/></BehaviorTree></root>')
    with pytest.raises(ObjectiveError, match="no world named 'nowhere'"):
        run_file(path, make_registry(), RunOptions(world="nowhere", live_port=0))
    [(what, reason)] = watcher.told
    assert what == "aborted" and reason.startswith("no world named 'nowhere' (worlds: ")


def test_no_installed_observer_is_bad_input_naming_the_extra(monkeypatch, wait_tree, tmp_path):
    installed(monkeypatch)
    with pytest.raises(ObjectiveError, match=r"^--record and --live need the recording package, which is not installed: "
                                             r"pip install 'objective-runtime\[record\]'$"):
        run_file(wait_tree, make_registry(), RunOptions(record_dir=tmp_path / "rec"))


def test_an_observer_whose_module_is_missing_names_the_extra(monkeypatch, wait_tree, tmp_path):
    def load():
        raise ModuleNotFoundError("No module named 'mcap'", name="mcap")

    installed(monkeypatch, EntryPoint("recording", load))
    with pytest.raises(ObjectiveError, match=r"^run observer 'recording': mcap is not installed: it comes with the "
                                             r"\[record\] extra, pip install 'objective-runtime\[record\]'$"):
        run_file(wait_tree, make_registry(), RunOptions(record_dir=tmp_path / "rec"))
