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
``window_ends`` finds, for each L, how far along a path that holds.
"""
from __future__ import annotations

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


def window_ends(Q_moving: NDArray[np.float64], start: int, levels_rad: NDArray[np.float64]) -> NDArray[np.intp]:
    """For each level L, the first index after ``start`` where some column of ``Q_moving``
    has moved more than L from its value at ``start`` (``len(Q_moving)`` if none has)."""
    deviation = np.abs(Q_moving[start:] - Q_moving[start]).max(axis=1, initial=0.0)
    np.maximum.accumulate(deviation, out=deviation)
    ends: NDArray[np.intp] = start + deviation.searchsorted(levels_rad, side="right")
    return ends
