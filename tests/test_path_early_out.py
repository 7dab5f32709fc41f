"""The path check's early-out answers exactly what checking every point on its own answers.

``check_path`` settles runs of points that a proven motion bound shows collision-free with one
check (``runtime.motion.scene.swept``). On random paths near the table, the cubes and the robot itself
(in the real cell scene, with and without a carried cube), the fast path and the plain per-point
check must agree on every colliding step, its pair and its distance; and the bound itself must
hold for random pairs of configurations.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from runtime.motion.scene import Box, collision, pose_matrix, swept
from sim.layouts import layout
from sim.planning import CUBE_SIZE, make_cell_scene
from sim.robot_model import ARM_JOINTS, load_waypoints

WAYPOINTS = [np.array([wp[j] for j in ARM_JOINTS]) for wp in load_waypoints().values()]
CUBES = {c: (np.array([x, y, CUBE_SIZE / 2]), np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]))
         for c, (x, y, yaw) in layout(0).items()}
_SCENES: dict[bool, object] = {}


def cell_scene(carrying: bool):
    """The cell scene; ``carrying``: a 6 cm box attached below the gripper base."""
    if carrying not in _SCENES:
        scene = make_cell_scene(CUBES)
        if carrying:
            scene.attach("carried", "gripper_base", shape=Box((0.06, 0.06, 0.06)),
                         pose_in_link=pose_matrix([0.0, 0.0, 0.2]))
        _SCENES[carrying] = scene
    return _SCENES[carrying]


paths = st.fixed_dictionaries({
    "start": st.sampled_from(range(len(WAYPOINTS))),
    "offset": st.lists(st.floats(-0.4, 0.4), min_size=6, max_size=6),
    "delta": st.lists(st.floats(-1.5, 1.5), min_size=6, max_size=6),
    "wiggle": st.lists(st.floats(-0.05, 0.05), min_size=6, max_size=6),
    "frequency": st.floats(0.0, 6.0),
    "points": st.integers(1, 300),
    "gripper": st.one_of(st.floats(0.0, 0.8), st.tuples(st.floats(0.0, 0.8), st.floats(0.0, 0.8))),
    "padding": st.sampled_from([0.0, 0.01, 0.05]),
    "carrying": st.booleans(),
})


def make_path(p: dict) -> np.ndarray:
    s = np.linspace(0.0, 1.0, p["points"])[:, None]
    start = WAYPOINTS[p["start"]] + np.array(p["offset"])
    arm = start + s * np.array(p["delta"]) + np.sin(2 * np.pi * p["frequency"] * s) * np.array(p["wiggle"])
    gripper = p["gripper"]
    column = np.full(len(s), gripper) if isinstance(gripper, float) else np.linspace(*gripper, len(s))
    return np.column_stack([arm, column])


def key(hit):
    """Everything but the distance: GJK starts from its previous answer, so the distance of
    the same configuration differs by up to its tolerance (1e-6 m) with what was checked before."""
    return None if hit is None else (hit.step, hit.time, hit.kind, hit.first, hit.second, hit.padding)


common = dict(deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])


@settings(max_examples=60, **common)
@given(paths)
def test_early_out_gives_the_per_point_answer(p):
    assert_same_answer_as_per_point(p)


@pytest.mark.slow
@settings(max_examples=1000, **common)
@given(paths)
def test_early_out_gives_the_per_point_answer_1000_examples(p):
    assert_same_answer_as_per_point(p)


def assert_same_answer_as_per_point(p: dict) -> None:
    scene = cell_scene(p["carrying"])
    Q = make_path(p)
    times = np.arange(len(Q)) * 0.01
    every = scene.check_path(Q, times, p["padding"], stop_at_first=False)
    plain = scene.check_path(Q, times, p["padding"], stop_at_first=False, early_out=False)
    event(f"colliding steps: {'none' if not plain else 'all' if len(plain) == len(Q) else 'some'}")
    assert [key(h) for h in every] == [key(h) for h in plain]
    assert [h.distance for h in every] == pytest.approx([h.distance for h in plain], abs=2e-6)
    first = scene.check_path(Q, times, p["padding"])
    assert key(first) == key(scene.check_path(Q, times, p["padding"], early_out=False)) == key(plain[0] if plain else None)
    if first is not None:
        assert first.distance == pytest.approx(plain[0].distance, abs=2e-6)
    for step in (0, len(Q) - 1):  # each row's answer is the single-configuration check's
        alone = scene.check_state(Q[step], p["padding"])
        assert (alone is None) == (step not in {h.step for h in plain})


def test_motion_bound_holds_for_every_geometry_point():
    """Every corner of every geometry's box moves by at most sum_j R[g, j] |dq_j|."""
    scene = cell_scene(True)
    checker = scene._checker(0.01, scene.snapshot())
    model, gm = checker.robot.model, checker.geometry_model
    radii = swept.motion_radii(model, gm)
    rng = np.random.default_rng(7)
    data, gd = model.createData(), pin.GeometryData(gm)

    def corners(q):
        pin.updateGeometryPlacements(model, data, gm, gd, q)
        out = []
        for g, geometry in enumerate(gm.geometryObjects):
            box = geometry.geometry.aabb_local
            lo, hi = np.asarray(box.min_), np.asarray(box.max_)
            local = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            out.append(local @ np.asarray(gd.oMg[g].rotation).T + np.asarray(gd.oMg[g].translation))
        return np.array(out)

    lower, upper = np.maximum(model.lowerPositionLimit, -np.pi), np.minimum(model.upperPositionLimit, np.pi)
    worst = 0.0
    for _ in range(300):
        q = rng.uniform(lower, upper)
        q2 = q + rng.normal(0.0, 0.3, q.shape) * (rng.random(q.shape) < 0.5)
        moved = np.linalg.norm(corners(q2) - corners(q), axis=2).max(axis=1)
        bound = radii[:, 1:] @ np.abs(q2 - q)
        assert np.all(moved <= bound + 1e-12)
        worst = max(worst, float(np.max(moved / np.maximum(bound, 1e-12))))
    assert worst > 0.3  # the bound is not vacuous: some motion comes near it


def test_pair_coefficients_ignore_joints_that_move_both_or_neither():
    radii = np.array([[0.0, 1.0, 0.5, 0.0], [0.0, 2.0, 0.0, 0.3], [0.0, 0.0, 0.0, 0.0]])
    coefficients = swept.pair_coefficients(radii, [(0, 1), (0, 2)])
    assert coefficients.tolist() == [[0.0, 0.0, 0.5, 0.3], [0.0, 1.0, 0.5, 0.0]]


def test_window_ends_stop_where_a_joint_travels_past_its_budget():
    Q = np.array([[0.0, 0.0], [0.004, 0.0], [0.004, -0.009], [0.0, -0.02], [0.0, 0.0]])
    travel = swept.path_travel(Q, np.array([0.005, 0.01, 0.02, 0.04]))
    assert swept.window_ends(travel, 0).tolist() == [2, 3, 4, 5]  # the second joint travels 0.04 by row 4
    assert swept.window_ends(travel, 3).tolist() == [4, 4, 5, 5]
    assert swept.window_ends(swept.path_travel(Q, np.array([0.005, 0.04])), 3).tolist() == [4, 5]


@settings(max_examples=200, **common)
@given(st.integers(2, 40), st.integers(1, 4), st.integers(0, 2**32 - 1), st.data())
def test_no_joint_leaves_its_budget_inside_a_window(rows, columns, seed, data):
    Q = np.random.default_rng(seed).normal(0.0, 0.01, (rows, columns)).cumsum(axis=0)
    levels = np.array([0.005, 0.01, 0.02, 0.04, 0.08, 0.16])
    start = data.draw(st.integers(0, rows - 1))
    ends = swept.window_ends(swept.path_travel(Q, levels), start)
    assert np.all(ends > start) and np.all(ends <= rows) and np.all(np.diff(ends) >= 0)
    for level, end in zip(levels, ends):
        assert np.abs(Q[start:end] - Q[start]).max() <= level + 1e-12


def test_moved_objects_are_seen_by_the_early_out():
    """A cube moved onto the path between two checks is hit where it was put, either way."""
    scene = make_cell_scene(CUBES)
    Q = make_path({"start": 0, "offset": [0.0] * 6, "delta": [0.0, 0.5, 0.3, 0.0, 0.0, 0.0], "wiggle": [0.0] * 6,
                   "frequency": 0.0, "points": 200, "gripper": 0.0})
    for step in (20, 60, 100):
        scene.move_object("cube_red", pose_matrix(scene.link_pose(Q[step], "wrist_2_link")[:3, 3]))
        fast, plain = scene.check_path(Q, stop_at_first=False), scene.check_path(Q, stop_at_first=False, early_out=False)
        assert [key(h) for h in fast] == [key(h) for h in plain]
        assert step in {h.step for h in plain} and any(h.second == "cube_red" for h in plain)
        scene.move_object("cube_red", pose_matrix([0.0, 0.0, -1.0]))  # away, under the table
        assert step not in {h.step for h in scene.check_path(Q, stop_at_first=False)}


@pytest.mark.parametrize("below_hit_rad", [0.01, -0.005])  # hovering 5 mm clear of the padding; inside it
def test_pairs_set_aside_over_the_table_give_the_per_point_answer_and_are_put_back(monkeypatch, below_hit_rad):
    """A finger hovering over the table keeps every window from being free: its pairs are set
    aside for the rest of the path, the answers stay the per-point ones, and afterwards every
    compiled check has its pairs as before."""
    scene = make_cell_scene(CUBES)
    ready = np.array([load_waypoints()["Ready"][j] for j in ARM_JOINTS])
    lift = np.eye(6)[1]  # turning the shoulder lift forward lowers the fingers
    lo, hi = 0.0, 1.5
    while hi - lo > 1e-4:  # the first shoulder angle where a finger reaches the table's padding
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if scene.check_state(np.append(ready + mid * lift, 0.0), 0.01) else (mid, hi)
    hover = ready + (hi - below_hit_rad) * lift
    along = hover + np.linspace(0.0, 0.3, 200)[:, None] * np.eye(6)[0]
    arm = np.vstack([np.linspace(ready, hover, 100), along, np.linspace(along[-1], along[-1] - hi * lift, 100)])
    Q = np.column_stack([arm, np.zeros(len(arm))])
    set_aside = []
    add = collision._NearPairs.add
    monkeypatch.setattr(collision._NearPairs, "add", lambda near, pair: (set_aside.append(pair), add(near, pair)))
    fast, plain = scene.check_path(Q, stop_at_first=False), scene.check_path(Q, stop_at_first=False, early_out=False)
    assert [key(h) for h in fast] == [key(h) for h in plain]
    assert set_aside and (len(plain) > 100) == (below_hit_rad < 0)
    checker = scene._checker(0.01, scene.snapshot())
    for levels in checker._swept_levels.values():
        for level in levels:
            assert all(level.geometry_data.activeCollisionPairs)
    assert not any(checker._near_data.activeCollisionPairs)
