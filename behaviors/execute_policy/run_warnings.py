"""The warnings of a policy run: what it says when something works but is likely a mistake, and
how often. Each is given through ``RunWarnings.say`` (the session's ``warn``: kept in the run's
metrics, logged, and an event):

- the sizing (``timing.sizing_warning``): the latency outgrows the sent window; once, and once
  more if it later outgrows what the chunk's tail covers as well;
- the step period: the first chunk's differs from ``dt``, or a later chunk's from the first's;
  once each;
- a real-time-chunking run whose answers carry no policy chunk; once;
- the gripper column clamped into its range; once (every clamp is counted in the metrics);
- the first chunk starting far from where the arm was (``FIRST_CHUNK_GAP_RAD``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from . import config as cfg
from ..safety import MotionSafety, SettledColumn
from .chunk import Chunk
from .timing import SizingRisk, sizing_risk, sizing_warning

FIRST_CHUNK_GAP_RAD = 0.2
"""A first chunk whose step 0 is further than this from the arm (on any joint) is warned about."""


@dataclass
class RunWarnings:
    """The warnings of one run, and which were given already."""

    say: Callable[[str], None]
    first_period_s: float | None = None
    """The step period the first chunk that gave one said (``native_control_period``)."""
    warned_period_change: bool = False
    warned_no_policy_chunk: bool = False
    warned_gripper_clamped: bool = False
    warned_sizing: SizingRisk = SizingRisk.COVERED
    """The worst sizing risk warned about so far."""

    def sizing(self, config: cfg.PolicyRunConfig, latency_s: float, chunk_steps: int | None, what: str, detail: str = "") -> None:
        """Warn, with the figures, when the latency outgrows the sent window: once, and
        once more if it later outgrows what the chunk's tail covers as well."""
        risk = sizing_risk(config.committed_action_steps, config.dt, latency_s, chunk_steps)
        if risk > self.warned_sizing:
            self.warned_sizing = risk
            text = sizing_warning(config.committed_action_steps, config.dt, latency_s, what, detail, chunk_steps)
            assert text is not None
            self.say(text)

    def period(self, period: float, chunk_number: int, dt: float) -> None:
        """Warn once when the first chunk's step period differs from ``dt``, and once when a later
        chunk's differs from the first's (0: the policy gives none)."""
        if period <= 0:
            return
        if self.first_period_s is None:
            self.first_period_s = period
            if abs(period - dt) > 1e-6:
                self.say(f"the policy was trained at {period:g} s per step but dt is {dt:g} s: the motion plays "
                         f"{period / dt:.2f}x as fast as trained (the chunk is not retimed)")
            return
        if abs(period - self.first_period_s) > 1e-6 and not self.warned_period_change:
            self.warned_period_change = True
            self.say(f"chunk {chunk_number} says the policy steps every {period:g} s, but the first chunk said "
                     f"{self.first_period_s:g} s: every chunk is played at dt = {dt:g} s per step (not retimed)")

    def no_policy_chunk(self, chunk_number: int) -> None:
        """Warn once that a real-time-chunking run's answer carries no policy chunk."""
        if self.warned_no_policy_chunk:
            return
        self.warned_no_policy_chunk = True
        self.say(f"policy_uses_real_time_chunking is true but chunk {chunk_number} carries no policy_action_chunk: "
                 "the policy gets no previous_action_chunk back, so real-time chunking does nothing (send it, or set "
                 "policy_uses_real_time_chunking=\"false\" for a policy without a denoising loop)")

    def gripper_clamped(self, settled: SettledColumn, safety: MotionSafety) -> None:
        """Warn once when the gripper column was clamped into its range (``settled``:
        ``MotionSafety.settle_gripper_column``'s result)."""
        if settled.clamped and not self.warned_gripper_clamped:
            self.warned_gripper_clamped = True
            assert safety.gripper_joint is not None  # a clamped column is a gripper's
            limit = safety.chunk_limits[safety.gripper_joint]
            self.say(
                f"the policy's gripper column leaves the range {limit.lower:.4f}..{limit.upper:.4f} rad by up to "
                f"{settled.farthest_rad:.4f} rad (within the {safety.gripper_band_rad():.4f} rad band): such values are "
                "clamped into the range and counted (gripper_clamped); further out a chunk is rejected"
            )

    def first_chunk_start(self, chunk: Chunk, anchor: Any, joints: Sequence[str]) -> None:
        """Warn when the first chunk starts far from where the arm was at its request
        (``FIRST_CHUNK_GAP_RAD``): it is blended in, but such a gap is usually a wrong joint
        order, unit or robot state."""
        at_request = np.asarray(anchor.position[:chunk.arm.shape[1]], dtype=float)
        gap = np.abs(chunk.arm[0] - at_request)
        if float(gap.max()) > FIRST_CHUNK_GAP_RAD:
            joint = joints[int(np.argmax(gap))]
            self.say(f"chunk 1 starts {float(gap.max()):.3f} rad from where the arm was at its request (joint {joint}; "
                     f"more than {FIRST_CHUNK_GAP_RAD} rad): it is blended in, but check the policy's joint order, "
                     "units and the state it was given")
