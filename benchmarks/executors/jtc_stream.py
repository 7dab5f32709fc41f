"""Knots streamed to the stock ``joint_trajectory_controller``, and the motion it will play.

The two queue-based executors (``ExecuteWithLeRobotQueue``, ``ExecuteNewestWinsOnJtc``) send
joint positions one policy step apart, with the knot velocities of the C2 cubic spline that runs
from the commanded state where the goal lands (position and velocity) through them and ends at
rest (close to what ros2_controllers' ``positions_upsampling`` computes from a positions-only
message, ``positions_upsampling``, which spans only the chunk's points; ``baselines.cubic_spline_velocities``).
A goal is stamped at the instant it is expected at the controller (``lands_s``), and the
controller merges it into the trajectory it plays at that instant (``allow_trajectory_replacement``,
ros2_controllers #2419), or installs it from rest when it holds. ``JtcStream.plan`` predicts that
motion with the controller's own merge (``sim.controllers.jtc_trajectory``) from the commanded
motion; ``send`` sends the goal and
makes the prediction the commanded motion. Only the newest goal is followed: one preempted by
the next ends aborted, as JTC ends it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from control_msgs.action import FollowJointTrajectory
from trajectory_msgs.msg import JointTrajectory

from behaviors.action_goal import Goal, GoalState
from behaviors.controller_link import ControllerKind, ControllerLink, GoalTolerances, trajectory_goal
from behaviors.execute_policy.failure import Failure, FailureKind
from behaviors.execute_policy.states import HeldChunk
from runtime.tree.behavior import Status
from runtime.io.bus import STATUS_SUCCEEDED
from runtime.io.timestamps import time_msg
from runtime.motion.trajectory_points import trajectory_points
from sim.controllers.jtc_trajectory import JtcPoints, JtcTrajectory, merge_at_arrival, replace_at_arrival

from benchmarks.baselines import cubic_spline_velocities

from .base import ChunkExecutor


RUNOUT_ACCELERATION_FRACTION = 0.5
"""The runout after the last knot slows down at this fraction of each joint's acceleration limit."""


def runout_knots(positions: np.ndarray, dt_s: float, deceleration: np.ndarray) -> np.ndarray:
    """Knots one step apart that carry on from the last two of ``positions`` and slow down at a
    constant ``deceleration`` (per joint, rad/s^2) to rest: empty when the knots end at rest.

    Without them the spline would stop the arm within one step at the last knot (0.1 rad/s in
    0.1 s is already 3-6 rad/s^2): the knots sent end in a runout, as ExecutePolicy's tail does,
    so that a stream that runs dry stops within the limits. A newer goal replaces the runout
    before it plays whenever the next chunk comes in time."""
    if len(positions) < 2 or dt_s <= 0:
        return np.empty((0, positions.shape[1]))
    velocity = (positions[-1] - positions[-2]) / dt_s
    steps = int(np.ceil(np.max(np.abs(velocity) / (deceleration * dt_s))))
    if steps < 1:
        return np.empty((0, positions.shape[1]))
    speeds = velocity[None, :] * (1.0 - np.arange(1, steps + 1)[:, None] / steps)  # to rest at the last
    previous = np.vstack([velocity[None, :], speeds[:-1]])
    return positions[-1] + np.cumsum(0.5 * (previous + speeds) * dt_s, axis=0)


@dataclass(frozen=True)
class JtcPlan:
    """Knots to send (absolute times) and the motion the controller will play from ``lands_s``."""

    lands_s: float
    times_s: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    motion: JtcTrajectory


class JtcStream:
    """The goals one executor sends to the JTC behind ``link`` (its kind checked at start-up)."""

    def __init__(self, link: ControllerLink, joints: tuple[str, ...], stamp_offset_s: float, tolerances: GoalTolerances,
                 runout_acceleration: np.ndarray) -> None:
        self.link, self.joints, self.stamp_offset_s, self.tolerances = link, joints, stamp_offset_s, tolerances
        self.runout_acceleration = runout_acceleration
        self.goal = Goal()
        self.motion: JtcTrajectory | None = None
        self.holding = True

    def start(self, now_s: float, position: np.ndarray) -> None:
        """The controller holds the arm at ``position``."""
        self.motion = JtcTrajectory.hold(now_s, position)
        self.holding = True

    def plan(self, lands_s: float, times_s: np.ndarray, positions: np.ndarray, runout: bool = True) -> JtcPlan:
        """The goal of the knots ``positions`` at ``times_s`` (all after ``lands_s``, one step
        apart), followed (``runout``) by their runout to rest (``runout_knots``)."""
        assert self.motion is not None, "start() first"
        before = self.motion.sample(lands_s)
        step_s = float(times_s[1] - times_s[0]) if len(times_s) > 1 else 0.0
        tail = runout_knots(positions, step_s, self.runout_acceleration) if runout else np.empty((0, positions.shape[1]))
        times_s = np.append(times_s, times_s[-1] + (times_s[1] - times_s[0]) * np.arange(1, len(tail) + 1)) if len(tail) else times_s
        positions = np.vstack([positions, tail]) if len(tail) else positions
        # The spline runs from the commanded state where the goal lands through the knots.
        velocities = cubic_spline_velocities(np.append(lands_s, times_s), np.vstack([before.position, positions]), before.velocity)[1:]
        points = JtcPoints.build(times_s - lands_s, positions, velocities)
        if self.holding:
            motion = replace_at_arrival(points, lands_s, lands_s, before)
        else:
            motion = merge_at_arrival(self.motion, points, lands_s, lands_s, before)
        return JtcPlan(lands_s, times_s, positions, velocities, motion)

    def send(self, plan: JtcPlan, now_s: float) -> None:
        trajectory = JointTrajectory(joint_names=list(self.joints))
        trajectory.header.stamp = time_msg(plan.lands_s + self.stamp_offset_s)
        trajectory.points = trajectory_points(plan.times_s - plan.lands_s, plan.positions, plan.velocities)
        self.goal = Goal.send(self.link.client, trajectory_goal(ControllerKind.JTC, trajectory, self.tolerances), now_s)
        self.motion, self.holding = plan.motion, False

    def follow(self, now_s: float) -> str | None:
        """The problem with the newest goal, or None; once it has finished the controller holds."""
        self.goal = self.goal.advance()
        if self.goal.state is GoalState.REJECTED:
            self.goal = Goal()
            return f"the controller '{self.link.name}' rejected the goal (a joint_trajectory_controller gives its reason only in its own log)"
        if self.goal.state is GoalState.ENDED and not self.holding:
            outcome = self.goal.outcome
            if outcome.status != STATUS_SUCCEEDED or outcome.result.error_code != FollowJointTrajectory.Result.SUCCESSFUL:
                return f"the controller aborted the motion: {outcome.result.error_string}"
            assert self.motion is not None
            self.motion, self.holding = JtcTrajectory.hold(now_s, self.motion.points.positions[-1]), True
        return None

    @property
    def finished(self) -> bool:
        """The last goal sent has ended and the arm rests."""
        return self.goal.state is GoalState.ENDED and self.holding

    def cancel(self) -> None:
        self.goal = self.goal.cancel()


class KnotStream(Protocol):
    """What ``StreamsToJtc`` follows every tick: a ``JtcStream``, or ``jtc_upsampling.UpsamplingTopic``."""

    def start(self, now_s: float, position: np.ndarray) -> None: ...

    def follow(self, now_s: float) -> str | None: ...

    @property
    def finished(self) -> bool: ...

    def cancel(self) -> None: ...


class StreamsToJtc(ChunkExecutor):
    """A benchmark executor that streams knots to the stock JTC through ``self.stream``: each
    tick follows the goal, hands an arrived chunk to ``take``, then does ``schedule``. ``runout``:
    the knots sent end in a runout to rest (``runout_knots``)."""

    runout = True

    def start_run(self, now: float) -> Status | None:
        link = self.session.controller_link
        if link.kind is not ControllerKind.JTC:
            raise self.session.setup_error(f"{self.xml_id} streams to a joint_trajectory_controller (control_msgs/FollowJointTrajectory); "
                                   f"controller_action_name '{self.config.controller_action_name}' is served by "
                                   f"{link.kind.label if link.kind else 'nothing'}")
        config = self.config
        tolerances = GoalTolerances(config.goal_path_tolerance, max(0.5, 5 * config.dt))
        self.stream: KnotStream = JtcStream(link, self.safety.group_joints, self.context.stamp_offset_s, tolerances,
                                RUNOUT_ACCELERATION_FRACTION * self.safety.limits.max_acceleration)
        self.stream.start(now, self.session.rest_position())
        self.session.request(now, new_episode=True)
        return None

    def take(self, received: HeldChunk, now: float) -> Status | None:
        """A chunk came: send what it changes."""
        raise NotImplementedError

    def schedule(self, now: float) -> Status | None:
        """After the chunks: play the control steps due, ask for the next chunk, or finish."""
        raise NotImplementedError

    def run_tick(self, now: float) -> Status | None:
        problem = self.stream.follow(now)
        if problem is not None:
            return self.session.fail(Failure(FailureKind.CONTROLLER, problem))
        if self.session.asking:
            received = self.session.receive(now)
            if isinstance(received, Status):
                return received
            status = self.take(received, now) if received is not None else None
            if status is not None:
                return status
        return self.schedule(now)

    def send_knots(self, lands_s: float, times_s: np.ndarray, arm: np.ndarray, gripper: np.ndarray | None) -> None:
        """Send the knots ``arm`` at ``times_s`` (landing at ``lands_s``) and the gripper targets,
        unchecked: a peer's home runs no ExecutePolicy checks (the benchmark's probe counts the
        unsafe points the controller commands)."""
        stream = self.stream
        assert isinstance(stream, JtcStream)  # the executors that send knots stream to the JTC's action
        stream.send(stream.plan(lands_s, times_s, arm, self.runout), self.context.clock.now())
        self.session.queue_gripper_at(times_s, gripper)
