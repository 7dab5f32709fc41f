"""The MuJoCo cell's 500 Hz sensor reads (wrench, wrist Jacobian, arm state) read through cached
views and buffers; they must equal fresh reads from MuJoCo, also after a reset."""
from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sim.cell_model import CellOptions
from sim.mujoco_cell import MujocoCell
from sim.robot_model import ARM_JOINTS, load_waypoints

HOME = np.array([load_waypoints()["Home"][j] for j in ARM_JOINTS])


@pytest.fixture(scope="module")
def cell() -> MujocoCell:
    cell = MujocoCell(CellOptions(image_width=32, image_height=24), HOME, seed=0)
    yield cell
    cell.close()


def fresh_reads(cell: MujocoCell) -> dict[str, np.ndarray]:
    """What the cell reports, recomputed from MuJoCo with nothing cached."""
    m, d = cell.model, cell.data
    site, body = m.site(cell._ft_site).id, m.site_bodyid[cell._ft_site]
    R = d.site_xmat[site].reshape(3, 3)
    force = R @ d.sensordata[cell._force_adr:cell._force_adr + 3]
    torque = R @ d.sensordata[cell._torque_adr:cell._torque_adr + 3]
    weight = m.body_subtreemass[body] * m.opt.gravity
    lever = d.subtree_com[body] - d.site_xpos[site]
    raw = np.concatenate([-force - weight, -torque - np.cross(lever, weight)])
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jacp, jacr, site)
    dofs = [m.joint(j).dofadr[0] for j in ARM_JOINTS]
    qpos = [m.joint(j).qposadr[0] for j in ARM_JOINTS]
    return {
        "wrench": raw - cell._tare,
        "jacobian": np.vstack([jacp[:, dofs], jacr[:, dofs]]),
        "position": d.qpos[qpos].copy(),
        "velocity": d.qvel[dofs].copy(),
    }


def reads(cell: MujocoCell) -> dict[str, np.ndarray]:
    return {"wrench": cell.wrench(), "jacobian": cell.wrist_jacobian(), "position": cell.arm_position(), "velocity": cell.arm_velocity()}


def test_sensor_reads_equal_fresh_reads_while_moving_and_after_a_reset(cell):
    rng = np.random.default_rng(0)
    for seed in (0, 1):
        cell.reset(seed, HOME + rng.uniform(-0.3, 0.3, 6))
        cell.external_wrench = np.array([0.0, 0.0, -15.0, 0.3, 0.0, 0.0])
        target = HOME + rng.uniform(-0.5, 0.5, 6)
        for step in range(150):
            cell.command_arm(target)
            cell.step(0.002)
            if step % 30 == 0:
                got, want = reads(cell), fresh_reads(cell)
                for key in want:  # the wrench is summed in another order (plain floats): last-bit differences
                    np.testing.assert_allclose(got[key], want[key], rtol=1e-14, atol=1e-12, err_msg=f"{key} at step {step} after reset({seed})")
        cell.external_wrench = np.zeros(6)


def test_reads_are_independent_copies(cell):
    cell.reset(0, HOME)
    jacobian, position = cell.wrist_jacobian(), cell.arm_position()
    kept_jacobian, kept_position = jacobian.copy(), position.copy()
    cell.command_arm(HOME + 0.3)
    for _ in range(50):
        cell.step(0.002)
    cell.wrist_jacobian(), cell.arm_position()
    np.testing.assert_array_equal(jacobian, kept_jacobian)
    np.testing.assert_array_equal(position, kept_position)
    assert not np.array_equal(cell.wrist_jacobian(), kept_jacobian)
