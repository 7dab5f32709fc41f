"""``objective build-interfaces`` beside a sourced ROS 2: a package the ROS install already has is
left out (building it into the venv would hide the installed one), unless it is named."""
from __future__ import annotations

import argparse
from pathlib import Path

from runtime.app import build_interfaces
from runtime.app.build_interfaces import provided_elsewhere


def ament_prefix(root: Path, *packages: str) -> Path:
    index = root / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True)
    for name in packages:
        (index / name).write_text("")
    return root


def test_a_package_of_a_sourced_prefix_is_found(tmp_path):
    ros = ament_prefix(tmp_path / "opt_ros_jazzy", "control_msgs", "tf2_msgs")
    venv = ament_prefix(tmp_path / "venv", "moveit_pro_ml_msgs")
    environ = {"AMENT_PREFIX_PATH": f"{venv}:{ros}"}
    assert provided_elsewhere("control_msgs", venv, environ) == ros
    assert provided_elsewhere("moveit_pro_ml_msgs", venv, environ) is None  # only in this venv
    assert provided_elsewhere("control_msgs", venv, {}) is None


def test_build_interfaces_leaves_out_what_the_sourced_ros_has(tmp_path, monkeypatch, capsys):
    ros = ament_prefix(tmp_path / "opt_ros_jazzy", *(d.name for d in build_interfaces.INTERFACES_DIR.iterdir()))
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(ros))
    monkeypatch.setattr(build_interfaces, "fix_cmake_exports", lambda prefix: 0)
    monkeypatch.setattr(build_interfaces, "build_package", lambda *a: (_ for _ in ()).throw(AssertionError("built")))
    assert build_interfaces.build(argparse.Namespace(force=False, build_dir=tmp_path / "b", packages=[])) == 0
    out = capsys.readouterr().out
    assert f"control_msgs: skipped, {ros} has it (name it to build this copy, which would hide that one)" in out
    assert "moveit_pro_ml_msgs: skipped" in out
