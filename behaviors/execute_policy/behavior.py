"""The ExecutePolicy behavior: wires its parts to the run's phases and to the pure planner.

Phases (``states.Phase``): STARTUP (wait for the service, the controller and gripper actions,
every camera and the joint states; 5 s), WARMUP (one discarded request, ``new_episode=true``,
that seeds the latency estimate), STREAM, then DONE. The parts, each with its own state:

- ``policy_link.PolicyLink``: requests, the latency estimate, the real-time-chunking carryover and
  the stale-observation check;
- ``controller_stream.ControllerStream``: the goals sent to the trajectory controller (the
  admittance controller or a stock JTC, ``controller_link``) and the rollback of a late goal;
- ``scene_watch.SceneWatch``: the rest of the sent motion checked again when the scene changes;
- ``gripper.GripperStream``: the gripper column streamed to the gripper action.

In STREAM each tick follows the controller goal, streams the gripper column, then does what
``states.StreamState`` says: send the next request when it is due, read an answered one, or plan
a held chunk again. ``planner.plan_chunk`` decides (Planned / Wait / Failure), ``checks.PointChecks``
checks every point, and only ``ControllerStream.send`` sends a motion to the controller. The bus
clients are built once (``setup``, or the first run when a name comes from the blackboard); each
run resets the parts (``initialise``). Halting the node cancels the controller goal: the
controller brings the arm to a smooth stop.
"""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
from control_msgs.action import GripperCommand
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image, JointState

from runtime.tree.behavior import Behavior, Status
from runtime.errors import PortError, SetupError
from runtime.tree.ports import Direction
from runtime.app.terminal import bounded

from . import config as cfg
from ..controller_link import ControllerLink
from ..wrench_watch import WrenchWatch
from .checks import PointChecks
from .chunk import Chunk, ChunkError, period_problem, read_chunk, read_policy_chunk
from .controller_stream import ControllerStream
from .failure import Failure, FailureKind
from .gripper import GripperStream
from .metrics import POLICY_RUNS, RunMetrics, summarise_runs
from .observation import ObservationError, StaleObservation, robot_state
from .planner import (
    Arrival,
    PlanInput,
    Planned,
    ShapingConfig,
    earliest_seam_step,
    goal_takes_effect_s,
    next_request_step,
    plan_chunk,
    stall_at_stop_s,
)
from .policy_link import PolicyLink
from .scene_watch import SceneWatch
from .states import HeldChunk, Phase, Rollback, SentMotion, StreamState, stream_finished, stream_state
from .stream import StepGrid
from .timing import SizingRisk, frozen_prefix_steps, prefetch_margin, sizing_risk, sizing_warning
from ..safety import MotionSafety, SafetyError, make_safety

STARTUP_WAIT_S = 5.0
FIRST_CHUNK_GAP_RAD = 0.2
"""A first chunk whose step 0 is further than this from the arm (on any joint) is warned about."""


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
        self.phase = Phase.DONE  # until a run starts
        # The bus links, built once (``_connect``).
        self.connected_to: tuple[object, ...] | None = None
        self.policy: PolicyLink | None = None
        self.controller: ControllerStream | None = None
        self.gripper: GripperStream | None = None
        self.joint_states: Any = None
        self.cameras: list[Any] = []
        self.wrench: WrenchWatch | None = None

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
        try:
            config = self._read_config()
            cfg.validate(config)
        except (PortError, cfg.ConfigError):  # a blackboard entry not set yet, or a mistake initialise reports
            return
        self._connect(config)

    def initialise(self) -> None:
        self.phase = Phase.STARTUP
        self.metrics = RunMetrics(node=self.name)
        self.context.resources.setdefault(POLICY_RUNS, []).append(self.metrics)
        self.message = ""
        self.rejection = ""
        self.started_at = self.context.clock.now()
        for part in (self.policy, self.controller, self.gripper, self.wrench):
            if part is not None:
                part.reset()
        # The STREAM phase's own state (see ``states``); the parts keep theirs.
        self.held: HeldChunk | None = None
        self.sent_motion: SentMotion | None = None  # from the end of the warmup
        self.rules: Any = None  # the safety rules of the run, taken when the robot is there
        self.first_period_s: float | None = None
        """The step period the first chunk that gave one said (``native_control_period``)."""
        self.warned_period_change = False
        self.warned_no_policy_chunk = False
        self.received: tuple[Chunk, int] | None = None  # the newest chunk read, with its request step
        self.warned_sizing = SizingRisk.COVERED  # the worst sizing risk warned about so far
        try:
            self.config = self._read_config()
            cfg.validate(self.config)
            self.safety: MotionSafety = make_safety(self.context.scene, self.config.joint_group_name, self.config.gripper_joint_name or None)
            self.safety = self.safety.narrowed(self.config.envelope_overrides)
        except (cfg.ConfigError, SafetyError) as err:  # the Objective does not fit this robot: ERROR, never retried
            raise self._setup_error(str(err)) from None
        config = self.config
        self.shaping = ShapingConfig(config.dt, config.committed_action_steps, config.policy_tracking_weight,
                                     config.num_interpolation_points, self.safety.limits.max_acceleration)
        self.scene_watch = SceneWatch(self.safety, config.link_padding)
        self._connect(config)

    def update(self) -> Status:
        try:
            if self.phase is Phase.STARTUP:
                return self._startup()
            if self.phase is Phase.WARMUP:
                return self._warmup()
            return self._stream()
        except StaleObservation as err:  # a publisher stopped: what the world did, not the setup
            return self._fail(Failure(FailureKind.STALE_OBSERVATION, str(err)))
        except (ObservationError, SafetyError) as err:  # e.g. joint states without the group's joints
            raise self._setup_error(str(err)) from None

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID and self.phase is not Phase.DONE:
            self._cancel_goals()
            self.message = self.metrics.message = "halted: goals cancelled, robot stopped"
            self.context.events.emit("policy_halted", self.name)
            self.phase = Phase.DONE

    def run_summary(self) -> dict[str, Any]:
        """Every ExecutePolicy run of the Objective (``POLICY_RUNS``): totals and each run."""
        return {"execute_policy": summarise_runs(self.context.resources.get(POLICY_RUNS, []))}

    # -- bus links ---------------------------------------------------------------------------
    def _connect(self, config: cfg.PolicyRunConfig) -> None:
        """Build the bus clients for ``config``'s names, once: again only when a name read from the
        blackboard changed between runs."""
        names = (config.policy_service_name, config.controller_action_name,
                 config.gripper_command_action_name if config.has_gripper else None,
                 config.joint_states_topic, config.image_topics, config.wrench_topic, config.absolute_force_torque_threshold)
        if names == self.connected_to:
            return
        self._close_subscriptions()
        bus = self.context.bus
        self.policy = PolicyLink(bus.create_client(config.policy_service_name, GetActionChunk))
        self.controller = ControllerStream(ControllerLink(bus, config.controller_action_name, self.location, self.xml_id),
                                           self.context.stamp_offset_s)
        self.gripper = (GripperStream(bus.create_action_client(config.gripper_command_action_name, GripperCommand),
                                      config.gripper_command_action_name) if config.has_gripper else None)
        self.joint_states = bus.create_subscription(config.joint_states_topic, JointState, reliable=True)
        # Best-effort matches both kinds of camera driver (most publish best-effort sensor-data QoS).
        self.cameras = [bus.create_subscription(t, Image, reliable=False) for t in config.image_topics]
        self.wrench = WrenchWatch(bus, config.wrench_topic, config.absolute_force_torque_threshold) if config.wrench_topic else None
        self.connected_to = names

    def _close_subscriptions(self) -> None:
        destroy = getattr(self.context.bus, "destroy_subscription", None)
        if destroy is None:
            return
        for sub in [self.joint_states, *self.cameras, self.wrench.subscription if self.wrench else None]:
            if sub is not None:
                destroy(sub)

    def _policy_link(self) -> PolicyLink:
        assert self.policy is not None, "initialise connects the links"
        return self.policy

    def _controller(self) -> ControllerStream:
        assert self.controller is not None, "initialise connects the links"
        return self.controller

    # -- phases ------------------------------------------------------------------------------
    def _startup(self) -> Status:
        config, now = self.config, self.context.clock.now()
        missing = []
        if not self._policy_link().ready():
            missing.append(f"policy service '{config.policy_service_name}' ({self._policy_hint()})")
        if not self._controller().ready():  # a name served with another type is an ERROR here
            missing.append(f"controller action '{config.controller_action_name}'")
        if self.gripper is not None and not self.gripper.ready():
            missing.append(f"gripper action '{config.gripper_command_action_name}'")
        if self.joint_states.latest is None:
            missing.append(f"joint states on '{config.joint_states_topic}' (the publisher must use reliable QoS)")
        if self.wrench is not None and not self.wrench.has_reading:
            missing.append(f"a reading on wrench topic '{config.wrench_topic}' (is force_torque_sensor_broadcaster active?)")
        timed_out = now - self.started_at >= STARTUP_WAIT_S
        if missing and not timed_out:
            return Status.RUNNING  # the cameras are looked at once the rest is there (a read may render a frame)
        frames = [sub.latest for sub in self.cameras]
        for topic, frame in zip(config.image_topics, frames):
            if frame is None:
                missing.append(f"a frame on camera topic '{topic}' (subscribed best-effort, so a reliable or a "
                               "best-effort publisher matches; is the camera driver publishing there?)")
        if missing:
            if timed_out:  # the Objective names what this robot does not have: ERROR, never retried
                raise self._setup_error(f"not available after {STARTUP_WAIT_S:.0f} s: " + "; ".join(missing))
            return Status.RUNNING
        self.rules = self.safety.snapshot()
        self._send_request(new_episode=True, request_step=0, frozen=0, frames=frames)
        self.phase = Phase.WARMUP
        self.context.events.emit("policy_warmup_sent", self.name)
        return Status.RUNNING

    def _warmup(self) -> Status:
        config, now, policy = self.config, self.context.clock.now(), self._policy_link()
        if policy.timed_out(now, config.policy_call_timeout):
            return self._finish(Status.FAILURE, Failure(
                FailureKind.POLICY_TIMEOUT,
                f"warming up the policy service '{config.policy_service_name}' timed out after {config.policy_call_timeout:g} s "
                "(raise policy_call_timeout, or make the server finish its own warmup before it reports ready)"))
        answer = policy.answer(now)
        if answer is None:
            return Status.RUNNING
        if answer.error is not None:  # a transport failure of the warmup call
            return self._finish(Status.FAILURE, Failure(
                FailureKind.POLICY_ERROR, f"warming up the policy service '{config.policy_service_name}' failed: {answer.error}"))
        response = answer.response
        if response.status == GetActionChunk.Response.ERROR or response.status == GetActionChunk.Response.UNKNOWN:
            # The warmup is the run's first request with its prompt, joints and cameras: a refusal
            # is of the setup (or of a policy not there to serve it), and a Retry would ask the same.
            raise self._setup_error(self._status_reason(response, "warmup"))
        policy.latency.update(answer.round_trip_s)
        self._check_sizing("measured latency")
        self.sent_motion = SentMotion(StepGrid(now, config.dt, config.committed_action_steps, config.total_action_steps))
        self.phase = Phase.STREAM
        self._send_request(new_episode=True, request_step=0, frozen=self._frozen())
        return Status.RUNNING

    def _stream(self) -> Status:
        now = self.context.clock.now()
        status = self._watch_controller(now)  # first: an abort the controller already made is the reason
        if status is not None:
            return status
        crossing = self.wrench.crossing() if self.wrench is not None else None
        if crossing is not None:
            return self._stop(Status.FAILURE, f"force-torque threshold exceeded on '{self.config.wrench_topic}': {crossing}; goal cancelled, robot stopped")
        if self.gripper is not None:
            self.gripper.stream(now)
            problem = self.gripper.follow()
            if problem is not None:
                return self._fail(Failure(FailureKind.GRIPPER, problem))
        self._track_progress(now)
        policy = self._policy_link()
        state = stream_state(self.held, policy.request)
        if state is StreamState.HOLDING:
            held, self.held = self.held, None
            assert held is not None
            status = self._plan_and_send(held, now)  # holds it again while it cannot join
        elif state is StreamState.AWAITING_CHUNK:
            status = self._receive(now)
        else:
            status = None
        if status is not None:
            return status
        if stream_state(self.held, policy.request) is StreamState.SCHEDULING:
            self._maybe_request(now)  # also in the tick a chunk was sent: its next request may be due already
        sent = self._sent_motion()
        collision = self.scene_watch.check(self.rules, sent.samples, now, self._gripper_now())
        if collision is not None:
            return self._fail(Failure(FailureKind.SCENE_CHANGED, f"the planning scene changed: {collision} in the remaining path; robot stopped"))
        if stream_finished(sent, policy.request, self._controller().goal):
            # The controller's success says it played every step sent, whatever this run's clock
            # reads (a robot's clock may run ahead of it).
            self.metrics.steps_executed = sent.grid.executed_until
            return self._stop(Status.SUCCESS, f"executed {sent.grid.total_steps} steps")
        return Status.RUNNING

    # -- requests and responses --------------------------------------------------------------
    def _frozen(self) -> int:
        estimate_s = self.metrics.latency_estimate_s = self._policy_link().latency.seconds
        tick_s = self.context.tick_period_s
        return frozen_prefix_steps(estimate_s, self.config.dt, prefetch_margin(estimate_s, tick_s) + 2 * self._controller().planned_latency_s)

    def _maybe_request(self, now: float) -> None:
        grid = self._sent_motion().grid
        if grid.remaining == 0:
            return
        frozen = self._frozen()
        step = next_request_step(grid, frozen, now)
        if step is not None:
            self._send_request(new_episode=False, request_step=step, frozen=frozen)

    def _send_request(self, new_episode: bool, request_step: int, frozen: int, frames: list[Image] | None = None) -> None:
        """Ask for the chunk of ``request_step`` with the camera frames of now (``frames``: read in this tick already)."""
        config = self.config
        state = robot_state(self.joint_states.latest, self.safety.group_joints, config.gripper_joint_name or None, config.joint_states_topic)
        frames = frames if frames is not None else [sub.latest for sub in self.cameras]
        now = self.context.clock.now()
        received = [(config.joint_states_topic, self.joint_states.received_at),
                    *zip(config.image_topics, (sub.received_at for sub in self.cameras))]
        self.metrics.oldest_observation_s = max([self.metrics.oldest_observation_s] + [now - at for _, at in received if at is not None])
        self._policy_link().send(config, state, frames, received, now, new_episode, request_step, frozen)
        self.context.events.emit("chunk_requested", self.name, request_step=request_step, frozen_prefix_steps=frozen)

    def _receive(self, now: float) -> Status | None:
        config, policy = self.config, self._policy_link()
        if policy.timed_out(now, config.policy_call_timeout):
            return self._fail(Failure(
                FailureKind.POLICY_TIMEOUT,
                f"the policy service '{config.policy_service_name}' did not answer within policy_call_timeout = {config.policy_call_timeout:g} s"))
        answer = policy.answer(now)
        if answer is None:
            return None
        if answer.error is not None:
            return self._fail(Failure(FailureKind.POLICY_ERROR, f"calling the policy service '{config.policy_service_name}' failed: {answer.error}"))
        response, flight = answer.response, answer.flight
        policy.latency.update(answer.round_trip_s)
        self.metrics.latencies.append(answer.round_trip_s)
        self._check_sizing("latency estimate", f" (the {policy.latency.quantile * 100:.0f}th percentile of the last {len(policy.latency.recent)} round trips)")
        if response.status == GetActionChunk.Response.NO_MORE_ACTIONS:
            return self._stop(Status.SUCCESS, f"the policy has no more actions: {response.message}".rstrip(": "))
        if response.status != GetActionChunk.Response.CHUNK_PRODUCED:
            return self._fail(Failure(FailureKind.POLICY_ERROR, self._status_reason(response, f"chunk {self.metrics.chunks + 1}")))
        self.metrics.chunks += 1
        self.received = None  # until this chunk is read
        period = period_problem(response.native_control_period)
        if period is not None:
            return self._fail(Failure(FailureKind.MALFORMED_CHUNK, f"chunk {self.metrics.chunks} rejected: {period}"))
        self._check_period(response.native_control_period, self.metrics.chunks)
        try:
            chunk = read_chunk(response.chunk, self.safety.group_joints, config.gripper_joint_name or None)
            policy_chunk = read_policy_chunk(response.policy_action_chunk) if config.policy_uses_real_time_chunking else None
        except ChunkError as err:
            return self._fail(Failure(FailureKind.MALFORMED_CHUNK, f"chunk {self.metrics.chunks} rejected: {err}"))
        if config.policy_uses_real_time_chunking and policy_chunk is None and not self.warned_no_policy_chunk:
            self.warned_no_policy_chunk = True
            self._warn(f"policy_uses_real_time_chunking is true but chunk {self.metrics.chunks} carries no policy_action_chunk: "
                       "the policy gets no previous_action_chunk back, so real-time chunking does nothing (send it, or set "
                       "policy_uses_real_time_chunking=\"false\" for a policy without a denoising loop)")
        chunk = Chunk(chunk.arm, self._settle_gripper(chunk.gripper))
        self.received = (chunk, flight.request_step)
        problem = cfg.committed_window_problem(config.committed_action_steps, chunk.steps) if self.metrics.chunks == 1 else None
        if problem is not None:
            return self._fail(Failure(FailureKind.SHORT_CHUNK, f"chunk 1 rejected: {problem}"))
        if self.metrics.chunks == 1:
            self._check_first_chunk_start(chunk, flight.anchor)
        self._controller().new_chunk()
        return self._plan_and_send(HeldChunk(chunk, response, flight), now)

    def _plan_and_send(self, held: HeldChunk, now: float) -> Status | None:
        """Plan ``held`` (``planner.plan_chunk``); send it, hold it, or end the run with its rejection."""
        config, sent, controller = self.config, self._sent_motion(), self._controller()
        grid = sent.grid
        rest_position = None
        if sent.motion is None:
            state = robot_state(self.joint_states.latest, self.safety.group_joints, None, config.joint_states_topic)
            rest_position = np.asarray(state.position, dtype=float)
        plan = plan_chunk(PlanInput(
            sent=sent,
            goal=controller.goal.state,
            chunk=held.chunk,
            index=self.metrics.chunks,
            request_step=held.flight.request_step,
            frozen=held.flight.frozen,
            earliest_seam_step=earliest_seam_step(grid, now, self.context.tick_period_s, controller.planned_latency_s),
            rest_position=rest_position,
            config=self.shaping,
            checks=PointChecks(self.safety, self.rules, config.link_padding, self._gripper_now(), grid),
            arrival=Arrival(grid.step_at_or_after(held.flight.future.ready_at),  # arrival, not when we looked
                            goal_takes_effect_s(now, self.context.tick_period_s, controller.planned_latency_s)),
        ))
        if isinstance(plan, Failure):
            return self._fail(plan)
        if not isinstance(plan, Planned):  # Wait
            self.held = held
            return None
        self._send_motion(held, plan, now)
        return None

    def _send_motion(self, held: HeldChunk, plan: Planned, now: float) -> None:
        """Send the planned motion to the controller: from here it is the sent motion."""
        config, window, controller, before = self.config, plan.window, self._controller(), self._sent_motion()
        samples = plan.sent.samples
        assert samples is not None
        self.metrics.stall_seconds += plan.stall_s
        # Kept until the controller accepts the seam: a goal refused only for arriving late is
        # planned again from the same chunk (see _roll_back).
        rollback = Rollback(held, before, controller.goal, plan.stall_s, window.index, plan.takes_over_s)
        self.scene_watch.checked(self._gripper_now())  # what the samples were checked against
        controller.send(config, self.safety.group_joints, samples, before.samples, rollback, now, self.context.tick_period_s)
        self.sent_motion = plan.sent
        if self.gripper is not None:
            limit = self.safety.chunk_limits[self.safety.gripper_joint]
            self.gripper.queue(held.chunk, window, plan.sent.grid, limit.max_velocity)
        if config.policy_uses_real_time_chunking:  # read (and checked) when the answer came in
            self._policy_link().carry_over(read_policy_chunk(held.response.policy_action_chunk), window.request_step, held.flight.anchor)
        self.context.events.emit(
            "chunk_executed",
            self.name,
            chunk=window.index,
            request_step=window.request_step,
            seam_step=window.seam_step,
            steps=window.steps,
            seam_time=plan.seam_time_s,
            takes_over_time=plan.takes_over_s,
            latency=self.metrics.latencies[-1],
            stall_s=plan.stall_s,
        )

    # -- controller --------------------------------------------------------------------------
    def _watch_controller(self, now: float) -> Status | None:
        controller = self._controller()
        try:
            news = controller.watch(now)
        except SetupError as err:  # a goal refused as sent: refused again on a retry
            raise self._setup_error(str(err)) from None
        self.metrics.goal_latency_max_s = controller.goal_latency_s
        if isinstance(news, Rollback):
            self._roll_back(news)
            return None
        if news is not None:
            return self._fail(Failure(FailureKind.CONTROLLER, news))
        return None

    def _roll_back(self, rollback: Rollback) -> None:
        """A goal refused for reaching the controller after its seam: go back to the motion sent
        before it and plan the same chunk again from there (``ControllerStream.watch``)."""
        self.sent_motion = rollback.sent
        self.metrics.stall_seconds -= rollback.stall_s  # the chunk that takes over counts the stall up to its own seam
        self.context.events.emit("chunk_rolled_back", self.name, stall_s=rollback.stall_s)
        late = (f"chunk {rollback.chunk_index}'s goal reached the controller after t={rollback.takes_over_s:.2f} s, the moment "
                f"it was meant to take over, so the controller went on with what it was playing")
        margin = f" (goals are now given {1000 * self._controller().late_margin_s:.0f} ms more to reach the controller)"
        if self.held is not None:
            # A newer chunk arrived while this goal was unanswered: it takes over from what the
            # arm actually does, and the refused one is dropped.
            self._warn(f"{late}; the next chunk, already here, is planned from what the arm is doing{margin}")
            return
        self.held = rollback.held  # planned again next tick
        self._warn(f"{late}; the chunk is planned again from what the arm is doing{margin}")

    def _track_progress(self, now: float) -> None:
        sent = self._sent_motion()
        if sent.motion is None:
            return
        self.metrics.steps_executed = max(self.metrics.steps_executed, sent.grid.steps_executed_by(now))

    # -- endings -----------------------------------------------------------------------------
    def _fail(self, failure: Failure) -> Status:
        """End the run with ``failure`` (the robot stopped); a rejected chunk is counted and its
        values go with the ``chunk_rejected`` event."""
        if failure.rejects_chunk:
            self.metrics.rejections += 1
            self.rejection = self.metrics.rejection_reason = failure.detail
            self.context.events.emit("chunk_rejected", self.name, reason=failure.detail, failure_kind=failure.kind.value,
                                     **self._rejected_chunk())
        return self._stop(Status.FAILURE, failure)

    def _rejected_chunk(self) -> dict[str, Any]:
        """The chunk being rejected, on the clock, for the report to plot: ``joints``, ``times`` and
        ``positions`` (one row per step, from its request step); nothing when it was never read."""
        if self.received is None or self.metrics.chunks == 0:
            return {}
        chunk, request_step = self.received
        grid = self._sent_motion().grid
        return {"joints": list(self.safety.group_joints), "times": [grid.time(request_step + k) for k in range(chunk.steps)],
                "positions": np.asarray(chunk.arm, dtype=float).round(6).tolist()}

    def _stop(self, status: Status, ending: Failure | str) -> Status:
        """Cancel the goals and end the run (``_finish``)."""
        stall_s = stall_at_stop_s(self.sent_motion, self.context.clock.now())
        self.metrics.stall_seconds += stall_s
        self._cancel_goals()
        return self._finish(status, ending, stall_s)

    def _finish(self, status: Status, ending: Failure | str, stall_s: float = 0.0) -> Status:
        """End the run with ``status`` and ``ending``: a ``Failure`` (its kind is the run's
        ``Behavior.failure_kind``) or the message of a SUCCESS, or of a FAILURE without a kind;
        ``stall_s``: how long the arm had been waiting for a chunk when it ended. The message may
        carry the policy's own text: it is kept ``bounded``."""
        kind = ending.kind if isinstance(ending, Failure) else None
        message = bounded(ending.detail if isinstance(ending, Failure) else ending)
        self.phase = Phase.DONE
        self.message = self.metrics.message = message
        self.feedback_message = message
        self.failure_kind = kind.value if kind is not None else None
        self._write_outputs()
        self.context.events.emit("policy_finished", self.name, status=status.value, message=message, stall_s=stall_s)
        if status is Status.SUCCESS:
            self.context.logger.info("%s: %s", self.name, message)
        return status

    def _setup_error(self, what: str) -> SetupError:
        """End this run for a mistake of the setup (goals cancelled, the message kept for the
        summary): the error to raise, which ends the whole run as ERROR."""
        self._cancel_goals()
        what = bounded(what)
        self.phase = Phase.DONE
        self.message = self.metrics.message = what
        self._write_outputs()
        self.context.events.emit("policy_finished", self.name, status="ERROR", message=what)
        return SetupError(what)

    def _cancel_goals(self) -> None:
        if self.controller is not None:
            self.controller.cancel()
        if self.policy is not None:
            self.policy.cancel()
        self.held = None
        if self.gripper is not None:
            self.gripper.cancel()

    def _write_outputs(self) -> None:
        outputs = {
            "steps_executed": self.metrics.steps_executed,
            "chunks_received": self.metrics.chunks,
            "rejection_reason": self.rejection,
            "status_message": self.message,
        }
        for name, value in outputs.items():
            self.set_output(name, value)

    # -- small helpers -----------------------------------------------------------------------
    def _sent_motion(self) -> SentMotion:
        assert self.sent_motion is not None, "the STREAM phase starts with a sent motion (the arm at rest)"
        return self.sent_motion

    def _gripper_now(self) -> float | None:
        joint = self.config.gripper_joint_name
        state = self.joint_states.latest if self.joint_states is not None else None
        if not joint or state is None or joint not in state.name:
            return None
        return float(state.position[list(state.name).index(joint)])

    def _policy_hint(self) -> str:
        """What to do about a missing policy service, in the mode this run is in."""
        served = getattr(self.context.bus, "served", None)
        if not callable(served):  # a ROS 2 graph: the adapter serves the policy
            return "start the adapter (`objective adapter`) before running the Objective"
        names = ", ".join(sorted(served())) or "none"
        return f"in this run the world serves the policy chosen with --policy; services here: {names}"

    def _status_reason(self, response: Any, what: str) -> str:
        names = {0: "UNKNOWN", 1: "CHUNK_PRODUCED", 2: "NO_MORE_ACTIONS", 3: "ERROR"}
        status = names.get(response.status, f"status {response.status}")
        detail = response.message or ("the policy left the status unset" if response.status == 0 else "no message")
        return f"the policy answered {status} for the {what}: {detail}"

    def _check_sizing(self, what: str, detail: str = "") -> None:
        """Warn, with the figures, when the latency outgrows the sent window: once, and
        once more if it later outgrows what the chunk's tail covers as well."""
        config, policy = self.config, self._policy_link()
        risk = sizing_risk(config.committed_action_steps, config.dt, policy.latency.seconds, policy.chunk_steps)
        if risk > self.warned_sizing:
            self.warned_sizing = risk
            text = sizing_warning(config.committed_action_steps, config.dt, policy.latency.seconds, what, detail, policy.chunk_steps)
            assert text is not None
            self._warn(text)

    def _check_period(self, period: float, chunk_number: int) -> None:
        """Warn once when the first chunk's step period differs from ``dt``, and once when a later
        chunk's differs from the first's (0: the policy gives none)."""
        if period <= 0:
            return
        if self.first_period_s is None:
            self.first_period_s = period
            if abs(period - self.config.dt) > 1e-6:
                self._warn(
                    f"the policy was trained at {period:g} s per step but dt is {self.config.dt:g} s: the motion plays "
                    f"{period / self.config.dt:.2f}x as fast as trained (the chunk is not retimed)"
                )
            return
        if abs(period - self.first_period_s) > 1e-6 and not self.warned_period_change:
            self.warned_period_change = True
            self._warn(
                f"chunk {chunk_number} says the policy steps every {period:g} s, but the first chunk said "
                f"{self.first_period_s:g} s: every chunk is played at dt = {self.config.dt:g} s per step (not retimed)"
            )

    def _check_first_chunk_start(self, chunk: Chunk, anchor: Any) -> None:
        """Warn when the first chunk starts far from where the arm was at its request
        (``FIRST_CHUNK_GAP_RAD``): it is blended in, but such a gap is usually a wrong joint
        order, unit or robot state."""
        at_request = np.asarray(anchor.position[:chunk.arm.shape[1]], dtype=float)
        gap = np.abs(chunk.arm[0] - at_request)
        if float(gap.max()) > FIRST_CHUNK_GAP_RAD:
            joint = self.safety.group_joints[int(np.argmax(gap))]
            self._warn(f"chunk 1 starts {float(gap.max()):.3f} rad from where the arm was at its request (joint {joint}; "
                       f"more than {FIRST_CHUNK_GAP_RAD} rad): it is blended in, but check the policy's joint order, "
                       "units and the state it was given")

    def _settle_gripper(self, gripper: np.ndarray | None) -> np.ndarray | None:
        """The gripper column clamped into its range where it is a little outside
        (``safety.GRIPPER_BAND_FRACTION``): counted, and warned about once per run."""
        settled = self.safety.settle_gripper_column(gripper)
        if settled.clamped and not self.metrics.gripper_clamped:
            limit = self.safety.chunk_limits[self.safety.gripper_joint]
            self._warn(
                f"the policy's gripper column leaves the range {limit.lower:.4f}..{limit.upper:.4f} rad by up to "
                f"{settled.farthest_rad:.4f} rad (within the {self.safety.gripper_band_rad():.4f} rad band): such values are "
                "clamped into the range and counted (gripper_clamped); further out a chunk is rejected"
            )
        self.metrics.gripper_clamped += settled.clamped
        return settled.values

    def _warn(self, text: str) -> None:
        self.metrics.warnings.append(text)
        self.context.logger.warning("%s: %s", self.name, text)
        self.context.events.emit("warning", self.name, message=text)

    def _read_config(self) -> cfg.PolicyRunConfig:
        values = {p.name: self.get_input(p.name) for p in self.ports if p.direction is Direction.INPUT}
        for key in ("absolute_force_torque_threshold", "image_topics", "image_names", "tcp_keep_in_box"):
            values[key] = tuple(values[key])
        return cfg.PolicyRunConfig(**values)


NODES = (ExecutePolicy,)
