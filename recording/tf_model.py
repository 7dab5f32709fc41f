"""``/tf`` computed from joint states by the recording worker, from a few numbers per link.

The run knows the robot (a pinocchio model); the worker must not pay for loading it. Each link's
pose relative to its parent link is ``A * motion(value) * B``, with ``A`` and ``B`` fixed
placements and ``motion`` the one joint between the two links (a rotation about an axis, or a
translation along one). Written out, each of the seven numbers ROS sends (x, y, z, qx, qy, qz,
qw) is a fixed linear combination of ``1, cos(v), sin(v), cos(v/2), sin(v/2), v``:

- revolute: the quaternion is ``qA * (axis sin(v/2), cos(v/2)) * qB`` (linear in ``cos(v/2)``
  and ``sin(v/2)``), the translation ``tA + RA (Rodrigues(v) tB)`` (linear in ``cos(v)``,
  ``sin(v)``);
- prismatic: the translation is ``tA + RA (axis v + tB)``, the quaternion ``qA * qB``;
- fixed (a link fixed to its parent): all constant.

So the run sends, once per robot, a ``TfModel``: per link its frame names, the 6 x 7
coefficients and where its joint's value comes from (the joint state names that drive it, with a
multiplier and an offset, as ``RobotModel.driven_by`` says); the worker evaluates it for each
recorded joint state and writes the CDR of the ``TFMessage`` into a prepared buffer
(``TfTemplate``). This module imports numpy only (``recording.scene_view`` builds the
model from pinocchio's).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .cdr import ENCAPSULATION, add_string, align

TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
TF_TYPE = "tf2_msgs/msg/TFMessage"
FEATURES = 6
"""1, cos(v), sin(v), cos(v/2), sin(v/2), v: what each of a link's seven numbers is linear in."""


@dataclass(frozen=True)
class LinkDriver:
    """``value = multiplier * position[joint] + offset``: a joint state entry that moves a link's joint."""

    joint: str
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class LinkTf:
    """One link relative to its parent link: ``coefficients`` (6 x 7, see ``FEATURES``) of its
    x, y, z, qx, qy, qz, qw; its joint's value from ``drivers`` (the last one a joint state
    names wins), ``neutral`` when it names none."""

    parent: str
    child: str
    coefficients: tuple[tuple[float, ...], ...]
    drivers: tuple[LinkDriver, ...] = ()
    neutral: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return {"parent": self.parent, "child": self.child, "coefficients": [list(row) for row in self.coefficients],
                "drivers": [[d.joint, d.multiplier, d.offset] for d in self.drivers], "neutral": self.neutral}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "LinkTf":
        coefficients = tuple(tuple(float(v) for v in row) for row in data["coefficients"])
        if len(coefficients) != FEATURES or any(len(row) != 7 for row in coefficients):
            raise ValueError(f"link '{data.get('child')}': coefficients must be {FEATURES} x 7")
        drivers = tuple(LinkDriver(str(j), float(m), float(o)) for j, m, o in data["drivers"])
        return cls(str(data["parent"]), str(data["child"]), coefficients, drivers, float(data["neutral"]))


@dataclass(frozen=True)
class TfModel:
    """Every link of a robot for ``/tf`` (``moving``: behind a joint) and ``/tf_static`` (``fixed``)."""

    moving: tuple[LinkTf, ...]
    fixed: tuple[LinkTf, ...]

    def to_json(self) -> dict[str, Any]:
        return {"moving": [link.to_json() for link in self.moving], "fixed": [link.to_json() for link in self.fixed]}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "TfModel":
        return cls(tuple(LinkTf.from_json(d) for d in data["moving"]), tuple(LinkTf.from_json(d) for d in data["fixed"]))


# -- the coefficients (the run's side) ---------------------------------------------------------
def _quat_left(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """The 4 x 4 matrix of ``p -> q * p`` (quaternions as x, y, z, w)."""
    x, y, z, w = q
    return np.array([[w, -z, y, x], [z, w, -x, y], [-y, x, w, z], [-x, -y, -z, w]])


def _quat_right(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """The 4 x 4 matrix of ``p -> p * q`` (quaternions as x, y, z, w)."""
    x, y, z, w = q
    return np.array([[w, z, -y, x], [-z, w, x, y], [y, -x, w, z], [-x, -y, -z, w]])


def _quat_of(rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    """A unit quaternion (x, y, z, w) of a rotation matrix."""
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
        q[i], q[j], q[k] = 0.25 * s, (m[j, i] + m[i, j]) / s, (m[k, i] + m[i, k]) / s
    quaternion = np.array(q)
    result: NDArray[np.float64] = quaternion / np.linalg.norm(quaternion)
    return result


def link_coefficients(before: tuple[NDArray[np.float64], NDArray[np.float64]], kind: str, axis: NDArray[np.float64] | None,
                      after: tuple[NDArray[np.float64], NDArray[np.float64]]) -> NDArray[np.float64]:
    """The 6 x 7 coefficients of ``before * motion(v) * after`` (each a rotation matrix and a
    translation); ``kind``: ``"revolute"``, ``"prismatic"`` or ``"fixed"``; ``axis``: a unit vector."""
    ra, ta = before
    rb, tb = after
    qa, qb = _quat_of(ra), _quat_of(rb)
    out = np.zeros((FEATURES, 7))
    if kind == "revolute":
        a = np.asarray(axis, dtype=float)
        along = a * float(a @ tb)
        out[0, :3] = ta + ra @ along
        out[1, :3] = ra @ (tb - along)
        out[2, :3] = ra @ np.cross(a, tb)
        both = _quat_left(qa) @ _quat_right(qb)
        out[3, 3:] = both @ np.array([0.0, 0.0, 0.0, 1.0])
        out[4, 3:] = both @ np.append(a, 0.0)
        return out
    out[0, 3:] = _quat_left(qa) @ qb
    out[0, :3] = ta + ra @ tb
    if kind == "prismatic":
        out[5, :3] = ra @ np.asarray(axis, dtype=float)
    elif kind != "fixed":
        raise ValueError(f"unknown joint kind '{kind}'")
    return out


# -- evaluation (the worker's side) ------------------------------------------------------------
def link_values(coefficients: NDArray[np.float64], values: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n_states, n_links, 7) x y z qx qy qz qw of every link, from its coefficients
    (n_links, 6, 7) and its joint's value in each state (n_states, n_links)."""
    half = 0.5 * values
    features = np.stack([np.ones_like(values), np.cos(values), np.sin(values), np.cos(half), np.sin(half), values], axis=-1)
    result: NDArray[np.float64] = np.einsum("nlf,lfo->nlo", features, coefficients)
    return result


@dataclass(frozen=True)
class _ValueMap:
    """For one list of joint state names: each link's joint value = multiplier * position[row] + offset."""

    rows: NDArray[np.float64]
    multiplier: NDArray[np.float64]
    offset: NDArray[np.float64]

    @classmethod
    def of(cls, links: tuple[LinkTf, ...], names: tuple[str, ...]) -> "_ValueMap":
        row_of = {name: row for row, name in enumerate(names)}
        rows, multiplier, offset = [], [], []
        for link in links:
            driver = max((d for d in link.drivers if d.joint in row_of), key=lambda d: row_of[d.joint], default=None)
            if driver is None:  # not in this joint state: the joint stays where the model's neutral has it
                rows.append(len(names))
                multiplier.append(0.0)
                offset.append(link.neutral)
            else:
                rows.append(row_of[driver.joint])
                multiplier.append(driver.multiplier)
                offset.append(driver.offset)
        return cls(np.array(rows, dtype=int), np.array(multiplier), np.array(offset))

    def values(self, positions: NDArray[np.float64]) -> NDArray[np.float64]:
        """(n_states, n_links) joint values of (n_states, n_names) positions."""
        padded = np.concatenate([positions, np.zeros((len(positions), 1))], axis=1)  # the row no name drives
        result: NDArray[np.float64] = self.multiplier * padded[:, self.rows] + self.offset
        return result


_STAMP_DTYPE = np.dtype([("sec", "<i4"), ("nanosec", "<u4")])


class TfTemplate:
    """The CDR (little endian) of a ``TFMessage`` of fixed frames; only the stamps and each
    entry's seven numbers change (the frame names are written once)."""

    def __init__(self, frames: list[tuple[str, str]]) -> None:
        buffer = bytearray(ENCAPSULATION) + struct.pack("<I", len(frames))
        stamps, values = [], []
        for parent, child in frames:
            stamps.append(len(buffer))
            buffer += bytes(8)
            add_string(buffer, parent)
            add_string(buffer, child)
            align(buffer, 8)
            values.append(len(buffer))
            buffer += bytes(56)
        self.buffer = buffer
        self.stamp_at = stamps
        self.values_at = values
        self._stamp_index = (np.array(stamps, dtype=int)[:, None] + np.arange(8)).ravel()
        self._values_index = (np.array(values, dtype=int)[:, None] + np.arange(56)).ravel()

    def encode(self, values: NDArray[np.float64], stamps_ns: list[int]) -> list[bytes]:
        """One message per stamp: every entry stamped alike, ``values`` (n_states, n, 7) in order."""
        out = np.tile(np.frombuffer(self.buffer, dtype=np.uint8), (len(stamps_ns), 1))
        stamps = np.array([divmod(ns, 1_000_000_000) for ns in stamps_ns], dtype=_STAMP_DTYPE)
        out[:, self._stamp_index] = np.tile(stamps.view(np.uint8).reshape(-1, 8), len(self.stamp_at))
        out[:, self._values_index] = np.ascontiguousarray(values, dtype="<f8").reshape(len(stamps_ns), -1).view(np.uint8)
        return [row.tobytes() for row in out]


class TfWriter:
    """The worker's ``/tf`` and ``/tf_static``: evaluates a ``TfModel`` for joint states, many at once."""

    def __init__(self, model: TfModel) -> None:
        self.model = model
        self._coefficients = np.array([link.coefficients for link in model.moving], dtype=float).reshape(-1, FEATURES, 7)
        self._moving = TfTemplate([(link.parent, link.child) for link in model.moving])
        self._fixed = TfTemplate([(link.parent, link.child) for link in model.fixed])
        self._maps: dict[tuple[str, ...], _ValueMap] = {}

    def tf(self, names: tuple[str, ...], positions: list[Any], stamps_ns: list[int]) -> list[bytes]:
        """The ``/tf`` message of each joint state (all with ``names``; ``positions``: one row
        per state), stamped like it."""
        value_map = self._maps.get(names)
        if value_map is None:
            value_map = self._maps[names] = _ValueMap.of(self.model.moving, names)
        values = link_values(self._coefficients, value_map.values(np.array(positions, dtype=float).reshape(len(stamps_ns), len(names))))
        return self._moving.encode(values, stamps_ns)

    def tf_static(self, stamp_ns: int) -> bytes:
        """The ``/tf_static`` message: the links fixed to their parent."""
        values = np.array([link.coefficients[0] for link in self.model.fixed], dtype=float).reshape(1, -1, 7)
        return self._fixed.encode(values, [stamp_ns])[0]
