"""``cameras.mp4``: the camera views a policy was given, side by side, one video frame per request.

The frames are the ones recorded from the GetActionChunk requests (nothing is rendered for the
video), so the video shows exactly what the policy saw, at the instants it saw it. Views are
scaled (nearest neighbour) to a common height of at least ``MIN_HEIGHT`` pixels so the tiny
frames of the kinematic world stay visible; H.264 needs even sizes, so the mosaic is padded.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .data import CameraFrame

MIN_HEIGHT = 240
FPS = 4.0


def scale_to_height(pixels: np.ndarray, height: int) -> np.ndarray:
    """Nearest-neighbour resize of an H x W x 3 image to ``height`` rows, keeping its aspect."""
    h, w = pixels.shape[:2]
    width = max(1, round(w * height / h))
    rows = (np.arange(height) * h // height).clip(0, h - 1)
    cols = (np.arange(width) * w // width).clip(0, w - 1)
    return pixels[rows][:, cols]


def mosaic(frame: CameraFrame, height: int) -> np.ndarray:
    """The frame's views in a row, each ``height`` pixels high, padded to even dimensions."""
    tiles = [scale_to_height(view, height) for _, view in frame.views]
    row = np.concatenate(tiles, axis=1)
    pad_h, pad_w = row.shape[0] % 2, row.shape[1] % 2
    if pad_h or pad_w:
        row = np.pad(row, ((0, pad_h), (0, pad_w), (0, 0)))
    return row


def camera_video(frames: list[CameraFrame], path: Path, fps: float = FPS) -> Path:
    """Write ``frames`` as an H.264 MP4 (imageio-ffmpeg's bundled ffmpeg); one video frame each."""
    import imageio.v2 as imageio

    if not frames:
        raise ValueError("no camera frames were recorded (no policy request carried images)")
    height = max(MIN_HEIGHT, max(view.shape[0] for f in frames for _, view in f.views))
    height += height % 2
    images = [mosaic(f, height) for f in frames]
    width = max(image.shape[1] for image in images)
    writer = imageio.get_writer(path, fps=fps, codec="libx264", macro_block_size=1, pixelformat="yuv420p",
                                output_params=["-movflags", "+faststart"])
    try:
        for image in images:
            if image.shape[1] < width:  # a request with fewer views: pad to the video's width
                image = np.pad(image, ((0, 0), (0, width - image.shape[1]), (0, 0)))
            writer.append_data(image)
    finally:
        writer.close()
    return path
