"""The ExecutePolicy behavior: wires the bus to the executor's states and its pure planner.

Phases (``states.Phase``): STARTUP (wait for the service, the controller and gripper actions,
every camera and the joint states; 5 s), WARMUP (one discarded request, ``new_episode=true``,
that seeds the latency estimate), STREAM, then DONE. In STREAM each tick watches the controller
goal (``action_goal.GoalState``), streams the gripper column, then does what ``states.StreamState``
says: send the next request when it is due, read an answered one, or plan a held chunk again.
``planner.plan_chunk`` decides (Planned / Wait / Reject), ``checks.PointChecks`` checks every
point, and only ``_send_goal`` sends a motion to the trajectory controller (the admittance
controller or a stock JTC, ``controller_link``). Halting the node
cancels the controller goal: the controller brings the arm to a smooth stop.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np
from control_msgs.action import GripperCommand
from moveit_pro_controllers_msgs.action import FollowJointTrajectoryWithAdmittance as FollowTrajectory
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image, JointState

from runtime.behavior import Behavior, Status
from runtime.errors import PortError, SetupError
from runtime.bus import STATUS_ABORTED, STATUS_SUCCEEDED
from runtime.ports import Direction

from . import config as cfg
from ..controller_link import ControllerKind, ControllerLink, GoalTolerances, jtc_stream_points, trajectory_goal
from ..wrench_watch import WrenchWatch
from .checks import PointChecks
from .chunk import Chunk, ChunkError, period_problem, read_chunk, read_policy_chunk
from .gripper import GripperGoal, follow_goals, join_targets
from .observation import ObservationError, StaleObservation, policy_tail, robot_state, stale_observation
from .planner import (
    Arrival,
    PlanInput,
    Planned,
    SHORT_CHUNK,
    Reject,
    ShapingConfig,
    earliest_seam_step,
    goal_takes_effect_s,
    next_request_step,
    plan_chunk,
    stall_at_stop_s,
)
from .shaping import Samples
from .states import Committed, FreeSamples, HeldChunk, InFlight, Phase, Rollback, StreamState, stream_finished, stream_state
from .stream import StepGrid, Window
from .timing import LatencyEstimate, SizingRisk, frozen_prefix_steps, prefetch_margin, sizing_risk, sizing_warning
from ..action_goal import Goal, GoalState
from ..gripper import gripper_command
from ..safety import MotionSafety, SafetyError, make_safety
from ..trajectory_goal import trajectory_msg

STARTUP_WAIT_S = 5.0
GRIPPER_MAX_EFFORT_N = 60.0  # the 2F-85 holds a 30 mm cube well below its 235 N maximum
GRIPPER_DEADBAND_RAD = 0.01  # of the driver joint: smaller changes are not re-sent
FIRST_CHUNK_GAP_RAD = 0.2
"""A first chunk whose step 0 is further than this from the arm (on any joint) is warned about."""
MAX_LATE_RETRIES = 3
LATE_GOAL_CODES = (FollowTrajectory.Result.OLD_HEADER_TIMESTAMP, FollowTrajectory.Result.SEAM_AFTER_TRAJECTORY_END)
"""The controller's answers to a goal that reached it after its seam (decided by code, not text)."""
GOAL_ACK_TIMEOUT_S = 5.0  # a controller that does not acknowledge a goal by then is gone
SCENE_WATCH_PERIOD_S = 0.05  # how often the rest of the committed motion is checked against the live scene


class FailureKind(enum.Enum):
    """What kind of FAILURE ended the run, besides a rejected chunk's ``checks.CheckKind``."""

    MALFORMED_CHUNK = "malformed chunk"
    POLICY_ERROR = "policy error"
    POLICY_TIMEOUT = "policy timeout"
    CONTROLLER = "controller"
    GRIPPER = "gripper"
    SCENE_CHANGED = "scene changed"
    STALE_OBSERVATION = "stale observation"


POLICY_RUNS = "execute_policy.runs"
"""The ``RunContext.resources`` key of the metrics of every ExecutePolicy run of the Objective:
each node's, each time a RetryUntilSuccessful or a loop started it again."""


@dataclass
class RunMetrics:
    """What one run of an ExecutePolicy node did."""

    node: str = ""
    chunks: int = 0
    steps_executed: int = 0
    stall_seconds: float = 0.0
    rejections: int = 0
    gripper_clamped: int = 0
    """Gripper targets a little outside the gripper's range, clamped into it."""
    latencies: list[float] = field(default_factory=list)
    latency_estimate_s: float = 0.0
    """What the last request was timed for (``timing.LatencyEstimate``)."""
    goal_latency_max_s: float = 0.0
    """The longest a controller goal took from sending to its acceptance."""
    oldest_observation_s: float = 0.0
    """The age of the oldest camera frame or joint state fed to the policy (see ``max_observation_age``)."""
    warnings: list[str] = field(default_factory=list)
    message: str = ""
    rejection_reason: str = ""

    def as_dict(self) -> dict[str, Any]:
        lat = np.asarray(self.latencies) if self.latencies else np.zeros(1)
        return {
            "chunks": self.chunks,
            "steps_executed": self.steps_executed,
            "stall_seconds": round(self.stall_seconds, 4),
            "rejections": self.rejections,
            "gripper_clamped": self.gripper_clamped,
            "latency_p50_s": round(float(np.percentile(lat, 50)), 4),
            "latency_p95_s": round(float(np.percentile(lat, 95)), 4),
            "latency_max_s": round(float(lat.max()), 4),
            "latency_estimate_s": round(self.latency_estimate_s, 4),
            "goal_latency_max_s": round(self.goal_latency_max_s, 4),
            "oldest_observation_s": round(self.oldest_observation_s, 4),
            "warnings": list(self.warnings),
            "message": self.message,
            "rejection_reason": self.rejection_reason,
        }


def summarise_runs(runs: list[RunMetrics]) -> dict[str, Any]:
    """The ``execute_policy`` summary of every run: totals (counts and stall summed, latency
    percentiles over every round trip, the last run's estimate, message and rejection), then
    ``run_count`` and ``runs``, each run's own figures in the order they started."""
    last = runs[-1] if runs else RunMetrics()
    total = RunMetrics(
        chunks=sum(r.chunks for r in runs),
        steps_executed=sum(r.steps_executed for r in runs),
        stall_seconds=sum(r.stall_seconds for r in runs),
        rejections=sum(r.rejections for r in runs),
        gripper_clamped=sum(r.gripper_clamped for r in runs),
        latencies=[s for r in runs for s in r.latencies],
        latency_estimate_s=last.latency_estimate_s,
        goal_latency_max_s=max((r.goal_latency_max_s for r in runs), default=0.0),
        oldest_observation_s=max((r.oldest_observation_s for r in runs), default=0.0),
        warnings=[w for r in runs for w in r.warnings],
        message=last.message,
        rejection_reason=last.rejection_reason,
    )
    return {**total.as_dict(), "run_count": len(runs), "runs": [{"node": r.node, **r.as_dict()} for r in runs]}


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
        "checked against limits and the planning scene, and streamed to the trajectory controller "
        "(MoveIt Pro's admittance controller or a stock joint_trajectory_controller)."
    )

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
        import scipy.linalg  # noqa: F401  (the chunk fit's banded solver: loaded here, not in the first chunk's tick)

    def initialise(self) -> None:
        self.phase = Phase.STARTUP
        self.metrics = RunMetrics(node=self.name)
        self.context.resources.setdefault(POLICY_RUNS, []).append(self.metrics)
        self.message = ""
        self.rejection = ""
        self.started_at = self.context.clock.now()
        # The STREAM phase's state (see ``states``): the policy side, the controller side and
        # what is committed.
        self.request: InFlight | None = None
        self.held: HeldChunk | None = None
        self.goal = Goal()
        self.committed: Committed | None = None  # from the end of the warmup
        self.rollback: Rollback | None = None  # kept until the controller accepts the seam
        self.late_retries = 0  # of the chunk being sent
        self.latency = LatencyEstimate()
        self.goal_latency_s = 0.0
        """The slowest send -> accepted of a controller goal so far: zero in process, a tick or
        more over ROS."""
        self.next_scene_check_s = 0.0
        self.checked_scene: tuple[object, ...] | None = None  # what the committed samples were last checked against
        self.free_samples: FreeSamples | None = None  # the watch's last collision-free answer
        self.policy_chunk: np.ndarray | None = None
        self.policy_chunk_request_step = 0
        self.gripper_schedule: list[tuple[float, float]] = []
        self.gripper_plan: dict[int, float] = {}  # the last window's gripper targets, by run step
        self.gripper_sent: float | None = None
        self.gripper_goals: list[GripperGoal] = []
        self.warned_period = False
        self.warned_no_policy_chunk = False
        self.warned_sizing = SizingRisk.COVERED  # the worst sizing risk warned about so far
        self.chunk_steps: int | None = None  # the policy's chunk size, once an answer showed it
        try:
            self.config = self._read_config()
            cfg.validate(self.config)
            self.safety: MotionSafety = make_safety(self.context.scene, self.config.joint_group_name, self.config.gripper_joint_name or None)
        except (cfg.ConfigError, SafetyError) as err:  # the Objective does not fit this robot: ERROR, never retried
            raise self._setup_error(str(err)) from None
        c, bus = self.config, self.context.bus
        self.shaping = ShapingConfig(c.dt, c.committed_action_steps, c.policy_tracking_weight, c.num_interpolation_points,
                                     self.safety.limits.max_acceleration)
        self.policy = bus.create_client(c.policy_service_name, GetActionChunk)
        self.controller = ControllerLink(bus, c.controller_action_name, self.location, self.xml_id)
        self.gripper = bus.create_action_client(c.gripper_command_action_name, GripperCommand) if c.has_gripper else None
        self.joint_states = bus.create_subscription(c.joint_states_topic, JointState, reliable=True)
        # Best-effort matches both kinds of camera driver (most publish best-effort sensor-data QoS).
        self.cameras = [bus.create_subscription(t, Image, reliable=False) for t in c.image_topics]
        self.wrench = WrenchWatch(bus, c.wrench_topic, c.absolute_force_torque_threshold) if c.wrench_topic else None

    def update(self) -> Status:
        try:
            if self.phase is Phase.STARTUP:
                return self._startup()
            if self.phase is Phase.WARMUP:
                return self._warmup()
            return self._stream()
        except StaleObservation as err:  # a publisher stopped: what the world did, not the setup
            return self._stop(Status.FAILURE, str(err), FailureKind.STALE_OBSERVATION)
        except (ObservationError, SafetyError) as err:  # e.g. joint states without the group's joints
            raise self._setup_error(str(err)) from None

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID and getattr(self, "phase", Phase.DONE) is not Phase.DONE:
            self._cancel_goals()
            self.message = self.metrics.message = "halted: goals cancelled, robot stopped"
            self.context.events.emit("policy_halted", self.name)
            self.phase = Phase.DONE
        self._close_subscriptions()

    def run_summary(self) -> dict[str, Any]:
        """Every ExecutePolicy run of the Objective (``POLICY_RUNS``): totals and each run."""
        return {"execute_policy": summarise_runs(self.context.resources.get(POLICY_RUNS, []))}

    # -- phases ------------------------------------------------------------------------------
    def _startup(self) -> Status:
        c, now = self.config, self.context.clock.now()
        missing = []
        if not self.policy.service_is_ready():
            missing.append(f"policy service '{c.policy_service_name}' ({self._policy_hint()})")
        if not self.controller.ready():  # a name served with another type is an ERROR here
            missing.append(f"controller action '{c.controller_action_name}'")
        if self.gripper is not None and not self.gripper.server_is_ready():
            missing.append(f"gripper action '{c.gripper_command_action_name}'")
        if self.joint_states.latest is None:
            missing.append(f"joint states on '{c.joint_states_topic}' (the publisher must use reliable QoS)")
        if self.wrench is not None and not self.wrench.has_reading:
            missing.append(f"a reading on wrench topic '{c.wrench_topic}' (is force_torque_sensor_broadcaster active?)")
        timed_out = now - self.started_at >= STARTUP_WAIT_S
        if missing and not timed_out:
            return Status.RUNNING  # the cameras are looked at once the rest is there (a read may render a frame)
        frames = [sub.latest for sub in self.cameras]
        for topic, frame in zip(c.image_topics, frames):
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
        c, now = self.config, self.context.clock.now()
        flight = self.request
        assert flight is not None
        if not flight.future.done():
            if now - flight.sent_at_s > c.policy_call_timeout:
                flight.future.cancel()
                return self._finish(
                    Status.FAILURE,
                    kind=FailureKind.POLICY_TIMEOUT,
                    message=f"warming up the policy service '{c.policy_service_name}' timed out after {c.policy_call_timeout:g} s "
                    "(raise policy_call_timeout, or make the server finish its own warmup before it reports ready)",
                )
            return Status.RUNNING
        self.request = None
        try:
            response = flight.future.result()
        except Exception as exc:  # a transport failure of the warmup call
            return self._finish(Status.FAILURE, f"warming up the policy service '{c.policy_service_name}' failed: {exc}",
                                FailureKind.POLICY_ERROR)
        if response.status == GetActionChunk.Response.ERROR or response.status == GetActionChunk.Response.UNKNOWN:
            return self._finish(Status.FAILURE, self._status_reason(response, "warmup"), FailureKind.POLICY_ERROR)
        self.latency.update(now - flight.sent_at_s)
        self._note_chunk_size(response)
        self._check_sizing("measured latency")
        self.committed = Committed(StepGrid(now, c.dt, c.committed_action_steps, c.total_action_steps))
        self.phase = Phase.STREAM
        self._send_request(new_episode=True, request_step=0, frozen=self._frozen())
        return Status.RUNNING

    def _stream(self) -> Status:
        now = self.context.clock.now()
        status = self._watch_controller()  # first: an abort the controller already made is the reason
        if status is not None:
            return status
        crossing = self.wrench.crossing() if self.wrench is not None else None
        if crossing is not None:
            return self._stop(Status.FAILURE, f"force-torque threshold exceeded on '{self.config.wrench_topic}': {crossing}; goal cancelled, robot stopped")
        self._stream_gripper(now)
        problem = follow_goals(self.gripper_goals, self.config.gripper_command_action_name)
        if problem is not None:
            return self._stop(Status.FAILURE, problem, FailureKind.GRIPPER)
        self._track_progress(now)
        state = stream_state(self.held, self.request)
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
        if stream_state(self.held, self.request) is StreamState.SCHEDULING:
            self._maybe_request(now)  # also in the tick a chunk was sent: its next request may be due already
        status = self._watch_scene(now)
        if status is not None:
            return status
        committed = self._committed()
        if stream_finished(committed, self.request, self.goal):
            return self._stop(Status.SUCCESS, f"executed {committed.grid.total_steps} steps")
        return Status.RUNNING

    def _watch_scene(self, now: float) -> Status | None:
        """Check the rest of the committed motion again when the planning scene has changed."""
        samples = self._committed().samples
        if samples is None or now < self.next_scene_check_s - 1e-9:
            return None
        self.next_scene_check_s = now + SCENE_WATCH_PERIOD_S
        scene_state = self._scene_state()
        if scene_state == self.checked_scene:  # the remaining samples were checked against this very scene
            return None
        version, free = self.safety.scene.version, self.free_samples
        if free is not None and free.samples is samples and _gripper_key(free.gripper_position) == scene_state[1]:
            # Found free before with a gripper position this state does not tell apart: only the
            # world objects that moved since need a check, at the gripper position of then.
            gripper, free_at = free.gripper_position, free.scene_version
        else:
            gripper, free_at = self._gripper_now(), None
        collision = self.safety.first_collision(self.rules, _samples_from(samples, now), self.config.link_padding, gripper, free_at)
        if collision is not None:
            return self._stop(Status.FAILURE, f"the planning scene changed: {collision} in the remaining path; robot stopped",
                              FailureKind.SCENE_CHANGED)
        self.checked_scene = scene_state
        self.free_samples = FreeSamples(samples, gripper, version)
        return None

    # -- requests and responses --------------------------------------------------------------
    def _frozen(self) -> int:
        est = self.metrics.latency_estimate_s = self.latency.seconds
        tick_s = self.context.tick_period_s
        return frozen_prefix_steps(est, self.config.dt, prefetch_margin(est, tick_s) + 2 * self.goal_latency_s)

    def _maybe_request(self, now: float) -> None:
        grid = self._committed().grid
        if grid.remaining == 0:
            return
        frozen = self._frozen()
        step = next_request_step(grid, frozen, now)
        if step is not None:
            self._send_request(new_episode=False, request_step=step, frozen=frozen)

    def _send_request(self, new_episode: bool, request_step: int, frozen: int, frames: list[Image] | None = None) -> None:
        """Ask for the chunk of ``request_step`` with the camera frames of now (``frames``: read in this tick already)."""
        c = self.config
        request = GetActionChunk.Request()
        request.prompt = c.prompt
        request.robot_state = robot_state(self.joint_states.latest, self.safety.group_joints, c.gripper_joint_name or None, c.joint_states_topic)
        request.image_names = list(c.image_names)
        request.images = frames if frames is not None else [sub.latest for sub in self.cameras]
        now = self.context.clock.now()
        received = [(c.joint_states_topic, self.joint_states.received_at),
                    *zip(c.image_topics, (sub.received_at for sub in self.cameras))]
        self.metrics.oldest_observation_s = max([self.metrics.oldest_observation_s] + [now - at for _, at in received if at is not None])
        stale = stale_observation(now, received, c.observation_age_limit_s)
        if stale is not None:
            raise StaleObservation(stale)
        request.new_episode = new_episode
        request.frozen_prefix_steps = frozen
        request.guidance_horizon = c.guidance_horizon
        if c.policy_uses_real_time_chunking and self.policy_chunk is not None and not new_episode:
            request.previous_action_chunk = policy_tail(self.policy_chunk, request_step - self.policy_chunk_request_step)
            request.previous_anchor_state = self.previous_anchor
        self.request = InFlight(self.policy.call_async(request), now, request_step, frozen, request.robot_state)
        self.context.events.emit("chunk_requested", self.name, request_step=request_step, frozen_prefix_steps=frozen)

    def _receive(self, now: float) -> Status | None:
        c, flight = self.config, self.request
        assert flight is not None
        if not flight.future.done():
            if now - flight.sent_at_s > c.policy_call_timeout:
                flight.future.cancel()
                return self._stop(
                    Status.FAILURE,
                    kind=FailureKind.POLICY_TIMEOUT,
                    message=f"the policy service '{c.policy_service_name}' did not answer within policy_call_timeout = {c.policy_call_timeout:g} s",
                )
            return None
        self.request = None
        try:
            response = flight.future.result()
        except Exception as exc:
            return self._stop(Status.FAILURE, f"calling the policy service '{c.policy_service_name}' failed: {exc}",
                              FailureKind.POLICY_ERROR)
        self.latency.update(now - flight.sent_at_s)
        self.metrics.latencies.append(now - flight.sent_at_s)
        self._note_chunk_size(response)
        self._check_sizing("latency estimate", f" (the {self.latency.quantile * 100:.0f}th percentile of the last {len(self.latency.recent)} round trips)")
        if response.status == GetActionChunk.Response.NO_MORE_ACTIONS:
            return self._stop(Status.SUCCESS, f"the policy has no more actions: {response.message}".rstrip(": "))
        if response.status != GetActionChunk.Response.CHUNK_PRODUCED:
            return self._stop(Status.FAILURE, self._status_reason(response, f"chunk {self.metrics.chunks + 1}"), FailureKind.POLICY_ERROR)
        self.metrics.chunks += 1
        period = period_problem(response.native_control_period)
        if period is not None:
            return self._reject(f"chunk {self.metrics.chunks} rejected: {period}", FailureKind.MALFORMED_CHUNK.value)
        self._check_period(response.native_control_period)
        try:
            chunk = read_chunk(response.chunk, self.safety.group_joints, c.gripper_joint_name or None)
            policy_chunk = read_policy_chunk(response.policy_action_chunk) if c.policy_uses_real_time_chunking else None
        except ChunkError as err:
            return self._reject(f"chunk {self.metrics.chunks} rejected: {err}", FailureKind.MALFORMED_CHUNK.value)
        if c.policy_uses_real_time_chunking and policy_chunk is None and not self.warned_no_policy_chunk:
            self.warned_no_policy_chunk = True
            self._warn(f"policy_uses_real_time_chunking is true but chunk {self.metrics.chunks} carries no policy_action_chunk: "
                       "the policy gets no previous_action_chunk back, so real-time chunking does nothing (send it, or set "
                       "policy_uses_real_time_chunking=\"false\" for a policy without a denoising loop, such as the scripted oracle)")
        chunk = Chunk(chunk.arm, self._settle_gripper(chunk.gripper))
        problem = cfg.committed_window_problem(c.committed_action_steps, chunk.steps) if self.metrics.chunks == 1 else None
        if problem is not None:
            return self._reject(f"chunk 1 rejected: {problem}", SHORT_CHUNK)
        if self.metrics.chunks == 1:
            self._check_first_chunk_start(chunk, flight.anchor)
        self.late_retries = 0
        return self._plan_and_send(HeldChunk(chunk, response, flight), now)

    def _plan_and_send(self, held: HeldChunk, now: float) -> Status | None:
        """Plan ``held`` (``planner.plan_chunk``); send it, hold it, or end the run with its rejection."""
        c, committed = self.config, self._committed()
        grid = committed.grid
        rest_position = None
        if committed.motion is None:
            state = robot_state(self.joint_states.latest, self.safety.group_joints, None, c.joint_states_topic)
            rest_position = np.asarray(state.position, dtype=float)
        plan = plan_chunk(PlanInput(
            committed=committed,
            goal=self.goal.state,
            chunk=held.chunk,
            index=self.metrics.chunks,
            request_step=held.flight.request_step,
            frozen=held.flight.frozen,
            earliest_seam_step=earliest_seam_step(grid, now, self.context.tick_period_s, self.goal_latency_s),
            rest_position=rest_position,
            config=self.shaping,
            checks=PointChecks(self.safety, self.rules, c.link_padding, self._gripper_now(), grid),
            arrival=Arrival(grid.step_at_or_after(held.flight.future.ready_at),  # arrival, not when we looked
                            goal_takes_effect_s(now, self.context.tick_period_s, self.goal_latency_s)),
        ))
        if isinstance(plan, Reject):
            return self._reject(plan.reason, plan.kind)
        if not isinstance(plan, Planned):  # Wait
            self.held = held
            return None
        self._send_goal(held, plan, now)
        return None

    def _send_goal(self, held: HeldChunk, plan: Planned, now: float) -> None:
        """Send the planned motion to the controller and commit it: the one place a motion is sent."""
        c, window = self.config, plan.window
        samples = plan.committed.samples
        assert samples is not None
        self.metrics.stall_seconds += plan.stall_s
        # Kept until the controller accepts the seam: a goal refused only for arriving late is
        # planned again from the same chunk (see _retry_late_goal).
        self.rollback = Rollback(held, self._committed(), self.goal, plan.stall_s, window.index, plan.takes_over_s)
        self.checked_scene = self._scene_state()  # what the samples were checked against
        self.goal = Goal.send(self.controller.client, self._goal(samples, plan.takes_over_s, now), now)
        self.committed = plan.committed
        self._queue_gripper(held.chunk, window)
        if c.policy_uses_real_time_chunking:  # read (and checked) when the answer came in
            policy_chunk = read_policy_chunk(held.response.policy_action_chunk)
            self.policy_chunk, self.policy_chunk_request_step = policy_chunk, window.request_step
            self.previous_anchor = held.flight.anchor
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

    def _goal(self, samples: Samples, seam_time_s: float, now: float) -> Any:
        """The controller goal for ``samples`` (from the seam on): stamped at the seam for the
        admittance controller; for a JTC, led by the motion already sent from where the arm will
        be when the goal lands (``controller_link.jtc_stream_points``)."""
        c = self.config
        stamp_s, seam_index = seam_time_s, None
        if self.controller.kind is ControllerKind.JTC:
            lands_s = goal_takes_effect_s(now, self.context.tick_period_s, self.goal_latency_s)
            jtc = jtc_stream_points(self._committed().samples, samples, lands_s)
            stamp_s, samples, seam_index = jtc.stamp_s, jtc.samples, jtc.seam_index
        trajectory = trajectory_msg(samples, self.safety.group_joints, stamp_s, self.context.stamp_offset_s)
        if seam_index is not None:
            trajectory.points[seam_index].accelerations = []
        tolerances = GoalTolerances(c.goal_path_tolerance, max(0.5, 5 * c.dt), tuple(c.absolute_force_torque_threshold))
        return trajectory_goal(self.controller.kind, trajectory, tolerances)

    # -- controller and gripper --------------------------------------------------------------
    def _watch_controller(self) -> Status | None:
        goal, name = self.goal, self.config.controller_action_name
        if goal.state is GoalState.SENT:
            if not goal.send_future.done():
                if self.context.clock.now() - goal.sent_at_s > GOAL_ACK_TIMEOUT_S:
                    return self._stop(Status.FAILURE, f"the controller '{name}' did not acknowledge a goal within {GOAL_ACK_TIMEOUT_S:g} s",
                                      FailureKind.CONTROLLER)
                return None
            # arrival, not when we looked
            self.goal_latency_s = max(self.goal_latency_s, goal.send_future.ready_at - goal.sent_at_s)
            self.metrics.goal_latency_max_s = self.goal_latency_s
        self.goal = goal.advance()
        if self.goal.state is GoalState.REJECTED:
            self.goal = Goal()  # nothing of it is playing
            why = " (a joint_trajectory_controller gives its reason only in its own log)" if self.controller.kind is ControllerKind.JTC else ""
            return self._stop(Status.FAILURE, f"the controller '{name}' rejected the goal{why}", FailureKind.CONTROLLER)
        if self.goal.state is GoalState.ENDED and goal.state is not GoalState.ENDED:  # its result came now
            outcome = self.goal.outcome
            if outcome.status == STATUS_ABORTED or outcome.result.error_code not in (0,):
                if outcome.result.error_code == FollowTrajectory.Result.SUPERSEDED:
                    return None
                if self._retry_late_goal(outcome.result):
                    return None
                return self._stop(Status.FAILURE, f"the controller aborted the motion: {outcome.result.error_string}", FailureKind.CONTROLLER)
            if outcome.status != STATUS_SUCCEEDED:
                return self._stop(Status.FAILURE, f"the controller ended the motion: {outcome.result.error_string}", FailureKind.CONTROLLER)
        return None

    def _retry_late_goal(self, result: Any) -> bool:
        """A goal refused only because it reached the controller after its seam (a first goal on
        a new connection, a slow tick or a busy transport): the controller goes on with what it
        was playing, the previous window and its runout, or rest. So roll back to what was
        committed before it and plan the same chunk again from there, now with the measured
        delivery time: it joins the runout, or starts from rest. At most ``MAX_LATE_RETRIES``
        times per chunk."""
        sent = self.rollback
        if result.error_code not in LATE_GOAL_CODES or sent is None or self.late_retries >= MAX_LATE_RETRIES:
            return False
        self.late_retries += 1
        self.committed = sent.committed
        self.metrics.stall_seconds -= sent.stall_s  # the chunk that takes over counts the stall up to its own seam
        self.context.events.emit("chunk_rolled_back", self.name, stall_s=sent.stall_s)
        if sent.goal.state is GoalState.PLAYING:  # still playing (or its result is waiting to be read)
            self.goal = sent.goal
        late = (f"chunk {sent.chunk_index}'s goal reached the controller after t={sent.takes_over_s:.2f} s, the moment "
                f"it was meant to take over, so the controller went on with what it was playing")
        if self.held is not None:
            # A newer chunk arrived while this goal was unanswered: it takes over from what the
            # arm actually does, and the refused one is dropped.
            self._warn(f"{late}; the next chunk, already here, is planned from what the arm is doing")
            return True
        self.held = sent.held  # planned again next tick
        self._warn(f"{late}; the chunk is planned again from what the arm is doing")
        return True

    def _queue_gripper(self, chunk: Chunk, window: Window) -> None:
        if self.gripper is None or chunk.gripper is None:
            return
        grid = self._committed().grid
        steps = range(window.seam_step, window.end_step + grid.tail.extension_steps)  # the arm plays the extension too
        earlier = [s for s in self.gripper_plan if s < window.seam_step]  # the target in effect before the seam
        before = self.gripper_plan[max(earlier)] if earlier else self.gripper_sent
        limit = self.safety.chunk_limits[self.safety.gripper_joint]
        targets = join_targets(before, [float(chunk.gripper[s - window.request_step]) for s in steps], limit.max_velocity * grid.dt)
        self.gripper_plan = dict(zip(steps, targets))
        self.gripper_schedule = [(grid.time(s), target) for s, target in self.gripper_plan.items()]

    def _stream_gripper(self, now: float) -> None:
        target = None
        while self.gripper_schedule and self.gripper_schedule[0][0] <= now + 1e-9:
            target = self.gripper_schedule.pop(0)[1]
        if target is None or self.gripper is None:
            return
        if self.gripper_sent is not None and abs(target - self.gripper_sent) < GRIPPER_DEADBAND_RAD:
            return
        self.gripper_goals.append(GripperGoal(target, Goal.send(self.gripper, gripper_command(target, GRIPPER_MAX_EFFORT_N), now)))
        self.gripper_sent = target

    def _track_progress(self, now: float) -> None:
        committed = self._committed()
        if committed.motion is None:
            return
        self.metrics.steps_executed = max(self.metrics.steps_executed, committed.grid.steps_executed_by(now))

    # -- endings -----------------------------------------------------------------------------
    def _reject(self, reason: str, kind: str) -> Status:
        """End the run with a rejected chunk; ``kind`` is a ``CheckKind``'s value, ``SHORT_CHUNK``
        or ``FailureKind.MALFORMED_CHUNK``'s."""
        self.metrics.rejections += 1
        self.rejection = self.metrics.rejection_reason = reason
        self.context.events.emit("chunk_rejected", self.name, reason=reason, failure_kind=kind)
        return self._stop(Status.FAILURE, reason, kind)

    def _stop(self, status: Status, message: str, kind: FailureKind | str | None = None) -> Status:
        stall_s = stall_at_stop_s(self.committed, self.context.clock.now())
        self.metrics.stall_seconds += stall_s
        self._cancel_goals()
        return self._finish(status, message, kind, stall_s)

    def _finish(self, status: Status, message: str, kind: FailureKind | str | None = None, stall_s: float = 0.0) -> Status:
        """End the run with ``status``; a FAILURE says its ``kind`` (``Behavior.failure_kind``);
        ``stall_s``: how long the arm had been waiting for a chunk when it ended."""
        self.phase = Phase.DONE
        self.message = self.metrics.message = message
        self.feedback_message = message
        self.failure_kind = kind.value if isinstance(kind, FailureKind) else kind
        self._write_outputs()
        self.context.events.emit("policy_finished", self.name, status=status.value, message=message, stall_s=stall_s)
        if status is Status.SUCCESS:
            self.context.logger.info("%s: %s", self.name, message)
        return status

    def _setup_error(self, what: str) -> SetupError:
        """End this run for a mistake of the setup (goals cancelled, the message kept for the
        summary): the error to raise, which ends the whole run as ERROR."""
        self._cancel_goals()
        self.phase = Phase.DONE
        self.message = self.metrics.message = what
        self._write_outputs()
        self.context.events.emit("policy_finished", self.name, status="ERROR", message=what)
        return SetupError(what)

    def _cancel_goals(self) -> None:
        self.goal = self.goal.cancel()
        if self.request is not None:
            self.request.future.cancel()
            self.request = None
        self.held = None
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
        wrench = getattr(self, "wrench", None)
        for sub in [getattr(self, "joint_states", None), *getattr(self, "cameras", []), wrench.subscription if wrench else None]:
            if sub is not None:
                destroy(sub)
        self.cameras = []
        self.joint_states = None
        self.wrench = None

    # -- small helpers -----------------------------------------------------------------------
    def _committed(self) -> Committed:
        assert self.committed is not None, "the STREAM phase starts with a committed state"
        return self.committed

    def _scene_state(self) -> tuple[object, ...]:
        """What a collision check of the committed samples depends on, besides the samples."""
        return (self.safety.scene.version, _gripper_key(self._gripper_now()))

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

    def _note_chunk_size(self, response: Any) -> None:
        """Remember the policy's chunk size from an answer that carries a chunk (the sizing warning uses it)."""
        if response.status == GetActionChunk.Response.CHUNK_PRODUCED and response.chunk.points:
            self.chunk_steps = len(response.chunk.points)

    def _check_sizing(self, what: str, detail: str = "") -> None:
        """Warn, with the figures, when the latency outgrows the committed window: once, and
        once more if it later outgrows what the chunk's tail covers as well."""
        c = self.config
        risk = sizing_risk(c.committed_action_steps, c.dt, self.latency.seconds, self.chunk_steps)
        if risk > self.warned_sizing:
            self.warned_sizing = risk
            text = sizing_warning(c.committed_action_steps, c.dt, self.latency.seconds, what, detail, self.chunk_steps)
            assert text is not None
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
        for key in ("absolute_force_torque_threshold", "image_topics", "image_names"):
            values[key] = tuple(values[key])
        return cfg.PolicyRunConfig(**values)


def _gripper_key(position: float | None) -> float | None:
    """The gripper position as the scene watch compares it: a change below 1e-4 rad (a few
    micrometres at the fingertips) is no reason to check the committed samples again."""
    return None if position is None else round(position, 4)


def _samples_from(samples: Samples, t: float) -> Samples:
    """The samples at or after ``t``."""
    keep = samples.times >= t
    return Samples(samples.times[keep], samples.positions[keep], samples.velocities[keep], samples.accelerations[keep])


NODES = (ExecutePolicy,)
