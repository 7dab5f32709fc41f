"""The admittance reuses the wrist Jacobian's damped pseudo-inverse for
``ControllersConfig.jacobian_refresh_period`` (10 ms by default), recomputed after that and after a reset."""
from __future__ import annotations

import numpy as np

from runtime.io.bus import FixedLatency, InProcessBus
from runtime.io.clock import SimClock
from sim.controllers import TRAJECTORY_CONTROLLER, VELOCITY_CONTROLLER, ControllersConfig, make_controllers
from sim.controllers.compliance import damped_pseudo_inverse
from tests.test_controllers import DT, JACOBIAN, FakeHardware


class CountingHardware(FakeHardware):
    """The fake cell, with a Jacobian that changes at every step and counts its reads."""

    def __init__(self, clock: SimClock) -> None:
        super().__init__(clock)
        self.jacobian_reads = 0

    def wrist_jacobian(self) -> np.ndarray:
        self.jacobian_reads += 1
        return JACOBIAN + 0.01 * np.sin(self.clock.now()) * np.eye(6)


def run(period: float, seconds: float, push: np.ndarray):
    clock = SimClock()
    bus = InProcessBus(clock, default_latency=FixedLatency(0.0))
    hw = CountingHardware(clock)
    manager = make_controllers(bus, hw, clock, ControllersConfig(jacobian_refresh_period=period))
    assert manager.switch([TRAJECTORY_CONTROLLER], [VELOCITY_CONTROLLER]).ok
    hw.external_wrench = push
    jtc = manager[TRAJECTORY_CONTROLLER]
    for _ in range(int(round(seconds / DT))):
        manager.update(clock.now(), DT)
        hw.step(DT)
        clock.advance(DT)
        bus.spin_once()
    return hw, jtc, manager


PUSH = np.array([21.0, 0.0, 0.0, 0.0, 0.0, 0.0])


def test_the_pseudo_inverse_is_refreshed_every_10_ms_by_default():
    hw, _, _ = run(ControllersConfig().jacobian_refresh_period, 0.1, PUSH)
    assert ControllersConfig().jacobian_refresh_period == 0.01
    assert hw.jacobian_reads == 10  # 50 control steps, one read per 5


def test_period_zero_maps_exactly_at_every_step():
    hw, jtc, _ = run(0.0, 0.1, PUSH)
    assert hw.jacobian_reads == 50
    last_step_jacobian = JACOBIAN + 0.01 * np.sin(0.098) * np.eye(6)  # the 50th step runs at t = 0.098 s
    np.testing.assert_allclose(jtc.joint_offset, damped_pseudo_inverse(last_step_jacobian) @ jtc.cartesian_offset, rtol=1e-12)


def test_the_cached_mapping_stays_within_a_small_fraction_of_the_exact_one():
    _, cached, _ = run(0.01, 0.5, PUSH)
    _, exact, _ = run(0.0, 0.5, PUSH)
    np.testing.assert_allclose(cached.cartesian_offset, exact.cartesian_offset, rtol=1e-12)
    error = np.abs(cached.joint_offset - exact.joint_offset).max()
    assert 0 < error < 0.01 * np.abs(exact.joint_offset).max()


def test_no_push_no_jacobian_reads_and_a_reset_forgets_the_cached_inverse():
    hw, jtc, manager = run(0.01, 0.05, np.zeros(6))
    assert hw.jacobian_reads == 0 and not jtc.joint_offset.any()
    hw.external_wrench = PUSH
    manager.update(manager.clock.now(), DT)
    assert hw.jacobian_reads == 1
    manager.reset()
    manager.update(manager.clock.now(), DT)  # same instant, but the robot may have been teleported
    assert hw.jacobian_reads == 2
