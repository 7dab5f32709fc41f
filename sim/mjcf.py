"""Load a MuJoCo MJCF robot into pinocchio (kinematics) and coal (collision geometry).

``pin.buildModelFromMJCF`` reads the Menagerie files without complaint but gets them wrong
in three silent ways (measured against MuJoCo's own kinematics); each has a fix here:

1. Attributes inherited from ``<default class>`` are dropped (mesh scale, geom and joint
   positions): we flatten the defaults with MjSpec, setting every element's class to the
   top default, so the XML written back spells every value out on the element itself.
2. The top-level body's pos/quat is dropped (forward kinematics off by the base placement):
   we write the root body at the identity and graft the model onto the world with
   ``pin.appendModel`` at the placement MuJoCo compiled (``body_pos``, ``body_quat``).
3. Frame names must be unique across bodies, joints and sites in pinocchio (``appendModel``
   refuses duplicates), while MuJoCo only needs them unique per element kind: a joint or site
   whose name is also another element's name gets the prefix ``joint_`` / ``site_``.

Two more traps handled here: MjSpec writes ``<frame>`` elements for attached models
(``MjSpec.attach``), which pinocchio's parser skips with everything inside; and ``to_xml``
prints 6 significant digits, which puts FK 3e-9 m off. Both go away by writing every body,
joint and geom placement from the compiled MuJoCo model at full precision. A fourth: sites on
bodies without joints are placed relative to the wrong frame by pinocchio (the Menagerie
``pinch`` site 26 cm off), so sites are added as frames here from MuJoCo's values.
"""
from __future__ import annotations

import json
import os
import tempfile
from dataclasses import asdict, dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Iterable

import coal
import mujoco
import numpy as np
import pinocchio as pin
from lxml import etree

from runtime.app.disk_cache import cached, cached_file, content_key
from runtime.motion.scene import hulls
from runtime.motion.scene.hulls import geometry_bytes, load_geometry, with_convex_hulls
from runtime.motion.scene.model import JointCoupling, RobotModel
from runtime.motion.scene.srdf import Srdf


@dataclass(frozen=True)
class MjcfRobot:
    """What ``load_mjcf`` produces: pinocchio model, collision geometry and MuJoCo facts."""

    model: pin.Model
    collision_model: pin.GeometryModel
    """Collision geometry, every mesh as its convex hull (``runtime.motion.scene.hulls``)."""
    body_parents: dict[str, str]
    """Parent body of every robot body (the root's parent is ``"universe"``)."""
    renamed: dict[str, str]
    """Original name -> frame name, for joints/sites renamed to keep frame names unique."""


def spec_from_source(source: str | os.PathLike | mujoco.MjSpec) -> mujoco.MjSpec:
    """A private MjSpec copy from a spec, an MJCF file path, or an MJCF XML string."""
    if isinstance(source, mujoco.MjSpec):
        return source.copy()
    text = str(source)
    if text.lstrip().startswith("<"):
        return mujoco.MjSpec.from_string(text)
    path = Path(text)
    if not path.is_file():
        raise FileNotFoundError(f"MJCF file not found: {path}")
    return mujoco.MjSpec.from_file(str(path))


def _absolute_mesh_paths(spec: mujoco.MjSpec) -> None:
    base = Path(spec.modelfiledir or os.getcwd()) / (spec.meshdir or "")
    for mesh in spec.meshes:
        if mesh.file and not os.path.isabs(mesh.file):
            mesh.file = str((base / mesh.file).resolve())
    spec.meshdir = ""


def _keep_only_robot(spec: mujoco.MjSpec, root_body: str | None) -> mujoco.MjsBody:
    """Strip everything but the robot's kinematic tree; return its root body."""
    top = [b for b in spec.worldbody.bodies]
    if root_body is None:
        if len(top) != 1:
            names = ", ".join(b.name or "<unnamed>" for b in top)
            raise ValueError(
                f"MJCF has {len(top)} top-level bodies ({names}); pass root_body= to name the robot's"
            )
        root = top[0]
    else:
        matches = [b for b in top if b.name == root_body]
        if not matches:
            names = ", ".join(b.name or "<unnamed>" for b in top)
            raise ValueError(f"root_body {root_body!r} is not a top-level body of the MJCF (found: {names})")
        root = matches[0]
    # Sensors, actuators, constraints and keyframes refer to elements we may delete and do not
    # matter for kinematics or collision; the gripper's closed linkage is handled by coupling.
    for collection in (spec.keys, spec.sensors, spec.actuators, spec.equalities, spec.tendons,
                       spec.excludes, spec.pairs, spec.cameras, spec.lights):
        for element in list(collection):
            spec.delete(element)
    for body in top:
        if body is not root:
            spec.delete(body)
    for geom in list(spec.worldbody.geoms):
        spec.delete(geom)
    for site in list(spec.worldbody.sites):
        spec.delete(site)
    return root


def _flatten_defaults(spec: mujoco.MjSpec) -> None:
    top = spec.default
    for collection in (spec.bodies, spec.geoms, spec.joints, spec.sites, spec.meshes,
                       spec.materials, spec.frames):
        for element in collection:
            if hasattr(element, "classname"):
                element.classname = top
            if hasattr(element, "childclass"):
                element.childclass = ""


def _unique_frame_names(spec: mujoco.MjSpec) -> dict[str, str]:
    bodies = {b.name for b in spec.bodies if b.name}
    renamed: dict[str, str] = {}
    taken = set(bodies)
    for prefix, collection in (("joint_", spec.joints), ("site_", spec.sites)):
        for element in collection:
            if element.name and element.name in taken:
                new = prefix + element.name
                renamed[element.name] = new
                element.name = new
            taken.add(element.name)
    return renamed


def _name_unnamed(spec: mujoco.MjSpec) -> None:
    """Give every body, joint, geom and site a name so XML elements map to compiled ids.

    Unnamed geoms get pinocchio's own naming scheme (``<body>Geom_<k>``, k counting every geom
    of the body), so names in the geometry model are the same as without this step.
    """
    for i, body in enumerate(spec.bodies):
        if body is spec.worldbody:
            continue
        if not body.name:
            body.name = f"body_{i}"
    for body in spec.bodies:
        if body is spec.worldbody:
            continue
        for k, geom in enumerate(body.geoms):
            if not geom.name:
                geom.name = f"{body.name}Geom_{k}"
        for k, joint in enumerate(body.joints):
            if not joint.name:
                joint.name = f"{body.name}_joint_{k}"
        for k, site in enumerate(body.sites):
            if not site.name:
                site.name = f"{body.name}_site_{k}"


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _exact_xml(xml: str, compiled: mujoco.MjModel, root_name: str) -> str:
    """Rewrite placements in ``xml`` with the compiled model's values, at full precision.

    ``MjSpec.to_xml`` prints 6 significant digits (``0.707107``), which alone puts forward
    kinematics 3e-9 m off MuJoCo. Compiled values are relative to the parent body with every
    ``<frame>`` already folded in, so frames are simply unwrapped. The root body is written at
    the identity: pinocchio would drop its placement anyway (``load_mjcf`` re-applies it).
    """
    root = etree.fromstring(xml.encode())
    for frame in list(root.iter("frame")):
        parent = frame.getparent()
        index = parent.index(frame)
        for child in list(frame):
            parent.insert(index, child)
            index += 1
        parent.remove(frame)

    def ident(kind: mujoco.mjtObj, element) -> int:
        name = element.get("name")
        index = mujoco.mj_name2id(compiled, kind, name) if name else -1
        if index < 0:
            raise ValueError(f"MJCF <{element.tag} name={name!r}> has no counterpart in the compiled model")
        return index

    world = root.find("worldbody")
    for element in world.iter("body"):
        i = ident(mujoco.mjtObj.mjOBJ_BODY, element)
        at_root = element.get("name") == root_name
        element.set("pos", "0 0 0" if at_root else _fmt(compiled.body_pos[i]))
        element.set("quat", "1 0 0 0" if at_root else _fmt(compiled.body_quat[i]))
    for element in world.iter("joint"):
        i = ident(mujoco.mjtObj.mjOBJ_JOINT, element)
        element.set("pos", _fmt(compiled.jnt_pos[i]))
        element.set("axis", _fmt(compiled.jnt_axis[i]))
    for element in list(world.iter("site")):
        element.getparent().remove(element)  # added by _add_sites: pinocchio misplaces them
    for element in world.iter("geom"):
        i = ident(mujoco.mjtObj.mjOBJ_GEOM, element)
        placement = _se3(compiled.geom_pos[i], compiled.geom_quat[i])
        if compiled.geom_type[i] == mujoco.mjtGeom.mjGEOM_MESH:
            # MuJoCo re-centres mesh vertices on their inertial frame and moves the geom by
            # the same offset; pinocchio reads the file as is, so undo the offset here.
            mesh = compiled.geom_dataid[i]
            placement = placement * _se3(compiled.mesh_pos[mesh], compiled.mesh_quat[mesh]).inverse()
        else:
            size = compiled.geom_size[i]
            count = {mujoco.mjtGeom.mjGEOM_SPHERE: 1, mujoco.mjtGeom.mjGEOM_CAPSULE: 2,
                     mujoco.mjtGeom.mjGEOM_CYLINDER: 2}.get(int(compiled.geom_type[i]), 3)
            element.set("size", _fmt(size[:count]))
        element.attrib.pop("fromto", None)
        element.set("pos", _fmt(placement.translation))
        element.set("quat", _fmt(pin.Quaternion(placement.rotation).coeffs()[[3, 0, 1, 2]]))
    return etree.tostring(root, encoding="unicode")


def _site_frames(compiled: mujoco.MjModel) -> list[tuple[str, str, list[float], list[float]]]:
    """``(site, body, pos, quat wxyz)`` of every site, from MuJoCo's compiled values."""
    return [(compiled.site(i).name, compiled.body(int(compiled.site_bodyid[i])).name,
             [float(v) for v in compiled.site_pos[i]], [float(v) for v in compiled.site_quat[i]])
            for i in range(compiled.nsite)]


def _add_sites(model: pin.Model, sites: list[tuple[str, str, list[float], list[float]]]) -> None:
    """Sites as OP_FRAMEs on their body's frame.

    pinocchio's own parser places a site on a body without joints (merged into its parent as a
    fixed frame) relative to the wrong frame: the Menagerie ``pinch`` site lands 26 cm off.
    """
    for name, body, pos, quat in sites:
        parent = model.getFrameId(body, pin.FrameType.BODY)
        frame = model.frames[parent]
        placement = frame.placement * _se3(np.array(pos), np.array(quat))
        model.addFrame(pin.Frame(name, frame.parentJoint, parent, placement, pin.FrameType.OP_FRAME))


def _se3(pos: np.ndarray, quat_wxyz: np.ndarray) -> pin.SE3:
    w, x, y, z = quat_wxyz
    return pin.SE3(pin.Quaternion(w, x, y, z).normalized().toRotationMatrix(), np.asarray(pos, float))


@dataclass(frozen=True)
class _MujocoFacts:
    """What loading needs from MuJoCo's compiler (JSON-able, so the disk cache can keep it)."""

    xml: str
    """The robot alone, defaults flattened, placements exact (what pinocchio parses)."""
    root_pos: list[float]
    root_quat: list[float]
    body_parents: dict[str, str]
    renamed: dict[str, str]
    sites: list[tuple[str, str, list[float], list[float]]]


def load_mjcf(source: str | os.PathLike | mujoco.MjSpec, root_body: str | None = None) -> MjcfRobot:
    """Load the robot rooted at ``root_body`` (default: the only top-level body) of an MJCF.

    ``source`` is an ``MjSpec`` (copied, never modified), an MJCF file path or an XML string.
    MuJoCo's part (a compile: ~1 s with meshes) comes from the on-disk cache
    (``runtime.app.disk_cache``) when the MJCF text, its mesh files, ``root_body``, this module and
    MuJoCo's version are what they were; so does the collision geometry (meshes loaded by
    assimp, hulls built by qhull: ~0.3 s), keyed by the same and the versions of pinocchio, coal,
    assimp and qhull.
    An ``MjSpec`` or an MJCF with ``<include>`` is always compiled.
    """
    spec = spec_from_source(source)
    _absolute_mesh_paths(spec)
    key = _facts_key(source, spec, root_body)
    if key is None:
        facts = _compile_facts(spec, root_body)
    else:
        facts = cached("mjcf_facts", key, lambda: json.dumps(asdict(_compile_facts(spec, root_body))).encode(),
                       lambda data: _MujocoFacts(**json.loads(data)))
    root_placement = _se3(np.array(facts.root_pos), np.array(facts.root_quat))
    with tempfile.TemporaryDirectory(prefix="mjcf_") as tmp:
        path = os.path.join(tmp, "robot.xml")
        with open(path, "w") as f:
            f.write(facts.xml)
        robot = pin.buildModelFromMJCF(path)

        def hull_geometry() -> pin.GeometryModel:
            geometry = pin.buildGeomFromMJCF(robot, path, pin.COLLISION)
            _, appended = pin.appendModel(pin.Model(), robot, pin.GeometryModel(), geometry, 0, root_placement)
            return with_convex_hulls(appended)

        if key is None:
            collision_model = hull_geometry()
        else:
            collision_model = cached_file("collision_hulls", _hulls_key(key), lambda: geometry_bytes(hull_geometry()),
                                          load_geometry)
    model = pin.appendModel(pin.Model(), robot, 0, root_placement)
    model.name = robot.name
    _add_sites(model, facts.sites)
    return MjcfRobot(model=model, collision_model=collision_model, body_parents=facts.body_parents, renamed=facts.renamed)


def robot_model_from_mjcf(
    source: str | os.PathLike | mujoco.MjSpec,
    srdf: str | os.PathLike | Srdf | None = None,
    couplings: Iterable[JointCoupling] | str | os.PathLike = (),
    root_body: str | None = None,
) -> RobotModel:
    """The planning scene's robot from an MJCF (MjSpec, file or XML text), with its SRDF and couplings."""
    loaded = load_mjcf(source, root_body=root_body)
    return RobotModel.from_pinocchio(loaded.model, loaded.collision_model, srdf, couplings,
                                     source=_describe_source(source))


def _describe_source(source: object) -> str:
    if hasattr(source, "compile"):
        return "<MjSpec>"
    text = str(source)
    return "<MJCF text>" if text.lstrip().startswith("<") else text


def _hulls_key(facts_key: str) -> str:
    """The collision hulls follow from the MuJoCo facts (``facts_key``), pinocchio's MJCF
    parser, assimp, coal's qhull and the hull code."""
    return content_key(facts_key, pin.__version__, coal.__version__, _installed_version("cmeel-assimp"),
                       _installed_version("cmeel-qhull"), Path(hulls.__file__))


def _installed_version(distribution: str) -> str:
    """The version of an installed distribution; ``"absent"`` where the library came another way."""
    try:
        return version(distribution)
    except PackageNotFoundError:
        return "absent"


def _facts_key(source: str | os.PathLike | mujoco.MjSpec, spec: mujoco.MjSpec, root_body: str | None) -> str | None:
    if isinstance(source, mujoco.MjSpec):
        return None
    text = str(source)
    if not text.lstrip().startswith("<"):
        text = f"{Path(text).resolve()}\n{Path(text).read_text()}"
    if "<include" in text:
        return None
    meshes = sorted({mesh.file for mesh in spec.meshes if mesh.file})
    try:
        return content_key(text, repr(root_body), mujoco.__version__, Path(__file__), *meshes, *map(Path, meshes))
    except OSError:  # a missing mesh: let MuJoCo's compiler say so
        return None


def _compile_facts(spec: mujoco.MjSpec, root_body: str | None) -> _MujocoFacts:
    root = _keep_only_robot(spec, root_body)
    root_name = root.name
    renamed = _unique_frame_names(spec)
    _name_unnamed(spec)
    _flatten_defaults(spec)

    compiled = spec.compile()
    root_id = mujoco.mj_name2id(compiled, mujoco.mjtObj.mjOBJ_BODY, root_name)
    body_parents = {
        compiled.body(i).name: ("universe" if compiled.body_parentid[i] == 0 else compiled.body(int(compiled.body_parentid[i])).name)
        for i in range(1, compiled.nbody)
    }
    return _MujocoFacts(
        xml=_exact_xml(spec.to_xml(), compiled, root_name),
        root_pos=[float(v) for v in compiled.body_pos[root_id]],
        root_quat=[float(v) for v in compiled.body_quat[root_id]],
        body_parents=body_parents,
        renamed=renamed,
        sites=_site_frames(compiled),
    )
