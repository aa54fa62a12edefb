"""Procedural grey textures for the domain-shift knobs (PyBullet multiplies them by the shape's colour)."""

import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from core.paths import data_subdir

TEXTURE_KINDS = ("checker", "noise")
TEXTURE_SIZE_PX = 64


def texture_file(kind: str, squares: int = 8) -> Path:
    """A PNG for `kind` ("checker" or "noise"), written once under the data dir's cache and reused."""
    if kind not in TEXTURE_KINDS:
        raise ValueError(
            f"unknown texture {kind!r}: choose one of {', '.join(TEXTURE_KINDS)} (or None for plain)"
        )
    path = data_subdir("cache", "textures") / f"{kind}_{squares}.png"
    if not path.exists():
        _write_atomically(path, _texture(kind, squares))
    return path


def _texture(kind: str, squares: int) -> np.ndarray:
    size = TEXTURE_SIZE_PX
    if kind == "checker":
        cells = np.arange(size) * squares // size
        light = (cells[:, None] + cells[None, :]) % 2 == 0
        grey = np.where(light, 255, 110).astype(np.uint8)
    else:
        rng = np.random.default_rng(1234)  # fixed: the same "noise" room in every process
        coarse = rng.uniform(90, 255, size=(squares, squares)).astype(np.float32)
        fine = rng.uniform(-25, 25, size=(size, size)).astype(np.float32)
        grey = np.clip(cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC) + fine, 0, 255)
        grey = grey.astype(np.uint8)
    return np.repeat(grey[:, :, None], 3, axis=2)


def _write_atomically(path: Path, image: np.ndarray) -> None:
    """Several env processes may create the same texture at once: write to a temporary name, then rename."""
    handle, temporary = tempfile.mkstemp(suffix=".png", dir=path.parent)
    os.close(handle)
    if not cv2.imwrite(temporary, image):
        raise OSError(f"could not write texture {temporary}")
    os.replace(temporary, path)
