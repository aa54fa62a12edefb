"""Fixed-seed fingerprints of the PPO trainer: five tiny runs (VAR reward with current sound and goal match,
in two groups and in lockstep, at 64 px, sparse TurtleBot, RSI), each's metrics (without timings) and a hash
of its final weights. A change that must not change what is learned (a speed-up) leaves every fingerprint as
it was: `--check` compares with bench/results/rl_fingerprint.json instead of writing it.

    nice -n 10 .venv/bin/python bench/rl_fingerprint.py           # write the fingerprints
    nice -n 10 .venv/bin/python bench/rl_fingerprint.py --check   # same as written? (exit 1 if not)
"""

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from conditions import Conditions, describe
from result_files import write_result
from rich.console import Console
from rich.table import Table
from tqdm import tqdm

RESULT = Path(__file__).resolve().parent / "results" / "rl_fingerprint.json"
TIMING_KEYS = ("sps", "time", "peak_memory_mb")  # what the machine, not the method, decides
TINY = dict(
    world="kuka", image_size=32, policy_image_size=16, max_episode_steps=7, num_envs=4, num_steps=10,
    num_minibatches=2, update_epochs=2, checkpoint_every=2, seed=5, total_steps=4 * 40,
)  # fmt: skip
RUNS: dict[str, dict[str, Any]] = {
    "kuka-var-current-sound-goal-match": {"current_sound": True, "goal_match": True},
    "kuka-var-lockstep": {"env_groups": 1},
    "kuka-var-64px": {"image_size": 64, "policy_image_size": 32},
    "turtlebot-sparse": {"world": "turtlebot", "reward": "sparse"},
    "kuka-rsi": {"goal_encoder": "learned", "reward": "sparse", "aux_loss_coef": 0.1},
}


def weights_hash(state: dict) -> str:
    digest = hashlib.sha256()
    for name, tensor in sorted(state.items()):
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().numpy().tobytes())
    return digest.hexdigest()


def fingerprint(overrides: dict[str, Any]) -> dict[str, Any]:
    import torch

    from learning.rl.frozen_var import LoadedVar
    from learning.rl.ppo import PPOConfig, PPOTrainer
    from learning.rl.rewards import ClipBank
    from learning.var.model import VAR, VARConfig

    config = PPOConfig(**{**TINY, **overrides})
    torch.manual_seed(0)
    var = VAR(VARConfig(image_size=config.image_size)).eval()
    rng = np.random.default_rng(0)
    goals = ClipBank(rng.normal(size=(8, 100, 40)).astype(np.float32), np.arange(8) % 4)
    heard = ClipBank(rng.normal(size=(8, 100, 40)).astype(np.float32), np.arange(8) % 4)
    with tempfile.TemporaryDirectory() as run_dir:
        loaded = LoadedVar.in_memory(var) if config.goal_encoder == "var" else None
        trainer = PPOTrainer(config, Path(run_dir), loaded, goals, current_sounds=heard)
        try:
            trainer.train(progress=False)
        finally:
            trainer.close()
        lines = (Path(run_dir) / "metrics.jsonl").read_text().splitlines()
    metrics = [{k: v for k, v in json.loads(line).items() if k not in TIMING_KEYS} for line in lines]
    return {"metrics": metrics, "weights_sha256": weights_hash(trainer.policy.state_dict())}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--check", action="store_true", help="compare with the stored fingerprints")
    args = parser.parse_args()
    conditions = Conditions()
    found = {name: fingerprint(overrides) for name, overrides in tqdm(RUNS.items(), unit="run")}
    stored = json.loads(RESULT.read_text())["runs"] if args.check else {}
    table = Table(title="PPO fingerprints (fixed seeds)")
    for column in ("run", "updates", "weights sha256", *(["as stored"] if args.check else [])):
        table.add_column(column)
    differs = []
    for name, print_ in found.items():
        same = stored.get(name) == print_
        if args.check and not same:
            differs.append(name)
        row = [name, str(len(print_["metrics"])), print_["weights_sha256"][:16]]
        table.add_row(*row, *(["yes" if same else "NO"] if args.check else []))
    measured = conditions.finish()
    console = Console()
    console.print(table)
    console.print(describe(measured))
    if args.check:
        if differs:
            console.print(f"[red]different from {RESULT.name}: {', '.join(differs)}")
            sys.exit(1)
        console.print(f"every run is as {RESULT.name} says")
        return
    write_result(RESULT, {"benchmark": "rl_fingerprint", "settings": TINY, "runs": found, **measured})
    console.print(f"wrote {RESULT}")


if __name__ == "__main__":
    main()
