"""A perception stage on the policy side: where the cubes are, read from two fixed cameras' frames.

The learned stacking policy (``tools/train_learned.py``) sees the cubes only through this: the
request's RGB frames of two fixed cameras (``position``: a cube's x, y; ``yaw``: its face heading
when it shows the cube whole), their poses and fields of view (the policy's configuration, kept in
the checkpoint's ``objective_policy.json`` like its normalisation), and the cubes' colours and
size. Never the simulator's state.

How a cube is located (pure functions, numpy only):

1. **Colour.** A pixel belongs to a cube when the cube's colour channel dominates the other two by
   ``dominance`` (ratio) and is at least ``min_channel`` bright: the shading of a face changes the
   brightness, not which channel leads. The table (wood), the robot (grey, light blue caps) and
   the floor do not pass for blue or green.
2. **Back-projection.** Every cube pixel's ray (a pinhole camera, MuJoCo's convention: it looks
   along its -z axis, +y up in the image, square pixels, ``fovy`` vertical) is cut with the
   horizontal plane of the view's ``plane_z_m`` (the cubes' centres for the oblique scene camera,
   their top faces for the overview camera looking straight down); the cube's x, y is the mean of
   those points.
3. **Yaw.** A square's corners lie farthest from its centre, at the face heading + 45 degrees, every
   quarter turn: the fourth-order moment ``sum r^4 exp(4 i theta)`` of the points about their mean
   points there, so the face heading is ``arg(-moment) / 4``, in [-pi/4, pi/4) like
   ``sim.oracle.cube_yaw``.

A cube with fewer than ``min_pixels`` pixels (hidden, or out of the frame) raises ``CubeNotFound``.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence, cast

import numpy as np
from numpy.typing import NDArray

from runtime.errors import ObjectiveError

COLOR_CHANNEL = {"red": 0, "green": 1, "blue": 2}


Vector3 = tuple[float, float, float]


class CubeNotFound(ObjectiveError, ValueError):
    """A cube's colour is not (or too little) in the frame."""


@dataclass(frozen=True)
class PinholeCamera:
    """A fixed camera: position (m, world), orientation (world-from-camera rotation, rows), fovy."""

    position_m: Vector3
    rotation: tuple[Vector3, ...]
    """3 x 3: its columns are the camera's x (image right), y (image up) and z (out of the lens, backwards)."""
    fovy_deg: float

    def rays(self, rows: NDArray[np.intp], columns: NDArray[np.intp], height: int, width: int) -> NDArray[np.float64]:
        """World directions (N, 3) through the centres of pixels (rows, columns) of a height x width frame."""
        focal = (height / 2.0) / math.tan(math.radians(self.fovy_deg) / 2.0)
        local = np.stack([(columns + 0.5 - width / 2.0) / focal, -(rows + 0.5 - height / 2.0) / focal,
                          -np.ones(len(rows))], axis=1)
        result: NDArray[np.float64] = local @ np.asarray(self.rotation, dtype=float).T
        return result


@dataclass(frozen=True)
class CameraView:
    """One request image, its camera, and the plane its cube pixels are back-projected onto."""

    image: str
    camera: PinholeCamera
    plane_z_m: float

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> CameraView:
        camera = data["camera"]
        return cls(str(data["image"]),
                   PinholeCamera(cast(Vector3, tuple(float(v) for v in camera["position_m"])),  # written by to_json: 3 each
                                 tuple(cast(Vector3, tuple(float(v) for v in row)) for row in camera["rotation"]),
                                 float(camera["fovy_deg"])),
                   float(data["plane_z_m"]))


@dataclass(frozen=True)
class CubeLocatorConfig:
    """What the locator knows: where a cube's position and yaw are read, the cubes' colours and size."""

    position: CameraView
    """The view a cube's x, y comes from (the scene camera: it sees the table past the arm at Home)."""
    yaw: CameraView
    """The view a cube's yaw comes from when it shows the cube whole (the overview camera, looking down)."""
    cube_size_m: float = 0.03
    colors: tuple[str, ...] = ("blue", "green")
    """The cubes located, in the order of the features (x, y, yaw per cube)."""
    dominance: float = 1.5
    min_channel: int = 50
    min_pixels: int = 4
    whole_share: float = 0.8
    """The yaw view counts as showing a cube whole from this share of the top face's expected pixels;
    with fewer (the arm hides part of it) the yaw comes from the position view."""

    def images(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys((self.position.image, self.yaw.image)))

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any], where: str) -> CubeLocatorConfig:
        try:
            return cls(
                position=CameraView.from_json(data["position"]), yaw=CameraView.from_json(data["yaw"]),
                cube_size_m=float(data.get("cube_size_m", cls.cube_size_m)),
                colors=tuple(str(c) for c in data.get("colors", cls.colors)),
                dominance=float(data.get("dominance", cls.dominance)),
                min_channel=int(data.get("min_channel", cls.min_channel)),
                min_pixels=int(data.get("min_pixels", cls.min_pixels)),
                whole_share=float(data.get("whole_share", cls.whole_share)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ObjectiveError(f"{where}: cube_locator is not a valid locator configuration ({exc!r})") from None


@dataclass(frozen=True)
class LocatedCube:
    x_m: float
    y_m: float
    yaw_rad: float
    """Face heading in [-pi/4, pi/4)."""
    pixels: int


def color_mask(rgb: NDArray[np.uint8], color: str, dominance: float, min_channel: int) -> NDArray[np.bool_]:
    """H x W bool: pixels whose ``color`` channel leads the other two by ``dominance`` and is bright enough."""
    channel = COLOR_CHANNEL[color]
    values = rgb.astype(np.int32)
    lead = values[..., channel]
    others = np.max(np.delete(values, channel, axis=-1), axis=-1)
    result: NDArray[np.bool_] = (lead >= min_channel) & (lead * 10 >= np.round(dominance * 10) * others)
    return result


def plane_points(camera: PinholeCamera, rows: NDArray[np.intp], columns: NDArray[np.intp], height: int, width: int,
                 plane_z_m: float) -> NDArray[np.float64]:
    """(N, 2) x, y where the pixels' rays cross the plane z = ``plane_z_m``."""
    rays = camera.rays(rows.astype(float), columns.astype(float), height, width)
    origin = np.asarray(camera.position_m, dtype=float)
    scale = (plane_z_m - origin[2]) / rays[:, 2]
    result: NDArray[np.float64] = origin[:2] + rays[:, :2] * scale[:, None]
    return result


def square_yaw(points: NDArray[np.float64]) -> float:
    """Face heading in [-pi/4, pi/4) of a square filled by ``points`` (N, 2) (module doc, step 3)."""
    offsets = points - points.mean(axis=0)
    radius_sq = np.sum(offsets**2, axis=1)
    moment = np.sum(radius_sq**2 * np.exp(4j * np.arctan2(offsets[:, 1], offsets[:, 0])))
    yaw = float(np.angle(-moment)) / 4.0
    return (yaw + math.pi / 4) % (math.pi / 2) - math.pi / 4


def cube_points(rgb: NDArray[np.uint8], color: str, view: CameraView, config: CubeLocatorConfig) -> NDArray[np.float64]:
    """(N, 2) plane points of the ``color`` pixels of ``rgb`` seen from ``view`` (empty when none)."""
    rows, columns = np.nonzero(color_mask(rgb, color, config.dominance, config.min_channel))
    return plane_points(view.camera, rows, columns, rgb.shape[0], rgb.shape[1], view.plane_z_m)


def expected_pixels(view: CameraView, height: int, cube_size_m: float) -> float:
    """Pixels of a cube's top face straight below ``view``'s camera in a frame ``height`` px high."""
    metres_per_pixel = (view.camera.position_m[2] - view.plane_z_m) * 2 * math.tan(math.radians(view.camera.fovy_deg) / 2) / height
    return (cube_size_m / metres_per_pixel) ** 2


def locate_cube(images: dict[str, NDArray[np.uint8]], color: str, config: CubeLocatorConfig) -> LocatedCube:
    """The ``color`` cube from the request ``images`` (name -> H x W x 3 uint8); raises ``CubeNotFound``."""
    points = cube_points(images[config.position.image], color, config.position, config)
    if len(points) < config.min_pixels:
        raise CubeNotFound(
            f"the {color} cube is not in the '{config.position.image}' frame ({len(points)} {color} pixels, "
            f"at least {config.min_pixels} wanted)"
        )
    centre = points.mean(axis=0)
    top = images[config.yaw.image]
    top_points = cube_points(top, color, config.yaw, config)
    whole = len(top_points) >= config.whole_share * expected_pixels(config.yaw, top.shape[0], config.cube_size_m)
    return LocatedCube(float(centre[0]), float(centre[1]), square_yaw(top_points if whole else points), int(len(points)))


def cube_features(cubes: Sequence[LocatedCube]) -> NDArray[np.float64]:
    """The policy's view of the cubes: x, y (m) and face yaw (rad, [-pi/4, pi/4)) per cube."""
    return np.array([v for cube in cubes for v in (cube.x_m, cube.y_m, cube.yaw_rad)], dtype=np.float32)


def layout_features(poses: Sequence[tuple[float, float, float]]) -> NDArray[np.float64]:
    """``cube_features`` of known (x, y, yaw) poses (what training reads from a layout)."""
    return cube_features([LocatedCube(x, y, yaw, 0) for x, y, yaw in poses])


def locate_cubes(images: dict[str, NDArray[np.uint8]], config: CubeLocatorConfig) -> list[LocatedCube]:
    """Every cube of ``config.colors``, in that order."""
    return [locate_cube(images, color, config) for color in config.colors]


def painted_frame(colors: Sequence[str], size: int = 224, patch: int = 6) -> NDArray[np.uint8]:
    """A black ``size`` px frame with a ``patch`` px square of each colour along the middle row (a
    synthetic observation the locator reads, for warm-ups)."""
    frame = np.zeros((size, size, 3), dtype=np.uint8)
    for index, color in enumerate(colors):
        left = (index + 1) * size // (len(colors) + 1) - patch // 2
        frame[size // 2 - patch // 2:size // 2 + patch // 2, left:left + patch, COLOR_CHANNEL[color]] = 200
    return frame
