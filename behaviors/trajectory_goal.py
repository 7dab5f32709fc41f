"""The trajectory message built from sampled motion (what every behavior that sends a trajectory
puts in its goal; ``controller_link.trajectory_goal`` wraps it in the goal of the controller's
type), and how a behavior that sends one trajectory goal follows it to its end."""
from __future__ import annotations

from collections.abc import Sequence

from control_msgs.action import FollowJointTrajectory
from trajectory_msgs.msg import JointTrajectory

from runtime.tree.behavior import Behavior, Status
from runtime.errors import SetupError
from runtime.io.bus import STATUS_SUCCEEDED
from runtime.io.timestamps import time_msg
from runtime.motion.trajectory_points import trajectory_points

from .action_goal import Goal, GoalState
from runtime.errors import ObjectiveError
from runtime.motion.samples import Samples

GOAL_TIME_TOLERANCE_S = 1.0
"""The controller's default: how late a goal may finish."""
REFUSED_GOAL_CODES = (FollowJointTrajectory.Result.INVALID_GOAL, FollowJointTrajectory.Result.INVALID_JOINTS)
"""Result codes of a goal the controller refused as sent (not running, other joints, a malformed
trajectory): the same goal is refused again, so the run ends as ERROR (the admittance controller
shares the codes)."""
DEFAULT_CONTROLLER = "/joint_trajectory_admittance_controller/follow_joint_trajectory"
NO_MOTION_S = 1e-6
"""Seconds below which a planned motion has no length: the arm is already at the goal, and
the motion is the goal alone (one point at time 0), which succeeds at once without a goal
to the controller (a controller refuses points that share one ``time_from_start``)."""
NOT_ACCEPTED = "is the controller active (a SwitchController before this node), and does it drive these joints?"



class PlanningError(ObjectiveError, ValueError):
    """No motion reaches the goal within the limits and the planning scene."""


def trajectory_msg(samples: Samples, joints: Sequence[str], stamp_s: float = 0.0, stamp_offset_s: float = 0.0) -> JointTrajectory:
    """``samples`` as a trajectory stamped ``stamp_s`` (0: start now), each point at its sample
    time less the stamp: samples on the clock for a stamped trajectory, timed from its start for
    one that starts now. A stamp goes out in the controllers' time, ``stamp_offset_s`` later
    (``RunContext.stamp_offset_s``)."""
    msg = JointTrajectory(joint_names=list(joints))
    msg.header.stamp = time_msg(stamp_s + stamp_offset_s if stamp_s else 0.0)
    msg.points = trajectory_points(samples.times - stamp_s, samples.positions, samples.velocities, samples.accelerations)
    return msg


class SendsTrajectoryGoal(Behavior):
    """A Behavior that sends one trajectory goal to the controller action ``action`` (kept in
    ``goal``) and succeeds when the controller finishes it."""

    action: str
    goal: Goal = Goal()

    def follow_goal(self, what: str) -> Status:
        """RUNNING while the controller plays the goal; SUCCESS when it finished ``what`` (the
        motion, the trajectory); FAILURE, saying why, when it aborted it; a ``SetupError`` when
        it refused it (rejected, or ``REFUSED_GOAL_CODES``)."""
        self.goal = self.goal.advance()
        if self.goal.state is GoalState.REJECTED:
            raise SetupError(f"controller '{self.action}' rejected the {what}: {NOT_ACCEPTED}")
        if self.goal.state is not GoalState.ENDED:
            return Status.RUNNING
        outcome = self.goal.outcome
        if outcome.status != STATUS_SUCCEEDED and outcome.result.error_code in REFUSED_GOAL_CODES:
            raise SetupError(f"controller '{self.action}' refused the {what}: {outcome.result.error_string}")
        if outcome.status != STATUS_SUCCEEDED:
            return self.fail(f"the controller aborted the {what}: {outcome.result.error_string}")
        return Status.SUCCESS

