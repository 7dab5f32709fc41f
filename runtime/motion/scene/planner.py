"""Collision-free joint paths: OMPL's RRT-Connect on the planning scene's own collision checks.

The planner knows nothing of the scene: it gets a state-validity callback (``scene_validity``
builds one from ``PlanningScene.check_state``, so padding, allowed-collision rules and attached
objects are the ones every other motion is checked with) and the joint bounds. A straight joint
move is tried first; only when it is blocked does RRT-Connect search (in the joint bounds
narrowed to ``margin_rad`` beyond the start and the goal), and its path is then shortcut by OMPL's
path simplifier (vertex reduction, then rope shortcutting). Timing the path is the caller's business (the path is a
polyline in joint space, each segment checked every ``check_step_rad``).

OMPL was chosen by measurement on this cell (docs/moveit-pro-behaviors.md, Motion planning;
``benchmarks/bench_planning.py``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
from numpy.typing import NDArray

from runtime.errors import ObjectiveError, SetupError

if TYPE_CHECKING:
    from .model import ConfigurationMap
    from .scene import PlanningScene, SceneSnapshot

Validity = Callable[[NDArray[np.float64]], bool]
"""True when a configuration (the group's joint values) is collision-free."""


class PathPlanningError(ObjectiveError, ValueError):
    """No path: the start or goal is invalid, or the search ran out of time."""

    def __init__(self, what: str, in_collision: str | None = None) -> None:
        super().__init__(what)
        self.in_collision = in_collision
        """``"start"`` or ``"goal"`` when that state is in collision, else None."""


@dataclass(frozen=True)
class PlannerSettings:
    timeout_s: float = 1.0
    """Seconds RRT-Connect may search (shortcutting its path takes a few milliseconds more)."""
    max_iterations: int = 5000
    """RRT-Connect iterations (one sample, one extension of each tree) before it gives up."""
    seed: int = 0
    """Seeds OMPL's random generator: the same seed, scene and query give the same path."""
    check_step_rad: float = 0.025
    """Largest joint-space (Euclidean) step between two checked states along a motion."""
    range_rad: float = 1.0
    """Longest edge RRT-Connect adds to a tree in one step (joint-space Euclidean)."""
    margin_rad: float = math.pi
    """The search space: the joint bounds, narrowed to this far beyond the start and the goal."""


@dataclass(frozen=True)
class JointPath:
    waypoints: NDArray[np.float64]
    """(N, dof): the start, the corners of the path, the goal; straight segments between."""
    search_s: float
    """Seconds RRT-Connect searched (0 when the straight move was free)."""
    shortcut_s: float
    straight: bool
    """True when the straight joint move from start to goal was free (no search)."""

    @property
    def length_rad(self) -> float:
        """Joint-space length: the sum of the segments' Euclidean lengths."""
        return float(np.linalg.norm(np.diff(self.waypoints, axis=0), axis=1).sum())


def segment_states(a: NDArray[np.float64], b: NDArray[np.float64], step_rad: float) -> NDArray[np.float64]:
    """States from ``a`` (excluded) to ``b`` (included), none more than ``step_rad`` apart."""
    count = max(1, int(math.ceil(float(np.linalg.norm(b - a)) / step_rad)))
    return a + np.linspace(0.0, 1.0, count + 1)[1:, None] * (b - a)


def motion_is_free(is_free: Validity, a: NDArray[np.float64], b: NDArray[np.float64], step_rad: float) -> bool:
    return all(is_free(q) for q in segment_states(a, b, step_rad))


def plan_path(is_free: Validity, start: NDArray[np.float64], goal: NDArray[np.float64], lower: NDArray[np.float64], upper: NDArray[np.float64],
              settings: PlannerSettings = PlannerSettings()) -> JointPath:
    """A collision-free path from ``start`` to ``goal`` within ``[lower, upper]``.

    Raises PathPlanningError naming the reason: the start or the goal in collision or outside
    the bounds, or no path found within ``settings.timeout_s``."""
    start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    for name, q in (("start", start), ("goal", goal)):
        if q.shape != lower.shape:
            raise PathPlanningError(f"the {name} has {q.size} joint values, the bounds {lower.size}")
        outside = np.flatnonzero((q < lower) | (q > upper))
        if outside.size:
            i = int(outside[0])
            raise PathPlanningError(f"the {name} is outside the joint bounds: joint {i} at {q[i]:.4f} rad, "
                                    f"bounds [{lower[i]:.4f}, {upper[i]:.4f}] rad")
        if not is_free(q):
            raise PathPlanningError(f"the {name} state is in collision", in_collision=name)
    if not settings.timeout_s > 0:
        raise PathPlanningError(f"the planning timeout must be positive, got {settings.timeout_s:g} s")
    if settings.max_iterations < 1:
        raise PathPlanningError(f"max_iterations must be at least 1, got {settings.max_iterations}")
    if motion_is_free(is_free, start, goal, settings.check_step_rad):
        return JointPath(np.stack([start, goal]), 0.0, 0.0, True)
    return _search(is_free, start, goal, lower, upper, settings)


def _search(is_free: Validity, start: NDArray[np.float64], goal: NDArray[np.float64], lower: NDArray[np.float64], upper: NDArray[np.float64],
            settings: PlannerSettings) -> JointPath:
    """RRT-Connect, then shortcutting, with OMPL; every OMPL object lives in this call only."""
    lower = np.maximum(lower, np.minimum(start, goal) - settings.margin_rad)
    upper = np.minimum(upper, np.maximum(start, goal) + settings.margin_rad)
    try:
        from ompl import base as ob, geometric as og, util as ou
    except ImportError as err:
        raise SetupError(f"planning around an obstacle needs OMPL, a core dependency that is not importable here "
                         f"({err}): pip install ompl==2.0.1") from None

    ou.setLogLevel(ou.LOG_NONE)
    ou.RNG.setSeed(int(settings.seed) & 0x7FFFFFFF or 1)
    dof = len(start)
    space = ob.RealVectorStateSpace(dof)
    bounds = ob.RealVectorBounds(dof)
    for i in range(dof):
        bounds.setLow(i, float(lower[i]))
        bounds.setHigh(i, float(upper[i]))
    space.setBounds(bounds)
    setup = og.SimpleSetup(space)
    setup.setStateValidityChecker(lambda state: bool(is_free(np.fromiter((state[i] for i in range(dof)), float, dof))))
    info = setup.getSpaceInformation()
    info.setStateValidityCheckingResolution(settings.check_step_rad / space.getMaximumExtent())
    planner = og.RRTConnect(info)
    planner.setRange(float(settings.range_rad))
    setup.setPlanner(planner)
    setup.setStartAndGoalStates(_state(space, start), _state(space, goal))
    iterations = [0]

    def iterated_enough() -> bool:  # OMPL asks once per RRT-Connect iteration
        iterations[0] += 1
        return iterations[0] > settings.max_iterations

    began = time.perf_counter()
    setup.solve(ob.plannerOrTerminationCondition(ob.timedPlannerTerminationCondition(float(settings.timeout_s)),
                                                 ob.PlannerTerminationCondition(iterated_enough)))
    searched = time.perf_counter() - began
    if not setup.haveExactSolutionPath():
        if iterations[0] > settings.max_iterations:
            raise PathPlanningError(f"no collision-free path found in {settings.max_iterations} iterations ({searched:.2f} s)")
        raise PathPlanningError(f"no collision-free path found within {settings.timeout_s:g} s")
    path = setup.getSolutionPath()
    simplifier = og.PathSimplifier(info)
    simplifier.reduceVertices(path)
    simplifier.ropeShortcutPath(path)
    shortcut = time.perf_counter() - began - searched
    waypoints = np.array([[path.getState(k)[i] for i in range(dof)] for k in range(path.getStateCount())])
    waypoints[0], waypoints[-1] = start, goal
    return JointPath(waypoints, searched, shortcut, False)


def _state(space: Any, q: NDArray[np.float64]) -> Any:
    state = space.allocState()
    for i, value in enumerate(q):
        state[i] = float(value)
    return state


def scene_validity(scene: PlanningScene, layout: ConfigurationMap, padding_m: float, snapshot: SceneSnapshot | None,
                   gripper_position: float | None) -> Validity:
    """``is_free`` for ``plan_path`` from a PlanningScene: ``check_state`` with this padding,
    snapshot (collision rules and attachments) and layout, the gripper held at
    ``gripper_position`` when the layout has a gripper column."""
    extra = [] if layout.gripper_joint is None else [0.0 if gripper_position is None else float(gripper_position)]

    def is_free(q: NDArray[np.float64]) -> bool:
        row = np.concatenate([q, extra]) if extra else q
        return scene.check_state(row, padding_m, snapshot=snapshot, layout=layout) is None

    return is_free
