"""Continue a policy's PPO on a lent GPU machine that has no corpus, no registry and no `varbot` command.

Here (`prepare`): the goal clips' features of a corpus split, as the VAR's front end computes them, go into an
.npz beside a copy of the policy checkpoint to start from, under .dev/. There (`train`): PPO starts from that
policy (`init_policy`: its weights, a fresh optimiser) with the same settings except the number of envs and
the step budget, on CUDA, and stops at the step budget or the time limit, whichever comes first; its run
directory (checkpoints, metrics, curves) goes under $OUT.

    .venv/bin/python scripts/gpu_continue_policy.py prepare --var worker/base_models/kuka/var.pt \
        --policy /work/runs/base_sharp/kuka-seed1/checkpoint.pt --sounds wordset --split train
    # on the GPU machine (scripts/gpu-continue-run.sh):
    python3 scripts/gpu_continue_policy.py train --var worker/base_models/kuka/var.pt --envs 14 \
        --steps 350000 --minutes 8 --out "$OUT/run"
"""

import argparse
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

DEV = Path(".dev")
GOALS = DEV / "goals.npz"
INIT_POLICY = DEV / "init_policy.pt"


def prepare(args: argparse.Namespace) -> None:
    from learning.rl.frozen_var import load_frozen_var
    from learning.rl.rewards import corpus_bank

    front_end = load_frozen_var(args.var).model.front_end
    bank = corpus_bank(args.sounds, args.split, front_end=front_end)
    DEV.mkdir(exist_ok=True)
    np.savez_compressed(GOALS, features=bank.features, intents=bank.intents)
    shutil.copyfile(args.policy, INIT_POLICY)
    print(f"{len(bank.features)} goal clips ({front_end}) -> {GOALS}; policy -> {INIT_POLICY}")


def train(args: argparse.Namespace) -> None:
    from learning.rl.checkpoints import read_policy_checkpoint
    from learning.rl.ppo import PPOConfig
    from learning.rl.rewards import ClipBank
    from learning.rl.run import train_run

    stored = np.load(GOALS)
    goals = ClipBank(stored["features"], stored["intents"])
    base = PPOConfig.from_dict(read_policy_checkpoint(INIT_POLICY)["config"])
    config = replace(
        base, num_envs=args.envs, total_steps=args.steps, num_minibatches=2 if args.envs % 2 == 0 else 1
    )
    config.validate()
    started = time.monotonic()

    def out_of_time(record: dict) -> bool:
        return time.monotonic() - started > 60 * args.minutes

    summary = train_run(
        config, Path(args.out), args.var, goals=goals, init_policy=INIT_POLICY, on_update=out_of_time,
        device=args.device, progress=False,
    )  # fmt: skip
    print({k: summary[k] for k in ("updates", "env_steps", "recent_success", "time_shares")})


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    commands = parser.add_subparsers(dest="command", required=True)
    here = commands.add_parser("prepare")
    here.add_argument("--var", type=Path, required=True)
    here.add_argument("--policy", type=Path, required=True)
    here.add_argument("--sounds", default="wordset")
    here.add_argument("--split", default="train")
    there = commands.add_parser("train")
    there.add_argument("--var", type=Path, required=True)
    there.add_argument("--envs", type=int, default=14)
    there.add_argument("--steps", type=int, required=True)
    there.add_argument("--minutes", type=float, required=True)
    there.add_argument("--out", type=Path, required=True)
    there.add_argument("--device", default="cuda")
    args = parser.parse_args()
    prepare(args) if args.command == "prepare" else train(args)


if __name__ == "__main__":
    main()
