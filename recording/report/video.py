"""``cameras.mp4``: the camera views a policy was given, side by side, one video frame per request.

The frames are the ones recorded from the GetActionChunk requests (nothing is rendered for the
video), so the video shows exactly what the policy saw, at the instants it saw it. Views are
scaled (nearest neighbour) to a common height of at least ``MIN_HEIGHT`` pixels so the tiny
frames of the kinematic world stay visible; H.264 needs even sizes, so the mosaic is padded.
The recording worker encodes each frame as its request arrives (``VideoEncoder``), so after the
run only the file's end is left to write.
"""
from __future__ import annotations

import contextlib
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .data import CameraFrame

MIN_HEIGHT = 240
FPS = 4.0


def scale_to_height(pixels: NDArray[np.uint8], height: int) -> NDArray[np.uint8]:
    """Nearest-neighbour resize of an H x W x 3 image to ``height`` rows, keeping its aspect."""
    h, w = pixels.shape[:2]
    width = max(1, round(w * height / h))
    rows = (np.arange(height) * h // height).clip(0, h - 1)
    cols = (np.arange(width) * w // width).clip(0, w - 1)
    result: NDArray[np.uint8] = pixels[rows][:, cols]
    return result


def mosaic(frame: CameraFrame, height: int) -> NDArray[np.uint8]:
    """The frame's views in a row, each ``height`` pixels high, padded to even dimensions."""
    tiles = [scale_to_height(view, height) for _, view in frame.views]
    row = np.concatenate(tiles, axis=1)
    pad_h, pad_w = row.shape[0] % 2, row.shape[1] % 2
    if pad_h or pad_w:
        row = np.pad(row, ((0, pad_h), (0, pad_w), (0, 0)))
    return row


def fit(image: NDArray[np.uint8], height: int, width: int) -> NDArray[np.uint8]:
    """``image`` in a ``height`` x ``width`` video frame: scaled down (keeping its aspect) if it is
    wider, padded with black on the right and bottom."""
    if image.shape[1] > width:
        image = scale_to_height(image, max(2, image.shape[0] * width // image.shape[1]))[:, :width]
    return np.pad(image, ((0, height - image.shape[0]), (0, width - image.shape[1]), (0, 0)))


class VideoEncoder:
    """``cameras.mp4`` written one frame at a time, as the frames arrive (imageio-ffmpeg's bundled
    ffmpeg, H.264): the first frame sets the video's size (its views scaled to at least
    ``MIN_HEIGHT`` pixels high); later frames are scaled to that height and fitted to its width.

    The frames go to ``cameras.<pid>.part.mp4``, renamed to ``path`` by ``close``: a worker killed
    while encoding never leaves a broken ``cameras.mp4``, nor writes into one rendered again. A
    failure is kept and raised by ``close``, so a broken video never interrupts the recording.
    """

    def __init__(self, path: Path, fps: float = FPS) -> None:
        self.path = path
        self.partial_path = path.with_name(f"{path.stem}.{os.getpid()}.part{path.suffix}")
        self.fps = fps
        self.frames = 0
        self._writer: Any = None
        self._size: tuple[int, int] | None = None
        self._error: Exception | None = None
        self._closing: threading.Thread | None = None

    def add(self, frame: CameraFrame) -> None:
        if self._error is not None:
            return
        try:
            self._add(frame)
        except Exception as err:
            self._error = err

    def _add(self, frame: CameraFrame) -> None:
        if self._size is None:
            import imageio.v2 as imageio

            height = max(MIN_HEIGHT, max(view.shape[0] for _, view in frame.views))
            height += height % 2
            self._size = (height, mosaic(frame, height).shape[1])
            self.partial_path.unlink(missing_ok=True)  # ffmpeg writes a new file, never through a link left there
            self._writer = imageio.get_writer(self.partial_path, fps=self.fps, codec="libx264", macro_block_size=1,
                                              pixelformat="yuv420p", output_params=["-movflags", "+faststart"])
        height, width = self._size
        self._writer.append_data(fit(mosaic(frame, height), height, width))
        self.frames += 1

    def close_soon(self) -> None:
        """Start finishing the file on a thread (ffmpeg encodes its last frames meanwhile); no
        frame may be added after it, and ``close`` waits for it."""
        if self._closing is None:
            self._closing = threading.Thread(target=self._close_writer, daemon=True)
            self._closing.start()

    def _close_writer(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.close()
            except Exception as err:
                self._error = self._error or err

    def close(self) -> Path:
        """Finish the file; ValueError if no frame came, the first failure if one failed."""
        if self._closing is not None:
            self._closing.join()
        else:
            self._close_writer()
        if self._error is not None:
            self.partial_path.unlink(missing_ok=True)
            raise self._error
        if self.frames == 0:
            raise ValueError("no camera frames were recorded (no policy request carried images)")
        os.replace(self.partial_path, self.path)
        return self.path

    def discard(self) -> None:
        """Stop encoding and remove the file (the run died: no report is rendered)."""
        if self._closing is not None:
            self._closing.join()
        writer, self._writer = self._writer, None
        if writer is not None:
            with contextlib.suppress(Exception):
                writer.close()
        self.partial_path.unlink(missing_ok=True)


def camera_video(frames: list[CameraFrame], path: Path, fps: float = FPS) -> Path:
    """Write ``frames`` as an H.264 MP4, one video frame each (``VideoEncoder``'s sizing), and
    remove what a recording worker killed while encoding left."""
    encoder = VideoEncoder(path, fps)
    for frame in frames:
        encoder.add(frame)
    encoder.close()
    for stale in path.parent.glob(f"{path.stem}.*.part{path.suffix}"):
        stale.unlink(missing_ok=True)
    return path
