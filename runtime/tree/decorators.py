"""Decorators with BehaviorTree.CPP v4 semantics (see ``runtime.tree.controls`` for the shared rules).

Time-based decorators (Timeout, Delay) read the run's clock, so under a ``SimClock`` they are
deterministic: a Timeout fires on the first tick at which ``msec`` have elapsed since it started,
halting its RUNNING child there (BT.CPP halts from a timer thread between ticks; the statuses the
tree sees are the same, the halt just lands on the tick). A Delay of 0 ms ticks its child in the
same tick (BT.CPP's zero-length timer fires asynchronously, usually a tick later).
"""
from __future__ import annotations

from typing import ClassVar

from . import script as scripting
from .behavior import Status
from .controls import COMPLETED, SKIPPED, DecoratorNode, TickGenerator, halt_child
from runtime.errors import LoadError, ScriptRunError
from .ports import INT32_MAX, UINT32_MAX, InputPort, PortType, Range

STATUS_BY_NAME = {"SUCCESS": Status.SUCCESS, "FAILURE": Status.FAILURE, "RUNNING": Status.RUNNING, "SKIPPED": SKIPPED}
"""A NodeStatus port's value (its name) as the tick result it stands for."""

# SimClock time is a float sum of tick periods (0.01 * 10 == 0.09999999999999999), so a
# deadline compares with a tolerance far below any period a runner uses.
TIME_TOLERANCE_S = 1e-9


def elapsed(start: float, now: float, msec: float) -> bool:
    """True when ``msec`` milliseconds have passed from ``start`` to ``now``."""
    return now - start >= msec / 1000.0 - TIME_TOLERANCE_S


class Inverter(DecoratorNode):
    """BT.CPP ``InverterNode`` (src/decorators/inverter_node.cpp)."""

    description: ClassVar[str] = "Swaps its child's SUCCESS and FAILURE; RUNNING passes through."

    def run(self) -> TickGenerator:
        self.status = Status.RUNNING
        result = yield from self.tick_child(self.child)
        if result is Status.SUCCESS:
            halt_child(self.child)
            return Status.FAILURE
        if result is Status.FAILURE:
            halt_child(self.child)
            return Status.SUCCESS
        return result


class ForceSuccess(DecoratorNode):
    """BT.CPP ``ForceSuccessNode`` (include/behaviortree_cpp/decorators/force_success_node.h)."""

    description: ClassVar[str] = "Returns SUCCESS whenever its child finishes, whatever the child returned."

    def run(self) -> TickGenerator:
        self.status = Status.RUNNING
        result = yield from self.tick_child(self.child)
        if result in COMPLETED:
            halt_child(self.child)
            return Status.SUCCESS
        return result


class ForceFailure(DecoratorNode):
    """BT.CPP ``ForceFailureNode`` (include/behaviortree_cpp/decorators/force_failure_node.h)."""

    description: ClassVar[str] = "Returns FAILURE whenever its child finishes, whatever the child returned."

    def run(self) -> TickGenerator:
        self.status = Status.RUNNING
        result = yield from self.tick_child(self.child)
        if result in COMPLETED:
            halt_child(self.child)
            return Status.FAILURE
        return result


class KeepRunningUntilFailure(DecoratorNode):
    """BT.CPP ``KeepRunningUntilFailureNode`` (keep_running_until_failure_node.h)."""

    description: ClassVar[str] = (
        "Restarts its child every time it succeeds and stays RUNNING; returns FAILURE when the child fails."
    )

    def run(self) -> TickGenerator:
        self.status = Status.RUNNING
        result = yield from self.tick_child(self.child)
        if result is Status.FAILURE:
            halt_child(self.child)
            return Status.FAILURE
        if result is Status.SUCCESS:
            halt_child(self.child)
        # BT.CPP returns its own status (RUNNING) for SUCCESS, RUNNING and a skipped child alike.
        return Status.RUNNING


class RetryUntilSuccessful(DecoratorNode):
    """BT.CPP ``RetryNode`` (src/decorators/retry_node.cpp)."""

    description: ClassVar[str] = (
        "Ticks its child again after each failure, up to num_attempts times in all (-1: forever); "
        "SUCCESS as soon as the child succeeds, FAILURE when the attempts are used up."
    )
    ports = (
        InputPort("num_attempts", PortType.INT, description="Attempts in all; -1 retries forever.", valid=Range(-1, INT32_MAX)),
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.tries = 0

    def run(self) -> TickGenerator:
        max_attempts = self.get_input("num_attempts")
        loop = self.tries < max_attempts or max_attempts == -1
        self.status = Status.RUNNING
        while loop:
            was_idle = self.child.status is Status.INVALID
            result = yield from self.tick_child(self.child)
            if result is Status.SUCCESS:
                self.tries = 0
                halt_child(self.child)
                return Status.SUCCESS
            if result is Status.RUNNING:
                return Status.RUNNING
            if result is SKIPPED:
                halt_child(self.child)
                return SKIPPED
            self.tries += 1
            max_attempts = self.get_input("num_attempts")  # BT.CPP re-reads it after a failure
            loop = self.tries < max_attempts or max_attempts == -1
            halt_child(self.child)
            if was_idle and loop:
                return Status.RUNNING  # one attempt per tick: the loop stays interruptible
        self.tries = 0
        return Status.FAILURE

    def halt(self) -> None:
        self.tries = 0
        super().halt()


class Repeat(DecoratorNode):
    """BT.CPP ``RepeatNode`` (src/decorators/repeat_node.cpp)."""

    description: ClassVar[str] = (
        "Ticks its child again after each success, num_cycles successes in all (-1: forever); "
        "FAILURE as soon as the child fails, SUCCESS after the last cycle."
    )
    ports = (
        InputPort("num_cycles", PortType.INT, description="Successful cycles in all; -1 repeats forever.", valid=Range(-1, INT32_MAX)),
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.cycles = 0

    def run(self) -> TickGenerator:
        num_cycles = self.get_input("num_cycles")
        loop = self.cycles < num_cycles or num_cycles == -1
        self.status = Status.RUNNING
        while loop:
            was_idle = self.child.status is Status.INVALID
            result = yield from self.tick_child(self.child)
            if result is Status.FAILURE:
                self.cycles = 0
                halt_child(self.child)
                return Status.FAILURE
            if result is Status.RUNNING:
                return Status.RUNNING
            if result is SKIPPED:
                halt_child(self.child)  # the counter is kept, as in BT.CPP
                return SKIPPED
            self.cycles += 1
            loop = self.cycles < num_cycles or num_cycles == -1
            halt_child(self.child)
            if was_idle and loop:
                return Status.RUNNING  # one attempt per tick: the loop stays interruptible
        self.cycles = 0
        return Status.SUCCESS

    def halt(self) -> None:
        self.cycles = 0
        super().halt()


class RunOnce(DecoratorNode):
    """BT.CPP ``RunOnceNode`` (include/behaviortree_cpp/decorators/run_once_node.h)."""

    description: ClassVar[str] = (
        "Runs its child to completion once; afterwards it is skipped (then_skip=true) or returns "
        "the child's first result again without ticking it (then_skip=false)."
    )
    ports = (
        InputPort("then_skip", PortType.BOOL, True, "Skip after the first run instead of repeating its result."),
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.done = False
        self.first_result = Status.INVALID

    def run(self) -> TickGenerator:
        skip = self.get_input("then_skip")
        if self.done:
            return SKIPPED if skip else self.first_result
        self.status = Status.RUNNING
        result = yield from self.tick_child(self.child)
        if result in COMPLETED:
            self.done = True
            self.first_result = result
            halt_child(self.child)
        return result


class Timeout(DecoratorNode):
    """BT.CPP ``TimeoutNode`` (src/decorators/timeout_node.cpp), on the run's clock."""

    description: ClassVar[str] = (
        "Halts its child and returns FAILURE if the child is still RUNNING msec milliseconds "
        "(of run-clock time) after the Timeout started; otherwise returns what the child returns."
    )
    ports = (
        InputPort("msec", PortType.UINT, description="Time limit in milliseconds (0: no limit).", valid=Range(0, UINT32_MAX, "ms")),
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.started_at: float | None = None

    def run(self) -> TickGenerator:
        msec = self.get_input("msec")
        now = self.context.clock.now()
        if self.started_at is None:
            self.started_at = now
            self.status = Status.RUNNING
        expired = msec > 0 and elapsed(self.started_at, now, msec)
        if expired and self.child.status is Status.RUNNING:
            self.feedback_message = f"timed out after {msec} ms"
            halt_child(self.child)
            self.started_at = None
            return Status.FAILURE
        result = yield from self.tick_child(self.child)
        if result in COMPLETED:
            self.started_at = None
            halt_child(self.child)
        return result

    def halt(self) -> None:
        self.started_at = None
        super().halt()


class Delay(DecoratorNode):
    """BT.CPP ``DelayNode`` (src/decorators/delay_node.cpp), on the run's clock."""

    description: ClassVar[str] = (
        "Returns RUNNING for delay_msec milliseconds of run-clock time, then ticks its child and "
        "returns what it returns."
    )
    ports = (
        InputPort("delay_msec", PortType.UINT, description="Wait before ticking the child, in milliseconds.", valid=Range(0, UINT32_MAX, "ms")),
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.started_at: float | None = None

    def run(self) -> TickGenerator:
        msec = self.get_input("delay_msec")
        now = self.context.clock.now()
        if self.started_at is None:
            self.started_at = now
            self.status = Status.RUNNING
        if not elapsed(self.started_at, now, msec):
            return Status.RUNNING
        result = yield from self.tick_child(self.child)
        if result in COMPLETED:
            self.started_at = None
            halt_child(self.child)
        return result

    def halt(self) -> None:
        self.started_at = None
        super().halt()


class Precondition(DecoratorNode):
    """BT.CPP ``PreconditionNode`` (include/behaviortree_cpp/decorators/script_precondition.h)."""

    description: ClassVar[str] = (
        "Ticks its child when the script in 'if' is true, else returns 'else' (FAILURE by "
        "default). Once the child is RUNNING the script is not checked again until it finishes."
    )
    ports = (
        InputPort("if", PortType.STRING, description="A script: the condition."),
        InputPort("else", PortType.NODE_STATUS, "FAILURE", "Status to return if the condition is false."),
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.child_running = False
        self.compiled: scripting.Script | None = None

    def check_literals(self) -> None:
        if self.bindings["if"].key is None:
            self.compiled = self._compile(self.bindings["if"].literal, LoadError)

    def _compile(self, source: str, error: type) -> scripting.Script:
        try:
            return scripting.compile_script(source)
        except scripting.ScriptError as err:
            what = f"port 'if': {err} in script {source!r}"
            if error is ScriptRunError:
                raise ScriptRunError(what, self.location, f"{self.xml_id} '{self.name}'", source) from None
            raise LoadError(what, self.location, self.xml_id) from None

    def _condition(self) -> bool:
        script = self.compiled
        source = self.get_input("if")
        if script is None or script.source != source:  # 'if' read from the blackboard
            script = self.compiled = self._compile(source, ScriptRunError)
        try:
            return scripting.evaluate_condition(script, self.blackboard)
        except scripting.ScriptError as err:
            raise ScriptRunError(
                f"port 'if': script {script.source!r}: {err}", self.location, f"{self.xml_id} '{self.name}'", script.source
            ) from None

    def run(self) -> TickGenerator:
        otherwise = STATUS_BY_NAME[self.get_input("else")]
        if not self.child_running:
            self.child_running = self._condition()
        if not self.child_running:
            return otherwise
        result = yield from self.tick_child(self.child)
        if result in COMPLETED:
            halt_child(self.child)
            self.child_running = False
        return result

    def halt(self) -> None:
        self.child_running = False  # not in BT.CPP 4.10, where a halted child keeps the flag set
        super().halt()


NODES = (
    Inverter,
    ForceSuccess,
    ForceFailure,
    KeepRunningUntilFailure,
    RetryUntilSuccessful,
    Repeat,
    RunOnce,
    Timeout,
    Delay,
    Precondition,
)
