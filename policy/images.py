"""``sensor_msgs/Image`` <-> numpy, for policy adapters.

Frames arrive as captured, so the adapter owns the encoding conversion (the guide: "check the
bgr8/rgb8 conversion", a silent failure mode). Every frame handed to a backend is
H x W x 3 uint8 RGB whatever the camera sent: ``bgr8`` is reversed channel-wise and ``mono8``
is replicated to three channels, so a backend has one format to handle.

Rows may be padded (``step`` larger than ``width * channels``); the padding is dropped.
Anything inconsistent (unknown encoding, short buffer, step too small) raises ``ImageError``
naming the image, because a wrong camera-to-slot mapping is otherwise invisible.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import Image

from runtime.errors import ObjectiveError

CHANNELS = {"rgb8": 3, "bgr8": 3, "mono8": 1}
"""Encodings understood, with their channel counts (all 8 bits per channel)."""


class ImageError(ObjectiveError, ValueError):
    """A frame cannot be read; the message names the image and what is wrong."""


def image_to_rgb(msg: Image, name: str = "") -> NDArray[np.uint8]:
    """An H x W x 3 uint8 RGB copy of ``msg`` (``name`` is used in error messages)."""
    label = f"image '{name}'" if name else "image"
    encoding = msg.encoding.lower()
    channels = CHANNELS.get(encoding)
    if channels is None:
        raise ImageError(
            f"{label}: unsupported encoding '{msg.encoding}' (expected one of {', '.join(CHANNELS)})"
        )
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        raise ImageError(f"{label}: empty frame ({width} x {height})")
    row_bytes = width * channels
    if step < row_bytes:
        raise ImageError(
            f"{label}: step {step} is smaller than width {width} x {channels} channel(s) = {row_bytes} bytes"
        )
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if data.size != step * height:
        raise ImageError(
            f"{label}: data has {data.size} bytes, expected step {step} x height {height} = {step * height}"
        )
    pixels = data.reshape(height, step)[:, :row_bytes].reshape(height, width, channels)
    if encoding == "bgr8":
        return np.ascontiguousarray(pixels[:, :, ::-1])
    if encoding == "mono8":
        return np.repeat(pixels, 3, axis=2)
    return pixels.copy()


def rgb_to_image(pixels: NDArray[np.uint8], encoding: str = "rgb8", frame_id: str = "") -> Image:
    """A ``sensor_msgs/Image`` from an H x W x 3 RGB (or H x W mono) uint8 array.

    ``encoding`` picks the wire format: ``rgb8`` as is, ``bgr8`` with the channels reversed,
    ``mono8`` from an H x W array (or the mean of an RGB one).
    """
    array = np.asarray(pixels)
    if array.dtype != np.uint8:
        raise ImageError(f"image pixels must be uint8, got {array.dtype}")
    encoding = encoding.lower()
    if encoding not in CHANNELS:
        raise ImageError(f"unsupported encoding '{encoding}' (expected one of {', '.join(CHANNELS)})")
    if encoding == "mono8":
        if array.ndim == 3:
            array = array.mean(axis=2).round().astype(np.uint8)
        if array.ndim != 2:
            raise ImageError(f"mono8 image needs an H x W array, got shape {array.shape}")
    elif array.ndim != 3 or array.shape[2] != 3:
        raise ImageError(f"{encoding} image needs an H x W x 3 array, got shape {array.shape}")
    elif encoding == "bgr8":
        array = array[:, :, ::-1]
    array = np.ascontiguousarray(array)
    msg = Image()
    msg.header.frame_id = frame_id
    msg.height, msg.width = int(array.shape[0]), int(array.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = int(array.shape[1] * CHANNELS[encoding])
    msg.data = array.tobytes()
    return msg
