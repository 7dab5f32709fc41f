"""The simulated UR5e + 2F-85 cell: MuJoCo and kinematic worlds, controllers, the oracle.

MuJoCo renders offscreen here (``MUJOCO_GL=egl`` unless the user chose a backend): set before any
module of this package imports mujoco, since its GL backend is fixed at import.
"""
import os

os.environ.setdefault("MUJOCO_GL", "egl")
