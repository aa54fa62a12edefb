"""Training-time image augmentation, batched: a small random shift and a brightness/contrast jitter.

A shift of the whole picture keeps what is under the gripper, so the heard intent stays true; the jitter
stands in for other lights and cameras.
"""

import torch


def augment_images(
    images: torch.Tensor, generator: torch.Generator, max_shift_fraction: float = 0.04, jitter: float = 0.1
) -> torch.Tensor:
    """uint8 (B, H, W, 3) → uint8 (B, H, W, 3), each image shifted and jittered on its own."""
    batch, height, width, _ = images.shape
    shift = round(max_shift_fraction * max(height, width))
    pixels = images.float()
    if shift > 0:
        offsets = torch.randint(-shift, shift + 1, (2, batch), generator=generator)
        rows = (torch.arange(height)[None, :] + offsets[0][:, None]).clamp(
            0, height - 1
        )  # edge pixels repeat
        cols = (torch.arange(width)[None, :] + offsets[1][:, None]).clamp(0, width - 1)
        index = torch.arange(batch)[:, None, None]
        pixels = pixels[index, rows[:, :, None], cols[:, None, :]]
    if jitter > 0:
        contrast = 1 + (torch.rand(batch, 1, 1, 1, generator=generator) * 2 - 1) * jitter
        brightness = (torch.rand(batch, 1, 1, 1, generator=generator) * 2 - 1) * jitter * 255
        mean = pixels.mean(dim=(1, 2, 3), keepdim=True)
        pixels = (pixels - mean) * contrast + mean + brightness
    return pixels.round_().clamp_(0, 255).to(torch.uint8)
