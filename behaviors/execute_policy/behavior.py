"""The ExecutePolicy behavior: one policy run as a state machine ticked by the tree.

Phases: STARTUP (wait for the service, the controller and gripper actions, every camera and the
joint states; 5 s), WARMUP (one discarded request, ``new_episode=true``, that seeds the latency
estimate), STREAM (request, shape, check, stitch, watch), then the run ends. Every chunk is
smoothed, densified and blended into the committed motion (``shaping``), checked point by point
against limits and the planning scene (``safety``), and only then sent to the admittance
controller as a goal that takes over at the seam. Halting the node cancels the controller goal:
the controller brings the arm to a smooth stop.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from control_msgs.action import GripperCommand
from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance as FollowTrajectory
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image, JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from runtime.behavior import Behavior, Status
from runtime.bus import STATUS_ABORTED, STATUS_SUCCEEDED
from runtime.ports import Direction
from runtime.timestamps import duration_msg, time_msg

from . import config as cfg
from .chunk import ChunkError, read_chunk, read_policy_chunk
from .observation import ObservationError, policy_tail, robot_state
from ..safety import MotionSafety, SafetyError, make_safety
from .gripper import GripperGoal, follow_goals
from .shaping import ChunkMotion, Samples, densify, fit_chunk, join_at_seam, runout_duration
from .stream import StepGrid, Window, WindowError, drained_seconds
from .timing import LatencyEstimate, frozen_prefix_steps, prefetch_margin, sizing_warning

STARTUP_WAIT_S = 5.0
GRIPPER_MAX_EFFORT = 60.0  # N; the 2F-85 holds a 30 mm cube well below its 235 N maximum
GRIPPER_DEADBAND = 0.01  # rad of the driver joint: smaller changes are not re-sent
TICK_PERIOD = 0.01
MAX_LATE_RETRIES = 3
LATE_GOAL_CODES = (FollowTrajectory.Result.OLD_HEADER_TIMESTAMP, FollowTrajectory.Result.SEAM_AFTER_TRAJECTORY_END)
"""The controller's answers to a goal that reached it after its seam (decided by code, not text)."""
GOAL_ACK_TIMEOUT = 5.0  # s: a controller that does not acknowledge a goal by then is gone
SCENE_WATCH_PERIOD = 0.05  # s: how often the rest of the committed motion is checked against the live scene


class Phase(enum.Enum):
    STARTUP = "startup"
    WARMUP = "warmup"
    STREAM = "stream"
    DONE = "done"


@dataclass
class InFlight:
    """A request the policy has not answered yet."""

    future: Any
    sent_at: float
    request_step: int
    frozen: int
    anchor: JointState


@dataclass
class _SentChunk:
    """A chunk sent to the controller, and the stream state from before it was committed."""

    chunk: Any
    response: Any
    flight: InFlight
    committed_end: int
    executed_until: int
    runout_steps: int
    motion: ChunkMotion | None
    samples: Samples | None
    goal_handle: Any  # the goal that was playing when this chunk was sent (None: the arm was at rest)
    result_future: Any


@dataclass
class RunMetrics:
    chunks: int = 0
    steps_executed: int = 0
    stall_seconds: float = 0.0
    rejections: int = 0
    latencies: list[float] = field(default_factory=list)
    latency_estimate_s: float = 0.0
    """What the last request was timed for (``timing.LatencyEstimate``)."""
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        lat = np.asarray(self.latencies) if self.latencies else np.zeros(1)
        return {
            "chunks": self.chunks,
            "steps_executed": self.steps_executed,
            "stall_seconds": round(self.stall_seconds, 4),
            "rejections": self.rejections,
            "latency_p50_s": round(float(np.percentile(lat, 50)), 4),
            "latency_p95_s": round(float(np.percentile(lat, 95)), 4),
            "latency_max_s": round(float(lat.max()), 4),
            "latency_estimate_s": round(self.latency_estimate_s, 4),
            "warnings": list(self.warnings),
        }


class ExecutePolicy(Behavior):
    """Stream a learned policy's action chunks as one continuous, checked motion.

    Every densified point is checked against joint position, velocity and acceleration limits,
    self-collision and world collision (with link_padding) before it reaches the controller.
    SUCCESS after total_action_steps steps or when the policy answers NO_MORE_ACTIONS; FAILURE on
    ERROR/UNKNOWN, timeouts, malformed or unsafe chunks, and controller aborts (F/T, path).
    """

    ports = cfg.PORTS
    needs_world = True
    description = (
        "Run a learned policy served over GetActionChunk: chunks are smoothed, blended at seams, "
        "checked against limits and the planning scene, and streamed to the admittance controller."
    )

    # -- lifecycle ---------------------------------------------------------------------------
    def initialise(self) -> None:
        self.phase = Phase.STARTUP
        self.metrics = RunMetrics()
        self.error: str | None = None
        self.message = ""
        self.rejection = ""
        self.started_at = self.context.clock.now()
        self.in_flight: InFlight | None = None
        self.waiting_chunk: tuple[Any, Any, InFlight] | None = None
        """A chunk that cannot be planned yet: the controller has not acknowledged the previous
        goal, or the motion still playing ends before the chunk could join it (it starts from
        rest once that motion finished)."""
        self.goal_handle: Any = None
        self.goal_result: Any = None
        self.pending_goal: Any = None
        self.goal_sent_at = 0.0
        self.last_sent: _SentChunk | None = None
        self.motion: ChunkMotion | None = None
        self.samples: Samples | None = None
        self.grid: StepGrid | None = None
        self.latency = LatencyEstimate()
        self.goal_latency_s = 0.0
        """The slowest send -> accepted of a controller goal so far: zero in process, a tick or
        more over ROS."""
        self.late_retries = 0  # of the chunk being sent
        self.result_future: Any = None
        self.next_scene_check = 0.0
        self.checked_scene: tuple[object, ...] | None = None  # what the committed samples were last checked against
        self.policy_chunk: np.ndarray | None = None
        self.policy_chunk_request_step = 0
        self.gripper_schedule: list[tuple[float, float]] = []
        self.gripper_sent: float | None = None
        self.gripper_goals: list[GripperGoal] = []
        self.warned_period = False
        self.warned_sizing = False
        try:
            self.config = self._read_config()
            cfg.validate(self.config)
            self.safety: MotionSafety = make_safety(self.context.scene, self.config.joint_group_name, self.config.gripper_joint_name or None)
        except (cfg.ConfigError, SafetyError) as err:
            self.error = str(err)
            return
        c, bus = self.config, self.context.bus
        self.policy = bus.create_client(c.policy_service_name, GetActionChunk)
        self.controller = bus.create_action_client(c.controller_action_name, FollowTrajectory)
        self.gripper = bus.create_action_client(c.gripper_command_action_name, GripperCommand) if c.has_gripper else None
        self.joint_states = bus.create_subscription(c.joint_states_topic, JointState, reliable=True)
        # Best-effort matches both kinds of camera driver (most publish best-effort sensor-data QoS).
        self.cameras = [bus.create_subscription(t, Image, reliable=False) for t in c.image_topics]

    def update(self) -> Status:
        if self.error is not None:
            return self._finish(Status.FAILURE, self.error)
        try:
            if self.phase is Phase.STARTUP:
                return self._startup()
            if self.phase is Phase.WARMUP:
                return self._warmup()
            return self._stream()
        except (ObservationError, SafetyError) as err:
            return self._stop(Status.FAILURE, str(err))

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID and getattr(self, "phase", Phase.DONE) is not Phase.DONE:
            self._cancel_goals()
            self.message = "halted: goals cancelled, robot stopped"
            self.context.events.emit("policy_halted", self.name)
            self.phase = Phase.DONE
        self._close_subscriptions()

    def run_summary(self) -> dict[str, Any]:
        data = self.metrics.as_dict() if hasattr(self, "metrics") else {}
        data["message"] = getattr(self, "message", "")
        data["rejection_reason"] = getattr(self, "rejection", "")
        return {"execute_policy": data}

    # -- phases ------------------------------------------------------------------------------
    def _startup(self) -> Status:
        c, now = self.config, self.context.clock.now()
        missing = []
        if not self.policy.service_is_ready():
            missing.append(f"policy service '{c.policy_service_name}' (start the adapter before running the Objective)")
        if not self.controller.server_is_ready():
            missing.append(f"controller action '{c.controller_action_name}'")
        if self.gripper is not None and not self.gripper.server_is_ready():
            missing.append(f"gripper action '{c.gripper_command_action_name}'")
        if self.joint_states.latest is None:
            missing.append(f"joint states on '{c.joint_states_topic}' (the publisher must use reliable QoS)")
        for topic, sub in zip(c.image_topics, self.cameras):
            if sub.latest is None:
                missing.append(f"a frame on camera topic '{topic}' (subscribed best-effort, so a reliable or a "
                               "best-effort publisher matches; is the camera driver publishing there?)")
        if missing:
            if now - self.started_at >= STARTUP_WAIT_S:
                return self._finish(Status.FAILURE, f"not available after {STARTUP_WAIT_S:.0f} s: " + "; ".join(missing))
            return Status.RUNNING
        self.rules = self.safety.snapshot()
        self._send_request(new_episode=True, request_step=0, frozen=0)
        self.phase = Phase.WARMUP
        self.context.events.emit("policy_warmup_sent", self.name)
        return Status.RUNNING

    def _warmup(self) -> Status:
        c, now = self.config, self.context.clock.now()
        flight = self.in_flight
        assert flight is not None
        if not flight.future.done():
            if now - flight.sent_at > c.policy_call_timeout:
                flight.future.cancel()
                return self._finish(
                    Status.FAILURE,
                    f"warming up the policy service '{c.policy_service_name}' timed out after {c.policy_call_timeout:g} s "
                    "(raise policy_call_timeout, or make the server finish its own warmup before it reports ready)",
                )
            return Status.RUNNING
        self.in_flight = None
        try:
            response = flight.future.result()
        except Exception as exc:  # a transport failure of the warmup call
            return self._finish(Status.FAILURE, f"warming up the policy service '{c.policy_service_name}' failed: {exc}")
        if response.status == GetActionChunk.Response.ERROR or response.status == GetActionChunk.Response.UNKNOWN:
            return self._finish(Status.FAILURE, self._status_reason(response, "warmup"))
        self.latency.update(now - flight.sent_at)
        self._check_sizing("measured latency")
        self.grid = StepGrid(now, c.dt, c.committed_action_steps, c.total_action_steps)
        self.phase = Phase.STREAM
        self._send_request(new_episode=True, request_step=0, frozen=self._frozen())
        return Status.RUNNING

    def _stream(self) -> Status:
        now, grid = self.context.clock.now(), self.grid
        assert grid is not None
        status = self._watch_controller()
        if status is not None:
            return status
        self._stream_gripper(now)
        problem = follow_goals(self.gripper_goals, self.config.gripper_command_action_name)
        if problem is not None:
            return self._stop(Status.FAILURE, problem)
        self._track_progress(now)
        if self.waiting_chunk is not None:
            chunk, response, flight = self.waiting_chunk
            self.waiting_chunk = None
            status = self._execute(chunk, response, flight, now)  # waits again while it cannot join
            if status is not None:
                return status
        elif self.in_flight is not None:
            status = self._receive(now)
            if status is not None:
                return status
        elif grid.remaining > 0:
            self._maybe_request(now)
        if self.samples is not None and now >= self.next_scene_check - 1e-9:
            self.next_scene_check = now + SCENE_WATCH_PERIOD
            scene_state = self._scene_state()
            if scene_state != self.checked_scene:  # else the remaining samples were checked against this very scene
                collision = self.safety.first_collision(self.rules, self._remaining_samples(now), self.config.link_padding, self._gripper_now())
                if collision is not None:
                    return self._stop(Status.FAILURE, f"the planning scene changed: {collision} in the remaining path; robot stopped")
                self.checked_scene = scene_state
        if grid.remaining == 0 and self.in_flight is None and self.goal_result is not None:
            return self._stop(Status.SUCCESS, f"executed {grid.total_steps} steps")
        return Status.RUNNING

    # -- requests and responses --------------------------------------------------------------
    def _frozen(self) -> int:
        est = self.metrics.latency_estimate_s = self.latency.seconds
        return frozen_prefix_steps(est, self.config.dt, prefetch_margin(est, TICK_PERIOD) + 2 * self.goal_latency_s)

    def _maybe_request(self, now: float) -> None:
        grid = self.grid
        assert grid is not None
        frozen = self._frozen()
        ideal = grid.ideal_request_step(frozen)
        if now + 1e-9 < grid.time(ideal):
            return
        self._send_request(new_episode=False, request_step=max(ideal, grid.step_at_or_before(now)), frozen=frozen)

    def _send_request(self, new_episode: bool, request_step: int, frozen: int) -> None:
        c = self.config
        request = GetActionChunk.Request()
        request.prompt = c.prompt
        request.robot_state = robot_state(self.joint_states.latest, self.safety.group_joints, c.gripper_joint_name or None, c.joint_states_topic)
        request.image_names = list(c.image_names)
        request.images = [sub.latest for sub in self.cameras]
        request.new_episode = new_episode
        request.frozen_prefix_steps = frozen
        request.guidance_horizon = c.guidance_horizon
        if c.policy_uses_real_time_chunking and self.policy_chunk is not None and not new_episode:
            request.previous_action_chunk = policy_tail(self.policy_chunk, request_step - self.policy_chunk_request_step)
            request.previous_anchor_state = self.previous_anchor
        now = self.context.clock.now()
        self.in_flight = InFlight(self.policy.call_async(request), now, request_step, frozen, request.robot_state)
        self.context.events.emit("chunk_requested", self.name, request_step=request_step, frozen_prefix_steps=frozen)

    def _receive(self, now: float) -> Status | None:
        c, flight = self.config, self.in_flight
        assert flight is not None
        if not flight.future.done():
            if now - flight.sent_at > c.policy_call_timeout:
                flight.future.cancel()
                return self._stop(
                    Status.FAILURE,
                    f"the policy service '{c.policy_service_name}' did not answer within policy_call_timeout = {c.policy_call_timeout:g} s",
                )
            return None
        self.in_flight = None
        try:
            response = flight.future.result()
        except Exception as exc:
            return self._stop(Status.FAILURE, f"calling the policy service '{c.policy_service_name}' failed: {exc}")
        self.latency.update(now - flight.sent_at)
        self.metrics.latencies.append(now - flight.sent_at)
        self._check_sizing("latency estimate", f" (the {self.latency.quantile * 100:.0f}th percentile of the last {len(self.latency.recent)} round trips)")
        if response.status == GetActionChunk.Response.NO_MORE_ACTIONS:
            return self._stop(Status.SUCCESS, f"the policy has no more actions: {response.message}".rstrip(": "))
        if response.status != GetActionChunk.Response.CHUNK_PRODUCED:
            return self._stop(Status.FAILURE, self._status_reason(response, f"chunk {self.metrics.chunks + 1}"))
        self.metrics.chunks += 1
        self._check_period(response.native_control_period)
        try:
            chunk = read_chunk(response.chunk, self.safety.group_joints, c.gripper_joint_name or None)
        except ChunkError as err:
            return self._reject(f"chunk {self.metrics.chunks} rejected: {err}")
        problem = cfg.committed_window_problem(c.committed_action_steps, chunk.steps) if self.metrics.chunks == 1 else None
        if problem is not None:
            return self._reject(f"chunk 1 rejected: {problem}")
        self.late_retries = 0
        return self._execute(chunk, response, flight, now)

    def _execute(self, chunk: Any, response: Any, flight: InFlight, now: float) -> Status | None:
        c, grid = self.config, self.grid
        assert grid is not None
        if self.pending_goal is not None:
            # Whether the controller plays the previous goal decides how this chunk joins: wait
            # for its answer (a refused goal rolls the stream back, see _retry_late_goal).
            self.waiting_chunk = (chunk, response, flight)
            return None
        index = self.metrics.chunks
        # The goal must reach the controller before its seam: one tick, plus twice the goal
        # delivery time seen so far (zero in process; over ROS, transport and the next spin).
        earliest = grid.step_at_or_after(now + TICK_PERIOD + 2 * self.goal_latency_s)
        try:
            window = grid.plan_window(index, flight.request_step, flight.frozen, chunk.steps, earliest)
        except WindowError as err:
            return self._reject(f"chunk {index} rejected: {err}")
        # The values the window is built from, as the policy sent them (the gripper column too).
        last = window.end_step - window.request_step + 1
        outside = self.safety.first_value_out_of_limits(chunk.arm[:last], None if chunk.gripper is None else chunk.gripper[:last])
        if outside is not None:
            return self._reject(f"chunk {index} rejected: {outside} (policy step {window.request_step + outside.step} of the run)")
        seam_time = grid.time(window.seam_step)
        if self.motion is not None and seam_time > self.motion.rest_time + 1e-9 and self.goal_result is None:
            # Too late to join the motion the controller is still playing (its runout included): a
            # seam after its end would be refused ("seam time exceeds the end of the current
            # trajectory"). Wait for the motion to finish; the chunk then starts from rest (a
            # pause, counted as a stall).
            self.waiting_chunk = (chunk, response, flight)
            return None
        start_p, start_v = self._state_at(seam_time)
        spline = fit_chunk(chunk.arm, c.policy_tracking_weight)
        motion = join_at_seam(
            spline,
            c.dt,
            grid.time(window.request_step),
            seam_time,
            grid.time(window.end_step),
            start_p,
            start_v,
            blend_duration=max(c.dt, 0.5 * window.steps * c.dt),
            max_acceleration=self.safety.limits.max_acceleration,
        )
        if window.end_step >= grid.total_steps:
            motion = motion.at_rest_at_end()
        else:
            motion = motion.with_runout(self._runout(motion, chunk, window))
        # A chunk over the limits on its own is the policy's; the join is planned within them.
        reason = self._limit_violation(densify(motion.chunk_alone(), c.num_interpolation_points), window)
        if reason is not None:
            return self._reject(f"chunk {index} rejected: {reason}")
        samples = densify(motion, c.num_interpolation_points)
        scene_state = self._scene_state()
        reason = self._check(samples, window)
        if reason is not None and motion.runout > 0:
            # The runout only makes a late next chunk a gentle pause: when the chunk's path beyond
            # its window is unsafe but the window is not, the window ends without one.
            bare = motion.with_runout(0.0)
            bare_samples = densify(bare, c.num_interpolation_points)
            if self._check(bare_samples, window) is None:
                motion, samples, reason = bare, bare_samples, None
        if reason is not None:
            return self._reject(f"chunk {index} rejected: {reason}")
        goal_future = self.controller.send_goal_async(self._goal(samples, seam_time))
        self.pending_goal, self.goal_sent_at = goal_future, now
        # Drained until the seam: in the runout (slowing down), then at rest.
        self.metrics.stall_seconds += drained_seconds(None if self.motion is None else self.motion.end, seam_time)
        # Kept until the controller accepts the seam: a goal refused only for arriving late is
        # planned again from the same chunk (see _retry_late_goal).
        self.last_sent = _SentChunk(chunk, response, flight, grid.committed_end, grid.executed_until, grid.runout_steps,
                                    self.motion, self.samples, self.goal_handle, self.result_future)
        self.motion, self.samples = motion, samples
        self.checked_scene = scene_state
        grid.commit(window, runout_steps=round(motion.runout / (2 * c.dt)))
        self.goal_result = None
        self.goal_handle = None
        self._queue_gripper(chunk, window)
        policy_chunk = read_policy_chunk(response.policy_action_chunk)
        if c.policy_uses_real_time_chunking:
            self.policy_chunk, self.policy_chunk_request_step = policy_chunk, window.request_step
            self.previous_anchor = flight.anchor
        self.context.events.emit(
            "chunk_executed",
            self.name,
            chunk=index,
            request_step=window.request_step,
            seam_step=window.seam_step,
            steps=window.steps,
            seam_time=seam_time,
            latency=self.metrics.latencies[-1],
        )
        return None

    def _check(self, samples: Samples, window: Window) -> str | None:
        violation = self._limit_violation(samples, window)
        if violation is not None:
            return violation
        collision = self.safety.first_collision(self.rules, samples, self.config.link_padding, self._gripper_now())
        return None if collision is None else f"densified {collision}"

    def _limit_violation(self, samples: Samples, window: Window) -> str | None:
        grid = self.grid
        assert grid is not None
        violation = self.safety.limits.check(samples.positions, samples.velocities, samples.accelerations, samples.times)
        if violation is None:
            return None
        step = window.request_step + int(np.floor((violation.time - grid.time(window.request_step)) / self.config.dt + 1e-9))
        return f"densified {violation} (policy step {step} of the run)"

    def _state_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity of the committed motion at ``t`` (at rest after it ends)."""
        if self.motion is None:
            state = robot_state(self.joint_states.latest, self.safety.group_joints, None, self.config.joint_states_topic)
            return np.asarray(state.position, dtype=float), np.zeros(len(state.position))
        if t > self.motion.rest_time + 1e-9:  # drained: the arm rests where the motion ended
            p, _, _ = self.motion.evaluate(np.array([self.motion.rest_time]))
            return p[0], np.zeros(p.shape[1])
        p, v, _ = self.motion.evaluate(np.array([t]))
        return p[0], v[0]

    def _runout(self, motion: ChunkMotion, chunk: Any, window: Window) -> float:
        """Seconds for the window's motion to come to rest along the chunk if no chunk follows."""
        _, v_end, _ = motion.evaluate(np.array([motion.end]))
        spare = chunk.steps - 1 - (window.end_step - window.request_step)
        nominal = 0.5 * self.config.committed_action_steps * self.config.dt
        return runout_duration(v_end[0], self.safety.limits.max_acceleration, self.config.dt, nominal, spare)

    def _goal(self, samples: Samples, seam_time: float) -> Any:
        c = self.config
        goal = FollowTrajectory.Goal()
        trajectory = JointTrajectory()
        trajectory.header.stamp = time_msg(seam_time)
        trajectory.joint_names = list(self.safety.group_joints)
        for t, p, v, a in zip(samples.times, samples.positions, samples.velocities, samples.accelerations):
            trajectory.points.append(
                JointTrajectoryPoint(positions=p.tolist(), velocities=v.tolist(), accelerations=a.tolist(), time_from_start=duration_msg(t - seam_time))
            )
        goal.joint_trajectory = trajectory
        goal.path_tolerance = c.goal_path_tolerance
        goal.goal_time_tolerance = max(0.5, 5 * c.dt)
        goal.absolute_force_torque_threshold = list(c.absolute_force_torque_threshold)
        return goal

    # -- controller and gripper --------------------------------------------------------------
    def _watch_controller(self) -> Status | None:
        pending = self.pending_goal
        if pending is not None and not pending.done() and self.context.clock.now() - self.goal_sent_at > GOAL_ACK_TIMEOUT:
            return self._stop(Status.FAILURE, f"the controller '{self.config.controller_action_name}' did not acknowledge "
                                              f"a goal within {GOAL_ACK_TIMEOUT:g} s")
        if pending is not None and pending.done():
            self.pending_goal = None
            self.goal_latency_s = max(self.goal_latency_s, pending.ready_at - self.goal_sent_at)  # arrival, not when we looked
            handle = pending.result()
            if not handle.accepted:
                return self._stop(Status.FAILURE, f"the controller '{self.config.controller_action_name}' rejected the goal")
            self.goal_handle = handle
            self.result_future = handle.get_result_async()
        if self.goal_handle is not None and self.result_future.done():
            outcome = self.result_future.result()
            self.goal_handle = None
            self.goal_result = outcome
            if outcome.status == STATUS_ABORTED or outcome.result.error_code not in (0,):
                if outcome.result.error_code == FollowTrajectory.Result.SUPERSEDED:
                    return None
                if self._retry_late_goal(outcome.result):
                    return None
                return self._stop(Status.FAILURE, f"the controller aborted the motion: {outcome.result.error_string}")
            if outcome.status != STATUS_SUCCEEDED:
                return self._stop(Status.FAILURE, f"the controller ended the motion: {outcome.result.error_string}")
        return None

    def _retry_late_goal(self, result: Any) -> bool:
        """A goal refused only because it reached the controller after its seam (a first goal on
        a new connection, a slow tick or a busy transport): the controller goes on with what it
        was playing, the previous window and its runout, or rest. So plan the same chunk again
        from there, now with the measured delivery time: it joins the runout, or starts from
        rest. At most ``MAX_LATE_RETRIES`` times per chunk."""
        sent = self.last_sent
        late = result.error_code in LATE_GOAL_CODES
        if not late or sent is None or self.late_retries >= MAX_LATE_RETRIES:
            return False
        self.late_retries += 1
        grid = self.grid
        assert grid is not None
        grid.committed_end, grid.executed_until, grid.runout_steps = sent.committed_end, sent.executed_until, sent.runout_steps
        self.motion, self.samples = sent.motion, sent.samples
        if sent.goal_handle is not None:  # still playing (or its result is waiting to be read)
            self.goal_handle, self.result_future, self.goal_result = sent.goal_handle, sent.result_future, None
        if self.waiting_chunk is not None:
            # A newer chunk arrived while this goal was unanswered: it takes over from what the
            # arm actually does, and the refused one is dropped.
            self._warn(f"the controller received a goal after its seam ({result.error_string}); the next chunk takes over")
            return True
        self.waiting_chunk = (sent.chunk, sent.response, sent.flight)  # planned again next tick
        self._warn(f"the controller received a goal after its seam ({result.error_string}); planning the chunk again")
        return True

    def _queue_gripper(self, chunk: Any, window: Window) -> None:
        if self.gripper is None or chunk.gripper is None:
            return
        grid = self.grid
        assert grid is not None
        steps = range(window.seam_step, window.end_step)
        self.gripper_schedule = [(grid.time(s), float(chunk.gripper[s - window.request_step])) for s in steps]

    def _stream_gripper(self, now: float) -> None:
        target = None
        while self.gripper_schedule and self.gripper_schedule[0][0] <= now + 1e-9:
            target = self.gripper_schedule.pop(0)[1]
        if target is None or self.gripper is None:
            return
        if self.gripper_sent is not None and abs(target - self.gripper_sent) < GRIPPER_DEADBAND:
            return
        goal = GripperCommand.Goal()
        goal.command.position = target
        goal.command.max_effort = GRIPPER_MAX_EFFORT
        self.gripper_goals.append(GripperGoal(target, self.gripper.send_goal_async(goal)))
        self.gripper_sent = target

    def _track_progress(self, now: float) -> None:
        grid = self.grid
        assert grid is not None
        if self.motion is None:
            return
        executed = grid.executed_until - max(0, grid.committed_end - grid.step_at_or_before(now))
        self.metrics.steps_executed = max(self.metrics.steps_executed, min(executed, grid.executed_until))

    def _remaining_samples(self, now: float) -> Samples:
        s = self.samples
        assert s is not None
        keep = s.times >= now
        return Samples(s.times[keep], s.positions[keep], s.velocities[keep], s.accelerations[keep])

    # -- endings -----------------------------------------------------------------------------
    def _reject(self, reason: str) -> Status:
        self.metrics.rejections += 1
        self.rejection = reason
        self.context.events.emit("chunk_rejected", self.name, reason=reason)
        return self._stop(Status.FAILURE, reason)

    def _stop(self, status: Status, message: str) -> Status:
        grid = self.grid
        if grid is not None and grid.remaining > 0 and self.motion is not None:
            # The run ends while the arm waits for a chunk: the wait so far is a stall too.
            self.metrics.stall_seconds += drained_seconds(self.motion.end, self.context.clock.now())
        self._cancel_goals()
        return self._finish(status, message)

    def _finish(self, status: Status, message: str) -> Status:
        self.phase = Phase.DONE
        self.message = message
        self.feedback_message = message
        self._write_outputs()
        self.context.events.emit("policy_finished", self.name, status=status.value, message=message)
        if status is Status.SUCCESS:
            self.context.logger.info("%s: %s", self.name, message)
        return status

    def _cancel_goals(self) -> None:
        if self.goal_handle is not None:
            self.goal_handle.cancel_goal_async()
            self.goal_handle = None
        pending = self.pending_goal
        if pending is not None and pending.done():
            handle = pending.result()
            if handle.accepted:
                handle.cancel_goal_async()
        self.pending_goal = None
        if self.in_flight is not None:
            self.in_flight.future.cancel()
            self.in_flight = None
        self.waiting_chunk = None
        self.gripper_schedule = []

    def _write_outputs(self) -> None:
        outputs = {
            "steps_executed": self.metrics.steps_executed,
            "chunks_received": self.metrics.chunks,
            "rejection_reason": self.rejection,
            "status_message": self.message,
        }
        for name, value in outputs.items():
            self.set_output(name, value)

    def _close_subscriptions(self) -> None:
        bus = self.context.bus
        destroy = getattr(bus, "destroy_subscription", None)
        if destroy is None:
            return
        for sub in [getattr(self, "joint_states", None), *getattr(self, "cameras", [])]:
            if sub is not None:
                destroy(sub)
        self.cameras = []
        self.joint_states = None

    # -- small helpers -----------------------------------------------------------------------
    def _scene_state(self) -> tuple[object, ...]:
        """What a collision check of the committed samples depends on, besides the samples."""
        gripper = self._gripper_now()
        return (self.safety.scene.version, None if gripper is None else round(gripper, 4))

    def _gripper_now(self) -> float | None:
        joint = self.config.gripper_joint_name
        state = self.joint_states.latest if self.joint_states is not None else None
        if not joint or state is None or joint not in state.name:
            return None
        return float(state.position[list(state.name).index(joint)])

    def _status_reason(self, response: Any, what: str) -> str:
        names = {0: "UNKNOWN", 1: "CHUNK_PRODUCED", 2: "NO_MORE_ACTIONS", 3: "ERROR"}
        status = names.get(response.status, f"status {response.status}")
        detail = response.message or ("the policy left the status unset" if response.status == 0 else "no message")
        return f"the policy answered {status} for the {what}: {detail}"

    def _check_sizing(self, what: str, detail: str = "") -> None:
        """Warn once per run, with the figures, when the latency outgrows the committed window."""
        c = self.config
        text = sizing_warning(c.committed_action_steps, c.dt, self.latency.seconds, what, detail)
        if text is not None and not self.warned_sizing:
            self.warned_sizing = True
            self._warn(text)

    def _check_period(self, period: float) -> None:
        if self.warned_period or period <= 0:
            return
        if abs(period - self.config.dt) > 1e-6:
            self._warn(
                f"the policy was trained at {period:g} s per step but dt is {self.config.dt:g} s: the motion plays "
                f"{period / self.config.dt:.2f}x as fast as trained (the chunk is not retimed)"
            )
        self.warned_period = True

    def _warn(self, text: str) -> None:
        self.metrics.warnings.append(text)
        self.context.logger.warning("%s: %s", self.name, text)
        self.context.events.emit("warning", self.name, message=text)

    def _read_config(self) -> cfg.PolicyRunConfig:
        values = {p.name: self.get_input(p.name) for p in self.ports if p.direction is Direction.INPUT}
        for key in ("absolute_force_torque_threshold", "image_topics", "image_names"):
            values[key] = tuple(values[key])
        return cfg.PolicyRunConfig(**values)


NODES = (ExecutePolicy,)
