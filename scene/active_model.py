"""The household's active model version as the scene uses it: its VAR and policy loaded once per version from
the blob store. torch comes in with `scene.brain`, imported only when a model is loaded."""

from typing import TYPE_CHECKING

import numpy as np

from backend import models
from scene.household import model_bytes

if TYPE_CHECKING:
    from scene.brain import Brain

DEFAULT_IMAGE_SIZE = 96  # the camera image without a model: the worlds' default


class ActiveModel:
    """Which version is loaded (`version_id`) and its `brain` (None without a VAR)."""

    def __init__(self) -> None:
        self.version_id: int | None = None
        self.brain: Brain | None = None

    def follow(self, version: models.ModelVersion | None) -> bool:
        """Load `version` unless it is the one loaded; True when the loaded model changed."""
        version_id = version.id if version is not None else None
        if version_id == self.version_id:
            return False
        self.version_id, self.brain = version_id, None
        var_bytes, policy_bytes = model_bytes(version) if version is not None else (None, None)
        if var_bytes is not None:
            from scene.brain import Brain

            self.brain = Brain(var_bytes, policy_bytes)
        return True

    @property
    def image_size(self) -> int:
        return self.brain.image_size if self.brain is not None else DEFAULT_IMAGE_SIZE

    @property
    def has_policy(self) -> bool:
        return self.brain is not None and self.brain.policy is not None

    def embed(self, image: np.ndarray) -> np.ndarray | None:
        """f_I(image) with the active VAR; None without one (or for an image of another size)."""
        if self.brain is None or image.shape[:2] != (self.brain.image_size, self.brain.image_size):
            return None
        return self.brain.embed_images(image[None])[0]
