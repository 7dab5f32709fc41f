"""The cold-start disk cache: keyed by content, atomic, recomputes damaged entries, and gives
the same robot, cell and planning model as building them from scratch."""
from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from runtime import disk_cache  # noqa: E402
from runtime.scene import RobotModel  # noqa: E402
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
    first = RobotModel.from_mjcf(robot_xml(), srdf=SRDF_PATH, couplings=COUPLINGS_PATH)
    assert len(list((cache / "mjcf_facts").iterdir())) == 1
    cached = RobotModel.from_mjcf(robot_xml(), srdf=SRDF_PATH, couplings=COUPLINGS_PATH)
    monkeypatch.setenv(disk_cache.ENV_SWITCH, "off")
    fresh = RobotModel.from_mjcf(mujoco.MjSpec.from_string(robot_xml()), srdf=SRDF_PATH, couplings=COUPLINGS_PATH)
    q = fresh.neutral() + 0.3
    for model in (first, cached):
        assert [f.name for f in model.model.frames] == [f.name for f in fresh.model.frames]
        assert len(model.collision_model.geometryObjects) == len(fresh.collision_model.geometryObjects)
        for frame in ("tcp", "wrist_3_link", "gripper_right_pad"):
            np.testing.assert_array_equal(_pose(model, q, frame), _pose(fresh, q, frame))


def _pose(robot: RobotModel, q: np.ndarray, frame: str) -> np.ndarray:
    from runtime.scene import frame_pose

    return frame_pose(robot, q, frame)
