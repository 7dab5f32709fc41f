"""The base of the benchmark executors: ExecutePolicy's policy session, played another way.

Each executor holds a ``PolicySession`` (``behaviors.execute_policy.session``), as ExecutePolicy
does: the same ports (less real-time chunking), start-up, warmup, requests, answers read with the
chunk contract, gripper stream, force-torque watch, endings, output ports and events. The
executor is the session's player: a subclass decides when to ask for a chunk
(``session.request``), what to do with one that came (``session.receive``), and what the
controller is sent. A peer's home runs no ExecutePolicy checks, so nothing here checks the motion
(the synchronous executor plans with ExecutePolicy's planner and its checks; the benchmark's
probe, ``unsafe_points``, counts what the controller commands for every executor).
"""
from __future__ import annotations

from typing import Any

from behaviors.execute_policy import config as cfg
from behaviors.execute_policy.chunk import Chunk
from behaviors.execute_policy.config import PolicyRunConfig
from behaviors.execute_policy.metrics import RunMetrics, summarise_runs
from behaviors.execute_policy.session import PolicySession
from behaviors.safety import MotionSafety
from runtime.tree.behavior import Behavior, Status
from runtime.tree.resources import Resource

RTC_PORTS = ("policy_uses_real_time_chunking", "guidance_horizon")
"""ExecutePolicy's ports that no benchmark executor has: none of them uses real-time chunking."""
PORTS = tuple(p for p in cfg.PORTS if p.name not in RTC_PORTS)
EXECUTOR_RUNS: Resource[list[RunMetrics]] = Resource("bench_executor.runs")
"""The ``RunContext.resources`` key of every benchmark executor run's ``RunMetrics``."""


class ChunkExecutor(Behavior):
    """Base of the benchmark executors (see the module docstring); not registered itself."""

    ports = PORTS
    needs_world = True
    reads_policy_chunk = False
    """Whether the executor reads the answers' ``policy_action_chunk`` (``HeldChunk.policy_chunk``)."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.session = PolicySession(self, self, EXECUTOR_RUNS, fixed={"policy_uses_real_time_chunking": False, "guidance_horizon": 0},
                                     reads_policy_chunk=self.reads_policy_chunk)

    @property
    def config(self) -> PolicyRunConfig:
        return self.session.config

    @property
    def safety(self) -> MotionSafety:
        return self.session.safety

    @property
    def metrics(self) -> RunMetrics:
        return self.session.metrics

    # -- lifecycle ---------------------------------------------------------------------------
    def setup(self, **kwargs: Any) -> None:
        self.session.setup()

    def initialise(self) -> None:
        self.session.begin()

    def update(self) -> Status:
        return self.session.update()

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID:
            self.session.halt()

    def run_summary(self) -> dict[str, Any]:
        return {"bench_executor": summarise_runs(self.context.resources.get(EXECUTOR_RUNS) or [])}

    # -- the session's player ----------------------------------------------------------------
    def begin_stream(self, now_s: float) -> Status | None:
        return self.start_run(now_s)

    def play(self, now_s: float) -> Status | None:
        return self.session.watch_robot(now_s) or self.run_tick(now_s)

    def cancel_motion(self) -> None:
        """Cancel the goal of ``self.stream`` (the controller brings the arm to rest)."""
        stream = getattr(self, "stream", None)
        if stream is not None:
            stream.cancel()

    def stall_at_stop_s(self, now_s: float) -> float:
        return 0.0  # an executor counts its stalls as it plays

    def chunk_plot(self, chunk: Chunk, request_step: int) -> dict[str, Any]:
        return {}

    # -- what a subclass does ----------------------------------------------------------------
    def start_run(self, now: float) -> Status | None:
        """The warmup answered: the run starts (ask for the first chunk)."""
        raise NotImplementedError

    def run_tick(self, now: float) -> Status | None:
        """One tick of the run: a Status ends it."""
        raise NotImplementedError
