"""Policy learning: PPO with the VAR's intrinsic reward, evaluation protocol, baselines, self-improvement."""
