"""Simulated ros2_control-style controllers for the cell, served on the bus with ROS names.

``make_controllers(bus, hardware, clock)`` builds the controller manager and its controllers; the
world hands it each tick's control steps (``manager.advance(times, dt, step_physics)``: 500 Hz,
one physics step after each), which is ``manager.update(t, dt)`` then a physics step at each time,
with the steps that nothing reacts to planned ahead. The trajectory maths (``Trajectory``,
``stitch``, ``stop_trajectory``) is pure and usable on its own.
"""
from .admittance import JointTrajectoryAdmittanceController, ParsedGoal, parse_goal
from .base import Controller, ControllersConfig, JtcParams
from .broadcaster import ForceTorqueSensorBroadcaster
from .compliance import AdmittanceParams, AdmittanceState, admittance_step, damped_pseudo_inverse
from .gripper import GripperActionController
from .jtc import JointTrajectoryController
from .manager import (
    BEST_EFFORT,
    FT_BROADCASTER,
    GRIPPER_CONTROLLER,
    JTC_CONTROLLER,
    LIST_SERVICE,
    STRICT,
    SWITCH_SERVICE,
    TRAJECTORY_CONTROLLER,
    VELOCITY_CONTROLLER,
    ControllerManager,
    SwitchOutcome,
    make_controllers,
)
from .trajectory import (
    SeamError,
    Trajectory,
    TrajectoryState,
    path_violation,
    stitch,
    stop_trajectory,
    wrench_violation,
)
from .velocity import VelocityForceController

TRAJECTORY_ACTION = f"/{TRAJECTORY_CONTROLLER}/follow_joint_trajectory"
JTC_ACTION = f"/{JTC_CONTROLLER}/follow_joint_trajectory"
JTC_TOPIC = f"/{JTC_CONTROLLER}/joint_trajectory"
WRENCH_TOPIC = f"/{FT_BROADCASTER}/wrench"
GRIPPER_ACTION = f"/{GRIPPER_CONTROLLER}/gripper_cmd"
VELOCITY_COMMAND_TOPIC = f"/{VELOCITY_CONTROLLER}/commands"

__all__ = [
    "AdmittanceParams",
    "AdmittanceState",
    "BEST_EFFORT",
    "Controller",
    "ControllerManager",
    "ControllersConfig",
    "FT_BROADCASTER",
    "ForceTorqueSensorBroadcaster",
    "GRIPPER_ACTION",
    "GRIPPER_CONTROLLER",
    "GripperActionController",
    "JTC_ACTION",
    "JTC_CONTROLLER",
    "JTC_TOPIC",
    "JointTrajectoryController",
    "JtcParams",
    "JointTrajectoryAdmittanceController",
    "LIST_SERVICE",
    "ParsedGoal",
    "STRICT",
    "SWITCH_SERVICE",
    "SeamError",
    "SwitchOutcome",
    "TRAJECTORY_ACTION",
    "TRAJECTORY_CONTROLLER",
    "Trajectory",
    "TrajectoryState",
    "VELOCITY_COMMAND_TOPIC",
    "VELOCITY_CONTROLLER",
    "VelocityForceController",
    "WRENCH_TOPIC",
    "admittance_step",
    "damped_pseudo_inverse",
    "make_controllers",
    "parse_goal",
    "path_violation",
    "stitch",
    "stop_trajectory",
    "wrench_violation",
]
