"""Collision checking: shapes, results, and a compiled checker over robot + world geometry.

``CollisionChecker`` is the fast inner loop. It is compiled for one set of world objects,
attachments, allowed-collision rules and padding; the planning scene caches checkers and
only moves world objects between queries. The pipeline per configuration is pinocchio FK,
geometry placement, a coal broadphase (pinocchio inflates bounding boxes by each pair's
``security_margin``) and GJK/EPA narrowphase on convex shapes, stopping at the first
colliding pair. Measured on the UR5e + 2F-85 cell with a table and three cubes: sweep-and-prune
(SSaP, the default) 6.4 us per configuration, DynamicAABBTree 12 us, all pairs without
broadphase 34 us; the three agree on 4000 random configurations.

A path (``check_many``) is cheaper than its points one by one: a run of points whose joints all
stay within a budget L of the run's first point is proven collision-free by one check at that
point with every pair's margin inflated by how far L of joint motion can bring the pair closer
(``swept``: link lengths and geometry extents). Points no such run covers are checked on their
own, so every point gets exactly the answer ``check`` gives it (tests/test_path_early_out.py).

Pairs checked:
- self: robot link vs robot link, unpadded, except adjacent links, SRDF-disabled pairs and
  geometries on the same joint (their relative pose never changes);
- self: attached object vs robot links other than its parent and touch links, unpadded;
- world: robot link or attached object vs world object, with ``padding`` as security margin,
  unless the collision rules allow the pair.
"""
from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from typing import Callable, Iterable, Sequence

import coal
import numpy as np
from numpy.typing import NDArray
import pinocchio as pin

from . import swept
from .model import RobotModel

SWEPT_LEVELS_RAD = (0.005, 0.01, 0.02, 0.04, 0.08, 0.16)
"""Joint-motion budgets of the path early-out (see ``swept``): a window of points whose joints
all stay within L of the window's first point is proven free by one check there with every
pair's margin inflated by L times its motion coefficients."""
SWEPT_SLACK_M = 1e-4
"""Added to every inflated margin: far more than coal's GJK tolerance (1e-6 m)."""


# -- shapes ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Box:
    size: tuple[float, float, float]
    """Full edge lengths along x, y, z (metres)."""


@dataclass(frozen=True)
class Sphere:
    radius: float


@dataclass(frozen=True)
class Cylinder:
    radius: float
    length: float
    """Along z, centred on the origin."""


@dataclass(frozen=True)
class Capsule:
    radius: float
    length: float
    """Length of the segment between the two hemisphere centres, along z."""


@dataclass(frozen=True)
class Mesh:
    """A mesh file, checked as its convex hull."""

    path: str
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)


Shape = Box | Sphere | Cylinder | Capsule | Mesh


def _positive(shape: Shape, **values: float) -> None:
    for name, value in values.items():
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{type(shape).__name__}.{name} must be a positive number, got {value!r}")


def make_geometry(shape: Shape) -> coal.CollisionGeometry:
    """A coal geometry for a shape; meshes become convex hulls (cached per file and scale)."""
    if isinstance(shape, Box):
        if len(shape.size) != 3:
            raise ValueError(f"Box.size needs 3 values (x, y, z), got {shape.size!r}")
        _positive(shape, x=shape.size[0], y=shape.size[1], z=shape.size[2])
        return coal.Box(*map(float, shape.size))
    if isinstance(shape, Sphere):
        _positive(shape, radius=shape.radius)
        return coal.Sphere(float(shape.radius))
    if isinstance(shape, Cylinder):
        _positive(shape, radius=shape.radius, length=shape.length)
        return coal.Cylinder(float(shape.radius), float(shape.length))
    if isinstance(shape, Capsule):
        _positive(shape, radius=shape.radius, length=shape.length)
        return coal.Capsule(float(shape.radius), float(shape.length))
    if isinstance(shape, Mesh):
        return _mesh_hull(str(shape.path), tuple(float(s) for s in shape.scale))
    raise TypeError(f"unsupported shape {shape!r}; use Box, Sphere, Cylinder, Capsule or Mesh")


@functools.lru_cache(maxsize=64)
def _mesh_hull(path: str, scale: tuple[float, float, float]) -> coal.CollisionGeometry:
    if not os.path.isfile(path):
        raise FileNotFoundError(f"mesh file not found: {path}")
    loader = coal.MeshLoader()
    bvh = loader.load(path, np.array(scale))
    bvh.buildConvexHull(True, "Qt")
    hull = bvh.convex
    hull.computeLocalAABB()
    return hull


def as_se3(pose: NDArray[np.float64] | pin.SE3) -> pin.SE3:
    if isinstance(pose, pin.SE3):
        return pose
    m = np.asarray(pose, dtype=float)
    if m.shape != (4, 4):
        raise ValueError(f"a pose must be a 4x4 homogeneous matrix, got shape {m.shape}")
    rotation = m[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6):
        raise ValueError("a pose's 3x3 block must be a rotation matrix")
    return pin.SE3(rotation, m[:3, 3])


def pose_matrix(translation: Sequence[float] | NDArray[np.float64] = (0.0, 0.0, 0.0), rotation: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """A 4x4 pose from a translation and an optional 3x3 rotation."""
    m = np.eye(4)
    m[:3, 3] = translation
    if rotation is not None:
        m[:3, :3] = rotation
    return m


# -- scene content the checker is compiled from ---------------------------------------------
@dataclass(frozen=True)
class WorldObject:
    name: str
    shape: Shape
    pose: tuple[float, ...]
    """Row-major 4x4 pose in the world frame (a tuple so the object is immutable)."""

    @property
    def matrix(self) -> NDArray[np.float64]:
        return np.array(self.pose).reshape(4, 4)


@dataclass(frozen=True)
class Attachment:
    """An object carried by a robot link: moves with it, never collides with it."""

    name: str
    link: str
    shape: Shape
    pose_in_link: tuple[float, ...]
    """Row-major 4x4 pose of the object in the link frame."""
    touch_links: frozenset[str] = frozenset()
    """Other links it may touch (e.g. the fingers holding it)."""

    @property
    def matrix(self) -> NDArray[np.float64]:
        return np.array(self.pose_in_link).reshape(4, 4)


@dataclass(frozen=True)
class CollisionResult:
    """One colliding pair: what, where in a path, and how deep."""

    kind: str
    """``self`` (robot vs robot or carried object) or ``world`` (vs a world object)."""
    first: str
    """A robot link, or ``attached:<object>``."""
    second: str
    """A robot link, ``attached:<object>``, or a world object name."""
    distance: float
    """Signed distance between the shapes (negative: penetration depth)."""
    padding: float
    step: int | None = None
    time: float | None = None

    def __str__(self) -> str:
        where = ""
        if self.step is not None:
            where = f"step {self.step}" + (f" (t={self.time:.3f} s)" if self.time is not None else "") + ": "
        head = f"{where}{self.kind} collision {self.first} vs {self.second}"
        if self.distance < 0:
            return f"{head}: penetration {-self.distance * 1000:.1f} mm"
        if self.kind != "world":
            return f"{head}: distance {self.distance * 1000:.1f} mm"
        distance, padding = millimetres_apart(self.distance * 1000, self.padding * 1000)
        return f"{head}: distance {distance} mm < padding {padding} mm"


def millimetres_apart(below_mm: float, limit_mm: float) -> tuple[str, str]:
    """Two lengths at one decimal, or at as many more (up to three, then the first cut down rather
    than rounded) as it takes for the first to read below the second: a distance 9.96 mm under a
    10 mm padding reads 9.96 < 10.00, not 10.0 < 10.0."""
    for digits in (1, 2, 3):
        if round(below_mm, digits) < round(limit_mm, digits):
            return f"{below_mm:.{digits}f}", f"{limit_mm:.{digits}f}"
    return f"{math.floor(below_mm * 1000) / 1000:.3f}", f"{limit_mm:.3f}"


@dataclass(frozen=True)
class Clearance:
    """The closest active pair of a configuration (no padding applied)."""

    distance: float
    first: str
    second: str
    kind: str


@dataclass(frozen=True)
class _Pair:
    kind: str
    first: str
    second: str
    padded: bool


@dataclass(frozen=True)
class _PairSet:
    """Geometry data whose active pairs are answered together: all pairs through a broadphase,
    or a few objects' pairs (then ``manager`` is None: checking those pairs one by one is
    cheaper than a broadphase over every geometry)."""

    geometry_data: pin.GeometryData
    manager: object | None
    callback: pin.CollisionCallBackDefault | None
    budget_rad: float = 0.0
    """Joint motion its margins are inflated for (``swept``); 0: the checker's own margins."""


def _next_start_level(level: int, start_level: int, levels: int) -> int:
    """The level the next window starts at: one larger after a window free at the level tried
    first, the free one after a smaller one; after a row where every window missed, none (that
    row's next row is checked on its own), and after that the smallest."""
    if level > 0:
        return min(level + 1, levels) if level == start_level else level
    return 0 if start_level > 0 else 1


class _NearPairs:
    """Pairs taken out of a path's windows (``levels``) to be checked on their own (``pair_set``)
    at every row the windows cover; ``restore`` puts everything back as it was."""

    def __init__(self, data: pin.GeometryData, levels: list[_PairSet]) -> None:
        self.pair_set = _PairSet(data, None, None)
        self.levels = levels
        self.pairs: list[int] = []

    def add(self, pair: int) -> None:
        self.pairs.append(pair)
        self.pair_set.geometry_data.activateCollisionPair(pair)
        for level in self.levels:
            level.geometry_data.deactivateCollisionPair(pair)

    def restore(self) -> None:
        for pair in self.pairs:
            self.pair_set.geometry_data.deactivateCollisionPair(pair)
            for level in self.levels:
                level.geometry_data.activateCollisionPair(pair)
        self.pairs.clear()


@dataclass(frozen=True)
class _Sweep:
    """The early-out of one path: inflated checkers for the joints that move in it, smallest
    budget first, and how far each of those joints travels along the path (``swept``)."""

    levels: list[_PairSet]
    travel: swept.PathTravel


class CollisionChecker:
    """Robot + attachments + world objects, compiled into one pinocchio geometry model.

    World objects can be moved in place (``move``); any change of the set of objects,
    attachments, rules or padding needs a new checker (the planning scene does that).
    Not thread-safe: one checker, one caller at a time.
    """

    def __init__(
        self,
        robot: RobotModel,
        world: Iterable[WorldObject],
        attachments: Iterable[Attachment],
        allowed: Callable[[str, str], bool],
        padding: float,
        broadphase: str = "SSaPCollisionManager",
    ):
        if not (np.isfinite(padding) and padding >= 0):
            raise ValueError(f"padding must be a non-negative number of metres, got {padding!r}")
        self.robot = robot
        self.padding = float(padding)
        model = robot.model
        self.data = model.createData()
        gm = pin.GeometryModel()
        owners: list[str] = []  # link name, "attached:<name>" or world object name
        joints: list[int] = []
        for go, link in zip(robot.collision_model.geometryObjects, robot.geometry_links):
            gm.addGeometryObject(go)
            owners.append(link)
            joints.append(go.parentJoint)
        robot_geoms = len(owners)

        attached_index: dict[str, Attachment] = {}
        for att in attachments:
            fid = robot.frame_id(att.link)
            frame = model.frames[fid]
            placement = frame.placement * as_se3(att.matrix)
            gm.addGeometryObject(pin.GeometryObject(f"attached:{att.name}", frame.parentJoint, fid, placement,
                                                    make_geometry(att.shape)))
            owners.append(f"attached:{att.name}")
            joints.append(frame.parentJoint)
            attached_index[f"attached:{att.name}"] = att
        movable = len(owners)

        self._world_ids: dict[str, int] = {}
        for obj in world:
            self._world_ids[obj.name] = len(owners)
            gm.addGeometryObject(pin.GeometryObject(f"world:{obj.name}", 0, 0, as_se3(obj.matrix),
                                                    make_geometry(obj.shape)))
            owners.append(obj.name)
            joints.append(0)

        adjacent = robot.adjacent_link_pairs()
        disabled = robot.srdf.disabled_keys()
        self._pairs: list[_Pair] = []

        def add(i: int, j: int, pair: _Pair) -> None:
            gm.addCollisionPair(pin.CollisionPair(i, j))
            self._pairs.append(pair)

        for i in range(robot_geoms):
            for j in range(i + 1, robot_geoms):
                a, b = owners[i], owners[j]
                key = frozenset((a, b))
                if a == b or joints[i] == joints[j] or key in adjacent or key in disabled:
                    continue
                add(i, j, _Pair("self", a, b, False))
        for i in range(robot_geoms, movable):
            att = attached_index[owners[i]]
            for j in range(robot_geoms):
                link = owners[j]
                if link == att.link or link in att.touch_links:
                    continue
                add(j, i, _Pair("self", link, owners[i], False))
        for k in range(movable, len(owners)):
            owner = owners[k]
            for i in range(movable):
                name = owners[i]
                rule_name = name.removeprefix("attached:")
                if allowed(owner, rule_name):
                    continue
                add(i, k, _Pair("world", name, owner, True))

        self.geometry_model = gm
        self._margins_m = np.array([self.padding if pair.padded else 0.0 for pair in self._pairs])
        """Each pair's security margin: the padding for world pairs, 0 for the others."""
        self.geometry_data = self._pair_data(None)
        self._callback = pin.CollisionCallBackDefault(gm, self.geometry_data, True)
        try:
            manager_class = getattr(pin, f"BroadPhaseManager_{broadphase}")
        except AttributeError:
            raise ValueError(f"unknown coal broadphase {broadphase!r} (e.g. SSaPCollisionManager, "
                             "DynamicAABBTreeCollisionManager)") from None
        self._manager_class = manager_class
        self._manager = manager_class(model, gm, self.geometry_data)
        self._coefficients = None
        if swept.supported(model):
            radii = swept.motion_radii(model, gm)
            self._coefficients = swept.pair_coefficients(radii, [(p.first, p.second) for p in gm.collisionPairs])
        self._all_pairs = _PairSet(self.geometry_data, self._manager, self._callback)
        self._swept_levels: dict[tuple[tuple[int, ...], frozenset[str] | None], list[_PairSet]] = {}
        self._object_pairs: dict[frozenset[str], tuple[list[int], _PairSet]] = {}
        self._near_data = self._pair_data([])  # the pairs a path check sets aside (``_NearPairs``), none between checks

    def pairs(self) -> list[tuple[str, str, str]]:
        """``(kind, first, second)`` of every checked pair of geometries."""
        return [(p.kind, p.first, p.second) for p in self._pairs]

    @property
    def world_names(self) -> frozenset[str]:
        return frozenset(self._world_ids)

    def move(self, name: str, pose: NDArray[np.float64]) -> None:
        gid = self._world_ids[name]
        self.geometry_model.geometryObjects[gid].placement = as_se3(pose)

    def check(self, q: NDArray[np.float64]) -> CollisionResult | None:
        """The first colliding pair at full configuration ``q``, or None."""
        if not pin.computeCollisions(self.robot.model, self.data, self._manager, self._callback, q):
            return None
        return self._result(self._callback.collisionPairIndex)

    def check_many(self, Q: NDArray[np.float64], times: NDArray[np.float64] | None, stop_at_first: bool,
                   early_out: bool = True) -> list[CollisionResult]:
        """First colliding pair of each colliding row of ``Q`` (N, nq); stops early if asked.

        The answer is the one ``check`` gives for each row. With ``early_out`` (the default),
        runs of rows that a proven bound shows collision-free are settled by one check at
        their first row (``swept``); every other row is checked on its own."""
        sweep = self._sweep_for(Q, None) if early_out else None
        return self._check_many(self._all_pairs, sweep, Q, stop_at_first, lambda step: self._last_hit(step, times))

    def first_hit_of_objects(self, objects: Iterable[str], Q: NDArray[np.float64], times: NDArray[np.float64] | None) -> CollisionResult | None:
        """``check_many(Q, times, stop_at_first=True)`` for a path whose every row was found free
        with the world objects of ``objects`` placed elsewhere and everything else as now: only
        the pairs of ``objects`` can have changed, so only they are checked, and the first row
        where one collides is checked again in full (the answer ``check`` gives that row).
        Wrong when that premise does not hold."""
        names = frozenset(objects) & frozenset(self._world_ids)
        if names not in self._object_pairs:
            active = [k for k, p in enumerate(self._pairs) if p.kind == "world" and p.second in names]
            self._object_pairs[names] = (active, _PairSet(self._pair_data(active), None, None))
        active, pairs = self._object_pairs[names]
        if not active:
            return None
        hits = self._check_many(pairs, self._sweep_for(Q, names), Q, True, lambda step: self._check_row(Q, step, times))
        return hits[0] if hits else None

    def _check_row(self, Q: NDArray[np.float64], step: int, times: NDArray[np.float64] | None) -> CollisionResult | None:
        """Row ``step`` checked against every pair, as ``check_many`` reports it."""
        if not self._collides(self._all_pairs, Q[step]):
            return None
        return self._last_hit(step, times)

    def _last_hit(self, step: int, times: NDArray[np.float64] | None) -> CollisionResult:
        """The pair the last check of every pair stopped at, as row ``step``'s answer."""
        hit = self._result(self._callback.collisionPairIndex)
        t = None if times is None else float(times[step])
        return CollisionResult(hit.kind, hit.first, hit.second, hit.distance, hit.padding, step, t)

    def _collides(self, pairs: _PairSet, q: NDArray[np.float64]) -> bool:
        if pairs.manager is None:
            hit: bool = pin.computeCollisions(self.robot.model, self.data, self.geometry_model, pairs.geometry_data, q, True)
            return hit
        hit = pin.computeCollisions(self.robot.model, self.data, pairs.manager, pairs.callback, q)
        return hit

    def _check_many(self, pairs: _PairSet, sweep: _Sweep | None, Q: NDArray[np.float64], stop_at_first: bool,
                    hit_at: Callable[[int], CollisionResult | None]) -> list[CollisionResult]:
        """Rows of ``Q`` where a pair of ``pairs`` collides, as ``hit_at(step)`` reports them
        (called right after that row's check of ``pairs``), settling runs of rows at once with
        ``sweep``.

        A pair that keeps even the smallest window from being free at a free row (a finger just
        above the table) is set aside for the rest of the path: later windows are proven without
        it, and it is checked on its own at every row they cover."""
        out: list[CollisionResult] = []
        levels = [] if sweep is None else sweep.levels
        near = _NearPairs(self._near_data, levels)
        step, start_level, free_until = 0, len(levels), 0
        try:
            while step < Q.shape[0]:
                missed = False  # every window was tried at this row and none is free
                if sweep is not None and step >= free_until:
                    tried = start_level > 0
                    level, free_until = self._free_window(sweep, step, start_level, Q[step])
                    start_level = _next_start_level(level, start_level, len(levels))
                    missed = tried and level == 0
                if step < free_until and not near.pairs:
                    step = free_until
                    continue
                check = near.pair_set if step < free_until else pairs
                if self._collides(check, Q[step]) and (check is pairs or self._collides(pairs, Q[step])):
                    hit = hit_at(step)
                    if hit is not None:
                        out.append(hit)
                        if stop_at_first:
                            break
                elif missed and levels[0].callback is not None:
                    near.add(levels[0].callback.collisionPairIndex)  # the pair the smallest window stopped at
                step += 1
        finally:
            near.restore()
        return out

    def _free_window(self, sweep: _Sweep, step: int, start_level: int, q: NDArray[np.float64]) -> tuple[int, int]:
        """The level (1-based) whose window from row ``step`` one inflated check at ``q`` proves
        free, trying ``start_level`` first and smaller ones after it, and where that window ends;
        ``(0, step)`` when none is (or ``start_level`` is 0)."""
        if start_level == 0:
            return 0, step
        ends = swept.window_ends(sweep.travel, step)
        level = start_level
        while level > 0:
            while level > 1 and ends[level - 2] == ends[level - 1]:
                level -= 1  # a smaller budget covers the same rows: less inflation
            if not self._collides(sweep.levels[level - 1], q):
                return level, int(ends[level - 1])
            level -= 1
        return 0, step

    @staticmethod
    def _moving_columns(Q: NDArray[np.float64]) -> NDArray[np.intp]:
        return np.flatnonzero((Q != Q[0]).any(axis=0))

    def _pair_data(self, active: list[int] | None, budget_rad: float | None = None,
                   per_rad: NDArray[np.float64] | None = None) -> pin.GeometryData:
        """Geometry data with this checker's margins, inflated for a joint budget when one is
        given (see ``swept``), and only the ``active`` pairs switched on (None: all)."""
        data = pin.GeometryData(self.geometry_model)
        margins = self._margins_m
        if budget_rad is not None and per_rad is not None:
            margins = margins + budget_rad * per_rad + SWEPT_SLACK_M
        for request, margin in zip(data.collisionRequests, margins.tolist()):
            request.security_margin = margin
            request.enable_contact = False
        if active is not None:
            data.deactivateAllCollisionPairs()
            for k in active:
                data.activateCollisionPair(k)
        return data

    def _sweep_for(self, Q: NDArray[np.float64], objects: frozenset[str] | None) -> _Sweep | None:
        """The early-out of path ``Q`` over every pair or ``objects``' pairs; None for a single
        row or an unsupported model."""
        if Q.shape[0] < 2:
            return None
        columns = self._moving_columns(Q)
        levels = self._levels_for(tuple(columns.tolist()), objects)
        if not levels:
            return None
        return _Sweep(levels, swept.path_travel(Q[:, columns], np.array(SWEPT_LEVELS_RAD)))

    def _levels_for(self, columns: tuple[int, ...], objects: frozenset[str] | None) -> list[_PairSet]:
        """Inflated checkers for the joints of configuration ``columns`` (compiled once per set of
        joints), of every pair or of ``objects``' pairs, one per ``SWEPT_LEVELS_RAD``; none for
        an unsupported model."""
        if self._coefficients is None:
            return []
        model = self.robot.model
        key = (columns, objects)
        if key not in self._swept_levels:
            joint_of_column = {int(model.idx_qs[j]): j for j in range(1, model.njoints)}
            joints = [joint_of_column[c] for c in columns]
            per_rad = self._coefficients[:, joints].sum(axis=1)
            active = None if objects is None else self._object_pairs[objects][0]
            levels = []
            for budget in SWEPT_LEVELS_RAD:
                data = self._pair_data(active, budget, per_rad)
                if objects is None:
                    levels.append(_PairSet(data, self._manager_class(model, self.geometry_model, data),
                                           pin.CollisionCallBackDefault(self.geometry_model, data, True), budget))
                else:
                    levels.append(_PairSet(data, None, None, budget))
            self._swept_levels[key] = levels
        return self._swept_levels[key]

    def _result(self, pair_index: int) -> CollisionResult:
        pair = self._pairs[pair_index]
        distance = pin.computeDistance(self.geometry_model, self.geometry_data, pair_index).min_distance
        return CollisionResult(pair.kind, pair.first, pair.second, float(distance),
                               self.padding if pair.padded else 0.0)

    def clearance(self, q: NDArray[np.float64], kind: str | None = None) -> Clearance | None:
        """Closest checked pair (distance without padding), optionally only ``self`` or
        ``world`` pairs; None if no such pair is checked."""
        if kind not in (None, "self", "world"):
            raise ValueError(f"kind must be None, 'self' or 'world', got {kind!r}")
        wanted = [k for k, p in enumerate(self._pairs) if kind is None or p.kind == kind]
        if not wanted:
            return None
        pin.computeDistances(self.robot.model, self.data, self.geometry_model, self.geometry_data, q)
        results = self.geometry_data.distanceResults
        k = min(wanted, key=lambda i: results[i].min_distance)
        pair = self._pairs[k]
        return Clearance(float(results[k].min_distance), pair.first, pair.second, pair.kind)
