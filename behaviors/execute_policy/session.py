"""One policy session: what every way of playing a policy's chunks does around the policy.

ExecutePolicy and each benchmark executor (``benchmarks/executors``) hold one ``PolicySession``;
they differ only in how they play the chunks (the ``Player`` the session calls). The session owns:

- the bus links (``connect``, ``links.py``): the GetActionChunk client, the controller action,
  the gripper action, the joint states, the cameras and the wrench watch; built once, and again
  only when a name read from the blackboard changed;
- one run's state (``begin``, from the node's ``initialise``): the config read from the ports,
  the robot's limits (``MotionSafety``, narrowed by the envelope ports), the run's metrics
  (``RunMetrics``, fed as things happen and never read to decide), its warnings
  (``run_warnings.RunWarnings``) and ``SessionRun``;
- the phases (``update``): STARTUP (what is waited for, ``startup.py``; 5 s, then an ERROR
  naming what is missing), WARMUP (one discarded request, ``new_episode=true``: the first round
  trip of the latency estimate), STREAM (the player plays), DONE;
- the requests (``request``: the robot state and camera frames of now, the stale-observation check)
  and the answers (``receive``): a chunk read with the contract (``answers.py``), its gripper
  column settled into its range;
- each STREAM tick's robot watch (``watch_robot``): the force-torque threshold and the gripper goals;
- the endings: ``fail`` (a ``failure.Failure``), ``stop`` (SUCCESS, and the end ``fail`` makes),
  ``setup_error`` (ERROR: a mistake of the setup, never retried) and ``halt``; the node's output
  ports and the ``policy_*`` events.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Protocol

import numpy as np
from numpy.typing import NDArray
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image

from runtime.app.terminal import bounded
from runtime.errors import PortError, SetupError
from runtime.tree.behavior import Behavior, Status
from runtime.tree.resources import Resource

from . import answers
from . import config as cfg
from . import startup
from ..controller_link import ControllerLink
from ..safety import MotionSafety, SafetyError, make_safety
from .chunk import Chunk
from .failure import Failure, FailureKind
from .gripper import GripperStream
from .links import SessionLinks, connect
from .metrics import RunMetrics
from .observation import ObservationError, StaleObservation, robot_state
from .policy_link import PolicyLink
from .run_warnings import RunWarnings
from .states import HeldChunk, Phase
from .stream import StepGrid, Window


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
    warnings: RunWarnings
    config: cfg.PolicyRunConfig | None = None
    """None until the ports are read (a run that ends on a mistake of them has none)."""
    safety: MotionSafety | None = None
    phase: Phase = Phase.STARTUP
    rules: Any = None
    """The collision rules of the run, taken when the robot is there."""
    chunks_received: int = 0
    last_chunk: tuple[Chunk, int] | None = None
    """The newest chunk read, with its request step (None from an answer until its chunk is read)."""
    message: str = ""
    rejection: str = ""


class PolicySession:
    """One node's policy session (see the module docstring): ``node`` is the behavior that runs it
    (its context, ports and status), ``player`` plays its chunks, ``runs_key`` is the
    ``RunContext.resources`` key of every run's ``RunMetrics``, ``fixed`` the config fields the
    node has no port for, and ``reads_policy_chunk`` whether answers' ``policy_action_chunk`` is
    read (besides when the run uses real-time chunking)."""

    def __init__(self, node: Behavior, player: Player, runs_key: Resource[list[RunMetrics]], fixed: Mapping[str, Any] | None = None,
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
            config = cfg.read_config(self.node, self.fixed)
            cfg.validate(config)
        except (PortError, cfg.ConfigError):  # a blackboard entry not set yet, or a mistake begin reports
            return
        self.connect(config)

    def connect(self, config: cfg.PolicyRunConfig) -> SessionLinks:
        """The bus links for ``config``'s names, built once: again only when a name read from the
        blackboard changed between runs (``links.connect``)."""
        self.links = connect(self.node, config, self.links)
        return self.links

    def begin(self) -> SessionRun:
        """Start a run (the node's ``initialise``): read and validate the config, build the robot's
        limits, connect, and reset the links. A config the robot does not fit is a SetupError."""
        context = self.node.context
        metrics = RunMetrics(node=self.node.name)
        context.resources.setdefault(self.runs_key, list).append(metrics)
        self.run = SessionRun(metrics, context.clock.now(), RunWarnings(self.warn))
        try:
            config = cfg.read_config(self.node, self.fixed)
            cfg.validate(config)
            safety = make_safety(context.scene, config.joint_group_name, config.gripper_joint_name or None)
            safety = safety.narrowed(config.envelope_overrides)
        except (cfg.ConfigError, SafetyError) as err:  # the Objective does not fit this robot: ERROR, never retried
            raise self.setup_error(str(err)) from None
        self.run.config, self.run.safety = config, safety
        self.connect(config).reset()
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
        """Wait for what the run needs (``startup.py``), then send the warmup."""
        run, links = self.run, self.links
        assert run is not None and links is not None
        config = self.config
        missing = startup.missing_links(links, config, self.node.context.bus)
        timed_out = now - run.started_at_s >= startup.STARTUP_WAIT_S
        if missing and not timed_out:
            return  # the cameras are looked at once the rest is there (a read may render a frame)
        frames = [sub.latest for sub in links.cameras]
        missing += startup.missing_frames(config.image_topics, frames)
        if missing:
            if timed_out:  # the Objective names what this robot does not have: ERROR, never retried
                raise self.setup_error(startup.not_available(missing))
            return
        run.rules = self.safety.snapshot()
        self.request(now, new_episode=True, frames=frames)
        run.phase = Phase.WARMUP
        self.node.context.events.emit("policy_warmup_sent", self.node.name)

    def _warmup(self, now: float) -> Status | None:
        """The warmup's answer, once it came: its round trip seeds the latency estimate, and the
        STREAM phase starts."""
        run, config, policy = self.run, self.config, self.policy
        assert run is not None
        if policy.timed_out(now, config.policy_call_timeout):
            return self.fail(startup.warmup_timed_out(config))
        answer = policy.answer(now)
        if answer is None:
            return None
        if answer.error is not None:  # a transport failure of the warmup call
            return self.fail(startup.warmup_failed(config, answer.error))
        response = answer.response
        if response.status == GetActionChunk.Response.ERROR or response.status == GetActionChunk.Response.UNKNOWN:
            # The warmup is the run's first request with its prompt, joints and cameras: a refusal
            # is of the setup (or of a policy not there to serve it), and a Retry would ask the same.
            raise self.setup_error(answers.status_reason(response, "warmup"))
        policy.latency.update(answer.round_trip_s)
        run.warnings.sizing(config, policy.latency.seconds, policy.chunk_steps, "measured latency")
        run.phase = Phase.STREAM
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
        """The chunk of the request in flight once it came, read with the contract
        (``answers.py``) and its gripper column settled (None while it has not come); a Status
        when the answer ends the run."""
        run, policy = self.run, self.policy
        assert run is not None
        config = self.config
        if policy.timed_out(now_s, config.policy_call_timeout):
            return self.fail(answers.timed_out(config))
        answer = policy.answer(now_s)
        if answer is None:
            return None
        if answer.error is not None:
            return self.fail(answers.call_failed(config, answer.error))
        response, flight = answer.response, answer.flight
        policy.latency.update(answer.round_trip_s)
        run.metrics.latencies.append(answer.round_trip_s)
        run.warnings.sizing(config, policy.latency.seconds, policy.chunk_steps, "latency estimate",
                            f" (the {policy.latency.quantile * 100:.0f}th percentile of the last {len(policy.latency.recent)} round trips)")
        if response.status == GetActionChunk.Response.NO_MORE_ACTIONS:
            return self.stop(Status.SUCCESS, answers.no_more_actions(response))
        if response.status != GetActionChunk.Response.CHUNK_PRODUCED:
            return self.fail(answers.not_a_chunk(response, run.chunks_received + 1))
        run.chunks_received += 1
        run.metrics.chunks += 1
        index = run.chunks_received
        run.last_chunk = None  # until this chunk is read
        read = answers.read_answer(response, index, config, self.safety.group_joints,
                                   config.policy_uses_real_time_chunking or self.reads_policy_chunk, run.warnings)
        if isinstance(read, Failure):
            return self.fail(read)
        chunk, policy_chunk = read
        chunk = Chunk(chunk.arm, self._settle_gripper(chunk.gripper))
        run.last_chunk = (chunk, flight.request_step)
        if index == 1:
            too_short = answers.first_chunk_problem(chunk, config)
            if too_short is not None:
                return self.fail(too_short)
            run.warnings.first_chunk_start(chunk, flight.anchor, self.safety.group_joints)
        return HeldChunk(chunk, flight, index, policy_chunk)

    def _settle_gripper(self, gripper: NDArray[np.float64] | None) -> NDArray[np.float64] | None:
        """The gripper column clamped into its range where it is a little outside
        (``safety.GRIPPER_BAND_FRACTION``): counted, and warned about once per run."""
        run, safety = self.run, self.safety
        assert run is not None
        settled = safety.settle_gripper_column(gripper)
        run.warnings.gripper_clamped(settled, safety)
        run.metrics.gripper_clamped += settled.clamped
        return settled.values

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

    def rest_position(self) -> NDArray[np.float64]:
        """Where a motion from rest starts (``SessionLinks.rest_position``): the reference the
        controller commands, else the measured positions of the newest joint state."""
        links = self.links
        assert links is not None
        return links.rest_position(self.safety.group_joints, self.config.joint_states_topic)

    def gripper_position(self) -> float | None:
        """The gripper joint's position in the newest joint state (None without a gripper or a state)."""
        joint = self.config.gripper_joint_name
        return self.links.gripper_position(joint) if self.links is not None else None

    def gripper_max_velocity_rad_s(self) -> float:
        assert self.safety.gripper_joint is not None  # asked only of a group with a gripper
        return self.safety.chunk_limits[self.safety.gripper_joint].max_velocity

    def queue_gripper_window(self, chunk: Chunk, window: Window, grid: StepGrid) -> None:
        """Stream the gripper column of ``window`` (``GripperStream.queue``)."""
        if self.gripper is not None:
            self.gripper.queue(chunk, window, grid, self.gripper_max_velocity_rad_s())

    def queue_gripper_at(self, times_s: NDArray[np.floating[Any]], targets: NDArray[np.float64] | None) -> None:
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

    # -- warnings (``run_warnings.py``) ------------------------------------------------------
    def warn(self, text: str) -> None:
        """A warning of the run (``RunWarnings.say``): kept in its metrics, logged, and an event."""
        self.metrics.warnings.append(text)
        self.node.context.logger.warning("%s: %s", self.node.name, text)
        self.node.context.events.emit("warning", self.node.name, message=text)
