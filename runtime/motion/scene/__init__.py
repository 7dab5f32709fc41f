"""Planning scene for the safety checks: robot model, world, rules, collision queries, IK.

Robot-agnostic: the robot comes from a URDF + SRDF (``RobotModel.from_urdf``) or from pinocchio
models another loader built (``RobotModel.from_pinocchio``; the simulated cell's MJCF loader is
``sim.mjcf``); nothing here knows about the simulated cell or imports MuJoCo.
"""
from .collision import (
    Attachment,
    Box,
    Capsule,
    Clearance,
    CollisionChecker,
    CollisionResult,
    Cylinder,
    Mesh,
    Shape,
    Sphere,
    WorldObject,
    pose_matrix,
)
from .envelope import CartesianEnvelope, EnvelopeOverrides, EnvelopeViolation, KeepInBox, ToolCone, PoseCheck, check_envelope, load_envelope, narrowed, shrunk, tool_speed_ratio
from .kinematics import IkResult, IkSolver, frame_pose, frame_poses, solve_ik
from .limits import JointLimit, JointLimits, LimitViolation, load_joint_limits
from .model import ConfigurationMap, GroupError, JointCoupling, JointGroup, RobotModel, load_couplings
from .scene import ANY, PlanningScene, SceneSnapshot
from .srdf import Srdf, SrdfError, SrdfGroup, parse_srdf

__all__ = [
    "ANY", "Attachment", "Box", "Capsule", "CartesianEnvelope", "Clearance", "CollisionChecker", "CollisionResult",
    "EnvelopeOverrides", "EnvelopeViolation", "KeepInBox", "ToolCone", "check_envelope", "load_envelope", "narrowed", "PoseCheck", "shrunk", "tool_speed_ratio",
    "ConfigurationMap", "Cylinder", "GroupError", "IkResult", "IkSolver", "JointCoupling", "JointGroup",
    "JointLimit", "JointLimits", "LimitViolation", "Mesh", "PlanningScene", "RobotModel",
    "SceneSnapshot", "Shape", "Sphere", "Srdf", "SrdfError", "SrdfGroup", "WorldObject",
    "frame_pose", "frame_poses", "load_couplings", "load_joint_limits", "parse_srdf",
    "pose_matrix", "solve_ik",
]
