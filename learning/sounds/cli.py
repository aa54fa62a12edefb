"""`varbot sounds build` and `varbot sounds info`."""

import json
from collections import Counter
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(help="Offline sound-command corpora (speech synthesizers, soundfonts, real recordings).",
                  no_args_is_help=True)  # fmt: skip


@app.command()
def build(
    sets: Annotated[
        list[str] | None,
        typer.Option(
            "--sets",
            help="Sets to build (repeat or comma-separate), or `all`; default: wordset, objects, notes, mix.",
        ),
    ] = None,
    small: Annotated[
        bool, typer.Option("--small", help="A tiny corpus that builds in seconds (tests).")
    ] = False,
    seed: Annotated[
        int, typer.Option(help="Seed for speakers and variations; the build is deterministic.")
    ] = 0,
    workers: Annotated[int, typer.Option(help="Parallel renderers (the machine has 2 cores).")] = 2,
) -> None:
    """Render the corpora under the data dir (cached: a rebuild with the same parameters does nothing)."""
    import torch

    from learning.sounds import DEFAULT_SETS, SET_NAMES
    from learning.sounds.build import build_corpora
    from learning.sounds.engines import EngineMissingError

    torch.set_num_threads(1)  # tiny MFCC ops per clip; parallelism comes from the renderer threads
    names = [n.strip() for option in (sets or list(DEFAULT_SETS)) for n in option.split(",") if n.strip()]
    if "all" in names:
        names = list(SET_NAMES)
    try:
        results = build_corpora(names, profile="small" if small else "default", seed=seed, workers=workers)
    except (EngineMissingError, ValueError) as error:
        typer.secho(str(error), fg=typer.colors.RED, err=True)
        raise typer.Exit(1) from None
    total = sum(r.seconds for r in results)
    typer.echo(f"{sum(r.clips for r in results)} clips in {len(results)} sets; built in {total:.1f} s.")


@app.command()
def info(
    data_dir: Annotated[
        Path | None, typer.Option(help="Data dir (default: $VARBOT_DATA_DIR or ./data).")
    ] = None,
) -> None:
    """Show what is built: clips per split, speakers, size on disk."""
    from rich.console import Console
    from rich.table import Table

    from learning.sounds import SET_NAMES
    from learning.sounds.build import BUILD_INFO, MANIFEST, sounds_root

    root = sounds_root(data_dir)
    table = Table(title=f"Sound corpora in {root}")
    for column in ("set", "kind", "clips", "clips per split", "speakers", "seed / profile", "size"):
        table.add_column(column)
    built = 0
    for name in SET_NAMES:
        folder = root / name
        if not (folder / BUILD_INFO).exists():
            table.add_row(name, "", "not built", "", "", "", "")
            continue
        built += 1
        build_info = json.loads((folder / BUILD_INFO).read_text())
        records = [json.loads(line) for line in (folder / MANIFEST).read_text().splitlines()]
        per_split = Counter(r["split"] for r in records)
        speakers = len({r["speaker"] for r in records})
        recipe = build_info["recipe"]
        size_mb = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6
        table.add_row(
            name,
            build_info["kind"],
            str(len(records)),
            ", ".join(f"{split} {count}" for split, count in sorted(per_split.items())),
            str(speakers),
            f"{recipe['seed']} / {recipe['profile']['name']}",
            f"{size_mb:.1f} MB",
        )
    Console().print(table)
    if built == 0:
        typer.echo(
            "Nothing built yet: run `varbot sounds build` (about 2 minutes) or `varbot sounds build --small`."
        )
