"""The physics cell: MuJoCo UR5e + Robotiq 2F-85 on a table with three cubes.

Implements ``sim.hardware.Hardware`` for the simulated controllers, plus what the world needs:
cube poses, seeded resets, and camera frames. A grasped cube is held by friction between the
pads, not welded. Rendering needs ``MUJOCO_GL=egl`` (set here before mujoco is imported).
"""
from __future__ import annotations

import copy

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from .cell_model import (  # noqa: E402
    CAMERA_NAMES,
    CUBE_COLORS,
    FT_FORCE_SENSOR,
    FT_TORQUE_SENSOR,
    SIM_BOX_PARKED_Z,
    SIM_BOX_SLOTS,
    CellOptions,
    box_slot_name,
    compile_cell,
    cube_body_name,
)
from .layouts import layout  # noqa: E402
from .robot_model import ARM_JOINTS, FT_SITE, GRIPPER_DRIVER_JOINT  # noqa: E402

GRIPPER_ACTUATOR = "gripper_fingers_actuator"
GRIPPER_CTRL_PER_RAD = 255.0 / 0.8  # the Menagerie 2F-85 maps ctrl 0..255 onto the driver's 0..0.8 rad
SETTLE_SECONDS = 0.2  # after a reset: cubes come to rest on the table before time starts
BOX_OVERLAP_TOLERANCE = 0.001  # metres a placed box may sink into what it touches (resting on the table)
NO_TARE = (0.0,) * 6  # subtracting 0.0 leaves every float as it is


def _block(indices: np.ndarray, what: str) -> slice:
    """``indices`` (consecutive and increasing) as a slice; ValueError otherwise.

    The cell's model lists the arm's joints and actuators first and in order, so the arm's
    entries of MjData's buffers are views (a slice of a buffer is a view, and copying a view
    takes a quarter of the time of indexing with an array)."""
    first = int(indices[0])
    if indices.tolist() != list(range(first, first + len(indices))):
        raise ValueError(f"the model's arm {what} are not consecutive: {indices.tolist()}")
    return slice(first, first + len(indices))


def _yaw_quat(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


class MujocoCell:
    """The cell's physics and sensors. ``t`` is the world time (runtime clock), which a reset
    does not rewind; MuJoCo's own ``data.time`` is not used for anything the outside sees."""

    arm_joint_names: tuple[str, ...] = ARM_JOINTS
    gripper_joint_name = GRIPPER_DRIVER_JOINT

    def __init__(self, options: CellOptions | None = None, arm: np.ndarray | None = None, seed: int = 0) -> None:
        self.options = options or CellOptions()
        self.model = compile_cell(self.options)
        self.data = mujoco.MjData(self.model)
        m = self.model
        arm_ctrl = np.array([m.actuator(j.replace("_joint", "")).id for j in ARM_JOINTS])
        self._arm_qpos = _block(np.array([m.joint(j).qposadr[0] for j in ARM_JOINTS]), "joints' positions")
        self._arm_dof = _block(np.array([m.joint(j).dofadr[0] for j in ARM_JOINTS]), "joints' velocities")
        self._arm_ctrl = _block(arm_ctrl, "actuators")
        # The arm servos are PD on position: force = kp (ctrl - q) - kd qdot. At constant speed v
        # they lag by kd v / kp; adding that to the target (velocity feed-forward) removes the lag.
        self._lead = np.array([-m.actuator_biasprm[a][2] / m.actuator_gainprm[a][0] for a in arm_ctrl])
        self._gripper_qpos = m.joint(GRIPPER_DRIVER_JOINT).qposadr[0]
        self._gripper_dof = m.joint(GRIPPER_DRIVER_JOINT).dofadr[0]
        self._gripper_ctrl = m.actuator(GRIPPER_ACTUATOR).id
        self._cube_body = {c: m.body(cube_body_name(c)).id for c in CUBE_COLORS}
        self._cube_qpos = {c: m.joint(f"{cube_body_name(c)}_joint").qposadr[0] for c in CUBE_COLORS}
        self._box_slots = [(m.body(box_slot_name(k)).mocapid[0], m.geom(box_slot_name(k)).id) for k in range(SIM_BOX_SLOTS)]
        self._boxes: dict[str, int] = {}  # placed box name -> slot
        self._ft_site = m.site(FT_SITE).id
        self._ft_body = m.site_bodyid[self._ft_site]
        self._force_adr = m.sensor(FT_FORCE_SENSOR).adr[0]
        self._torque_adr = m.sensor(FT_TORQUE_SENSOR).adr[0]
        # Views into MjData's buffers for the 500 Hz reads (valid for the cell's lifetime: resets
        # write into the same buffers); each attribute access through the bindings builds a new
        # array object, which costs more than the arithmetic done with it.
        d = self.data
        self._qpos, self._qvel, self._xfrc_applied, self._ctrl = d.qpos, d.qvel, d.xfrc_applied, d.ctrl
        self._xpos, self._xquat = d.xpos, d.xquat
        self._arm_positions, self._arm_velocities = self._qpos[self._arm_qpos], self._qvel[self._arm_dof]
        self._arm_targets = self._ctrl[self._arm_ctrl]
        self._site_rotation = d.site_xmat[self._ft_site].reshape(3, 3)
        self._site_position = d.site_xpos[self._ft_site]
        self._gripper_com = d.subtree_com[self._ft_body]
        self._support_force = d.sensordata[self._force_adr:self._force_adr + 3]
        self._support_torque = d.sensordata[self._torque_adr:self._torque_adr + 3]
        self._gripper_weight = tuple((m.body_subtreemass[self._ft_body] * m.opt.gravity).tolist())  # fixed once compiled
        self._site_jacobian = np.zeros((6, m.nv))  # mj_jacSite fills rows 0-2 (linear) and 3-5 (angular)
        self._renderer: mujoco.Renderer | None = None  # one for all cameras: each costs ~50 ms to create
        self._snapshot_renderer: mujoco.Renderer | None = None  # the camera thread's (sim.camera_thread)
        self._frames: dict[str, tuple[float, np.ndarray]] = {}
        self.external_wrench = np.zeros(6)  # tests push the tool with this (world frame, at the F/T site)
        self._pushed = False  # whether xfrc_applied holds a push from external_wrench
        self._substeps_dt, self._substeps_count = 0.0, 1
        self.t = 0.0
        self.renders = 0
        self.reset(seed, np.asarray(arm) if arm is not None else self._arm_positions.copy())

    # -- Hardware ---------------------------------------------------------------------------
    def time(self) -> float:
        return self.t

    def arm_position(self) -> np.ndarray:
        return self._arm_positions.copy()

    def arm_velocity(self) -> np.ndarray:
        return self._arm_velocities.copy()

    def command_arm(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        targets = self._arm_targets
        if velocity is None:
            targets[:] = position
        else:  # position + lead * velocity, computed in the actuators' own buffer (a sum commutes exactly)
            np.multiply(self._lead, velocity, out=targets)
            targets += position

    def gripper_position(self) -> float:
        return float(self._qpos[self._gripper_qpos])

    def gripper_velocity(self) -> float:
        return float(self._qvel[self._gripper_dof])

    def command_gripper(self, position: float, max_effort: float) -> None:
        """Position control of the driver. The 2F-85 model's actuator has a fixed force range,
        so ``max_effort`` is not modelled (documented in docs/cell.md)."""
        self.data.ctrl[self._gripper_ctrl] = float(np.clip(position, 0.0, 0.8)) * GRIPPER_CTRL_PER_RAD

    def wrench(self) -> np.ndarray:
        return np.array(self._wrench_minus(self._tare))

    def tare_wrench(self) -> None:
        self._tare = self._wrench_minus()

    def wrist_jacobian(self) -> np.ndarray:
        jacobian = self._site_jacobian
        mujoco.mj_jacSite(self.model, self.data, jacobian[:3], jacobian[3:], self._ft_site)
        return jacobian[:, self._arm_dof].copy()  # the buffer is overwritten by the next call

    # -- the world's view -------------------------------------------------------------------
    def cube_pose(self, color: str) -> tuple[np.ndarray, np.ndarray]:
        body = self._cube_body[color]
        return self._xpos[body].copy(), self._xquat[body].copy()

    def cube_poses(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        return {c: self.cube_pose(c) for c in CUBE_COLORS}

    def place_box(self, name: str, size_m: np.ndarray, position_m: np.ndarray, quat_wxyz: np.ndarray) -> None:
        """Make a fixed box appear (or move one placed before) at a world pose.

        It collides with the robot and the cubes from the next physics step and shows in the
        cameras. Raises ValueError, leaving the cell as it was, when every slot is taken or when
        the box would overlap something (the robot, a cube, the table) by more than 1 mm: an
        object cannot appear inside another.
        """
        slot = self._boxes.get(name)
        if slot is None:
            free = [k for k in range(SIM_BOX_SLOTS) if k not in self._boxes.values()]
            if not free:
                raise ValueError(f"all {SIM_BOX_SLOTS} box slots of the cell are taken ({', '.join(sorted(self._boxes))}): remove one first")
            slot = free[0]
        geom = self._box_slots[slot][1]
        before = self._box_state(slot)
        half = np.asarray(size_m, dtype=float) / 2.0
        self._set_box(slot, half, np.asarray(position_m, dtype=float), np.asarray(quat_wxyz, dtype=float), shown=True)
        overlap = self._deepest_contact(geom)
        if overlap is not None and overlap[1] < -BOX_OVERLAP_TOLERANCE:
            self._set_box(slot, *before)
            raise ValueError(f"box '{name}' would overlap '{overlap[0]}' by {-overlap[1] * 1000:.1f} mm: place it where nothing is")
        self._boxes[name] = slot

    def remove_box(self, name: str) -> None:
        slot = self._boxes.pop(name)  # the world checks the name first
        self._park_box(slot)

    def _park_box(self, slot: int) -> None:
        self._set_box(slot, np.full(3, 0.01), np.array([0.0, 0.0, SIM_BOX_PARKED_Z]), np.array([1.0, 0.0, 0.0, 0.0]), shown=False)

    def _box_state(self, slot: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        mocap, geom = self._box_slots[slot]
        d, m = self.data, self.model
        return m.geom_size[geom].copy(), d.mocap_pos[mocap].copy(), d.mocap_quat[mocap].copy(), bool(m.geom_contype[geom])

    def _set_box(self, slot: int, half: np.ndarray, position: np.ndarray, quat: np.ndarray, shown: bool) -> None:
        mocap, geom = self._box_slots[slot]
        m, d = self.model, self.data
        m.geom_size[geom] = half
        m.geom_rbound[geom] = float(np.linalg.norm(half))  # the broadphase's bounding sphere
        m.geom_aabb[geom] = [0.0, 0.0, 0.0, *half]
        body = m.geom_bodyid[geom]  # the broadphase filters bodies first, by their compiled flags
        m.geom_contype[geom] = m.geom_conaffinity[geom] = m.body_contype[body] = m.body_conaffinity[body] = 1 if shown else 0
        m.geom_rgba[geom][3] = 1.0 if shown else 0.0
        d.mocap_pos[mocap] = position
        d.mocap_quat[mocap] = quat
        mujoco.mj_forward(m, d)  # place it now: contacts, cameras and sensors see it at once
        self._frames.clear()

    def _deepest_contact(self, geom: int) -> tuple[str, float] | None:
        """The body the geom penetrates most and the signed distance (m), or None."""
        d, m = self.data, self.model
        deepest: tuple[str, float] | None = None
        for i in range(d.ncon):
            contact = d.contact[i]
            if geom not in (contact.geom1, contact.geom2):
                continue
            other = contact.geom2 if contact.geom1 == geom else contact.geom1
            if deepest is None or contact.dist < deepest[1]:
                deepest = (m.body(m.geom_bodyid[other]).name, float(contact.dist))
        return deepest

    def step(self, dt: float) -> None:
        self._apply_external_wrench()
        model, data = self.model, self.data
        for _ in range(self._substeps(dt)):
            mujoco.mj_step(model, data)
        self.t += dt

    def _substeps(self, dt: float) -> int:
        """Physics steps in ``dt`` (at least one); remembered, as the world always asks the same."""
        if dt != self._substeps_dt:
            self._substeps_dt, self._substeps_count = dt, max(1, int(round(dt / self.model.opt.timestep)))
        return self._substeps_count

    def reset(self, seed: int, arm: np.ndarray) -> None:
        """Arm at ``arm``, gripper open, cubes at the layout of ``seed``, settled at rest."""
        mujoco.mj_resetData(self.model, self.data)
        for name in list(self._boxes):  # placed boxes go with the run that placed them
            self._park_box(self._boxes.pop(name))
        self.data.qpos[self._arm_qpos] = arm
        self.data.ctrl[self._arm_ctrl] = arm
        self.data.ctrl[self._gripper_ctrl] = 0.0
        half = self.options.cube_size / 2
        for color, (x, y, yaw) in layout(seed).items():
            adr = self._cube_qpos[color]
            self.data.qpos[adr:adr + 3] = (x, y, half)
            self.data.qpos[adr + 3:adr + 7] = _yaw_quat(yaw)
        mujoco.mj_forward(self.model, self.data)
        for _ in range(int(SETTLE_SECONDS / self.model.opt.timestep)):
            mujoco.mj_step(self.model, self.data)
        self._tare = self._wrench_minus()
        self._pushed = False  # mj_resetData cleared xfrc_applied
        self._frames.clear()

    def render(self, camera: str) -> np.ndarray:
        """An RGB frame of ``camera`` now (rendered once per instant, then cached)."""
        cached = self._frames.get(camera)
        if cached is not None and cached[0] == self.t:
            return cached[1]
        if camera not in CAMERA_NAMES:
            raise ValueError(f"unknown camera '{camera}' (cameras: {', '.join(CAMERA_NAMES)})")
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, self.options.image_height, self.options.image_width)
        self._renderer.update_scene(self.data, camera=camera)
        frame = self._renderer.render().copy()
        self.renders += 1
        self._frames[camera] = (self.t, frame)
        return frame

    def snapshot(self) -> mujoco.MjData:
        """A copy of the cell's state now, for ``render_snapshot`` on another thread."""
        return copy.copy(self.data)

    def render_snapshot(self, snapshot: mujoco.MjData, camera: str) -> np.ndarray:
        """An RGB frame of ``camera`` in the state ``snapshot`` (from ``snapshot()``), drawn with a
        renderer of the calling thread's own (``sim.camera_thread``; close it there with
        ``close_snapshot_renderer``)."""
        if self._snapshot_renderer is None:
            self._snapshot_renderer = mujoco.Renderer(self.model, self.options.image_height, self.options.image_width)
        self._snapshot_renderer.update_scene(snapshot, camera=camera)
        self.renders += 1
        return self._snapshot_renderer.render().copy()

    def close_snapshot_renderer(self) -> None:
        if self._snapshot_renderer is not None:
            self._snapshot_renderer.close()
            self._snapshot_renderer = None

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # -- internals --------------------------------------------------------------------------
    def _wrench_minus(self, tare: tuple[float, ...] = NO_TARE) -> tuple[float, ...]:
        """What the environment applies to the tool, in the world frame, about the sensor
        (Fx Fy Fz Tx Ty Tz), minus ``tare``.

        The sensors give what the wrist exerts on the gripper (site frame). At rest that support
        balances the gripper's weight plus the external wrench, so the external part is minus the
        support minus the weight, with the weight's torque taken about the gripper's current
        centre of mass: a constant tare alone would drift by ~0.4 Nm as the wrist turns.

        Written out in Python floats (rotation, lever arm, cross product): this runs at 500 Hz,
        and on 3-vectors each numpy call costs more than its arithmetic (18 us became ~4 us).
        """
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self._site_rotation.tolist()
        fx, fy, fz = self._support_force.tolist()
        tx, ty, tz = self._support_torque.tolist()
        (cx, cy, cz), (sx, sy, sz) = self._gripper_com.tolist(), self._site_position.tolist()
        lx, ly, lz = cx - sx, cy - sy, cz - sz
        wx, wy, wz = self._gripper_weight
        t0, t1, t2, t3, t4, t5 = tare
        return (
            -(r00 * fx + r01 * fy + r02 * fz) - wx - t0,
            -(r10 * fx + r11 * fy + r12 * fz) - wy - t1,
            -(r20 * fx + r21 * fy + r22 * fz) - wz - t2,
            -(r00 * tx + r01 * ty + r02 * tz) - (ly * wz - lz * wy) - t3,
            -(r10 * tx + r11 * ty + r12 * tz) - (lz * wx - lx * wz) - t4,
            -(r20 * tx + r21 * ty + r22 * tz) - (lx * wy - ly * wx) - t5,
        )

    def _apply_external_wrench(self) -> None:
        # On six Python floats (a NaN counts as a push): cheaper than numpy's reductions, every control step.
        pushing = any(self.external_wrench.tolist())
        if pushing or self._pushed:  # otherwise xfrc_applied is all zeros already
            self._xfrc_applied[:] = 0.0
            if pushing:
                self._xfrc_applied[self._ft_body] = self.external_wrench
        self._pushed = pushing
