"""Demo-only recording settings (sim.demos): the motion noise of recovery demonstrations and the
oracle configuration a recording uses. The recording itself is tested in test_lerobot_backend.py."""
from __future__ import annotations

import math

import numpy as np
import pytest

from runtime.errors import OptionError
from sim.demos import DemoOptions, MotionNoise
from sim.oracle import OracleConfig, SceneKinematics, plan_stack

HOME = np.array([-1.5708, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


@pytest.fixture(scope="module")
def plan():
    from sim.robot_model import planning_robot_model

    kinematics = SceneKinematics(planning_robot_model())
    return plan_stack(kinematics, HOME, 0.0, (np.array([0.10, 0.45, 0.015]), yaw_quat(0.3)),
                      (np.array([-0.12, 0.50, 0.015]), yaw_quat(-0.6)), OracleConfig(max_gripper_velocity=0.5))


def test_noise_is_zero_where_the_cube_is_grasped_carried_up_and_released(plan):
    bounds = plan.boundaries()
    noise = MotionNoise(0.05, seed=7)
    quiet = [0.0, bounds["close"][0], *np.linspace(bounds["close"][0], bounds["lift"][1], 7), bounds["open"][0],
             bounds["open"][1], plan.duration, plan.duration + 5.0]
    np.testing.assert_array_equal(noise.offsets(plan, np.array(quiet)), 0.0)
    times = np.arange(0.0, plan.duration, 0.1)
    offsets = noise.offsets(plan, times)
    assert 0.01 < np.abs(offsets).max() <= 0.05
    # Smooth: at 10 Hz far inside every joint's velocity and acceleration limits.
    assert np.abs(np.diff(offsets, axis=0)).max() < 0.02 and np.abs(np.diff(offsets, 2, axis=0)).max() < 0.01
    np.testing.assert_array_equal(MotionNoise(0.05, seed=7).offsets(plan, times), offsets)
    assert not np.array_equal(MotionNoise(0.05, seed=8).offsets(plan, times), offsets)


def test_demo_options_change_the_oracle_only_for_the_recording(tmp_path):
    options = DemoOptions(episodes=1, seed=0, out=tmp_path, gripper_velocity=0.5)
    assert options.oracle_config() == OracleConfig(max_gripper_velocity=0.5)
    assert DemoOptions(episodes=1, seed=0, out=tmp_path).oracle_config() == OracleConfig()
    assert OracleConfig().max_gripper_velocity == 1.0  # what make demo and the benchmarks use
    for bad, message in (({"gripper_velocity": 0.0}, "--gripper-velocity must be positive"),
                         ({"motion_noise_rad": -0.1}, "--motion-noise must be >= 0"),
                         ({"cameras": ()}, "--cameras must name distinct cameras"),
                         ({"hold_after_plan_s": -1.0}, "--hold-after-plan must be >= 0")):
        with pytest.raises(OptionError, match=message):
            DemoOptions(episodes=1, seed=0, out=tmp_path, **bad).check()
