"""One action goal and what is known of it, for every behavior that sends goals (controller
trajectories, gripper commands). It knows nothing of the action's type: it holds the futures the
bus returns.

``GoalState``: NONE -> SENT -> PLAYING -> ENDED, or SENT -> REJECTED. ``Goal`` is immutable; each
transition returns a new one, so a behavior may keep the goal from before a send (ExecutePolicy
rolls back to it when the controller refuses a late goal).
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, replace
from typing import Any


class GoalState(enum.Enum):
    NONE = "none"  # no goal sent (or the last one was cancelled)
    SENT = "sent"  # on its way; the server has not accepted it yet
    PLAYING = "playing"  # accepted; its result has not come
    ENDED = "ended"  # the result came: ``Goal.outcome``
    REJECTED = "rejected"  # the server refused it


@dataclass(frozen=True)
class Goal:
    """The newest goal a behavior sent to one action server."""

    state: GoalState = GoalState.NONE
    send_future: Any = None  # SENT
    sent_at_s: float = 0.0
    handle: Any = None  # PLAYING
    result_future: Any = None  # PLAYING
    outcome: Any = None  # ENDED: the action's result, with ``status`` and ``result``

    @staticmethod
    def send(client: Any, message: Any, now_s: float = 0.0) -> Goal:
        """Send ``message`` through the action ``client``; the goal is SENT."""
        return Goal(GoalState.SENT, send_future=client.send_goal_async(message), sent_at_s=now_s)

    def accepted(self, handle: Any) -> Goal:
        return replace(self, state=GoalState.PLAYING, send_future=None, handle=handle, result_future=handle.get_result_async())

    def ended(self, outcome: Any) -> Goal:
        return Goal(GoalState.ENDED, sent_at_s=self.sent_at_s, outcome=outcome)

    def advance(self) -> Goal:
        """The goal after what the server has answered so far: a SENT goal is accepted (PLAYING)
        or REJECTED once the answer came, a PLAYING one ENDED once its result came."""
        goal = self
        if goal.state is GoalState.SENT and goal.send_future.done():
            handle = goal.send_future.result()
            if not handle.accepted:
                return Goal(GoalState.REJECTED, sent_at_s=goal.sent_at_s)
            goal = goal.accepted(handle)
        if goal.state is GoalState.PLAYING and goal.result_future.done():
            goal = goal.ended(goal.result_future.result())
        return goal

    def cancel(self) -> Goal:
        """Ask the server to cancel the goal if it may be playing it (it brings the motion to a
        smooth stop); a goal still on its way is cancelled as soon as the server accepts it.
        What is left is no goal."""
        if self.state is GoalState.PLAYING:
            self.handle.cancel_goal_async()
        elif self.state is GoalState.SENT:
            self.send_future.add_done_callback(_cancel_if_accepted)
        return Goal()


def _cancel_if_accepted(send_future: Any) -> None:
    if send_future.cancelled() or send_future.exception() is not None:
        return  # never reached the server: nothing plays
    handle = send_future.result()
    if handle.accepted:
        handle.cancel_goal_async()
