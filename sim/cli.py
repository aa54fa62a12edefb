"""`varbot sim ...`: look at the simulated worlds and check that their tasks are solvable."""

from pathlib import Path

import typer

app = typer.Typer(help="Simulated robots: render frames, run the scripted oracle.", no_args_is_help=True)

WORLD_HELP = "kuka, kinova or turtlebot"


@app.command()
def show(
    world: str = typer.Argument(..., help=WORLD_HELP),
    out: Path = typer.Option(Path("frame.png"), "--out", help="PNG file to write"),
    intent: int = typer.Option(0, "--intent", help="commanded target (0..3)"),
    size: int = typer.Option(96, "--size", help="image size in pixels"),
    seed: int = typer.Option(0, "--seed", help="scene seed"),
    domain: str = typer.Option(
        "none", "--domain", help="'none' (training room), 'unseen' or 'lamplit' (the held-out rooms)"
    ),
    oracle_steps: int = typer.Option(0, "--oracle-steps", help="let the oracle drive this many steps first"),
) -> None:
    """Render what the robot's camera sees after a reset (and optionally a few oracle steps)."""
    from sim.render import render_world_frame, save_png

    try:
        image, info = render_world_frame(world, intent, size, seed, domain, oracle_steps)
    except ValueError as error:
        raise typer.BadParameter(str(error)) from None
    save_png(out, image)
    typer.echo(f"wrote {out} ({world}, intent {intent}, {size}×{size} px, heard={info['heard']})")


@app.command()
def oracle(
    world: str = typer.Argument(..., help=WORLD_HELP),
    episodes: int = typer.Option(200, "--episodes", help="episodes in all, split evenly over the intents"),
    rule: str = typer.Option("final", "--rule", help="success rule: final or hold"),
    seed: int = typer.Option(0, "--seed", help="seed of the first episode (episode i uses seed + i)"),
) -> None:
    """Run the scripted oracle and print its success rate per intent."""
    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table

    from sim.oracle import evaluate_oracle

    with Progress(transient=True) as progress:
        task = progress.add_task(f"oracle on {world} ({rule})", total=episodes)
        try:
            report = evaluate_oracle(world, episodes, rule, seed, on_episode=lambda: progress.advance(task))
        except ValueError as error:
            raise typer.BadParameter(str(error)) from None
    table = Table(title=f"oracle success on {world}, rule '{rule}', {report.episodes} episodes")
    table.add_column("intent")
    table.add_column("success", justify="right")
    for intent in report.successes:
        table.add_row(str(intent), f"{100 * report.intent_rate(intent):.1f} %")
    table.add_row("all", f"{100 * report.success_rate:.1f} %", style="bold")
    Console().print(table)


@app.command()
def demo() -> None:
    """Render every world and intent (training and unseen room) as PNG contact sheets under the data dir."""
    from sim.demo import run_demo

    run_demo()
