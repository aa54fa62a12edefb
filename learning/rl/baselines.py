"""The methods compared in the paper's Table I, as settings of the one PPO (nothing here is tuned).

- `var`: the method. Frozen VAR; intrinsic reward f_I(I_{t+1})·f_S(S_goal); the policy sees f_I(I_t),
f_S(S_goal).
- `var-current-sound`: the ablation that adds f_S(S_t)·f_S(S_goal), S_t = what is heard now (silence if
nothing).
- `sparse` (NoAux+SparseR): reward 1 on every step that ends with the robot at its target, as the reference
implementation's environment reward (until 2026-12-02 only at the last step of a successful episode, which a
random policy reaches about once in 100 episodes); no VAR, no auxiliary losses. As in the paper, its image and
sound encoders start from one-hot pre-training (`learning.rl.pretrain`, passed as `init_encoders`); without it
they learn from the sparse reward alone.
- `rsi` (RSI-style): a hand-shaped reward from simulator ground truth (progress towards the target + the
sparse reward on every step at the target; until 2026-12-02 + 1 once, on success at the episode's end) and
auxiliary classification losses on ground-truth labels (what is in view; which intent the goal is).

Labels are counted as the paper does (`PPOTrainer.labels_used`): a VAR triplet = 2 labels; each
extrinsic-reward step = one simulator query; each auxiliary-loss step = 2 ground-truth labels; each one-hot
pre-training example = 1 label.
"""

from dataclasses import replace

from learning.rl.ppo import PPOConfig

METHODS: dict[str, dict] = {
    "var": {"reward": "var", "goal_encoder": "var", "current_sound": False, "aux_loss_coef": 0.0},
    "var-current-sound": {
        "reward": "var",
        "goal_encoder": "var",
        "current_sound": True,
        "aux_loss_coef": 0.0,
    },
    "sparse": {"reward": "sparse", "goal_encoder": "learned", "current_sound": False, "aux_loss_coef": 0.0},
    "rsi": {"reward": "shaped", "goal_encoder": "learned", "current_sound": False, "aux_loss_coef": 1.0},
}


def method_config(method: str, base: PPOConfig | None = None, **overrides) -> PPOConfig:
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    return replace(base or PPOConfig(), **{**METHODS[method], **overrides})


def needs_var(method: str) -> bool:
    return METHODS[method]["goal_encoder"] == "var"
