"""A mistaken environment or world option is a clear error (exit 2) naming it, never an internal
error: ``MUJOCO_GL``, ``ROS_DOMAIN_ID``, ``image_size``."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.app.cli import main
from runtime.io.ros.bus import domain_id_problem
from sim import mujoco_gl_problem

REPO = Path(__file__).resolve().parent.parent


def objective(*argv: str, **env: str) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, "PYTHONPATH": str(REPO), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", **env}
    return subprocess.run([sys.executable, "-m", "runtime.app.cli", *argv], cwd=REPO, env=environment,
                          capture_output=True, text=True, timeout=120)


def test_a_mujoco_gl_that_names_no_backend_is_an_error_naming_it():
    proc = objective("run", "objectives/stack_cubes.xml", "--max-seconds", "0.1", MUJOCO_GL="bogus")
    assert proc.returncode == 2
    assert proc.stderr.strip() == ("error: MUJOCO_GL='bogus' names no rendering backend: the cell renders offscreen "
                                   "with egl (the default) or osmesa")
    assert [value for value in ("egl", "osmesa", "EGL", "", "glfw") if mujoco_gl_problem(value)] == []


@pytest.mark.ros
def test_a_ros_domain_id_that_is_not_one_is_an_error_naming_it():
    proc = objective("run", "objectives/cell/open_gripper.xml", "--ros", "--world", "kinematic", "--max-seconds", "1",
                     ROS_DOMAIN_ID="abc")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == (
        "error: ROS_DOMAIN_ID='abc' must be a whole number from 0 to 232 (0-101 are safe everywhere)")
    assert [text for text in ("", "0", "61", "232") if domain_id_problem(text)] == []
    assert [text for text in ("-1", "233", "１", "1.5") if not domain_id_problem(text)] == []


@pytest.mark.parametrize("world", ["kinematic", "vla_sim"])
def test_an_image_size_outside_what_a_cell_renders_is_an_error_naming_it(capsys, world):
    """On main the kinematic world tried to allocate 27.9 GiB for image_size=100000."""
    code = main(["run", "objectives/stack_cubes.xml", "--world", world, "--world-option", "image_size=100000"])
    assert code == 2
    assert f"error: world '{world}': option 'image_size' 100000: must be an integer in [16, 4096]" in capsys.readouterr().err
