"""The simulated UR5e + 2F-85 cell: MuJoCo and kinematic worlds, controllers, the oracle.

MuJoCo renders offscreen here (``MUJOCO_GL=egl`` unless the user chose a backend): set before any
module of this package imports mujoco, since its GL backend is fixed at import. A ``MUJOCO_GL``
that names no backend is an OptionError here, before mujoco's import fails on it with a bare
RuntimeError.
"""
import os

from runtime.errors import OptionError

MUJOCO_GL_VALUES = frozenset({"egl", "osmesa", "glfw", "glx", "", "enable", "enabled", "on", "true", "1",
                              "disable", "disabled", "off", "false", "0"})
"""What MuJoCo's Python bindings accept as ``MUJOCO_GL`` on Linux (mujoco/rendering/classic/gl_context.py)."""


def mujoco_gl_problem(value: str) -> str | None:
    """What is wrong with ``value`` as ``MUJOCO_GL``, or None."""
    if value.lower().strip() in MUJOCO_GL_VALUES:
        return None
    return f"MUJOCO_GL={value!r} names no rendering backend: the cell renders offscreen with egl (the default) or osmesa"


os.environ.setdefault("MUJOCO_GL", "egl")
_problem = mujoco_gl_problem(os.environ["MUJOCO_GL"])
if _problem is not None:
    raise OptionError(_problem)
