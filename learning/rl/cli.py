"""`varbot rl train | improve | eval | plot`. Heavy imports (torch, pybullet) happen inside the commands."""

import json
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
    from learning.rl.stopping import StopRequest

app = typer.Typer(help="Policy learning with the VAR's intrinsic reward (PPO), evaluation and baselines.",
                  no_args_is_help=True)  # fmt: skip


def _fail(message: str) -> None:
    typer.secho(message, fg=typer.colors.RED, err=True)
    raise typer.Exit(1)


def _exit_if_stopped(stop: "StopRequest", summary: dict[str, Any], run_dir: Path) -> None:
    if stop.signal is not None:
        typer.secho(stop.explain(summary, run_dir), fg=typer.colors.YELLOW, err=True)
        raise typer.Exit(stop.exit_code)


@app.command()
def train(
    world: Annotated[str, typer.Option(help="kuka, kinova or turtlebot")] = "kuka",
    sounds: Annotated[
        str, typer.Option(help="Sound corpus the goal clips come from (its train split).")
    ] = "wordset",
    var: Annotated[
        Path | None, typer.Option(help="Frozen VAR checkpoint (needed by the var methods).")
    ] = None,
    method: Annotated[
        str, typer.Option(help="var, var-current-sound, sparse (NoAux+SparseR) or rsi")
    ] = "var",
    current_sound: Annotated[bool, typer.Option("--current-sound", help="Add f_S(S_t)·f_S(S_goal).")] = False,
    steps: Annotated[int, typer.Option(help="Environment steps in all.")] = 1_000_000,
    run_dir: Annotated[
        Path | None, typer.Option(help="Default: <data dir>/rl/runs/<world>-<sounds>-<method>.")
    ] = None,
    image_size: Annotated[int | None, typer.Option(help="Rendered image size (default: the VAR's).")] = None,
    policy_image_size: Annotated[int, typer.Option(help="Image size the policy CNN sees.")] = 32,
    lr: Annotated[float, typer.Option(help="Adam learning rate (annealed to 0).")] = 3e-4,
    envs: Annotated[int, typer.Option(help="Parallel environments (processes).")] = 8,
    seed: int = 1,
    init_encoders: Annotated[
        Path | None,
        typer.Option(help="Baselines: start from one-hot pre-trained encoders (`varbot rl pretrain`)."),
    ] = None,
    hard_target_share: Annotated[
        float,
        typer.Option(
            help="Curriculum: share of episodes whose target favours low recent return (0: uniform)."
        ),
    ] = 0.5,
    hard_start_share: Annotated[
        float,
        typer.Option(
            help="Block worlds: share of episodes whose gripper starts in the strips of the table where "
            "recent episodes earned least (0: anywhere, uniformly)."
        ),
    ] = 0.0,
    room: Annotated[
        str, typer.Option(help="training, or randomised: a room per episode from core.rooms.RoomRanges")
    ] = "training",
    init_policy: Annotated[
        Path | None,
        typer.Option(
            help="Start from this policy's weights (a checkpoint of the same network, e.g. a base model's "
            "policy.pt); the optimiser starts afresh."
        ),
    ] = None,
    goal_match: Annotated[
        bool,
        typer.Option(
            "--goal-match",
            help="The policy also sees f_I(I_t)·f_S(S_goal), the reward it earns now (experimental).",
        ),
    ] = False,
    reward_temperature: Annotated[
        float | None,
        typer.Option(
            help="Pay exp((match − 1)/T) instead of the VAR match, so a block near the goal's pays about "
            "nothing (experimental; Table I's sharpened recipe uses 0.25)."
        ),
    ] = None,
    contact: Annotated[
        str | None,
        typer.Option(
            help="TurtleBot: a blocked robot stands still (stop, the world's own) or glides along what it "
            "meets (slide); sim.turtlebot_arena."
        ),
    ] = None,
    policy_colour_jitter: Annotated[
        float,
        typer.Option(
            help="Each episode the policy sees its view with the RGB channels shuffled and scaled by gains "
            "within 1 ± this (0: off; the VAR always sees the real view; experimental, learning.rl.colours)."
        ),
    ] = 0.0,
    policy_hue_turn: Annotated[
        float,
        typer.Option(
            help="Each episode also turns the hues of the policy's view about the grey axis by an angle "
            "within ± this many degrees (0: off; experimental, learning.rl.colours)."
        ),
    ] = 0.0,
    policy_view_shift: Annotated[
        int,
        typer.Option(
            help="Each episode also shifts the policy's view by up to ± this many pixels of its "
            "--policy-image-size view, as a camera moved sideways would (0: off; experimental, "
            "learning.rl.view_changes)."
        ),
    ] = 0,
    policy_view: Annotated[
        str,
        typer.Option(
            help="pixels: the policy's own CNN sees a --policy-image-size copy of the view; var: it sees "
            "through a frozen copy of the VAR's image encoder, up to its hidden layer (experimental)."
        ),
    ] = "pixels",
    resume: Annotated[bool, typer.Option("--resume", help="Continue the run in --run-dir.")] = False,
) -> None:
    """Train a policy with PPO (8 worker processes); checkpoints, metrics and curves go to the run dir."""
    from core.paths import data_dir
    from learning.rl.baselines import METHODS, method_config, needs_var
    from learning.rl.frozen_var import load_frozen_var
    from learning.rl.run import train_run
    from learning.rl.stopping import StopRequest

    if method not in METHODS:
        _fail(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if current_sound:
        method = "var-current-sound" if method == "var" else method
    if needs_var(method) and var is None:
        _fail(f"method {method} needs a VAR checkpoint: pass --var PATH (train one with `varbot var train`)")
    try:
        frozen = load_frozen_var(var)  # read once: its image size here, the model and its labels for the run
    except (ValueError, FileNotFoundError) as error:
        _fail(str(error))
    if image_size is None:
        image_size = frozen.image_size if frozen is not None else 96
    config = method_config(
        method,
        world=world,
        sounds=sounds,
        total_steps=steps,
        image_size=image_size,
        policy_image_size=policy_image_size,
        learning_rate=lr,
        num_envs=envs,
        num_minibatches=2 if envs % 2 == 0 else 1,
        seed=seed,
        hard_target_share=hard_target_share,
        hard_start_share=hard_start_share,
        room=room,
        goal_match=goal_match,
        reward_temperature=reward_temperature,
        contact=contact,
        policy_colour_jitter=policy_colour_jitter,
        policy_hue_turn=policy_hue_turn,
        policy_view_shift=policy_view_shift,
        policy_view=policy_view,
    )
    run_dir = run_dir or data_dir() / "rl" / "runs" / f"{world}-{sounds}-{method}"
    try:
        if init_encoders is not None:
            config = replace(config, init_encoders=str(init_encoders))
        config.validate()
        with StopRequest() as stop:
            summary = train_run(
                config,
                run_dir,
                frozen if needs_var(method) else None,
                init_policy=init_policy,
                resume=resume,
                on_update=stop,
            )
    except (ValueError, FileNotFoundError, FileExistsError) as error:
        _fail(str(error))
    _exit_if_stopped(stop, summary, run_dir)
    typer.echo(json.dumps(summary, indent=2))
    typer.echo(f"run directory: {run_dir}")


@app.command()
def pretrain(
    dataset: Annotated[str, typer.Argument(help="A collected triplet dataset (`varbot var collect`).")],
    out: Annotated[Path, typer.Option(help="Where to write the encoders (.pt).")],
    sounds: Annotated[
        str, typer.Option(help="Corpus whose training split teaches the goal encoder.")
    ] = "wordset",
    policy_image_size: Annotated[int, typer.Option(help="Image size the policy CNN sees.")] = 32,
    steps: Annotated[int, typer.Option(help="Optimiser steps per encoder.")] = 2000,
    seed: int = 0,
) -> None:
    """One-hot pre-training of the baselines' image and goal encoders (the paper's NoAux+SparseR)."""
    from learning.rl.pretrain import PretrainConfig, pretrain_encoders
    from learning.var.dataset import DatasetError

    config = PretrainConfig(dataset, sounds, policy_image_size=policy_image_size, steps=steps, seed=seed)
    try:
        result = pretrain_encoders(config, out)
    except (DatasetError, FileNotFoundError, ValueError) as error:
        _fail(str(error))
    typer.echo(json.dumps(result, indent=2))
    typer.echo(
        f"encoders written to {out}; train with `varbot rl train --method sparse --init-encoders {out}`"
    )


@app.command()
def improve(
    policy: Annotated[Path, typer.Option(help="Policy checkpoint to start from.")],
    var: Annotated[Path, typer.Option(help="The (fine-tuned) VAR checkpoint.")],
    goal: Annotated[list[str], typer.Option(help="Goal clip [INTENT:]PATH (WAV or .npy MFCC); repeat.")],
    steps: Annotated[int, typer.Option(help="Step budget.")] = 10_000,
    run_dir: Annotated[
        Path | None, typer.Option(help="Default: <data dir>/rl/improve/<policy run name>.")
    ] = None,
    lr: Annotated[float | None, typer.Option(help="Default: a third of the original learning rate.")] = None,
    resume: Annotated[bool, typer.Option("--resume")] = False,
) -> None:
    """Self-improvement: continue PPO with a fine-tuned VAR and the household's own clips as goals."""
    from core.paths import data_dir
    from learning.rl.improve import improve as run_improve
    from learning.rl.stopping import StopRequest

    run_dir = run_dir or data_dir() / "rl" / "improve" / policy.parent.name
    try:
        with StopRequest() as stop:
            summary = run_improve(
                policy, var, goal, steps, run_dir, learning_rate=lr, resume=resume, on_update=stop
            )
    except (ValueError, FileNotFoundError, FileExistsError) as error:
        _fail(str(error))
    _exit_if_stopped(stop, summary, run_dir)
    typer.echo(json.dumps(summary, indent=2))


@app.command("eval")
def evaluate_command(
    policy: Annotated[Path, typer.Option(help="Policy checkpoint (a run's checkpoint.pt).")],
    var: Annotated[
        Path | None, typer.Option(help="VAR checkpoint (default: the one the policy trained with).")
    ] = None,
    split: Annotated[
        str | None, typer.Option(help="Unheard tier for the goal clips (default: the first).")
    ] = None,
    sounds: Annotated[
        str | None, typer.Option(help="Corpus (default: the one the policy trained with).")
    ] = None,
    episodes_per_intent: int = 50,
    seed: int = 12345,
    room: Annotated[
        str, typer.Option(help="training, unseen_room or lamplit_room (core.rooms), or randomised")
    ] = "training",
    gif: Annotated[Path | None, typer.Option(help="Write a GIF of the first episodes here.")] = None,
    out: Annotated[
        Path | None, typer.Option(help="JSON result (default: <run dir>/eval-<split>.json).")
    ] = None,
) -> None:
    """The evaluation protocol: 50 episodes per intent, deterministic policy, unheard goal clips."""
    from rich.console import Console
    from rich.table import Table

    from core.rooms import world_room
    from learning.rl.evaluate import evaluate, save_eval
    from learning.rl.frozen_var import load_frozen_var
    from learning.rl.ppo import PPOConfig, load_policy
    from learning.rl.rewards import corpus_bank

    try:
        model, payload = load_policy(policy)
        config = PPOConfig.from_dict(payload["config"])
        sounds = sounds or config.sounds
        split = split or _first_unheard_split(sounds)
        var_path = var or (payload.get("var_path") if model.config.goal_encoder == "var" else None)
        loaded = load_frozen_var(var_path)
        frozen = loaded.model if loaded is not None else None
        goals = corpus_bank(sounds, split, front_end=frozen.front_end if frozen is not None else "mfcc")
        if frozen is not None:
            goals.embed(frozen)
        result = evaluate(
            model, frozen, goals, config.world, config.image_size, split=split,
            episodes_per_intent=episodes_per_intent, seed=seed, success_rule=config.success_rule,
            max_steps=config.max_episode_steps, domain=world_room(room), gif_path=gif,
            world_options=config.world_options,
        )  # fmt: skip
    except (ValueError, FileNotFoundError) as error:
        _fail(str(error))
    out = out or policy.parent / (f"eval-{split}.json" if room == "training" else f"eval-{split}-{room}.json")
    save_eval(result, out)
    table = Table(title=f"{config.world} / {sounds} / {split} / {room}: {result.success_rate:.1%} success")
    table.add_column("intent")
    table.add_column("episodes", justify="right")
    table.add_column("success", justify="right")
    for name in [*result.intent_names, "none"]:
        table.add_column(f"ended at {name}", justify="right")
    rows = zip(
        result.intent_names, result.episodes_by_intent, result.success_by_intent,
        result.final_view_by_intent, strict=True,
    )  # fmt: skip
    for name, count, rate, ended in rows:
        table.add_row(name, str(count), f"{rate:.1%}", *map(str, ended))
    table.add_row("mean", str(sum(result.episodes_by_intent)), f"{result.success_rate:.1%}")
    Console().print(table)
    typer.echo(f"mean episode length {result.mean_episode_length:.1f}; result: {out}")


@app.command()
def plot(
    run_dirs: Annotated[list[Path], typer.Argument(help="One or more run directories.")],
    out: Annotated[Path | None, typer.Option(help="Comparison PNG (several runs).")] = None,
) -> None:
    """Curves of a run (curves.png in its directory); with several runs also success-vs-steps on one axis."""
    from learning.rl.plots import plot_run, plot_success_curves, success_curve

    for run_dir in run_dirs:
        try:
            typer.echo(f"wrote {plot_run(run_dir)}")
        except FileNotFoundError as error:
            _fail(str(error))
    if len(run_dirs) > 1 or out is not None:
        target = out or Path("success_vs_steps.png")
        typer.echo(f"wrote {plot_success_curves({d.name: success_curve(d) for d in run_dirs}, target)}")


def _first_unheard_split(sounds: str) -> str:
    from learning.sounds import load_corpus

    unheard = [s for s in load_corpus(sounds).splits if s != "train"]
    if not unheard:
        raise ValueError(f"the corpus {sounds} has no unheard split")
    return unheard[0]
