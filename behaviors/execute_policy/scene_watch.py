"""ExecutePolicy's scene watch: the rest of the sent motion checked again when the planning scene
changes (an object moved or was added, the gripper moved).

Every ``SCENE_WATCH_PERIOD_S`` ``check`` compares what a collision check of the samples depends on
(the scene's version and the gripper position, ``scene_state``) with what they were last checked
against; only a change costs a check. Samples found collision-free before, at a gripper position
the state does not tell apart, are checked against the world objects that moved since only.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

from runtime.motion.samples import Samples

if TYPE_CHECKING:
    from runtime.motion.scene import CollisionResult

    from ..safety import MotionSafety

SCENE_WATCH_PERIOD_S = 0.05  # how often the rest of the sent motion is checked against the live scene


@dataclass(frozen=True)
class FreeSamples:
    """Sent samples the scene watch found collision-free: at which scene version and with
    which gripper position (the gripper column of every checked row)."""

    samples: Samples
    gripper_position: float | None
    scene_version: tuple[int, int]


class SceneWatch:
    """What the sent samples were last checked against, and when the next look is due."""

    def __init__(self, safety: MotionSafety, link_padding: float) -> None:
        self.safety, self.link_padding = safety, link_padding
        self.next_check_s = 0.0
        self.checked_scene: tuple[object, ...] | None = None  # what the sent samples were last checked against
        self.free_samples: FreeSamples | None = None  # the last collision-free answer

    def checked(self, gripper_now: float | None) -> None:
        """The samples just sent were checked against the scene of now (by the planner's point checks)."""
        self.checked_scene = self.scene_state(gripper_now)

    def scene_state(self, gripper_now: float | None) -> tuple[object, ...]:
        """What a collision check of the sent samples depends on, besides the samples."""
        return (self.safety.scene.version, gripper_key(gripper_now))

    def check(self, rules: Any, samples: Samples | None, now_s: float,
              gripper_position: Callable[[], float | None]) -> CollisionResult | None:
        """The first collision in the rest of ``samples`` (from ``now_s``, under the safety
        ``rules``) when the scene changed since they were last checked; None when there is none,
        or nothing to look at yet. ``gripper_position`` reads the gripper's position of now
        (asked only when a look is due)."""
        if samples is None or now_s < self.next_check_s - 1e-9:
            return None
        self.next_check_s = now_s + SCENE_WATCH_PERIOD_S
        gripper_now = gripper_position()
        scene_state = self.scene_state(gripper_now)
        if scene_state == self.checked_scene:  # the remaining samples were checked against this very scene
            return None
        version, free = self.safety.scene.version, self.free_samples
        if free is not None and free.samples is samples and gripper_key(free.gripper_position) == scene_state[1]:
            # Found free before with a gripper position this state does not tell apart: only the
            # world objects that moved since need a check, at the gripper position of then.
            gripper, free_at = free.gripper_position, free.scene_version
        else:
            gripper, free_at = gripper_now, None
        collision = self.safety.first_collision(rules, samples_from(samples, now_s), self.link_padding, gripper, free_at)
        if collision is not None:
            return collision
        self.checked_scene = scene_state
        self.free_samples = FreeSamples(samples, gripper, version)
        return None


def gripper_key(position: float | None) -> float | None:
    """The gripper position as the scene watch compares it: a change below 1e-4 rad (a few
    micrometres at the fingertips) is no reason to check the sent samples again."""
    return None if position is None else round(position, 4)


def samples_from(samples: Samples, t: float) -> Samples:
    """The samples at or after ``t``."""
    keep = samples.times >= t
    return Samples(samples.times[keep], samples.positions[keep], samples.velocities[keep], samples.accelerations[keep])
