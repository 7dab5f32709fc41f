"""The trajectory message and the admittance controller's goal built from sampled motion (the
one goal builder of every behavior that sends a trajectory), and how a behavior that sends one
trajectory goal follows it to its end."""
from __future__ import annotations

from collections.abc import Sequence

from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance as FollowTrajectory
from trajectory_msgs.msg import JointTrajectory

from runtime.behavior import Behavior, Status
from runtime.bus import STATUS_SUCCEEDED
from runtime.timestamps import time_msg
from runtime.trajectory_points import trajectory_points

from .action_goal import Goal, GoalState
from .execute_policy.shaping import Samples

GOAL_TIME_TOLERANCE_S = 1.0
"""The controller's default: how late a goal may finish."""


def trajectory_msg(samples: Samples, joints: Sequence[str], stamp_s: float = 0.0, stamp_offset_s: float = 0.0) -> JointTrajectory:
    """``samples`` as a trajectory stamped ``stamp_s`` (0: start now), each point at its sample
    time less the stamp: samples on the clock for a stamped trajectory, timed from its start for
    one that starts now. A stamp goes out in the controllers' time, ``stamp_offset_s`` later
    (``RunContext.stamp_offset_s``)."""
    msg = JointTrajectory(joint_names=list(joints))
    msg.header.stamp = time_msg(stamp_s + stamp_offset_s if stamp_s else 0.0)
    msg.points = trajectory_points(samples.times - stamp_s, samples.positions, samples.velocities, samples.accelerations)
    return msg


def admittance_goal(
    trajectory: JointTrajectory,
    path_tolerance_rad: float,
    goal_time_tolerance_s: float = GOAL_TIME_TOLERANCE_S,
    force_torque_threshold: Sequence[float] = (),
) -> FollowTrajectory.Goal:
    """A FollowJointTrajectoryWithAdmittance goal that plays ``trajectory``; the controller aborts
    beyond ``path_tolerance_rad`` of tracking error or the ``force_torque_threshold`` (empty: none)."""
    goal = FollowTrajectory.Goal()
    goal.joint_trajectory = trajectory
    goal.path_tolerance = float(path_tolerance_rad)
    goal.goal_time_tolerance = float(goal_time_tolerance_s)
    goal.absolute_force_torque_threshold = [float(v) for v in force_torque_threshold]
    return goal


class SendsTrajectoryGoal(Behavior):
    """A Behavior that sends one trajectory goal to the controller action ``action`` (kept in
    ``goal``) and succeeds when the controller finishes it."""

    action: str
    goal: Goal = Goal()

    def follow_goal(self, what: str) -> Status:
        """RUNNING while the controller plays the goal; SUCCESS when it finished ``what`` (the
        motion, the trajectory); FAILURE, saying why, when it refused or aborted it."""
        self.goal = self.goal.advance()
        if self.goal.state is GoalState.REJECTED:
            return self.fail(f"controller '{self.action}' rejected the {what}")
        if self.goal.state is not GoalState.ENDED:
            return Status.RUNNING
        outcome = self.goal.outcome
        if outcome.status != STATUS_SUCCEEDED:
            return self.fail(f"the controller aborted the {what}: {outcome.result.error_string}")
        return Status.SUCCESS

