"""The gripper column's goals and what their answers mean. Decisions are pure functions.

The chunk's gripper column is streamed to a ``control_msgs/GripperCommand`` action, one goal
per change of target. A chunk's column was checked against the gripper's limits on its own; where
it takes over from the previous chunk's at the seam, ``join_targets`` moves from the target in
effect toward it no faster than the gripper's velocity limit, as the arm's blend does. Every goal is followed until it ends: a goal the controller refuses, or
one it aborts short of its target without having stalled, ends the run. A goal that ends with
``stalled`` (the fingers stopped on an object: a grasp) is normal, whether the controller
reports it as succeeded or, like ros2_controllers' GripperActionController without
``allow_stalling``, as aborted. A goal preempted by the next one ends CANCELED: normal too.

``GripperStream`` holds one run's gripper schedule and goals: ``queue`` plans a window's targets
(``queue_at``: targets at given times),
``stream`` sends those that are due, ``follow`` reads the answers.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from runtime.io.bus import STATUS_ABORTED, STATUS_CANCELED, STATUS_SUCCEEDED

from ..action_goal import Goal, GoalState
from ..gripper import gripper_command
from .chunk import Chunk
from .stream import StepGrid, Window

GRIPPER_MAX_EFFORT_N = 60.0  # the 2F-85 holds a 30 mm cube well below its 235 N maximum
GRIPPER_DEADBAND_RAD = 0.01  # of the driver joint: smaller changes are not re-sent


def join_targets(before: float | None, targets: list[float], max_step_rad: float) -> list[float]:
    """``targets`` (one per step) taken over from ``before`` (the target one step earlier; None:
    nothing streamed yet) with no step larger than ``max_step_rad``: the first targets move toward
    the column at that rate until they meet it, then follow it."""
    joined, previous = [], before
    for target in targets:
        if previous is not None:
            target = min(max(target, previous - max_step_rad), previous + max_step_rad)
        joined.append(target)
        previous = target
    return joined


@dataclass
class GripperGoal:
    """A goal sent to the gripper action: its target, and what is known of it."""

    target: float
    goal: Goal


def refused(action_name: str, target: float) -> str:
    return f"the gripper controller '{action_name}' refused the goal to {target:.4f} rad"


def result_problem(action_name: str, target: float, status: int, result: Any) -> str | None:
    """Why a finished gripper goal ends the run, or None when it ended normally."""
    if status in (STATUS_SUCCEEDED, STATUS_CANCELED) or (status == STATUS_ABORTED and result.stalled):
        return None
    how = "aborted" if status == STATUS_ABORTED else f"ended (status {status})"
    return (f"the gripper controller '{action_name}' {how} the goal to {target:.4f} rad with the fingers at "
            f"{result.position:.4f} rad, not stalled on an object")


def follow_goals(goals: list[GripperGoal], action_name: str) -> str | None:
    """Read the answers that have come in (and drop the goals that are over); return the first
    problem, or None. Goals still waiting for an answer stay in ``goals``."""
    for sent in list(goals):
        sent.goal = sent.goal.advance()
        if sent.goal.state is GoalState.REJECTED:
            return refused(action_name, sent.target)
        if sent.goal.state is GoalState.ENDED:
            goals.remove(sent)
            outcome = sent.goal.outcome
            problem = result_problem(action_name, sent.target, outcome.status, outcome.result)
            if problem is not None:
                return problem
    return None


class GripperStream:
    """The gripper column of the sent windows, streamed to the gripper action ``action_name``
    through ``client`` (built once); ``reset`` starts a run."""

    def __init__(self, client: Any, action_name: str) -> None:
        self.client, self.action_name = client, action_name
        self.reset()

    def reset(self) -> None:
        self.schedule: list[tuple[float, float]] = []  # (time, target), due in order
        self.plan: dict[int, float] = {}  # the last window's targets, by run step
        self.last_target: float | None = None  # the last target sent
        self.goals: list[GripperGoal] = []

    def ready(self) -> bool:
        return bool(self.client.server_is_ready())

    def queue(self, chunk: Chunk, window: Window, grid: StepGrid, max_velocity_rad_s: float) -> None:
        """Plan the targets of ``window`` (the arm plays the tail's extension too), taken over from
        the target in effect before its seam (``join_targets``)."""
        if chunk.gripper is None:
            return
        steps = range(window.seam_step, window.end_step + grid.tail.extension_steps)
        earlier = [s for s in self.plan if s < window.seam_step]  # the target in effect before the seam
        before = self.plan[max(earlier)] if earlier else self.last_target
        targets = join_targets(before, [float(chunk.gripper[s - window.request_step]) for s in steps], max_velocity_rad_s * grid.dt)
        self.plan = dict(zip(steps, targets))
        self.schedule = [(grid.time(s), target) for s, target in self.plan.items()]

    def queue_at(self, times_s: Any, targets: Any, max_step_rad: float) -> None:
        """Plan the targets ``targets[k]`` due at ``times_s[k]``, taken over from the target sent
        last with no step larger than ``max_step_rad`` (``join_targets``)."""
        joined = join_targets(self.last_target, [float(v) for v in targets], max_step_rad)
        self.schedule = list(zip((float(t) for t in times_s), joined))

    def stream(self, now_s: float) -> None:
        """Send the newest target due by ``now_s`` unless it is within ``GRIPPER_DEADBAND_RAD`` of the last one sent."""
        target = None
        while self.schedule and self.schedule[0][0] <= now_s + 1e-9:
            target = self.schedule.pop(0)[1]
        if target is None:
            return
        if self.last_target is not None and abs(target - self.last_target) < GRIPPER_DEADBAND_RAD:
            return
        self.goals.append(GripperGoal(target, Goal.send(self.client, gripper_command(target, GRIPPER_MAX_EFFORT_N), now_s)))
        self.last_target = target

    def follow(self) -> str | None:
        """The first problem in the answers that came (``follow_goals``), or None."""
        return follow_goals(self.goals, self.action_name) if self.goals else None

    def cancel(self) -> None:
        """Send nothing more (the goals sent play out)."""
        self.schedule = []
