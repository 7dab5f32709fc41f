"""``CountUnsafeCommands``: the success-under-latency benchmark's probe of what an executor had the
arm commanded, beside the executor in a ``Parallel`` (``objectives.objective_xml``).

Every tick while it runs, it takes the state the simulated ``joint_trajectory_controller``
commands at that instant (position, velocity, acceleration: what the controller writes to the
hardware) and counts it as an **unsafe point** when it is outside a joint's position, velocity or
acceleration limit, or when the arm there comes within ``link_padding`` of a world object (or
collides with itself): the checks ExecutePolicy runs before it sends a motion
(``MotionSafety.first_limit_violation`` and ``first_collision``, with the collision rules of the
probe's start), used here to count, never to stop anything. So every executor is measured the
same way: ExecutePolicy, which refuses such points before it sends them (0 expected), and the
peers, which send what their home would send. The run's summary gets ``unsafe_points``: the
count, the ticks probed, and the first unsafe point in words.

It reads the simulated cell's controller (``RunContext.world``): a measuring instrument of the
benchmark, where a real cell would read the controller's state topic. Without a simulated cell
with that controller it is a SetupError.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from sensor_msgs.msg import JointState

from behaviors.execute_policy import config as cfg
from runtime.motion.samples import Samples
from behaviors.safety import MotionSafety, SafetyError, make_safety
from runtime.tree.behavior import Behavior, Status
from runtime.errors import SetupError
from runtime.tree.ports import InputPort, OutputPort, PortType

PADDING_DEFAULT_M = next(p.default for p in cfg.PORTS if p.name == "link_padding")


def unsafe_reason(safety: MotionSafety, rules: Any, state: Samples, padding_m: float, gripper_position: float | None) -> str | None:
    """Why one commanded state (a Samples of one row) is unsafe, or None: a limit, then a collision."""
    violation = safety.first_limit_violation(state)
    if violation is not None:
        return str(violation)
    hit = safety.first_collision(rules, state, padding_m, gripper_position)
    return None if hit is None else str(hit)


class CountUnsafeCommands(Behavior):
    """Benchmark probe (see the module docstring): counts the controller's commanded states that
    violate a limit or come within the padding of a collision; RUNNING until halted."""

    ports = (
        InputPort("joint_group_name", PortType.STRING, description="The arm's joint group (its limits and links)."),
        InputPort("gripper_joint_name", PortType.STRING, "", "The gripper joint, read from the joint states for the collision check."),
        InputPort("link_padding", PortType.FLOAT, PADDING_DEFAULT_M, "Meters of padding around the robot for the world collision check."),
        InputPort("controller_name", PortType.STRING, "joint_trajectory_controller", "The simulated controller whose commands are probed."),
        InputPort("joint_states_topic", PortType.STRING, "/joint_states", "Where the gripper joint's position is read."),
        OutputPort("unsafe_points", PortType.INT, "Commanded states counted unsafe so far.", "{unsafe_points}"),
    )
    description = ("Benchmark probe (benchmarks/executors): counts the simulated controller's commanded states that violate a "
                   "joint limit or come within link_padding of a collision.")
    needs_world = True

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.count, self.probed, self.first = 0, 0, ""
        self.joint_states: Any = None

    def initialise(self) -> None:
        gripper = self.get_input("gripper_joint_name") or None
        try:
            self.safety = make_safety(self.context.scene, self.get_input("joint_group_name"), gripper)
        except SafetyError as err:
            raise SetupError(str(err)) from None
        name = self.get_input("controller_name")
        controllers: Any = getattr(self.context.world, "controllers", None)  # not indexable: TypeError below
        try:
            self.controller = controllers[name]
        except (KeyError, TypeError):
            raise SetupError(f"{self.xml_id} probes a simulated controller '{name}': this run's world has none") from None
        self.rules = self.safety.snapshot()
        self.padding_m = float(self.get_input("link_padding"))
        self.gripper_joint = gripper
        if self.joint_states is None:
            self.joint_states = self.context.bus.create_subscription(self.get_input("joint_states_topic"), JointState, reliable=True)
        self.count, self.probed, self.first = 0, 0, ""

    def update(self) -> Status:
        now = self.context.clock.now()
        commanded = self.controller.trajectory.sample(now)
        state = Samples(np.array([now]), commanded.position[None, :], commanded.velocity[None, :], commanded.acceleration[None, :])
        reason = unsafe_reason(self.safety, self.rules, state, self.padding_m, self.gripper_position())
        self.probed += 1
        if reason is not None:
            self.count += 1
            self.first = self.first or reason
        self.set_output("unsafe_points", self.count)
        return Status.RUNNING

    def gripper_position(self) -> float | None:
        state = None if self.joint_states is None else self.joint_states.latest
        if self.gripper_joint is None or state is None or self.gripper_joint not in state.name:
            return None
        return float(state.position[list(state.name).index(self.gripper_joint)])

    def run_summary(self) -> dict[str, Any]:
        return {"unsafe_points": {"count": self.count, "probed": self.probed, "first": self.first}}
