"""``objective build-interfaces``: a package is built once per machine and interpreter, kept in the
machine's cache, and installed from there into every other venv (no cmake, no compiler here: the
build step is replaced by one that installs two files)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from runtime.app import build_interfaces as tool


@pytest.fixture
def fake_build(tmp_path, monkeypatch):
    """``build_package`` replaced by one that installs a text file naming the prefix and a binary
    one (what cmake's install of a message package looks like), counting its calls; every
    package's types load."""
    monkeypatch.setenv("OBJECTIVE_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("OBJECTIVE_CACHE", raising=False)
    monkeypatch.setattr(tool, "types_load", lambda pkg, env: True)
    calls = []

    def build_package(pkg, prefix, env, build_dir, jobs, generators_script):
        calls.append(prefix)
        files = {f"share/{pkg.name}/local_setup.sh": f'AMENT_CURRENT_PREFIX="{prefix}"\n'.encode(),
                 f"lib/lib{pkg.name}__rosidl_generator_c.so": b"\0ELF\0" + str(prefix).encode()}
        for name, data in files.items():
            (prefix / name).parent.mkdir(parents=True, exist_ok=True)
            (prefix / name).write_bytes(data)
        return sorted(files)

    monkeypatch.setattr(tool, "build_package", build_package)
    return calls


def how(prefix: Path) -> tool.Build:
    prefix.mkdir(parents=True, exist_ok=True)
    return tool.Build(prefix, {}, prefix / "build", 2, None)


def package(tmp_path: Path) -> tool.Package:
    return tool.Package("demo_msgs", tmp_path / "src", set())


def test_a_package_built_for_one_venv_installs_from_the_cache_into_another(tmp_path, fake_build):
    first, second = tmp_path / "clone1" / ".venv", tmp_path / "clone2" / ".venv"
    pkg = package(tmp_path)
    assert tool.provide(pkg, "k1", how(first), force=False).startswith("demo_msgs: built in ")
    line = tool.provide(pkg, "k1", how(second), force=False)
    assert line.startswith("demo_msgs: installed from the cache in "), line
    assert fake_build == [first]  # built once
    # Text files name the venv they are in; binaries are copied as built.
    assert (second / "share/demo_msgs/local_setup.sh").read_text() == f'AMENT_CURRENT_PREFIX="{second}"\n'
    assert (second / "lib/libdemo_msgs__rosidl_generator_c.so").read_bytes() == b"\0ELF\0" + str(first).encode()
    marker = json.loads((second / "share/demo_msgs" / tool.MARKER).read_text())
    assert (marker["key"], marker["prefix"]) == ("k1", str(second))
    assert tool.provide(pkg, "k1", how(second), force=False) == "demo_msgs: up to date"
    assert not [p for p in second.iterdir() if p.name.startswith(".")]  # no staging directory left


def test_a_new_build_replaces_the_files_of_the_one_before(tmp_path, fake_build, monkeypatch):
    prefix = tmp_path / "venv"
    pkg = package(tmp_path)
    tool.provide(pkg, "k1", how(prefix), force=False)
    old_library = prefix / "lib/libdemo_msgs__rosidl_generator_c.so"
    assert old_library.is_file()

    def smaller(pkg, prefix, env, build_dir, jobs, generators_script):
        (prefix / "share/demo_msgs/local_setup.sh").write_text("v2\n")
        return ["share/demo_msgs/local_setup.sh"]

    monkeypatch.setattr(tool, "build_package", smaller)
    assert tool.provide(pkg, "k2", how(prefix), force=False).startswith("demo_msgs: built in ")
    assert not old_library.exists()
    assert (prefix / "share/demo_msgs/local_setup.sh").read_text() == "v2\n"


def test_force_builds_again_and_replaces_the_cached_build(tmp_path, fake_build):
    pkg = package(tmp_path)
    tool.provide(pkg, "k1", how(tmp_path / "a"), force=False)
    assert tool.provide(pkg, "k1", how(tmp_path / "a"), force=True).startswith("demo_msgs: built in ")
    assert tool.provide(pkg, "k1", how(tmp_path / "b"), force=False).startswith("demo_msgs: installed from the cache")
    assert fake_build == [tmp_path / "a", tmp_path / "a"]


def test_a_cached_build_whose_types_do_not_load_is_built_again(tmp_path, fake_build, monkeypatch):
    pkg = package(tmp_path)
    tool.provide(pkg, "k1", how(tmp_path / "a"), force=False)
    answers = iter([False, True])  # the cached copy does not load in b; the new build does
    monkeypatch.setattr(tool, "types_load", lambda pkg, env: next(answers))
    assert tool.provide(pkg, "k1", how(tmp_path / "b"), force=False).startswith("demo_msgs: built in ")
    assert fake_build == [tmp_path / "a", tmp_path / "b"]


def test_without_the_cache_every_venv_builds(tmp_path, fake_build, monkeypatch):
    monkeypatch.setenv("OBJECTIVE_CACHE", "off")
    pkg = package(tmp_path)
    tool.provide(pkg, "k1", how(tmp_path / "a"), force=False)
    assert tool.provide(pkg, "k1", how(tmp_path / "b"), force=False).startswith("demo_msgs: built in ")
    assert (tmp_path / "b/share/demo_msgs/local_setup.sh").read_text() == f'AMENT_CURRENT_PREFIX="{tmp_path / "b"}"\n'


def test_packages_build_side_by_side_by_dependency_level_largest_first(tmp_path):
    def pkg(name, depends, interfaces):
        (tmp_path / name / "msg").mkdir(parents=True)
        for i in range(interfaces):
            (tmp_path / name / "msg" / f"M{i}.msg").write_text("int32 x\n")
        return tool.Package(name, tmp_path / name, set(depends))

    levels = tool.dependency_levels([pkg("small", [], 1), pkg("big", ["std_msgs"], 5), pkg("uses_small", ["small"], 9)])
    assert [[p.name for p in level] for level in levels] == [["big", "small"], ["uses_small"]]


def test_what_shapes_a_build_is_in_its_key():
    assert tool.is_build_input("ros-jazzy-rosidl-generator-c") and tool.is_build_input("ros_rmw")
    assert tool.is_build_input("empy") and tool.is_build_input("numpy")
    assert not tool.is_build_input("mujoco") and not tool.is_build_input("rosbags")
    assert tool.parse_cmake_version("cmake version 3.25.1\n\nCMake suite maintained") == (3, 25)
    assert tool.parse_cmake_version("") == (0, 0)


def test_the_configure_command_builds_only_what_python_uses(tmp_path):
    script = tmp_path / "generators.cmake"
    cmd = tool.cmake_arguments(tmp_path / "src", tmp_path / "b", tmp_path / "venv", script, ninja=True)
    assert f"-DCMAKE_PROJECT_TOP_LEVEL_INCLUDES={script}" in cmd and cmd[-3:-1] == ["-G", "Ninja"]
    assert not any(arg.startswith("-DCMAKE_BUILD_TYPE") for arg in cmd)  # -O0, as colcon builds by default
    plain = tool.cmake_arguments(tmp_path / "src", tmp_path / "b", tmp_path / "venv", None, ninja=False)
    assert not any("TOP_LEVEL_INCLUDES" in arg or arg == "Ninja" for arg in plain)
    assert 'EXCLUDE REGEX "_cpp:"' in tool.GENERATORS_CMAKE


def test_repairing_the_wheels_cmake_exports_leaves_hard_linked_copies_alone(tmp_path):
    """uv installs hard links to its cache: a file rewritten in place would change every venv's."""
    export = tmp_path / "venv" / "share" / "std_msgs" / "cmake" / "export.cmake"
    export.parent.mkdir(parents=True)
    export.write_text('INTERFACE_INCLUDE_DIRECTORIES "/opt/python/cp311-cp311/include/python3.11"\n')
    cached = tmp_path / "installer-cache" / "export.cmake"
    cached.parent.mkdir()
    cached.hardlink_to(export)
    assert tool.fix_cmake_exports(tmp_path / "venv") == 1
    assert "/opt/python/" not in export.read_text()
    assert cached.read_text() == 'INTERFACE_INCLUDE_DIRECTORIES "/opt/python/cp311-cp311/include/python3.11"\n'
