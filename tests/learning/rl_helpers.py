"""Settings shared by the PPO tests: tiny runs on the real simulated worlds, a few seconds each."""

from learning.rl.ppo import PPOConfig

IMAGE = 16
WORDS = ["zero", "one", "two", "three"]  # the goal clips' commands, intent by intent


def tiny_config(**overrides: object) -> PPOConfig:
    settings: dict = {
        "world": "kuka",
        "image_size": IMAGE,
        "policy_image_size": IMAGE,
        "max_episode_steps": 5,
        "num_envs": 2,
        "num_steps": 12,
        "num_minibatches": 2,
        "update_epochs": 2,
        "checkpoint_every": 1,
        "seed": 3,
    }
    settings.update(overrides)
    return PPOConfig(**settings)
