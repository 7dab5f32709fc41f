"""The benchmark executors: the ways to run a policy's chunks that ExecutePolicy is compared
with in ``benchmarks/bench_success_under_latency.py``. They are benchmark code, not product
behaviors: ``objective`` finds them only when ``benchmarks/executors/plugin`` (an
``objective.behaviors`` entry point, as a user's plug-in package declares one) and the
repository root are on ``PYTHONPATH``:

    PYTHONPATH=.:benchmarks/executors/plugin .venv/bin/objective run benchmarks/executors/objectives/sync.xml --world kinematic

- ``ExecuteChunksSynchronously`` (``synchronous``): stop, infer, execute, repeat;
- ``ExecuteWithLeRobotQueue`` (``lerobot_queue``): LeRobot's async client queue, one action per step;
- ``ExecuteWithLeRobotRtc`` (``lerobot_rtc``): LeRobot's rollout RTC engine's queue on the sim clock;
- ``ExecuteNewestWinsOnJtc`` (``newest_wins``): each chunk wins on arrival, merged by the stock JTC;
- ``ExecuteOnJtcWithUpsampling`` (``jtc_upsampling``): chunks published on arrival, positions only,
  to the stock JTC with ros2_controllers' ``positions_upsampling``;
- ``CountUnsafeCommands`` (``unsafe_points``): the benchmark's probe beside each executor, counting
  the controller's commanded states that violate a limit or come within the padding of a collision.

Each runs ExecutePolicy's policy session (``behaviors.execute_policy.session``, through ``base``):
its ports (less real-time chunking), start-up, warmup, requests, chunk contract, gripper, endings
and outputs; they differ only in how they play the chunks. The peers of ros2_controllers and
LeRobot check nothing, as at home.
"""
from __future__ import annotations

from typing import Any


def register(registry: Any) -> None:
    from .jtc_upsampling import ExecuteOnJtcWithUpsampling
    from .lerobot_queue import ExecuteWithLeRobotQueue
    from .lerobot_rtc import ExecuteWithLeRobotRtc
    from .newest_wins import ExecuteNewestWinsOnJtc
    from .synchronous import ExecuteChunksSynchronously
    from .unsafe_points import CountUnsafeCommands

    registry.register_all([ExecuteChunksSynchronously, ExecuteWithLeRobotQueue, ExecuteWithLeRobotRtc, ExecuteNewestWinsOnJtc,
                           ExecuteOnJtcWithUpsampling,
                           CountUnsafeCommands])
