"""``objective sim-robot``: the simulated cell alone on ROS 2, a robot on the graph.

It hosts one world (``vla_sim`` or ``kinematic``) as node ``/sim_robot`` and serves what a real
arm's drivers serve: ``/joint_states``, the controller manager and every controller it holds
(their actions and topics), the cameras and their infos, the wrist wrench, the cube poses, and
``/clock`` (the cell's own time). No Objective runs here; another process drives it exactly as
it would drive a real arm:

    objective sim-robot --describe cell/       # the description files, once
    objective sim-robot                        # the robot, until SIGINT/SIGTERM
    objective run FILE --ros --use-sim-time --world robot --world-option mjcf=cell/robot.xml ...

The loop, at ``tick_hz`` of wall time: step the cell to the clock (its controllers run at 500 Hz
on the cell's own clock, see ``sim.world.CellClock``), serve what arrived on the bus (goals,
commands, switches; due camera frames), publish ``/clock``. The runtime that drives it only
ticks its tree. On a stop signal the node finishes: goals end, the node leaves the graph, and
the last stdout line is a JSON summary (the world's, as ``objective run --json`` reports it,
plus the loop's pacing).
"""
from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from runtime.tree.behavior import RunContext
from runtime.io.clock import WallClock
from runtime.tree.events import EventLog
from runtime.io.heap import PacedHeap
from runtime.io.interrupt import StopRequest
from runtime.app.runner import Pacing
from runtime.app.world import create_world
from runtime.io.timestamps import time_msg

from .robot_model import CARTESIAN_LIMITS_PATH, COUPLINGS_PATH, JOINT_LIMITS_PATH, SRDF_PATH, WAYPOINTS_PATH, robot_xml

NODE_NAME = "sim_robot"
DESCRIPTION_FILES = {
    "srdf": ("robot.srdf", SRDF_PATH),
    "joint_limits": ("joint_limits.yaml", JOINT_LIMITS_PATH),
    "cartesian_limits": ("cartesian_limits.yaml", CARTESIAN_LIMITS_PATH),
    "couplings": ("coupled_joints.yaml", COUPLINGS_PATH),
    "waypoints": ("waypoints.yaml", WAYPOINTS_PATH),
}
GRIPPER_JOINT = "robotiq_85_left_knuckle_joint"


@dataclass
class SimRobotOptions:
    world: str = "vla_sim"
    seed: int = 0
    world_options: dict[str, Any] = field(default_factory=dict)
    tick_hz: float = 100.0
    node_name: str = NODE_NAME


def describe(directory: Path) -> list[str]:
    """Write the cell's robot description into ``directory`` (MJCF, SRDF, joint limits, the
    Cartesian envelope, couplings, waypoints); returns the ``--world-option`` arguments of ``--world robot`` for it."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "robot.xml").write_text(robot_xml())
    options = [f"mjcf={directory / 'robot.xml'}"]
    for option, (name, source) in DESCRIPTION_FILES.items():
        shutil.copyfile(source, directory / name)
        options.append(f"{option}={directory / name}")
    return options + [f"gripper_joint={GRIPPER_JOINT}"]


def run_sim_robot(options: SimRobotOptions, stop: StopRequest) -> dict[str, Any]:
    """Host the cell on ROS 2 until ``stop`` is requested; returns the summary.

    ValueError (bad world options) before anything joins the graph."""
    from rosgraph_msgs.msg import Clock

    from runtime.io.ros.run import CLOCK_TOPIC, deliver_pending, make_ros_bus

    world: Any = create_world(options.world, {"seed": options.seed, "realtime": True, "policy": "none", **options.world_options})  # a simulated world: World and its cell
    clock = WallClock()
    bus = make_ros_bus(clock, options.node_name)
    period = 1.0 / options.tick_hz
    pacing = Pacing(period)
    ticks = 0
    try:
        try:
            world.start(RunContext(clock=clock, bus=bus, events=EventLog(clock), seed=options.seed))
        except ValueError as err:
            raise ValueError(f"world '{options.world}': {err}") from None
        clock_publisher = bus.create_publisher(CLOCK_TOPIC, Clock)
        print(f"sim robot '{options.world}' (seed {options.seed}) serving on ROS 2 as node /{options.node_name}", flush=True)
        with PacedHeap() as heap:  # garbage is collected between ticks
            while stop.signum is None:
                clock.advance(period)
                started = time.monotonic()
                world.step_to(clock.now())
                bus.spin_once()
                clock_publisher.publish(Clock(clock=time_msg(world.cell.t)))
                pacing.record(started, time.monotonic())
                heap.between_ticks()
                ticks += 1
        deliver_pending(bus)
        summary = world.summary()
    finally:
        try:
            world.close()
        finally:
            bus.close()
    return {"world": summary, "ticks": ticks, "robot_seconds": round(world.cell.t, 3), "pacing": pacing.as_dict()}


def print_summary(summary: dict[str, Any]) -> None:
    print(json.dumps(summary), flush=True)
