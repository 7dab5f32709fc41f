"""Proven motion bounds for skipping collision checks of path points: pure functions.

A path check must answer, for every point, exactly what a check of that point alone answers.
It may skip the narrowphase at points where a bound *proves* that nothing collides:

- ``motion_radii``: for every geometry g and revolute joint j, ``R[g, j]`` bounds the distance
  from joint j's origin to any point of g, whatever the joints between them are. Turning joint
  j by ``d`` radians (all other joints fixed) moves every point of g by at most ``R[g, j] * |d|``
  (a chord is never longer than its arc). Going from configuration q to q' one joint at a time,
  every point of g moves by at most ``sum_j R[g, j] * |q'_j - q_j|``.
- ``pair_coefficients``: the same for the *distance* of a pair (a, b). A joint that moves both
  (a common ancestor) moves them rigidly together and leaves their distance unchanged; a joint
  that moves only one of them changes the distance by at most that one's displacement. So
  ``|d(q') - d(q)| <= sum_j C[p, j] * |q'_j - q_j|``.

If a pair's distance at q is at least ``margin + L * sum_j C[p, j] + slack`` (coal reports "no
collision" for a security margin inflated by that much), then at every q' with
``|q'_j - q_j| <= L`` for all joints the distance is above ``margin``: no collision there.
``window_ends`` finds, for each L, how far along a path that holds, from each joint's travel
along the path (``path_travel``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
import pinocchio as pin

REVOLUTE = frozenset({"JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned"})


def supported(model: pin.Model) -> bool:
    """The bounds hold for chains of single-angle revolute joints only."""
    return all(model.joints[j].shortname() in REVOLUTE for j in range(1, model.njoints))


def _local_radius(geometry: pin.GeometryObject) -> float:
    """Largest distance from the parent joint's origin to any point of the geometry: the
    farthest corner of its local bounding box, placed in the joint frame."""
    shape = geometry.geometry
    shape.computeLocalAABB()
    box = shape.aabb_local
    lo, hi = np.asarray(box.min_), np.asarray(box.max_)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    placement = geometry.placement
    placed = corners @ np.asarray(placement.rotation).T + np.asarray(placement.translation)
    return float(np.linalg.norm(placed, axis=1).max())


def motion_radii(model: pin.Model, geometry_model: pin.GeometryModel) -> NDArray[np.float64]:
    """``R[g, j]`` (metres per radian, shape (ngeoms, njoints)); zero where joint j does not
    move geometry g. Column 0 (the universe) is always zero."""
    radii = np.zeros((len(geometry_model.geometryObjects), model.njoints))
    link_length = [float(np.linalg.norm(model.jointPlacements[j].translation)) for j in range(model.njoints)]
    for g, geometry in enumerate(geometry_model.geometryObjects):
        parent = int(geometry.parentJoint)
        if parent == 0:
            continue
        chain = [int(j) for j in model.supports[parent] if j != 0]  # root ... parent
        reach = _local_radius(geometry)
        for j in reversed(chain):  # parent first: its radius is the geometry's own reach
            radii[g, j] = reach
            reach += link_length[j]  # from joint j's parent joint origin to j's origin
    return radii


def pair_coefficients(radii: NDArray[np.float64], pairs: list[tuple[int, int]]) -> NDArray[np.float64]:
    """``C[p, j]``: how much pair p's distance can change per radian of joint j."""
    out = np.zeros((len(pairs), radii.shape[1]))
    for p, (a, b) in enumerate(pairs):
        moves_a, moves_b = radii[a] > 0, radii[b] > 0
        out[p] = np.where(moves_a & ~moves_b, radii[a], 0.0) + np.where(moves_b & ~moves_a, radii[b], 0.0)
    return out


@dataclass(frozen=True)
class PathTravel:
    """How far each moving joint has travelled along a path, summed step by step, ready to find
    where budgets run out. Joint j's travel from row s to row t bounds its displacement,
    ``|q_j(t) - q_j(s)| <= T_j(t) - T_j(s)`` (equal while the joint moves one way).

    The columns' travels lie one after the other in one non-decreasing array (column j lifted
    above the travel plus budget of every column before it), so that one ``searchsorted`` finds
    where every column leaves every budget."""

    stacked: NDArray[np.float64]
    """Column j's travel at row i at index ``j * rows + i``, plus column j's lift."""
    rows: int
    levels: int
    column_starts: NDArray[np.intp]
    """Per (column, level), flattened column-major: the index of the column's row 0 in ``stacked``."""
    budgets_rad: NDArray[np.float64]
    """Per (column, level), as ``column_starts``: the level's budget."""


def path_travel(Q_moving: NDArray[np.float64], levels_rad: NDArray[np.float64]) -> PathTravel:
    """The travel of every column of ``Q_moving`` (N, k) from row 0, for the joint budgets
    ``levels_rad`` (non-negative)."""
    rows, columns = Q_moving.shape
    travel = np.zeros((columns, rows))  # a row per column: cumsum runs along contiguous memory
    np.cumsum(np.abs(np.diff(Q_moving.T, axis=1)), axis=1, out=travel[:, 1:])
    lift = float(travel[:, -1].max(initial=0.0)) + float(levels_rad.max(initial=0.0)) + 1.0
    travel += (lift * np.arange(columns))[:, None]
    stacked = travel.ravel()
    column_starts = np.repeat(rows * np.arange(columns), len(levels_rad))
    return PathTravel(stacked, rows, len(levels_rad), column_starts, np.tile(levels_rad, columns))


def window_ends(travel: PathTravel, start: int) -> NDArray[np.intp]:
    """For each level L, the first index after ``start`` where some joint has travelled more
    than L since ``start`` (``travel.rows`` if none has): up to there, no joint is more than L
    from its value at ``start``. Rounding in the sums (below 1e-12 rad) is far inside
    ``SWEPT_SLACK_M``."""
    limits = travel.stacked[travel.column_starts + start]
    limits += travel.budgets_rad
    ends = travel.stacked.searchsorted(limits, side="right")
    ends -= travel.column_starts  # each column's row index
    first: NDArray[np.intp] = np.minimum.reduce(ends.reshape(-1, travel.levels), axis=0, initial=travel.rows)
    return first
