"""What a run's world gives the tree's nodes (``RunContext.world`` and ``RunContext.scene``): the
world itself, and the planning scene it fills.

Both are protocols: the tree engine imports nothing of the motion room, where the planning
scene lives (``runtime.motion.scene.PlanningScene`` is the one every world fills in), nor of the
application, which finds and creates worlds (``runtime.app.world``). The types of the scene's
own parts (robot model, layouts, snapshots, collision results) are the motion room's; here they
are ``Any``.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Iterable, Protocol, Sequence

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from .behavior import RunContext


class World(Protocol):
    """A simulated (or real) robot cell that serves a run on its bus.

    The runner owns the loop: ``clock.advance(period)``, ``world.step_to(clock.now())``,
    ``bus.spin_once()``, then one tick of the tree. A world therefore keeps its own time equal to
    the clock after each ``step_to``; its controllers run at their own rate in between.
    """

    name: str

    def start(self, context: RunContext) -> None:
        """Serve topics, services and actions on ``context.bus``; fill ``context.scene``."""
        ...

    def step_to(self, t: float) -> None:
        """Advance physics and controllers until clock time ``t``."""
        ...

    def reset(self, seed: int) -> None:
        """Restore the initial state with a layout drawn from ``seed``."""
        ...

    def summary(self) -> dict[str, Any]:
        """JSON-serialisable facts for the run summary (may be empty)."""
        ...

    def close(self) -> None: ...


class Scene(Protocol):
    """The planning scene: the robot model, the world objects, the collision rules between
    objects and links, the objects attached to links, and collision queries on all of them
    (``runtime.motion.scene.PlanningScene`` says what each does)."""

    robot: Any
    """The robot model (``runtime.motion.scene.RobotModel``)."""
    limits: Any
    """The joint limits (``runtime.motion.scene.JointLimits``), or None."""
    envelope: Any
    """The Cartesian envelope (``runtime.motion.scene.CartesianEnvelope``), or None."""

    @property
    def group(self) -> str: ...
    @property
    def gripper_joint(self) -> str | None: ...
    def layout(self, group: str | None = None, gripper_joint: str | None = None) -> Any: ...
    def full_configuration(self, group_positions: Sequence[float], gripper_position: float | None = None,
                           layout: Any = None) -> NDArray[np.float64]: ...

    # -- world objects
    def add_object(self, name: str, shape: Any, pose: NDArray[np.float64], fixed: bool = False) -> None: ...
    @property
    def version(self) -> tuple[int, int]: ...
    def move_object(self, name: str, pose: Any) -> None: ...
    def remove_object(self, name: str) -> None: ...
    def object_pose(self, name: str) -> NDArray[np.float64]: ...
    @property
    def objects(self) -> dict[str, Any]: ...
    @property
    def handled_objects(self) -> list[str]: ...

    # -- collision rules and attachments
    def allow(self, object_name: str, links: str | Iterable[str]) -> None: ...
    def disallow(self, object_name: str, links: str | Iterable[str]) -> None: ...
    def is_allowed(self, object_name: str, link: str) -> bool: ...
    def snapshot_with_rule(self, snapshot: Any, object_name: str, links: str | Iterable[str], allowed: bool) -> Any: ...
    def attach(self, name: str, link: str, *, q: NDArray[np.float64] | None = None, shape: Any = None,
               pose_in_link: NDArray[np.float64] | None = None, touch_links: Iterable[str] = ()) -> Any: ...
    def detach(self, name: str, q: NDArray[np.float64] | None = None) -> None: ...
    @property
    def attachments(self) -> tuple[Any, ...]: ...
    def snapshot(self) -> Any: ...

    # -- queries
    def link_pose(self, q: NDArray[np.float64], link: str, layout: Any = None) -> NDArray[np.float64]: ...
    def object_world_pose(self, name: str, q: NDArray[np.float64], layout: Any = None) -> NDArray[np.float64]: ...
    def check_state(self, q: NDArray[np.float64], padding: float = 0.01, snapshot: Any = None, layout: Any = None) -> Any: ...
    def check_path(self, Q: NDArray[np.float64], times: NDArray[np.float64] | None = None, padding: float = 0.01,
                   stop_at_first: bool = True, snapshot: Any = None, layout: Any = None, early_out: bool = True,
                   free_at: tuple[int, int] | None = None) -> Any: ...
    def min_distance(self, q: NDArray[np.float64], kind: str | None = None, snapshot: Any = None, layout: Any = None) -> Any: ...
