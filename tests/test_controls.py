"""Control nodes, decorators, utility leaves and condition attributes, built in Python.

Each tree is made of our node classes bound to one run context, with scripted leaves whose
status per tick the test chooses; the assertions are the root status after every tick, which
leaves were halted (``terminate(INVALID)`` while RUNNING), and time read from the SimClock.
The XML-level comparison with BehaviorTree.CPP itself lives in tests/conformance/.
"""
from __future__ import annotations

import logging

import pytest

from runtime.tree import builtin, controls, decorators, utility
from runtime.tree.behavior import Behavior, RunContext, Status
from runtime.tree.blackboard import Blackboard
from runtime.io.bus import InProcessBus
from runtime.io.clock import SimClock
from runtime.tree.conditions import ConditionGuard, attach_conditions, unwrap
from runtime.tree.controls import tick_root
from runtime.errors import LoadError, ObjectiveError, PortError, SourceLocation
from runtime.tree.registry import Registry

R, S, F = Status.RUNNING, Status.SUCCESS, Status.FAILURE
SKIPPED = Status.INVALID


class Scripted(Behavior):
    """Returns the given statuses one per tick (the last one repeats) and records its lifecycle."""

    def __init__(self, name: str, statuses: list[Status]) -> None:
        super().__init__(name)
        self.statuses = list(statuses)
        self.ticks = 0
        self.starts = 0
        self.halts = 0
        self.finishes: list[Status] = []

    def initialise(self) -> None:
        self.starts += 1

    def update(self) -> Status:
        status = self.statuses[min(self.ticks, len(self.statuses) - 1)]
        self.ticks += 1
        return status

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID:
            if self.status is Status.RUNNING:
                self.halts += 1
        else:
            self.finishes.append(new_status)


@pytest.fixture
def clock() -> SimClock:
    return SimClock()


@pytest.fixture
def context(clock: SimClock) -> RunContext:
    from runtime.tree.events import EventLog

    return RunContext(clock=clock, bus=InProcessBus(clock), events=EventLog(clock))


@pytest.fixture
def board() -> Blackboard:
    return Blackboard()


@pytest.fixture
def make(context: RunContext, board: Blackboard):
    """make(cls, *children, name=..., **ports): a bound node with its children added."""

    def build(cls, *children, name: str | None = None, **ports):
        node = cls(name or cls.__name__)
        node.bind(context, board, {k: str(v) for k, v in ports.items()}, SourceLocation("test.xml", 7), cls.__name__)
        for child in children:
            node.add_child(child)
        return node

    return build


@pytest.fixture
def leaf(context: RunContext, board: Blackboard):
    def build(name: str, *statuses: Status) -> Scripted:
        node = Scripted(name, list(statuses))
        node.bind(context, board, {}, None, "Scripted")
        return node

    return build


def run(root, ticks: int, clock: SimClock | None = None, dt: float = 0.0) -> list[Status]:
    results = []
    for index in range(ticks):
        if index and clock is not None:
            clock.advance(dt)
        results.append(tick_root(root))
    return results


# -- sequences and fallbacks ----------------------------------------------------------------------
def test_sequence_resumes_the_running_child_and_restarts_after_failure(make, leaf) -> None:
    check = leaf("check", S)
    act = leaf("act", R, S, R, F)
    root = make(controls.Sequence, check, act)
    assert run(root, 4) == [R, S, R, F]
    assert check.ticks == 2  # not re-ticked while 'act' was running (ticks 2 and 4)
    assert act.halts == 0 and act.finishes == [S, F]


def test_sequence_with_memory_retries_the_failed_child(make, leaf, context) -> None:
    first, second = leaf("first", S), leaf("second", F, S)
    root = make(controls.SequenceWithMemory, first, second)
    assert run(root, 3) == [R, F, S]  # RUNNING after the synchronous first child: one child per tick
    assert first.ticks == 1 and second.ticks == 2


def test_fallback_returns_first_success(make, leaf) -> None:
    root = make(controls.Fallback, leaf("a", F), leaf("b", R, S), leaf("c", S))
    assert run(root, 2) == [R, S]
    assert root.children[2].ticks == 0


def test_reactive_sequence_halts_the_action_when_its_condition_flips(make, leaf) -> None:
    condition = leaf("cond", S, S, F)
    action = leaf("policy", R)
    root = make(controls.ReactiveSequence, condition, action)
    assert run(root, 3) == [R, R, F]
    assert action.halts == 1  # terminate(INVALID) while RUNNING: the robot is stopped
    assert action.status is Status.INVALID
    assert condition.halts == 0 and condition.ticks == 3


def test_reactive_fallback_stops_the_policy_once_the_check_passes(make, leaf) -> None:
    done = leaf("cubes_stacked", F, F, S)
    policy = leaf("policy", R)
    root = make(controls.ReactiveFallback, done, policy)
    assert run(root, 3) == [R, R, S]
    assert policy.halts == 1 and policy.starts == 1


def test_halting_the_root_terminates_every_running_descendant(make, leaf) -> None:
    finished, arm, gripper = leaf("finished", S), leaf("arm", R), leaf("gripper", R)
    root = make(controls.Sequence, finished, make(controls.Parallel, arm, gripper))
    assert tick_root(root) is R
    root.stop(Status.INVALID)
    assert (arm.halts, gripper.halts) == (1, 1)
    assert finished.halts == 0  # it had already finished: reset, not halted
    assert all(n.status is Status.INVALID for n in root.iterate())


# -- parallel -------------------------------------------------------------------------------------
def test_parallel_success_threshold_halts_the_rest(make, leaf) -> None:
    slow, fast = leaf("slow", R), leaf("fast", R, S)
    root = make(controls.Parallel, slow, fast, success_count=1)
    assert run(root, 2) == [R, S]
    assert slow.halts == 1


def test_parallel_with_more_required_successes_than_children_is_an_error(make, leaf) -> None:
    root = make(controls.Parallel, leaf("a", S), success_count=3)
    with pytest.raises(ObjectiveError, match=r"test.xml:7: Parallel 'Parallel': success_count=3 needs 3 children"):
        tick_root(root)


# -- conditionals ---------------------------------------------------------------------------------
def test_while_do_else_switches_branch_and_halts_the_other(make, leaf) -> None:
    condition, work, idle = leaf("c", S, F), leaf("work", R), leaf("idle", R)
    root = make(controls.WhileDoElse, condition, work, idle)
    assert run(root, 2) == [R, R]
    assert work.halts == 1 and idle.starts == 1


def test_if_then_else_with_a_skipped_condition_is_an_error_like_btcpp(make, leaf, board) -> None:
    condition = attach_conditions(leaf("c", S), {"_skipIf": "true"}, None)
    root = make(controls.IfThenElse, condition, leaf("a", S))
    with pytest.raises(ObjectiveError, match="condition \\(first child\\) was skipped"):
        tick_root(root)


def test_child_count_checks() -> None:
    assert controls.Sequence.check_children(0) == "a Sequence needs at least one child, got none"
    assert controls.IfThenElse.check_children(4) == "IfThenElse takes 2 or 3 children, got 4"
    assert decorators.Inverter.check_children(2) == "a decorator takes exactly one child, got 2"
    assert controls.WhileDoElse.check_children(2) is None


# -- decorators -----------------------------------------------------------------------------------
def test_inverter_and_force_nodes(make, leaf) -> None:
    assert run(make(decorators.Inverter, leaf("a", R, S)), 2) == [R, F]
    assert run(make(decorators.ForceSuccess, leaf("b", F)), 1) == [S]
    assert run(make(decorators.ForceFailure, leaf("c", S)), 1) == [F]


def test_repeat_runs_one_synchronous_cycle_per_tick(make, leaf) -> None:
    child = leaf("a", S)
    root = make(decorators.Repeat, child, num_cycles=3)
    assert run(root, 3) == [R, R, S]
    assert child.ticks == 3


def test_retry_gives_up_after_num_attempts(make, leaf, context) -> None:
    child = leaf("a", F)
    root = make(decorators.RetryUntilSuccessful, child, num_attempts=3)
    assert run(root, 3) == [R, R, F]
    assert child.ticks == 3


def test_keep_running_until_failure(make, leaf) -> None:
    root = make(decorators.KeepRunningUntilFailure, leaf("a", S, S, F))
    assert run(root, 3) == [R, R, F]


def test_run_once_skips_afterwards(make, leaf) -> None:
    child = leaf("a", R, S)
    root = make(decorators.RunOnce, child)
    assert run(root, 3) == [R, S, SKIPPED]
    assert root.skipped and child.ticks == 2
    again = make(decorators.RunOnce, leaf("b", F), then_skip="false")
    assert run(again, 3) == [F, F, F]
    assert again.child.ticks == 1


def test_timeout_halts_the_child_on_the_sim_clock(make, leaf, clock) -> None:
    arm, gripper = leaf("arm", R), leaf("gripper", R)
    root = make(decorators.Timeout, make(controls.Parallel, arm, gripper), msec=250)
    assert run(root, 4, clock, dt=0.1) == [R, R, R, F]  # t = 0, 0.1, 0.2, 0.3 s
    assert (arm.halts, gripper.halts) == (1, 1)
    assert arm.ticks == 3  # not ticked at t=0.3: it was halted instead
    assert root.feedback_message == "timed out after 250 ms"


def test_timeout_restarts_its_timer_for_the_next_run(make, leaf, clock) -> None:
    child = leaf("a", R, S, R, R, R)
    root = make(decorators.Timeout, child, msec=150)
    assert run(root, 5, clock, dt=0.1) == [R, S, R, R, F]  # second run starts at t=0.2


def test_delay_follows_the_sim_clock(make, leaf, clock) -> None:
    child = leaf("a", S)
    root = make(decorators.Delay, child, delay_msec=100)
    results = run(root, 12, clock, dt=0.01)
    assert results == [R] * 10 + [S, R]  # child ticked at t=0.10 (tolerant of float sums)
    assert child.ticks == 1


def test_decorator_halt_propagates(make, leaf) -> None:
    child = leaf("a", R)
    root = make(decorators.Repeat, make(decorators.Inverter, child), num_cycles=2)
    assert tick_root(root) is R
    root.stop(Status.INVALID)
    assert child.halts == 1


# -- utility leaves --------------------------------------------------------------------------------
def test_wait_runs_until_the_clock_passes(make, clock) -> None:
    node = make(utility.Wait, seconds=0.5)
    assert run(node, 7, clock, dt=0.1) == [R, R, R, R, R, S, R]


def test_wait_rejects_negative_seconds_at_load(make) -> None:
    with pytest.raises(PortError, match=r"test.xml:7: Wait: port 'seconds' must be in \[0, 4294967.295\] s, got -1.0"):
        make(utility.Wait, seconds=-1)


def test_sleep_zero_succeeds_at_once(make, clock) -> None:
    assert run(make(utility.Sleep, msec=0), 1) == [S]
    assert run(make(utility.Sleep, msec=20), 3, clock, dt=0.01) == [R, R, S]


def test_log_message_logs_and_records_an_event(make, context, caplog) -> None:
    node = make(utility.LogMessage, name="say", message="cubes stacked", log_level="warn")
    with caplog.at_level(logging.DEBUG, logger="objective"):
        assert tick_root(node) is S
    assert [(r.levelname, r.getMessage()) for r in caplog.records] == [("WARNING", "cubes stacked")]
    (event,) = context.events.of_kind("log")
    assert (event.source, event.data) == ("say", {"level": "warning", "message": "cubes stacked"})


def test_log_message_rejects_an_unknown_level_at_load(make) -> None:
    with pytest.raises(PortError, match="port 'log_level' must be one of debug, info, warn, error; got 'loud'"):
        make(utility.LogMessage, message="x", log_level="loud")
    with pytest.raises(PortError, match="port 'log_level' must be one of debug, info, warn, error; got 'warning'"):
        make(utility.LogMessage, message="x", log_level="warning")  # only the listed names


def test_always_success_and_failure(make) -> None:
    assert tick_root(make(utility.AlwaysSuccess)) is S
    assert tick_root(make(utility.AlwaysFailure)) is F


# -- pre/post conditions ---------------------------------------------------------------------------
def test_attach_without_conditions_returns_the_node(leaf) -> None:
    node = leaf("a", S)
    assert attach_conditions(node, {}, None) is node


def test_script_syntax_error_names_the_attribute(leaf) -> None:
    with pytest.raises(LoadError, match=r"x.xml:3: Scripted 'a': attribute '_skipIf': "):
        attach_conditions(leaf("a", S), {"_skipIf": "n ==="}, SourceLocation("x.xml", 3))


def test_unknown_condition_attribute_is_refused(leaf) -> None:
    with pytest.raises(LoadError, match="unknown condition attribute '_skipif'"):
        attach_conditions(leaf("a", S), {"_skipif": "true"}, None)


def test_skipped_children_in_a_sequence(make, leaf, board) -> None:
    board.set("n", 0)
    skipped = attach_conditions(leaf("a", S), {"_skipIf": "n == 0"}, None)
    root = make(controls.Sequence, skipped, leaf("b", S))
    assert tick_root(root) is S
    assert unwrap(skipped).ticks == 0
    all_skipped = make(controls.Sequence, attach_conditions(leaf("c", S), {"_skipIf": "true"}, None))
    assert tick_root(all_skipped) is SKIPPED and all_skipped.skipped


def test_while_halts_a_running_node_and_runs_on_halted(make, leaf, board) -> None:
    board.set("go", True)
    board.set("halted", 0)
    action = leaf("act", R)
    guarded = attach_conditions(action, {"_while": "go", "_onHalted": "halted := halted + 1"}, None)
    assert isinstance(guarded, ConditionGuard) and guarded.status is Status.INVALID
    root = make(controls.Sequence, guarded, leaf("next", S))
    assert tick_root(root) is R
    board.set("go", False)
    assert tick_root(root) is S  # the guarded node is skipped, the Sequence moves on
    assert action.halts == 1 and board.get("halted") == 1


def test_post_conditions_and_success_if(leaf, board) -> None:
    board.set("done", True)
    node = leaf("a", F)
    guarded = attach_conditions(node, {"_successIf": "done", "_onSuccess": "ok := 1", "_post": "post := 2"}, None)
    assert tick_root(guarded) is S
    assert node.ticks == 0 and board.get("ok") == 1 and board.get("post") == 2


def test_halting_a_guarded_running_node_runs_on_halted(make, leaf, board) -> None:
    board.set("h", 0)
    action = leaf("act", R)
    guarded = attach_conditions(action, {"_onHalted": "h := 5", "_post": "h := 9"}, None)
    root = make(controls.ReactiveSequence, leaf("cond", S, F), guarded)
    assert run(root, 2) == [R, F]
    assert action.halts == 1 and board.get("h") == 5


def test_condition_runtime_error_names_the_attribute(leaf) -> None:
    guarded = attach_conditions(leaf("a", S), {"_skipIf": "missing > 1"}, SourceLocation("x.xml", 9))
    with pytest.raises(ObjectiveError, match=r"x.xml:9: Scripted 'a': attribute '_skipIf'"):
        tick_root(guarded)


# -- registration ----------------------------------------------------------------------------------
def test_builtin_registers_every_node_with_a_description() -> None:
    registry = Registry()
    builtin.register(registry)
    ids = {
        "Sequence", "ReactiveSequence", "SequenceWithMemory", "Fallback", "ReactiveFallback", "Parallel",
        "ParallelAll", "IfThenElse", "WhileDoElse", "Inverter", "ForceSuccess", "ForceFailure",
        "RetryUntilSuccessful", "Repeat", "KeepRunningUntilFailure", "RunOnce", "Timeout", "Delay",
        "LogMessage", "Wait", "AlwaysSuccess", "AlwaysFailure", "Sleep",
    }
    assert ids <= {spec.id for spec in registry.specs()}
    for node_id in ids:
        assert len(registry.get(node_id).cls.description) > 20, node_id


def test_a_leaf_that_returns_no_status_is_reported_not_passed_on(make):
    """A leaf's update() that forgets its return: py_trees' rule (logged, taken as INVALID) and
    then ours (a tick must not return INVALID) name the node; its parent never sees a result."""
    leaf = Scripted("forgetful", [None])  # type: ignore[list-item]
    leaf.xml_id = "Scripted"
    root = make(controls.Sequence, leaf)
    with pytest.raises(ObjectiveError, match="returned INVALID from a tick: a node must return RUNNING, SUCCESS or FAILURE") as info:
        tick_root(root)
    assert "forgetful" in str(info.value)
    assert leaf.status is Status.INVALID and leaf.ticks == 1
