"""The planning scene: robot model, world objects, collision rules and attached objects.

Everything a safety check needs to answer "does this configuration (or path) collide?".
World geometry is live: the simulator (or perception) adds and moves objects at any time.
Collision rules and attachments can be frozen with ``snapshot()``; ExecutePolicy takes one at
start and passes it to every check of the run, so a rule changed mid-run does not change what
the run allows, while a new object in the path is still seen.

Configurations passed to the checks are rows in a *layout*: the joints of a group, then the
gripper value (optional). The default layout is the scene's ``group`` + ``gripper_joint``;
``scene.layout(group, gripper_joint)`` gives another. ``full_configuration`` turns a row into
pinocchio's full configuration (coupled gripper joints filled in).

Thread safety: one lock guards mutations and queries, so a simulator thread may move objects
while the tree thread checks paths.
"""
from __future__ import annotations

import functools
import threading
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
import pinocchio as pin

from .collision import (
    Attachment,
    Clearance,
    CollisionChecker,
    CollisionResult,
    Shape,
    WorldObject,
    as_se3,
    make_geometry,
)
from .envelope import CartesianEnvelope
from .kinematics import frame_pose
from .limits import JointLimits
from .model import ConfigurationMap, RobotModel

ANY = "*"


@dataclass(frozen=True)
class SceneSnapshot:
    """Immutable collision rules and attachments at one instant (hashable)."""

    rules: tuple[tuple[str, str, bool], ...]
    """``(object or "*", link or "*", allowed)`` entries, sorted."""
    attachments: tuple[Attachment, ...]

    def is_allowed(self, obj: str, link: str) -> bool:
        return _lookup(self._table, obj, link)

    @functools.cached_property
    def _table(self) -> dict[tuple[str, str], bool]:
        return {(o, l): a for o, l, a in self.rules}


def _lookup(rules: Mapping[tuple[str, str], bool], obj: str, link: str) -> bool:
    for key in ((obj, link), (obj, ANY), (ANY, link), (ANY, ANY)):
        if key in rules:
            return rules[key]
    return False


def _pose_tuple(pose: NDArray[np.float64] | pin.SE3) -> tuple[float, ...]:
    return tuple(as_se3(pose).homogeneous.reshape(-1).tolist())


class PlanningScene:
    """Robot + world objects + collision rules + attachments, with collision queries."""

    def __init__(
        self,
        robot: RobotModel,
        group: str,
        gripper_joint: str | None = None,
        limits: JointLimits | None = None,
        reference: NDArray[np.float64] | None = None,
        envelope: CartesianEnvelope | None = None,
    ):
        self._lock = threading.RLock()
        self.robot = robot
        self.limits = limits
        self.envelope = envelope
        """The cell's Cartesian envelope (``envelope.load_envelope``), or None: none checked."""
        self._reference = np.array(robot.neutral() if reference is None else reference, dtype=float)
        self._layouts: dict[tuple[str, str | None], ConfigurationMap] = {}
        self._default = (group, gripper_joint)
        self.layout(group, gripper_joint)  # fail early on a bad group or gripper joint
        self._objects: dict[str, WorldObject] = {}
        self._fixed: set[str] = set()
        self._rules: dict[tuple[str, str], bool] = {}
        self._attachments: dict[str, Attachment] = {}
        self._structure = 0  # bumped when the set of world objects changes
        self._poses = 0  # bumped when a world object moves
        self._moved_at: dict[str, int] = {}  # each object's ``_poses`` after its last move
        self._checkers: dict[tuple[int, SceneSnapshot, float], _PlacedChecker] = {}

    # -- layouts and configurations -------------------------------------------------------
    @property
    def group(self) -> str:
        return self._default[0]

    @property
    def gripper_joint(self) -> str | None:
        return self._default[1]

    def layout(self, group: str | None = None, gripper_joint: str | None = None) -> ConfigurationMap:
        """The row layout ``[joints of group..., gripper_joint]`` (default: the scene's)."""
        key = self._default if group is None else (group, gripper_joint)
        with self._lock:
            if key not in self._layouts:
                self._layouts[key] = self.robot.configuration_map(key[0], key[1], self._reference)
            return self._layouts[key]

    def full_configuration(self, group_positions: Sequence[float], gripper_position: float | None = None,
                           layout: ConfigurationMap | None = None) -> NDArray[np.float64]:
        """Pinocchio's full ``q`` from group joint values (+ gripper value)."""
        rows = self._rows(np.asarray(group_positions, dtype=float)[None, :] if gripper_position is None
                          else np.append(np.asarray(group_positions, dtype=float), gripper_position)[None, :], layout)
        q: NDArray[np.float64] = rows[0]
        return q

    def _rows(self, Q: NDArray[np.float64], layout: ConfigurationMap | None) -> NDArray[np.float64]:
        """Rows in a layout (with or without the gripper column) -> full configurations."""
        lay = layout or self.layout()
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        if not np.all(np.isfinite(Q)):
            bad = np.argwhere(~np.isfinite(Q))[0]
            raise ValueError(f"configuration row {bad[0]} column {bad[1]} is not finite")
        if lay.gripper_joint is not None and Q.shape[1] == lay.dof - 1:
            return self.layout(lay.group.name, None)(Q)
        if Q.shape[1] != lay.dof:
            accepted = f"{lay.dof}" + (f" or {lay.dof - 1} (without the gripper)" if lay.gripper_joint else "")
            raise ValueError(f"configurations have {Q.shape[1]} values per row; expected {accepted}: "
                             f"{', '.join(lay.columns)}")
        return lay(Q)

    # -- world objects --------------------------------------------------------------------
    def add_object(self, name: str, shape: Shape, pose: NDArray[np.float64], fixed: bool = False) -> None:
        """Add (or replace) a world object; ``pose`` is a 4x4 matrix in the world frame.

        ``fixed`` marks the cell's furniture (a table, a welded box): an object the task never
        handles, so ``handled_objects`` leaves it out."""
        if not name or name == ANY:
            raise ValueError(f"invalid object name {name!r}")
        make_geometry(shape)  # validate now, not at the next check
        with self._lock:
            if name in self._attachments:
                raise ValueError(f"object {name!r} is attached to {self._attachments[name].link!r}; detach it first")
            self._objects[name] = WorldObject(name, shape, _pose_tuple(pose))
            (self._fixed.add if fixed else self._fixed.discard)(name)
            self._structure += 1

    @property
    def version(self) -> tuple[int, int]:
        """Changes whenever a world object is added, removed, attached, detached or moved:
        a check repeated at the same version gives the same answer."""
        with self._lock:
            return (self._structure, self._poses)

    def move_object(self, name: str, pose: NDArray[np.float64] | pin.SE3) -> None:
        """Move a world object to ``pose``: a 4x4 matrix (its 3x3 block must be a rotation), or a
        ``pin.SE3``, taken as it is."""
        with self._lock:
            obj = self._object(name)
            self._objects[name] = WorldObject(name, obj.shape, _pose_tuple(pose))
            self._poses += 1
            self._moved_at[name] = self._poses

    def remove_object(self, name: str) -> None:
        with self._lock:
            self._object(name)
            del self._objects[name]
            self._fixed.discard(name)
            self._structure += 1

    def object_pose(self, name: str) -> NDArray[np.float64]:
        with self._lock:
            return self._object(name).matrix

    @property
    def objects(self) -> dict[str, WorldObject]:
        with self._lock:
            return dict(self._objects)

    @property
    def handled_objects(self) -> list[str]:
        """The world objects a task may handle, sorted: every one but the fixed ones (the
        table). What an Objective's ``SetCollisionRule object_name="*"`` stands for."""
        with self._lock:
            return sorted(n for n in self._objects if n not in self._fixed)

    def _object(self, name: str) -> WorldObject:
        try:
            return self._objects[name]
        except KeyError:
            known = ", ".join(self._objects) or "none"
            raise KeyError(f"no world object {name!r} in the planning scene (objects: {known})") from None

    # -- collision rules ------------------------------------------------------------------
    def _expand_links(self, links: str | Iterable[str]) -> list[str]:
        names = [links] if isinstance(links, str) else list(links)
        out = []
        for name in names:
            if name == ANY or name in self.robot.link_names or name in self._attachments:
                out.append(name)
            elif name in self.robot.group_names:
                out.extend(self.robot.group(name).links)
            else:
                raise KeyError(f"{name!r} is neither a link, a group nor an attached object of the robot")
        return out

    def allow(self, object_name: str, links: str | Iterable[str]) -> None:
        """Let ``object_name`` (or ``"*"``: every object) touch these links / groups / ``"*"``."""
        with self._lock:
            for link in self._expand_links(links):
                self._rules[(object_name, link)] = True

    def disallow(self, object_name: str, links: str | Iterable[str]) -> None:
        """Forbid contact again; an explicit entry wins over a ``"*"`` one."""
        with self._lock:
            for link in self._expand_links(links):
                self._rules[(object_name, link)] = False

    def is_allowed(self, object_name: str, link: str) -> bool:
        with self._lock:
            return _lookup(self._rules, object_name, link)

    def snapshot_with_rule(self, snapshot: SceneSnapshot, object_name: str, links: str | Iterable[str],
                           allowed: bool) -> SceneSnapshot:
        """``snapshot`` with ``object_name`` allowed (or forbidden) to touch these links / groups
        / ``"*"``, as ``allow``/``disallow`` would set it; the scene's own rules are unchanged."""
        with self._lock:
            rules = {(o, l): a for o, l, a in snapshot.rules}
            for link in self._expand_links(links):
                rules[(object_name, link)] = allowed
        return SceneSnapshot(tuple(sorted((o, l, a) for (o, l), a in rules.items())), snapshot.attachments)

    # -- attachments ----------------------------------------------------------------------
    def attach(
        self,
        name: str,
        link: str,
        *,
        q: NDArray[np.float64] | None = None,
        shape: Shape | None = None,
        pose_in_link: NDArray[np.float64] | None = None,
        touch_links: Iterable[str] = (),
    ) -> Attachment:
        """Carry an object with ``link``.

        A world object of that name moves from the world to the link, keeping its current
        world pose (needs ``q``, a layout row, to know where the link is) unless
        ``pose_in_link`` is given. A new object needs ``shape`` and ``pose_in_link``.
        """
        touch = set(self._expand_links(touch_links))
        with self._lock:
            if link not in self.robot.link_names:
                raise KeyError(f"cannot attach {name!r}: {link!r} is not a link of the robot")
            if name in self._attachments:
                raise ValueError(f"object {name!r} is already attached to {self._attachments[name].link!r}")
            world = self._objects.get(name)
            if shape is None:
                if world is None:
                    raise ValueError(f"cannot attach {name!r}: not a world object, and no shape given")
                shape = world.shape
            if pose_in_link is None:
                if world is None or q is None:
                    raise ValueError(f"attach {name!r}: give pose_in_link, or q with {name!r} in the world")
                link_pose = self.link_pose(q, link)
                pose_in_link = np.linalg.inv(link_pose) @ world.matrix
            attachment = Attachment(name, link, shape, _pose_tuple(pose_in_link), frozenset(touch))
            self._objects.pop(name, None)
            self._attachments[name] = attachment
            self._structure += 1
            return attachment

    def detach(self, name: str, q: NDArray[np.float64] | None = None) -> None:
        """Stop carrying ``name``; with ``q`` (a layout row) it stays in the world where it is."""
        with self._lock:
            att = self._attachments.pop(name, None)
            if att is None:
                raise KeyError(f"no attached object {name!r} (attached: {', '.join(self._attachments) or 'none'})")
            if q is not None:
                pose = self.link_pose(q, att.link) @ att.matrix
                self._objects[name] = WorldObject(name, att.shape, _pose_tuple(pose))
            self._structure += 1

    @property
    def attachments(self) -> tuple[Attachment, ...]:
        with self._lock:
            return tuple(self._attachments.values())

    def snapshot(self) -> SceneSnapshot:
        with self._lock:
            rules = tuple(sorted((o, l, a) for (o, l), a in self._rules.items()))
            return SceneSnapshot(rules, tuple(sorted(self._attachments.values(), key=lambda a: a.name)))

    # -- queries --------------------------------------------------------------------------
    def link_pose(self, q: NDArray[np.float64], link: str, layout: ConfigurationMap | None = None) -> NDArray[np.float64]:
        """4x4 world pose of a link or frame at layout row ``q``."""
        return frame_pose(self.robot, self._rows(q, layout)[0], link)

    def object_world_pose(self, name: str, q: NDArray[np.float64], layout: ConfigurationMap | None = None) -> NDArray[np.float64]:
        """Where an object is: its world pose, or its carrying link's pose times its offset."""
        with self._lock:
            if name in self._attachments:
                att = self._attachments[name]
                return self.link_pose(q, att.link, layout) @ att.matrix
            return self._object(name).matrix

    def check_state(self, q: NDArray[np.float64], padding: float = 0.01, snapshot: SceneSnapshot | None = None,
                    layout: ConfigurationMap | None = None) -> CollisionResult | None:
        """First colliding pair at one layout row, or None when collision-free."""
        q_full = self._rows(q, layout)[0]
        with self._lock:
            return self._checker(padding, snapshot).check(q_full)

    def check_path(
        self,
        Q: NDArray[np.float64],
        times: NDArray[np.float64] | None = None,
        padding: float = 0.01,
        stop_at_first: bool = True,
        snapshot: SceneSnapshot | None = None,
        layout: ConfigurationMap | None = None,
        early_out: bool = True,
        free_at: tuple[int, int] | None = None,
    ) -> CollisionResult | None | list[CollisionResult]:
        """Check every row of ``Q`` (N, dof). ``stop_at_first``: the first hit or None;
        otherwise a list with the first colliding pair of every colliding step. The answer for
        every row is the one ``check_state`` gives; ``early_out=False`` checks each row on its
        own instead of settling proven-free runs of rows at once (for comparisons).

        ``free_at`` (with ``stop_at_first``): a ``version`` at which the caller found these very
        rows free with the same padding and snapshot. If only world objects moved since, only
        their pairs are checked (9 of the cell's 143 for one cube), with the same answer."""
        full = self._rows(Q, layout)
        if times is not None and len(times) != len(full):
            raise ValueError(f"times has {len(times)} entries for {len(full)} path points")
        with self._lock:
            checker = self._checker(padding, snapshot)
            if stop_at_first and free_at is not None and free_at[0] == self._structure:
                moved = [name for name, at in self._moved_at.items() if at > free_at[1]]
                return checker.first_hit_of_objects(moved, full, times)
            hits = checker.check_many(full, times, stop_at_first, early_out)
        if stop_at_first:
            return hits[0] if hits else None
        return hits

    def min_distance(self, q: NDArray[np.float64], kind: str | None = None, snapshot: SceneSnapshot | None = None,
                     layout: ConfigurationMap | None = None) -> Clearance | None:
        """Closest checked pair at ``q`` (unpadded signed distance), optionally only ``"self"``
        or ``"world"`` pairs; None if no such pair is checked. About 50 us: not per path point."""
        q_full = self._rows(q, layout)[0]
        with self._lock:
            return self._checker(0.0, snapshot).clearance(q_full, kind)

    def _checker(self, padding: float, snapshot: SceneSnapshot | None) -> CollisionChecker:
        snap = snapshot or self.snapshot()
        key = (self._structure, snap, float(padding))
        cached = self._checkers.get(key)
        if cached is None:
            carried = {a.name for a in snap.attachments}
            world = {o.name: o for o in self._objects.values() if o.name not in carried}
            checker = CollisionChecker(self.robot, list(world.values()), snap.attachments, snap.is_allowed, padding)
            if len(self._checkers) >= 8:
                self._checkers.clear()
            cached = _PlacedChecker(checker, self._poses, {n: o for n, o in world.items() if n in checker.world_names})
            self._checkers[key] = cached
        if cached.poses != self._poses:  # move the objects that moved since (usually one cube of several)
            for name, placed in cached.placed.items():
                obj = self._objects[name]
                if obj is not placed:
                    cached.checker.move(name, obj.matrix)
                    cached.placed[name] = obj
            cached.poses = self._poses
        return cached.checker


@dataclass
class _PlacedChecker:
    """A compiled checker and the world objects (immutable) its placements were taken from."""

    checker: CollisionChecker
    poses: int
    """``PlanningScene._poses`` when the placements were last brought up to date."""
    placed: dict[str, WorldObject]
