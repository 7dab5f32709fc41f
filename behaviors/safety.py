"""What motion behaviors need from the planning scene: the group's joints, their limits, the
cell's Cartesian envelope, and collision checks of a densified motion against a snapshot of the
collision rules."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from runtime.errors import ObjectiveError, OptionError
from runtime.motion.scene import (
    CartesianEnvelope, CollisionResult, ConfigurationMap, EnvelopeOverrides, EnvelopeViolation, GroupError, JointLimit, JointLimits,
    LimitViolation, PlanningScene, PoseCheck, SceneSnapshot, check_envelope, narrowed, shrunk, tool_speed_ratio,
)

from runtime.motion.samples import Samples


GRIPPER_BAND_FRACTION = 0.1
"""A gripper target at most this fraction of the gripper joint's range outside the range (0.08 rad
on the cell's 0..0.8 rad) is clamped into it: a learned policy's gripper output is continuous and
lands a little beyond the range (-0.056 rad from a LeRobot regression head for "open"), where the
fingers cannot go anyway. Further out it is the policy's error, and the chunk is rejected like an
arm joint out of its limits."""
GRIPPER_ROUNDING_RAD = 1e-6
"""A gripper target this close outside the range is the range's end written with rounding (a
scripted policy's 0.8 computed as 0.8000000000000002): clamped without being counted or warned."""


@dataclass(frozen=True)
class SettledColumn:
    """A chunk's gripper column after ``MotionSafety.settle_gripper_column``."""

    values: NDArray[np.float64] | None
    clamped: int
    """How many targets were moved into the range."""
    farthest_rad: float
    """The largest distance outside the range among them (0 when none)."""


class SafetyError(ObjectiveError, ValueError):
    """The scene cannot check this group: unknown group, several tips, missing limits..."""


@dataclass(frozen=True)
class MotionSafety:
    scene: PlanningScene
    group: str
    group_joints: tuple[str, ...]
    tip: str
    limits: JointLimits
    layout: ConfigurationMap
    gripper_joint: str | None
    chunk_limits: JointLimits
    """The limits of the group's joints, then of the gripper joint when there is one."""
    envelope: CartesianEnvelope | None = None
    """The Cartesian envelope every point is checked against (the cell's, perhaps narrowed)."""

    def narrowed(self, overrides: EnvelopeOverrides) -> MotionSafety:
        """This safety with the envelope tightened by a behavior's ports (``envelope.narrowed``);
        a SafetyError when a port would widen it. Without a cell envelope, the ports make one
        around the group's tip."""
        base = self.envelope if self.envelope is not None else CartesianEnvelope(self.tip)
        source = "the cell's envelope" if self.envelope is not None else "an unlimited envelope"
        try:
            envelope = narrowed(base, overrides, source)
        except OptionError as err:
            raise SafetyError(str(err)) from None
        return replace(self, envelope=None if envelope == CartesianEnvelope(self.tip) else envelope)

    def snapshot(self) -> SceneSnapshot:
        """Collision rules and attachments now; checks with it ignore later rule changes."""
        return self.scene.snapshot()

    def gripper_band_rad(self) -> float:
        """How far outside its range a gripper target is clamped (``GRIPPER_BAND_FRACTION``)."""
        assert self.gripper_joint is not None  # asked only of a group with a gripper
        limit = self.chunk_limits[self.gripper_joint]
        return GRIPPER_BAND_FRACTION * (limit.upper - limit.lower)

    def settle_gripper_column(self, gripper: NDArray[np.float64] | None) -> SettledColumn:
        """The gripper column with targets within ``gripper_band_rad`` outside the gripper
        joint's limits clamped into them; values further out (or NaN) are left as they are, for
        the limit check to reject."""
        if gripper is None or self.gripper_joint is None:
            return SettledColumn(gripper, 0, 0.0)
        limit, band = self.chunk_limits[self.gripper_joint], self.gripper_band_rad()
        outside = np.maximum(limit.lower - gripper, gripper - limit.upper)
        settle = (outside > 0) & (outside <= band)
        if not settle.any():
            return SettledColumn(gripper, 0, 0.0)
        settled = np.where(settle, np.clip(gripper, limit.lower, limit.upper), gripper)
        counted = settle & (outside > GRIPPER_ROUNDING_RAD)
        return SettledColumn(settled, int(counted.sum()), float(outside[counted].max()) if counted.any() else 0.0)

    def first_gripper_target_out_of_limits(self, gripper: NDArray[np.float64] | None, dt_s: float) -> LimitViolation | None:
        """The first step of a column of gripper targets ``dt_s`` apart outside the gripper
        joint's position limits, or asking it for more velocity or acceleration than they allow."""
        if gripper is None or self.gripper_joint is None or len(gripper) == 0:
            return None
        return self.chunk_limits.subset([self.gripper_joint]).check_steps(gripper[:, None], dt_s)

    def first_limit_violation(self, samples: Samples) -> LimitViolation | EnvelopeViolation | None:
        """The earliest sample of a motion outside the group's position, velocity or
        acceleration limits or outside the Cartesian envelope (at one sample, a joint limit is
        reported first): the one limit check of every behavior that sends motion."""
        joint = self.limits.check(samples.positions, samples.velocities, samples.accelerations, samples.times)
        cartesian = self.first_envelope_violation(samples, len(samples) if joint is None else joint.step)
        return joint if cartesian is None else cartesian

    def first_envelope_violation(self, samples: Samples, end: int | None = None) -> EnvelopeViolation | None:
        """The earliest of the first ``end`` samples (all: None) of a motion outside the Cartesian
        envelope; None without an envelope."""
        if self.envelope is None or len(samples) == 0:
            return None
        end = len(samples) if end is None else end
        return check_envelope(self.envelope, self.scene.robot, self.scene.layout(self.group, None),
                              samples.positions[:end], samples.velocities[:end], samples.times[:end])

    def pose_check(self, margin_m: float = 0.005, margin_deg: float = 1.0) -> Callable[[NDArray[np.float64]], bool]:
        """Whether the group's joint positions put every frame inside the keep-in boxes and the
        tool inside its cone, ``margin_m`` and ``margin_deg`` within them (always True without an
        envelope): a planner's state check, so that the motion timed between two such states
        stays within the envelope itself."""
        if self.envelope is None:
            return lambda q: True
        return PoseCheck(shrunk(self.envelope, margin_m, margin_deg), self.scene.robot, self.scene.layout(self.group, None))

    def tool_speed_ratio(self, samples: Samples) -> float:
        """The largest share of the envelope's TCP speed limits a motion reaches (0 without an
        envelope): above 1, the motion slowed down evenly by that factor keeps within them."""
        if self.envelope is None or len(samples) == 0:
            return 0.0
        return tool_speed_ratio(self.envelope, self.scene.robot, self.scene.layout(self.group, None),
                                samples.positions, samples.velocities)

    def first_value_out_of_limits(self, arm: NDArray[np.float64], gripper: NDArray[np.float64] | None) -> LimitViolation | None:
        """The first step of a chunk, as the policy sent it, with a value outside its joint's
        position limits: the arm columns against the group's joints, the gripper column
        (when there is one) against the gripper joint's."""
        rows = arm if gripper is None or self.gripper_joint is None else np.column_stack([arm, gripper])
        return self.chunk_limits.check(rows)

    def first_collision(
        self, snapshot: SceneSnapshot, samples: Samples, padding: float, gripper_position: float | None = None,
        free_at: tuple[int, int] | None = None,
    ) -> CollisionResult | None:
        """The first colliding sample (``str()`` says it as a sentence), or None. World objects are checked with
        ``padding``; self-collision with the unpadded geometry. ``free_at``: the scene version
        at which these samples were found free with the same snapshot, padding and gripper
        position (see ``PlanningScene.check_path``)."""
        if len(samples) == 0:
            return None
        rows = samples.positions
        if self.gripper_joint is not None:
            value = 0.0 if gripper_position is None else gripper_position
            rows = np.hstack([rows, np.full((len(rows), 1), value)])
        hit = self.scene.check_path(rows, samples.times, padding, snapshot=snapshot, layout=self.layout, free_at=free_at)
        assert not isinstance(hit, list)  # stop_at_first: the first hit or None
        return hit


def make_safety(scene: Any, group: str, gripper_joint: str | None) -> MotionSafety:
    """Resolve ``group`` (exactly one tip) and ``gripper_joint`` (single-DOF, outside the group)."""
    if not isinstance(scene, PlanningScene):
        raise SafetyError("this run has no planning scene, so motions cannot be checked (run it with a world or a robot description)")
    robot = scene.robot
    try:
        joint_group = robot.group(group)
        tip = joint_group.tip_link
    except GroupError as err:
        raise SafetyError(str(err)) from None
    except KeyError:
        raise SafetyError(f"unknown joint group '{group}' (groups: {', '.join(robot.group_names)})") from None
    joints = tuple(joint_group.joints)
    if gripper_joint is not None:
        if gripper_joint in joints:
            raise SafetyError(f"gripper joint '{gripper_joint}' is inside the joint group '{group}'; it must be outside it")
        if gripper_joint not in robot.movable_joints:
            raise SafetyError(f"gripper joint '{gripper_joint}' is not a joint of the robot model")
        jid = robot.model.getJointId(gripper_joint)
        if robot.model.joints[jid].nq != 1:
            raise SafetyError(f"gripper joint '{gripper_joint}' has {robot.model.joints[jid].nq} degrees of freedom; only single-DOF grippers are supported")
    if scene.limits is None:
        raise SafetyError("the planning scene has no joint limits (joint_limits.yaml)")
    try:
        limits = scene.limits.subset(joints)
        chunk_limits = JointLimits(limits.joints + ((_gripper_limit(scene, gripper_joint),) if gripper_joint is not None else ()))
        layout = scene.layout(group, gripper_joint)
    except (KeyError, GroupError, ValueError) as err:
        raise SafetyError(str(err).strip('"')) from None
    return MotionSafety(scene, group, joints, tip, limits, layout, gripper_joint, chunk_limits, scene.envelope)


def _gripper_limit(scene: PlanningScene, joint: str) -> JointLimit:
    """The gripper joint's limits from joint_limits.yaml, or its position range in the robot
    model when the file has no entry for it."""
    assert scene.limits is not None  # make_safety reads the limits first
    try:
        return scene.limits[joint]
    except KeyError:
        model = scene.robot.model
        q = model.joints[model.getJointId(joint)].idx_q
        return JointLimit(joint, float(model.lowerPositionLimit[q]), float(model.upperPositionLimit[q]))
