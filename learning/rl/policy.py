"""The recurrent actor-critic of the paper (Fig. 3), sized for a 2-core CPU.

    I_t ──► policy CNN ──► 128 ─┐
                                 (+) ──► x_t ──► GRU ──► h_t ──┐
    [f_I(I_t), M_t] ──► MLP ─► 128 ┘      │                     ├──► actor (Gaussian mean) / critic (value)
                                          └──► fusion ─► g_t ───┘
    goal ──► goal MLP (once per episode) ────────┘

The goal joins after the recurrent core because it is a one-time signal. With `goal_fusion="image"` (the
default for new runs, as the reference network does) it is first fused with this step's image features x_t
by a two-layer MLP, so "where is the block that the goal names, relative to the gripper" is computed from the
goal and the current view together; with "core" (the first runs' policies, still loadable) it is only
concatenated with h_t, and a single head layer has to make every goal-and-position interaction on its own.
On Kuka/Wordset the fusion learned much faster (training success 0.43 against 0.07 at about 175k steps), but
the goal "zero" was still never reached. With the VAR the goal is the frozen f_S(S_goal) and f_I(I_t) is part
of the observation. The baselines (no VAR) use `goal_encoder="learned"`: a
small MFCC CNN trained by RL (and, RSI-style, by auxiliary classification losses on ground-truth labels).
"""

import itertools
from dataclasses import asdict, dataclass
from typing import Literal

import torch
from torch import nn
from torch.distributions import Normal
from torch.nn import functional as F

from learning.rl.envs import NO_SOUND

GoalEncoder = Literal["var", "learned"]
MFCC_SHAPE = (100, 40)
GOAL_FEATURES = 64  # what the goal MLP (VAR) or the goal CNN (baselines) hands to the heads
GoalFusion = Literal["core", "image"]
PolicyView = Literal["pixels", "var"]


@dataclass(frozen=True)
class PolicyConfig:
    image_size: int  # size of the images the env renders (the VAR's input size)
    state_dim: int  # M_t: gripper (x, y) or odometry (x, y, sin, cos)
    var_dim: int = 3  # size of f_I(I_t) in the observation; 0 when the policy has no VAR
    goal_encoder: GoalEncoder = "var"
    goal_dim: int = 3  # size of f_S(S_goal) when goal_encoder == "var"
    policy_image_size: int = 32  # the policy CNN sees a smaller copy: its cost dominates the PPO update
    hidden: int = 128
    action_dim: int = 2
    num_intents: int = 4  # only used by the auxiliary heads (RSI baseline)
    aux_heads: bool = False
    # The network's defaults live here only (`PPOConfig` takes its own from them). Checkpoints saved before an
    # option existed load with the value they were trained with (`learning.rl.checkpoints`).
    goal_fusion: GoalFusion = "image"
    bounded_mean: bool = True  # tanh on the action mean
    goal_match: bool = False  # also give the fusion f_I(I_t)·f_S(S_goal): the reward it is earning now
    # None: its own CNN sees a policy_image_size copy of the view. A VARConfig's fields: it sees through a
    # frozen copy of that VAR's image encoder, up to its hidden layer (`VarView`)
    view_var: dict | None = None

    def to_dict(self) -> dict:
        return asdict(self)


def layer_init(layer: nn.Module, std: float = 2**0.5, bias: float = 0.0) -> nn.Module:
    nn.init.orthogonal_(layer.weight, std)
    nn.init.constant_(layer.bias, bias)
    return layer


def downsample_images(images: torch.Tensor, size: int) -> torch.Tensor:
    """uint8 (B, H, W, 3) → uint8 (B, size, size, 3) by area averaging (done once per step, stored in the
    buffer)."""
    if images.shape[1] == size and images.shape[2] == size:
        return images
    x = images.permute(0, 3, 1, 2).float()
    x = F.interpolate(x, size=(size, size), mode="area")
    return x.round_().clamp_(0, 255).to(torch.uint8).permute(0, 2, 3, 1).contiguous()


class ImageEncoder(nn.Module):
    """Three stride-2 3×3 convolutions: about 0.6 M multiply-adds per 32×32 image."""

    def __init__(self, image_size: int, out: int) -> None:
        super().__init__()
        self.conv = nn.Sequential(
            layer_init(nn.Conv2d(3, 16, 3, stride=2, padding=1)),
            nn.ReLU(),
            layer_init(nn.Conv2d(16, 32, 3, stride=2, padding=1)),
            nn.ReLU(),
            layer_init(nn.Conv2d(32, 32, 3, stride=2, padding=1)),
            nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            flat = self.conv(torch.zeros(1, 3, image_size, image_size)).shape[1]
        self.fc = nn.Sequential(layer_init(nn.Linear(flat, out)), nn.ReLU())

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = images.permute(0, 3, 1, 2).float().mul_(1.0 / 255.0)
        return self.fc(self.conv(x))


class VarView(nn.Module):
    """A frozen copy of a VAR's image encoder up to its hidden layer: uint8 views at the VAR's size → (B,
    hidden). It is the policy's own copy, saved with it, so a household's fine-tune of the VAR does not change
    what the policy sees; it stays in eval mode (its batch norms keep the statistics the VAR learnt)."""

    def __init__(self, var_fields: dict) -> None:
        from learning.var.model import ImageEncoder as VarImageEncoder
        from learning.var.model import VARConfig

        super().__init__()
        config = VARConfig.from_dict(var_fields)
        self.encoder = VarImageEncoder(config).requires_grad_(False).eval()
        self.features = config.hidden

    def train(self, mode: bool = True) -> "VarView":
        return self  # frozen: never back into training mode

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            return self.encoder.hidden(images)


class SoundEncoder(nn.Module):
    """MFCC (B, 100, 40) → features; used only by the baselines, which learn their own goal encoder."""

    def __init__(self, out: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            layer_init(nn.Conv2d(1, 16, 3, stride=2, padding=1)),
            nn.ReLU(),
            layer_init(nn.Conv2d(16, 32, 3, stride=2, padding=1)),
            nn.ReLU(),
            layer_init(nn.Conv2d(32, 32, 3, stride=2, padding=1)),
            nn.ReLU(),
            nn.AdaptiveAvgPool2d((4, 2)),
            nn.Flatten(),
            layer_init(nn.Linear(32 * 8, out)),
            nn.ReLU(),
        )

    def forward(self, mfcc: torch.Tensor) -> torch.Tensor:
        return self.net(mfcc.unsqueeze(1))


class Policy(nn.Module):
    def __init__(self, config: PolicyConfig) -> None:
        super().__init__()
        self.config = config
        h = config.hidden
        if config.view_var is not None:
            self.var_view = VarView(config.view_var)
            self.image_encoder: nn.Module = nn.Sequential(
                layer_init(nn.Linear(self.var_view.features, h)), nn.ReLU()
            )
        else:
            self.image_encoder = ImageEncoder(config.policy_image_size, h)
        self.vector_encoder = nn.Sequential(
            layer_init(nn.Linear(config.var_dim + config.state_dim, h)), nn.ReLU()
        )
        self.gru = nn.GRU(h, h)
        for name, param in self.gru.named_parameters():
            if "weight" in name:
                nn.init.orthogonal_(param, 1.0)
            else:
                nn.init.constant_(param, 0.0)
        goal_features = GOAL_FEATURES
        if config.goal_encoder == "var":
            self.goal_encoder: nn.Module = nn.Sequential(
                layer_init(nn.Linear(config.goal_dim, goal_features)), nn.ReLU()
            )
        else:
            self.goal_encoder = SoundEncoder(goal_features)
        if config.goal_match and (config.goal_encoder != "var" or config.goal_fusion != "image"):
            raise ValueError("goal_match needs the VAR's goal embedding and goal_fusion='image'")
        if config.goal_fusion == "image":
            fused_in = h + goal_features + int(config.goal_match)
            self.goal_image_fusion = nn.Sequential(
                layer_init(nn.Linear(fused_in, h)), nn.ReLU(), layer_init(nn.Linear(h, h)), nn.ReLU()
            )
            joined = 2 * h
        else:
            joined = h + goal_features
        self.actor_mean = nn.Sequential(
            layer_init(nn.Linear(joined, h)), nn.Tanh(), layer_init(nn.Linear(h, config.action_dim), std=0.01)
        )
        self.actor_logstd = nn.Parameter(torch.zeros(1, config.action_dim))
        self.critic = nn.Sequential(
            layer_init(nn.Linear(joined, h)), nn.Tanh(), layer_init(nn.Linear(h, 1), std=1.0)
        )
        if config.aux_heads:
            # RSI-style auxiliary classifiers: what is in view (intents + "nothing") and which intent the
            # goal is
            self.aux_view = layer_init(nn.Linear(h, config.num_intents + 1), std=0.01)
            self.aux_goal = layer_init(nn.Linear(goal_features, config.num_intents), std=0.01)

    # -- where the weights are ------------------------------------------------------------------------------
    # step, encode_goal, evaluate_sequences and auxiliary_loss take and return CPU tensors wherever the
    # weights are (`.to(device)`): the trainer's buffers stay on the CPU and only the network runs on a GPU.
    # On the CPU both moves are no-ops.
    @property
    def device(self) -> torch.device:
        return self.actor_logstd.device

    def _here(self, *tensors: torch.Tensor) -> list[torch.Tensor]:
        return [tensor.to(self.device) for tensor in tensors]

    # -- pieces ----------------------------------------------------------------------------------------------
    def initial_state(self, batch: int) -> torch.Tensor:
        return torch.zeros(batch, self.config.hidden)

    @property
    def goal_feature_size(self) -> int:
        return GOAL_FEATURES + (self.config.goal_dim if self.config.goal_match else 0)

    def view_of(self, images: torch.Tensor) -> torch.Tensor:
        """uint8 (B, H, W, 3) rendered views → what the policy's step takes for them (and its buffers keep):
        the smaller copy its CNN sees, or the features of its frozen VAR view."""
        if self.config.view_var is None:
            return downsample_images(images, self.config.policy_image_size)
        (images,) = self._here(images)
        return self.var_view(images).cpu()

    def encode_goal(self, goal: torch.Tensor) -> torch.Tensor:
        """goal: (B, goal_dim) VAR embedding, or (B, 100, 40) MFCC for a learned encoder. Once per episode.
        With goal_match the raw embedding rides along (last goal_dim columns) for the per-step match."""
        (goal,) = self._here(goal)
        features = self.goal_encoder(goal)
        return (torch.cat([features, goal], dim=-1) if self.config.goal_match else features).cpu()

    def encode_inputs(
        self, images: torch.Tensor, var_embedding: torch.Tensor, state: torch.Tensor
    ) -> torch.Tensor:
        vector = torch.cat([var_embedding, state], dim=-1) if self.config.var_dim else state
        return F.relu(self.image_encoder(images) + self.vector_encoder(vector))

    def heads(
        self,
        core: torch.Tensor,
        inputs: torch.Tensor,
        goal_features: torch.Tensor,
        var_embedding: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """core: the GRU output; inputs: this step's features before the GRU (x_t)."""
        goal = goal_features
        if self.config.goal_fusion == "image":
            parts = [inputs, goal_features]
            if self.config.goal_match:
                raw_goal = goal_features[..., GOAL_FEATURES:]
                parts[1] = goal_features[..., :GOAL_FEATURES]
                parts.append((var_embedding * raw_goal).sum(dim=-1, keepdim=True))
            goal = self.goal_image_fusion(torch.cat(parts, dim=-1))
        joined = torch.cat([core, goal], dim=-1)
        mean = self.actor_mean(joined)
        if self.config.bounded_mean:
            # Actions are clipped to [-1, 1]. An unbounded mean drifts far outside (±6.5 measured in the first
            # Kuka runs): every sample then clips to the same action and the noise explores nothing.
            mean = torch.tanh(mean)
        return mean, self.critic(joined).squeeze(-1)

    def auxiliary_loss(
        self, inputs: torch.Tensor, goal_features: torch.Tensor, heard: torch.Tensor, intent: torch.Tensor
    ) -> torch.Tensor:
        """RSI-style: classify what is in view (intents + "nothing") and which intent the goal is."""
        inputs, goal_features, heard, intent = self._here(inputs, goal_features, heard, intent)
        view_labels = torch.where(heard == NO_SOUND, self.config.num_intents, heard)
        view = F.cross_entropy(self.aux_view(inputs.flatten(0, 1)), view_labels.flatten())
        goal = F.cross_entropy(self.aux_goal(goal_features.flatten(0, 1)), intent.flatten())
        return (view + goal).cpu()

    # -- one environment step (rollout) ----------------------------------------------------------------------
    def step(
        self,
        images: torch.Tensor,
        var_embedding: torch.Tensor,
        state: torch.Tensor,
        goal_features: torch.Tensor,
        hidden: torch.Tensor,
        episode_start: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Returns (action mean, value, new hidden). `episode_start` (B,) zeroes the hidden state first."""
        images, var_embedding, state, goal_features, hidden, episode_start = self._here(
            images, var_embedding, state, goal_features, hidden, episode_start
        )
        hidden = hidden * (1.0 - episode_start).unsqueeze(-1)
        inputs = self.encode_inputs(images, var_embedding, state)
        core, _ = self.gru(inputs.unsqueeze(0), hidden.unsqueeze(0))
        hidden = core[0]
        mean, value = self.heads(hidden, inputs, goal_features, var_embedding)
        return mean.cpu(), value.cpu(), hidden.cpu()

    def distribution(self, mean: torch.Tensor) -> Normal:
        # validate_args=False: the same numbers without checking every argument (per step, per group)
        return Normal(mean, self.actor_logstd.to(mean.device).expand_as(mean).exp(), validate_args=False)

    # -- whole sequences (PPO update) ------------------------------------------------------------------------
    def evaluate_sequences(
        self,
        images: torch.Tensor,
        var_embedding: torch.Tensor,
        state: torch.Tensor,
        goal_features: torch.Tensor,
        hidden: torch.Tensor,
        episode_start: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Inputs are time-major (T, B, ...) with whole sequences per environment; `hidden` (B, hidden) is the
        state before step 0. The CNN and the heads run on all T·B samples at once; the GRU runs fused over
        each stretch of time in which no episode starts (episodes of fixed length that started together: one
        or two stretches per rollout), resetting the state of the environments that start a new episode.
        Returns (action means (T, B, A), values (T, B), core features before the GRU (T, B, hidden)).
        """
        images, var_embedding, state, goal_features, hidden, episode_start = self._here(
            images, var_embedding, state, goal_features, hidden, episode_start
        )
        steps, batch = episode_start.shape
        flat = lambda x: x.reshape(steps * batch, *x.shape[2:])  # noqa: E731
        inputs = self.encode_inputs(flat(images), flat(var_embedding), flat(state)).view(steps, batch, -1)
        keep = (1.0 - episode_start).unsqueeze(-1)
        starts = torch.nonzero(episode_start[1:].any(dim=1)).flatten().add(1).tolist()
        bounds = [0, *starts, steps]
        cores, hidden = [], hidden.unsqueeze(0)
        for begin, end in itertools.pairwise(bounds):
            out, hidden = self.gru(inputs[begin:end], hidden * keep[begin])
            cores.append(out)
        core = torch.cat(cores)
        mean, value = self.heads(flat(core), flat(inputs), flat(goal_features), flat(var_embedding))
        return mean.view(steps, batch, -1).cpu(), value.view(steps, batch).cpu(), inputs.cpu()
