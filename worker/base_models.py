"""The pre-trained base models a new household starts from (VAR + policy per simulated world).

Looked up in order: `$VARBOT_BASE_MODELS_DIR/<world>/`, `data_dir()/base_models/<world>/` (what
`varbot models build-base` writes by default), then the copies shipped in the repository
(`worker/base_models/<world>/`). Each folder holds `var.pt`, `policy.pt` and `base.json` (the command and the
figures that made them).
"""

import hashlib
import json
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from core.paths import REPO_ROOT, data_dir, data_dir_in
from core.rooms import HELD_OUT_ROOMS, RANDOMISED_ROOMS, TRAINING_ROOM, RoomRanges, world_room

if TYPE_CHECKING:
    import torch

    from learning.rl.rewards import ClipBank

SHIPPED_DIR = REPO_ROOT / "worker" / "base_models"
RECORD = "base.json"
EVALUATION_SEED_OFFSET = 999  # a base's evaluation episodes come from its recipe's seed + this


class BaseModelMissing(FileNotFoundError):
    pass


@dataclass(frozen=True)
class BaseModel:
    world: str
    folder: Path

    @property
    def var_path(self) -> Path:
        return self.folder / "var.pt"

    @property
    def policy_path(self) -> Path:
        return self.folder / "policy.pt"

    @property
    def record(self) -> dict[str, Any]:
        path = self.folder / RECORD
        return json.loads(path.read_text()) if path.is_file() else {}

    @property
    def image_size(self) -> int:
        return int(self.record.get("image_size", 96))

    @property
    def feature_kind(self) -> str:
        return str(self.record.get("feature_kind", "speech"))


def search_path(environ: Mapping[str, str] | None = None) -> list[Path]:
    """Where a process with `environ` (default: this one's) looks for base models, in order."""
    environ = os.environ if environ is None else environ
    own = environ.get("VARBOT_BASE_MODELS_DIR")
    return [*([Path(own)] if own else []), data_dir_in(environ) / "base_models", SHIPPED_DIR]


def find_base(world: str, roots: Sequence[Path] | None = None) -> BaseModel:
    """The first base model of `world` along `roots` (default: this process's `search_path()`)."""
    roots = search_path() if roots is None else roots
    for root in roots:
        folder = root / world
        if (folder / "var.pt").is_file() and (folder / "policy.pt").is_file():
            return BaseModel(world, folder)
    raise BaseModelMissing(
        f"no base model for the {world} world in {', '.join(map(str, roots))}; "
        f"build one with `varbot models build-base --world {world}`"
    )


def write_base(
    world: str, var_checkpoint: Path, policy_checkpoint: Path, out_root: Path, record: dict
) -> Path:
    """Copy a VAR and a policy into `out_root/<world>/` (the policy without optimiser state) with a record."""
    import torch

    from learning.rl.checkpoints import compact_policy_checkpoint
    from learning.var.checkpoint import read_checkpoint

    folder = out_root / world
    folder.mkdir(parents=True, exist_ok=True)
    var_payload = read_checkpoint(var_checkpoint)
    var_payload.pop("training", None)
    torch.save(var_payload, folder / "var.pt")
    compact_policy_checkpoint(policy_checkpoint, folder / "policy.pt")
    _write_record(folder, record)
    return folder


def _write_record(folder: Path, record: dict) -> None:
    """`base.json` beside the folder's var.pt and policy.pt, with their sizes."""
    sizes = {name: (folder / name).stat().st_size for name in ("var.pt", "policy.pt")}
    (folder / RECORD).write_text(json.dumps({**record, "file_bytes": sizes}, indent=2) + "\n")


@dataclass(frozen=True)
class BaseRecipe:
    """How a world's base model is made with the project's own trainers (recorded in its base.json).

    `room` is a `core.rooms.world_room` name: "randomised" (the default) trains the VAR's views and the
    policy's episodes over rooms drawn from `RoomRanges`, so the model survives a room it never saw;
    "training" keeps the world's own look. The policy's PPO settings are PPOConfig's defaults, the shipped
    Kuka policy's (intrinsic reward only, goal fused with the view, bounded mean, hard-target curriculum).
    """

    world: str = "kuka"
    sounds: str = "wordset"
    front_end: str = "mfcc"  # the VAR's sound front end (learning.front_ends)
    room: str = RANDOMISED_ROOMS
    views: int = 20_000
    image_size: int = 96
    var_epochs: int = 12
    var_max_steps: int | None = None  # overrides var_epochs: the VAR's schedule in optimiser steps
    policy_steps: int = 300_000
    eval_episodes_per_intent: int = 25
    eval_rooms: tuple[str, ...] = (TRAINING_ROOM, *HELD_OUT_ROOMS)
    seed: int = 0
    ppo_settings: dict[str, Any] = field(default_factory=dict)  # PPOConfig fields other than its defaults

    @property
    def name(self) -> str:
        """The work folder's name: one per recipe, so a rerun of the same recipe resumes it."""
        steps = f"{self.var_max_steps}steps" if self.var_max_steps else f"{self.var_epochs}ep"
        return (
            f"{self.world}-{self.sounds}-{self.front_end}-{self.room_label}-{self.views}-{self.image_size}px-"
            f"{steps}-seed{self.seed}"
        )

    @property
    def room_label(self) -> str:
        """The room as the work folder and the views name it. Randomised rooms carry a digest of the ranges,
        so a build after the ranges changed renders new views and trains a new VAR instead of resuming the
        ones of the old ranges."""
        room = world_room(self.room)
        if not isinstance(room, RoomRanges):
            return self.room
        ranges = json.dumps(asdict(room), sort_keys=True).encode()
        return f"{self.room}-{hashlib.sha256(ranges).hexdigest()[:8]}"

    @property
    def policy_folder(self) -> str:
        """The policy's folder inside the work folder: one per set of PPO settings, so a recipe that changes
        only the policy's settings reuses the views and the VAR but never resumes another policy."""
        if not self.ppo_settings:
            return "policy"
        settings = json.dumps(self.ppo_settings, sort_keys=True).encode()
        return f"policy-{hashlib.sha256(settings).hexdigest()[:10]}"


def build_base(
    recipe: BaseRecipe, out_root: Path, progress: bool = True, device: "str | torch.device" = "cpu"
) -> dict[str, Any]:
    """Collect views → train the VAR → train the policy with the intrinsic reward → evaluate → write.
    `device`: where PPO's VAR and policy run (`learning.device.resolve_device`).

    Every stage resumes: a complete view set is reused, the VAR continues from its `last.pt` and the policy
    from its `checkpoint.pt` (in `<data dir>/base_build/<recipe name>/`), so running the same recipe again
    after an interruption, or with more `policy_steps`, picks up where it stopped.
    """
    from learning.rl.ppo import PPOConfig
    from learning.rl.run import train_run
    from learning.var.dataset import collect_dataset
    from learning.var.model import VARConfig
    from learning.var.train import TrainConfig, train

    work = data_dir() / "base_build" / recipe.name
    work.mkdir(parents=True, exist_ok=True)
    clock = StageClock(work / "timings.json")
    room = world_room(recipe.room)
    with clock("collect_s"):
        dataset = collect_dataset(
            recipe.world, recipe.views, f"base-{recipe.world}-{recipe.room_label}-{recipe.views}-"
            f"{recipe.image_size}px-seed{recipe.seed}", seed=recipe.seed, image_size=recipe.image_size,
            domain=room, progress=progress,
        )  # fmt: skip
    with clock("var_train_s"):
        var_result = train(
            TrainConfig(
                dataset=str(dataset.path), sounds=recipe.sounds, run_dir=str(work / "var"),
                model=VARConfig(front_end=recipe.front_end), epochs=recipe.var_epochs,
                max_steps=recipe.var_max_steps, seed=recipe.seed, threads=1, progress=progress,
            )
        )  # fmt: skip
    ppo = PPOConfig(
        world=recipe.world, sounds=recipe.sounds, image_size=recipe.image_size,
        total_steps=recipe.policy_steps, seed=recipe.seed, room=recipe.room, **recipe.ppo_settings,
    )  # fmt: skip
    policy_dir = work / recipe.policy_folder
    with clock("policy_train_s"):
        summary = train_run(
            ppo, policy_dir, var_result.checkpoint, resume=True, progress=progress, device=device
        )
    with clock("evaluate_s"):
        evaluations = evaluate_in_rooms(
            var_result.checkpoint, policy_dir / "checkpoint.pt", recipe.eval_rooms,
            episodes_per_intent=recipe.eval_episodes_per_intent, seed=recipe.seed + EVALUATION_SEED_OFFSET,
            progress=progress,
        )  # fmt: skip
    record = {
        "world": recipe.world,
        "sounds": recipe.sounds,
        "front_end": recipe.front_end,
        "feature_kind": "speech",
        "image_size": recipe.image_size,
        "recipe": asdict(recipe),
        "room_ranges": asdict(room) if isinstance(room, RoomRanges) else None,
        "command": " ".join(["varbot", "models", "build-base", *sys.argv[3:]])
        if "build-base" in sys.argv
        else None,
        "views": recipe.views,
        "var_steps": var_result.steps,
        "var_best_val_balanced_accuracy": var_result.best_val_accuracy,
        "var_final_val_balanced_accuracy": var_result.final_val_accuracy,
        "policy_config": asdict(ppo),
        "policy_env_steps": summary["env_steps"],
        "policy_recent_success_in_training": summary["recent_success"],
        "evaluation": evaluations,
        "timings": clock.totals(),
        "built_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    folder = write_base(recipe.world, var_result.checkpoint, policy_dir / "checkpoint.pt", out_root, record)
    for source, name in (
        (work / "var" / "metrics.png", "var_curves.png"),
        (policy_dir / "curves.png", "policy_curves.png"),
    ):
        if source.is_file():
            shutil.copy(source, folder / name)
    return record


def refit_base(
    world: str,
    front_end: str,
    out_root: Path,
    extra_sounds: Sequence[str] = (),
    eval_episodes_per_intent: int | None = None,
    progress: bool = True,
    **refit_settings: Any,
) -> dict[str, Any]:
    """A world's base model moved to another sound front end (`learning.var.refit`): the same policy and f_I,
    f_S taught to agree with the old one, evaluated again in the rooms of its record with the same seed,
    written to `out_root/<world>/` with its record (the one before kept under `before_refit`);
    `refit_settings` are RefitConfig's (steps, room_copies...). Households whose VAR was fine-tuned from the
    old base keep it: its checkpoint names its own front end."""
    from learning.var.checkpoint import load_var, read_checkpoint, save_var
    from learning.var.refit import RefitConfig, refit_front_end

    base = find_base(world)
    before = base.record
    recipe = before.get("recipe", {})
    teacher_payload = read_checkpoint(base.var_path)
    teacher = load_var(base.var_path)
    config = RefitConfig(
        front_end=front_end, sounds=before.get("sounds", "wordset"), extra_sounds=tuple(extra_sounds),
        **refit_settings,
    )  # fmt: skip
    result = refit_front_end(teacher, config, progress=progress)
    extra = {
        key: teacher_payload[key] for key in ("manifest_hash", "sound_set", "world") if key in teacher_payload
    }
    with _staged(out_root / world) as staging:
        save_var(result.var, staging / "var.pt", **extra, refit=result.report)
        for name in ("policy.pt", "policy_curves.png", "var_curves.png"):
            if (base.folder / name).is_file():
                shutil.copy(base.folder / name, staging / name)
        evaluation = evaluate_as_recorded(staging, recipe, eval_episodes_per_intent, progress)
        record = _refit_record(base, front_end, result.report, evaluation)
        _write_record(staging, record)
    return record


def evaluate_as_recorded(
    folder: Path, recipe: dict[str, Any], episodes_per_intent: int | None, progress: bool
) -> dict[str, dict[str, dict[str, Any]]]:
    """The folder's VAR + policy evaluated in the rooms of a base's recipe, with its episodes and seed (so a
    changed base is scored on the episodes the old one was)."""
    return evaluate_in_rooms(
        folder / "var.pt", folder / "policy.pt", recipe.get("eval_rooms", [TRAINING_ROOM, *HELD_OUT_ROOMS]),
        episodes_per_intent=episodes_per_intent or int(recipe.get("eval_episodes_per_intent", 25)),
        seed=int(recipe.get("seed", 0)) + EVALUATION_SEED_OFFSET, progress=progress,
    )  # fmt: skip


@contextmanager
def _staged(folder: Path) -> Iterator[Path]:
    """A hidden folder beside `folder` to write a base model into: it replaces `folder` when the block ends,
    and is removed if the block fails, so a failed build leaves the old base and no half-written one."""
    staging = folder.with_name(f".{folder.name}.staging")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        yield staging
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    shutil.rmtree(folder, ignore_errors=True)
    staging.rename(folder)


def _refit_record(
    base: BaseModel, front_end: str, report: dict[str, Any], evaluation: dict[str, Any]
) -> dict[str, Any]:
    before = base.record
    folder = base.folder.relative_to(REPO_ROOT) if base.folder.is_relative_to(REPO_ROOT) else base.folder
    command = _command_line("refit-front-end")
    return {
        **{key: value for key, value in before.items() if key not in ("evaluation", "before_refit")},
        "front_end": front_end,
        "evaluation": evaluation,
        "refit": {
            **report,
            "command": command,
            "refitted_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        },
        "before_refit": {
            "front_end": before.get("front_end", "mfcc"),
            "evaluation": before.get("evaluation"),
            "folder": str(folder),
        },
    }


def replace_policy(
    world: str,
    run_dir: Path,
    out_root: Path,
    eval_episodes_per_intent: int | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """A world's base model with the finished policy of `run_dir` (`varbot rl train --var <base>/var.pt`):
    the same VAR, the run's policy and curves, evaluated again in the rooms of the record with its seed,
    written to `out_root/<world>/` with its record (the policy's part of the one before kept under
    `before_policy_replaced`). Households that started from the old base keep their own model versions."""
    from learning.rl.checkpoints import compact_policy_checkpoint

    base = find_base(world)
    run_dir = Path(run_dir)
    summary_path = run_dir / "summary.json"
    if not summary_path.is_file():
        raise ValueError(f"{run_dir} holds no finished policy run (no summary.json); finish it with --resume")
    config = json.loads((run_dir / "config.json").read_text())  # the run's settings, with its VAR's path
    _check_trained_on_base(base, config)
    summary = json.loads(summary_path.read_text())
    curves = {"var_curves.png": base.folder / "var_curves.png", "policy_curves.png": run_dir / "curves.png"}
    with _staged(out_root / world) as staging:
        shutil.copy(base.var_path, staging / "var.pt")
        compact_policy_checkpoint(run_dir / "checkpoint.pt", staging / "policy.pt")
        for name, source in curves.items():
            if source.is_file():
                shutil.copy(source, staging / name)
        evaluation = evaluate_as_recorded(
            staging, base.record.get("recipe", {}), eval_episodes_per_intent, progress
        )
        _write_record(staging, _replaced_policy_record(base, run_dir, config, summary, evaluation))
    return json.loads((out_root / world / RECORD).read_text())


def room_invariant_base(
    world: str,
    out_root: Path,
    eval_episodes_per_intent: int | None = None,
    progress: bool = True,
    **settings: Any,
) -> dict[str, Any]:
    """A world's base model whose image encoder was taught to see any room of its ranges as the training room
    (`learning.var.room_invariance`), in its VAR and in its policy's frozen view alike, evaluated again in the
    rooms of its record with its seed and written to `out_root/<world>/` (the evaluation before is kept under
    `before_room_invariance`). `settings` are InvarianceConfig's (views, steps...)."""
    from learning.var.checkpoint import load_var
    from learning.var.room_invariance import (
        InvarianceConfig,
        check_world_renders_rooms,
        render_pairs,
        teach_room_invariance,
    )

    base = find_base(world)
    check_world_renders_rooms(world)
    _require_policy_seeing_through_var(base)
    config = InvarianceConfig(world=world, **settings)
    teacher = load_var(base.var_path)
    pairs = render_pairs(config, teacher.config.image_size, data_dir() / "room_pairs" / world, progress)
    result = teach_room_invariance(teacher, pairs, config, progress)
    return _write_with_new_view(
        base, result.var, {"room_invariance": result.report}, out_root, eval_episodes_per_intent, progress,
        lambda evaluation: _room_invariant_record(base, result.report, evaluation),
    )  # fmt: skip


VAR_PAYLOAD_KEPT = ("manifest_hash", "sound_set", "world", "refit", "room_invariance", "block_ends")


def _require_policy_seeing_through_var(base: BaseModel) -> None:
    """A new image encoder reaches a policy only through its VAR view, never a policy with its own CNN."""
    from learning.rl.checkpoints import read_policy_checkpoint

    if read_policy_checkpoint(base.policy_path)["policy_config"].get("view_var") is None:
        raise ValueError(
            f"the {base.world} base's policy sees through its own CNN, not its VAR: give it one that sees "
            "through the VAR first (`varbot rl train --policy-view var`, then `varbot models "
            "replace-policy`)"
        )


def _write_with_new_view(
    base: BaseModel,
    var: Any,
    saved_with_var: dict[str, Any],
    out_root: Path,
    eval_episodes_per_intent: int | None,
    progress: bool,
    record_for: Callable[[dict], dict[str, Any]],
) -> dict[str, Any]:
    """`base` written to `out_root/<world>/` with `var` as its VAR (what the old one's file said of its
    origin kept, `saved_with_var` added) and as its policy's view, its curves copied, evaluated again in the
    rooms of its record with its seed; `record_for(evaluation)` is the new record, which is returned."""
    from learning.rl.checkpoints import policy_with_view
    from learning.var.checkpoint import read_checkpoint, save_var

    old_payload = read_checkpoint(base.var_path)
    origin = {key: old_payload[key] for key in VAR_PAYLOAD_KEPT if key in old_payload}
    with _staged(out_root / base.world) as staging:
        save_var(var, staging / "var.pt", **(origin | saved_with_var))
        policy_with_view(base.policy_path, var.image_encoder.state_dict(), staging / "policy.pt")
        for name in ("policy_curves.png", "var_curves.png"):
            if (base.folder / name).is_file():
                shutil.copy(base.folder / name, staging / name)
        recipe = base.record.get("recipe", {})
        _write_record(
            staging, record_for(evaluate_as_recorded(staging, recipe, eval_episodes_per_intent, progress))
        )
    return json.loads((out_root / base.world / RECORD).read_text())


def _room_invariant_record(base: BaseModel, report: dict[str, Any], evaluation: dict) -> dict[str, Any]:
    before = base.record
    command = _command_line("room-invariance")
    return {
        **{key: value for key, value in before.items() if key != "before_room_invariance"},
        "evaluation": evaluation,
        "room_invariance": {
            **report,
            "command": command,
            "taught_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        },
        "before_room_invariance": {"evaluation": before.get("evaluation")},
    }


def block_ends_base(
    world: str,
    out_root: Path,
    eval_episodes_per_intent: int | None = None,
    progress: bool = True,
    **settings: Any,
) -> dict[str, Any]:
    """A world's base model whose VAR was taught where its blocks end (`learning.var.block_ends`), in the
    rooms it was trained over, with its policy seeing through the new image encoder; evaluated again in the
    rooms of its record with its seed and written to `out_root/<world>/` (the evaluation before is kept under
    `before_block_ends`). `settings` are BlockEndsConfig's (views, epochs...)."""
    from learning.var.block_ends import BlockEndsConfig, check_world_has_blocks, teach_block_ends

    check_world_has_blocks(world)
    base = find_base(world)
    before = base.record
    config = BlockEndsConfig(world=world, sounds=before.get("sounds", "wordset"), **settings)
    _require_policy_seeing_through_var(base)
    rooms = world_room({"ranges": before["room_ranges"]}) if before.get("room_ranges") else None
    result = teach_block_ends(base.var_path, config, rooms, data_dir() / "block_ends" / world, progress)
    return _write_with_new_view(
        base, result.var, {"block_ends": result.report}, out_root, eval_episodes_per_intent, progress,
        lambda evaluation: _block_ends_record(base, result.report, evaluation),
    )  # fmt: skip


def _block_ends_record(base: BaseModel, report: dict[str, Any], evaluation: dict) -> dict[str, Any]:
    before = base.record
    return {
        **{key: value for key, value in before.items() if key != "before_block_ends"},
        "evaluation": evaluation,
        "block_ends": {
            **report,
            "command": _command_line("block-ends"),
            "taught_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        },
        "before_block_ends": {"evaluation": before.get("evaluation")},
    }


def _command_line(subcommand: str) -> str | None:
    """`varbot models <subcommand> …` as it was typed, for a record; None when called from Python."""
    return " ".join(["varbot", "models", subcommand, *sys.argv[3:]]) if subcommand in sys.argv else None


def _check_trained_on_base(base: BaseModel, config: dict[str, Any]) -> None:
    """A policy's reward and goals come from the VAR it trained with: it only works beside that VAR."""
    if config.get("world") != base.world:
        raise ValueError(f"the policy was trained in the {config.get('world')} world, not {base.world}")
    var_path = Path(config.get("var_path") or "")
    var_path = var_path if var_path.is_file() else REPO_ROOT / var_path  # a path relative to the repository
    if not var_path.is_file() or _digest(var_path) != _digest(base.var_path):
        raise ValueError(
            f"the policy was trained with the VAR {config.get('var_path')}, not the {base.world} base's "
            f"{base.var_path}; train it with `varbot rl train --var {base.var_path}`"
        )


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


RUN_ONLY_KEYS = ("var_path", "init_policy")  # a policy run's config: where it started, not how it trains


def _replaced_policy_record(
    base: BaseModel, run_dir: Path, config: dict[str, Any], summary: dict[str, Any], evaluation: dict
) -> dict[str, Any]:
    before = base.record
    policy_keys = ("policy_config", "policy_env_steps", "policy_recent_success_in_training", "evaluation")
    command = _command_line("replace-policy")
    room = world_room(config["room"])  # a run names its room only: its ranges are those of the code it ran
    return {
        **{key: value for key, value in before.items() if key != "before_policy_replaced"},
        "policy_config": {key: value for key, value in config.items() if key not in RUN_ONLY_KEYS},
        "policy_env_steps": summary["env_steps"],
        "policy_recent_success_in_training": summary["recent_success"],
        "evaluation": evaluation,
        "policy_replaced": {
            "run_dir": str(run_dir),
            "trained_with": {key: config.get(key) for key in RUN_ONLY_KEYS},
            "policy_room_ranges": asdict(room) if isinstance(room, RoomRanges) else None,
            "run_time_s": summary.get("time_s"),
            "command": command,
            "replaced_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        },
        "before_policy_replaced": {key: before.get(key) for key in policy_keys},
    }


def evaluate_in_rooms(
    var_path: Path,
    policy_path: Path,
    rooms: Sequence[str],
    splits: Sequence[str] | None = None,
    episodes_per_intent: int = 50,
    seed: int = 12345,
    progress: bool = False,
    on_cell: Callable[[str, str, dict[str, Any]], None] | None = None,
    goal_clips: Callable[[str, str, str], "ClipBank"] | None = None,
) -> dict[str, dict[str, dict[str, Any]]]:
    """Zero-shot success of a VAR + policy in each room on each unheard tier (default: all of the corpus's),
    with the RL evaluation protocol: {room: {tier: cell}}. `on_cell(room, tier, cell)` hears of each cell.
    `goal_clips(sounds, tier, front end)` picks a tier's goal clips (default: all of them)."""
    import torch

    from learning.rl.evaluate import evaluate
    from learning.rl.ppo import PPOConfig, load_policy
    from learning.rl.rewards import corpus_bank
    from learning.sounds import load_corpus
    from learning.var.checkpoint import load_var

    var = load_var(var_path)
    policy, payload = load_policy(policy_path)
    config = PPOConfig.from_dict(payload["config"])
    torch.set_num_threads(1)  # the env workers come from a fork server, which torch's threads never reach
    splits = splits or [s for s in load_corpus(config.sounds).splits if s != "train"]
    evaluations: dict[str, dict[str, dict[str, Any]]] = {}
    for split in splits:
        if goal_clips is None:
            goals = corpus_bank(config.sounds, split, front_end=var.front_end)
        else:
            goals = goal_clips(config.sounds, split, var.front_end)
        goals.embed(var)
        for room in rooms:
            tick = time.perf_counter()
            result = evaluate(
                policy, var, goals, config.world, config.image_size, split=split,
                episodes_per_intent=episodes_per_intent, seed=seed, success_rule=config.success_rule,
                max_steps=config.max_episode_steps, domain=world_room(room), progress=progress,
                world_options=config.world_options,
            )  # fmt: skip
            cell = {
                "success_rate": result.success_rate,
                "success_by_intent": result.success_by_intent,
                "episodes": len(result.episodes),
                # [intent][intent whose object the robot ended at, or the last column: none]
                "final_view_by_intent": result.final_view_by_intent,
                "wall_s": round(time.perf_counter() - tick, 1),
            }
            evaluations.setdefault(room, {})[split] = cell
            if on_cell is not None:
                on_cell(room, split, cell)
    return evaluations


class StageClock:
    """Wall time per stage, summed over every run of a recipe (kept in a file, so resumes add to it)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def totals(self) -> dict[str, float]:
        return json.loads(self.path.read_text()) if self.path.is_file() else {}

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        tick = time.perf_counter()
        try:
            yield
        finally:
            totals = self.totals()
            totals[stage] = round(totals.get(stage, 0.0) + time.perf_counter() - tick, 1)
            totals["total_s"] = round(sum(v for k, v in totals.items() if k != "total_s"), 1)
            self.path.write_text(json.dumps(totals, indent=2) + "\n")
