"""How far from the target a VAR's intrinsic reward starts to guide: the reward f_I(I_{t+1}) · f_S(S_goal)
along scripted-oracle and random-action episodes, binned by the simulator's distance to the target.

A reward that rises steadily as the distance falls gives PPO a slope to climb from anywhere; one that is flat
until the target fills the view is close to a sparse reward, and exploration has to find the target first.
The goal clip is drawn per episode from the training split, as in training. A minute or two on a CPU.

    .venv/bin/python bench/reward_by_distance.py --world turtlebot --sounds objects \
        --var data/bench/reproduce/var/reproduce-turtlebot-50000-objects-2400steps/final.pt
"""

import argparse
import itertools
import json
from pathlib import Path

import gymnasium
import matplotlib
import numpy as np
import torch
from conditions import Conditions, describe
from result_files import write_result
from rich.console import Console
from rich.table import Table
from tqdm import tqdm

matplotlib.use("Agg")
import matplotlib.pyplot as plt

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
RESULT = RESULTS / "reward_by_distance.json"
DISTANCE_BINS_M = {
    "turtlebot": [0.0, 0.2, 0.35, 0.5, 0.75, 1.0, 1.5, 3.0],  # bumper-to-object clearance
    "kuka": [0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5],  # gripper (x, y) to the target block
}
POLICIES = ("oracle", "random")


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--world", choices=sorted(DISTANCE_BINS_M), default="turtlebot")
    parser.add_argument("--sounds", default="objects")
    parser.add_argument("--var", type=Path, required=True)
    parser.add_argument("--episodes", type=int, default=24, help="episodes per policy (split over intents)")
    parser.add_argument("--seed", type=int, default=100)
    return parser.parse_args()


def collect(args: argparse.Namespace, var: torch.nn.Module) -> dict[str, np.ndarray]:
    """Per policy: an (N, 3) array of (distance to target, reward, target in view) over every step."""
    import sim
    from learning.rl.envs import RLInfo
    from learning.rl.rewards import corpus_bank

    bank = corpus_bank(args.sounds, "train").embed(var)
    env = RLInfo(gymnasium.make(sim.world_id(args.world), image_size=int(var.config.image_size)))
    rng = np.random.default_rng(args.seed)
    env.action_space.seed(args.seed)
    steps: dict[str, list[np.ndarray]] = {policy: [] for policy in POLICIES}
    with tqdm(total=len(POLICIES) * args.episodes, desc=f"reward by distance {args.world}", unit="ep") as bar:
        for policy in POLICIES:
            for episode in range(args.episodes):
                intent = episode % env.unwrapped.num_intents
                goal = bank.embeddings[bank.sample(np.array([intent]), rng)]
                steps[policy].append(run_episode(env, policy, intent, args.seed + episode, var, goal))
                bar.update()
    env.close()
    return {policy: np.concatenate(episodes) for policy, episodes in steps.items()}


def run_episode(
    env: gymnasium.Env, policy: str, intent: int, seed: int, var: torch.nn.Module, goal: torch.Tensor
) -> np.ndarray:
    """One episode's (distance, reward, target in view) per step; the images are embedded in one batch."""
    from learning.rl.rewards import intrinsic_reward_from_embeddings
    from learning.var.evaluate import embed_images
    from sim.oracle import oracle_action

    env.reset(seed=seed, options={"intent": intent})
    images, distances, in_view = [], [], []
    done = False
    while not done:
        action = oracle_action(env) if policy == "oracle" else env.action_space.sample()
        observation, _, terminated, truncated, info = env.step(action)
        images.append(observation["image"])
        distances.append(info["distance"])
        in_view.append(float(info["heard"] == intent))
        done = terminated or truncated
    embedded = torch.from_numpy(embed_images(var, np.stack(images)))
    rewards = intrinsic_reward_from_embeddings(embedded, goal).numpy()
    return np.column_stack([distances, rewards, in_view])


def binned(steps: np.ndarray, bins: list[float]) -> list[dict]:
    rows = []
    for low, high in itertools.pairwise(bins):
        chosen = steps[(steps[:, 0] >= low) & (steps[:, 0] < high)]
        if len(chosen):
            rows.append({
                "distance_m": [low, high],
                "steps": len(chosen),
                "reward_mean": round(float(chosen[:, 1].mean()), 4),
                "reward_std": round(float(chosen[:, 1].std()), 4),
                "target_in_view": round(float(chosen[:, 2].mean()), 4),
            })  # fmt: skip
    return rows


def report(args: argparse.Namespace, profile: dict[str, list[dict]], measured: dict) -> None:
    table = Table(title=f"VAR reward by distance to the target: {args.world}/{args.sounds}")
    for column in ("policy", "distance (m)", "steps", "reward mean ± std", "target in view"):
        table.add_column(column, justify="right")
    for policy, rows in profile.items():
        for row in rows:
            low, high = row["distance_m"]
            reward = f"{row['reward_mean']:+.3f} ± {row['reward_std']:.3f}"
            in_view = f"{row['target_in_view']:.2f}"
            table.add_row(policy, f"{low:.2f}–{high:.2f}", str(row["steps"]), reward, in_view)
    Console().print(table)
    print(describe(measured))


def plot(args: argparse.Namespace, profile: dict[str, list[dict]]) -> Path:
    figure, axis = plt.subplots(figsize=(6, 4))
    for policy, rows in profile.items():
        centres = [sum(row["distance_m"]) / 2 for row in rows]
        means = np.array([row["reward_mean"] for row in rows])
        spreads = np.array([row["reward_std"] for row in rows])
        axis.plot(centres, means, marker="o", label=policy)
        axis.fill_between(centres, means - spreads, means + spreads, alpha=0.2)
    axis.set_xlabel("distance to the target (m, bin centre)")
    axis.set_ylabel("f_I(I) · f_S(S_goal)")
    axis.set_title(f"VAR reward by distance: {args.world}/{args.sounds}")
    axis.legend()
    axis.grid(alpha=0.3)
    path = RESULTS / f"reward_by_distance_{args.world}_{args.sounds}.png"
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def save(args: argparse.Namespace, profile: dict[str, list[dict]], png: Path, measured: dict) -> None:
    results = json.loads(RESULT.read_text()) if RESULT.exists() else {}
    results[f"{args.world}-{args.sounds}"] = {
        "var": str(args.var),
        "episodes_per_policy": args.episodes,
        "seed": args.seed,
        "goal_split": "train",
        "profile": profile,
        "png": str(png.relative_to(ROOT)),
        **measured,
    }
    write_result(RESULT, results)
    print(f"wrote {RESULT.relative_to(ROOT)} and {png.relative_to(ROOT)}")


def main() -> None:
    from learning.var.checkpoint import load_var

    args = parse_args()
    conditions = Conditions()
    torch.set_num_threads(1)
    var = load_var(args.var).eval()
    steps = collect(args, var)
    measured = conditions.finish()
    profile = {policy: binned(rows, DISTANCE_BINS_M[args.world]) for policy, rows in steps.items()}
    report(args, profile, measured)
    save(args, profile, plot(args, profile), measured)


if __name__ == "__main__":
    main()
