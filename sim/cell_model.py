"""The simulated cell's MuJoCo scene: the robot on a table, three cubes, lights and cameras.

``build_cell_spec`` starts from the robot model that the planning scene also loads
(``sim.robot_model.build_robot_spec``), so the simulation and the collision checks see one robot.
It adds what only the simulation needs:

- a table whose top is the plane z = 0 of the world frame, with the robot base standing on it at
  the origin (world frame = robot base frame, so cube poses need no extra transform);
- three 30 mm cubes (``cube_red``, ``cube_green``, ``cube_blue``) on free joints, 40 g each, with
  enough friction for the 2F-85 pads to hold one by friction alone;
- ``SIM_BOX_SLOTS`` fixed (mocap) boxes, parked out of sight and without contacts until a run
  places one (``MujocoCell.place_box``: an object that appears in the cell mid-run);
- cheap lighting (no shadows, no reflections, no multisampling: a frame set costs tens of ms on
  CPU instead of most of a second) and three cameras: ``scene`` (in front of the table, looking
  back at the robot), ``overview`` (straight down on the workspace) and ``wrist`` (on the
  gripper, looking along the fingers);
- lighter meshes for drawing (``sim.render_meshes``): the robot's visual meshes keep
  ``CellOptions.visual_mesh_detail`` of their triangles (the gripper ``GRIPPER_DETAIL_FACTOR``
  times more), which makes a camera frame about 5x cheaper to render on CPU; collision meshes,
  masses and so the dynamics are exactly those of the original meshes.

The robot faces +y: the Menagerie ``home`` keyframe (-pi/2, -pi/2, pi/2, -pi/2, -pi/2, 0) hovers
the gripper over the table, and ``sim.layouts`` places cubes in front of it.
"""
from __future__ import annotations

from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path
from typing import Any, Sequence

import mujoco
import numpy as np

from runtime.app.disk_cache import cached_file, content_key
from sim.render_meshes import simplify_visual_meshes
from sim.robot_model import FT_SITE, GRIPPER_PREFIX, build_robot_spec, mesh_files, robot_xml
from runtime.errors import OptionError

CUBE_COLORS: dict[str, tuple[float, float, float, float]] = {
    "red": (0.85, 0.1, 0.1, 1.0),
    "green": (0.1, 0.7, 0.15, 1.0),
    "blue": (0.1, 0.25, 0.85, 1.0),
}
"""The cubes, in a fixed order (layouts and published topics follow it)."""

CAMERA_NAMES: tuple[str, ...] = ("scene", "wrist", "overview")
CAMERA_FOVY_DEG: dict[str, float] = {"scene": 50.0, "wrist": 70.0, "overview": 55.0}
"""Vertical field of view of each camera (degrees), as MuJoCo's ``fovy``."""

TABLE_TOP_Z = 0.0
TABLE_HALF_SIZE = (0.6, 0.55, 0.02)
TABLE_CENTER_XY = (0.0, 0.3)
"""The table spans x in [-0.6, 0.6] and y in [-0.25, 0.85]; its top is z = 0."""

DEFAULT_VISUAL_MESH_DETAIL = 0.1
"""10% of the arm's visual triangles, 25% of the gripper's: 193k -> 31k triangles drawn, a
224x224 frame in ~2.6 ms instead of ~13 ms on llvmpipe, mean pixel change < 2/255."""
GRIPPER_DETAIL_FACTOR = 2.5
ARM_WELD_TOLERANCE = 1e-3
GRIPPER_WELD_TOLERANCE = 2e-4
"""Vertices closer than this (metres) merge before simplifying. A pixel of the scene and
overview cameras covers 3-6 mm at the arm, one of the wrist camera 0.3-1 mm at the fingers."""

HOME_CONFIGURATION: tuple[float, ...] = (-1.5708, -1.5708, 1.5708, -1.5708, -1.5708, 0.0)
"""Where the arm starts after a reset (the Menagerie ``home`` keyframe, gripper above the table)."""



IMAGE_SIZES_PX = (16, 4096)
"""The camera image sizes (width, height, in pixels) a cell renders."""


def image_size_problem(value: Any) -> str | None:
    """What is wrong with ``value`` as a camera image width or height, or None."""
    low, high = IMAGE_SIZES_PX
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        return f"{value!r}: must be an integer in [{low}, {high}]"
    return None


@dataclass(frozen=True)
class CellOptions:
    """What can vary between cells. Defaults are the reference cell."""

    cube_size: float = 0.03
    cube_mass: float = 0.04
    cube_friction: float = 1.0
    image_width: int = 224
    image_height: int = 224
    timestep: float = 0.002
    visual_mesh_detail: float = DEFAULT_VISUAL_MESH_DETAIL
    """Fraction of the robot's visual-mesh triangles kept for drawing (1.0: the original meshes).
    The gripper keeps ``GRIPPER_DETAIL_FACTOR`` times more, since the wrist camera sees it up close."""

    def __post_init__(self) -> None:
        if not 0.01 <= self.cube_size <= 0.06:
            raise OptionError(f"cube_size {self.cube_size} m: must be in [0.01, 0.06] for the 2F-85 to grasp it")
        if self.cube_mass <= 0:
            raise OptionError(f"cube_mass {self.cube_mass} kg: must be positive")
        if self.cube_friction <= 0:
            raise OptionError(f"cube_friction {self.cube_friction}: must be positive")
        for name in ("image_width", "image_height"):
            problem = image_size_problem(getattr(self, name))
            if problem is not None:
                raise OptionError(f"{name} {problem}")
        if not 0 < self.timestep <= 0.005:
            raise OptionError(f"timestep {self.timestep} s: must be in (0, 0.005]")
        detail = self.visual_mesh_detail
        if isinstance(detail, bool) or not isinstance(detail, (int, float)) or not 0.01 <= detail <= 1.0:
            raise OptionError(
                f"visual_mesh_detail {self.visual_mesh_detail!r}: must be a fraction of triangles in "
                "[0.01, 1.0] (1.0 draws the original meshes)"
            )


def cube_body_name(color: str) -> str:
    return f"cube_{color}"


def build_cell_spec(options: CellOptions | None = None) -> mujoco.MjSpec:
    """The whole cell as an uncompiled spec (compile with ``spec.compile()``)."""
    options = options or CellOptions()
    spec = build_robot_spec()
    spec.modelname = "vla_sim_cell"
    spec.option.timestep = options.timestep
    # Resting cubes sleep (MuJoCo skips their dynamics and contacts until something awake touches
    # them); the actuated arm and gripper never do. A third less physics per step over a stacking
    # run, in which two cubes rest most of the time (docs/cell.md, "Resting cubes sleep").
    spec.option.enableflags |= mujoco.mjtEnableBit.mjENBL_SLEEP
    _configure_rendering(spec, options)
    _add_lights(spec)
    _add_table(spec)
    for color, rgba in CUBE_COLORS.items():
        _add_cube(spec, color, rgba, options)
    for slot in range(SIM_BOX_SLOTS):
        _add_box_slot(spec, slot)
    _add_cameras(spec)
    _add_ft_sensor(spec)
    if options.visual_mesh_detail < 1.0:
        simplify_visual_meshes(
            spec,
            keep=lambda mesh: _visual_mesh_keep(mesh, options.visual_mesh_detail),
            tolerance=lambda mesh: GRIPPER_WELD_TOLERANCE if mesh.startswith(GRIPPER_PREFIX) else ARM_WELD_TOLERANCE,
        )
    return spec


def compile_cell(options: CellOptions | None = None) -> mujoco.MjModel:
    """``build_cell_spec(options).compile()``, from the on-disk cache (a MuJoCo binary model)
    when the robot's MJCF, its mesh files, ``options``, the sim package's source and the
    libraries' versions are what they were: compiling processes every mesh (~1-2 s)."""
    options = options or CellOptions()
    xml = robot_xml()
    sources = sorted(Path(__file__).resolve().parent.glob("*.py"))
    key = content_key(xml, repr(options), mujoco.__version__, version("fast-simplification"), np.__version__,
                      *(str(p) for p in mesh_files(xml)), *mesh_files(xml), *sources)
    return cached_file("cell_mjb", key, lambda: _to_mjb(build_cell_spec(options).compile()), mujoco.MjModel.from_binary_path)


def _to_mjb(model: mujoco.MjModel) -> bytes:
    buffer = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return buffer.tobytes()


def _visual_mesh_keep(mesh: str, detail: float) -> float:
    if mesh.startswith(GRIPPER_PREFIX):
        return min(1.0, GRIPPER_DETAIL_FACTOR * detail)
    return detail


FT_FORCE_SENSOR = "wrist_ft_force"
FT_TORQUE_SENSOR = "wrist_ft_torque"


def _add_ft_sensor(spec: mujoco.MjSpec) -> None:
    """Force and torque at the gripper mount: what the gripper (and anything it touches) exerts."""
    for name, kind in ((FT_FORCE_SENSOR, mujoco.mjtSensor.mjSENS_FORCE), (FT_TORQUE_SENSOR, mujoco.mjtSensor.mjSENS_TORQUE)):
        sensor = spec.add_sensor()
        sensor.name = name
        sensor.type = kind
        sensor.objtype = mujoco.mjtObj.mjOBJ_SITE
        sensor.objname = FT_SITE


def _configure_rendering(spec: mujoco.MjSpec, options: CellOptions) -> None:
    spec.visual.global_.offwidth = max(options.image_width, 640)
    spec.visual.global_.offheight = max(options.image_height, 480)
    spec.visual.quality.offsamples = 0
    spec.visual.quality.shadowsize = 0
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.4, 0.4, 0.4]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    for light in spec.lights:  # the robot models may bring their own lights
        light.castshadow = False


def _add_lights(spec: mujoco.MjSpec) -> None:
    light = spec.worldbody.add_light()
    light.name = "cell_light"
    light.type = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
    light.pos = [0.0, 0.3, 2.0]
    light.dir = [0.0, 0.2, -1.0]
    light.diffuse = [0.6, 0.6, 0.6]
    light.specular = [0.0, 0.0, 0.0]
    light.castshadow = False


def _add_table(spec: mujoco.MjSpec) -> None:
    wood = spec.add_material()
    wood.name = "table_top"
    wood.rgba = [0.72, 0.62, 0.48, 1.0]
    wood.specular = 0.0
    wood.shininess = 0.0
    wood.reflectance = 0.0

    hx, hy, hz = TABLE_HALF_SIZE
    table = spec.worldbody.add_body()
    table.name = "table"
    table.pos = [TABLE_CENTER_XY[0], TABLE_CENTER_XY[1], TABLE_TOP_Z - hz]
    top = table.add_geom()
    top.name = "table"
    top.type = mujoco.mjtGeom.mjGEOM_BOX
    top.size = [hx, hy, hz]
    top.material = "table_top"
    top.friction = [0.8, 0.005, 0.0001]
    leg_height = 0.73
    for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        leg = table.add_geom()  # visual only: nothing reaches below the top
        leg.name = f"table_leg_{i}"
        leg.type = mujoco.mjtGeom.mjGEOM_BOX
        leg.size = [0.03, 0.03, leg_height / 2]
        leg.pos = [sx * (hx - 0.05), sy * (hy - 0.05), -hz - leg_height / 2]
        leg.rgba = [0.35, 0.3, 0.25, 1.0]
        leg.contype = 0
        leg.conaffinity = 0
    floor = spec.worldbody.add_geom()
    floor.name = "floor"
    floor.type = mujoco.mjtGeom.mjGEOM_PLANE
    floor.size = [3.0, 3.0, 0.1]
    floor.pos = [0.0, 0.0, TABLE_TOP_Z - 2 * hz - leg_height]
    floor.rgba = [0.5, 0.52, 0.55, 1.0]
    floor.contype = 0
    floor.conaffinity = 0


def _add_cube(spec: mujoco.MjSpec, color: str, rgba: tuple[float, ...], options: CellOptions) -> None:
    half = options.cube_size / 2
    body = spec.worldbody.add_body()
    body.name = cube_body_name(color)
    body.pos = [0.0, 0.45, TABLE_TOP_Z + half]  # placed properly by Cell.reset
    joint = body.add_freejoint()
    joint.name = f"{body.name}_joint"
    geom = body.add_geom()
    geom.name = body.name
    geom.type = mujoco.mjtGeom.mjGEOM_BOX
    geom.size = [half, half, half]
    geom.mass = options.cube_mass
    geom.rgba = list(rgba)
    # condim 4 adds torsional friction, so a grasped cube does not spin about the pad normal.
    geom.condim = 4
    geom.friction = [options.cube_friction, 0.01, 0.0001]
    geom.solref = [0.004, 1.0]
    geom.solimp = [0.95, 0.99, 0.001, 0.5, 2.0]


SIM_BOX_SLOTS = 4
"""How many boxes a run can place in the MuJoCo cell at once."""
SIM_BOX_PARKED_Z = -5.0
"""Metres: where an unused box slot waits (below the floor, without contacts, transparent)."""
SIM_BOX_RGBA = (0.95, 0.55, 0.1, 1.0)


def box_slot_name(slot: int) -> str:
    return f"sim_box_{slot}"


def _add_box_slot(spec: mujoco.MjSpec, slot: int) -> None:
    body = spec.worldbody.add_body()
    body.name = box_slot_name(slot)
    body.mocap = True  # fixed in the world, moved only by the run: it pushes, nothing pushes it
    body.pos = [0.0, 0.0, SIM_BOX_PARKED_Z]
    geom = body.add_geom()
    geom.name = body.name
    geom.type = mujoco.mjtGeom.mjGEOM_BOX
    geom.size = [0.01, 0.01, 0.01]
    geom.rgba = [*SIM_BOX_RGBA[:3], 0.0]
    geom.contype = 0
    geom.conaffinity = 0


def look_at_quat(pos: np.ndarray, target: np.ndarray | Sequence[float], up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """Quaternion (w, x, y, z) of a MuJoCo camera at ``pos`` looking at ``target``.

    A MuJoCo camera looks along its -z axis with +y up in the image.
    """
    forward = np.asarray(target, float) - np.asarray(pos, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:
        raise ValueError(f"camera at {pos} looks straight along the up vector {up}: pick another up")
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    rotation = np.column_stack([right, cam_up, -forward])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, rotation.flatten())
    return quat


def _add_cameras(spec: mujoco.MjSpec) -> None:
    workspace = np.array([0.0, 0.45, 0.0])

    scene = spec.worldbody.add_camera()
    scene.name = "scene"
    scene.pos = [0.0, 1.35, 0.55]
    scene.quat = look_at_quat(np.array(scene.pos), workspace + [0.0, -0.05, 0.05])
    scene.fovy = CAMERA_FOVY_DEG["scene"]

    overview = spec.worldbody.add_camera()
    overview.name = "overview"
    overview.pos = [0.0, 0.42, 1.25]
    overview.quat = look_at_quat(np.array(overview.pos), [0.0, 0.42, 0.0], up=np.array([0.0, 1.0, 0.0]))
    overview.fovy = CAMERA_FOVY_DEG["overview"]

    # On the gripper body (z along the fingers, fingers opening along y): offset sideways along x
    # and tilted toward the fingertips, like a camera on a wrist bracket.
    gripper = spec.body(GRIPPER_PREFIX + "base")
    wrist = gripper.add_camera()
    wrist.name = "wrist"
    wrist.pos = [0.075, 0.0, 0.02]
    wrist.quat = look_at_quat(np.array([0.075, 0.0, 0.02]), np.array([0.0, 0.0, 0.2]), up=np.array([1.0, 0.0, 0.0]))
    wrist.fovy = CAMERA_FOVY_DEG["wrist"]
