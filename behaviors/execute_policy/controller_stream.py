"""ExecutePolicy's side of the trajectory controller: the goal playing, its acknowledgement, and
the rollback of a goal that reached the controller after its seam.

``send`` is the one place a motion is sent: it builds the goal (``controller_link.trajectory_goal``;
for a JTC led by the motion already sent, ``controller_link.jtc_stream_points``) and keeps the
``states.Rollback`` to return to. ``watch`` follows the goal, and the goal it replaced until that
one's result comes, and says what their news means for the run: nothing, a problem that ends it
(an abort of either), or a rollback to plan the chunk again (``MAX_LATE_RETRIES`` times per
chunk); a goal the controller refuses as sent before any goal of the run has played (a controller
that is not active, other joints) is a ``SetupError``: the same goal would be refused again. The action client is built once (``ControllerLink``); ``reset`` starts a run.
"""
from __future__ import annotations

from typing import Any, Sequence

from control_msgs.action import FollowJointTrajectory
from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance as FollowTrajectory

from runtime.errors import SetupError
from runtime.io.bus import STATUS_ABORTED, STATUS_SUCCEEDED

from ..action_goal import Goal, GoalState
from ..controller_link import ControllerKind, ControllerLink, GoalTolerances, jtc_stream_points, trajectory_goal
from ..trajectory_goal import NOT_ACCEPTED, REFUSED_GOAL_CODES, trajectory_msg
from .config import PolicyRunConfig
from .timing import goal_takes_effect_s
from runtime.motion.samples import Samples
from .states import Rollback

MAX_LATE_RETRIES = 3
LATE_MARGIN_STEP_S = 0.05
"""What the first goal refused for arriving late adds to the delivery time seams are planned with;
each further refusal doubles the addition (50, 100, 200 ms), kept for the rest of the run: a link
that delivered late once (a robot whose clock runs ahead of the runtime's ``/clock``, a busy
transport) is planned for with room to spare."""
LATE_GOAL_CODES = (FollowTrajectory.Result.OLD_HEADER_TIMESTAMP, FollowTrajectory.Result.SEAM_AFTER_TRAJECTORY_END)
"""The controller's answers to a goal that reached it after its seam (decided by code, not text)."""
JTC_PREEMPTED_CODE = FollowJointTrajectory.Result.INVALID_GOAL
"""How a stock JTC ends the goal a newer one preempts (aborted, "Current goal preempted by new incoming action.")."""
GOAL_ACK_TIMEOUT_S = 5.0  # a controller that does not acknowledge a goal by then is gone


class ControllerStream:
    """The goals one ExecutePolicy node sends to the trajectory controller behind ``link``; a goal's
    stamp goes out ``stamp_offset_s`` after the run's time (``RunContext.stamp_offset_s``)."""

    def __init__(self, link: ControllerLink, stamp_offset_s: float = 0.0) -> None:
        self.link = link
        self.stamp_offset_s = stamp_offset_s
        self.reset()

    def reset(self) -> None:
        self.goal = Goal()
        self.replaced = Goal()
        """The goal that was playing when ``goal`` was sent, until its result comes: the
        controller may have aborted it (a force or a path limit) before the new goal arrived,
        and then plays the new goal from rest; that abort ends the run all the same."""
        self.rollback: Rollback | None = None  # kept until the controller accepts the seam
        self.played = False
        """Whether a goal of this run has played: replaced while playing, or finished."""
        self.late_retries = 0  # of the chunk being sent
        self.goal_latency_s = 0.0
        """The slowest send -> accepted of a controller goal so far: zero in process, a tick or
        more over ROS."""
        self.late_margin_s = 0.0
        """What late refusals added to the delivery time planned for (``LATE_MARGIN_STEP_S``)."""

    @property
    def planned_latency_s(self) -> float:
        """The goal delivery time seams are planned with: the slowest measured, plus ``late_margin_s``."""
        return self.goal_latency_s + self.late_margin_s

    def ready(self) -> bool:
        """Whether the controller's action server is up (a name served with another type is an ERROR)."""
        return self.link.ready()

    def new_chunk(self) -> None:
        """A new chunk arrived: it has its own ``MAX_LATE_RETRIES``."""
        self.late_retries = 0

    def send(self, config: PolicyRunConfig, joints: Sequence[str], samples: Samples, playing: Samples | None,
             rollback: Rollback, now_s: float, tick_period_s: float) -> None:
        """Send the motion ``samples`` (from the seam on, taking over at ``rollback.takes_over_s``)
        after ``playing``, the samples the controller was sent last; ``rollback``: what a goal
        refused for arriving late goes back to, kept until the controller accepts the seam."""
        self.rollback = rollback
        message = self._goal_message(config, joints, samples, playing, rollback.takes_over_s, now_s, tick_period_s)
        if self.goal.state is GoalState.PLAYING:
            self.replaced = self.goal
            self.played = True
        self.goal = Goal.send(self.link.client, message, now_s)

    def _goal_message(self, config: PolicyRunConfig, joints: Sequence[str], samples: Samples, playing: Samples | None,
                      seam_time_s: float, now_s: float, tick_period_s: float) -> Any:
        """The controller goal for ``samples`` (from the seam on): stamped at the seam for the
        admittance controller; for a JTC, led by the motion already sent from where the arm will
        be when the goal lands (``controller_link.jtc_stream_points``)."""
        stamp_s, seam_index = seam_time_s, None
        if self.link.kind is ControllerKind.JTC:
            lands_s = goal_takes_effect_s(now_s, tick_period_s, self.planned_latency_s)
            jtc = jtc_stream_points(playing, samples, lands_s)
            stamp_s, samples, seam_index = jtc.stamp_s, jtc.samples, jtc.seam_index
        trajectory = trajectory_msg(samples, joints, stamp_s, self.stamp_offset_s)
        if seam_index is not None:
            trajectory.points[seam_index].accelerations = []
        tolerances = GoalTolerances(config.goal_path_tolerance, max(0.5, 5 * config.dt), tuple(config.absolute_force_torque_threshold))
        assert self.link.kind is not None  # the link is ready
        return trajectory_goal(self.link.kind, trajectory, tolerances)

    def watch(self, now_s: float) -> str | Rollback | None:
        """Follow the goal: None (nothing that changes the run), the problem that ends the run,
        or the ``Rollback`` of a goal refused only for arriving after its seam; a ``SetupError``
        when the controller refuses a goal as sent (rejected; or, before any goal of the run
        played, ended with one of ``REFUSED_GOAL_CODES``)."""
        if self.replaced.state is not GoalState.NONE:  # a goal was replaced: its abort ends the run too
            aborted = self._watch_replaced()
            if aborted is not None:
                return aborted
        goal, name = self.goal, self.link.name
        if goal.state is GoalState.SENT:
            if not goal.send_future.done():
                if now_s - goal.sent_at_s > GOAL_ACK_TIMEOUT_S:
                    return f"the controller '{name}' did not acknowledge a goal within {GOAL_ACK_TIMEOUT_S:g} s"
                return None
            # arrival, not when we looked
            self.goal_latency_s = max(self.goal_latency_s, goal.send_future.ready_at - goal.sent_at_s)
        self.goal = goal.advance()
        if self.goal.state is GoalState.REJECTED:
            self.goal = Goal()  # nothing of it is playing
            why = " (a joint_trajectory_controller gives its reason only in its own log)" if self.link.kind is ControllerKind.JTC else ""
            raise SetupError(f"the controller '{name}' rejected the goal{why}: {NOT_ACCEPTED}")
        if self.goal.state is GoalState.ENDED and goal.state is not GoalState.ENDED:  # its result came now
            outcome = self.goal.outcome
            if outcome.status == STATUS_SUCCEEDED or outcome.result.error_code == FollowTrajectory.Result.SUPERSEDED:
                self.played = True
            elif not self.played and outcome.result.error_code in REFUSED_GOAL_CODES:
                raise SetupError(f"the controller '{name}' refused the goal: {outcome.result.error_string}: {NOT_ACCEPTED}")
            if outcome.status == STATUS_ABORTED or outcome.result.error_code not in (0,):
                if outcome.result.error_code == FollowTrajectory.Result.SUPERSEDED:
                    return None
                rollback = self._late_rollback(outcome.result)
                if rollback is not None:
                    return rollback
                return f"the controller aborted the motion: {outcome.result.error_string}"
            if outcome.status != STATUS_SUCCEEDED:
                return f"the controller ended the motion: {outcome.result.error_string}"
        return None

    def _watch_replaced(self) -> str | None:
        """The abort of the goal the newest one replaced, once its result comes (a goal the
        controller superseded ends cancelled; one that ran to its end succeeded)."""
        replaced = self.replaced = self.replaced.advance()
        if replaced.state is not GoalState.ENDED:
            return None
        self.replaced = Goal()
        outcome = replaced.outcome
        if outcome.status != STATUS_ABORTED or self._preempted(outcome.result):
            return None
        return f"the controller aborted the motion: {outcome.result.error_string}"

    def _preempted(self, result: Any) -> bool:
        """Whether an aborted goal ended only because a newer goal took over: a stock JTC aborts
        the goal it preempts with INVALID_GOAL (ros2_controllers #2422); the admittance controller
        ends it CANCELED with SUPERSEDED."""
        return self.link.kind is ControllerKind.JTC and result.error_code == JTC_PREEMPTED_CODE

    def _late_rollback(self, result: Any) -> Rollback | None:
        """A goal refused only because it reached the controller after its seam (a first goal on
        a new connection, a slow tick or a busy transport): the controller goes on with what it
        was playing, the previous window and its runout, or rest. The rollback goes back to what
        was sent before it (the goal still playing, if it is), to plan the same chunk again from
        there with the measured delivery time: it joins the runout, or starts from rest. At most
        ``MAX_LATE_RETRIES`` times per chunk; None when this refusal is not one to retry."""
        rollback = self.rollback
        if result.error_code not in LATE_GOAL_CODES or rollback is None or self.late_retries >= MAX_LATE_RETRIES:
            return None
        self.late_retries += 1
        self.late_margin_s = max(2 * self.late_margin_s, LATE_MARGIN_STEP_S)
        if rollback.goal.state is GoalState.PLAYING:  # still playing (or its result is waiting to be read)
            self.goal, self.replaced = rollback.goal, Goal()  # the replaced goal is the goal again
        return rollback

    def cancel(self) -> None:
        self.goal = self.goal.cancel()
        self.replaced = self.replaced.cancel()
