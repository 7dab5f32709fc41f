"""Lighter copies of the robot's visual meshes, so camera frames render fast on a CPU.

The Menagerie UR5e and 2F-85 visual geoms draw about 193k triangles, far more than a 224x224
camera can show: the arm spans a few hundred pixels, so most triangles cover less than a pixel.
With software OpenGL (Mesa llvmpipe) the time of a frame grows with the triangles drawn, and
these meshes make up almost all of it. This module replaces them by simplified copies, for
drawing only:

1. ``load_mesh_file``: the mesh as MuJoCo reads it (scale applied), in the file's own frame.
2. ``weld``: merges vertices closer than a sub-pixel tolerance. The UR5e OBJ files repeat every
   vertex once per triangle, and the CAD exports are full of needle-thin triangles; both stop a
   quadric simplifier from collapsing edges, and welding removes both.
3. ``decimate``: quadric edge collapse (``fast-simplification``, the Fast-Quadric-Mesh-
   Simplification library) down to a fraction of the original triangle count.
4. ``simplify_visual_meshes``: swaps the result into an ``MjSpec`` for the geoms that are only
   drawn (no contacts, no mass).

Dynamics cannot change: every collision geom keeps its mesh, and every body its mass and
inertia (see ``simplify_visual_meshes`` for how shared and mass-giving meshes are handled).
Simplifying all the cell's meshes takes about 0.25 s of CPU, once per machine: the results are
kept in the on-disk cache (``simplified_mesh``).
"""
from __future__ import annotations

import functools
import io
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path
from typing import Callable

import fast_simplification
import mujoco
import numpy as np

from runtime.app.disk_cache import cached, content_key

VISUAL_SUFFIX = "_visual"
"""Name suffix of the simplified copy of a mesh that collision geoms also use."""


@dataclass(frozen=True)
class MeshReduction:
    """What ``simplify_visual_meshes`` did to one mesh."""

    mesh: str  # the mesh that the drawn geoms use now
    source: str  # the mesh it was made from (the same name when it was replaced in place)
    faces_before: int
    faces_after: int


def load_mesh_file(path: str, scale: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3, metres, scale applied) and triangles (m, 3) of a mesh file (OBJ, STL, MSH).

    MuJoCo reads the file (so every format it supports works), then moves the vertices to the
    mesh's centre of mass and principal axes; that move is undone here, because a mesh set from
    vertices gets the same move again when it is compiled.
    """
    spec = mujoco.MjSpec()
    mesh = spec.add_mesh()
    mesh.name = "mesh"
    mesh.file = path
    mesh.scale = list(scale)
    model = spec.compile()
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.mesh_quat[0])
    vertices = model.mesh_vert.astype(np.float64) @ rotation.reshape(3, 3).T + model.mesh_pos[0]
    return vertices, model.mesh_face.astype(np.int64)


def weld(vertices: np.ndarray, faces: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Merges the vertices that fall in one cube of side ``tolerance`` into their mean.

    Triangles that lose a corner this way, and repeats of a triangle, are dropped, and so are
    vertices no triangle uses. Identical vertices always merge, whatever the tolerance.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if tolerance <= 0:
        raise ValueError(f"weld tolerance {tolerance}: must be positive")
    cell = np.floor((vertices - vertices.min(axis=0)) / tolerance).astype(np.int64)
    dims = cell.max(axis=0) + 1
    if float(dims[0]) * float(dims[1]) * float(dims[2]) >= 2.0**62:
        raise ValueError(f"weld tolerance {tolerance}: too small for a mesh {np.ptp(vertices, axis=0)} m across")
    cluster, n = _group((cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2])
    merged = np.column_stack([np.bincount(cluster, weights=vertices[:, k], minlength=n) for k in range(3)])
    merged /= np.bincount(cluster, minlength=n)[:, None]  # type: ignore[misc]  # numpy's stub: bincount with weights is float64, not intp

    faces = cluster[faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    corners = np.sort(faces, axis=1)
    _, first = np.unique((corners[:, 0] * n + corners[:, 1]) * n + corners[:, 2], return_index=True)
    faces = faces[np.sort(first)]

    used = np.zeros(n, dtype=bool)
    used[faces.ravel()] = True
    renumber = np.cumsum(used) - 1
    return merged[used], renumber[faces]


def _group(keys: np.ndarray) -> tuple[np.ndarray, int]:
    """Numbers equal keys alike, 0..n-1: ``np.unique(keys, return_inverse=True)`` without its
    stable sort, which is the slow part on the ~60k vertices of a UR5e link."""
    order = np.argsort(keys)
    ordered = keys[order]
    ids = np.empty(len(keys), dtype=np.int64)
    ids[order] = np.concatenate([[0], np.cumsum(ordered[1:] != ordered[:-1])])
    return ids, int(ids.max()) + 1 if len(ids) else 0


def decimate(vertices: np.ndarray, faces: np.ndarray, target_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadric edge collapse down to about ``target_faces`` triangles (at least 4).

    The simplifier's error threshold is absolute, so the mesh is scaled to a unit diagonal
    first: a small part and a long one are then simplified equally carefully. On meshes with
    many needle-thin triangles it may stop above the target (``weld`` them first).
    """
    target = max(4, int(target_faces))
    if target >= len(faces):
        return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    low = vertices.min(axis=0)
    size = float(np.linalg.norm(vertices.max(axis=0) - low)) or 1.0
    points, triangles = fast_simplification.simplify((vertices - low) / size, faces, target_count=target)
    return points * size + low, triangles


@dataclass(frozen=True)
class SimplifiedMesh:
    vertices: np.ndarray  # (n, 3) metres, in the mesh file's frame, read-only
    faces: np.ndarray  # (m, 3) vertex indices, read-only
    original_faces: int


@functools.lru_cache(maxsize=None)
def simplified_mesh(path: str, scale: tuple[float, float, float], keep: float, tolerance: float) -> SimplifiedMesh:
    """``decimate(weld(load_mesh_file(path, scale), tolerance), keep)``, once per process, and
    from the on-disk cache (``runtime.app.disk_cache``) when the mesh file's bytes, the settings,
    the libraries' versions and this module are what they were.

    The arrays are read-only: every cell built in this process shares them.
    """
    if not 0 < keep <= 1:
        raise ValueError(f"keep {keep}: must be a fraction of triangles in (0, 1]")
    key = content_key(Path(path), repr((tuple(scale), keep, tolerance)), mujoco.__version__,
                      version("fast-simplification"), np.__version__, Path(__file__))
    return cached("visual_mesh", key, lambda: _npz(_simplify(path, scale, keep, tolerance)), _from_npz)


def _simplify(path: str, scale: tuple[float, float, float], keep: float, tolerance: float) -> SimplifiedMesh:
    original = load_mesh_file(path, scale)
    original_faces = len(original[1])
    vertices, faces = decimate(*weld(*original, tolerance), round(keep * original_faces))
    if len(faces) < 4:  # a part smaller than the tolerance: keep it as it is
        vertices, faces = original
    return SimplifiedMesh(vertices, faces, original_faces)


def _npz(mesh: SimplifiedMesh) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, vertices=mesh.vertices, faces=mesh.faces, original_faces=np.array(mesh.original_faces))
    return buffer.getvalue()


def _from_npz(data: bytes) -> SimplifiedMesh:
    with np.load(io.BytesIO(data), allow_pickle=False) as arrays:
        vertices, faces = np.array(arrays["vertices"], dtype=float), np.array(arrays["faces"])
        original_faces = int(arrays["original_faces"])
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError("a simplified mesh needs (n, 3) vertices and (m, 3) faces")
    vertices.setflags(write=False)
    faces.setflags(write=False)
    return SimplifiedMesh(vertices, faces, original_faces)


def _gives_mass(spec: mujoco.MjSpec, geom: mujoco.MjsGeom) -> bool:
    """Whether the compiler takes ``geom`` into its body's mass and inertia."""
    mode = spec.compiler.inertiafromgeom
    low, high = spec.compiler.inertiagrouprange
    if mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE or not low <= geom.group <= high:
        return False
    if mode == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE:
        return True
    return not geom.parent.explicitinertial


def simplify_visual_meshes(
    spec: mujoco.MjSpec, keep: Callable[[str], float], tolerance: Callable[[str], float]
) -> list[MeshReduction]:
    """Draws the robot's visual mesh geoms with simplified meshes; edits ``spec`` in place.

    ``keep(mesh_name)`` is the fraction of triangles to keep (1.0 leaves the mesh alone) and
    ``tolerance(mesh_name)`` the weld distance in metres (below what a camera resolves).
    Only geoms with ``contype == conaffinity == 0`` change, and only what is drawn changes:

    - a mesh that only such geoms use is replaced (its file is dropped);
    - a mesh that a collision geom also uses keeps its data for it; the visual geoms get a
      simplified copy named ``<name>_visual``;
    - a visual geom that gives its body mass (a body without ``<inertial>``) keeps its mesh and
      its mass but moves to the hidden group ``HIDDEN_GROUP``; a massless copy of it draws the
      simplified mesh in its place.

    Returns one ``MeshReduction`` per mesh simplified.
    """
    visual: dict[str, list[tuple[mujoco.MjsGeom, bool]]] = {}  # mesh: [(geom, gives mass)]
    needed: set[str] = set()  # meshes that some geom needs unchanged, for contacts or mass
    for geom in spec.geoms:
        if geom.type != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        if geom.contype or geom.conaffinity:
            needed.add(geom.meshname)
            continue
        gives_mass = _gives_mass(spec, geom)
        if gives_mass:
            needed.add(geom.meshname)
            if not _can_hide(spec, geom):
                continue
        visual.setdefault(geom.meshname, []).append((geom, gives_mass))

    reductions = []
    for name, geoms in visual.items():
        fraction = keep(name)
        source = spec.mesh(name)
        if fraction >= 1.0 or not source.file:  # a mesh given by vertices is left as its author made it
            continue
        simplified = simplified_mesh(source.file, tuple(float(s) for s in source.scale), fraction, tolerance(name))
        if name in needed:
            target = spec.add_mesh()
            target.name = name + VISUAL_SUFFIX
            for geom, gives_mass in geoms:
                drawn = _massless_copy(geom) if gives_mass else geom
                drawn.meshname = target.name
        else:
            target = source
            target.file = ""
        target.scale = [1.0, 1.0, 1.0]
        target.uservert = simplified.vertices.ravel()
        target.userface = simplified.faces.ravel()
        reductions.append(MeshReduction(target.name, name, simplified.original_faces, len(simplified.faces)))
    return reductions


HIDDEN_GROUP = 3
"""Where a mass-giving visual geom goes when a copy draws it: viewers and ``mujoco.Renderer``
hide geom groups 3-5 by default, and the Menagerie puts its collision geoms there too."""


def _can_hide(spec: mujoco.MjSpec, geom: mujoco.MjsGeom) -> bool:
    """Whether ``geom`` can move to ``HIDDEN_GROUP`` and keep its mass (the group counts for
    inertia), and ``_massless_copy`` can place a copy exactly on it (pose given as pos + quat)."""
    low, high = spec.compiler.inertiagrouprange
    return (
        low <= HIDDEN_GROUP <= high
        and geom.frame is None
        and geom.alt.type == mujoco.mjtOrientation.mjORIENTATION_QUAT
    )


def _massless_copy(geom: mujoco.MjsGeom) -> mujoco.MjsGeom:
    """Hides ``geom`` and returns a new geom of its body that draws it instead, with no mass."""
    copy = geom.parent.add_geom()
    copy.type = geom.type
    copy.meshname = geom.meshname
    copy.pos = geom.pos
    copy.quat = geom.quat
    copy.material = geom.material
    copy.rgba = geom.rgba
    copy.group = geom.group
    copy.contype = 0
    copy.conaffinity = 0
    copy.mass = 0.0
    geom.group = HIDDEN_GROUP
    return copy
