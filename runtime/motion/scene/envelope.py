"""The Cartesian envelope: where the tool and chosen links may be, how fast the tool may move,
and how far its axis may tilt, checked on every densified point of a motion.

Configured per cell in a YAML file beside joint_limits.yaml (the simulated cell's is
``sim/config/cartesian_limits.yaml``); every key is optional::

    cartesian_limits:
      tcp_frame: tcp                       # the tool centre point: a link or site of the model
      max_tcp_speed_m_s: 1.0               # linear speed of the tcp_frame origin
      max_tcp_angular_speed_rad_s: 4.0     # angular speed of the tcp_frame
      keep_in_boxes:                       # each frame's origin stays inside every box naming it
        table_workspace:
          frames: [tcp, wrist_3_link]
          min_m: [-0.6, -0.25, 0.0]        # world x, y, z
          max_m: [0.6, 0.85, 1.0]
      tool_axis_cone:                      # the frame's axis within max_angle_deg of direction
        frame: tcp
        axis: [0, 0, 1]                    # in the frame
        direction: [0, 0, -1]              # in the world
        max_angle_deg: 90

Speeds are the frame's velocity at a point (the Jacobian times the point's joint velocities);
positions and the axis come from forward kinematics of the point's joint positions, for all the
points of a motion at once (``batch_kinematics.py``; pinocchio point by point for joints it does
not cover). ``narrowed`` applies a behavior's port
overrides, which may only tighten the cell's envelope.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray
import pinocchio as pin
import yaml

from runtime.errors import OptionError
from .model import ConfigurationMap, RobotModel

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class KeepInBox:
    """An axis-aligned box in the world that the origins of ``frames`` stay inside."""

    name: str
    frames: tuple[str, ...]
    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]


@dataclass(frozen=True)
class ToolCone:
    """``axis`` of ``frame`` (in the frame) stays within ``max_angle_deg`` of ``direction`` (world)."""

    frame: str
    axis: tuple[float, float, float]
    direction: tuple[float, float, float]
    max_angle_deg: float


@dataclass(frozen=True)
class CartesianEnvelope:
    tcp_frame: str
    max_tcp_speed_m_s: float = math.inf
    max_tcp_angular_speed_rad_s: float = math.inf
    keep_in_boxes: tuple[KeepInBox, ...] = ()
    tool_cone: ToolCone | None = None

    @property
    def needs_velocities(self) -> bool:
        return math.isfinite(self.max_tcp_speed_m_s) or math.isfinite(self.max_tcp_angular_speed_rad_s)

    @property
    def frames(self) -> tuple[str, ...]:
        """Every frame the envelope reads, each once."""
        names = [self.tcp_frame] + [f for box in self.keep_in_boxes for f in box.frames]
        if self.tool_cone is not None:
            names.append(self.tool_cone.frame)
        return tuple(dict.fromkeys(names))


@dataclass(frozen=True)
class EnvelopeOverrides:
    """A behavior's port values for the envelope; 0 (or no box) keeps the cell's."""

    max_tcp_speed_m_s: float = 0.0
    max_tcp_angular_speed_rad_s: float = 0.0
    tcp_keep_in_box_m: tuple[float, ...] = ()
    """``(xmin, ymin, zmin, xmax, ymax, zmax)`` for the TCP, or empty."""
    tool_axis_max_angle_deg: float = 0.0


DEFAULT_TOOL_AXIS = (0.0, 0.0, 1.0)
DEFAULT_TOOL_DIRECTION = (0.0, 0.0, -1.0)
"""A port's tool-axis cone on a cell without one: the TCP frame's z axis (out of the gripper, by
the ROS tool-frame convention) within the angle of straight down."""


def narrowed(envelope: CartesianEnvelope, overrides: EnvelopeOverrides, source: str = "the cell's envelope") -> CartesianEnvelope:
    """``envelope`` tightened by ``overrides``; OptionError when an override would widen it."""

    def tighter(port: str, value: float, current: float, unit: str) -> float:
        if value <= 0:
            return current
        if value > current:
            raise OptionError(f"{port} {value:g} {unit} is above the limit {current:g} {unit} of {source}: "
                              f"a port may only tighten the Cartesian envelope")
        return value

    speed = tighter("max_tcp_speed", overrides.max_tcp_speed_m_s, envelope.max_tcp_speed_m_s, "m/s")
    angular = tighter("max_tcp_angular_speed", overrides.max_tcp_angular_speed_rad_s,
                      envelope.max_tcp_angular_speed_rad_s, "rad/s")
    boxes = envelope.keep_in_boxes
    if overrides.tcp_keep_in_box_m:
        values = tuple(float(v) for v in overrides.tcp_keep_in_box_m)
        if len(values) != 6 or any(lo >= hi for lo, hi in zip(values[:3], values[3:])):
            raise OptionError(f"tcp_keep_in_box needs 6 values xmin;ymin;zmin;xmax;ymax;zmax with each min below its max, "
                              f"got {';'.join(f'{v:g}' for v in values)}")
        boxes = boxes + (KeepInBox("tcp_keep_in_box", (envelope.tcp_frame,), values[:3], values[3:]),)
    cone = envelope.tool_cone
    if overrides.tool_axis_max_angle_deg > 0:
        current = cone.max_angle_deg if cone is not None else 180.0
        angle = tighter("tool_axis_max_angle", overrides.tool_axis_max_angle_deg, current, "deg")
        cone = (replace(cone, max_angle_deg=angle) if cone is not None
                else ToolCone(envelope.tcp_frame, DEFAULT_TOOL_AXIS, DEFAULT_TOOL_DIRECTION, angle))
    return replace(envelope, max_tcp_speed_m_s=speed, max_tcp_angular_speed_rad_s=angular, keep_in_boxes=boxes, tool_cone=cone)


@dataclass(frozen=True)
class EnvelopeViolation:
    """The first (earliest) point of a path outside the Cartesian envelope."""

    step: int
    time: float | None
    link: str
    quantity: str
    """``workspace``, ``tool axis``, ``linear speed`` or ``angular speed``."""
    value: float
    limit: float
    axis: str = ""
    """For ``workspace``: the world axis (x, y, z); for ``tool axis``: the direction."""
    box: str = ""

    family = "Cartesian limit"

    def __str__(self) -> str:
        when = f"step {self.step}" + (f" (t={self.time:.3f} s)" if self.time is not None else "")
        return f"{when}: {self.what}"

    @property
    def what(self) -> str:
        """The violation without its step: link, quantity, value and limit."""
        if self.quantity == "workspace":
            relation = "below" if self.value < self.limit else "exceeds"
            return (f"link {self.link} {self.axis} {self.value:.4f} m {relation} the limit {self.limit:.4f} m "
                    f"of keep-in box '{self.box}'")
        if self.quantity == "tool axis":
            return f"link {self.link} tool axis {self.value:.4f} deg from {self.axis} exceeds the limit {self.limit:.4f} deg"
        unit = {"linear speed": "m/s", "angular speed": "rad/s"}[self.quantity]
        return f"link {self.link} {self.quantity} {self.value:.4f} {unit} exceeds the limit {self.limit:.4f} {unit}"


def check_envelope(
    envelope: CartesianEnvelope,
    robot: RobotModel,
    layout: ConfigurationMap,
    positions: NDArray[np.float64],
    velocities: NDArray[np.float64] | None = None,
    times: NDArray[np.float64] | None = None,
    tolerance: float = 1e-9,
) -> EnvelopeViolation | None:
    """The earliest point of ``(N, J)`` rows in ``layout``'s columns (``velocities`` of the
    group's joints, the same rows) outside ``envelope``. At one point the keep-in boxes are
    reported before the tool axis, then the linear and the angular speed.

    The frames' poses and the TCP's velocity come for all points at once (``RobotModel.batch_kinematics``);
    the checks then run on all points together."""
    full = np.atleast_2d(layout(np.atleast_2d(positions)))
    if len(full) == 0:
        return None
    frames = envelope.frames
    poses = _frame_states(envelope, robot, layout, full, velocities)
    found: list[tuple[int, int, EnvelopeViolation]] = []  # step, order at one step, violation

    def first(mask: NDArray[np.bool_]) -> int | None:
        hits = np.flatnonzero(mask)
        return int(hits[0]) if len(hits) else None

    order = 0
    for box in envelope.keep_in_boxes:
        inside = poses.positions[:, [frames.index(f) for f in box.frames]]
        if ((inside >= np.asarray(box.min_m) - tolerance) & (inside <= np.asarray(box.max_m) + tolerance)).all():
            order += 6 * len(box.frames)
            continue
        for frame in box.frames:
            xyz = poses.positions[:, frames.index(frame)]
            for k, axis in enumerate(AXES):
                for bound, outside in ((box.min_m[k], xyz[:, k] < box.min_m[k] - tolerance),
                                       (box.max_m[k], xyz[:, k] > box.max_m[k] + tolerance)):
                    step = first(outside)
                    if step is not None:
                        found.append((step, order, EnvelopeViolation(step, None, frame, "workspace", float(xyz[step, k]), bound, axis, box.name)))
                    order += 1
    cone = envelope.tool_cone
    if cone is not None and poses.axes is not None:
        cosines = np.clip(poses.axes @ np.asarray(cone.direction), -1.0, 1.0)
        angles = np.degrees(np.arccos(cosines))
        step = first(angles > cone.max_angle_deg + tolerance)
        if step is not None:
            found.append((step, order, EnvelopeViolation(step, None, cone.frame, "tool axis", float(angles[step]), cone.max_angle_deg,
                                                         _vector_text(cone.direction))))
    if poses.twists is not None:
        for k, (quantity, limit) in enumerate((("linear speed", envelope.max_tcp_speed_m_s),
                                               ("angular speed", envelope.max_tcp_angular_speed_rad_s))):
            speeds = np.linalg.norm(poses.twists[:, 3 * k: 3 * k + 3], axis=1)
            step = first(speeds > limit + tolerance)
            if step is not None:
                found.append((step, order + 1 + k, EnvelopeViolation(step, None, envelope.tcp_frame, quantity, float(speeds[step]), limit)))
    if not found:
        return None
    step, _, violation = min(found, key=lambda c: (c[0], c[1]))
    return replace(violation, time=None if times is None else float(np.asarray(times)[step]))


def _shifted(point: tuple[float, float, float], by: float) -> tuple[float, float, float]:
    return (point[0] + by, point[1] + by, point[2] + by)


def shrunk(envelope: CartesianEnvelope, margin_m: float, margin_deg: float) -> CartesianEnvelope:
    """``envelope`` with every keep-in box ``margin_m`` smaller on each side and the tool cone
    ``margin_deg`` narrower: what a planner keeps its states within, so that a motion timed and
    sampled between two of them stays within ``envelope`` itself."""
    boxes = tuple(replace(box, min_m=_shifted(box.min_m, margin_m), max_m=_shifted(box.max_m, -margin_m))
                  for box in envelope.keep_in_boxes)
    cone = envelope.tool_cone
    if cone is not None:
        cone = replace(cone, max_angle_deg=max(0.0, cone.max_angle_deg - margin_deg))
    return replace(envelope, keep_in_boxes=boxes, tool_cone=cone)


class PoseCheck:
    """Whether one configuration keeps every keep-in box's frames inside it and the tool inside its
    cone (speeds are not looked at): the planner's per-state check. Built once per plan, it keeps
    its own pinocchio data and frame ids, so a call is one forward-kinematics pass."""

    def __init__(self, envelope: CartesianEnvelope, robot: RobotModel, layout: ConfigurationMap) -> None:
        self.model = robot.model
        self.data = robot.model.createData()
        self.layout = layout
        self.boxes = [(np.asarray(box.min_m), np.asarray(box.max_m), [robot.frame_id(f) for f in box.frames])
                      for box in envelope.keep_in_boxes]
        cone = envelope.tool_cone
        self.cone = None if cone is None else (
            robot.frame_id(cone.frame), np.asarray(cone.axis), np.asarray(cone.direction), math.cos(math.radians(cone.max_angle_deg)))

    def __call__(self, q: NDArray[np.float64]) -> bool:
        full = self.layout(np.atleast_2d(q))[0]
        pin.forwardKinematics(self.model, self.data, full)
        for low, high, frame_ids in self.boxes:
            for frame_id in frame_ids:
                xyz = pin.updateFramePlacement(self.model, self.data, frame_id).translation
                if (xyz < low).any() or (xyz > high).any():
                    return False
        if self.cone is not None:
            frame_id, axis, direction, cos_max = self.cone
            rotation = pin.updateFramePlacement(self.model, self.data, frame_id).rotation
            if float(direction @ (rotation @ axis)) < cos_max:
                return False
        return True


def tool_speed_ratio(envelope: CartesianEnvelope, robot: RobotModel, layout: ConfigurationMap,
                     positions: NDArray[np.float64], velocities: NDArray[np.float64]) -> float:
    """The largest share of its limit the TCP's linear or angular speed reaches over ``(N, J)``
    rows of ``layout``'s columns with their joint ``velocities``: above 1, slowing the motion down
    evenly by that factor brings it within both speed limits (speeds scale with the time scale)."""
    full = np.atleast_2d(layout(np.atleast_2d(positions)))
    if len(full) == 0 or not envelope.needs_velocities:
        return 0.0
    twists = _frame_states(envelope, robot, layout, full, np.atleast_2d(velocities)).twists
    if twists is None:
        return 0.0
    linear = float(np.max(np.linalg.norm(twists[:, :3], axis=1))) / envelope.max_tcp_speed_m_s
    angular = float(np.max(np.linalg.norm(twists[:, 3:], axis=1))) / envelope.max_tcp_angular_speed_rad_s
    return max(linear, angular)


@dataclass(frozen=True)
class _FrameStates:
    positions: NDArray[np.float64]
    """(N, F, 3): the origin of each of ``envelope.frames`` at each point."""
    axes: NDArray[np.float64] | None
    """(N, 3): the tool cone's axis in the world, when there is a cone."""
    twists: NDArray[np.float64] | None
    """(N, 6): the TCP frame's linear then angular velocity (world axes), when speeds are limited."""


def _frame_states(envelope: CartesianEnvelope, robot: RobotModel, layout: ConfigurationMap, full: NDArray[np.float64],
                  velocities: NDArray[np.float64] | None) -> _FrameStates:
    model = robot.model
    frames = envelope.frames
    cone = envelope.tool_cone
    use_velocities = velocities is not None and envelope.needs_velocities
    v_columns = [int(model.idx_vs[model.getJointId(j)]) for j in layout.group.joints]
    v_full = None
    if use_velocities:
        v_full = np.zeros((len(full), model.nv))
        assert velocities is not None  # use_velocities says so
        v_full[:, v_columns] = np.atleast_2d(velocities)[:, : len(v_columns)]
    kinematics = robot.batch_kinematics(frames)
    if not kinematics.supported:
        return _frame_states_per_point(envelope, robot, full, v_full)
    states = kinematics.states(full, v_full, frames.index(envelope.tcp_frame))
    axes = None if cone is None else states.axis(frames.index(cone.frame), np.asarray(cone.axis))
    return _FrameStates(states.positions, axes, states.twist)


def _frame_states_per_point(envelope: CartesianEnvelope, robot: RobotModel, full: NDArray[np.float64],
                            v_full: NDArray[np.float64] | None) -> _FrameStates:
    """``_frame_states`` through pinocchio one point at a time: for chains with joints
    ``BatchKinematics`` does not cover."""
    model = robot.model
    data = model.createData()
    frame_ids = [robot.frame_id(name) for name in envelope.frames]
    count = len(full)
    positions = np.empty((count, len(frame_ids), 3))
    cone = envelope.tool_cone
    rotations = np.empty((count, 3, 3)) if cone is not None else None
    cone_id = robot.frame_id(cone.frame) if cone is not None else 0
    twists = np.empty((count, 6)) if v_full is not None else None
    tcp_id = robot.frame_id(envelope.tcp_frame)
    world_aligned = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for i, q in enumerate(full):
        if v_full is not None:
            pin.forwardKinematics(model, data, q, v_full[i])
        else:
            pin.forwardKinematics(model, data, q)
        for k, fid in enumerate(frame_ids):
            positions[i, k] = pin.updateFramePlacement(model, data, fid).translation
        if rotations is not None:
            rotations[i] = pin.updateFramePlacement(model, data, cone_id).rotation
        if twists is not None:
            twists[i] = pin.getFrameVelocity(model, data, tcp_id, world_aligned).vector
    axes = None if rotations is None or cone is None else rotations @ np.asarray(cone.axis)  # both or neither
    return _FrameStates(positions, axes, twists)


def _vector_text(v: Sequence[float]) -> str:
    return "(" + ", ".join(f"{x:g}" for x in v) + ")"


# -- the YAML file ------------------------------------------------------------------------------
def load_envelope(path: str | os.PathLike[str], robot: RobotModel, default_tcp_frame: str) -> CartesianEnvelope:
    """The ``cartesian_limits`` of a YAML file, its frames checked against ``robot``; OptionError
    naming the file and the key for anything wrong."""
    try:
        with open(path) as f:
            doc = yaml.safe_load(f) or {}
    except yaml.YAMLError as err:
        raise OptionError(f"{path}: not YAML: {err}") from None
    except OSError as err:
        raise OptionError(f"{path}: cannot read it: {err.strerror}") from None
    table = doc.get("cartesian_limits", {}) if isinstance(doc, dict) else None
    if not isinstance(table, dict):
        raise OptionError(f"{path}: 'cartesian_limits' must be a mapping")
    where = f"{path}: cartesian_limits"
    known = {"tcp_frame", "max_tcp_speed_m_s", "max_tcp_angular_speed_rad_s", "keep_in_boxes", "tool_axis_cone"}
    unknown = sorted(set(table) - known)
    if unknown:
        raise OptionError(f"{where} has unknown keys {unknown} (known: {', '.join(sorted(known))})")

    def frame(value: Any, key: str) -> str:
        if not isinstance(value, str) or not robot.has_frame(value):
            raise OptionError(f"{where}.{key}: {value!r} is not a link or frame of the robot model")
        return value

    def positive(key: str) -> float:
        value = _number(table[key], f"{where}.{key}")
        if value <= 0:
            raise OptionError(f"{where}.{key} must be positive, got {value:g}")
        return value

    tcp = frame(table.get("tcp_frame", default_tcp_frame), "tcp_frame")
    speed = positive("max_tcp_speed_m_s") if "max_tcp_speed_m_s" in table else math.inf
    angular = positive("max_tcp_angular_speed_rad_s") if "max_tcp_angular_speed_rad_s" in table else math.inf
    boxes_doc = table.get("keep_in_boxes") or {}
    if not isinstance(boxes_doc, dict):
        raise OptionError(f"{where}.keep_in_boxes must be a mapping of box name -> frames, min_m, max_m")
    boxes = []
    for name, box in boxes_doc.items():
        key = f"keep_in_boxes.{name}"
        if not isinstance(box, dict) or not isinstance(box.get("frames"), list) or not box["frames"]:
            raise OptionError(f"{where}.{key} needs 'frames' (a list of links), 'min_m' and 'max_m'")
        frames = tuple(frame(f, f"{key}.frames") for f in box["frames"])
        low = _vector(box.get("min_m"), f"{where}.{key}.min_m")
        high = _vector(box.get("max_m"), f"{where}.{key}.max_m")
        if any(lo >= hi for lo, hi in zip(low, high)):
            raise OptionError(f"{where}.{key}: min_m {list(low)} must be below max_m {list(high)} on every axis")
        boxes.append(KeepInBox(str(name), frames, low, high))
    cone = None
    cone_doc = table.get("tool_axis_cone")
    if cone_doc is not None:
        if not isinstance(cone_doc, dict):
            raise OptionError(f"{where}.tool_axis_cone must be a mapping with frame, axis, direction, max_angle_deg")
        angle = _number(cone_doc.get("max_angle_deg"), f"{where}.tool_axis_cone.max_angle_deg")
        if not 0 < angle <= 180:
            raise OptionError(f"{where}.tool_axis_cone.max_angle_deg must be in (0, 180], got {angle:g}")
        cone = ToolCone(frame(cone_doc.get("frame", tcp), "tool_axis_cone.frame"),
                        _unit(cone_doc.get("axis"), f"{where}.tool_axis_cone.axis"),
                        _unit(cone_doc.get("direction"), f"{where}.tool_axis_cone.direction"), angle)
    return CartesianEnvelope(tcp, speed, angular, tuple(boxes), cone)


def _number(value: Any, where: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise OptionError(f"{where} is not a number: {value!r}") from None
    if not math.isfinite(number):
        raise OptionError(f"{where} must be finite, got {value!r}")
    return number


def _vector(value: Any, where: str) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise OptionError(f"{where} needs 3 numbers [x, y, z], got {value!r}")
    x, y, z = (_number(v, where) for v in value)
    return (x, y, z)


def _unit(value: Any, where: str) -> tuple[float, float, float]:
    v = np.array(_vector(value, where))
    norm = float(np.linalg.norm(v))
    if norm == 0:
        raise OptionError(f"{where} must not be the zero vector")
    x, y, z = (float(c) for c in v / norm)
    return (x, y, z)
