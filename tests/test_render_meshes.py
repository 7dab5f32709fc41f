"""Light visual meshes for the cell's cameras (sim.render_meshes): same dynamics, same-looking
frames, far fewer triangles to draw."""
from __future__ import annotations

import copy
import statistics
import time

import mujoco
import numpy as np
import pytest

from sim import render_meshes
from sim.cell_model import CAMERA_NAMES, HOME_CONFIGURATION, CellOptions, build_cell_spec
from sim.mujoco_cell import MujocoCell

ORIGINAL = CellOptions(visual_mesh_detail=1.0)
LIGHT = CellOptions()  # the default detail

# Mean absolute difference per pixel and channel (0-255) allowed between a frame drawn with the
# original meshes and one drawn with the light ones. Shifting a frame of the scene camera by a
# single pixel changes it by 1.2 (sideways) to 3.2 (up/down) on this scale, so 2.0 means the
# light meshes change a frame less than moving the camera by about one pixel would.
MAX_MEAN_PIXEL_DIFFERENCE = 2.0
# ... and at most this share of pixels changes visibly (by more than 32 levels in a channel):
# only silhouette edges and small features such as bolt heads may move.
MAX_CHANGED_PIXELS = 0.03


def unshared_cube(size: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """A cube as OBJ exporters write it: every triangle with its own three vertex copies."""
    corners = np.array([[x, y, z] for x in (0, size) for y in (0, size) for z in (0, size)], dtype=float)
    triangles = np.array([
        [0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
        [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5],
    ])
    return corners[triangles.ravel()], np.arange(36).reshape(12, 3)


def sphere(radius: float = 0.05, rings: int = 32, segments: int = 64) -> tuple[np.ndarray, np.ndarray]:
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.column_stack([np.sin(t).ravel() * np.cos(p).ravel(), np.sin(t).ravel() * np.sin(p).ravel(), np.cos(t).ravel()])
    vertices = radius * np.vstack([[0, 0, 1], ring, [0, 0, -1]])
    faces = []
    for s in range(segments):
        n = (s + 1) % segments
        faces.append([0, 1 + s, 1 + n])
        for r in range(rings - 2):
            a, b = 1 + r * segments + s, 1 + r * segments + n
            faces += [[a, a + segments, b], [b, a + segments, b + segments]]
        last = 1 + (rings - 2) * segments
        faces.append([last + s, len(vertices) - 1, last + n])
    return vertices, np.array(faces)


def drawn_triangles(model: mujoco.MjModel) -> int:
    """Triangles of the mesh geoms that mujoco.Renderer draws by default (groups 0-2)."""
    return int(sum(
        model.mesh_facenum[model.geom_dataid[g]]
        for g in range(model.ngeom)
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH and model.geom_group[g] <= 2
    ))


def collision_geoms(model: mujoco.MjModel) -> np.ndarray:
    return np.array([g for g in range(model.ngeom) if model.geom_contype[g] or model.geom_conaffinity[g]])


# -- pure functions ------------------------------------------------------------------------

def test_weld_keeps_one_vertex_per_position():
    vertices, faces = render_meshes.weld(*unshared_cube(), tolerance=1e-6)
    assert len(vertices) == 8 and faces.shape == (12, 3)
    corner_sets = {frozenset(map(tuple, np.round(vertices[f], 9))) for f in faces}
    original_sets = {frozenset(map(tuple, np.round(v, 9))) for v in unshared_cube()[0].reshape(12, 3, 3)}
    assert corner_sets == original_sets


def test_weld_merges_close_vertices_and_drops_the_triangles_that_collapse():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1e-5, 1e-5, 0], [1, 1, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [1, 4, 2], [0, 3, 1]])  # the last one has two corners 1.4e-5 apart
    welded, kept = render_meshes.weld(vertices, faces, tolerance=1e-3)
    assert len(welded) == 4
    assert kept.shape == (2, 3)


def test_weld_rejects_a_tolerance_that_is_not_positive():
    with pytest.raises(ValueError, match="weld tolerance 0"):
        render_meshes.weld(*unshared_cube(), tolerance=0)


def test_decimate_reaches_the_target_and_keeps_the_shape():
    vertices, faces = sphere()
    assert len(faces) == 3968
    light_vertices, light_faces = render_meshes.decimate(vertices, faces, target_faces=400)
    assert 380 <= len(light_faces) <= 400
    radii = np.linalg.norm(light_vertices, axis=1)
    assert np.abs(radii - 0.05).max() < 0.002  # within 4% of the radius


def test_decimate_leaves_a_mesh_already_small_enough_alone():
    vertices, faces = sphere(rings=4, segments=8)
    same_vertices, same_faces = render_meshes.decimate(vertices, faces, target_faces=len(faces))
    assert np.array_equal(same_vertices, vertices) and np.array_equal(same_faces, faces)


@pytest.mark.parametrize("detail", [0, 0.001, 1.5, "0.1", True])
def test_cell_options_reject_a_detail_that_is_not_a_fraction(detail):
    with pytest.raises(ValueError, match=r"visual_mesh_detail .*must be a fraction of triangles in \[0.01, 1.0\]"):
        CellOptions(visual_mesh_detail=detail)


def test_load_mesh_file_gives_the_vertices_mujoco_places():
    """A mesh rebuilt from ``load_mesh_file``'s arrays sits exactly where the file's does."""
    robot = build_cell_spec(ORIGINAL)
    models = []
    for from_file in (True, False):
        spec = mujoco.MjSpec()
        mesh = spec.add_mesh()
        mesh.name = "gripper_base"
        if from_file:
            mesh.file, mesh.scale = robot.mesh("gripper_base").file, robot.mesh("gripper_base").scale
        else:
            vertices, faces = render_meshes.load_mesh_file(robot.mesh("gripper_base").file, tuple(robot.mesh("gripper_base").scale))
            mesh.uservert, mesh.userface = vertices.ravel(), faces.ravel()
        geom = spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname="gripper_base", pos=[0.1, 0.2, 0.3])
        geom.contype = geom.conaffinity = 0
        models.append(spec.compile())
    a, b = models
    assert np.allclose(a.geom_pos, b.geom_pos, atol=1e-7) and np.allclose(a.geom_quat, b.geom_quat, atol=1e-6)
    assert np.allclose(a.mesh_vert, b.mesh_vert, atol=1e-6)


# -- the cell --------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def models() -> tuple[mujoco.MjModel, mujoco.MjModel]:
    return build_cell_spec(ORIGINAL).compile(), build_cell_spec(LIGHT).compile()


def test_the_light_cell_draws_a_sixth_of_the_triangles(models):
    original, light = models
    print(f"\ntriangles drawn: original {drawn_triangles(original)}, light {drawn_triangles(light)}")
    assert drawn_triangles(original) > 190_000
    assert drawn_triangles(light) < drawn_triangles(original) / 5


def test_masses_inertias_and_collision_geoms_are_unchanged(models):
    original, light = models
    for field in ("body_mass", "body_inertia", "body_ipos", "body_iquat", "body_subtreemass"):
        assert np.array_equal(getattr(original, field), getattr(light, field)), field
    a, b = collision_geoms(original), collision_geoms(light)
    assert len(a) == len(b) > 20
    for field in ("geom_type", "geom_bodyid", "geom_size", "geom_pos", "geom_quat", "geom_rbound",
                  "geom_aabb", "geom_friction", "geom_contype", "geom_conaffinity", "geom_margin"):
        assert np.array_equal(getattr(original, field)[a], getattr(light, field)[b]), field
    mesh_of = lambda model, geoms: [model.mesh(model.geom_dataid[g]).name for g in geoms if model.geom_dataid[g] >= 0]
    assert mesh_of(original, a) == mesh_of(light, b)
    for name in set(mesh_of(original, a)):
        assert np.array_equal(original.mesh(name).vertnum, light.mesh(name).vertnum), name


@pytest.mark.parametrize("sleep", [True, False], ids=["as-built", "cubes-awake"])
def test_trajectories_are_bit_identical(models, sleep):
    """Arm swinging, gripper closing, cubes resting on the table: every step the same to the bit,
    as built (resting cubes sleep) and with the cubes kept awake, so that their contacts are
    computed and compared at every step."""
    models = [copy.deepcopy(model) for model in models]
    for model in models:
        assert model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
        if not sleep:
            model.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    datas = [mujoco.MjData(model) for model in models]
    contacts = []
    for model, data in zip(models, datas):
        data.qpos[:6] = HOME_CONFIGURATION
        for i, color in enumerate(("red", "green", "blue")):
            adr = model.joint(f"cube_{color}_joint").qposadr[0]
            data.qpos[adr:adr + 3] = (0.1 * i - 0.1, 0.45, 0.015)
        mujoco.mj_forward(model, data)
    for step in range(400):
        for model, data in zip(models, datas):
            data.ctrl[:6] = np.array(HOME_CONFIGURATION) + 0.3 * np.sin(0.01 * step)
            data.ctrl[model.actuator("gripper_fingers_actuator").id] = 255.0 if step > 150 else 0.0
            mujoco.mj_step(model, data)
        contacts.append(datas[0].ncon)
        assert np.array_equal(datas[0].qpos, datas[1].qpos), f"step {step}"
    if not sleep:
        assert min(contacts[10:]) >= 12  # the cubes on the table: contacts are part of what matches


def test_meshes_that_collisions_or_masses_need_get_a_drawn_copy():
    spec = build_cell_spec(ORIGINAL)
    reductions = {r.source: r for r in render_meshes.simplify_visual_meshes(spec, keep=lambda mesh: 0.2, tolerance=lambda mesh: 1e-3)}
    # only drawn: replaced in place
    assert reductions["upperarm_3"].mesh == "upperarm_3" and spec.mesh("upperarm_3").file == ""
    assert reductions["upperarm_3"].faces_after <= 0.2 * reductions["upperarm_3"].faces_before
    # also a collision mesh: the collision geom keeps it, the drawn geom gets a copy
    assert reductions["gripper_base"].mesh == "gripper_base_visual"
    users = {(g.meshname, g.contype != 0) for g in spec.geoms if g.meshname.startswith("gripper_base")}
    assert ("gripper_base", True) in users and ("gripper_base_visual", False) in users
    assert spec.mesh("gripper_base").file.endswith("base.stl")
    # gives its body mass (no <inertial>): hidden but kept, a massless copy draws it
    mount = [g for g in spec.geoms if g.parent.name == "gripper_base_mount" and g.contype == 0]
    assert [g.group for g in mount if g.meshname == "gripper_base_mount"] == [render_meshes.HIDDEN_GROUP]
    assert [(g.meshname, g.mass) for g in mount if g.group == 2] == [("gripper_base_mount_visual", 0.0)]


def test_simplified_meshes_are_made_once_per_process():
    build_cell_spec(LIGHT)
    hits = render_meshes.simplified_mesh.cache_info().hits
    build_cell_spec(LIGHT)
    assert render_meshes.simplified_mesh.cache_info().hits > hits


@pytest.fixture(scope="module")
def cells():
    pair = [MujocoCell(options, np.array(HOME_CONFIGURATION), seed=0) for options in (ORIGINAL, LIGHT)]
    yield pair
    for cell in pair:
        cell.close()


POSES = {
    "home, gripper open": (np.array(HOME_CONFIGURATION), 0.0),
    "reaching aside, gripper half closed": (np.array([-1.2, -1.9, 2.1, -1.8, -1.5, 0.6]), 0.4),
}


@pytest.mark.parametrize("pose", POSES)
def test_frames_look_the_same(cells, pose):
    arm, gripper = POSES[pose]
    for cell in cells:
        cell.reset(0, arm)
        for _ in range(150):
            cell.command_arm(arm)
            cell.command_gripper(gripper, 50.0)
            cell.step(0.002)
    print()
    for camera in CAMERA_NAMES:
        original, light = (cell.render(camera).astype(float) for cell in cells)
        difference = np.abs(original - light)
        mean, changed = difference.mean(), (difference.max(axis=2) > 32).mean()
        print(f"{pose} / {camera}: mean pixel difference {mean:.2f}, pixels changed visibly {changed:.2%}")
        assert mean < MAX_MEAN_PIXEL_DIFFERENCE, camera
        assert changed < MAX_CHANGED_PIXELS, camera


def test_render_time_per_frame(cells):
    """Prints the median render time of each camera (no timing assertion: the machine is shared)."""
    print()
    for camera in CAMERA_NAMES:
        medians = []
        for cell in cells:
            times = []
            for _ in range(20):
                cell.t += 0.01  # a new instant: the cell would return its cached frame otherwise
                start = time.perf_counter()
                frame = cell.render(camera)
                times.append(time.perf_counter() - start)
            assert frame.shape == (224, 224, 3)
            medians.append(1e3 * statistics.median(times))
        print(f"{camera}: {medians[0]:.1f} ms per frame with the original meshes, {medians[1]:.1f} ms light")
