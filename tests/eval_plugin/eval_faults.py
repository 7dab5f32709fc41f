"""A behavior plug-in for the evaluation tests: an episode that crashes its process, hangs, or
raises, chosen by the run's seed. Registered like a user's package (an ``objective.behaviors``
entry point in ``eval_faults-0.1.dist-info``), so worker processes and Ray actors find it when
this folder is on their ``PYTHONPATH``."""
from __future__ import annotations

import os
import time

from runtime.tree.behavior import Behavior, Status
from runtime.tree.ports import InputPort, PortType


class FaultBySeed(Behavior):
    """SUCCESS, except for the seeds named: abort the process, block forever, raise, or fail."""

    description = "Test plug-in: crash, hang, raise or fail on the named seeds."
    ports = (
        InputPort("crash_seed", PortType.INT, -1, "seed whose episode aborts its process (SIGABRT)"),
        InputPort("hang_seed", PortType.INT, -1, "seed whose episode never returns from its tick"),
        InputPort("raise_seed", PortType.INT, -1, "seed whose episode raises RuntimeError"),
        InputPort("fail_seed", PortType.INT, -1, "seed whose episode fails with a numbered reason"),
    )

    def update(self) -> Status:
        seed = self.context.seed
        if seed == self.get_input("crash_seed"):
            os.abort()
        if seed == self.get_input("hang_seed"):
            while True:
                time.sleep(1.0)
        if seed == self.get_input("raise_seed"):
            raise RuntimeError(f"fault injected for seed {seed}")
        if seed == self.get_input("fail_seed"):
            return self.fail(f"check missed by {0.01 * seed + 0.003:.3f} m on seed {seed}")
        return Status.SUCCESS


def register(registry) -> None:
    registry.register(FaultBySeed)
