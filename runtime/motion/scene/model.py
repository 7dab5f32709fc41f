"""The robot model of the planning scene: kinematics, collision geometry, groups, coupling.

``RobotModel`` is built once from either the URDF + SRDF pair ROS users have (``from_urdf``)
or pinocchio models another loader built (``from_pinocchio``: the simulated cell's MJCF, see
``sim.mjcf``) and is read-only afterwards, so the same instance can
serve several scenes. Links are pinocchio BODY frames (MJCF bodies, URDF links); the world is
the link ``"universe"``.

Configurations: pinocchio's full vector ``q`` holds every joint of the model, including the
gripper linkage. Callers think in a joint group plus one gripper value, so
``ConfigurationMap`` turns rows ``[group joints..., gripper]`` into full ``q`` vectors
(vectorised for whole paths), filling coupled joints from their driver (``JointCoupling``).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
import pinocchio as pin
import yaml

from .batch_kinematics import BatchKinematics
from .hulls import with_convex_hulls
from .srdf import Srdf, SrdfGroup, parse_srdf
from runtime.errors import ObjectiveError

WORLD_LINK = "universe"


class GroupError(ObjectiveError, ValueError):
    """A joint group that is unknown or cannot be used as asked (e.g. it has two tips)."""


class DescriptionError(ObjectiveError, ValueError):
    """A robot description file (URDF) its parser refuses; the message names the file."""


@dataclass(frozen=True)
class JointCoupling:
    """``joint = multiplier * driver + offset``: a joint moved by another (mimic, linkage)."""

    joint: str
    driver: str
    multiplier: float = 1.0
    offset: float = 0.0


def load_couplings(path: str | os.PathLike[str]) -> tuple[JointCoupling, ...]:
    """Read ``coupled_joints:`` from a YAML file: ``{joint: {driver, multiplier, offset}}``."""
    with open(path) as f:
        doc = yaml.safe_load(f) or {}
    table = doc.get("coupled_joints")
    if not isinstance(table, dict):
        raise ValueError(f"{path}: expected a mapping 'coupled_joints: {{joint: {{driver, multiplier, offset}}}}'")
    couplings = []
    for joint, spec in table.items():
        if not isinstance(spec, dict) or "driver" not in spec:
            raise ValueError(f"{path}: coupled_joints.{joint} needs a 'driver' (and optional multiplier, offset)")
        unknown = set(spec) - {"driver", "multiplier", "offset"}
        if unknown:
            raise ValueError(f"{path}: coupled_joints.{joint} has unknown keys {sorted(unknown)}")
        couplings.append(JointCoupling(str(joint), str(spec["driver"]), float(spec.get("multiplier", 1.0)),
                                       float(spec.get("offset", 0.0))))
    return tuple(couplings)


@dataclass(frozen=True)
class JointGroup:
    """A named set of joints and links; ``tip_link`` exists only when the tips are unique."""

    name: str
    joints: tuple[str, ...]
    """Movable joints, in model order (base to tip along each branch)."""
    links: tuple[str, ...]
    tips: tuple[str, ...]
    """Links of the group with no descendant in the group."""

    @property
    def tip_link(self) -> str:
        if len(self.tips) != 1:
            found = ", ".join(self.tips) if self.tips else "none"
            raise GroupError(
                f"joint group {self.name!r} must resolve to exactly one tip link; found {len(self.tips)}: {found}"
            )
        return self.tips[0]


class ConfigurationMap:
    """Rows ``[group joints..., gripper?]`` -> full pinocchio configurations, vectorised.

    Joints that are neither in the group nor driven by the gripper keep their value from
    ``reference`` (a full ``q``). Coupled joints follow their driver when the driver is part
    of the row.
    """

    def __init__(self, robot: "RobotModel", group: JointGroup, gripper_joint: str | None, reference: NDArray[np.float64]):
        self.group = group
        self.gripper_joint = gripper_joint
        self.columns: tuple[str, ...] = group.joints + ((gripper_joint,) if gripper_joint else ())
        self.reference = np.array(reference, dtype=float)
        nq = robot.model.nq
        # q = reference * keep + rows @ gain + bias, then unbounded joints get (cos, sin).
        self._gain = np.zeros((len(self.columns), nq))
        self._bias = np.zeros(nq)
        self._keep = np.ones(nq)
        for col, joint in enumerate(self.columns):
            for target, mult, offset in robot.driven_by(joint):
                idx = robot.joint_q_index(target)
                self._gain[col, idx] = mult
                self._bias[idx] = offset
                self._keep[idx] = 0.0
        self._unbounded = [(robot.joint_q_index(j), col) for col, j in enumerate(self.columns)
                           if robot.model.joints[robot.model.getJointId(j)].nq == 2]
        self._unbounded_cols = {col for _, col in self._unbounded}

    @property
    def dof(self) -> int:
        return len(self.columns)

    def __call__(self, rows: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(N, dof) -> (N, nq)``; a single row ``(dof,) -> (nq,)``."""
        x = np.asarray(rows, dtype=float)
        single = x.ndim == 1
        x2 = np.atleast_2d(x)
        if x2.shape[1] != self.dof:
            raise ValueError(
                f"configuration rows have {x2.shape[1]} values; expected {self.dof} ({', '.join(self.columns)})"
            )
        q: NDArray[np.float64] = self.reference * self._keep + x2 @ self._gain + self._bias
        for idx, col in self._unbounded:
            q[:, idx] = np.cos(x2[:, col])
            q[:, idx + 1] = np.sin(x2[:, col])
        return q[0] if single else q


class RobotModel:
    """Kinematic + collision model of one robot, with its SRDF groups and joint couplings."""

    def __init__(
        self,
        model: pin.Model,
        collision_model: pin.GeometryModel,
        srdf: Srdf | None = None,
        couplings: Iterable[JointCoupling] = (),
        source: str = "",
    ):
        self.model = model
        self.source = source
        self.srdf = srdf if srdf is not None else Srdf(robot_name=model.name, source="<none>")
        self.couplings = tuple(couplings)
        self.collision_model = with_convex_hulls(collision_model)
        self._frame_ids = {f.name: i for i, f in enumerate(model.frames)}
        self.link_names: tuple[str, ...] = tuple(
            f.name for f in model.frames if f.type == pin.FrameType.BODY
        ) or ()
        self._link_parent = self._compute_link_parents()
        self.movable_joints: tuple[str, ...] = tuple(
            model.names[j] for j in range(1, model.njoints) if model.joints[j].nv == 1
        )
        self.geometry_links: tuple[str, ...] = tuple(
            self.link_of_frame(go.parentFrame) for go in self.collision_model.geometryObjects
        )
        self._check_couplings()
        self._check_srdf_names()
        self._groups: dict[str, JointGroup] = {}
        self._batch_kinematics: dict[tuple[str, ...], BatchKinematics] = {}

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def from_pinocchio(
        cls,
        model: pin.Model,
        collision_model: pin.GeometryModel,
        srdf: str | os.PathLike[str] | Srdf | None = None,
        couplings: Iterable[JointCoupling] | str | os.PathLike[str] = (),
        source: str = "",
    ) -> "RobotModel":
        """A robot from models a loader built (``sim.mjcf`` builds them from the simulator's MJCF),
        with its SRDF and couplings given as objects or files."""
        return cls(model, collision_model, _srdf(srdf), _couplings(couplings), source=source)

    @classmethod
    def from_urdf(
        cls,
        urdf: str | os.PathLike[str],
        srdf: str | os.PathLike[str] | Srdf | None = None,
        package_dirs: Sequence[str | os.PathLike[str]] = (),
        couplings: Iterable[JointCoupling] | str | os.PathLike[str] = (),
    ) -> "RobotModel":
        """Load a robot from a URDF file (meshes through ``package://`` and ``package_dirs``).

        URDF ``<mimic>`` joints become couplings unless ``couplings`` names them already.
        """
        path = Path(urdf)
        if not path.is_file():
            raise FileNotFoundError(f"URDF file not found: {path}")
        dirs = [str(d) for d in package_dirs] or [str(path.parent)]
        try:
            model = pin.buildModelFromUrdf(str(path))
            geometry = pin.buildGeomFromUrdf(model, str(path), pin.COLLISION, package_dirs=dirs)
        except (ValueError, RuntimeError) as err:  # pinocchio's URDF parser: the file, not a bug here
            raise DescriptionError(f"{path}: {str(err).strip().splitlines()[0]}") from None
        explicit = _couplings(couplings)
        named = {c.joint for c in explicit}
        mimic = tuple(c for c in _urdf_mimics(path) if c.joint not in named)
        return cls(model, geometry, _srdf(srdf), explicit + mimic, source=str(path))

    # -- names and structure --------------------------------------------------------------
    def frame_id(self, name: str) -> int:
        try:
            return self._frame_ids[name]
        except KeyError:
            raise KeyError(f"unknown frame {name!r} in robot model {self.model.name!r}") from None

    def has_frame(self, name: str) -> bool:
        return name in self._frame_ids

    def batch_kinematics(self, frames: Sequence[str]) -> BatchKinematics:
        """Forward kinematics of ``frames`` over many configurations at once (built once per
        set of frames and kept)."""
        key = tuple(frames)
        if key not in self._batch_kinematics:
            self._batch_kinematics[key] = BatchKinematics(self.model, [self.frame_id(f) for f in key])
        return self._batch_kinematics[key]

    def link_of_frame(self, frame_id: int) -> str:
        """The link (BODY frame) a frame is rigidly attached to; ``universe`` for the world."""
        frames = self.model.frames
        while frame_id != 0 and frames[frame_id].type != pin.FrameType.BODY:
            frame_id = frames[frame_id].parentFrame
        name: str = frames[frame_id].name
        return name

    def parent_link(self, link: str) -> str:
        return self._link_parent[link]

    def _compute_link_parents(self) -> dict[str, str]:
        parents = {}
        for i, f in enumerate(self.model.frames):
            if f.type == pin.FrameType.BODY:
                parents[f.name] = self.link_of_frame(f.parentFrame) if i != 0 else WORLD_LINK
        return parents

    def ancestors(self, link: str) -> list[str]:
        out = []
        while link in self._link_parent and link != WORLD_LINK:
            link = self._link_parent[link]
            out.append(link)
        return out

    def adjacent_link_pairs(self) -> frozenset[frozenset[str]]:
        """Parent-child link pairs: touching by construction, never checked against each other."""
        return frozenset(frozenset((c, p)) for c, p in self._link_parent.items() if p != c)

    def joint_q_index(self, joint: str) -> int:
        jid = self.model.getJointId(joint)
        if jid >= self.model.njoints:
            raise KeyError(f"unknown joint {joint!r} in robot model {self.model.name!r}")
        return int(self.model.idx_qs[jid])

    def joint_child_link(self, joint: str) -> str:
        """The link a joint moves directly (the BODY frame hanging off the joint's frame)."""
        jframe = self.frame_id(joint)
        for f in self.model.frames:
            if f.type == pin.FrameType.BODY and f.parentFrame == jframe:
                child: str = f.name
                return child
        raise KeyError(f"joint {joint!r} has no child link")

    def driven_by(self, joint: str) -> list[tuple[str, float, float]]:
        """``[(joint, multiplier, offset)]`` set by one value of ``joint``: itself and its followers."""
        return [(joint, 1.0, 0.0)] + [(c.joint, c.multiplier, c.offset) for c in self.couplings if c.driver == joint]

    def _check_couplings(self) -> None:
        known = set(self.movable_joints)
        for c in self.couplings:
            for name in (c.joint, c.driver):
                if name not in known:
                    raise ValueError(f"joint coupling {c.joint} <- {c.driver}: unknown joint {name!r}")

    def _check_srdf_names(self) -> None:
        links = set(self.link_names) | {WORLD_LINK}
        joints = {self.model.names[j] for j in range(1, self.model.njoints)}
        joints |= {f.name for f in self.model.frames if f.type == pin.FrameType.FIXED_JOINT}
        where = self.srdf.source
        for g in self.srdf.groups.values():
            for j in g.joints:
                if j not in joints:
                    raise GroupError(f"{where}:{g.line}: group {g.name!r}: unknown joint {j!r}")
            for link in list(g.links) + [x for chain in g.chains for x in chain]:
                if link not in links:
                    raise GroupError(f"{where}:{g.line}: group {g.name!r}: unknown link {link!r}")
        for pair in self.srdf.disabled_collisions:
            for link in (pair.link1, pair.link2):
                if link not in links:
                    raise GroupError(f"{where}: disable_collisions names unknown link {link!r}")

    # -- groups ---------------------------------------------------------------------------
    @property
    def group_names(self) -> tuple[str, ...]:
        return tuple(self.srdf.groups)

    def group(self, name: str) -> JointGroup:
        """Resolve an SRDF group: its joints (model order), links and tips."""
        if name not in self._groups:
            if name not in self.srdf.groups:
                known = ", ".join(self.srdf.groups) or "none"
                raise GroupError(f"unknown joint group {name!r} (groups: {known})")
            self._groups[name] = self._resolve_group(self.srdf.groups[name], set())
        return self._groups[name]

    def _resolve_group(self, g: SrdfGroup, seen: set[str]) -> JointGroup:
        if g.name in seen:
            raise GroupError(f"group {g.name!r} includes itself")
        joints: set[str] = set(g.joints)
        links: set[str] = set(g.links)
        for base, tip in g.chains:
            path = [tip] + self.ancestors(tip)
            if base not in path:
                raise GroupError(f"group {g.name!r}: chain base {base!r} is not an ancestor of tip {tip!r}")
            chain_links = path[: path.index(base)]
            links.update(chain_links)
            for link in chain_links:
                joints.update(self._joints_moving(link, base))
        for joint in list(joints):
            if joint in self.movable_joints:
                links.add(self.joint_child_link(joint))
        for link in g.links:
            fid = self.frame_id(link)
            parent_joint_frame = self.model.frames[fid].parentFrame
            if self.model.frames[parent_joint_frame].type == pin.FrameType.JOINT:
                joints.add(self.model.frames[parent_joint_frame].name)
        for sub in g.subgroups:
            resolved = self._resolve_group(self.srdf.groups[sub], seen | {g.name})
            joints.update(resolved.joints)
            links.update(resolved.links)
        movable = [j for j in self.movable_joints if j in joints]
        ordered_links = [link for link in self.link_names if link in links]
        tips = tuple(link for link in ordered_links
                     if not any(link in self.ancestors(other) for other in ordered_links))
        return JointGroup(name=g.name, joints=tuple(movable), links=tuple(ordered_links), tips=tips)

    def _joints_moving(self, link: str, base: str) -> list[str]:
        """Movable joints between ``base`` and ``link`` (the one entering ``link`` if any)."""
        fid = self.frame_id(link)
        parent = self.model.frames[fid].parentFrame
        frame = self.model.frames[parent]
        return [frame.name] if frame.type == pin.FrameType.JOINT else []

    # -- configurations -------------------------------------------------------------------
    def neutral(self) -> NDArray[np.float64]:
        neutral: NDArray[np.float64] = pin.neutral(self.model)
        return neutral

    def configuration(self, positions: Mapping[str, float], reference: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """A full ``q`` from ``{joint: value}``; coupled joints follow their drivers."""
        q = np.array(self.neutral() if reference is None else reference, dtype=float)
        for joint, value in positions.items():
            if joint not in self.movable_joints:
                raise KeyError(f"unknown joint {joint!r} (movable joints: {', '.join(self.movable_joints)})")
            for target, mult, offset in self.driven_by(joint):
                idx = self.joint_q_index(target)
                v = mult * float(value) + offset
                if self.model.joints[self.model.getJointId(target)].nq == 2:
                    q[idx], q[idx + 1] = np.cos(v), np.sin(v)
                else:
                    q[idx] = v
        return q

    def configuration_map(self, group: str, gripper_joint: str | None = None,
                          reference: NDArray[np.float64] | None = None) -> ConfigurationMap:
        """Map rows ``[joints of group..., gripper_joint]`` to full configurations."""
        resolved = self.group(group)
        if gripper_joint is not None:
            if gripper_joint not in self.movable_joints:
                raise GroupError(f"gripper joint {gripper_joint!r} is not a single-DOF joint of the model")
            if gripper_joint in resolved.joints:
                raise GroupError(f"gripper joint {gripper_joint!r} is part of group {group!r}; it must be outside it")
        ref = self.neutral() if reference is None else np.asarray(reference, dtype=float)
        return ConfigurationMap(self, resolved, gripper_joint, ref)

    def position_limits(self, joints: Sequence[str]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Lower and upper position limits of 1-DOF joints, from the model."""
        lower, upper = [], []
        for joint in joints:
            idx = self.joint_q_index(joint)
            if self.model.joints[self.model.getJointId(joint)].nq == 2:
                lower.append(-np.inf)
                upper.append(np.inf)
            else:
                lower.append(float(self.model.lowerPositionLimit[idx]))
                upper.append(float(self.model.upperPositionLimit[idx]))
        return np.array(lower), np.array(upper)


def _srdf(srdf: str | os.PathLike[str] | Srdf | None) -> Srdf | None:
    if srdf is None or isinstance(srdf, Srdf):
        return srdf
    return parse_srdf(srdf)


def _couplings(couplings: Iterable[JointCoupling] | str | os.PathLike[str]) -> tuple[JointCoupling, ...]:
    if isinstance(couplings, (str, os.PathLike)):
        return load_couplings(couplings)
    return tuple(couplings)


def _urdf_mimics(path: Path) -> tuple[JointCoupling, ...]:
    from lxml import etree

    root = etree.parse(str(path), etree.XMLParser(resolve_entities=False, no_network=True)).getroot()
    out = []
    for joint in root.iterfind("joint"):
        mimic = joint.find("mimic")
        if mimic is not None:
            out.append(JointCoupling(joint.get("name"), mimic.get("joint"),
                                     float(mimic.get("multiplier", 1.0)), float(mimic.get("offset", 0.0))))
    return tuple(out)
