"""The gripper column's goals and what their answers mean. Decisions are pure functions.

The chunk's gripper column is streamed to a ``control_msgs/GripperCommand`` action, one goal
per change of target. A chunk's column was checked against the gripper's limits on its own; where
it takes over from the previous chunk's at the seam, ``join_targets`` moves from the target in
effect toward it no faster than the gripper's velocity limit, as the arm's blend does. Every goal is followed until it ends: a goal the controller refuses, or
one it aborts short of its target without having stalled, ends the run. A goal that ends with
``stalled`` (the fingers stopped on an object: a grasp) is normal, whether the controller
reports it as succeeded or, like ros2_controllers' GripperActionController without
``allow_stalling``, as aborted. A goal preempted by the next one ends CANCELED: normal too.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from runtime.bus import STATUS_ABORTED, STATUS_CANCELED, STATUS_SUCCEEDED

from ..action_goal import Goal, GoalState


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
