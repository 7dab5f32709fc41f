"""What the benchmark executors share with ExecutePolicy: the ports, the start-up, the policy
requests and answers, the chunk's reading, the gripper and the wrench watch.

``ChunkExecutor`` runs the phases STARTUP (the policy service, the controller and gripper
actions, every camera and the joint states; 5 s, then an ERROR naming what is missing) and WARMUP
(one discarded request, ``new_episode=true``) as ExecutePolicy does, then RUN, where each tick
follows the gripper goals and the wrench and hands over to the executor's own ``run_tick``. A
subclass decides when to ask for a chunk (``ask``), what to do with one that came (``receive``
reads it with ExecutePolicy's contract), and what the controller is sent: a peer's home runs no
ExecutePolicy checks, so nothing here checks the motion (the synchronous executor plans with
ExecutePolicy's planner and its checks; the benchmark's probe, ``unsafe_points``, counts what the
controller commands for every executor). A run ends with ``finish`` (SUCCESS, or FAILURE with its kind, the robot
stopped); a mistake of the setup raises ``SetupError`` (ERROR).
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

import numpy as np
from control_msgs.action import GripperCommand
from moveit_pro_ml_msgs.srv import GetActionChunk
from sensor_msgs.msg import Image, JointState

from behaviors.controller_link import ControllerLink
from behaviors.execute_policy import config as cfg
from behaviors.execute_policy.failure import Failure, FailureKind
from behaviors.execute_policy.checks import CheckKind
from behaviors.execute_policy.chunk import Chunk, ChunkError, period_problem, read_chunk, read_policy_chunk
from behaviors.execute_policy.gripper import GripperStream, join_targets
from behaviors.execute_policy.metrics import RunMetrics, summarise_runs
from behaviors.execute_policy.observation import ObservationError, StaleObservation, robot_state
from behaviors.execute_policy.policy_link import PolicyLink
from behaviors.execute_policy.states import InFlight
from behaviors.safety import MotionSafety, SafetyError, make_safety
from behaviors.wrench_watch import WrenchWatch
from runtime.tree.behavior import Behavior, Status
from runtime.errors import SetupError
from runtime.tree.ports import Direction

STARTUP_WAIT_S = 5.0
RTC_PORTS = ("policy_uses_real_time_chunking", "guidance_horizon")
"""ExecutePolicy's ports that no benchmark executor has: none of them uses real-time chunking."""
PORTS = tuple(p for p in cfg.PORTS if p.name not in RTC_PORTS)
EXECUTOR_RUNS = "bench_executor.runs"
"""The ``RunContext.resources`` key of every benchmark executor run's ``RunMetrics``."""


class Phase(enum.Enum):
    STARTUP = "startup"
    WARMUP = "warmup"
    RUN = "run"
    DONE = "done"


@dataclass(frozen=True)
class Received:
    """A chunk read from an answer, with the request it answers."""

    chunk: Chunk
    flight: InFlight
    index: int  # chunk number, 1-based
    policy_chunk: np.ndarray | None = None
    """The policy's own chunk (``policy_action_chunk``; None when the answer carries none)."""


class ChunkExecutor(Behavior):
    """Base of the benchmark executors (see the module docstring); not registered itself."""

    ports = PORTS
    needs_world = True
    reads_policy_chunk = False
    """Whether the executor reads the answers' ``policy_action_chunk`` (``Received.policy_chunk``)."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.phase = Phase.DONE  # until a run starts
        self.policy: PolicyLink | None = None  # the bus links, built on the first run
        self.gripper: GripperStream | None = None

    # -- lifecycle ---------------------------------------------------------------------------
    def initialise(self) -> None:
        self.phase = Phase.STARTUP
        self.metrics = RunMetrics(node=self.name)
        self.context.resources.setdefault(EXECUTOR_RUNS, []).append(self.metrics)
        self.message = ""
        self.started_at = self.context.clock.now()
        values = {p.name: self.get_input(p.name) for p in self.ports if p.direction is Direction.INPUT and p.name in cfg.PolicyRunConfig.__annotations__}
        for key in ("absolute_force_torque_threshold", "image_topics", "image_names"):
            values[key] = tuple(values[key])
        try:
            self.config = cfg.PolicyRunConfig(**values, policy_uses_real_time_chunking=False, guidance_horizon=0)
            cfg.validate(self.config)
            self.safety: MotionSafety = make_safety(self.context.scene, self.config.joint_group_name, self.config.gripper_joint_name or None)
        except (cfg.ConfigError, SafetyError) as err:
            raise SetupError(str(err)) from None
        self.rules: Any = None
        if self.policy is None:
            self._connect()
        for part in (self.policy, self.gripper, self.wrench):
            if part is not None:
                part.reset()

    def _connect(self) -> None:
        """The bus links, built on the first run (the Objectives name them literally)."""
        config, bus = self.config, self.context.bus
        self.policy = PolicyLink(bus.create_client(config.policy_service_name, GetActionChunk))
        self.link = ControllerLink(bus, config.controller_action_name, self.location, self.xml_id)
        self.gripper = (GripperStream(bus.create_action_client(config.gripper_command_action_name, GripperCommand),
                                      config.gripper_command_action_name) if config.has_gripper else None)
        self.joint_states = bus.create_subscription(config.joint_states_topic, JointState, reliable=True)
        self.cameras = [bus.create_subscription(t, Image, reliable=False) for t in config.image_topics]
        self.wrench = WrenchWatch(bus, config.wrench_topic, config.absolute_force_torque_threshold) if config.wrench_topic else None

    def update(self) -> Status:
        try:
            if self.phase is Phase.STARTUP:
                return self._startup()
            if self.phase is Phase.WARMUP:
                return self._warmup()
            return self._run()
        except StaleObservation as err:
            return self.fail(Failure(FailureKind.STALE_OBSERVATION, str(err)))
        except (ObservationError, SafetyError) as err:
            raise self.setup_error(str(err)) from None

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID and self.phase is not Phase.DONE:
            self._stop_motion()
            self.phase = Phase.DONE

    def run_summary(self) -> dict[str, Any]:
        return {"bench_executor": summarise_runs(self.context.resources.get(EXECUTOR_RUNS, []))}

    # -- what a subclass does ----------------------------------------------------------------
    def start_run(self, now: float) -> Status | None:
        """The warmup answered: the run starts (ask for the first chunk)."""
        raise NotImplementedError

    def run_tick(self, now: float) -> Status | None:
        """One tick of the run: a Status ends it."""
        raise NotImplementedError

    def cancel_motion(self) -> None:
        """Stop the controller's motion (the run ends): cancel the goal of ``self.stream``
        (the controller brings the arm to rest)."""
        stream = getattr(self, "stream", None)
        if stream is not None:
            stream.cancel()

    # -- phases ------------------------------------------------------------------------------
    def _startup(self) -> Status:
        config, now = self.config, self.context.clock.now()
        missing = []
        if not self.policy.ready():
            missing.append(f"policy service '{config.policy_service_name}'")
        if not self.link.ready():
            missing.append(f"controller action '{config.controller_action_name}'")
        if self.gripper is not None and not self.gripper.ready():
            missing.append(f"gripper action '{config.gripper_command_action_name}'")
        if self.joint_states.latest is None:
            missing.append(f"joint states on '{config.joint_states_topic}'")
        if self.wrench is not None and not self.wrench.has_reading:
            missing.append(f"a reading on wrench topic '{config.wrench_topic}'")
        if not missing:
            missing = [f"a frame on camera topic '{t}'" for t, sub in zip(config.image_topics, self.cameras) if sub.latest is None]
        if missing:
            if now - self.started_at >= STARTUP_WAIT_S:
                raise self.setup_error(f"not available after {STARTUP_WAIT_S:.0f} s: " + "; ".join(missing))
            return Status.RUNNING
        self.rules = self.safety.snapshot()
        self.ask(now, new_episode=True)
        self.phase = Phase.WARMUP
        return Status.RUNNING

    def _warmup(self) -> Status:
        now = self.context.clock.now()
        answer = self._answer(now, "warmup")
        if answer is None:
            return Status.RUNNING
        if isinstance(answer, Status):
            return answer
        self.phase = Phase.RUN
        return self.start_run(now) or Status.RUNNING

    def _run(self) -> Status:
        now = self.context.clock.now()
        crossing = self.wrench.crossing() if self.wrench is not None else None
        if crossing is not None:
            return self.fail(Failure(FailureKind.CONTROLLER, f"force-torque threshold exceeded on '{self.config.wrench_topic}': {crossing}; robot stopped"))
        if self.gripper is not None:
            self.gripper.stream(now)
            problem = self.gripper.follow()
            if problem is not None:
                return self.fail(Failure(FailureKind.GRIPPER, problem))
        return self.run_tick(now) or Status.RUNNING

    # -- the policy --------------------------------------------------------------------------
    @property
    def asking(self) -> bool:
        """Whether a request is in flight."""
        return self.policy.request is not None

    def arm_position(self) -> np.ndarray:
        state = robot_state(self.joint_states.latest, self.safety.group_joints, None, self.config.joint_states_topic)
        return np.asarray(state.position, dtype=float)

    def ask(self, now: float, new_episode: bool = False, frozen: int = 0, config: cfg.PolicyRunConfig | None = None) -> None:
        """Ask for a chunk with the observation of now (robot state and camera frames);
        ``frozen`` and ``config`` (with its real-time-chunking settings): as ExecutePolicy sends them."""
        config = config or self.config
        state = robot_state(self.joint_states.latest, self.safety.group_joints, config.gripper_joint_name or None, config.joint_states_topic)
        frames = [sub.latest for sub in self.cameras]  # read first: reading a camera may render its frame
        received = [(config.joint_states_topic, self.joint_states.received_at),
                    *zip(config.image_topics, (sub.received_at for sub in self.cameras))]
        self.policy.send(config, state, frames, received, now, new_episode, 0, frozen)

    def receive(self, now: float) -> Received | Status | None:
        """The chunk of the request in flight once it came, read and with its gripper column
        settled (None while it has not come); a Status when the answer ends the run."""
        answer = self._answer(now, f"chunk {self.metrics.chunks + 1}")
        if answer is None or isinstance(answer, Status):
            return answer
        response, flight = answer
        if response.status == GetActionChunk.Response.NO_MORE_ACTIONS:
            return self.finish(Status.SUCCESS, f"the policy has no more actions: {response.message}".rstrip(": "))
        self.metrics.chunks += 1
        index = self.metrics.chunks
        period = period_problem(response.native_control_period)
        try:
            if period is not None:
                raise ChunkError(period)
            chunk = read_chunk(response.chunk, self.safety.group_joints, self.config.gripper_joint_name or None)
            policy_chunk = read_policy_chunk(response.policy_action_chunk) if self.reads_policy_chunk else None
        except ChunkError as err:
            return self.fail(Failure(FailureKind.MALFORMED_CHUNK, f"chunk {index} rejected: {err}"))
        settled = self.safety.settle_gripper_column(chunk.gripper)
        self.metrics.gripper_clamped += settled.clamped
        return Received(Chunk(chunk.arm, settled.values), flight, index, policy_chunk)

    def _answer(self, now: float, what: str) -> tuple[Any, InFlight] | Status | None:
        """The response to the request in flight (None while it has not come); a Status when
        it timed out, failed or is not a chunk."""
        config, name = self.config, self.config.policy_service_name
        if self.policy.timed_out(now, config.policy_call_timeout):
            return self.fail(Failure(FailureKind.POLICY_TIMEOUT, f"the policy service '{name}' did not answer the {what} request within "
                                     f"policy_call_timeout = {config.policy_call_timeout:g} s"))
        answer = self.policy.answer(now)
        if answer is None:
            return None
        if answer.error is not None:
            return self.fail(Failure(FailureKind.POLICY_ERROR, f"calling the policy service '{name}' failed: {answer.error}"))
        response = answer.response
        self.metrics.latencies.append(answer.round_trip_s)
        if response.status not in (GetActionChunk.Response.CHUNK_PRODUCED, GetActionChunk.Response.NO_MORE_ACTIONS):
            names = {0: "UNKNOWN", 3: "ERROR"}
            detail = response.message or "no message"
            return self.fail(Failure(FailureKind.POLICY_ERROR,
                                     f"the policy answered {names.get(response.status, response.status)} for the {what}: {detail}"))
        return response, answer.flight

    # -- checks ------------------------------------------------------------------------------
    def gripper_position(self) -> float | None:
        joint, state = self.config.gripper_joint_name, self.joint_states.latest
        if not joint or state is None or joint not in state.name:
            return None
        return float(state.position[list(state.name).index(joint)])

    def queue_gripper(self, times_s: np.ndarray, targets: np.ndarray | None) -> None:
        """Stream the gripper column: ``targets[k]`` due at ``times_s[k]``, taken over from the
        target sent last no faster than the gripper's velocity limit (``gripper.join_targets``)."""
        if self.gripper is None or targets is None:
            return
        limit = self.safety.chunk_limits[self.safety.gripper_joint]
        joined = join_targets(self.gripper.last_target, [float(v) for v in targets], limit.max_velocity * self.config.dt)
        self.gripper.schedule = list(zip((float(t) for t in times_s), joined))

    # -- endings -----------------------------------------------------------------------------
    def fail(self, failure: Failure) -> Status:
        """End the run with ``failure`` (the robot stopped); a rejected chunk is counted."""
        if failure.rejects_chunk:
            self.metrics.rejections += 1
            self.metrics.rejection_reason = failure.detail
        return self.finish(Status.FAILURE, failure.detail, failure.kind)

    def finish(self, status: Status, message: str, kind: FailureKind | CheckKind | None = None) -> Status:
        """End the run with ``status`` (the robot stopped unless it succeeded)."""
        if status is not Status.SUCCESS:
            self._stop_motion()
        self.phase = Phase.DONE
        self.message = self.metrics.message = self.feedback_message = message
        self.failure_kind = kind.value if kind is not None else None
        self._write_outputs()
        return status

    def setup_error(self, what: str) -> SetupError:
        self._stop_motion()
        self.phase = Phase.DONE
        self.message = self.metrics.message = what
        self._write_outputs()
        return SetupError(what)

    def _stop_motion(self) -> None:
        if self.policy is not None:
            self.policy.cancel()
        if self.phase is Phase.RUN:
            self.cancel_motion()
        if self.gripper is not None:
            self.gripper.cancel()

    def _write_outputs(self) -> None:
        outputs = {"steps_executed": self.metrics.steps_executed, "chunks_received": self.metrics.chunks,
                   "rejection_reason": self.metrics.rejection_reason, "status_message": self.message}
        for name, value in outputs.items():
            self.set_output(name, value)
