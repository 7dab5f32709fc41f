"""One policy session: what every way of playing a policy's chunks does around the policy.

ExecutePolicy and each benchmark executor (``benchmarks/executors``) hold one ``PolicySession``;
they differ only in how they play the chunks (the ``Player`` the session calls). The session owns:

- the bus links (``connect``): the GetActionChunk client (``PolicyLink``), the controller action
  (``ControllerLink``), the gripper action (``GripperStream``), the joint states, the cameras and
  the wrench watch; built once, and again only when a name read from the blackboard changed;
- one run's state (``begin``, from the node's ``initialise``): the config read from the ports,
  the robot's limits (``MotionSafety``, narrowed by the envelope ports), the run's metrics
  (``RunMetrics``, fed as things happen and never read to decide) and ``SessionRun``;
- the phases (``update``): STARTUP (the policy service, the controller and gripper actions, the
  joint states and a wrench reading, then a frame on every camera; 5 s, then an ERROR naming what
  is missing), WARMUP (one discarded request, ``new_episode=true``: the first round trip of the
  latency estimate), STREAM (the player plays), DONE;
- the requests (``request``: the robot state and camera frames of now, the stale-observation check)
  and the answers (``receive``): a chunk read with the contract (``chunk.read_chunk``: joint names,
  shape, finite values; the step period; a first chunk longer than the window), its gripper column
  settled into its range, and the warnings (step period, sizing, the first chunk's start, a
  real-time-chunking policy that sends no policy chunk);
- each STREAM tick's robot watch (``watch_robot``): the force-torque threshold and the gripper goals;
- the endings: ``fail`` (a ``failure.Failure``), ``stop`` (SUCCESS, and the end ``fail`` makes),
  ``setup_error`` (ERROR: a mistake of the setup, never retried) and ``halt``; the node's output
  ports and the ``policy_*`` events.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol

import numpy as np
from control_msgs.action import GripperCommand
from control_msgs.msg import JointTrajectoryControllerState
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image, JointState

from runtime.app.terminal import bounded
from runtime.errors import PortError, SetupError
from runtime.io.bus import Bus, ServedListing, capability
from runtime.tree.behavior import Behavior, Status
from runtime.tree.ports import Direction

from . import config as cfg
from ..controller_link import ControllerLink, controller_topic, reference_position
from ..safety import MotionSafety, SafetyError, make_safety
from ..wrench_watch import WrenchWatch
from .chunk import Chunk, ChunkError, period_problem, read_chunk, read_policy_chunk
from .failure import Failure, FailureKind
from .gripper import GripperStream
from .metrics import RunMetrics
from .observation import ObservationError, StaleObservation, robot_state
from .policy_link import PolicyLink
from .states import HeldChunk, Phase
from .stream import StepGrid, Window
from .timing import SizingRisk, sizing_risk, sizing_warning

STARTUP_WAIT_S = 5.0
FIRST_CHUNK_GAP_RAD = 0.2
"""A first chunk whose step 0 is further than this from the arm (on any joint) is warned about."""
TUPLE_PORTS = ("absolute_force_torque_threshold", "image_topics", "image_names", "tcp_keep_in_box")
"""The ports read as lists that ``PolicyRunConfig`` keeps as tuples."""
STATUS_NAMES = {0: "UNKNOWN", 1: "CHUNK_PRODUCED", 2: "NO_MORE_ACTIONS", 3: "ERROR"}
"""GetActionChunk's response statuses, by value."""


class Player(Protocol):
    """How a node plays the chunks: what the session calls back."""

    def begin_stream(self, now_s: float) -> Status | None:
        """The warmup answered: the STREAM phase starts (ask for the first chunk). A Status ends the run."""
        ...

    def play(self, now_s: float) -> Status | None:
        """One STREAM tick. A Status ends the run."""
        ...

    def cancel_motion(self) -> None:
        """Stop the controller's motion (the run ends in the STREAM phase)."""
        ...

    def stall_at_stop_s(self, now_s: float) -> float:
        """How long the arm has been waiting for a chunk when the run ends at ``now_s``."""
        ...

    def chunk_plot(self, chunk: Chunk, request_step: int) -> dict[str, Any]:
        """A rejected chunk on the clock, for the report to plot (``chunk_rejected``'s data)."""
        ...


@dataclass
class SessionRun:
    """What one run of the session knows; built by ``PolicySession.begin``."""

    metrics: RunMetrics
    started_at_s: float
    config: cfg.PolicyRunConfig | None = None
    """None until the ports are read (a run that ends on a mistake of them has none)."""
    safety: MotionSafety | None = None
    phase: Phase = Phase.STARTUP
    rules: Any = None
    """The collision rules of the run, taken when the robot is there."""
    chunks_received: int = 0
    last_chunk: tuple[Chunk, int] | None = None
    """The newest chunk read, with its request step (None from an answer until its chunk is read)."""
    first_period_s: float | None = None
    """The step period the first chunk that gave one said (``native_control_period``)."""
    warned_period_change: bool = False
    warned_no_policy_chunk: bool = False
    warned_gripper_clamped: bool = False
    warned_sizing: SizingRisk = SizingRisk.COVERED
    """The worst sizing risk warned about so far."""
    message: str = ""
    rejection: str = ""


@dataclass
class SessionLinks:
    """The bus links of the names in ``names`` (``PolicySession.connect``)."""

    names: tuple[object, ...]
    policy: PolicyLink
    controller: ControllerLink
    gripper: GripperStream | None
    joint_states: Any
    controller_state: Any
    """The controller's ``~/controller_state`` (where a motion from rest starts)."""
    cameras: list[Any] = field(default_factory=list)
    wrench: WrenchWatch | None = None


def read_config(node: Behavior, fixed: Mapping[str, Any]) -> cfg.PolicyRunConfig:
    """The run's config from ``node``'s input ports; ``fixed``: the values of the fields the node
    has no port for."""
    fields = cfg.PolicyRunConfig.__dataclass_fields__
    values = {p.name: node.get_input(p.name) for p in node.ports if p.direction is Direction.INPUT and p.name in fields}
    for key in TUPLE_PORTS:
        if key in values:
            values[key] = tuple(values[key])
    return cfg.PolicyRunConfig(**values, **fixed)


class PolicySession:
    """One node's policy session (see the module docstring): ``node`` is the behavior that runs it
    (its context, ports and status), ``player`` plays its chunks, ``runs_key`` is the
    ``RunContext.resources`` key of every run's ``RunMetrics``, ``fixed`` the config fields the
    node has no port for, and ``reads_policy_chunk`` whether answers' ``policy_action_chunk`` is
    read (besides when the run uses real-time chunking)."""

    def __init__(self, node: Behavior, player: Player, runs_key: str, fixed: Mapping[str, Any] | None = None,
                 reads_policy_chunk: bool = False) -> None:
        self.node, self.player, self.runs_key = node, player, runs_key
        self.fixed = dict(fixed or {})
        self.reads_policy_chunk = reads_policy_chunk
        self.links: SessionLinks | None = None
        self.run: SessionRun | None = None

    # -- links and runs ----------------------------------------------------------------------
    def setup(self) -> None:
        """Build the bus links when the names are known before the run (literal ports); a name
        read from the blackboard is known when the node first runs."""
        try:
            config = read_config(self.node, self.fixed)
            cfg.validate(config)
        except (PortError, cfg.ConfigError):  # a blackboard entry not set yet, or a mistake begin reports
            return
        self.connect(config)

    def connect(self, config: cfg.PolicyRunConfig) -> SessionLinks:
        """The bus links for ``config``'s names, built once: again only when a name read from the
        blackboard changed between runs."""
        names = (config.policy_service_name, config.controller_action_name,
                 config.gripper_command_action_name if config.has_gripper else None,
                 config.joint_states_topic, config.image_topics, config.wrench_topic, config.absolute_force_torque_threshold)
        if self.links is not None and self.links.names == names:
            return self.links
        self._close_subscriptions()
        node, bus = self.node, self.node.context.bus
        self.links = SessionLinks(
            names=names,
            policy=PolicyLink(bus.create_client(config.policy_service_name, GetActionChunk)),
            controller=ControllerLink(bus, config.controller_action_name, node.location, node.xml_id),
            gripper=(GripperStream(bus.create_action_client(config.gripper_command_action_name, GripperCommand),
                                   config.gripper_command_action_name) if config.has_gripper else None),
            joint_states=bus.create_subscription(config.joint_states_topic, JointState, reliable=True),
            controller_state=bus.create_subscription(controller_topic(config.controller_action_name, "controller_state"),
                                                     JointTrajectoryControllerState, reliable=False),
            # Best-effort matches both kinds of camera driver (most publish best-effort sensor-data QoS).
            cameras=[bus.create_subscription(t, Image, reliable=False) for t in config.image_topics],
            wrench=WrenchWatch(bus, config.wrench_topic, config.absolute_force_torque_threshold) if config.wrench_topic else None,
        )
        return self.links

    def _close_subscriptions(self) -> None:
        if self.links is None:
            return
        links, bus = self.links, self.node.context.bus
        for sub in [links.joint_states, links.controller_state, *links.cameras, links.wrench.subscription if links.wrench else None]:
            if sub is not None:
                bus.destroy_subscription(sub)

    def begin(self) -> SessionRun:
        """Start a run (the node's ``initialise``): read and validate the config, build the robot's
        limits, connect, and reset the links. A config the robot does not fit is a SetupError."""
        context = self.node.context
        metrics = RunMetrics(node=self.node.name)
        context.resources.setdefault(self.runs_key, []).append(metrics)
        self.run = SessionRun(metrics, context.clock.now())
        try:
            config = read_config(self.node, self.fixed)
            cfg.validate(config)
            safety = make_safety(context.scene, config.joint_group_name, config.gripper_joint_name or None)
            safety = safety.narrowed(config.envelope_overrides)
        except (cfg.ConfigError, SafetyError) as err:  # the Objective does not fit this robot: ERROR, never retried
            raise self.setup_error(str(err)) from None
        self.run.config, self.run.safety = config, safety
        links = self.connect(config)
        for part in (links.policy, links.gripper, links.wrench):
            if part is not None:
                part.reset()
        return self.run

    @property
    def phase(self) -> Phase:
        return self.run.phase if self.run is not None else Phase.DONE

    @property
    def config(self) -> cfg.PolicyRunConfig:
        assert self.run is not None and self.run.config is not None, "begin() starts a run"
        return self.run.config

    @property
    def safety(self) -> MotionSafety:
        assert self.run is not None and self.run.safety is not None, "begin() starts a run"
        return self.run.safety

    @property
    def metrics(self) -> RunMetrics:
        assert self.run is not None, "begin() starts a run"
        return self.run.metrics

    @property
    def policy(self) -> PolicyLink:
        assert self.links is not None, "begin() connects the links"
        return self.links.policy

    @property
    def controller_link(self) -> ControllerLink:
        assert self.links is not None, "begin() connects the links"
        return self.links.controller

    @property
    def gripper(self) -> GripperStream | None:
        return self.links.gripper if self.links is not None else None

    # -- phases ------------------------------------------------------------------------------
    def update(self) -> Status:
        """One tick of the run: STARTUP, WARMUP, or the player's STREAM tick."""
        assert self.run is not None, "begin() starts a run"
        now = self.node.context.clock.now()
        try:
            if self.run.phase is Phase.STARTUP:
                self._startup(now)
                return Status.RUNNING
            if self.run.phase is Phase.WARMUP:
                return self._warmup(now) or Status.RUNNING
            return self.player.play(now) or Status.RUNNING
        except StaleObservation as err:  # a publisher stopped: what the world did, not the setup
            return self.fail(Failure(FailureKind.STALE_OBSERVATION, str(err)))
        except (ObservationError, SafetyError) as err:  # e.g. joint states without the group's joints
            raise self.setup_error(str(err)) from None

    def _startup(self, now: float) -> None:
        run, links = self.run, self.links
        assert run is not None and links is not None
        config = self.config
        missing = []
        if not links.policy.ready():
            missing.append(f"policy service '{config.policy_service_name}' ({policy_hint(self.node.context.bus)})")
        if not links.controller.ready():  # a name served with another type is an ERROR here
            missing.append(f"controller action '{config.controller_action_name}'")
        if links.gripper is not None and not links.gripper.ready():
            missing.append(f"gripper action '{config.gripper_command_action_name}'")
        if links.joint_states.latest is None:
            missing.append(f"joint states on '{config.joint_states_topic}' (the publisher must use reliable QoS)")
        if links.wrench is not None and not links.wrench.has_reading:
            missing.append(f"a reading on wrench topic '{config.wrench_topic}' (is force_torque_sensor_broadcaster active?)")
        timed_out = now - run.started_at_s >= STARTUP_WAIT_S
        if missing and not timed_out:
            return  # the cameras are looked at once the rest is there (a read may render a frame)
        frames = [sub.latest for sub in links.cameras]
        for topic, frame in zip(config.image_topics, frames):
            if frame is None:
                missing.append(f"a frame on camera topic '{topic}' (subscribed best-effort, so a reliable or a "
                               "best-effort publisher matches; is the camera driver publishing there?)")
        if missing:
            if timed_out:  # the Objective names what this robot does not have: ERROR, never retried
                raise self.setup_error(f"not available after {STARTUP_WAIT_S:.0f} s: " + "; ".join(missing))
            return
        run.rules = self.safety.snapshot()
        self.request(now, new_episode=True, frames=frames)
        run.phase = Phase.WARMUP
        self.node.context.events.emit("policy_warmup_sent", self.node.name)

    def _warmup(self, now: float) -> Status | None:
        config, policy = self.config, self.policy
        if policy.timed_out(now, config.policy_call_timeout):
            return self.fail(Failure(
                FailureKind.POLICY_TIMEOUT,
                f"warming up the policy service '{config.policy_service_name}' timed out after {config.policy_call_timeout:g} s "
                "(raise policy_call_timeout, or make the server finish its own warmup before it reports ready)"))
        answer = policy.answer(now)
        if answer is None:
            return None
        if answer.error is not None:  # a transport failure of the warmup call
            return self.fail(Failure(FailureKind.POLICY_ERROR,
                                     f"warming up the policy service '{config.policy_service_name}' failed: {answer.error}"))
        response = answer.response
        if response.status == GetActionChunk.Response.ERROR or response.status == GetActionChunk.Response.UNKNOWN:
            # The warmup is the run's first request with its prompt, joints and cameras: a refusal
            # is of the setup (or of a policy not there to serve it), and a Retry would ask the same.
            raise self.setup_error(status_reason(response, "warmup"))
        policy.latency.update(answer.round_trip_s)
        self._check_sizing("measured latency")
        assert self.run is not None
        self.run.phase = Phase.STREAM
        return self.player.begin_stream(now)

    # -- requests and answers ----------------------------------------------------------------
    def request(self, now_s: float, new_episode: bool = False, request_step: int = 0, frozen: int = 0,
                frames: list[Image] | None = None, config: cfg.PolicyRunConfig | None = None) -> None:
        """Ask for the chunk of ``request_step`` with the robot state and camera frames of now
        (``frames``: read in this tick already); ``config``: the run's, or one with other
        real-time-chunking settings. Raises StaleObservation when an observation is too old."""
        links = self.links
        assert links is not None
        config = config or self.config
        state = robot_state(links.joint_states.latest, self.safety.group_joints, config.gripper_joint_name or None,
                            config.joint_states_topic)
        frames = frames if frames is not None else [sub.latest for sub in links.cameras]  # a read may render a frame
        received = [(config.joint_states_topic, links.joint_states.received_at),
                    *zip(config.image_topics, (sub.received_at for sub in links.cameras))]
        metrics = self.metrics
        metrics.oldest_observation_s = max([metrics.oldest_observation_s] + [now_s - at for _, at in received if at is not None])
        links.policy.send(config, state, frames, received, now_s, new_episode, request_step, frozen)
        self.node.context.events.emit("chunk_requested", self.node.name, request_step=request_step, frozen_prefix_steps=frozen)

    @property
    def asking(self) -> bool:
        """Whether a request is in flight."""
        return self.policy.request is not None

    def receive(self, now_s: float) -> HeldChunk | Status | None:
        """The chunk of the request in flight once it came, read with the contract and its gripper
        column settled (None while it has not come); a Status when the answer ends the run."""
        run, policy = self.run, self.policy
        assert run is not None
        config = self.config
        if policy.timed_out(now_s, config.policy_call_timeout):
            return self.fail(Failure(
                FailureKind.POLICY_TIMEOUT,
                f"the policy service '{config.policy_service_name}' did not answer within policy_call_timeout = {config.policy_call_timeout:g} s"))
        answer = policy.answer(now_s)
        if answer is None:
            return None
        if answer.error is not None:
            return self.fail(Failure(FailureKind.POLICY_ERROR, f"calling the policy service '{config.policy_service_name}' failed: {answer.error}"))
        response, flight = answer.response, answer.flight
        policy.latency.update(answer.round_trip_s)
        run.metrics.latencies.append(answer.round_trip_s)
        self._check_sizing("latency estimate", f" (the {policy.latency.quantile * 100:.0f}th percentile of the last {len(policy.latency.recent)} round trips)")
        if response.status == GetActionChunk.Response.NO_MORE_ACTIONS:
            return self.stop(Status.SUCCESS, f"the policy has no more actions: {response.message}".rstrip(": "))
        if response.status != GetActionChunk.Response.CHUNK_PRODUCED:
            return self.fail(Failure(FailureKind.POLICY_ERROR, status_reason(response, f"chunk {run.chunks_received + 1}")))
        run.chunks_received += 1
        run.metrics.chunks += 1
        index = run.chunks_received
        run.last_chunk = None  # until this chunk is read
        period = period_problem(response.native_control_period)
        if period is not None:
            return self.fail(Failure(FailureKind.MALFORMED_CHUNK, f"chunk {index} rejected: {period}"))
        self._check_period(response.native_control_period, index)
        reads_policy_chunk = config.policy_uses_real_time_chunking or self.reads_policy_chunk
        try:
            chunk = read_chunk(response.chunk, self.safety.group_joints, config.gripper_joint_name or None)
            policy_chunk = read_policy_chunk(response.policy_action_chunk) if reads_policy_chunk else None
        except ChunkError as err:
            return self.fail(Failure(FailureKind.MALFORMED_CHUNK, f"chunk {index} rejected: {err}"))
        if config.policy_uses_real_time_chunking and policy_chunk is None and not run.warned_no_policy_chunk:
            run.warned_no_policy_chunk = True
            self.warn(f"policy_uses_real_time_chunking is true but chunk {index} carries no policy_action_chunk: "
                      "the policy gets no previous_action_chunk back, so real-time chunking does nothing (send it, or set "
                      "policy_uses_real_time_chunking=\"false\" for a policy without a denoising loop)")
        chunk = Chunk(chunk.arm, self._settle_gripper(chunk.gripper))
        run.last_chunk = (chunk, flight.request_step)
        if index == 1:
            problem = cfg.committed_window_problem(config.committed_action_steps, chunk.steps)
            if problem is not None:
                return self.fail(Failure(FailureKind.SHORT_CHUNK, f"chunk 1 rejected: {problem}"))
            self._check_first_chunk_start(chunk, flight.anchor)
        return HeldChunk(chunk, flight, index, policy_chunk)

    # -- the robot ---------------------------------------------------------------------------
    def watch_robot(self, now_s: float) -> Status | None:
        """The force-torque watch and the gripper goals (due targets sent, answers read): a Status
        when either ends the run."""
        links = self.links
        assert links is not None
        crossing = links.wrench.crossing() if links.wrench is not None else None
        if crossing is not None:
            return self.fail(Failure(
                FailureKind.FORCE_TORQUE,
                f"force-torque threshold exceeded on '{self.config.wrench_topic}': {crossing}; goal cancelled, robot stopped"))
        if links.gripper is not None:
            links.gripper.stream(now_s)
            problem = links.gripper.follow()
            if problem is not None:
                return self.fail(Failure(FailureKind.GRIPPER, problem))
        return None

    def rest_position(self) -> np.ndarray:
        """Where a motion from rest starts: the reference the controller commands, when it
        publishes its state (``~/controller_state``) for the group's joints, else the measured
        positions of the newest joint state. A JTC that interpolates from its desired state (as
        a JTC that plays streamed goals should) starts the next trajectory from its reference; at
        rest under load the measured state lies off it (a few mrad in the simulated cell), and a
        first point there would be a jump the controller plays within one control step."""
        links = self.links
        assert links is not None
        reference = reference_position(links.controller_state.latest, self.safety.group_joints)
        if reference is not None:
            return reference
        state = robot_state(links.joint_states.latest, self.safety.group_joints, None, self.config.joint_states_topic)
        return np.asarray(state.position, dtype=float)

    def gripper_position(self) -> float | None:
        """The gripper joint's position in the newest joint state (None without a gripper or a state)."""
        joint = self.config.gripper_joint_name
        state = self.links.joint_states.latest if self.links is not None else None
        if not joint or state is None or joint not in state.name:
            return None
        return float(state.position[list(state.name).index(joint)])

    def gripper_max_velocity_rad_s(self) -> float:
        return self.safety.chunk_limits[self.safety.gripper_joint].max_velocity

    def queue_gripper_window(self, chunk: Chunk, window: Window, grid: StepGrid) -> None:
        """Stream the gripper column of ``window`` (``GripperStream.queue``)."""
        if self.gripper is not None:
            self.gripper.queue(chunk, window, grid, self.gripper_max_velocity_rad_s())

    def queue_gripper_at(self, times_s: np.ndarray, targets: np.ndarray | None) -> None:
        """Stream the gripper targets ``targets[k]`` due at ``times_s[k]`` (``GripperStream.queue_at``)."""
        if self.gripper is not None and targets is not None:
            self.gripper.queue_at(times_s, targets, self.gripper_max_velocity_rad_s() * self.config.dt)

    # -- endings -----------------------------------------------------------------------------
    def fail(self, failure: Failure) -> Status:
        """End the run with ``failure``, the robot stopped; a rejected chunk is counted and its
        values go with the ``chunk_rejected`` event."""
        run = self.run
        assert run is not None
        if failure.rejects_chunk:
            run.metrics.rejections += 1
            run.rejection = run.metrics.rejection_reason = failure.detail
            plot = self.player.chunk_plot(*run.last_chunk) if run.last_chunk is not None else {}
            self.node.context.events.emit("chunk_rejected", self.node.name, reason=failure.detail, failure_kind=failure.kind.value, **plot)
        return self.stop(Status.FAILURE, failure)

    def stop(self, status: Status, ending: Failure | str) -> Status:
        """End the run with ``status``, the goals cancelled: ``ending`` is a ``Failure`` (its kind is
        the node's ``failure_kind``; ``fail`` ends a run with one) or the message of a SUCCESS.
        The message may carry the policy's own text: it is kept ``bounded``."""
        run = self.run
        assert run is not None
        stall_s = self.player.stall_at_stop_s(self.node.context.clock.now()) if run.phase is Phase.STREAM else 0.0
        run.metrics.stall_seconds += stall_s
        self.cancel()
        message = bounded(ending.detail if isinstance(ending, Failure) else ending)
        run.phase = Phase.DONE
        run.message = run.metrics.message = message
        self.node.feedback_message = message
        self.node.failure_kind = ending.kind.value if isinstance(ending, Failure) else None
        self.write_outputs()
        self.node.context.events.emit("policy_finished", self.node.name, status=status.value, message=message, stall_s=stall_s)
        if status is Status.SUCCESS:
            self.node.context.logger.info("%s: %s", self.node.name, message)
        return status

    def setup_error(self, what: str) -> SetupError:
        """End this run for a mistake of the setup (goals cancelled, the message kept for the
        summary): the error to raise, which ends the whole run as ERROR."""
        run = self.run
        assert run is not None
        self.cancel()
        what = bounded(what)
        run.phase = Phase.DONE
        run.message = run.metrics.message = what
        self.write_outputs()
        self.node.context.events.emit("policy_finished", self.node.name, status="ERROR", message=what)
        return SetupError(what)

    def halt(self) -> None:
        """The node was halted: cancel the goals (the controller stops the arm)."""
        run = self.run
        if run is None or run.phase is Phase.DONE:
            return
        self.cancel()
        run.message = run.metrics.message = "halted: goals cancelled, robot stopped"
        self.node.context.events.emit("policy_halted", self.node.name)
        run.phase = Phase.DONE

    def cancel(self) -> None:
        """Cancel the controller's motion (in the STREAM phase), the request in flight and the
        gripper targets not sent yet."""
        if self.run is not None and self.run.phase is Phase.STREAM:
            self.player.cancel_motion()
        if self.links is not None:
            self.links.policy.cancel()
            if self.links.gripper is not None:
                self.links.gripper.cancel()

    def write_outputs(self) -> None:
        run = self.run
        assert run is not None
        outputs = {
            "steps_executed": run.metrics.steps_executed,
            "chunks_received": run.chunks_received,
            "rejection_reason": run.rejection,
            "status_message": run.message,
        }
        for name, value in outputs.items():
            self.node.set_output(name, value)

    # -- warnings ----------------------------------------------------------------------------
    def warn(self, text: str) -> None:
        """A warning of the run: kept in its metrics, logged, and an event."""
        self.metrics.warnings.append(text)
        self.node.context.logger.warning("%s: %s", self.node.name, text)
        self.node.context.events.emit("warning", self.node.name, message=text)

    def _check_sizing(self, what: str, detail: str = "") -> None:
        """Warn, with the figures, when the latency outgrows the sent window: once, and
        once more if it later outgrows what the chunk's tail covers as well."""
        run, policy = self.run, self.policy
        assert run is not None
        config = self.config
        risk = sizing_risk(config.committed_action_steps, config.dt, policy.latency.seconds, policy.chunk_steps)
        if risk > run.warned_sizing:
            run.warned_sizing = risk
            text = sizing_warning(config.committed_action_steps, config.dt, policy.latency.seconds, what, detail, policy.chunk_steps)
            assert text is not None
            self.warn(text)

    def _check_period(self, period: float, chunk_number: int) -> None:
        """Warn once when the first chunk's step period differs from ``dt``, and once when a later
        chunk's differs from the first's (0: the policy gives none)."""
        run = self.run
        assert run is not None
        dt = self.config.dt
        if period <= 0:
            return
        if run.first_period_s is None:
            run.first_period_s = period
            if abs(period - dt) > 1e-6:
                self.warn(f"the policy was trained at {period:g} s per step but dt is {dt:g} s: the motion plays "
                          f"{period / dt:.2f}x as fast as trained (the chunk is not retimed)")
            return
        if abs(period - run.first_period_s) > 1e-6 and not run.warned_period_change:
            run.warned_period_change = True
            self.warn(f"chunk {chunk_number} says the policy steps every {period:g} s, but the first chunk said "
                      f"{run.first_period_s:g} s: every chunk is played at dt = {dt:g} s per step (not retimed)")

    def _check_first_chunk_start(self, chunk: Chunk, anchor: Any) -> None:
        """Warn when the first chunk starts far from where the arm was at its request
        (``FIRST_CHUNK_GAP_RAD``): it is blended in, but such a gap is usually a wrong joint
        order, unit or robot state."""
        at_request = np.asarray(anchor.position[:chunk.arm.shape[1]], dtype=float)
        gap = np.abs(chunk.arm[0] - at_request)
        if float(gap.max()) > FIRST_CHUNK_GAP_RAD:
            joint = self.safety.group_joints[int(np.argmax(gap))]
            self.warn(f"chunk 1 starts {float(gap.max()):.3f} rad from where the arm was at its request (joint {joint}; "
                      f"more than {FIRST_CHUNK_GAP_RAD} rad): it is blended in, but check the policy's joint order, "
                      "units and the state it was given")

    def _settle_gripper(self, gripper: np.ndarray | None) -> np.ndarray | None:
        """The gripper column clamped into its range where it is a little outside
        (``safety.GRIPPER_BAND_FRACTION``): counted, and warned about once per run."""
        run, safety = self.run, self.safety
        assert run is not None
        settled = safety.settle_gripper_column(gripper)
        if settled.clamped and not run.warned_gripper_clamped:
            run.warned_gripper_clamped = True
            limit = safety.chunk_limits[safety.gripper_joint]
            self.warn(
                f"the policy's gripper column leaves the range {limit.lower:.4f}..{limit.upper:.4f} rad by up to "
                f"{settled.farthest_rad:.4f} rad (within the {safety.gripper_band_rad():.4f} rad band): such values are "
                "clamped into the range and counted (gripper_clamped); further out a chunk is rejected"
            )
        run.metrics.gripper_clamped += settled.clamped
        return settled.values


def policy_hint(bus: Bus) -> str:
    """What to do about a missing policy service, in the mode the run on ``bus`` is in."""
    listing = capability(bus, ServedListing)
    if listing is None:  # a ROS 2 graph: the adapter serves the policy
        return "start the adapter (`objective adapter`) before running the Objective"
    names = ", ".join(sorted(listing.served())) or "none"
    return f"in this run the world serves the policy chosen with --policy; services here: {names}"


def status_reason(response: Any, what: str) -> str:
    """Why an answer that is not a chunk ends the run: its status and the policy's message."""
    status = STATUS_NAMES.get(response.status, f"status {response.status}")
    detail = response.message or ("the policy left the status unset" if response.status == 0 else "no message")
    return f"the policy answered {status} for the {what}: {detail}"
