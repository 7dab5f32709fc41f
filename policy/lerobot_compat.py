"""Make ``import torchvision`` work next to the CPU-only torch wheel, before LeRobot imports it.

Why this exists: the only torch that installs here without gigabytes of CUDA packages is the local
``torch==2.13.0+cpu`` wheel, and the torchvision release built for it (0.28.0) ships a compiled
``_C.so`` linked against the CUDA build of torch. Loading it fails (``libc10.so`` not found),
torchvision silently carries on without its C++ ops, and then its own ``_meta_registrations``
module registers fake kernels for ``torchvision::nms`` / ``torchvision::qnms`` unconditionally,
so ``import torchvision`` dies with "operator torchvision::nms does not exist". Every LeRobot policy
module imports torchvision, so without a remedy no LeRobot policy can be imported at all.

The remedy, applied once per process by :func:`ensure_torchvision`:

1. try to load ``torchvision/_C.so`` the way torchvision would; if it loads (a matching torch
   build), nothing else is done;
2. otherwise define the two operator schemas torchvision's import expects, ``torchvision::nms`` and
   ``torchvision::qnms``, with a pure-torch greedy non-maximum suppression as their CPU kernel.

What LeRobot uses of torchvision (resnets, ``transforms.v2``, ``FrozenBatchNorm2d``) is pure Python
on top of torch. torchvision itself still reports that its C++ ops are missing: ``torchvision.ops.nms``
and the other compiled ops (roi_align, deform_conv2d, image decoding) raise its own "Couldn't load
custom C++ ops" error if called; ``torch.ops.torchvision.nms`` runs the pure-torch kernel.

Call :func:`ensure_torchvision` before anything imports torchvision or lerobot; the LeRobot modules
of this project (``lerobot_backend``, ``tiny_smolvla``, the demo and training tools) do so at import.
"""
from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

OFFLINE_ENV = {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
"""Every hub access must fail fast: nothing here may download at run time."""

_operator_library = None
"""The ``torch.library.Library`` holding the fallback schemas. torch keeps an operator registered only
while its Library object lives, so the reference must outlive this module's callers."""


def force_offline() -> None:
    """Set the Hugging Face offline switches (before ``huggingface_hub`` reads them at import)."""
    for key, value in OFFLINE_ENV.items():
        os.environ[key] = value


def ensure_torchvision() -> str:
    """Make ``import torchvision`` succeed; returns ``"native"`` or ``"fallback"`` (what was done).

    Idempotent. Raises ImportError naming the cause when torch or torchvision is not installed.
    """
    force_offline()
    if "torchvision" in sys.modules:
        return "fallback" if _operator_library is not None else "native"
    import torch

    if _torchvision_ops_exist(torch):
        return "fallback" if _operator_library is not None else "native"
    spec = importlib.util.find_spec("torchvision")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("torchvision is not installed: run `make lerobot` and use .venv-lerobot (Python 3.11)")
    native = Path(next(iter(spec.submodule_search_locations))) / "_C.so"
    if native.is_file():
        try:
            torch.ops.load_library(str(native))
            return "native"
        except (OSError, RuntimeError):
            pass
    _define_fallback_ops(torch)
    return "fallback"


def _torchvision_ops_exist(torch) -> bool:
    try:
        torch.ops.torchvision.nms.default
    except (AttributeError, RuntimeError):
        return False
    return True


def _define_fallback_ops(torch) -> None:
    global _operator_library
    library = torch.library.Library("torchvision", "DEF")
    library.define("nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
    library.define("qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
    library.impl("nms", nms_reference, "CPU")
    library.impl("qnms", _qnms_reference, "QuantizedCPU")
    _operator_library = library


def nms_reference(dets, scores, iou_threshold: float):
    """Greedy non-maximum suppression, as torchvision's CPU kernel: indices kept, by falling score.

    ``dets`` is (N, 4) boxes as (x1, y1, x2, y2); a box is dropped when its IoU with a kept,
    higher-scoring box is strictly greater than ``iou_threshold``.
    """
    import torch

    if dets.numel() == 0:
        return torch.empty(0, dtype=torch.long, device=dets.device)
    x1, y1, x2, y2 = dets.unbind(1)
    areas = (x2 - x1) * (y2 - y1)
    order = scores.argsort(descending=True)
    suppressed = torch.zeros(dets.shape[0], dtype=torch.bool, device=dets.device)
    keep = []
    for index in order.tolist():
        if suppressed[index]:
            continue
        keep.append(index)
        width = (torch.minimum(x2[index], x2) - torch.maximum(x1[index], x1)).clamp(min=0)
        height = (torch.minimum(y2[index], y2) - torch.maximum(y1[index], y1)).clamp(min=0)
        overlap = width * height
        iou = overlap / (areas[index] + areas - overlap)
        suppressed |= iou > iou_threshold
    return torch.tensor(keep, dtype=torch.long, device=dets.device)


def _qnms_reference(dets, scores, iou_threshold: float):
    return nms_reference(dets.dequantize(), scores.dequantize(), iou_threshold)
