"""The two encoders of the VAR: f_I over camera images and f_S over a clip's features, onto the unit sphere.

f_S is chosen by the sound front end (`VARConfig.front_end`, learning.front_ends): 1-D convolutions over MFCC
(the paper's), or a small trainable head over frozen speech-embedding frames.
"""

import copy
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

from learning.front_ends import DEFAULT_FRONT_END, MFCC, VALUES_PER_FRAME, check_front_end

MFCC_FRAMES = 100
MFCC_COEFFICIENTS = VALUES_PER_FRAME[MFCC]


@dataclass(frozen=True)
class VARConfig:
    """Everything that fixes the shape of a VAR; stored in every checkpoint and compared on load."""

    image_size: int = 96
    embedding_dim: int = 3
    image_channels: tuple[int, ...] = (8, 16, 32, 64, 128)
    sound_channels: tuple[int, ...] = (32, 64, 96)
    hidden: int = 128
    front_end: str = DEFAULT_FRONT_END  # a checkpoint written before front ends existed is MFCC
    sound_hidden: int | None = None  # f_S's width; None: `hidden` (as every checkpoint before it)

    def __post_init__(self) -> None:
        check_front_end(self.front_end)
        if self.sound_hidden is not None and self.sound_hidden < 1:
            raise ValueError(f"f_S's width must be 1 or more, not {self.sound_hidden}: leave it out for 128.")

    @property
    def sound_width(self) -> int:
        return self.sound_hidden or self.hidden

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "VARConfig":
        known = {k: v for k, v in data.items() if k in cls.__dataclass_fields__}
        for key in ("image_channels", "sound_channels"):
            if key in known:
                known[key] = tuple(known[key])
        return cls(**known)


def _conv_block(in_channels: int, out_channels: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel_size=3, stride=2, padding=1, bias=False),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


class ImageEncoder(nn.Module):
    """Stride-2 3×3 convolutions (the reference's five), flattened so where things are in view is kept."""

    def __init__(self, config: VARConfig) -> None:
        super().__init__()
        layers, channels, size = [], 3, config.image_size
        for out_channels in config.image_channels:
            layers.append(_conv_block(channels, out_channels))
            channels, size = out_channels, (size + 1) // 2
        self.features = nn.Sequential(*layers)
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(channels * size * size, config.hidden),
            nn.ReLU(inplace=True),
            nn.Linear(config.hidden, config.embedding_dim),
        )

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.head[-1](self.hidden(images))

    def hidden(self, images: torch.Tensor) -> torch.Tensor:
        """uint8 (B, H, W, 3) → the (B, hidden) layer before the embedding: where things are in view, in more
        numbers than the sphere keeps (what a policy that sees through the VAR reads)."""
        x = images.permute(0, 3, 1, 2).float().div_(127.5).sub_(1.0)
        x = x.contiguous(memory_format=torch.channels_last)
        return self.head[:-1](self.features(x))


class SoundEncoder(nn.Module):
    """1-D convolutions over time with the 40 MFCC coefficients as channels, then max over time."""

    def __init__(self, config: VARConfig) -> None:
        super().__init__()
        layers, channels = [], MFCC_COEFFICIENTS
        for out_channels in config.sound_channels:
            layers += [
                nn.Conv1d(channels, out_channels, kernel_size=5, stride=2, padding=2, bias=False),
                nn.BatchNorm1d(out_channels),
                nn.ReLU(inplace=True),
            ]
            channels = out_channels
        self.features = nn.Sequential(*layers)
        self.head = nn.Sequential(
            nn.Linear(2 * channels, config.sound_width),
            nn.ReLU(inplace=True),
            nn.Linear(config.sound_width, config.embedding_dim),
        )
        # Per-coefficient standardisation, set from the training corpus (`set_sound_statistics`); silence (all
        # zeros) stays one fixed input after it.
        self.register_buffer("mfcc_mean", torch.zeros(MFCC_COEFFICIENTS))
        self.register_buffer("mfcc_std", torch.ones(MFCC_COEFFICIENTS))

    def forward(self, mfcc: torch.Tensor) -> torch.Tensor:
        x = (mfcc.float() - self.mfcc_mean) / self.mfcc_std
        x = self.features(x.transpose(1, 2))
        pooled = torch.cat([x.amax(dim=2), x.mean(dim=2)], dim=1)
        return self.head(pooled)


class EmbeddingSoundEncoder(nn.Module):
    """A small trainable head over frozen embedding frames (B, frames, values): one layer per frame, the mean
    and the max over the clip's frames (all-zero padding frames left out), then two layers."""

    def __init__(self, config: VARConfig) -> None:
        super().__init__()
        values = VALUES_PER_FRAME[config.front_end]
        width = config.sound_width
        self.frame = nn.Sequential(nn.Linear(values, width), nn.ReLU(inplace=True))
        self.head = nn.Sequential(
            nn.Linear(2 * width, width),
            nn.ReLU(inplace=True),
            nn.Linear(width, config.embedding_dim),
        )
        self.register_buffer("feature_mean", torch.zeros(values))
        self.register_buffer("feature_std", torch.ones(values))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        heard = (features != 0).any(dim=2, keepdim=True)  # silence is all frames zero: one fixed output
        x = self.frame((features.float() - self.feature_mean) / self.feature_std) * heard
        mean = x.sum(dim=1) / heard.sum(dim=1).clamp_min(1)
        return self.head(torch.cat([x.amax(dim=1), mean], dim=1))  # after ReLU, masked frames (0) never win

    def set_statistics(self, features: torch.Tensor) -> None:
        flat = features.float().reshape(-1, features.shape[-1])
        heard = flat[(flat != 0).any(dim=1)]
        if len(heard) > 1:
            self.feature_mean.copy_(heard.mean(dim=0))
            self.feature_std.copy_(heard.std(dim=0).clamp_min(1e-3))


class VAR(nn.Module):
    """f_I and f_S; both return L2-normalised embeddings in R^d."""

    def __init__(self, config: VARConfig | None = None) -> None:
        super().__init__()
        self.config = config or VARConfig()
        self.image_encoder = ImageEncoder(self.config)
        self.sound_encoder = (
            SoundEncoder(self.config) if self.config.front_end == MFCC else EmbeddingSoundEncoder(self.config)
        )

    @property
    def front_end(self) -> str:
        return self.config.front_end

    def encode_image(self, images: torch.Tensor) -> torch.Tensor:
        """uint8 (B, H, W, 3) camera images, channels last, as rendered → (B, d) unit vectors."""
        self._check_image_shape(images)
        return F.normalize(self.image_encoder(images), dim=1)

    def encode_image_and_hidden(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """f_I(images) and the hidden layer it came from, in one pass (a policy that sees through this VAR
        reads the hidden layer)."""
        self._check_image_shape(images)
        hidden = self.image_encoder.hidden(images)
        return F.normalize(self.image_encoder.head[-1](hidden), dim=1), hidden

    def with_batch_norms_folded(self) -> "VAR":
        """A frozen copy whose image convolutions absorbed the batch norms after them (their eval statistics):
        the same f_I up to rounding in fewer passes over the activations, for embedding views while acting.
        Its weights have other names than a VAR's: never save it."""
        folded = copy.deepcopy(self).eval().requires_grad_(False)
        for block in folded.image_encoder.features:
            conv, norm = block[0], block[1]
            scale = norm.weight / torch.sqrt(norm.running_var + norm.eps)
            conv.weight = nn.Parameter(conv.weight * scale.view(-1, 1, 1, 1), requires_grad=False)
            conv.bias = nn.Parameter(norm.bias - norm.running_mean * scale, requires_grad=False)
            block[1] = nn.Identity()
        return folded

    def _check_image_shape(self, images: torch.Tensor) -> None:
        size = self.config.image_size
        if images.ndim != 4 or tuple(images.shape[1:]) != (size, size, 3):
            raise ValueError(
                f"encode_image expects uint8 images shaped (B, {size}, {size}, 3), "
                f"got {tuple(images.shape)}; this VAR was built for {size}×{size} images."
            )
        if images.dtype != torch.uint8:
            raise ValueError(f"encode_image expects uint8 pixels (0..255), got {images.dtype}.")

    def encode_sound(self, features: torch.Tensor) -> torch.Tensor:
        """The front end's features (B, frames, values), e.g. MFCC (B, 100, 40) → (B, d) unit vectors.
        Silence is all zeros."""
        self._check_sound_shape(features)
        return F.normalize(self.sound_encoder(features), dim=1)

    def encode_silence(self) -> torch.Tensor:
        """f_S of nothing heard, (1, d)."""
        frames = MFCC_FRAMES if self.front_end == MFCC else 1  # the head pools over frames: any count will do
        return self.encode_sound(torch.zeros(1, frames, VALUES_PER_FRAME[self.front_end]))

    def set_sound_statistics(self, features: torch.Tensor) -> None:
        """Standardise each feature value with the mean/std of these (N, frames, values) training features."""
        self._check_sound_shape(features)
        if self.front_end != MFCC:
            self.sound_encoder.set_statistics(features)
            return
        flat = features.float().reshape(-1, MFCC_COEFFICIENTS)
        self.sound_encoder.mfcc_mean.copy_(flat.mean(dim=0))
        self.sound_encoder.mfcc_std.copy_(flat.std(dim=0).clamp_min(1e-3))

    def _check_sound_shape(self, features: torch.Tensor) -> None:
        values = VALUES_PER_FRAME[self.front_end]
        frames_fit = features.ndim == 3 and (self.front_end != MFCC or features.shape[1] == MFCC_FRAMES)
        if not frames_fit or features.shape[2] != values:
            expected = f"(B, {MFCC_FRAMES}, {values})" if self.front_end == MFCC else f"(B, frames, {values})"
            raise ValueError(
                f"encode_sound expects {self.front_end} features shaped {expected}, got "
                f"{tuple(features.shape)}: this VAR's sound front end is '{self.front_end}'; compute them "
                f"with learning.audio.features_from_bytes(..., front_end='{self.front_end}')."
            )
