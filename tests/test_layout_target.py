"""The cube layout as an auxiliary training target of a policy's vision (tools/layout_target.py):
the target itself (always run), the probe on a toy module, and the training script with it
(skipped without `make lerobot`)."""
from __future__ import annotations

import importlib.util
import json
import math
import runpy
from pathlib import Path

import numpy as np
import pytest

from sim.layouts import layout
from tools.layout_target import LAYOUT_DIM, layout_vector

ROOT = Path(__file__).resolve().parent.parent
needs_torch = pytest.mark.skipif(importlib.util.find_spec("torch") is None, reason="torch is not in this venv")
needs_lerobot = pytest.mark.skipif(
    importlib.util.find_spec("lerobot") is None or importlib.util.find_spec("torch") is None,
    reason="the LeRobot extra is not installed (make lerobot)",
)


def test_the_layout_vector_scales_each_cube_into_the_workspace_and_folds_its_yaw_by_quarter_turns():
    for seed in (0, 100, 1000, 1119):
        vector = layout_vector(seed)
        assert len(vector) == LAYOUT_DIM == 4 * len(layout(seed))
        assert all(-1.0 <= v <= 1.0 for v in vector)
    blue = layout(1000)["blue"]
    x, y, cos4, sin4 = layout_vector(1000)[4 * list(layout(1000)).index("blue"):][:4]
    assert x == pytest.approx(2 * (blue[0] + 0.25) / 0.5 - 1) and y == pytest.approx(2 * (blue[1] - 0.32) / 0.28 - 1)
    assert (cos4, sin4) == pytest.approx((math.cos(4 * blue[2]), math.sin(4 * blue[2])))
    assert layout_vector(1000) == layout_vector(1000) and layout_vector(1000) != layout_vector(1001)


def test_cube_errors_are_distances_on_the_table_per_cube():
    from tools.layout_target import cube_errors_cm

    truth = np.array([layout_vector(seed) for seed in (1000, 1001, 1002)])
    moved = truth.copy()
    blue = 4 * list(layout(1000)).index("blue")
    moved[:, blue] += 0.2  # a fifth of the half range in x: 5 cm
    moved[:, blue + 1] += 0.5  # half of the half range in y: 7 cm
    assert cube_errors_cm(moved, truth) == {"red": 0.0, "green": 0.0, "blue": pytest.approx(math.hypot(5.0, 7.0), abs=0.01)}


@needs_torch
def test_the_target_can_hold_only_the_cubes_named():
    import torch

    from tools.layout_target import LayoutProbe, layout_targets

    blue_only = layout_targets([1000, 1001], torch.tensor([1, 0]), ("blue",))
    everything = layout_targets([1000, 1001], torch.tensor([1, 0]))
    column = 4 * list(layout(1000)).index("blue")
    assert blue_only.shape == (2, 4) and torch.equal(blue_only, everything[:, column:column + 4])
    assert LayoutProbe(torch.nn.Linear(3, 5), 0, 1, 5, blue_only, 1.0).head.out_features == 4
    with pytest.raises(SystemExit, match="--layout-cubes blue,yellow: the cubes are red, green, blue"):
        layout_targets([1000], torch.tensor([0]), ("blue", "yellow"))


@needs_torch
def test_the_probe_reads_its_camera_s_call_and_teaches_the_module_the_layout():
    # Two calls per forward (two cameras); the probe reads the second. Its loss starts at the
    # targets' mean square (the head starts at zero) and its gradient reaches the hooked module.
    import torch

    from tools.layout_target import LayoutProbe, layout_targets

    torch.manual_seed(0)
    module = torch.nn.Linear(3, 5)
    targets = layout_targets([1000, 1001, 1002], torch.tensor([0, 1, 2, 2]))
    assert targets.shape == (4, LAYOUT_DIM) and torch.equal(targets[2], targets[3])
    probe = LayoutProbe(module, call=1, calls=2, features_dim=5, targets=targets, weight=2.0)
    seen = torch.randn(4, 3)
    module(torch.randn(4, 3))  # the first camera: not read
    module(seen)
    rows = torch.tensor([0, 1, 2, 3])
    loss = probe(rows)
    assert float(loss) == pytest.approx(2.0 * float((targets ** 2).mean()))
    optimizer = torch.optim.SGD([*module.parameters(), *probe.head.parameters()], lr=0.1)
    optimizer.zero_grad()
    loss.backward()
    # The head learns from the first step; the module is reached through the head's weights, zero
    # at first, so from the second step on.
    assert float(probe.head.weight.grad.abs().sum()) > 0.0 and float(module.weight.grad.abs().sum()) == 0.0
    optimizer.step()
    module(torch.randn(4, 3)), module(seen)
    optimizer.zero_grad()
    probe(rows).backward()
    assert float(module.weight.grad.abs().sum()) > 0.0
    with pytest.raises(RuntimeError, match="no features captured"):
        probe(rows)  # nothing ran since the last loss
    probe.remove()
    module(seen), module(seen)
    with pytest.raises(RuntimeError, match="no features captured"):
        probe(rows)
    with pytest.raises(ValueError, match="call 2 is not one of the 2 calls"):
        LayoutProbe(module, call=2, calls=2, features_dim=5, targets=targets, weight=1.0)


@needs_lerobot
def test_the_tiny_smolvla_trains_with_the_layout_target_and_records_it(tmp_path, capsys):
    train = runpy.run_path(str(ROOT / "tools" / "train_tiny_smolvla.py"))
    dataset, out = tmp_path / "demos", tmp_path / "policy"
    common = ["--dataset", str(dataset), "--episodes", "2", "--demo-seed", "0", "--world", "kinematic", "--image-size", "32",
              "--record-steps", "30", "--keep-failed", "--workers", "2", "--steps", "3", "--batch", "4", "--eval-episodes", "0"]
    assert train["main"]([*common, "--out", str(out), "--layout-target", "1.0", "--layout-camera", "overview"]) == 0
    training = json.loads((out / "objective_policy.json").read_text())["training"]
    assert training["layout_target"] == {"weight": 1.0, "camera": "overview", "cubes": ["red", "green", "blue"]} and training["steps"] == 3
    assert train["main"]([*common, "--out", str(tmp_path / "plan"), "--layout-target", "1.0", "--plan-layouts", "2",
                          "--plan-seed", "40000", "--plan-every", "10", "--plan-share", "0.5", "--workers", "1",
                          "--plan-cache", str(tmp_path / "plan_frames")]) == 0
    training = json.loads((tmp_path / "plan" / "objective_policy.json").read_text())["training"]
    assert training["plan_frames"] == {"layouts": 2, "early_layouts": 0, "seed": 40000, "every": 10, "share": 0.5, "noise": None, "detour_m": 0.0, "detour_descent": False}
    # The per-cube probe of that checkpoint's features: fitted on one plan layout, validated on the
    # other, tested on the two recorded episodes; the blind answer is the fitted layout itself.
    from tools.layout_target import cube_errors_cm

    probe = runpy.run_path(str(ROOT / "tools" / "vision_probe.py"))
    plan_file = next((tmp_path / "plan_frames").glob("*.npz"))
    capsys.readouterr()
    assert probe["main"](["--checkpoint", str(tmp_path / "plan"), "--plan-frames", str(plan_file),
                          "--dataset", str(dataset), "--camera", "overview"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (report["fit_layouts"], report["validation_layouts"], report["recorded_episodes"]) == (1, 1, 2)
    assert set(report["recorded_cm"]) == {"red", "green", "blue"}
    assert report["blind_recorded_cm"] == cube_errors_cm(np.array([layout_vector(40000)] * 2),
                                                         np.array([layout_vector(0), layout_vector(1)]))
    with pytest.raises(SystemExit, match=r"--camera top: .*\.npz holds \[overview, scene, wrist\]"):
        probe["main"](["--checkpoint", str(tmp_path / "plan"), "--plan-frames", str(plan_file), "--dataset", str(dataset),
                       "--camera", "top"])
    with pytest.raises(SystemExit, match=r"--plan-seed 99: the plan layouts would include demonstration or "
                                         r"held-out seeds \(100..100\)"):
        train["main"]([*common, "--out", str(tmp_path / "other"), "--plan-layouts", "2", "--plan-seed", "99"])
    with pytest.raises(SystemExit, match=r"--layout-camera top: the policy sees \[scene, wrist, overview\]"):
        train["main"]([*common, "--out", str(tmp_path / "other"), "--layout-target", "1.0", "--layout-camera", "top"])
    with pytest.raises(SystemExit, match=r"--plan-early-layouts needs --early-frames >= 1"):
        train["main"]([*common, "--out", str(tmp_path / "other"), "--plan-early-layouts", "2"])
    # Early layouts join the full ones; the layout target covers their rows too.
    assert train["main"]([*common, "--out", str(tmp_path / "early"), "--layout-target", "1.0", "--plan-layouts", "1",
                          "--plan-early-layouts", "2", "--plan-seed", "40000", "--plan-every", "5", "--plan-share", "0.5",
                          "--early-frames", "10", "--early-share", "0.5", "--workers", "1",
                          "--plan-cache", str(tmp_path / "early_frames")]) == 0
    training = json.loads((tmp_path / "early" / "objective_policy.json").read_text())["training"]
    assert training["plan_frames"]["layouts"] == 1 and training["plan_frames"]["early_layouts"] == 2
    assert len(list((tmp_path / "early_frames").glob("*.npz"))) == 2
