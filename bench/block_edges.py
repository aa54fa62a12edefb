"""Where a block ends, for the VAR and for the policy that reads it (arm worlds): why tries end at no block.

1. **The VAR across the target block.** The gripper is moved through the centre of the target block along x
   (towards the camera is +x, the block's long side) and along y (across the row), 1 cm at a time. At each
   offset: the ray's verdict (the simulator's ground truth: is the gripper over the target block?), the VAR's
   call (the nearest of the four commands' mean embeddings and silence's) and the intrinsic reward the policy
   was trained with (exp((match − 1)/T) for a sharpened base, the match itself otherwise).
2. **Where the policy ends.** The VAR + policy play the evaluation protocol's episodes (deterministic, goal
   clips from an unheard tier) in one process; each try's end is put in one class: success, at another block,
   past an end of the target block (in its column, beyond its long side), beside it, or elsewhere; and
   whether the gripper's target ended on a limit of the workspace (each try keeps where the gripper
   started). `--episodes-from RUN/bench-eval-TIER.json` replays the very tries a `bench/reproduce.py`
   evaluation recorded (layout, command, goal clip) instead, and counts how many end as recorded.
   `--actions sampled` plays each try with actions drawn from the policy's Gaussian, as in training (one
   seeded draw per try), instead of its mean, as the evaluation protocol does: whether a failure is the
   mean's alone. Sampled tries are not compared with the record, which holds the mean's outcomes.

Prints a table, writes JSON and a PNG per room. About 3 min a room on this machine.

    .venv/bin/python bench/block_edges.py --rooms training,unseen_room
    .venv/bin/python bench/block_edges.py --var VAR.pt --policy RUN/checkpoint.pt --rooms training \
        --tier unheard-easy --episodes-from RUN/bench-eval-unheard-easy.json
"""

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium
import matplotlib
import numpy as np
import torch
from conditions import Conditions, describe
from result_files import file_sha256, write_result
from rich.console import Console
from rich.table import Table
from tqdm import tqdm

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.patches import Rectangle

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
FAR_M = 0.10  # an end farther than this from the target's centre is "elsewhere"
START_BAND_CM = 5  # the summary counts tries by the gripper's start y in bands this wide
EDGE_M = 1e-4  # a target this close to a workspace limit was clipped there
REACHED_M = 0.005  # a scan view counts only where the gripper got this close to its position


@dataclass(frozen=True)
class Models:
    var: torch.nn.Module
    policy: Any
    temperature: float | None  # the policy's sharpened reward, None for the plain match
    prototypes: torch.Tensor  # (5, d): each command's mean embedding, then silence's
    bank: Any  # the tier's clips, embedded


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--world", choices=["kuka", "kinova"], default="kuka")
    parser.add_argument("--var", type=Path, help="VAR checkpoint (default: the world's base model)")
    parser.add_argument("--policy", type=Path, help="policy checkpoint (default: the world's base model)")
    parser.add_argument("--rooms", default="training,unseen_room", help="comma-separated room names")
    parser.add_argument("--tier", default="unheard-real-voices", help="the corpus tier goal clips come from")
    parser.add_argument("--layouts", type=int, default=10, help="block layouts scanned per command")
    parser.add_argument("--reach-cm", type=int, default=10, help="the scan runs from -reach to +reach")
    parser.add_argument("--episodes-per-intent", type=int, default=50, help="policy tries (0: scan only)")
    parser.add_argument(
        "--episodes-from",
        type=Path,
        help="replay the tries of a bench/reproduce.py evaluation (RUN/bench-eval-TIER.json)",
    )
    parser.add_argument(
        "--actions",
        choices=["mean", "sampled"],
        default="mean",
        help="the policy's mean action (the evaluation protocol) or one drawn from its Gaussian (training)",
    )
    parser.add_argument("--seed", type=int, default=12345)
    parser.add_argument("--out", type=Path, default=RESULTS / "block_edges.json")
    args = parser.parse_args(argv)
    if args.episodes_from is not None and args.rooms != "training":
        parser.error(
            "--episodes-from replays tries that bench/reproduce.py played in the training room, "
            f"not in {args.rooms!r}: pass --rooms training"
        )
    return args


def load_models(var_path: Path, policy_path: Path, tier: str) -> Models:
    from learning.rl.ppo import PPOConfig, load_policy
    from learning.rl.rewards import corpus_bank
    from learning.var.checkpoint import load_var

    var = load_var(var_path).eval()
    policy, payload = load_policy(policy_path)
    config = PPOConfig.from_dict(payload["config"])
    bank = corpus_bank(config.sounds, tier, front_end=var.front_end)
    temperature = config.reward_temperature if config.reward == "var" else None
    return models_from(var, policy, bank, temperature)


def models_from(var: torch.nn.Module, policy: Any, bank: Any, temperature: float | None) -> Models:
    """The models with the bank's clips embedded and the VAR's five prototypes: each command's mean embedding
    over the bank's clips, then silence's."""
    bank = bank.embed(var)
    means = [bank.embeddings[torch.from_numpy(bank.intents == k)].mean(0) for k in range(4)]
    silence = var.encode_silence().reshape(-1)
    prototypes = torch.nn.functional.normalize(torch.stack([*means, silence]), dim=1)
    return Models(var.eval(), policy.eval(), temperature, prototypes, bank)


def make_world(world: str, room: str, image_size: int) -> gymnasium.Env:
    import sim
    from core.rooms import world_room
    from learning.rl.envs import RLInfo

    shift = world_room(room)
    kwargs: dict[str, Any] = {"image_size": image_size} | ({"domain": shift} if shift is not None else {})
    return RLInfo(gymnasium.make(sim.world_id(world), **kwargs))


def reward_of(match: torch.Tensor, temperature: float | None) -> torch.Tensor:
    return match if temperature is None else torch.exp((match - 1.0) / temperature)


def scan(env: gymnasium.Env, models: Models, layouts: int, reach_cm: int, seed: int) -> dict[str, list[dict]]:
    """Per axis, one row per offset (cm): the ray's share on target, the VAR's calls, the mean reward, over
    the views where the gripper got there (the workspace's edge stops it short of some offsets)."""
    from sim.explore import place_gripper

    offsets = np.arange(-reach_cm, reach_cm + 1)
    rng = np.random.default_rng(seed)
    # per axis and offset: views, ray on target, VAR calls the target, VAR calls nothing, reward (sums)
    tallies = {axis: np.zeros((len(offsets), 5)) for axis in ("x", "y")}
    world = env.unwrapped
    with tqdm(total=layouts * 4, desc="scan", unit="layout") as bar:
        for layout in range(layouts):
            for intent in range(4):
                env.reset(seed=seed + 4 * layout + intent, options={"intent": intent})
                goal = models.bank.embeddings[models.bank.sample(np.array([intent]), rng)[0]]
                centre = np.asarray(world.slot_position(intent)[:2])
                for axis, step in (("x", np.array([0.01, 0.0])), ("y", np.array([0.0, 0.01]))):
                    images, on_target, reached = [], [], []
                    for offset in offsets:
                        wanted = centre + offset * step
                        place_gripper(world, wanted)
                        images.append(world.render())
                        on_target.append(world.heard() == intent)
                        reached.append(np.hypot(*(np.asarray(world.arm.gripper_xy()) - wanted)) < REACHED_M)
                    scores = score_views(models, np.stack(images), np.array(on_target), goal, intent)
                    tallies[axis] += (
                        np.column_stack([np.ones(len(offsets)), scores]) * np.array(reached)[:, None]
                    )
                bar.update()
    return {axis: [scan_row(int(offset), row) for offset, row in zip(offsets, table, strict=True)]
            for axis, table in tallies.items()}  # fmt: skip


def scan_row(offset_cm: int, sums: np.ndarray) -> dict[str, Any]:
    views = int(sums[0])
    share = (lambda total: round(float(total) / views, 4)) if views else (lambda total: None)
    return {
        "offset_cm": offset_cm, "views": views, "ray_on_target": share(sums[1]),
        "var_says_target": share(sums[2]), "var_says_nothing": share(sums[3]), "reward_mean": share(sums[4]),
    }  # fmt: skip


@torch.inference_mode()
def score_views(
    models: Models, images: np.ndarray, on_target: np.ndarray, goal: torch.Tensor, intent: int
) -> np.ndarray:
    """(offsets, 4): ray on target, VAR calls the target, VAR calls nothing, reward."""
    embedded = models.var.encode_image(torch.from_numpy(images))
    calls = (embedded @ models.prototypes.T).argmax(dim=1).numpy()
    rewards = reward_of(embedded @ goal, models.temperature).numpy()
    return np.column_stack([on_target, calls == intent, calls == 4, rewards]).astype(np.float64)


def extent_cm(rows: list[dict], key: str) -> list[int] | None:
    """The offsets (cm) between which at least half the views count as on the target, by `key`."""
    inside = [row["offset_cm"] for row in rows if row[key] is not None and row[key] >= 0.5]
    return [min(inside), max(inside)] if inside else None


def classify_end(offset_m: np.ndarray, heard: int, intent: int, block_m: tuple[float, float]) -> str:
    """What a try's last step shows: `offset_m` = gripper minus the target block's centre (x, y)."""
    if heard == intent:
        return "success"
    if heard >= 0:
        return "another block"
    dx, dy = np.abs(offset_m)
    if np.hypot(dx, dy) > FAR_M:
        return "elsewhere"
    if dy <= block_m[1] / 2 + 0.01 and dx > block_m[0] / 2:
        return "past an end of the target"
    return "beside the target"


def at_workspace_edge(target_xy: tuple[float, float]) -> bool:
    """Whether the gripper's target stands on a limit of the workspace (the arm clips every move to it)."""
    from sim.arm import WORKSPACE_X_M, WORKSPACE_Y_M

    return any(
        abs(value - limit) < EDGE_M
        for value, limits in zip(target_xy, (WORKSPACE_X_M, WORKSPACE_Y_M), strict=True)
        for limit in limits
    )


END_CLASSES = ("success", "another block", "past an end of the target", "beside the target", "elsewhere")


@dataclass(frozen=True)
class Try:
    intent: int
    layout_seed: int
    goal_clip: int  # row of the tier's clip bank
    stored_success: bool | None = None  # the outcome `bench/reproduce.py` recorded, for a replayed try


def protocol_tries(models: Models, per_intent: int, seed: int) -> list[Try]:
    """The evaluation protocol's schedule of tries, with a goal clip drawn for each."""
    from learning.rl.evaluate import episode_schedule

    schedule = episode_schedule(4, per_intent, seed)
    return [
        Try(
            intent,
            layout_seed,
            int(models.bank.sample(np.array([intent]), np.random.default_rng([seed, i + 1]))[0]),
        )
        for i, (intent, layout_seed) in enumerate(schedule)
    ]


def stored_tries(path: Path, tier: str) -> list[Try]:
    """The tries a `bench/reproduce.py` evaluation recorded (RUN/bench-eval-<tier>.json), to replay them."""
    stored = json.loads(path.read_text())
    if stored.get("split") != tier:
        raise SystemExit(
            f"{path} holds {stored.get('split')!r} tries; pass --tier {stored.get('split')} to replay them"
        )
    return [Try(e["intent"], e["seed"], e["goal_clip"], e["success"]) for e in stored["episodes"]]


def play(
    env: gymnasium.Env, models: Models, schedule: list[Try], sampled_seed: int | None = None
) -> list[dict]:
    """The tries one at a time: each try's intent, end class and final offset (cm). With `sampled_seed`,
    actions are drawn from the policy's Gaussian (try i's draws seeded by `sampled_seed + i`)."""
    from sim.blocks import BLOCK_SIZE_M

    tries = []
    for index, planned in enumerate(tqdm(schedule, desc="tries", unit="try")):
        intent = planned.intent
        observation, _ = env.reset(seed=planned.layout_seed, options={"intent": intent})
        start_xy = [round(float(v), 4) for v in env.unwrapped.arm.gripper_xy()]
        centre = np.asarray(env.unwrapped.slot_position(intent)[:2])
        goal = np.array([planned.goal_clip])
        noise = None if sampled_seed is None else torch.Generator().manual_seed(sampled_seed + index)
        touched, final_heard = play_one(env, models, models.policy, observation, goal, intent, noise)
        recorded = planned.stored_success if noise is None else None  # the record holds the mean's outcomes
        offset = np.asarray(env.unwrapped.arm.gripper_xy()) - centre
        tries.append({
            "intent": intent, "end": classify_end(offset, final_heard, intent, BLOCK_SIZE_M[:2]),
            "offset_cm": [round(100 * float(v), 2) for v in offset], "touched_target": touched,
            "at_workspace_edge": at_workspace_edge(env.unwrapped.arm.target_xy), "start_xy_m": start_xy,
            **({} if recorded is None else {"stored_success": recorded}),
        })  # fmt: skip
    return tries


@torch.inference_mode()
def play_one(
    env: gymnasium.Env,
    models: Models,
    policy: Any,
    observation: dict,
    goal: np.ndarray,
    intent: int,
    noise: torch.Generator | None = None,
) -> tuple[bool, int]:
    """Plays one try to its end; (whether the gripper was over the target at any step, what it ends over).
    With `noise`, each action is drawn from the policy's Gaussian around its mean, as in training."""
    from learning.rl.evaluate import goal_inputs

    goal_features = policy.encode_goal(goal_inputs(models.bank, goal, policy.config.goal_encoder))
    hidden, start = policy.initial_state(1), torch.ones(1)
    touched, done, heard = False, False, -1
    while not done:
        image = torch.from_numpy(observation["image"][None])
        state = torch.from_numpy(np.asarray(observation["state"], dtype=np.float32)[None])
        var_view = models.var.encode_image(image) if policy.config.var_dim else torch.zeros(1, 0)
        mean, _, hidden = policy.step(policy.view_of(image), var_view, state, goal_features, hidden, start)
        if noise is not None:  # the trainer's own Gaussian, drawn from this try's generator
            gaussian = policy.distribution(mean)
            action = torch.normal(gaussian.mean, gaussian.stddev, generator=noise)
        else:
            action = mean
        observation, _, terminated, truncated, info = env.step(action.clamp(-1.0, 1.0).numpy()[0])
        start, heard = torch.zeros(1), int(info["heard"])
        touched |= heard == intent
        done = terminated or truncated
    return touched, heard


def summarise_tries(tries: list[dict]) -> dict[str, Any]:
    by_intent = []
    for intent in range(4):
        mine = [t for t in tries if t["intent"] == intent]
        by_intent.append({end: sum(t["end"] == end for t in mine) for end in END_CLASSES})
    failed = [t for t in tries if t["end"] != "success"]
    return {
        "tries": len(tries),
        "success_rate": round(sum(t["end"] == "success" for t in tries) / max(len(tries), 1), 4),
        "ends": {end: sum(t["end"] == end for t in tries) for end in END_CLASSES},
        "ends_by_intent": by_intent,
        "failed_after_touching_target": sum(t["touched_target"] for t in failed),
        "failed_at_workspace_edge": sum(t.get("at_workspace_edge", False) for t in failed),
        "past_an_end_towards_camera": sum(
            t["end"] == "past an end of the target" and t["offset_cm"][0] > 0 for t in tries
        ),
        "success_offset_cm_mean": mean_offset([t for t in tries if t["end"] == "success"]),
        **agreement(tries),
        **by_start_band(tries),
    }


def by_start_band(tries: list[dict]) -> dict[str, dict]:
    """Tries and failed tries by where the gripper started across the row (y, in START_BAND_CM bands)."""
    started = [t for t in tries if "start_xy_m" in t]
    if not started:
        return {}
    bands: dict[str, dict[str, int]] = {}
    for t in sorted(started, key=lambda t: t["start_xy_m"][1]):
        low = START_BAND_CM * math.floor(100 * t["start_xy_m"][1] / START_BAND_CM)
        band = bands.setdefault(f"{low:+d} to {low + START_BAND_CM:+d} cm", {"tries": 0, "failed": 0})
        band["tries"] += 1
        band["failed"] += t["end"] != "success"
    return {"by_start_y": bands}


def agreement(tries: list[dict]) -> dict[str, int]:
    """For replayed tries: how many ended as `bench/reproduce.py` recorded them (success or not)."""
    replayed = [t for t in tries if "stored_success" in t]
    if not replayed:
        return {}
    return {"agrees_with_stored": sum((t["end"] == "success") == t["stored_success"] for t in replayed)}


def mean_offset(tries: list[dict]) -> list[float] | None:
    if not tries:
        return None
    return [round(float(v), 2) for v in np.mean([t["offset_cm"] for t in tries], axis=0)]


def planned_tries(args: argparse.Namespace, models: Models) -> list[Try]:
    if args.episodes_from is not None:
        return stored_tries(args.episodes_from, args.tier)
    return protocol_tries(models, args.episodes_per_intent, args.seed)


def measure_room(args: argparse.Namespace, models: Models, room: str) -> dict[str, Any]:
    env = make_world(args.world, room, int(models.var.config.image_size))
    try:
        profile = scan(env, models, args.layouts, args.reach_cm, args.seed)
        sampled_seed = args.seed if args.actions == "sampled" else None
        tries = play(env, models, planned_tries(args, models), sampled_seed)
    finally:
        env.close()
    return {
        "scan": profile,
        "extent_cm": {
            axis: {"ray": extent_cm(rows, "ray_on_target"), "var": extent_cm(rows, "var_says_target")}
            for axis, rows in profile.items()
        },
        "policy": summarise_tries(tries) if tries else None,
        "tries": tries,
    }


def report(results: dict[str, dict], actions: str = "mean") -> None:
    console = Console()
    table = Table(title="Where the target block ends: the ray against the VAR (cm from its centre)")
    for column in ("room", "axis", "ray: on it", "VAR: on it", "reward: centre / 2 cm past the ray's edge"):
        table.add_column(column, justify="right")
    for room, result in results.items():
        for axis, extents in result["extent_cm"].items():
            rows = {row["offset_cm"]: row for row in result["scan"][axis]}
            ray = extents["ray"]
            past = rows.get(ray[1] + 2) if ray else None
            reward = f"{rows[0]['reward_mean']:.3f} / " + (
                f"{past['reward_mean']:.3f}" if past and past["views"] else "-"
            )
            table.add_row(room, axis, span(ray), span(extents["var"]), reward)
    console.print(table)
    tries = Table(title=f"Where the policy's tries end ({actions} actions)")
    for column in (
        "room",
        "success",
        *END_CLASSES[1:],
        "failed after touching the target",
        "failed at the edge",
        "as recorded",
    ):
        tries.add_column(column, justify="right")
    for room, result in results.items():
        policy = result["policy"]
        if policy:
            ends = policy["ends"]
            tries.add_row(
                room, f"{100 * policy['success_rate']:.1f} %", *(str(ends[e]) for e in END_CLASSES[1:]),
                str(policy["failed_after_touching_target"]), str(policy["failed_at_workspace_edge"]),
                as_recorded(policy),
            )  # fmt: skip
    console.print(tries)


def as_recorded(policy: dict[str, Any]) -> str:
    """How many replayed tries ended as recorded ("–": tries of the protocol's own schedule)."""
    return f"{policy['agrees_with_stored']} of {policy['tries']}" if "agrees_with_stored" in policy else "–"


def span(extent: list[int] | None) -> str:
    return "none" if extent is None else f"{extent[0]:+d} to {extent[1]:+d}"


def plot(results: dict[str, dict], path: Path) -> None:
    from sim.blocks import BLOCK_SIZE_M

    figure, axes = plt.subplots(len(results), 2, figsize=(10, 4 * len(results)), squeeze=False)
    for (room, result), (left, right) in zip(results.items(), axes, strict=True):
        for axis, style in (("x", "-"), ("y", "--")):
            rows = [row for row in result["scan"][axis] if row["views"]]
            offsets = [row["offset_cm"] for row in rows]
            left.plot(offsets, [row["ray_on_target"] for row in rows], "k" + style, label=f"ray, {axis}")
            left.plot(offsets, [row["var_says_target"] for row in rows], "C0" + style, label=f"VAR, {axis}")
            left.plot(offsets, [row["reward_mean"] for row in rows], "C1" + style, label=f"reward, {axis}")
        left.set_xlabel("gripper offset from the target block's centre (cm)")
        left.set_ylabel("share on target / mean reward")
        left.set_title(f"{room}: the target block for the ray and for the VAR")
        left.legend(fontsize=7)
        left.grid(alpha=0.3)
        draw_ends(right, result["tries"], BLOCK_SIZE_M)
        right.set_title(f"{room}: where the policy's tries end")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def draw_ends(axis: Any, tries: list[dict], block_m: tuple[float, ...]) -> None:
    length, width = 100 * block_m[0], 100 * block_m[1]
    axis.add_patch(Rectangle((-width / 2, -length / 2), width, length, color="0.85", label="target block"))
    for succeeded, colour in ((True, "C2"), (False, "C3")):
        chosen = [t["offset_cm"] for t in tries if (t["end"] == "success") == succeeded]
        if chosen:
            points = np.array(chosen)
            label = "success" if succeeded else "failure"
            axis.scatter(points[:, 1], points[:, 0], s=10, color=colour, label=label)
    axis.set_xlabel("y offset (cm)")
    axis.set_ylabel("x offset (cm), + towards the camera")
    axis.set_xlim(-15, 15)
    axis.set_ylim(-15, 15)
    axis.set_aspect("equal")
    axis.legend(fontsize=7)


def checkpoint_paths(args: argparse.Namespace) -> tuple[Path, Path]:
    """The VAR and policy asked for, the world's base model's where one is not given."""
    from worker.base_models import find_base

    base = find_base(args.world) if args.var is None or args.policy is None else None
    return args.var or base.var_path, args.policy or base.policy_path


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    conditions = Conditions()
    torch.set_num_threads(1)
    var_path, policy_path = checkpoint_paths(args)
    models = load_models(var_path, policy_path, args.tier)
    results = {room: measure_room(args, models, room) for room in args.rooms.split(",")}
    measured = conditions.finish()
    report(results, args.actions)
    print(describe(measured))
    png = args.out.with_suffix(".png")
    plot(results, png)
    write_result(args.out, {
        "world": args.world, "var": str(var_path), "policy": str(policy_path),
        "var_sha256": file_sha256(var_path), "policy_sha256": file_sha256(policy_path),
        "tier": args.tier, "layouts_per_command": args.layouts,
        "episodes_per_intent": args.episodes_per_intent, "seed": args.seed, "actions": args.actions,
        "episodes_from": None if args.episodes_from is None else str(args.episodes_from),
        "reward_temperature": models.temperature, "rooms": results, "png": png.name,
        **measured,
    })  # fmt: skip
    print(f"wrote {args.out} and {png}")


if __name__ == "__main__":
    main()
