"""``objective run --ros``: the runtime as a node on a real ROS 2 graph.

In ROS mode the run's bus is a ``RosBus`` and its clock a ``WallClock``: every service, action
and topic the behaviors use, and every one the hosted world (the simulated cell) serves, is a
real ROS 2 endpoint of one node (``/objective_runtime`` by default). A policy adapter, an
inference server or a real controller in another process is then reached exactly as the
in-process ones are in a headless run.

Why these choices:
- ``WallClock``: the other processes on the graph live in real time (their timeouts, ROS
  timers, a policy's latency), so simulated time that runs ahead of the wall would make every
  answer look instant and every timeout meaningless. ``--ros`` therefore implies ``--realtime``.
- ``serve_in_spin_once=True``: the hosted world's servers (simulated controllers, the controller
  manager, camera frames) share state with the world, which the runner steps on its own thread
  (and MuJoCo renders on the thread that owns its GL context). Their callbacks therefore wait
  for the runner's ``bus.spin_once()`` once per tick instead of running on rclpy's threads.
- SIGTERM and SIGINT stop the run at the next tick in every mode (``runtime.interrupt``), so a
  process manager (or a test) that stops the runner gets a clean end: the tree is halted (goals
  cancelled, the robot stopped; the cancels are delivered for ``HALT_GRACE_S``), the world
  closed and the node destroyed. The bus's rclpy context installs no signal handlers of its own.
"""
from __future__ import annotations

import os
import time
from typing import Any

from runtime.clock import WallClock

DEFAULT_NODE_NAME = "objective_runtime"
HALT_GRACE_S = 0.25
"""Wall time the runner keeps serving after halting a tree, so cancel requests leave the node
(and hosted controllers, which serve in ``spin_once``, act on them) before it is destroyed."""
EXECUTOR_THREADS = 12
"""Executor threads of the runner's node. Each active action goal holds one (the controller's
trajectory goal and the gripper goal, from both the client and the server side, since the hosted
controllers live on the same node); the rest deliver replies, frames and discovery."""


def make_ros_bus(clock: WallClock, node_name: str = DEFAULT_NODE_NAME, serves: bool = True) -> Any:
    """The runner's ``RosBus``: server callbacks run in ``spin_once`` on the runner thread.
    ``serves=False`` (a world that hosts nothing, such as ``robot``): the node only calls,
    sends goals and subscribes, on rclpy's events executor (see ``RosBus``)."""
    from runtime.ros.bus import RosBus  # rclpy is imported only for ROS runs

    return RosBus(clock, node_name=node_name, serve_in_spin_once=True, num_threads=EXECUTOR_THREADS, serves=serves)


CLOCK_TOPIC = "/clock"
CLOCK_WAIT_S = 10.0
"""Wall time ``--use-sim-time`` waits for the first ``/clock`` message."""


def sync_to_graph_clock(bus: Any, clock: WallClock, timeout_s: float = CLOCK_WAIT_S) -> float:
    """Set ``clock`` to the time the graph's ``/clock`` reads (``--use-sim-time``); returns it.

    Read once: from then on the run's clock goes on at wall-clock rate, as a simulated robot
    paced to the wall clock does. ObjectiveError when nothing publishes ``/clock`` in time."""
    from rosgraph_msgs.msg import Clock

    from runtime.errors import ObjectiveError
    from runtime.timestamps import to_seconds

    subscription = bus.create_subscription(CLOCK_TOPIC, Clock, reliable=False)
    try:
        deadline = time.monotonic() + timeout_s
        while subscription.latest is None:
            if time.monotonic() >= deadline:
                raise ObjectiveError(
                    f"--use-sim-time: nothing published {CLOCK_TOPIC} within {timeout_s:g} s "
                    "(start the simulated robot first: objective sim-robot)"
                )
            time.sleep(0.01)
        now = to_seconds(subscription.latest.clock)
        clock.sync(now)
        return now
    finally:
        bus.destroy_subscription(subscription)


def graph_description(node_name: str = DEFAULT_NODE_NAME) -> str:
    """One line saying where the run lives on ROS 2, for the start-up log."""
    domain = os.environ.get("ROS_DOMAIN_ID", "0")
    scope = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "SUBNET (ROS default)")
    return f"on ROS 2 as node /{node_name} (ROS_DOMAIN_ID={domain}, ROS_AUTOMATIC_DISCOVERY_RANGE={scope})"


def deliver_pending(bus: Any, seconds: float = HALT_GRACE_S) -> None:
    """Keep spinning ``bus`` for ``seconds`` of wall time (after a halt, before closing)."""
    deadline = time.monotonic() + seconds
    while True:
        bus.spin_once()
        if time.monotonic() >= deadline:
            return
        time.sleep(0.01)
