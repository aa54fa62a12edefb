"""The paper's Table I on this machine: VAR and the baselines on Kuka and TurtleBot with each sound set.

    nice -n 10 .venv/bin/python bench/reproduce.py --resume                      # the required rows, 1M steps
    nice -n 19 .venv/bin/python bench/reproduce.py --rows kuka-wordset:var --steps 300000 --tag reduced \\
        --var-dataset bench-kuka-50000-96px-seed0 --var-max-steps 500 --max-minutes 35 --resume  # reduced

Each row is world-sounds:method. A row trains a policy (resuming from its checkpoint with --resume), then runs
the evaluation protocol (50 episodes per intent, deterministic policy) on every unheard tier of the corpus.
Missing pieces are made first through the project's own commands: the corpus (`varbot sounds build`), the
VAR's triplets (`varbot var collect`) and the VAR (`varbot var train`), unless --var names a checkpoint to
use.

Three training options. --hard-target-share S (default 0.5, as every new run; 0 draws every target
uniformly, as the paper) gives a share S of the episodes to targets whose recent mean return (the run's own
reward, intrinsic for VAR) is furthest below the best target's. --hard-start-share S (Kuka and Kinova; default
0, uniform starts) does the same for where the gripper starts: five strips across the table, 0.1 m wide in y,
so that starts at the edge of the camera's frame, which the policy rarely learns to leave, come up more often;
evaluation episodes start where they always did. --target-intents 0 trains on target 0 only: the
diagnostic that showed "zero" alone is learnable; such runs go under "diagnostics", not into the table.
--experiment records a run under "experiments", beside its row, so trying a PPO variant (--ent-coef,
--goal-match, --reward-against-others, --reward-temperature, --contact, --hard-start-share) never replaces
the row's result; its curve still joins the row's figure. --var-heard-reach R makes the TurtleBot's VAR
from views named after an object only within R metres of it (its own dataset and VAR). --contact slide trains
and evaluates TurtleBot rows in the arena where a blocked robot glides along what it meets instead of standing
still (sim.turtlebot_arena).

`bench/results/reproduce.json` keeps one record per row: status (complete / partial), env steps, wall time,
steps/s, labels used (counted as the paper does), success per unheard tier and per intent, where each
evaluation episode ended (which object, or none), peak memory, the curve PNG; for VAR rows also the share of
each tier's clips the VAR embeds nearest their own command and the success split by that (misread goal clips
against ones the policy failed to reach). Each episode (goal clip, layout seed, end distance) stays in the run
directory as bench-eval-<tier>.json. A row run again under an earlier tag becomes the row's record again.
Success-vs-steps curves: `bench/results/reproduce_<world>-<sounds>.png`. Never tuned on test voices:
evaluation only reads the unheard tiers, training only the train split. Each record also holds the machine and
the load average before and after its run; paths are relative to the data directory or the repository.

The printed table (stored under "table") gives each row as the mean and spread over the seeds of its recipe
and lists every seed. This script is the only writer of the JSON: records are moved, relabelled or dropped
after their runs with `bench/reproduce.py records list|move|relabel|drop|hand-edit|relativise-paths --why …`,
and every such edit is logged in the file under "edits" (see bench/reproduce_records.py).
"""

import argparse
import subprocess
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

from conditions import Conditions, describe
from reproduce_records import RESULTS, records_command, updated_results
from reproduce_table import print_table
from result_files import relative_path, resolve

from varbot.services import exit_on_sigterm

WORLD_SOUNDS = {
    "kuka-wordset": ("kuka", "wordset"),
    "kuka-notes": ("kuka", "notes"),
    "kuka-mix": ("kuka", "mix"),
    "turtlebot-objects": ("turtlebot", "objects"),
    "turtlebot-notes": ("turtlebot", "notes"),
    "turtlebot-mix": ("turtlebot", "mix"),
}
# Paper, Table I (success %, 200 test episodes). The paper's TurtleBot "Wordset" row is our "objects" set.
PAPER = {
    "kuka-wordset": {"sparse": 46.0, "rsi": 95.5, "var": 97.0},
    "kuka-notes": {"sparse": 28.5, "rsi": 92.5, "var": 98.0},
    "kuka-mix": {"sparse": 23.0, "rsi": 94.0, "var": 95.5},
    "turtlebot-objects": {"sparse": 22.0, "rsi": 92.0, "var": 94.0},
    "turtlebot-notes": {"sparse": 9.5, "rsi": 95.0, "var": 96.0},
    "turtlebot-mix": {"sparse": 21.0, "rsi": 87.0, "var": 91.0},
}
REQUIRED = [
    "kuka-wordset:var",
    "kuka-notes:var",
    "turtlebot-objects:var",
    "kuka-wordset:sparse",
    "kuka-wordset:rsi",
]


def parse_arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--rows", default=",".join(REQUIRED), help="comma-separated world-sounds:method")
    parser.add_argument("--steps", type=int, default=1_000_000, help="env steps per row")
    parser.add_argument(
        "--triplets", type=int, default=50_000, help="VAR training views (when a VAR is made)"
    )
    parser.add_argument("--var", type=Path, default=None, help="use this VAR checkpoint for the var rows")
    parser.add_argument("--var-dataset", default=None, help="train the VAR on this collected dataset")
    parser.add_argument("--var-max-steps", type=int, default=None, help="shorter VAR schedule (reduced runs)")
    parser.add_argument(
        "--var-speed-copies", type=int, default=0, help="train the VAR with this many speed-perturbed copies"
    )
    parser.add_argument(
        "--var-front-end",
        default="mfcc",
        help="sound front end of a VAR trained here: mfcc, speech-embedding or speech-embedding-fast",
    )
    parser.add_argument(
        "--var-room-copies", type=int, default=0, help="train the VAR with this many simulated-room copies"
    )
    parser.add_argument(
        "--var-voice-copies",
        type=int,
        default=0,
        help="train the VAR with this many formant-warped copies (another vocal tract) of every clip",
    )
    parser.add_argument(
        "--var-heard-reach",
        type=float,
        default=None,
        help="TurtleBot: collect views named after an object only within this many metres of it (a new "
        "dataset; the world's default is 0.6, the success distance 0.35)",
    )
    parser.add_argument("--image-size", type=int, default=None, help="default: the VAR's (96 when none)")
    parser.add_argument(
        "--policy-image-size", type=int, default=None, help="policy CNN input size (default: PPOConfig)"
    )
    parser.add_argument("--ent-coef", type=float, default=None, help="PPO entropy bonus (default: PPOConfig)")
    parser.add_argument(
        "--goal-match",
        action="store_const",
        const=True,
        default=None,
        help="the policy also sees f_I(I_t)·f_S(S_goal), the reward it earns now (experimental)",
    )
    parser.add_argument(
        "--reward-against-others",
        action="store_const",
        const=True,
        default=None,
        help="the VAR reward minus the view's best match with another command (experimental)",
    )
    parser.add_argument(
        "--reward-temperature",
        type=float,
        default=None,
        help="pay exp((match - 1)/T) instead of the plain VAR match (experimental)",
    )
    parser.add_argument(
        "--contact",
        choices=["stop", "slide"],
        default=None,
        help="TurtleBot: a blocked robot stands still (stop, the world's own) or glides along what it meets",
    )
    parser.add_argument("--episodes-per-intent", type=int, default=50)
    parser.add_argument(
        "--room",
        default="training",
        help="evaluate in this room: training, unseen_room, lamplit_room (core.rooms)",
    )
    parser.add_argument("--max-minutes", type=float, default=None, help="stop a row after this wall time")
    parser.add_argument("--tag", default="full", help="label stored with the rows (e.g. reduced)")
    parser.add_argument("--resume", action="store_true", help="continue rows from their checkpoints")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--hard-target-share",
        type=float,
        default=0.5,
        help="curriculum: share of episodes whose target favours low recent return (0: uniform, the paper)",
    )
    parser.add_argument(
        "--hard-start-share",
        type=float,
        default=None,
        help="block worlds: share of episodes whose gripper starts in the strips of the table where recent "
        "episodes earned least (default 0: uniform starts, the paper); training only",
    )
    parser.add_argument(
        "--experiment",
        action="store_true",
        help="record the run under experiments, beside its row, instead of making it the row",
    )
    parser.add_argument(
        "--target-intents",
        type=lambda text: [int(k) for k in text.split(",")],
        default=None,
        help="diagnostics: the world asks only for these targets, e.g. 0 or 0,3 (default: all)",
    )
    return parser.parse_args()


def varbot(*arguments: str) -> None:
    command = [str(Path(sys.executable).with_name("varbot")), *arguments]
    print("$", " ".join(command), flush=True)
    subprocess.run(command, check=True)


def ensure_corpus(sounds: str) -> None:
    from learning.sounds import load_corpus

    try:
        load_corpus(sounds)
    except FileNotFoundError:
        varbot("sounds", "build", "--sets", sounds)


def row_dataset(world: str, args: argparse.Namespace) -> str:
    reach = f"-reach{round(args.var_heard_reach * 100)}cm" if args.var_heard_reach else ""
    return args.var_dataset or f"reproduce-{world}-{args.triplets}{reach}"


def ensure_dataset(world: str, sounds: str, args: argparse.Namespace) -> str:
    """The collected views behind a row's VAR or one-hot encoders: --var-dataset, or collected here once."""
    from learning.var.dataset import DatasetError, open_dataset

    dataset = row_dataset(world, args)
    try:
        open_dataset(dataset)
    except DatasetError:
        reach_args = ["--heard-reach", str(args.var_heard_reach)] if args.var_heard_reach else []
        varbot("var", "collect", world, "--triplets", str(args.triplets), "--sounds", sounds,
               "--name", dataset, "--image-size", str(args.image_size or 96), *reach_args)  # fmt: skip
    return dataset


def ensure_encoders(world: str, sounds: str, policy_image_size: int, args: argparse.Namespace) -> Path:
    """The sparse baseline's encoders, pre-trained on one-hot labels of the row's views (as the paper)."""
    from core.paths import data_subdir

    dataset = ensure_dataset(world, sounds, args)
    out = (
        data_subdir("bench", "reproduce", "encoders")
        / f"{Path(dataset).name}-{sounds}-{policy_image_size}px.pt"
    )
    if not out.exists():
        varbot("rl", "pretrain", dataset, "--sounds", sounds, "--out", str(out),
               "--policy-image-size", str(policy_image_size))  # fmt: skip
    return out


# Copies a VAR trained here may add to its clips: (the name's tag, the argument, `varbot var train`'s flag)
VAR_COPIES = (
    ("speed", "var_speed_copies", "--speed-copies"),
    ("rooms", "var_room_copies", "--room-copies"),
    ("voices", "var_voice_copies", "--voice-copies"),
)


def var_name(world: str, sounds: str, args: argparse.Namespace) -> str:
    """A VAR trained here is named by its views, its sounds and each training option off its default."""
    schedule = f"-{args.var_max_steps}steps" if args.var_max_steps else ""
    copies = "".join(f"-{tag}{getattr(args, arg)}" for tag, arg, _ in VAR_COPIES if getattr(args, arg))
    front_end = "" if args.var_front_end == "mfcc" else f"-{args.var_front_end}"
    return f"{Path(row_dataset(world, args)).name}-{sounds}{schedule}{copies}{front_end}"


def ensure_var(world: str, sounds: str, args: argparse.Namespace) -> Path:
    """The VAR for a row: --var if given, else one trained here (on --var-dataset or on new views)."""
    if args.var is not None:
        return args.var
    from core.paths import data_subdir

    run_dir = data_subdir("bench", "reproduce", "var", var_name(world, sounds, args))
    final = run_dir / "final.pt"
    if not final.exists():
        dataset = ensure_dataset(world, sounds, args)
        copy_args = []
        for _, arg, flag in VAR_COPIES:
            if getattr(args, arg):
                copy_args += [flag, str(getattr(args, arg))]
        schedule_args = ["--max-steps", str(args.var_max_steps)] if args.var_max_steps else []
        varbot("var", "train", dataset, "--sounds", sounds, "--run-dir", str(run_dir), "--threads", "1",
               "--front-end", args.var_front_end, *schedule_args, *copy_args)  # fmt: skip
    return final


def run_row(key: str, args: argparse.Namespace) -> dict:
    from core.paths import data_subdir
    from core.rooms import world_room
    from learning.rl.baselines import method_config, needs_var
    from learning.rl.evaluate import evaluate, save_eval
    from learning.rl.frozen_var import load_frozen_var
    from learning.rl.plots import plot_run, read_metrics
    from learning.rl.ppo import load_policy
    from learning.rl.rewards import REWARD_REVISIONS, corpus_bank
    from learning.rl.run import train_run
    from learning.rl.stopping import StopRequest
    from learning.sounds import load_corpus

    row, method = key.split(":")
    world, sounds = WORLD_SOUNDS[row]
    ensure_corpus(sounds)
    var_path = ensure_var(world, sounds, args) if needs_var(method) else None
    image_size = args.image_size
    loaded_var = load_frozen_var(var_path)  # read once, for the run and its evaluation
    if image_size is None and loaded_var is not None:
        image_size = loaded_var.image_size
    config = method_config(
        method,
        world=world,
        sounds=sounds,
        total_steps=args.steps,
        image_size=image_size or 96,
        seed=args.seed,
        hard_target_share=args.hard_target_share,
        target_intents=args.target_intents,
        **optional_overrides(args),
    )
    if method == "sparse":
        encoders = ensure_encoders(world, sounds, config.policy_image_size, args)
        config = replace(config, init_encoders=str(encoders))
    run_dir = data_subdir("bench", "reproduce", "rl", args.tag, f"{row}-{method}")
    conditions = Conditions()
    started = time.monotonic()
    stop = StopRequest()

    def on_update(record: dict) -> bool:
        out_of_time = args.max_minutes is not None and time.monotonic() - started > 60 * args.max_minutes
        stopping = out_of_time or stop(record)
        if record["update"] % 10 == 0 or stopping:  # a stopped run's progress is its checkpoint's
            with updated_results() as results:
                store, entry = record_slot(results, key, args)
                previous = store.get(entry, {})
                if previous.get("tag") != args.tag:  # a new run: none of the old run's figures
                    previous = {"row": row, "method": method, "tag": args.tag}
                # the config: an interrupted run still says which seed and settings it ran with
                store[entry] = {**previous, "config": asdict(config), "status": "running", "progress": record}
        return stopping

    with stop:
        summary = train_run(config, run_dir, loaded_var, resume=args.resume, on_update=on_update)
    if stop.signal is not None:  # no evaluation: main() stores the run as interrupted
        sys.exit(stop.explain(summary, run_dir))
    records = read_metrics(run_dir)
    wall = sum(config.batch_size / r["sps"] for r in records)
    complete = summary["env_steps"] >= config.num_updates * config.batch_size
    policy, payload = load_policy(run_dir / "checkpoint.pt")
    var = loaded_var.model if loaded_var is not None else None
    front_end = var.front_end if var is not None else "mfcc"  # goal clips as the VAR's f_S reads them
    corpus = load_corpus(sounds, front_end=front_end)
    understood = goal_clips_understood(var, corpus) if var is not None else None
    evaluations = {}
    for split in [s for s in corpus.splits if s != "train"]:
        goals = corpus_bank(sounds, split, front_end=front_end)
        if var is not None:
            goals.embed(var)
        result = evaluate(policy, var, goals, world, config.image_size, split=split,
                          episodes_per_intent=args.episodes_per_intent, seed=2023,
                          domain=world_room(args.room), world_options=config.world_options)  # fmt: skip
        evaluations[split] = result.to_dict()
        in_room = "" if args.room == "training" else f"-{args.room}"
        # every episode, for failure analysis
        save_eval(result, run_dir / f"bench-eval-{split}{in_room}.json")
        if understood is not None:
            evaluations[split]["by_goal_understanding"] = success_by_understanding(understood[split], result)
    plot_run(run_dir)
    return {
        "row": row,
        "world": world,
        "sounds": sounds,
        "method": method,
        "tag": args.tag,
        "evaluation_room": args.room,
        "status": "complete" if complete else "partial",
        "env_steps": summary["env_steps"],
        "target_steps": config.num_updates * config.batch_size,
        "wall_s": wall,
        "steps_per_s": summary["env_steps"] / wall if wall else None,
        "time_shares": summary["time_shares"],
        "peak_memory_mb": summary["peak_memory_mb"],
        "labels": summary["labels"],
        "training_recent_success": summary["recent_success"],
        "success": {split: e["success_rate"] for split, e in evaluations.items()},
        "evaluation": evaluations,
        "var_nearest_command": None
        if understood is None
        else {t: float(h.mean()) for t, h in understood.items()},
        "paper_success": PAPER[row].get(method.replace("-current-sound", "")),
        "reward_revision": REWARD_REVISIONS[config.reward],
        "var_checkpoint": None if var_path is None else relative_path(var_path),
        "run_dir": relative_path(run_dir),
        "curves": relative_path(run_dir / "curves.png"),
        "config": payload["config"],
        **conditions.finish(),
    }


def goal_clips_understood(var, corpus) -> dict:
    """Per unheard tier, which goal clips the VAR embeds nearest their own command (centroids of the training
    clips), in the order `corpus_bank` gives them. Their share bounds success: the policy heads for the
    command a clip embeds as."""
    from learning.var.evaluate import nearest_command_accuracy

    train, num_intents = corpus.subset("train"), len(corpus.intent_names)
    return {
        split: nearest_command_accuracy(var, train, corpus.subset(split), num_intents)[1]
        for split in corpus.splits
        if split != "train"
    }


def success_by_understanding(understood_clips, result) -> dict[str, float | int | None]:
    """Success on the episodes whose goal clip the VAR understands, and on the others: separates what the
    sound encoder misreads from what the policy fails to reach."""
    import numpy as np

    understood = np.array([understood_clips[e.goal_clip] for e in result.episodes])
    success = np.array([e.success for e in result.episodes])
    return {
        "episodes_understood": int(understood.sum()),
        "success_understood": float(success[understood].mean()) if understood.any() else None,
        "episodes_misunderstood": int((~understood).sum()),
        "success_misunderstood": float(success[~understood].mean()) if (~understood).any() else None,
    }


def optional_overrides(args: argparse.Namespace) -> dict:
    """PPO settings given on the command line; the others keep PPOConfig's defaults."""
    given = {
        "policy_image_size": args.policy_image_size,
        "ent_coef": args.ent_coef,
        "goal_match": args.goal_match,
        "reward_against_others": args.reward_against_others,
        "reward_temperature": args.reward_temperature,
        "contact": args.contact,
        "hard_start_share": args.hard_start_share,
    }
    return {name: value for name, value in given.items() if value is not None}


def record_slot(results: dict, key: str, args: argparse.Namespace) -> tuple[dict, str]:
    """Where a run's record goes: a row of the table, or its own entry beside the table for a diagnostic run
    (--target-intents, under "diagnostics") or an experiment (--experiment, under "experiments")."""
    if args.target_intents:
        targets = ",".join(map(str, args.target_intents))
        return results.setdefault("diagnostics", {}), f"{key} targets {targets} ({args.tag})"
    if args.experiment:
        return results.setdefault("experiments", {}), f"{key} ({args.tag})"
    return results["rows"], key


def curves(results: dict) -> None:
    """One success-vs-steps figure per row, over all its runs, drawn from the curves stored in the results (so
    a new machine redraws them without the old run directories). The one place a run's curve is stored: read
    from its run directory the first time, while that is here."""
    from learning.rl.plots import plot_success_curves, success_curve

    by_row: dict[str, dict] = {}
    experiments = results.get("experiments", {}).values()
    for record in [*results.get("earlier_runs", []), *results["rows"].values(), *experiments]:
        run_dir = resolve(record["run_dir"]) if "run_dir" in record else None
        if "success_curve" not in record and run_dir is not None and (run_dir / "metrics.jsonl").is_file():
            record["success_curve"] = success_curve(run_dir)
        label = f"{record.get('method')} ({record.get('tag')})"
        if "success_curve" in record:
            by_row.setdefault(record["row"], {})[label] = record["success_curve"]
        elif "success" in record:
            print(f"{record['row']} {label}: no training curve stored or here, so not in the figure")
    for row, row_curves in by_row.items():
        path = plot_success_curves(
            row_curves, RESULTS / f"reproduce_{row}.png", title=f"{row}: success vs env steps"
        )
        results.setdefault("curves", {})[row] = relative_path(path)


def mark_interrupted(store: dict, entry: str) -> None:
    """A run stopped by Ctrl-C or SIGTERM says so, instead of staying "running" in the JSON."""
    record = store.get(entry, {})
    if record.get("status") != "running":
        return
    steps = record.get("progress", {}).get("global_step", 0)
    config = record.get("config") or {}
    of = f" of {config['total_steps']:,}, seed {config['seed']}" if config else ""
    store[entry] = {
        **record,
        "status": "interrupted",
        "note": f"stopped at {steps:,} env steps{of} (its last checkpoint may be earlier); the same command "
        "with --resume takes it up again from its run directory",
    }


def curves_and_table(results: dict) -> None:
    """What every change to the records ends with: the figures redrawn, the table printed and stored."""
    curves(results)
    print_table(results)


def main() -> None:
    exit_on_sigterm()
    if sys.argv[1:2] == ["records"]:
        records_command(sys.argv[2:], curves_and_table)
        return
    conditions = Conditions()
    args = parse_arguments()
    keys = [k.strip() for k in args.rows.split(",") if k.strip()]
    for key in keys:
        row, _, method = key.partition(":")
        if row not in WORLD_SOUNDS or method not in ("var", "var-current-sound", "sparse", "rsi"):
            sys.exit(
                f"unknown row {key!r}: use world-sounds:method with world-sounds in {', '.join(WORLD_SOUNDS)}"
            )
    for key in keys:
        if not begin_run(key, args):
            continue
        try:
            record = run_row(key, args)
        except (KeyboardInterrupt, SystemExit):
            with updated_results() as results:
                mark_interrupted(*record_slot(results, key, args))
            raise
        with updated_results() as results:
            store, entry = record_slot(results, key, args)
            store[entry] = record
    with updated_results() as results:
        curves_and_table(results)
    print(describe(conditions.finish()))


def begin_run(key: str, args: argparse.Namespace) -> bool:
    """Makes room for a run of `key` in the file; False: it is complete already and --resume skips it."""
    row, _, method = key.partition(":")
    with updated_results() as results:
        store, entry = record_slot(results, key, args)
        done = store.get(entry, {})
        if args.resume and done.get("status") == "complete" and done.get("tag") == args.tag:
            print(f"{entry}: complete, skipped")
            return False
        if done.get("tag", args.tag) != args.tag and "success" in done:
            results.setdefault("earlier_runs", []).append(done)  # kept for comparison, not replaced
        if store is results["rows"]:  # a run taken up again is the row's record now, not an earlier one
            results["earlier_runs"] = [
                r
                for r in results.get("earlier_runs", [])
                if (r.get("row"), r.get("method"), r.get("tag")) != (row, method, args.tag)
            ]
    return True


if __name__ == "__main__":
    main()
