"""`varbot worker --queue training|robot` and `varbot models …` (build-base, adopt, refit-front-end,
replace-policy, room-invariance, block-ends, show).

Heavy imports happen inside the commands."""

import os
from collections.abc import Callable
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import typer

models_app = typer.Typer(help="Base models for the simulated robots.", no_args_is_help=True)
# options the commands that write a base model share
BaseModelsOut = Annotated[Path | None, typer.Option(help="default: <data dir>/base_models")]
RecordedEvalEpisodes = Annotated[
    int | None, typer.Option(min=1, help="default: the base model's own recipe's")
]


class Queue(StrEnum):
    TRAINING = "training"
    ROBOT = "robot"


def register_worker_commands(app: typer.Typer) -> None:
    app.command(name="worker")(worker)
    app.add_typer(models_app, name="models")


def celery_worker_argv(queue: Queue, concurrency: int, loglevel: str) -> list[str]:
    """The Celery worker command line for one queue (training: one task per fresh child process)."""
    argv = [
        "worker",
        "--queues", queue.value,
        "--hostname", f"{queue.value}-{os.getpid()}@%h",
        "--concurrency", str(concurrency),
        "--prefetch-multiplier", "1",
        "--loglevel", loglevel,
        "--without-gossip", "--without-mingle",
    ]  # fmt: skip
    if queue == Queue.TRAINING:
        argv += ["--max-tasks-per-child", "1"]
    return argv


def worker(
    queue: Annotated[Queue, typer.Option(help="which queue this worker consumes")] = Queue.TRAINING,
    concurrency: Annotated[int, typer.Option(min=1, help="tasks at once (training: keep 1 per machine)")] = 1,
    loglevel: Annotated[str, typer.Option(help="Celery log level")] = "info",
) -> None:
    """Run a Celery worker: `training` (fine-tuning runs, one at a time) or `robot` (snapshot capture)."""
    import logging

    logging.basicConfig(level=loglevel.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from worker.celery_app import app

    app.worker_main(celery_worker_argv(queue, concurrency, loglevel))


@models_app.command("build-base")
def build_base(
    world: Annotated[str, typer.Option(help="kuka, kinova or turtlebot")] = "kuka",
    sounds: Annotated[str, typer.Option(help="sound corpus (built with `varbot sounds build`)")] = "wordset",
    front_end: Annotated[
        str, typer.Option(help="the VAR's sound front end: mfcc, speech-embedding or speech-embedding-fast")
    ] = "mfcc",
    room: Annotated[
        str, typer.Option(help="randomised (a room per episode from core.rooms.RoomRanges) or training")
    ] = "randomised",
    views: Annotated[int, typer.Option(min=100, help="random views collected for VAR triplets")] = 20_000,
    image_size: Annotated[int, typer.Option(help="camera image size (pixels)")] = 96,
    var_epochs: Annotated[int, typer.Option(min=1)] = 12,
    var_max_steps: Annotated[int | None, typer.Option(min=1, help="overrides --var-epochs")] = None,
    policy_steps: Annotated[int, typer.Option(min=800, help="PPO environment steps")] = 300_000,
    eval_episodes_per_intent: Annotated[int, typer.Option(min=1)] = 25,
    out: BaseModelsOut = None,
    seed: Annotated[int, typer.Option()] = 0,
    device: Annotated[
        str | None, typer.Option(help="where PPO runs: auto, cpu or cuda (default: VARBOT_DEVICE, else auto)")
    ] = None,
    ppo: Annotated[
        list[str] | None,
        typer.Option(
            help="a PPO setting other than its default, as NAME=VALUE (repeat; e.g. policy_view=var, "
            "goal_match=true, reward_temperature=0.25; learning.rl.ppo.PPOConfig's fields)"
        ),
    ] = None,
) -> None:
    """Train the base VAR + policy for one simulated world with the project's own trainers and record how.

    Rerunning the same command resumes it (views, VAR and policy each continue from their checkpoints)."""
    import json
    import signal

    from backend.settings import get_settings
    from core.paths import data_dir
    from learning.device import DeviceUnavailable, resolve_device
    from worker.base_models import BaseRecipe
    from worker.base_models import build_base as build

    try:  # before anything starts: a missing GPU says so
        on = resolve_device(device or get_settings().device)
    except (DeviceUnavailable, ValueError) as refused:
        raise typer.BadParameter(str(refused), param_hint="--device") from None

    recipe = BaseRecipe(
        world=world, sounds=sounds, front_end=front_end, room=room, views=views, image_size=image_size,
        var_epochs=var_epochs, var_max_steps=var_max_steps, policy_steps=policy_steps,
        eval_episodes_per_intent=eval_episodes_per_intent, seed=seed, ppo_settings=ppo_settings(ppo or []),
    )  # fmt: skip
    signal.signal(signal.SIGTERM, _exit_when_terminated)  # a stopped build still adds up its stage times
    record = build(recipe, out or data_dir() / "base_models", device=on)
    typer.echo(json.dumps(record, indent=2))


def ppo_settings(pairs: list[str]) -> dict[str, object]:
    """NAME=VALUE pairs as PPO settings (`core.plain.name_value`), checked as PPO checks its settings."""
    from dataclasses import fields

    from core.plain import name_value
    from learning.rl.ppo import PPOConfig

    known = {field.name for field in fields(PPOConfig)}
    settings: dict[str, object] = {}
    for pair in pairs:
        try:
            name, value = name_value(pair)
        except ValueError:
            name, value = "", None
        if name not in known:
            raise typer.BadParameter(
                f"{pair!r} is not NAME=VALUE with NAME a PPO setting; they are: {', '.join(sorted(known))}",
                param_hint="--ppo",
            )
        settings[name] = value
    try:
        PPOConfig(**settings).validate()
    except (ValueError, TypeError) as refused:
        raise typer.BadParameter(str(refused), param_hint="--ppo") from None
    return settings


def _exit_when_terminated(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)


@models_app.command("adopt")
def adopt(
    world: Annotated[str, typer.Option(help="kuka, kinova or turtlebot")],
    var: Annotated[
        Path, typer.Option(exists=True, dir_okay=False, help="a VAR checkpoint (varbot var train)")
    ],
    policy: Annotated[
        Path, typer.Option(exists=True, dir_okay=False, help="a policy checkpoint (varbot rl train)")
    ],
    record: Annotated[
        Path, typer.Option(exists=True, dir_okay=False, help="JSON: how they were made and what they scored")
    ],
    out: BaseModelsOut = None,
) -> None:
    """Make checkpoints trained elsewhere (e.g. by the benchmarks) a world's base model, with their record."""
    import json

    from core.paths import data_dir
    from learning.rl.ppo import read_policy_checkpoint
    from learning.var.checkpoint import read_checkpoint
    from worker.base_models import write_base

    var_config = read_checkpoint(var)["config"]
    policy_config = read_policy_checkpoint(policy)["config"]
    if policy_config.get("world") != world:
        raise typer.BadParameter(
            f"the policy was trained in the {policy_config.get('world')} world, not {world}"
        )
    if policy_config.get("image_size") != var_config["image_size"]:
        sizes = f"{policy_config.get('image_size')} px against the VAR's {var_config['image_size']} px"
        raise typer.BadParameter(f"the policy was trained on images of {sizes}")
    facts = json.loads(record.read_text())
    facts.update(
        world=world,
        image_size=var_config["image_size"],
        adopted_from={"var": str(var), "policy": str(policy)},
    )
    folder = write_base(world, var, policy, out or data_dir() / "base_models", facts)
    typer.echo(f"{world}: base model written to {folder}")


@models_app.command("refit-front-end")
def refit_front_end(
    world: Annotated[str, typer.Option(help="kuka, kinova or turtlebot")],
    front_end: Annotated[str, typer.Option(help="the new sound front end, e.g. speech-embedding-fast")],
    extra_sounds: Annotated[
        str, typer.Option(help="comma-separated corpora whose training clips teach f_S too (no labels used)")
    ] = "",
    eval_episodes_per_intent: RecordedEvalEpisodes = None,
    steps: Annotated[int, typer.Option(min=1, help="optimiser steps teaching the new sound encoder")] = 3000,
    room_copies: Annotated[
        int, typer.Option(min=0, help="recordings of every teaching clip in simulated rooms")
    ] = 2,
    out: BaseModelsOut = None,
) -> None:
    """Move a world's base model to another sound front end: the same policy and image encoder, the sound
    encoder taught to agree with the old one; evaluated again in every room of its record."""
    import json

    from core.paths import data_dir
    from learning.front_ends import check_front_end
    from worker.base_models import BaseModelMissing, refit_base

    try:
        check_front_end(front_end)
        record = refit_base(
            world, front_end, out or data_dir() / "base_models",
            [name for name in extra_sounds.split(",") if name], eval_episodes_per_intent,
            steps=steps, room_copies=room_copies,
        )  # fmt: skip
    except (ValueError, BaseModelMissing) as refused:
        raise typer.BadParameter(str(refused)) from None
    typer.echo(
        json.dumps({"refit": record["refit"]["agreement"], "evaluation": record["evaluation"]}, indent=2)
    )


@models_app.command("replace-policy")
def replace_policy(
    world: Annotated[str, typer.Option(help="kuka, kinova or turtlebot")],
    run_dir: Annotated[
        Path,
        typer.Option(exists=True, file_okay=False, help="a finished `varbot rl train --var BASE/var.pt`"),
    ],
    eval_episodes_per_intent: RecordedEvalEpisodes = None,
    out: BaseModelsOut = None,
) -> None:
    """Give a world's base model another policy trained on its VAR: the same VAR, the run's policy and
    curves, evaluated again in every room of its record (the old policy's figures are kept in the record)."""
    import json

    from core.paths import data_dir
    from worker.base_models import BaseModelMissing
    from worker.base_models import replace_policy as replace

    try:
        record = replace(world, run_dir, out or data_dir() / "base_models", eval_episodes_per_intent)
    except (ValueError, FileNotFoundError, BaseModelMissing) as refused:
        raise typer.BadParameter(str(refused)) from None
    typer.echo(json.dumps({"evaluation": record["evaluation"]}, indent=2))


@models_app.command("room-invariance")
def room_invariance(
    world: Annotated[
        str, typer.Option(help="kuka or kinova (worlds that can render a scene in another room)")
    ],
    views: Annotated[
        int, typer.Option(min=20, help="scenes rendered in a drawn room and in the own look")
    ] = 20_000,
    steps: Annotated[int, typer.Option(min=1, help="optimiser steps teaching the image encoder")] = 3000,
    desaturate_share: Annotated[
        float,
        typer.Option(min=0.0, max=1.0, help="share of views moved part of the way to grey while taught"),
    ] = 0.0,
    seed: Annotated[int, typer.Option()] = 0,
    eval_episodes_per_intent: RecordedEvalEpisodes = None,
    out: BaseModelsOut = None,
) -> None:
    """Teach a world's base model to see every room of its training ranges as its own training room: the image
    encoder of its VAR and of its policy's view learn, on pairs of renders of one scene, to give for any room
    what they gave for the world's own look; evaluated again in every room of its record."""
    import json

    from worker.base_models import room_invariant_base

    record = _teach_base(
        room_invariant_base, world, out, eval_episodes_per_intent,
        views=views, steps=steps, seed=seed, desaturate_share=desaturate_share,
    )  # fmt: skip
    agreement = {key: record["room_invariance"][key] for key in ("agreement_before", "agreement_after")}
    typer.echo(json.dumps({**agreement, "evaluation": record["evaluation"]}, indent=2))


@models_app.command("block-ends")
def block_ends(
    world: Annotated[str, typer.Option(help="kuka or kinova (the worlds with blocks)")],
    views: Annotated[int, typer.Option(min=1, help="views rendered around the blocks' ends")] = 12_000,
    replay_views: Annotated[
        int, typer.Option(min=1, help="random exploration views of the same rooms, replayed beside them")
    ] = 12_000,
    epochs: Annotated[int, typer.Option(min=1, help="the VAR fine-tune's epochs at most")] = 8,
    seed: Annotated[int, typer.Option()] = 0,
    eval_episodes_per_intent: RecordedEvalEpisodes = None,
    out: BaseModelsOut = None,
) -> None:
    """Teach a world's base model where its blocks end: its VAR is fine-tuned on views with the gripper placed
    around the blocks' ends in the rooms it was trained over, labelled by the simulator's ray, and its policy
    sees through the new image encoder; evaluated again in every room of its record."""
    import json

    from worker.base_models import block_ends_base

    record = _teach_base(
        block_ends_base, world, out, eval_episodes_per_intent,
        views=views, replay_views=replay_views, epochs=epochs, seed=seed,
    )  # fmt: skip
    taught = {key: record["block_ends"][key] for key in ("best_held_out_accuracy", "epochs", "seconds")}
    typer.echo(json.dumps({**taught, "evaluation": record["evaluation"]}, indent=2))


def _teach_base(
    teach: Callable[..., dict[str, Any]],
    world: str,
    out: Path | None,
    eval_episodes_per_intent: int | None,
    **settings: Any,
) -> dict[str, Any]:
    """Runs one of `worker.base_models`' steps that rewrite a base model (default folder: the data
    directory's `base_models`); a refusal is a usage error with its reason."""
    from core.paths import data_dir
    from worker.base_models import BaseModelMissing

    try:
        return teach(world, out or data_dir() / "base_models", eval_episodes_per_intent, **settings)
    except (ValueError, FileNotFoundError, BaseModelMissing) as refused:
        raise typer.BadParameter(str(refused)) from None


@models_app.command("show")
def show() -> None:
    """Which base model each simulated world would start from."""
    from worker.base_models import BaseModelMissing, find_base

    for world in ("kuka", "kinova", "turtlebot"):
        try:
            base = find_base(world)
            record = base.record
            made = record.get("built_at") or ("adopted" if "adopted_from" in record else "no record")
            rooms = record.get("recipe", {}).get("room", "training")
            front_end = record.get("front_end", "mfcc")
            if "refit" in record:
                refitted = record["refit"].get("refitted_at", "")
                front_end += f", refitted {refitted} from {record['before_refit']['front_end']}"
            if "policy_replaced" in record:
                front_end += f"; policy replaced {record['policy_replaced']['replaced_at']}"
            if "room_invariance" in record:
                front_end += f"; taught room invariance {record['room_invariance']['taught_at']}"
            if "block_ends" in record:
                front_end += f"; taught block ends {record['block_ends']['taught_at']}"
            typer.echo(f"{world}: {base.folder} ({made}; trained in rooms: {rooms}; front end: {front_end})")
        except BaseModelMissing as missing:
            typer.echo(f"{world}: {missing}")
