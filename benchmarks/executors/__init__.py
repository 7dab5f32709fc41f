"""The benchmark executors: three ways to run a policy's chunks that ExecutePolicy is compared
with in ``benchmarks/bench_success_under_latency.py``. They are benchmark code, not product
behaviors: ``objective`` finds them only when ``benchmarks/executors/plugin`` (an
``objective.behaviors`` entry point, as a user's plug-in package declares one) and the
repository root are on ``PYTHONPATH``:

    PYTHONPATH=.:benchmarks/executors/plugin .venv/bin/objective run benchmarks/executors/objectives/sync.xml --world kinematic

- ``ExecuteChunksSynchronously`` (``synchronous``): stop, infer, execute, repeat;
- ``ExecuteWithLeRobotQueue`` (``lerobot_queue``): LeRobot's async client queue, one action per step;
- ``ExecuteNewestWinsOnJtc`` (``newest_wins``): each chunk wins on arrival, merged by the stock JTC.

Each shares ExecutePolicy's ports (less real-time chunking), start-up, policy requests, chunk
contract and point checks (``base``).
"""
from __future__ import annotations

from typing import Any


def register(registry: Any) -> None:
    from .lerobot_queue import ExecuteWithLeRobotQueue
    from .newest_wins import ExecuteNewestWinsOnJtc
    from .synchronous import ExecuteChunksSynchronously

    registry.register_all([ExecuteChunksSynchronously, ExecuteWithLeRobotQueue, ExecuteNewestWinsOnJtc])
