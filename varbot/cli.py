"""The `varbot` command. Each area owns its sub-command group; heavy imports happen inside commands."""

from typing import Annotated

import typer

from backend.cli import register_backend_commands
from learning.rl.cli import app as rl_app
from learning.sounds.cli import app as sounds_app
from learning.var.cli import app as var_app
from scene.cli import run_scene
from sim.cli import app as sim_app
from worker.cli import register_worker_commands

app = typer.Typer(help="varbot: teach a robot what your own spoken commands mean.", no_args_is_help=True)
app.add_typer(sim_app, name="sim")
app.add_typer(sounds_app, name="sounds")
app.add_typer(rl_app, name="rl")
app.add_typer(var_app, name="var")
register_backend_commands(app)  # admin, db, blobs, api
register_worker_commands(app)  # worker, models
app.command(name="scene")(run_scene)


@app.command()
def up(
    host: Annotated[str, typer.Option(help="address the API listens on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="port the API listens on")] = 8000,
    demo: Annotated[bool, typer.Option(help="render the simulated robots first")] = True,
) -> None:
    """Start the whole product on embedded defaults (Redis, migrations, API) and print its URL."""
    from varbot.up import run_up

    run_up(host=host, port=port, demo=demo)


if __name__ == "__main__":
    app()
