"""``objective run --ros``: the runtime as a node on a real ROS 2 graph.

In ROS mode the run's bus is on ROS 2 and its clock a ``WallClock``: every service, action and
topic the behaviors use, and every one the hosted world (the simulated cell) serves, is a real
ROS 2 endpoint. The behaviors' side is node ``/objective_runtime`` (by default); a hosted world's
servers are node ``/objective_runtime_cell`` in the same process (``HostingBus``). A policy
adapter, an inference server or a real controller in another process is then reached exactly as
the in-process ones are in a headless run.

Why these choices:
- ``WallClock``: the other processes on the graph live in real time (their timeouts, ROS
  timers, a policy's latency), so simulated time that runs ahead of the wall would make every
  answer look instant and every timeout meaningless. ``--ros`` therefore implies ``--realtime``.
- Two nodes, two executors: a node that serves nothing spins rclpy's events executor (a tenth or
  less of the CPU per message), while servers need the multi-threaded one (an accepted goal holds
  a thread until its owner finishes it). So the behaviors' node, which only calls, sends goals
  and subscribes, is apart from the hosted servers' node.
- ``serve_in_spin_once=True``: the hosted world's servers (simulated controllers, the controller
  manager, camera frames) share state with the world, which the runner steps on its own thread
  (and MuJoCo renders on the thread that owns its GL context). Their callbacks therefore wait
  for the runner's ``bus.spin_once()`` once per tick instead of running on rclpy's threads.
- SIGTERM and SIGINT stop the run at the next tick in every mode (``runtime.io.interrupt``), so a
  process manager (or a test) that stops the runner gets a clean end: the tree is halted (goals
  cancelled, the robot stopped; the cancels are delivered for ``HALT_GRACE_S``), the world
  closed and the node destroyed. The bus's rclpy context installs no signal handlers of its own.
"""
from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING, Any, Callable, Iterable

from runtime.io.clock import WallClock

if TYPE_CHECKING:
    from runtime.io.bus import ActionClient, Bus, Publisher, ServerGoalHandle, ServiceClient, Subscription

DEFAULT_NODE_NAME = "objective_runtime"
HALT_GRACE_S = 0.25
"""Wall time the runner keeps serving after halting a tree, so cancel requests leave the node
(and hosted controllers, which serve in ``spin_once`` and run in the world's steps, act on them:
the simulated cell's controllers bring a cancelled trajectory to rest within 0.2 s) before it
is destroyed."""
EXECUTOR_THREADS = 12
"""Executor threads of the hosted servers' node. Each active action goal holds one (the
controller's trajectory goal and the gripper goal); the rest deliver requests and cancels."""
CELL_NODE_SUFFIX = "_cell"


DISCOVERY_VARIABLE = "ROS_AUTOMATIC_DISCOVERY_RANGE"


def set_discovery_range(opened: str | None = None) -> str:
    """Fix the ROS 2 discovery range of this process before rclpy initialises, and return it:
    ``opened`` when the operator opens it (``--discovery-range``), else what the environment
    already says, else LOCALHOST, so that only processes on this machine can see the node and
    call it (the policy adapter does the same)."""
    if opened is not None:
        os.environ[DISCOVERY_VARIABLE] = opened.upper()
    return os.environ.setdefault(DISCOVERY_VARIABLE, "LOCALHOST")


def make_ros_bus(clock: WallClock, node_name: str = DEFAULT_NODE_NAME, serves: bool = True) -> Bus:
    """The runner's bus on ROS 2: a ``HostingBus`` when the world hosts servers (``serves``),
    else one ``RosBus`` that serves nothing (the ``robot`` world: the robot's drivers serve).
    Discovery stays on this machine unless the range was opened (``set_discovery_range``)."""
    from runtime.io.ros.bus import RosBus  # rclpy is imported only for ROS runs

    set_discovery_range()

    if serves:
        return HostingBus(clock, node_name)
    return RosBus(clock, node_name=node_name, serve_in_spin_once=True, serves=False)


class HostingBus:
    """The bus of a run that hosts a world's servers on ROS 2: services and action servers on
    node ``<name>_cell`` (multi-threaded executor, callbacks served in ``spin_once``),
    everything else (clients, goals sent, subscriptions, publishers) on node ``<name>`` (events
    executor). ``spin_once`` and ``close`` handle both; the cancels the behaviors' node sends to
    the hosted action servers are served before either node leaves the graph."""

    clock: WallClock
    produces_on_read = False
    serves = True

    def __init__(self, clock: WallClock, node_name: str = DEFAULT_NODE_NAME) -> None:
        from runtime.io.ros.bus import RosBus

        self.clock = clock
        self.calls = RosBus(clock, node_name=node_name, serve_in_spin_once=True, serves=False)
        try:
            self.servers = RosBus(clock, node_name=node_name + CELL_NODE_SUFFIX, serve_in_spin_once=True,
                                  num_threads=EXECUTOR_THREADS)
        except BaseException:
            self.calls.close()
            raise

    # -- on the hosted servers' node ---
    def create_service(self, name: str, srv_type: type, handler: Callable[[Any], Any], own_thread: bool = False) -> Any:
        return self.servers.create_service(name, srv_type, handler, own_thread)

    def destroy_service(self, name: str) -> None:
        self.servers.destroy_service(name)

    def create_action_server(
        self,
        name: str,
        action_type: type,
        on_goal: Callable[[ServerGoalHandle], bool],
        on_cancel: Callable[[ServerGoalHandle], bool] | None = None,
    ) -> Any:
        return self.servers.create_action_server(name, action_type, on_goal, on_cancel)

    def destroy_action_server(self, name: str) -> None:
        self.servers.destroy_action_server(name)

    # -- on the behaviors' node ---
    def create_client(self, name: str, srv_type: type) -> ServiceClient:
        return self.calls.create_client(name, srv_type)

    def create_publisher(self, name: str, msg_type: type, reliable: bool = True) -> Publisher:
        return self.calls.create_publisher(name, msg_type, reliable)

    def create_lazy_publisher(
        self,
        name: str,
        msg_type: type,
        produce: Callable[[], Any],
        reliable: bool = True,
        rate_hz: float = 30.0,
    ) -> None:
        self.calls.create_lazy_publisher(name, msg_type, produce, reliable, rate_hz)

    def destroy_publisher(self, name: str) -> None:
        self.calls.destroy_publisher(name)

    def create_subscription(
        self,
        name: str,
        msg_type: type,
        callback: Callable[[Any], None] | None = None,
        reliable: bool = True,
    ) -> Subscription:
        return self.calls.create_subscription(name, msg_type, callback, reliable)

    def destroy_subscription(self, sub: Subscription) -> None:
        self.calls.destroy_subscription(sub)

    def create_action_client(self, name: str, action_type: type) -> ActionClient:
        return self.calls.create_action_client(name, action_type)

    def action_types(self, name: str) -> list[str]:
        """What the graph serves under action ``name``."""
        return self.calls.action_types(name)

    # -- both ---
    def spin_once(self) -> None:
        self.calls.spin_once()
        self.servers.spin_once()

    def cancels_in_flight(self) -> int:
        return self.calls.cancels_in_flight() + self.servers.cancels_in_flight()

    def deliver_cancels(self, timeout_s: float | None = None) -> bool:
        """``RosBus.deliver_cancels`` for both nodes at once: the behaviors' cancels are answered
        only once the hosted servers' node has served them."""
        from runtime.io.ros.bus import CANCEL_DELIVERY_S

        deadline = time.monotonic() + (CANCEL_DELIVERY_S if timeout_s is None else timeout_s)
        while self.cancels_in_flight():
            self.servers.serve_cancels()
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.005)
        return True

    def close(self) -> None:
        try:
            self.deliver_cancels()
            self.calls.close()
        finally:
            self.servers.close()


CLOCK_TOPIC = "/clock"
CLOCK_WAIT_S = 10.0
"""Wall time ``--use-sim-time`` waits for the first ``/clock`` message."""


def follow_graph_clock(bus: Bus, clock: WallClock, timeout_s: float = CLOCK_WAIT_S) -> float:
    """Set ``clock`` to the time the graph's ``/clock`` reads (``--use-sim-time``) and keep it
    there; returns the first reading.

    Between readings the run's clock goes on at wall-clock rate, as a simulated robot paced to
    the wall clock does; each later ``/clock`` message (delivered in ``bus.spin_once``) moves it
    forward when it reads ahead, never back, so a first reading that was already old (the
    robot's process starved just then) costs no more than until the next fresh one.
    ObjectiveError when nothing publishes ``/clock`` in time."""
    from rosgraph_msgs.msg import Clock

    from runtime.errors import ObjectiveError
    from runtime.io.timestamps import to_seconds

    subscription = bus.create_subscription(CLOCK_TOPIC, Clock, lambda msg: clock.catch_up(to_seconds(msg.clock)),
                                           reliable=False)
    deadline = time.monotonic() + timeout_s
    while subscription.latest is None:
        if time.monotonic() >= deadline:
            bus.destroy_subscription(subscription)
            raise ObjectiveError(
                f"--use-sim-time: nothing published {CLOCK_TOPIC} within {timeout_s:g} s "
                "(start the simulated robot first: objective sim-robot)"
            )
        time.sleep(0.01)
    now = to_seconds(subscription.latest.clock)
    clock.sync(now)
    return now


def prepare_links(bus: Bus, interfaces: Iterable[type], services: Iterable[tuple[str, type]],
                  actions: Iterable[tuple[str, tuple[type, ...]]]) -> None:
    """Before the first tick, what behaviors would otherwise pay for in a tick when they start:
    rclpy's C type support of every service and action type the tree declares (``interfaces``;
    rclpy loads it when the first client of a type is made: 30-50 ms per type on this project's
    machines), and the clients of the services and actions it names (``services``: name and type;
    ``actions``: name and the types it may have; the runner takes them from
    ``runtime.app.world_check.named_links``; a few ms each), which the bus then hands to the behaviors
    that ask for them (``RosBus.create_client`` keeps one client per name and type). An action
    that may have several types (a trajectory controller) gets the client of the type the graph
    serves, when it serves one yet."""
    from rclpy.type_support import check_for_type_support

    from runtime.io.bus import interface_type_name

    for interface in interfaces:
        check_for_type_support(interface)
    for name, service_type in services:
        bus.create_client(name, service_type)
    for name, types in actions:
        served = bus.action_types(name)
        for action_type in types:
            if len(types) == 1 or interface_type_name(action_type, "action") in served:
                bus.create_action_client(name, action_type)


def graph_description(node_name: str = DEFAULT_NODE_NAME) -> str:
    """One line saying where the run lives on ROS 2, for the start-up log."""
    domain = os.environ.get("ROS_DOMAIN_ID", "0")
    scope = os.environ.get(DISCOVERY_VARIABLE, "SUBNET (ROS default)")
    return f"on ROS 2 as node /{node_name} (ROS_DOMAIN_ID={domain}, {DISCOVERY_VARIABLE}={scope})"


def deliver_pending(bus: Bus, step_world: Callable[[], None] | None = None, seconds: float = HALT_GRACE_S) -> None:
    """Keep spinning ``bus`` for ``seconds`` of wall time (after a halt, before closing), stepping
    the hosted world (``step_world``) too, so its controllers bring the arm to rest on the cancels."""
    deadline = time.monotonic() + seconds
    while True:
        if step_world is not None:
            step_world()
        bus.spin_once()
        if time.monotonic() >= deadline:
            return
        time.sleep(0.01)
