"""The runner: ticks on the clock, statuses, the failing node, halting, worlds and summaries."""
from __future__ import annotations

import io
import signal
from pathlib import Path
from typing import Any

import pytest

from runtime.tree.behavior import Status
from runtime.errors import ObjectiveError
from runtime.io.interrupt import StopRequest
from runtime.tree.loader import load_tree
from runtime.app.display import ProgressLine
from runtime.app.observer import RunObserver
from runtime.app.runner import RunOptions, json_entries, make_context, run_file, run_tree
from tests.data.nodes import Forever, make_registry


class AfterTick(RunObserver):
    """Calls ``act(ticks so far)`` after every tick."""

    def __init__(self, act: Any) -> None:
        self.act, self.ticks = act, 0

    def ticked(self, now_s: float, visited: list) -> None:
        self.ticks += 1
        self.act(self.ticks)


class Notes(RunObserver):
    """Notes everything it is told."""

    def __init__(self) -> None:
        self.told: list[tuple[Any, ...]] = []

    def started(self, loaded) -> None:
        self.told.append(("started", loaded.tree_id))

    def ticked(self, now_s: float, visited: list) -> None:
        self.told.append(("ticked", round(now_s, 6), [node.name for node, _, _ in visited]))

    def finished(self, result, stop) -> None:
        self.told.append(("finished", result.status))

    def aborted(self, error: BaseException, stop) -> None:
        self.told.append(("aborted", str(error)))


@pytest.fixture(scope="module")
def registry():
    return make_registry()


@pytest.fixture
def run(registry, tmp_path):
    lib = tmp_path / "lib"
    lib.mkdir()

    def _run(body: str, options: RunOptions | None = None, world: Any = None, **kwargs):
        path = tmp_path / "tree.xml"
        path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="T">\n<BehaviorTree ID="T">\n{body}\n</BehaviorTree>\n</root>')
        options = options or RunOptions()
        context = make_context(options)
        loaded = load_tree(path, registry, context, objectives_dir=lib)
        return run_tree(loaded, context, options, world=world, **kwargs), loaded, context

    return _run


def test_wait_finishes_on_the_clock(run):
    # The first tick is at t = 0.01 s (the clock advances before each tick); Wait starts there
    # and succeeds on the tick where 0.5 s have passed: tick 51, t = 0.51 s.
    result, _, _ = run('<Wait seconds="0.5"/>')
    assert (result.status, result.ticks) == ("SUCCESS", 51)
    assert result.sim_seconds == pytest.approx(0.51)
    assert result.failing_node is None and result.reason == ""
    assert result.exit_code == 0


def test_tick_rate_sets_the_period(run):
    result, _, _ = run('<Wait seconds="0.5"/>', RunOptions(tick_hz=10))
    assert (result.ticks, round(result.sim_seconds, 6)) == (6, 0.6)


def test_failure_names_the_failing_leaf_and_its_reason(run):
    result, _, _ = run("""<Sequence>
  <AlwaysSuccess/>
  <FailWith name="grasp" reason="cube slipped"/>
  <AlwaysSuccess/>
</Sequence>""")
    assert (result.status, result.failing_node, result.reason, result.ticks) == ("FAILURE", "grasp", "cube slipped", 1)
    assert result.failing_location.endswith("tree.xml:5")
    assert result.exit_code == 1


def test_fallback_blames_the_last_child_it_tried(run):
    result, _, _ = run("""<Fallback>
  <FailWith name="first" reason="a"/>
  <FailWith name="second" reason="b"/>
</Fallback>""")
    assert (result.failing_node, result.reason) == ("second", "b")



def test_a_fallback_ending_in_always_failure_blames_the_check_that_failed_inside_it(run):
    """It blamed "AlwaysFailure ... no reason given"."""
    result, _, _ = run("""<Fallback>
  <Sequence><FailWith name="stack check" reason="not stacked"/></Sequence>
  <AlwaysFailure/>
</Fallback>""")
    assert (result.status, result.failing_node, result.reason) == ("FAILURE", "stack check", "not stacked")

def test_a_forgiven_failure_is_not_blamed(run):
    result, _, _ = run("""<Sequence>
  <ForceSuccess><FailWith name="forgiven" reason="no matter"/></ForceSuccess>
  <Inverter name="flip"><AlwaysSuccess/></Inverter>
</Sequence>""")
    assert (result.status, result.failing_node) == ("FAILURE", "flip")


def test_timeout_blames_the_timeout_node_and_halts_the_child(run):
    result, loaded, _ = run('<Timeout msec="200" name="deadline"><Forever name="slow"/></Timeout>')
    assert (result.status, result.failing_node) == ("FAILURE", "deadline")
    forever = next(n.node for n in loaded.nodes if isinstance(n.node, Forever))
    assert forever.terminated == [Status.INVALID]


def test_failure_in_a_subtree_names_the_leaf(run, tmp_path):
    result, _, _ = run('<Sequence><SubTree ID="Inner"/></Sequence>\n</BehaviorTree>\n<BehaviorTree ID="Inner">\n'
                       '<FailWith name="deep" reason="down here"/>')
    assert (result.failing_node, result.reason) == ("deep", "down here")


def test_max_seconds_stops_and_halts_the_running_node(run):
    result, loaded, _ = run('<Forever name="spin"/>', RunOptions(max_seconds=0.25))
    assert result.status == "FAILURE"
    assert result.ticks == 25 and result.sim_seconds == pytest.approx(0.25)
    assert result.failing_node == "spin"
    assert result.reason == "stopped after --max-seconds 0.25 s of clock time while 'spin' was RUNNING"
    assert loaded.root.terminated == [Status.INVALID]


def test_sets_fill_the_root_blackboard_and_the_summary_keeps_json_entries(run):
    result, _, _ = run('<Typed x="{x}" out="{y}"/>', RunOptions(sets={"x": "2.5", "note": "hi"}))
    assert result.status == "SUCCESS"
    assert result.blackboard == {"note": "hi", "x": "2.5", "y": 7.5}
    assert result.to_json()["blackboard"] == {"note": "hi", "x": "2.5", "y": 7.5}


def test_json_entries_keeps_what_json_can_carry():
    import numpy as np

    entries = json_entries([("a", 1), ("b", np.array([1.0, 2.0])), ("c", object()), ("d", float("nan")), ("e", "s")])
    assert entries == {"a": 1, "b": [1.0, 2.0], "e": "s"}


def test_runtime_port_errors_end_the_run_as_error_after_halting(run):
    result, loaded, _ = run('<Parallel><Forever/><Sequence><Wait seconds="0.02"/><Typed x="{missing}"/></Sequence></Parallel>')
    assert (result.status, result.exit_code, result.ticks) == ("ERROR", 2, 3)
    assert result.reason.endswith("Typed: port 'x' reads blackboard entry 'missing', which is not set")
    assert result.running_nodes == ["Forever", "Sequence"]  # the Sequence was ticking Typed
    forever = next(n for n in loaded.root.iterate() if n.name == "Forever")
    assert forever.terminated == [Status.INVALID]
    assert result.to_json()["status"] == "ERROR" and result.log_file is None


def test_blackboard_values_outside_a_port_range_are_an_error_when_read(run):
    result, _, _ = run('<Wait seconds="{s}"/>', RunOptions(sets={"s": "inf"}))
    assert result.status == "ERROR"
    assert result.reason.endswith("Wait: port 'seconds' (from '{s}') must be in [0, 4294967.295] s, got inf")


def test_an_unexpected_exception_names_the_node_and_logs_the_traceback(run, tmp_path):
    result, loaded, _ = run('<Parallel><Forever/><Crash name="probe" after="2"/></Parallel>',
                            RunOptions(log_dir=tmp_path / "logs"))
    assert (result.status, result.exit_code, result.ticks, result.failing_node) == ("ERROR", 2, 3, "probe")
    assert result.failing_location == f"{tmp_path / 'tree.xml'}:3"
    log = Path(result.log_file)
    assert log.parent == tmp_path / "logs" and "RuntimeError: sensor exploded" in log.read_text()
    assert "Traceback" in log.read_text()
    assert result.reason.startswith(f"{tmp_path / 'tree.xml'}:3: Crash 'probe': an unexpected RuntimeError in tests/data/nodes.py:")
    assert result.reason.endswith(f": sensor exploded. The run was stopped and its running nodes halted; "
                                  f"the full traceback is in {log} (a bug: please report it with that file)")
    forever = next(n for n in loaded.root.iterate() if n.name == "Forever")
    assert forever.terminated == [Status.INVALID]


def test_a_stop_request_halts_the_tree_as_a_preemption(run):
    stop = StopRequest()

    def act(ticks: int) -> None:
        if ticks == 5:
            stop.on_signal(signal.SIGTERM)

    result, loaded, context = run('<Sequence><Forever name="hold"/></Sequence>', observers=[AfterTick(act)], stop=stop)
    assert (result.status, result.exit_code, result.ticks, result.signum) == ("INTERRUPTED", 143, 5, signal.SIGTERM)
    assert result.running_nodes == ["hold"]
    assert result.reason == f"interrupted by SIGTERM at 0.05 s; halted 'hold' ({loaded.info(loaded.root.children[0]).location}) (RUNNING)"
    assert loaded.root.children[0].terminated == [Status.INVALID]
    summary = result.to_json()
    assert (summary["status"], summary["signal"], summary["running_nodes"]) == ("INTERRUPTED", "SIGTERM", ["hold"])
    halted = [e.data for e in context.events.of_kind("node_status") if e.source == "hold"]
    assert (halted[-1]["status"], halted[-1]["message"]) == ("INVALID", "halted")
    assert context.events.of_kind("run_finished")[-1].data == {"status": "INTERRUPTED"}


def test_a_second_signal_raises_at_once_and_the_run_still_ends_interrupted(run):
    stop = StopRequest()

    def act(ticks: int) -> None:
        if ticks == 2:
            stop.on_signal(signal.SIGINT)
            stop.on_signal(signal.SIGINT)  # raises Interrupted here, in the middle of the loop

    result, loaded, _ = run('<Forever name="hold"/>', observers=[AfterTick(act)], stop=stop)
    assert (result.status, result.exit_code, result.ticks) == ("INTERRUPTED", 130, 2)
    assert loaded.root.terminated == [Status.INVALID]


class FakeWorld:
    name = "fake"

    def __init__(self) -> None:
        self.calls: list[Any] = []

    def start(self, context) -> None:
        self.calls.append("start")

    def step_to(self, t: float) -> None:
        self.calls.append(round(t, 6))

    def reset(self, seed: int) -> None:
        pass

    def summary(self) -> dict[str, Any]:
        return {"cubes_stacked": 3}

    def close(self) -> None:
        self.calls.append("close")


def test_world_is_stepped_before_each_tick_and_summaries_are_merged(run):
    world = FakeWorld()
    result, loaded, context = run('<Sequence><Robot/><Wait seconds="0.02"/></Sequence>', world=world)
    assert result.status == "SUCCESS"
    assert world.calls == ["start", 0.01, 0.02, 0.03, "close"]
    assert context.world is world
    assert result.extra == {"robot": {"ticks": 1}, "world": {"cubes_stacked": 3}}
    summary = result.to_json()
    assert summary["robot"] == {"ticks": 1} and summary["world"] == {"cubes_stacked": 3}


def test_a_missing_world_is_a_clear_error(run):
    notes = Notes()
    with pytest.raises(ObjectiveError) as info:
        run("<Robot/>", RunOptions(world="no-such-world"), observers=[notes])
    assert str(info.value).startswith("no world named 'no-such-world' (worlds: ")
    assert notes.told == [("aborted", str(info.value))]


def test_trees_that_need_no_world_start_none(run):
    result, _, context = run("<AlwaysSuccess/>", RunOptions(world="no-such-world"))
    assert result.status == "SUCCESS" and context.world is None


def test_world_is_closed_when_a_tick_raises(run):
    world = FakeWorld()
    result, _, _ = run('<Sequence><Robot/><Typed x="{missing}"/></Sequence>', world=world)
    assert result.status == "ERROR" and world.calls[-1] == "close"


def test_bad_options_are_objective_errors():
    with pytest.raises(ObjectiveError, match="--policy-latency: latency 'soon'"):
        RunOptions(policy_latency="soon").check()
    with pytest.raises(ObjectiveError, match="--max-seconds must be positive"):
        RunOptions(max_seconds=0).check()


def test_runs_are_deterministic(registry, tmp_path):
    path = Path(__file__).parent / "data" / "subtrees.xml"
    results = [run_file(path, registry, RunOptions(), objectives_dir=tmp_path) for _ in range(2)]
    assert results[0].to_json() | {"wall_seconds": 0} == results[1].to_json() | {"wall_seconds": 0}
    assert results[0].blackboard["greeting"] == "hello world"


def test_observers_are_told_the_start_every_tick_and_the_end(run):
    notes = Notes()
    result, _, _ = run('<Wait name="pause" seconds="0.03"/>', observers=[notes])
    assert result.status == "SUCCESS"
    assert notes.told == [("started", "T"), *[("ticked", t, ["pause"]) for t in (0.01, 0.02, 0.03, 0.04)],
                          ("finished", "SUCCESS")]


def test_an_observer_is_told_of_an_exception_that_ends_the_run_abruptly(run):
    class Exits(Notes):
        def ticked(self, now_s: float, visited: list) -> None:
            raise SystemExit(7)

    world, notes = FakeWorld(), Exits()
    with pytest.raises(SystemExit):
        run('<Sequence><Robot/><Forever name="hold"/></Sequence>', world=world, observers=[notes])
    assert notes.told == [("started", "T"), ("aborted", "7")]
    assert world.calls[-1] == "close"  # halted and closed before it went on


def test_the_progress_line_shows_the_running_node(run):
    stream = io.StringIO()
    result, _, _ = run('<Wait name="pause" seconds="0.03"/>', observers=[ProgressLine(stream, rate_hz=1e9)])
    lines = stream.getvalue().split("\r")[1:]
    assert result.status == "SUCCESS" and len(lines) == 4
    assert lines[0] == "t=    0.01s  ticks=      1  running: pause"
    assert lines[3].rstrip() == "t=    0.04s  ticks=      4  running:"


@pytest.mark.parametrize("name, blackboard", [
    ("countdown.xml", {"count": 0, "trace": "T-3 2 1 "}),
    ("reactive_stop.xml", {"done": True, "halted": True}),
])
def test_shipped_pure_logic_examples_succeed(registry, tmp_path, name, blackboard):
    path = Path(__file__).resolve().parent.parent / "objectives" / "examples" / name
    result = run_file(path, registry, RunOptions(), objectives_dir=tmp_path)
    assert (result.status, result.blackboard) == ("SUCCESS", blackboard)


def test_a_signal_while_loading_ends_the_run_before_any_world_starts(run):
    stop = StopRequest()
    stop.on_signal(signal.SIGTERM)
    result, _, context = run("<Robot/>", RunOptions(world="no-such-world"), stop=stop)  # the world is never created
    assert (result.status, result.exit_code, result.ticks, result.running_nodes) == ("INTERRUPTED", 143, 0, [])
    assert result.reason == "interrupted by SIGTERM at 0.00 s" and context.world is None
