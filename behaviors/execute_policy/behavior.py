"""The ExecutePolicy behavior: plays a policy session's chunks as one continuous, checked motion.

The policy session (``session.PolicySession``) runs the phases STARTUP (wait for the service, the
controller and gripper actions, every camera and the joint states; 5 s), WARMUP (one discarded
request, ``new_episode=true``, that seeds the latency estimate), STREAM, then DONE; it sends the
requests, reads the answers with the chunk contract, streams the gripper column, watches the
force-torque threshold and ends the run. ExecutePolicy is its player: in STREAM each tick follows
the controller goal, has the session watch the robot, then does what ``states.StreamState`` says:
send the next request when it is due, read an answered one, or plan a held chunk again. Its parts,
each with its own state:

- ``controller_stream.ControllerStream``: the goals sent to the trajectory controller (the
  admittance controller or a stock JTC, ``controller_link``) and the rollback of a late goal;
- ``scene_watch.SceneWatch``: the rest of the sent motion checked again when the scene changes.

``planner.plan_chunk`` decides (Planned / Wait / Failure), ``checks.PointChecks`` checks every
point, and only ``ControllerStream.send`` sends a motion to the controller. The bus clients are
built once (``setup``, or the first run when a name comes from the blackboard); each run starts
its state afresh (``initialise``: the session's ``SessionRun`` and this node's ``StreamRun``).
Halting the node cancels the controller goal: the controller brings the arm to a smooth stop.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from runtime.tree.behavior import Behavior, Status
from runtime.errors import PortError, SetupError

from . import config as cfg
from .config import ShapingConfig
from .checks import PointChecks
from .chunk import Chunk
from .controller_stream import ControllerStream
from .failure import Failure, FailureKind
from .metrics import POLICY_RUNS, RunMetrics, summarise_runs
from .at_rest import Arrival
from .planner import PlanInput, Planned, plan_chunk
from .scene_watch import SceneWatch
from .session import PolicySession, SessionRun
from .states import HeldChunk, Rollback, SentMotion, StreamState, stream_finished, stream_state
from .stream import StepGrid, stall_at_stop_s
from .timing import earliest_seam_step, frozen_prefix_steps, goal_takes_effect_s, next_request_step, prefetch_margin


@dataclass
class StreamRun:
    """ExecutePolicy's own state of one run (the session keeps the rest, ``SessionRun``)."""

    shaping: ShapingConfig
    scene_watch: SceneWatch
    sent_motion: SentMotion | None = None
    """What the controller has been sent: from the end of the warmup (the arm at rest)."""
    held: HeldChunk | None = None
    """A chunk read that waits to be planned (``StreamState.HOLDING``)."""


class ExecutePolicy(Behavior):
    """Stream a learned policy's action chunks as one continuous, checked motion.

    Every densified point is checked against joint position, velocity and acceleration limits,
    the Cartesian envelope (TCP speed, keep-in boxes, tool axis cone), self-collision and world
    collision (with link_padding) before it reaches the controller.
    SUCCESS after total_action_steps steps or when the policy answers NO_MORE_ACTIONS; FAILURE on
    ERROR/UNKNOWN, timeouts, malformed or unsafe chunks, and controller aborts (F/T, path).
    """

    ports = cfg.PORTS
    needs_world = True
    needs_heartbeat = True  # a deadman (``runtime.app.protective_stop``) watches it while it runs
    description = (
        "Run a learned policy served over GetActionChunk: chunks are smoothed, blended at seams, "
        "checked against limits and the planning scene, and streamed to the trajectory controller "
        "(MoveIt Pro's admittance controller or a stock joint_trajectory_controller)."
    )

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.session = PolicySession(self, self, POLICY_RUNS)
        self.controller: ControllerStream | None = None
        """The goals sent to the controller, on the session's controller link (built with it)."""
        self.run: StreamRun | None = None

    def check_literals(self) -> None:
        """The port combinations ``config.validate`` refuses (image_topics and image_names of
        different lengths, a gripper action without its joint, ...), at load time when written as literals."""
        bindings = [self.bindings[name] for name in cfg.COMBINED_PORTS]
        if any(b.key is not None for b in bindings):
            return  # known when the node runs: then a SetupError
        values = {b.info.name: tuple(b.literal) if isinstance(b.literal, list) else b.literal for b in bindings}
        try:
            cfg.validate(SimpleNamespace(**values))
        except cfg.ConfigError as err:
            raise PortError(str(err), self.location, self.xml_id) from None

    # -- lifecycle ---------------------------------------------------------------------------
    def setup(self, **kwargs: Any) -> None:
        """Build the bus links when the names are known before the run (literal ports); a name
        read from the blackboard is known when the node first runs."""
        import scipy.linalg  # noqa: F401  (the chunk fit's banded solver: loaded here, not in the first chunk's tick)
        self.session.setup()

    def initialise(self) -> None:
        """Start a run: the session's (config, limits, links) and this node's ``StreamRun``."""
        self.run = None
        self.session.begin()
        config, safety, link = self.session.config, self.session.safety, self.session.controller_link
        if self.controller is None or self.controller.link is not link:
            self.controller = ControllerStream(link, self.context.stamp_offset_s)
        self.controller.reset()
        self.run = StreamRun(
            shaping=ShapingConfig(config.dt, config.committed_action_steps, config.policy_tracking_weight,
                                  config.num_interpolation_points, safety.limits.max_acceleration),
            scene_watch=SceneWatch(safety, config.link_padding),
        )

    def update(self) -> Status:
        return self.session.update()

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID:
            self.session.halt()

    def run_summary(self) -> dict[str, Any]:
        """Every ExecutePolicy run of the Objective (``POLICY_RUNS``): totals and each run."""
        return {"execute_policy": summarise_runs(self.context.resources.get(POLICY_RUNS) or [])}

    # -- the session's player ----------------------------------------------------------------
    def begin_stream(self, now_s: float) -> Status | None:
        """The warmup answered: the arm rests where it is, and the first request goes out."""
        config = self.session.config
        self._run().sent_motion = SentMotion(StepGrid(now_s, config.dt, config.committed_action_steps, config.total_action_steps))
        self.session.request(now_s, new_episode=True, request_step=0, frozen=self._frozen())
        return None

    def cancel_motion(self) -> None:
        self._controller().cancel()
        self._run().held = None

    def stall_at_stop_s(self, now_s: float) -> float:
        return stall_at_stop_s(self._run().sent_motion, now_s)

    # -- STREAM ------------------------------------------------------------------------------
    def play(self, now: float) -> Status:
        """One STREAM tick: the controller, the robot watch, then what ``StreamState`` says."""
        session, run, controller = self.session, self._run(), self._controller()
        metrics, policy = session.metrics, session.policy
        status = self._watch_controller(controller, now)  # first: an abort the controller already made is the reason
        if status is not None:
            return status
        status = session.watch_robot(now)
        if status is not None:
            return status
        track_progress(metrics, self._sent_motion(), now)
        state = stream_state(run.held, policy.request)
        if state is StreamState.HOLDING:
            held, run.held = run.held, None
            assert held is not None
            status = self._plan_and_send(held, now)  # holds it again while it cannot join
        elif state is StreamState.AWAITING_CHUNK:
            status = self._receive(now)
        else:
            status = None
        if status is not None:
            return status
        sent = self._sent_motion()  # with the chunk sent in this tick, if one was
        if stream_state(run.held, policy.request) is StreamState.SCHEDULING:
            self._maybe_request(sent.grid, now)  # also in the tick a chunk was sent: its next request may be due already
        collision = run.scene_watch.check(self._rules(), sent.samples, now, session.gripper_position)
        if collision is not None:
            return session.fail(Failure(FailureKind.SCENE_CHANGED, f"the planning scene changed: {collision} in the remaining path; robot stopped"))
        if stream_finished(sent, policy.request, controller.goal):
            # The controller's success says it played every step sent, whatever this run's clock
            # reads (a robot's clock may run ahead of it).
            metrics.steps_executed = sent.grid.executed_until
            return session.stop(Status.SUCCESS, f"executed {sent.grid.total_steps} steps")
        return Status.RUNNING

    # -- requests and responses --------------------------------------------------------------
    def _frozen(self) -> int:
        session = self.session
        estimate_s = session.metrics.latency_estimate_s = session.policy.latency.seconds
        tick_s = self.context.tick_period_s
        return frozen_prefix_steps(estimate_s, session.config.dt, prefetch_margin(estimate_s, tick_s, self._controller().planned_latency_s))

    def _maybe_request(self, grid: StepGrid, now: float) -> None:
        """Send the next request once its step is due on ``grid`` (the sent motion's)."""
        if grid.remaining == 0:
            return
        frozen = self._frozen()
        step = next_request_step(grid, frozen, now)
        if step is not None:
            self.session.request(now, new_episode=False, request_step=step, frozen=frozen)

    def _receive(self, now: float) -> Status | None:
        held = self.session.receive(now)
        if held is None or isinstance(held, Status):
            return held
        self._controller().new_chunk()
        return self._plan_and_send(held, now)

    def _plan_and_send(self, held: HeldChunk, now: float) -> Status | None:
        """Plan ``held`` (``planner.plan_chunk``), then send the planned motion to the controller
        (from here it is the sent motion), hold the chunk, or end the run with its rejection."""
        session, run, before, controller = self.session, self._run(), self._sent_motion(), self._controller()
        config, safety, grid = session.config, session.safety, before.grid
        rest_position = session.rest_position() if before.motion is None else None
        plan = plan_chunk(PlanInput(
            sent=before,
            goal=controller.goal.state,
            chunk=held.chunk,
            index=self._session_run().chunks_received,
            request_step=held.flight.request_step,
            frozen=held.flight.frozen,
            earliest_seam_step=earliest_seam_step(grid, now, self.context.tick_period_s, controller.planned_latency_s),
            rest_position=rest_position,
            config=run.shaping,
            checks=PointChecks(safety, self._rules(), config.link_padding, session.gripper_position(), grid),
            arrival=Arrival(grid.step_at_or_after(held.flight.future.ready_at),  # arrival, not when we looked
                            goal_takes_effect_s(now, self.context.tick_period_s, controller.planned_latency_s)),
        ))
        if isinstance(plan, Failure):
            return session.fail(plan)
        if not isinstance(plan, Planned):  # Wait
            run.held = held
            return None
        window, samples = plan.window, plan.sent.samples
        assert samples is not None
        session.metrics.stall_seconds += plan.stall_s
        # Kept until the controller accepts the seam: a goal refused only for arriving late is
        # planned again from the same chunk (see _roll_back).
        rollback = Rollback(held, before, controller.goal, plan.stall_s, window.index, plan.takes_over_s)
        run.scene_watch.checked(session.gripper_position())  # what the samples were checked against
        controller.send(config, safety.group_joints, samples, before.samples, rollback, now, self.context.tick_period_s)
        run.sent_motion = plan.sent
        session.queue_gripper_window(held.chunk, window, plan.sent.grid)
        if config.policy_uses_real_time_chunking:  # read (and checked) when the answer came in
            session.policy.carry_over(held.policy_chunk, window.request_step, held.flight.anchor)
        self.context.events.emit(
            "chunk_executed",
            self.name,
            chunk=window.index,
            request_step=window.request_step,
            seam_step=window.seam_step,
            steps=window.steps,
            seam_time=plan.seam_time_s,
            takes_over_time=plan.takes_over_s,
            latency=session.metrics.latencies[-1],
            stall_s=plan.stall_s,
        )
        return None

    # -- controller --------------------------------------------------------------------------
    def _watch_controller(self, controller: ControllerStream, now: float) -> Status | None:
        try:
            news = controller.watch(now)
        except SetupError as err:  # a goal refused as sent: refused again on a retry
            raise self.session.setup_error(str(err)) from None
        self.session.metrics.goal_latency_max_s = controller.goal_latency_s
        if news is None:
            return None
        if isinstance(news, Rollback):
            self._roll_back(news)
            return None
        return self.session.fail(Failure(FailureKind.CONTROLLER, news))

    def _roll_back(self, rollback: Rollback) -> None:
        """A goal refused for reaching the controller after its seam: go back to the motion sent
        before it and plan the same chunk again from there (``ControllerStream.watch``)."""
        run = self._run()
        run.sent_motion = rollback.sent
        self.session.metrics.stall_seconds -= rollback.stall_s  # the chunk that takes over counts the stall up to its own seam
        self.context.events.emit("chunk_rolled_back", self.name, stall_s=rollback.stall_s)
        late = (f"chunk {rollback.chunk_index}'s goal reached the controller after t={rollback.takes_over_s:.2f} s, the moment "
                f"it was meant to take over, so the controller went on with what it was playing")
        margin = f" (goals are now given {1000 * self._controller().late_margin_s:.0f} ms more to reach the controller)"
        if run.held is not None:
            # A newer chunk arrived while this goal was unanswered: it takes over from what the
            # arm actually does, and the refused one is dropped.
            self.session.warn(f"{late}; the next chunk, already here, is planned from what the arm is doing{margin}")
            return
        run.held = rollback.held  # planned again next tick
        self.session.warn(f"{late}; the chunk is planned again from what the arm is doing{margin}")

    # -- endings -----------------------------------------------------------------------------
    def chunk_plot(self, chunk: Chunk, request_step: int) -> dict[str, Any]:
        """The chunk being rejected, on the clock, for the report to plot: ``joints``, ``times`` and
        ``positions`` (one row per step, from its request step)."""
        grid = self._sent_motion().grid
        return {"joints": list(self.session.safety.group_joints), "times": [grid.time(request_step + k) for k in range(chunk.steps)],
                "positions": np.asarray(chunk.arm, dtype=float).round(6).tolist()}

    # -- small helpers -----------------------------------------------------------------------
    def _run(self) -> StreamRun:
        assert self.run is not None, "initialise starts a run"
        return self.run

    def _session_run(self) -> SessionRun:
        assert self.session.run is not None, "initialise starts a run"
        return self.session.run

    def _rules(self) -> Any:
        """The run's collision rules, snapshotted at the end of the start-up."""
        return self._session_run().rules

    def _controller(self) -> ControllerStream:
        assert self.controller is not None, "initialise connects the links"
        return self.controller

    def _sent_motion(self) -> SentMotion:
        sent = self._run().sent_motion
        assert sent is not None, "the STREAM phase starts with a sent motion (the arm at rest)"
        return sent


def track_progress(metrics: RunMetrics, sent: SentMotion, now: float) -> None:
    """Count the steps the arm has played by ``now`` (none before the first chunk)."""
    if sent.motion is not None:
        metrics.steps_executed = max(metrics.steps_executed, sent.grid.steps_executed_by(now))


NODES = (ExecutePolicy,)
