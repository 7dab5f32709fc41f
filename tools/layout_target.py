"""An auxiliary training target that teaches a policy's vision where the cubes are.

Every recorded episode starts from ``sim.layouts.layout(seed)``, so each frame's cube layout is
known without any extra recording: for every cube (``CUBE_COLORS`` order) its x and y scaled to
[-1, 1] over the workspace band, and cos 4·yaw, sin 4·yaw (a cube looks the same every quarter
turn), ``LAYOUT_DIM`` numbers in all, or those of the cubes named (``colors``: e.g. only the blue
cube, the one the policy has to find among its look-alikes). The layout is the episode's start: a
cube the arm carries is still labelled where it started, which is where the policy has to go for it.

``LayoutProbe`` reads one camera's vision features while the policy runs its own ``forward``
(a forward hook on the module that outputs them) and fits a linear head from those features to
the layout; its mean squared error, times ``weight``, is added to the policy's loss
(``demo_training.train``'s ``auxiliary``). The gradient reaches the vision tower through the
features, so the tower must encode where the cubes are, linearly decodable; the action head then
learns from features that hold the answer. The head is training scaffolding: the checkpoint is
the LeRobot policy alone, unchanged at inference.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

from sim.cell_model import CUBE_COLORS
from sim.layouts import DEFAULT_WORKSPACE, layout

LAYOUT_DIM = 4 * len(CUBE_COLORS)


def layout_vector(seed: int, colors: tuple[str, ...] = tuple(CUBE_COLORS)) -> list[float]:
    """The target for an episode of layout ``seed``: four numbers per cube of ``colors`` (see the module doc)."""
    cubes = layout(seed)
    (x_low, x_high), (y_low, y_high) = DEFAULT_WORKSPACE.x_range, DEFAULT_WORKSPACE.y_range
    vector: list[float] = []
    for color in colors:
        x, y, yaw = cubes[color]
        vector += [2 * (x - x_low) / (x_high - x_low) - 1, 2 * (y - y_low) / (y_high - y_low) - 1,
                   math.cos(4 * yaw), math.sin(4 * yaw)]
    return vector


def cube_errors_cm(predicted: Any, truth: Any) -> dict[str, float]:
    """Per cube, the median distance (cm) between the positions of two sets of layout vectors
    (rows of all ``LAYOUT_DIM`` numbers, as :func:`layout_vector` writes them)."""
    import numpy as np

    half_range_cm = 50.0 * np.array([DEFAULT_WORKSPACE.x_range[1] - DEFAULT_WORKSPACE.x_range[0],
                                     DEFAULT_WORKSPACE.y_range[1] - DEFAULT_WORKSPACE.y_range[0]])
    errors = {}
    for index, color in enumerate(CUBE_COLORS):
        position = slice(4 * index, 4 * index + 2)
        distance = np.linalg.norm((np.asarray(predicted)[:, position] - np.asarray(truth)[:, position]) * half_range_cm, axis=1)
        errors[color] = round(float(np.median(distance)), 2)
    return errors


def checked_colors(colors: Sequence[str]) -> tuple[str, ...]:
    """``colors`` as a tuple when each names a cube (SystemExit naming the cubes otherwise)."""
    if not colors or any(color not in CUBE_COLORS for color in colors):
        raise SystemExit(f"--layout-cubes {','.join(colors)}: the cubes are {', '.join(CUBE_COLORS)}")
    return tuple(colors)


def layout_targets(episode_seeds: list[int], episode: Any, colors: tuple[str, ...] = tuple(CUBE_COLORS)) -> Any:
    """(rows, 4 x len(``colors``)) float tensor: the layout of each row's episode (``episode``: a
    row's index into ``episode_seeds``)."""
    import torch

    if not episode_seeds:
        raise SystemExit("--layout-target needs datasets recorded by `objective record-demos` (meta/demos.json holds their seeds)")
    table = torch.tensor([layout_vector(seed, checked_colors(colors)) for seed in episode_seeds], dtype=torch.float32)
    return table[episode]


class LayoutProbe:
    """A linear read-out of the layout from the output of ``module``'s ``call``-th call (0-based)
    in each policy forward of ``calls`` calls (one per camera: the camera to read)."""

    def __init__(self, module: Any, call: int, calls: int, features_dim: int, targets: Any, weight: float) -> None:
        import torch

        if not 0 <= call < calls:
            raise ValueError(f"LayoutProbe: call {call} is not one of the {calls} calls per forward")
        self.targets, self.weight, self.call, self.calls = targets, weight, call, calls
        self.head = torch.nn.Linear(features_dim, targets.shape[1])
        """Its parameters go to the optimizer with the policy's."""
        torch.nn.init.zeros_(self.head.weight)
        torch.nn.init.zeros_(self.head.bias)
        self._count = 0
        self._features: Any = None
        self._hook = module.register_forward_hook(self._capture)

    def _capture(self, module: Any, inputs: Any, output: Any) -> None:
        if self._count % self.calls == self.call:
            self._features = output
        self._count += 1

    def __call__(self, rows: Any) -> Any:
        """The weighted auxiliary loss of the forward just run on ``rows``."""
        import torch

        if self._features is None:
            raise RuntimeError("LayoutProbe: no features captured (the hooked module did not run in the forward)")
        features = self._features.flatten(1)
        self._features, self._count = None, 0
        return self.weight * torch.nn.functional.mse_loss(self.head(features), self.targets[rows])

    def remove(self) -> None:
        self._hook.remove()
