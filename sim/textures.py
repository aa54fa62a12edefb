"""Procedural grey textures for the domain-shift knobs (PyBullet multiplies them by the shape's colour).

"checker" is the held-out rooms' (tiles); the training ranges draw from the others: "noise" (mottled),
"stripes" (planks or a woven cloth), "speckle" (granite or terrazzo) and "blotch" (a two-tone patterned cloth
or camouflage print: large light and dark patches with curved edges, as strong a contrast as the checker's
but no grid), so a base model meets more than one kind of surface pattern before it meets a checkered one.
"""

import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from core.paths import data_subdir
from core.rooms import TEXTURES

TEXTURE_KINDS = TEXTURES  # the names a room may give (core.rooms); each is drawn by `_texture`
TEXTURE_SIZE_PX = 64


def texture_file(kind: str, squares: int = 8) -> Path:
    """A PNG for `kind` (one of TEXTURE_KINDS), written once under the data dir's cache and reused."""
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
    rng = np.random.default_rng(1234)  # fixed: the same texture in every process
    cells = np.arange(size) * squares // size
    if kind == "checker":
        grey = np.where((cells[:, None] + cells[None, :]) % 2 == 0, 255, 110).astype(np.float32)
    elif kind == "stripes":
        bands = rng.uniform(120, 255, size=squares)[cells]  # planks of differing shades along one axis
        grain = rng.uniform(-20, 20, size=(size, 1)) + rng.uniform(-10, 10, size=(size, size))
        grey = np.broadcast_to(bands[None, :], (size, size)) + grain.T
    elif kind == "speckle":
        grey = np.full((size, size), 205.0, dtype=np.float32)
        dots = rng.random((size, size))
        grey[dots < 0.12] = 90.0
        grey[dots > 0.94] = 255.0
    elif kind == "blotch":
        coarse = rng.uniform(0, 1, size=(2 * squares, 2 * squares)).astype(np.float32)  # patches a tile wide
        smooth = cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)
        grey = np.where(smooth > np.median(smooth), 255, 110).astype(np.float32)
    else:
        coarse = rng.uniform(90, 255, size=(squares, squares)).astype(np.float32)
        fine = rng.uniform(-25, 25, size=(size, size)).astype(np.float32)
        grey = cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC) + fine
    grey = np.clip(grey, 0, 255).astype(np.uint8)
    return np.repeat(grey[:, :, None], 3, axis=2)


def _write_atomically(path: Path, image: np.ndarray) -> None:
    """Several env processes may create the same texture at once: write to a temporary name, then rename."""
    handle, temporary = tempfile.mkstemp(suffix=".png", dir=path.parent)
    os.close(handle)
    if not cv2.imwrite(temporary, image):
        raise OSError(f"could not write texture {temporary}")
    os.replace(temporary, path)
