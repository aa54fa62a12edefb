"""`varbot var collect|train|finetune|eval|plot`: the VAR from the command line; heavy imports inside."""

import json
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(
    help="The visual-audio representation: collect triplets, train, fine-tune, evaluate, plot.",
    no_args_is_help=True,
)

DOMAINS = ("none", "unseen-room", "randomised")


def _domain(name: str):
    """The room views are collected in: the training room, the shifted one, or a room per episode drawn from
    the training ranges (core.rooms.RoomRanges, how base models are trained)."""
    from core.rooms import world_room

    if name not in DOMAINS:
        raise typer.BadParameter(f"--domain must be one of {', '.join(DOMAINS)}, got {name!r}.")
    return world_room({"none": "training", "unseen-room": "unseen_room"}.get(name, name))


def _default_run_dir(dataset: str, sounds: str, kind: str) -> str:
    from core.paths import data_subdir

    return str(data_subdir("var", "runs", f"{Path(dataset).name}-{sounds}-{kind}"))


def _corpus(name: str, front_end: str = "mfcc"):
    from learning.sounds import load_corpus

    return load_corpus(name, front_end=front_end)


def _sounds_for(dataset: str, sounds: str | None) -> str:
    if sounds:
        return sounds
    from learning.var.dataset import open_dataset

    recorded = open_dataset(dataset).meta.get("sounds")
    if not recorded:
        raise typer.BadParameter("Say which sound corpus to use with --sounds (e.g. wordset).")
    return recorded


def _fail(error: Exception) -> None:
    typer.secho(f"error: {error}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


@app.command()
def collect(
    world: Annotated[str, typer.Argument(help="kuka, kinova or turtlebot")],
    triplets: Annotated[int, typer.Option(help="How many views (one triplet each per epoch).")] = 50_000,
    sounds: Annotated[
        str, typer.Option(help="The sound corpus these views will be paired with.")
    ] = "wordset",
    name: Annotated[str | None, typer.Option(help="Dataset name (default WORLD-N-seedS).")] = None,
    seed: int = 0,
    image_size: int = 96,
    domain: Annotated[
        str,
        typer.Option(
            help="none, unseen-room (a shifted room, for fine-tuning) or randomised (a room per episode)."
        ),
    ] = "none",
    workers: Annotated[int, typer.Option(help="Parallel worker processes.")] = 2,
    heard_reach: Annotated[
        float | None,
        typer.Option(
            help="TurtleBot only: name a view after an object only within this many metres of the bumper "
            "(default 0.6; 0.35 is the success distance)."
        ),
    ] = None,
    overwrite: bool = False,
) -> None:
    """Move the robot at random and store each view with the intent a person would name (-1: none)."""
    from learning.var.dataset import DatasetError, collect_dataset

    if heard_reach is not None and world != "turtlebot":
        raise typer.BadParameter(
            f"--heard-reach applies to the turtlebot world only; the {world} world names a view by what the "
            "gripper is at. Leave it out."
        )
    try:
        _corpus(sounds)  # fail now, not after an hour of collection, if the corpus is missing
        dataset = collect_dataset(
            world,
            triplets,
            name or f"{world}-{triplets}-seed{seed}",
            seed=seed,
            image_size=image_size,
            domain=_domain(domain),
            workers=workers,
            overwrite=overwrite,
            world_options={"heard_reach_m": heard_reach} if heard_reach is not None else None,
        )
    except (DatasetError, FileNotFoundError, ValueError) as error:
        _fail(error)
    meta = dataset.meta
    meta["sounds"] = sounds
    (dataset.path / "meta.json").write_text(json.dumps(meta, indent=2))
    typer.echo(
        f"{dataset.path}: {meta['count']} views in {meta['collection_seconds']} s "
        f"({meta['views_per_second']} views/s); heard: {meta['heard_counts']}"
    )


@app.command()
def train(
    dataset: Annotated[str, typer.Argument(help="Dataset name or path (from `varbot var collect`).")],
    sounds: Annotated[
        str | None, typer.Option(help="Sound corpus (default: the one named at collection).")
    ] = None,
    run_dir: Annotated[str | None, typer.Option(help="Where checkpoints and metrics go.")] = None,
    epochs: int = 12,
    max_steps: Annotated[
        int | None, typer.Option(help="Schedule length in steps (overrides --epochs).")
    ] = None,
    batch_size: int = 128,
    lr: float = 2e-3,
    margin: float = 1.0,
    embedding_dim: int = 3,
    sound_hidden: Annotated[
        int | None, typer.Option(help="Width of f_S's layers (default: the same as f_I's head, 128).")
    ] = None,
    front_end: Annotated[
        str,
        typer.Option(
            help="Sound front end of f_S: mfcc (the paper's), speech-embedding or speech-embedding-fast."
        ),
    ] = "mfcc",
    augment: bool = True,
    speed_copies: Annotated[
        int, typer.Option(help="Add this many faster/slower renderings of every training clip.")
    ] = 0,
    speed_range: Annotated[
        str, typer.Option(help="Playback-rate range of those copies, MIN,MAX.")
    ] = "0.85,1.15",
    room_copies: Annotated[
        int,
        typer.Option(
            help="Add this many recordings of every training clip in simulated rooms (reverberation, "
            "background noise, a cheap microphone)."
        ),
    ] = 0,
    voice_copies: Annotated[
        int,
        typer.Option(
            help="Add this many renderings of every training clip with its formants moved (another vocal "
            "tract at the same pitch and tempo)."
        ),
    ] = 0,
    voice_range: Annotated[
        str, typer.Option(help="Formant warp range of those copies, MIN,MAX.")
    ] = "0.85,1.15",
    speakers: Annotated[
        str | None, typer.Option(help="Comma-separated speakers to train on (default: all of the split).")
    ] = None,
    seed: int = 0,
    threads: int = 2,
    resume: Annotated[bool, typer.Option(help="Continue from RUN_DIR/last.pt when it exists.")] = True,
) -> None:
    """Pre-train a VAR on a triplet dataset (resumes an interrupted run in the same --run-dir)."""
    from learning.var.model import VARConfig
    from learning.var.train import TrainConfig
    from learning.var.train import train as run_training

    try:
        sounds = _sounds_for(dataset, sounds)
        config = TrainConfig(
            dataset=dataset,
            sounds=sounds,
            run_dir=run_dir or _default_run_dir(dataset, sounds, "var"),
            epochs=epochs,
            max_steps=max_steps,
            batch_size=batch_size,
            lr=lr,
            margin=margin,
            model=VARConfig(embedding_dim=embedding_dim, front_end=front_end, sound_hidden=sound_hidden),
            augment=augment,
            sound_speakers=tuple(speakers.split(",")) if speakers else None,
            sound_speed_copies=speed_copies,
            sound_speed_range=_factor_range(speed_range, "--speed-range"),
            sound_room_copies=room_copies,
            sound_voice_copies=voice_copies,
            sound_voice_range=_factor_range(voice_range, "--voice-range"),
            seed=seed,
            threads=threads,
        )
        result = run_training(config, resume=resume)
    except (ValueError, FileNotFoundError) as error:
        _fail(error)
    _report(result)


@app.command()
def finetune(
    checkpoint: Annotated[Path, typer.Argument(help="The VAR to start from.")],
    dataset: Annotated[str, typer.Argument(help="The new triplet dataset.")],
    sounds: Annotated[str | None, typer.Option(help="Corpus with the new clips.")] = None,
    splits: Annotated[str, typer.Option(help="Comma-separated corpus splits to draw clips from.")] = "train",
    speakers: Annotated[str | None, typer.Option(help="Comma-separated speakers (a new voice).")] = None,
    replay_dataset: Annotated[
        str | None, typer.Option(help="Original triplets to mix into each batch.")
    ] = None,
    replay_fraction: float = 0.25,
    run_dir: str | None = None,
    epochs: int = 20,
    lr: float = 3e-4,
    patience: int = 3,
    front_end: Annotated[
        str | None,
        typer.Option(help="Sound front end: the checkpoint's (the default); any other is refused."),
    ] = None,
    room_copies: Annotated[
        int, typer.Option(help="Add this many recordings of every new clip in simulated rooms.")
    ] = 0,
    seed: int = 0,
    threads: int = 2,
) -> None:
    """Fine-tune a VAR on new triplets, with early stopping on a held-out part of them."""
    from learning.var.finetune import finetune_config
    from learning.var.train import train as run_training

    try:
        sounds = _sounds_for(dataset, sounds)
        config = finetune_config(
            checkpoint,
            dataset,
            sounds,
            run_dir or _default_run_dir(dataset, sounds, "finetune"),
            sound_splits=tuple(splits.split(",")),
            sound_speakers=tuple(speakers.split(",")) if speakers else None,
            replay_dataset=replay_dataset,
            replay_fraction=replay_fraction,
            epochs=epochs,
            lr=lr,
            patience=patience,
            front_end=front_end,
            sound_room_copies=room_copies,
            seed=seed,
            threads=threads,
        )
        result = run_training(config)
    except (ValueError, FileNotFoundError) as error:
        _fail(error)
    _report(result)


def _factor_range(text: str, option: str) -> tuple[float, float]:
    try:
        low, high = (float(part) for part in text.split(","))
    except ValueError:
        raise ValueError(f"{option} must be MIN,MAX (e.g. 0.85,1.15), got {text!r}") from None
    if not 0.5 <= low <= high <= 2.0:
        raise ValueError(f"{option} must satisfy 0.5 ≤ MIN ≤ MAX ≤ 2, got {text!r}")
    return low, high


def _report(result) -> None:
    typer.echo(
        f"{result.steps} steps, {result.epochs_completed:.1f} epochs in {result.seconds:.0f} s "
        f"({result.triplets_per_second:.0f} triplets/s); held-out accuracy {result.final_val_accuracy} "
        f"(best {result.best_val_accuracy}){'; stopped early' if result.stopped_early else ''}"
    )
    typer.echo(f"checkpoint: {result.checkpoint}\nmetrics: {result.run_dir / 'metrics.png'}")


@app.command("eval")
def evaluate(
    checkpoint: Path,
    dataset: Annotated[
        str, typer.Argument(help="Views the VAR was not trained on (collect with another seed).")
    ],
    sounds: str | None = None,
    output: Annotated[Path | None, typer.Option(help="Also write the results here as JSON.")] = None,
    allow_other_corpus: Annotated[
        bool, typer.Option(help="Evaluate with a corpus other than the trained one.")
    ] = False,
    threads: int = 2,
) -> None:
    """Triplet accuracy per unheard tier and command retrieval both ways."""
    import torch

    from learning.var.checkpoint import load_var
    from learning.var.dataset import open_dataset
    from learning.var.evaluate import evaluate_var

    torch.set_num_threads(threads)
    try:
        sounds = _sounds_for(dataset, sounds)
        var = load_var(checkpoint)
        corpus = _corpus(sounds, var.front_end)  # the clips' features as the VAR's f_S reads them
        if not allow_other_corpus:
            var = load_var(checkpoint, manifest_hash=corpus.manifest_hash)
        result = evaluate_var(var, open_dataset(dataset), corpus)
    except (ValueError, FileNotFoundError) as error:
        _fail(error)
    _print_evaluation(result)
    if output:
        output.write_text(json.dumps(result, indent=2))


def _print_evaluation(result: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(
        title=f"VAR evaluation — image → command retrieval {result['image_to_command']:.3f} "
        f"({result['images_in_view']} images with a target in view)"
    )
    for column in ("tier", "triplet acc", "in view", "nothing in view", "clip → image", "clips"):
        table.add_column(column)
    for tier, scores in result["tiers"].items():
        table.add_row(
            tier,
            f"{scores['triplet_accuracy']:.4f}",
            f"{scores['triplet_accuracy_in_view']:.4f}",
            f"{scores['triplet_accuracy_nothing_in_view']:.4f}",
            f"{scores['clip_to_image']:.4f}",
            str(scores["clips"]),
        )
    Console().print(table)


@app.command()
def plot(
    checkpoint: Path,
    dataset: str,
    sounds: str | None = None,
    output: Annotated[Path | None, typer.Option(help="PNG path (default: beside the checkpoint).")] = None,
    splits: Annotated[
        str | None, typer.Option(help="Comma-separated corpus splits to show (default all).")
    ] = None,
    metrics: Annotated[
        bool, typer.Option(help="Also redraw the training curves of the checkpoint's run.")
    ] = True,
) -> None:
    """The embedding sphere (images: circles, sounds: triangles, coloured by intent) and training curves."""
    from learning.var.checkpoint import load_var
    from learning.var.dataset import open_dataset
    from learning.var.plot import plot_metrics, plot_sphere

    try:
        sounds = _sounds_for(dataset, sounds)
        var = load_var(checkpoint)
        path = plot_sphere(
            var,
            open_dataset(dataset),
            _corpus(sounds, var.front_end),
            output or checkpoint.with_suffix(".sphere.png"),
            splits=splits.split(",") if splits else None,
        )
    except (ValueError, FileNotFoundError) as error:
        _fail(error)
    typer.echo(f"sphere: {path}")
    if metrics and (checkpoint.parent / "metrics.jsonl").is_file():
        typer.echo(
            f"curves: {plot_metrics(checkpoint.parent / 'metrics.jsonl', checkpoint.parent / 'metrics.png')}"
        )
