"""The cold-start disk cache: keyed by content, atomic, recomputes damaged entries, and gives
the same robot, cell and planning model as building them from scratch."""
from __future__ import annotations

import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from runtime.app import disk_cache  # noqa: E402
from runtime.motion.scene import RobotModel  # noqa: E402
from sim.mjcf import robot_model_from_mjcf  # noqa: E402
from sim.cell_model import CellOptions, build_cell_spec, compile_cell  # noqa: E402
from sim.robot_model import COUPLINGS_PATH, SRDF_PATH, robot_xml  # noqa: E402


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(disk_cache.ENV_DIR, str(tmp_path))
    monkeypatch.delenv(disk_cache.ENV_SWITCH, raising=False)
    return tmp_path


def test_an_entry_is_computed_once_then_read(cache):
    calls = []

    def compute() -> bytes:
        calls.append(1)
        return b"value"

    assert disk_cache.cached("kind", "k1", compute, bytes.decode) == "value"
    assert disk_cache.cached("kind", "k1", compute, bytes.decode) == "value"
    assert len(calls) == 1
    assert (cache / "kind" / "k1").read_bytes() == b"value"
    assert [p.name for p in (cache / "kind").iterdir()] == ["k1"]  # no temporary file left


def test_a_changed_input_file_is_a_different_key(tmp_path):
    source = tmp_path / "mesh.obj"
    source.write_text("v 0 0 0\n")
    before = disk_cache.content_key(source, "detail=0.1")
    assert disk_cache.content_key(source, "detail=0.1") == before
    assert disk_cache.content_key(source, "detail=0.2") != before
    source.write_text("v 0 0 1\n")
    os.utime(source, ns=(1, 1))  # a new time: the digest is read again
    assert disk_cache.content_key(source, "detail=0.1") != before
    assert disk_cache.content_key("ab", "c") != disk_cache.content_key("a", "bc")


@pytest.mark.parametrize("settled_ns", [disk_cache.SETTLED_NS, 0])
def test_a_file_rewritten_with_its_size_and_time_is_a_different_key(cache, tmp_path, monkeypatch, settled_ns):
    """Just written (hashed every time), or as if long settled (known by its stat stamp)."""
    monkeypatch.setattr(disk_cache, "SETTLED_NS", settled_ns)
    source = tmp_path / "mesh.obj"
    source.write_text("v 0 0 0\n")
    before = disk_cache.content_key(source)
    mtime_ns = source.stat().st_mtime_ns
    time.sleep(0.05)  # past the kernel's timestamp tick
    source.write_text("v 0 0 1\n")
    os.utime(source, ns=(mtime_ns, mtime_ns))  # same size, same time: the change time still moves
    assert disk_cache.content_key(source) != before


def test_a_settled_file_digest_is_read_from_the_cache_by_later_processes(cache, tmp_path, monkeypatch):
    source = tmp_path / "mesh.obj"
    source.write_text("v 0 0 0\n")
    assert disk_cache.content_key(source)
    assert not (cache / "file_sha256").exists()  # just written: hashed, not kept
    monkeypatch.setattr(disk_cache, "SETTLED_NS", 0)  # as if it had been written long ago
    key = disk_cache.content_key(source)
    assert len(list((cache / "file_sha256").iterdir())) == 1
    disk_cache._settled_file_digest.cache_clear()  # as a new process

    def no_hashing(path: str) -> bytes:
        raise AssertionError(f"{path} hashed again")

    monkeypatch.setattr(disk_cache, "_sha256_of", no_hashing)
    assert disk_cache.content_key(source) == key


def test_a_damaged_entry_is_computed_again_and_replaced(cache):
    (cache / "kind").mkdir()
    (cache / "kind" / "k").write_bytes(b"garbage")

    def decode(data: bytes) -> int:
        if not data.isdigit():
            raise ValueError("not a number")
        return int(data)

    assert disk_cache.cached("kind", "k", lambda: b"42", decode) == 42
    assert (cache / "kind" / "k").read_bytes() == b"42"


def test_off_reads_and_writes_nothing(cache, monkeypatch):
    monkeypatch.setenv(disk_cache.ENV_SWITCH, "off")
    assert disk_cache.cache_dir() is None
    assert disk_cache.cached("kind", "k", lambda: b"x", bytes.decode) == "x"
    assert not (cache / "kind").exists()


def test_an_unwritable_cache_only_costs_the_store(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv(disk_cache.ENV_DIR, str(blocker))  # a file where the directory should be
    assert disk_cache.cached("kind", "k", lambda: b"x", bytes.decode) == "x"


def test_cached_cell_is_the_compiled_cell(cache):
    options = CellOptions()
    fresh = build_cell_spec(options).compile()
    first, again = compile_cell(options), compile_cell(options)  # computes and stores, then reads
    assert len(list((cache / "cell_mjb").iterdir())) == 1
    for model in (first, again):
        for field in ("nbody", "ngeom", "nmesh", "nmeshvert", "nmeshface", "njnt", "nsensor", "ncam"):
            assert getattr(model, field) == getattr(fresh, field), field
        for field in ("body_mass", "body_inertia", "body_pos", "geom_size", "geom_pos", "mesh_vert", "cam_pos"):
            np.testing.assert_array_equal(getattr(model, field), getattr(fresh, field), err_msg=field)
    assert compile_cell(CellOptions(cube_size=0.04)).geom_size.tolist() != first.geom_size.tolist()


def test_cached_planning_model_is_the_compiled_one(cache, monkeypatch):
    first = robot_model_from_mjcf(robot_xml(), srdf=SRDF_PATH, couplings=COUPLINGS_PATH)
    assert len(list((cache / "mjcf_facts").iterdir())) == 1
    cached = robot_model_from_mjcf(robot_xml(), srdf=SRDF_PATH, couplings=COUPLINGS_PATH)
    monkeypatch.setenv(disk_cache.ENV_SWITCH, "off")
    fresh = robot_model_from_mjcf(mujoco.MjSpec.from_string(robot_xml()), srdf=SRDF_PATH, couplings=COUPLINGS_PATH)
    q = fresh.neutral() + 0.3
    for model in (first, cached):
        assert [f.name for f in model.model.frames] == [f.name for f in fresh.model.frames]
        assert len(model.collision_model.geometryObjects) == len(fresh.collision_model.geometryObjects)
        for frame in ("tcp", "wrist_3_link", "gripper_right_pad"):
            np.testing.assert_array_equal(_pose(model, q, frame), _pose(fresh, q, frame))


def _pose(robot: RobotModel, q: np.ndarray, frame: str) -> np.ndarray:
    from runtime.motion.scene import frame_pose

    return frame_pose(robot, q, frame)


def _robot(source) -> RobotModel:
    return robot_model_from_mjcf(source, srdf=SRDF_PATH, couplings=COUPLINGS_PATH)


def _distances(robot: RobotModel, q: np.ndarray) -> list[tuple[float, tuple[float, ...]]]:
    """Distance and nearest points of every pair of collision objects at ``q``."""
    import pinocchio as pin

    geometry = robot.collision_model.copy()
    geometry.addAllCollisionPairs()
    data, geometry_data = robot.model.createData(), pin.GeometryData(geometry)
    pin.computeDistances(robot.model, data, geometry, geometry_data, q)
    return [(r.min_distance, tuple(r.getNearestPoint1()) + tuple(r.getNearestPoint2()))
            for r in geometry_data.distanceResults]


def test_cached_collision_hulls_collide_exactly_like_fresh_ones(cache):
    first, cached = _robot(robot_xml()), _robot(robot_xml())  # computes and stores, then reads
    assert len(list((cache / "collision_hulls").iterdir())) == 1
    fresh = _robot(mujoco.MjSpec.from_string(robot_xml()))  # an MjSpec is never cached
    hulls = [go for go in fresh.collision_model.geometryObjects if type(go.geometry).__name__ == "Convex"]
    assert len(hulls) == 10  # the gripper's meshes
    for model in (first, cached):
        assert model.collision_model == fresh.collision_model  # names, parents, placements, hull points and faces
        rng = np.random.default_rng(0)
        for _ in range(5):
            q = fresh.neutral() + rng.uniform(-1.5, 1.5, fresh.model.nq)
            assert _distances(model, q) == _distances(fresh, q)


def test_a_damaged_collision_hulls_entry_is_rebuilt(cache):
    fresh = _robot(robot_xml())
    (entry,) = (cache / "collision_hulls").iterdir()
    good = entry.read_bytes()
    for damaged in (b"", b"not an archive", good[: len(good) // 2]):
        entry.write_bytes(damaged)
        assert _robot(robot_xml()).collision_model == fresh.collision_model
        assert entry.read_bytes() == good


def test_a_changed_collision_mesh_is_a_new_collision_hulls_entry(cache, tmp_path):
    xml = robot_xml()
    original = next(part.split('"')[1] for part in xml.split("file=")[1:] if "base_mount.stl" in part)
    mesh = tmp_path / "base_mount.stl"
    mesh.write_bytes(Path(original).read_bytes())
    xml = xml.replace(original, str(mesh))
    before = _robot(xml)
    _scale_binary_stl(mesh, 1.5)
    after = _robot(xml)
    assert len(list((cache / "collision_hulls").iterdir())) == 2
    assert after.collision_model != before.collision_model
    name = "gripper_base_mountGeom_1"
    (old,) = [go.geometry for go in before.collision_model.geometryObjects if go.name == name]
    (new,) = [go.geometry for go in after.collision_model.geometryObjects if go.name == name]
    assert new.aabb_radius == pytest.approx(1.5 * old.aabb_radius)


def _scale_binary_stl(path: Path, factor: float) -> None:
    """Scale every vertex of a binary STL file in place (80-byte header, count, 50-byte triangles)."""
    data = bytearray(path.read_bytes())
    count = int.from_bytes(data[80:84], "little")
    triangles = np.frombuffer(data, dtype=np.dtype([("normal", "<f4", 3), ("vertices", "<f4", 9), ("attribute", "<u2")]),
                              count=count, offset=84).copy()
    triangles["vertices"] *= factor
    path.write_bytes(bytes(data[:84]) + triangles.tobytes())


def _read_path(path: str) -> tuple[str, bytes]:
    with open(path, "rb") as f:
        data = f.read()
    if not data.startswith(b"entry:"):
        raise ValueError(f"{path}: not an entry")
    return path, data


def test_a_file_entry_is_loaded_from_its_path(cache):
    calls = []

    def compute() -> bytes:
        calls.append(1)
        return b"entry:1"

    first = disk_cache.cached_file("kind", "k", compute, _read_path)
    again = disk_cache.cached_file("kind", "k", compute, _read_path)
    assert first == again == (str(cache / "kind" / "k"), b"entry:1")
    assert len(calls) == 1
    (cache / "kind" / "k").write_bytes(b"damaged")
    assert disk_cache.cached_file("kind", "k", compute, _read_path) == (str(cache / "kind" / "k"), b"entry:1")
    assert len(calls) == 2


def test_a_file_entry_without_a_cache_is_loaded_from_a_removed_temporary_file(cache, monkeypatch):
    monkeypatch.setenv(disk_cache.ENV_SWITCH, "off")
    path, data = disk_cache.cached_file("kind", "k", lambda: b"entry:2", _read_path)
    assert data == b"entry:2"
    assert not os.path.exists(path)
    assert not (cache / "kind").exists()


def test_a_damaged_cell_entry_is_compiled_again(cache):
    good = compile_cell(CellOptions())
    (entry,) = (cache / "cell_mjb").iterdir()
    entry.write_bytes(entry.read_bytes()[:1000])  # truncated
    again = compile_cell(CellOptions())
    np.testing.assert_array_equal(again.mesh_vert, good.mesh_vert)
    assert mujoco.MjModel.from_binary_path(str(entry)).nmeshvert == good.nmeshvert


# -- size: least recently used entries are pruned ------------------------------------------------
def _entry(root: Path, kind: str, name: str, size: int, age_s: float) -> Path:
    path = root / kind / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)
    then = time.time() - age_s
    os.utime(path, (then, then))
    return path


def test_the_least_recently_used_entries_go_first_and_the_new_one_stays():
    entries = [disk_cache.Entry(Path(name), size, used) for name, size, used in
               [("old", 50, 1), ("new", 50, 9), ("mid", 50, 5), ("kept", 50, 0)]]
    assert disk_cache.entries_to_remove(entries, 100, keep=Path("kept")) == [Path("old"), Path("mid")]
    assert disk_cache.entries_to_remove(entries, 200, keep=Path("kept")) == []
    assert disk_cache.entries_to_remove(entries, 0, keep=Path("kept")) == [Path("old"), Path("mid"), Path("new")]


def test_prune_removes_the_oldest_entries_and_stale_temporary_files(cache):
    old = _entry(cache, "cell_mjb", "a", 600, age_s=300)
    recent = _entry(cache, "cell_mjb", "b", 600, age_s=10)
    small = _entry(cache, "file_sha256", "c", 32, age_s=200)
    stale_tmp = _entry(cache, "cell_mjb", ".a.123.tmp", 100, age_s=2 * disk_cache.STALE_TEMPORARY_S)
    live_tmp = _entry(cache, "cell_mjb", ".b.456.tmp", 100, age_s=1)
    removed = disk_cache.prune(cache, 1000)
    assert sorted(removed) == sorted([old, stale_tmp])
    assert recent.exists() and small.exists() and live_tmp.exists()
    assert not old.exists() and not stale_tmp.exists()


def test_a_read_entry_counts_as_recently_used(cache):
    read = _entry(cache, "kind", "read", 600, age_s=500)
    unread = _entry(cache, "kind", "unread", 600, age_s=100)
    assert disk_cache.cached("kind", "read", lambda: b"never", len) == 600  # a hit: not computed
    assert disk_cache.prune(cache, 1000) == [unread]
    assert read.exists()


def test_a_store_prunes_at_most_once_a_period(cache, monkeypatch):
    monkeypatch.setenv(disk_cache.ENV_LIMIT, "0.001")  # 1000 bytes
    first = _entry(cache, "kind", "first", 600, age_s=500)
    disk_cache.cached("kind", "second", lambda: b"y" * 600, len)  # over the limit, never pruned before
    assert not first.exists() and (cache / "kind" / "second").exists()
    disk_cache.cached("kind", "third", lambda: b"z" * 600, len)  # pruned just now: not again
    assert (cache / "kind" / "second").exists() and (cache / "kind" / "third").exists()
    marker = cache / disk_cache.PRUNE_MARKER
    then = time.time() - 2 * disk_cache.PRUNE_PERIOD_S
    os.utime(marker, (then, then))
    os.utime(cache / "kind" / "second", (then, then))
    disk_cache.cached("kind", "fourth", lambda: b"w" * 100, len)
    assert sorted(p.name for p in (cache / "kind").iterdir()) == ["fourth", "third"]


@pytest.mark.parametrize("value", ["lots", "-5", "nan", "inf"])
def test_a_bad_size_limit_is_reported_and_nothing_is_pruned(cache, monkeypatch, capsys, value):
    monkeypatch.setenv(disk_cache.ENV_LIMIT, value)
    kept = _entry(cache, "kind", "old", 10_000, age_s=500)
    assert disk_cache.cached("kind", "new", lambda: b"v", bytes.decode) == "v"
    assert kept.exists()
    assert f"OBJECTIVE_CACHE_MAX_MB={value!r} is not a number of megabytes >= 0" in capsys.readouterr().err
