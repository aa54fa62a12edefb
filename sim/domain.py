"""Domain-shift knobs: make a world look like an unseen room (used to show fine-tuning)."""

from dataclasses import dataclass


@dataclass(frozen=True)
class DomainShift:
    """Every knob at its default reproduces the training room exactly.

    Colours are RGB in [0, 1]; `None` keeps the world's own colour.
    """

    object_rgb: tuple[float, float, float] | None = None
    floor_rgb: tuple[float, float, float] | None = None
    floor_texture: str | None = None  # "checker", "noise" or None (plain)
    object_texture: str | None = None  # "checker", "noise" or None (plain)
    camera_jitter_m: float = 0.0  # uniform jitter of the camera eye, per episode
    camera_jitter_deg: float = 0.0  # uniform jitter of the look-at direction, per episode
    light_direction: tuple[float, float, float] | None = None
    light_ambient: float | None = None  # tiny-renderer ambient coefficient
    light_diffuse: float | None = None  # tiny-renderer diffuse coefficient

    @classmethod
    def unseen_room(cls) -> "DomainShift":
        """A ready-made shifted room: other colours and textures, a nudged camera, other light."""
        return cls(
            object_rgb=(0.85, 0.55, 0.1),
            floor_rgb=(0.35, 0.45, 0.6),
            floor_texture="checker",
            camera_jitter_m=0.02,
            camera_jitter_deg=2.0,
            light_direction=(-0.5, 0.8, 1.0),
            light_ambient=0.5,
            light_diffuse=0.45,
        )
