"""The fixed table camera of the block worlds, rendered with PyBullet's tiny (CPU) renderer.

The reference renders 100×75 pixels with a 48.8° vertical field of view, keeps the centre 75 columns
(12..86) and resizes to the image size. We render only those 75×75 pixels directly, through an off-centre
frustum that covers exactly the kept columns: the same pixels for a quarter less rasterising.
"""

from dataclasses import dataclass, field

import cv2
import numpy as np
import pybullet as p
from pybullet_utils.bullet_client import BulletClient

EYE_M = (1.2, 0.0, 0.3)
LOOK_AT_M = (0.6, 0.0, 0.0)
UP = (0.0, 0.0, 1.0)
FOV_DEG = 48.8
REFERENCE_SIZE_PX = (100, 75)  # width, height rendered by the reference
CROP_COLUMNS = (12, 87)  # the reference keeps img[:, 12:87]
NEAR_M, FAR_M = 0.01, 100.0


@dataclass
class Lighting:
    """Tiny-renderer light settings; `None` keeps PyBullet's default."""

    direction: tuple[float, float, float] | None = None
    ambient: float | None = None
    diffuse: float | None = None

    def as_kwargs(self) -> dict:
        kwargs: dict = {}
        if self.direction is not None:
            kwargs["lightDirection"] = list(self.direction)
        if self.ambient is not None:
            kwargs["lightAmbientCoeff"] = self.ambient
        if self.diffuse is not None:
            kwargs["lightDiffuseCoeff"] = self.diffuse
        return kwargs


@dataclass
class TableCamera:
    image_size: int = 96
    eye: tuple[float, float, float] = EYE_M
    look_at: tuple[float, float, float] = LOOK_AT_M
    lighting: Lighting = field(default_factory=Lighting)

    def __post_init__(self) -> None:
        if not 8 <= self.image_size <= 1024:
            raise ValueError(f"image_size must be between 8 and 1024 pixels, got {self.image_size}")
        self._view: list[float] = []
        self._projection = _crop_projection()
        self.point_at(self.eye, self.look_at)

    def point_at(self, eye: tuple[float, float, float], look_at: tuple[float, float, float]) -> None:
        self.eye, self.look_at = tuple(eye), tuple(look_at)
        self._view = p.computeViewMatrix(list(self.eye), list(self.look_at), list(UP))

    def jitter(self, rng: np.random.Generator, shift_m: float, turn_deg: float) -> None:
        """Shift the eye by up to `shift_m` per axis and turn the view by up to `turn_deg` (per episode)."""
        eye = np.asarray(EYE_M) + rng.uniform(-shift_m, shift_m, size=3)
        direction = np.asarray(LOOK_AT_M) - np.asarray(EYE_M)
        yaw, pitch = np.deg2rad(rng.uniform(-turn_deg, turn_deg, size=2))
        direction = _rotate_z(direction, yaw)
        direction = _tilt(direction, pitch)
        self.point_at(tuple(eye), tuple(eye + direction))

    def render(self, client: BulletClient) -> np.ndarray:
        """The current view as uint8 RGB (image_size, image_size, 3)."""
        crop_width = CROP_COLUMNS[1] - CROP_COLUMNS[0]
        height = REFERENCE_SIZE_PX[1]
        rgba = client.getCameraImage(
            crop_width,
            height,
            self._view,
            self._projection,
            shadow=0,
            renderer=p.ER_TINY_RENDERER,
            flags=p.ER_NO_SEGMENTATION_MASK,
            **self.lighting.as_kwargs(),
        )[2]
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(height, crop_width, 4)[:, :, :3]
        if self.image_size == crop_width:
            return np.ascontiguousarray(rgb)
        return cv2.resize(rgb, (self.image_size, self.image_size), interpolation=cv2.INTER_LINEAR)

    def render_reference(self, client: BulletClient) -> np.ndarray:
        """The reference's way (100×75 render, crop, resize); kept to prove that `render` equals it."""
        width, height = REFERENCE_SIZE_PX
        projection = p.computeProjectionMatrixFOV(FOV_DEG, width / height, NEAR_M, FAR_M)
        rgba = client.getCameraImage(
            width,
            height,
            self._view,
            projection,
            shadow=0,
            renderer=p.ER_TINY_RENDERER,
            flags=p.ER_NO_SEGMENTATION_MASK,
            **self.lighting.as_kwargs(),
        )[2]
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[
            :, CROP_COLUMNS[0] : CROP_COLUMNS[1], :3
        ]
        return cv2.resize(rgb, (self.image_size, self.image_size), interpolation=cv2.INTER_LINEAR)


def _crop_projection() -> list[float]:
    width, height = REFERENCE_SIZE_PX
    top = NEAR_M * np.tan(np.deg2rad(FOV_DEG) / 2)
    half_width = top * width / height
    left = -half_width + 2 * half_width * CROP_COLUMNS[0] / width
    right = -half_width + 2 * half_width * CROP_COLUMNS[1] / width
    return p.computeProjectionMatrix(left, right, -top, top, NEAR_M, FAR_M)


def _rotate_z(vector: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([c * vector[0] - s * vector[1], s * vector[0] + c * vector[1], vector[2]])


def _tilt(vector: np.ndarray, angle: float) -> np.ndarray:
    """Rotate `vector` up or down by `angle` in its own vertical plane."""
    horizontal = np.linalg.norm(vector[:2])
    elevation = np.arctan2(vector[2], horizontal) + angle
    length = np.linalg.norm(vector)
    heading = vector[:2] / max(horizontal, 1e-9)
    return np.array([*(heading * length * np.cos(elevation)), length * np.sin(elevation)])
