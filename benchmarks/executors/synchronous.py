"""``ExecuteChunksSynchronously``: stop, infer, execute the chunk's committed steps, repeat.

The arm rests while each request is in flight. Each chunk is planned by ExecutePolicy's own
planner (``planner.plan_chunk``) as a run of one window: the first chunk of a run, which starts
from rest, and its last window, which comes to rest at its end. So its steps 1 ..
``committed_action_steps`` (step 0 is the observed state) are smoothed, densified and checked
(``checks.PointChecks``) exactly as ExecutePolicy's are, and sent through ExecutePolicy's
``ControllerStream``. Once the controller has finished the goal (the arm at rest again) the next
request goes out; the run succeeds after ``total_action_steps`` steps. ``benchmarks/baselines.py``
``run_sync`` is the same executor as a pure stream simulation.
"""
from __future__ import annotations

import numpy as np

from behaviors.action_goal import GoalState
from behaviors.execute_policy.at_rest import Arrival
from behaviors.execute_policy.failure import Failure, FailureKind
from behaviors.execute_policy.checks import PointChecks
from behaviors.execute_policy.planner import PlanInput, Planned, plan_chunk
from behaviors.execute_policy.config import ShapingConfig
from behaviors.execute_policy.controller_stream import ControllerStream
from behaviors.execute_policy.states import HeldChunk, Rollback, SentMotion
from behaviors.execute_policy.stream import StepGrid
from behaviors.execute_policy.timing import earliest_seam_step, goal_takes_effect_s
from runtime.tree.behavior import Status

from .base import ChunkExecutor


class ExecuteChunksSynchronously(ChunkExecutor):
    """Benchmark executor: the arm rests while the policy infers, then executes the chunk's
    committed steps from rest to rest (ExecutePolicy's planner and checks), and asks again."""

    description = ("Benchmark executor (benchmarks/executors): stop, infer with the arm at rest, execute the chunk's "
                   "committed steps (planned and checked as ExecutePolicy does), repeat.")

    def start_run(self, now: float) -> Status | None:
        self.stream = ControllerStream(self.session.controller_link, self.context.stamp_offset_s)
        self.held: HeldChunk | None = None  # a chunk read, waiting for its plan to be sent
        self.window_steps = 0  # of the goal playing
        self.session.request(now, new_episode=True)
        return None

    def run_tick(self, now: float) -> Status | None:
        news = self.stream.watch(now)
        if isinstance(news, Rollback):  # the goal reached the controller after its seam: plan the chunk again
            self.held = news.held
            self.window_steps = 0
        elif news is not None:
            return self.session.fail(Failure(FailureKind.CONTROLLER, news))
        if self.session.asking:
            received = self.session.receive(now)
            if isinstance(received, Status):
                return received
            self.held = received
        if self.held is not None:
            return self._plan_and_send(self.held, now)
        if self.stream.goal.state is GoalState.ENDED and self.window_steps:
            self.metrics.steps_executed += self.window_steps
            self.window_steps = 0
            if self.metrics.steps_executed >= self.config.total_action_steps:
                return self.session.stop(Status.SUCCESS, f"executed {self.metrics.steps_executed} steps")
            self.session.request(now)
        return None

    def _plan_and_send(self, held: HeldChunk, now: float) -> Status | None:
        config, tick_s = self.config, self.context.tick_period_s
        remaining = config.total_action_steps - self.metrics.steps_executed
        grid = StepGrid(held.flight.sent_at_s, config.dt, config.committed_action_steps, min(config.committed_action_steps, remaining))
        shaping = ShapingConfig(config.dt, config.committed_action_steps, config.policy_tracking_weight,
                                config.num_interpolation_points, self.safety.limits.max_acceleration)
        assert self.session.run is not None  # a chunk came: the run has started
        plan = plan_chunk(PlanInput(
            sent=SentMotion(grid), goal=GoalState.NONE, chunk=held.chunk, index=held.index, request_step=0, frozen=0,
            earliest_seam_step=earliest_seam_step(grid, now, tick_s, self.stream.planned_latency_s),
            rest_position=self.session.rest_position(), config=shaping,
            checks=PointChecks(self.safety, self.session.run.rules, config.link_padding, self.session.gripper_position(), grid),
            arrival=Arrival(grid.step_at_or_after(held.flight.future.ready_at), goal_takes_effect_s(now, tick_s, self.stream.planned_latency_s)),
        ))
        if isinstance(plan, Failure):
            return self.session.fail(plan)
        if not isinstance(plan, Planned):
            return None  # waits for the controller's answer to the previous goal
        self.held = None
        samples = plan.sent.samples
        assert samples is not None
        rollback = Rollback(held, SentMotion(grid), self.stream.goal, 0.0, held.index, plan.takes_over_s)
        self.stream.new_chunk()
        self.stream.send(config, self.safety.group_joints, samples, None, rollback, now, tick_s)
        self.window_steps = plan.window.steps
        if held.chunk.gripper is not None:
            window, steps = plan.window, np.arange(plan.window.seam_step, plan.window.end_step + 1)
            self.session.queue_gripper_at(grid.time(0) + steps * config.dt, held.chunk.gripper[steps - window.request_step])
        return None
