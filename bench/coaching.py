"""How much a coaching session lifts success: the shipped Kuka base (worker/base_models/kuka) improved for N
minutes at a person's pace (5 steps/s, so N × 300 environment steps) by `learning.rl.coaching`, once with the
simulator playing the coach and once with nobody speaking (plain self-improvement: S_t is silence), from the
same policy, on the same goals and the same seed; then both, and the policy they started from, play the same
evaluation episodes.

The simulated coach uses ground truth (allowed in this bench only): over every step whose frame shows the
gripper at the episode's target (the simulator's `heard` equals the goal's target), it "says" a clip of that
command, drawn from the same voices as the goals. The sessions run unpaced (as fast as the machine goes):
the step count is what a paced session of N minutes takes.

    nice -n 10 .venv/bin/python bench/coaching.py [--minutes 2] [--seeds 0 1 2] [--episodes-per-command 10]

Writes bench/results/coaching.json (every seed) with the load average before/after, and prints a table. Each
finished piece (the base's evaluation, each session and its evaluation) is kept under
<data dir>/bench/coaching/<settings>/, so a stopped run started again with the same settings goes on from
there.
"""

import argparse
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch
from conditions import Conditions, describe
from result_files import write_result
from tqdm.auto import tqdm

from core.paths import data_subdir
from learning.rl.coaching import (
    DEFAULT_STEPS_PER_S,
    CoachingSettings,
    SilentCoach,
    StepMoment,
    coaching_trainer,
)
from learning.rl.evaluate import evaluate
from learning.rl.ppo import load_policy
from learning.rl.rewards import ClipBank, corpus_bank
from learning.var.checkpoint import load_var

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "bench" / "results" / "coaching.json"
BASE = ROOT / "worker" / "base_models" / "kuka"
CONDITIONS = ("coached", "silent")


class SimulatedCoach:
    """Says a clip of the goal's command over every frame that shows the gripper at the goal's target."""

    def __init__(self, voices: ClipBank, seed: int) -> None:
        self.voices, self.rng = voices, np.random.default_rng(seed)

    def voice_over(self, moments: Sequence[StepMoment]) -> list[torch.Tensor | None]:
        said: list[torch.Tensor | None] = []
        for moment in moments:
            at_target = moment.goal_intent >= 0 and moment.heard == moment.goal_intent
            pick = self.voices.sample(np.array([moment.goal_intent]), self.rng)[0] if at_target else None
            said.append(None if pick is None else self.voices.embeddings[pick])
        return said


def success(policy_path: Path, var: torch.nn.Module, goals: ClipBank, episodes: int, seed: int) -> dict:
    policy, _ = load_policy(policy_path)
    started = time.perf_counter()
    result = evaluate(
        policy, var, goals, "kuka", var.config.image_size, "coaching", episodes, seed, num_envs=2,
        progress=False,
    )  # fmt: skip
    return {
        "success_rate": result.success_rate, "success_by_intent": result.success_by_intent,
        "eval_s": round(time.perf_counter() - started, 1),
    }  # fmt: skip


def improve(condition: str, seed: int, steps: int, goals: ClipBank, out: Path) -> dict:
    coach = SimulatedCoach(goals, seed) if condition == "coached" else SilentCoach()
    settings = CoachingSettings(steps=steps, steps_per_s=None, seed=seed)
    started = time.perf_counter()
    with coaching_trainer(BASE / "policy.pt", BASE / "var.pt", goals, coach, settings, out) as trainer:
        trainer.coach_session()
        trainer.save_checkpoint()
        voiced = trainer.voiced_steps
    return {"voiced_steps": voiced, "env_steps": steps, "train_s": round(time.perf_counter() - started, 1)}


def kept(path: Path, make: Callable[[], dict]) -> dict:
    """The piece stored at `path` by an earlier run with the same settings, or made now and stored."""
    if path.exists():
        return json.loads(path.read_text())
    made = make()
    path.write_text(json.dumps(made))
    return made


def measure(minutes: float, seeds: list[int], episodes: int, split: str, eval_seed: int) -> dict:
    var = load_var(BASE / "var.pt").eval()
    goals = corpus_bank("wordset", split, front_end=var.front_end).embed(var)
    steps = int(minutes * 60 * DEFAULT_STEPS_PER_S)
    work = data_subdir("bench", "coaching", f"{split}-{steps}steps-{episodes}eps-eval{eval_seed}")
    before = kept(work / "before.json", lambda: success(BASE / "policy.pt", var, goals, episodes, eval_seed))
    runs = []
    for seed in tqdm(seeds, desc="seeds", unit="seed"):
        for condition in CONDITIONS:
            out = work / f"{condition}-{seed}"

            def session_and_eval(condition: str = condition, seed: int = seed, out: Path = out) -> dict:
                trained = improve(condition, seed, steps, goals, out)
                after = success(out / "checkpoint.pt", var, goals, episodes, eval_seed)
                return {"seed": seed, "condition": condition, **trained, "after": after}

            runs.append(kept(work / f"{condition}-{seed}.json", session_and_eval))
    lifts = {
        c: [r["after"]["success_rate"] - before["success_rate"] for r in runs if r["condition"] == c]
        for c in CONDITIONS
    }
    return {
        "minutes": minutes, "steps_per_s": DEFAULT_STEPS_PER_S, "env_steps": steps, "split": split,
        "episodes": episodes * 4, "eval_seed": eval_seed, "before": before, "runs": runs,
        "mean_lift": {c: float(np.mean(v)) for c, v in lifts.items()},
        "coached_minus_silent": float(np.mean(lifts["coached"]) - np.mean(lifts["silent"])),
    }  # fmt: skip


def print_table(result: dict) -> None:
    print(
        f"\n{result['minutes']} min of coaching = {result['env_steps']} steps; {result['episodes']} "
        f"evaluation episodes ({result['split']}), the same for every policy"
    )
    print(f"{'policy':<22} {'seed':>4} {'voiced steps':>12} {'success':>8} {'lift':>7}")
    base = result["before"]["success_rate"]
    print(f"{'base (before)':<22} {'':>4} {'':>12} {base:>8.3f} {'':>7}")
    for run in result["runs"]:
        rate = run["after"]["success_rate"]
        name = f"{run['condition']} session"
        print(f"{name:<22} {run['seed']:>4} {run['voiced_steps']:>12} {rate:>8.3f} {rate - base:>+7.3f}")
    for condition, lift in result["mean_lift"].items():
        print(f"mean lift, {condition:<11} {lift:+.3f}")
    print(f"coached minus silent: {result['coached_minus_silent']:+.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=2.0, help="length of a paced session")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--episodes-per-command", type=int, default=10)
    parser.add_argument(
        "--split", default="unheard-real-voices", help="the household's voices: the goals and the coach's"
    )
    parser.add_argument("--eval-seed", type=int, default=7)
    args = parser.parse_args()
    torch.set_num_threads(1)
    conditions = Conditions()
    result = measure(args.minutes, args.seeds, args.episodes_per_command, args.split, args.eval_seed)
    result |= conditions.finish()
    write_result(RESULT, result)
    print_table(result)
    print(describe(result))


if __name__ == "__main__":
    main()
