"""`varbot scene`: the 3D scene service (Viser on 127.0.0.1 only, open to the app's proxy only, which shows it
to signed-in members). It runs on the API's machine: it is never reachable from another one."""

import signal
import threading
from typing import Annotated

import typer

from scene.on_demand import DEFAULT_FPS

WAIT_POLL_S = 5.0


def run_scene(
    household: Annotated[
        int | None, typer.Option(help="household id to show (default: the first one)")
    ] = None,
    robot: Annotated[
        int | None,
        typer.Option(
            help="robot id (default: the one whose model was made active last, else the first simulated)"
        ),
    ] = None,
    port: Annotated[int, typer.Option(help="Viser's port (0: any free port, announced to the API)")] = 0,
    fps: Annotated[
        float, typer.Option(min=1.0, max=60.0, help="simulation and camera frames per second")
    ] = DEFAULT_FPS,
    wait: Annotated[bool, typer.Option(help="wait for the first household instead of stopping")] = False,
    stop_when_unwatched_s: Annotated[
        float, typer.Option(min=0.0, help="stop after this many seconds without a viewer (0: never)")
    ] = 0.0,
) -> None:
    """The 3D scene of one household: the robot, its camera view, the embedding sphere, "try a command". Runs
    until Ctrl-C (or, with --stop-when-unwatched-s, until nobody has watched for that long). The API finds it
    through data_dir()/scene/household-<id>.json; the API starts one on demand when a member opens /scene."""
    import torch

    from scene.endpoint import hold_scene_lock
    from scene.household import default_household_id
    from scene.service import SceneService

    torch.set_num_threads(
        1
    )  # no worker processes are forked here; one thread keeps the 2-core machine usable
    stopping = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stopping.set())
    signal.signal(signal.SIGINT, lambda *_: stopping.set())
    household_id = household if household is not None else default_household_id()
    while household_id is None and wait and not stopping.wait(WAIT_POLL_S):
        household_id = default_household_id()
    if stopping.is_set():
        return
    if household_id is None:
        typer.echo(
            "no household yet: create the first admin with `varbot admin create`, then start the scene",
            err=True,
        )
        raise typer.Exit(1)
    lock = hold_scene_lock(household_id)
    if lock is None:
        typer.echo(f"a scene for household {household_id} is already running", err=True)
        return
    service = SceneService(
        household_id, robot_id=robot, port=port, fps=fps, idle_stop_s=stop_when_unwatched_s or None
    )
    signal.signal(signal.SIGTERM, lambda *_: service.stop())
    signal.signal(signal.SIGINT, lambda *_: service.stop())
    typer.echo(f"scene for household {household_id} at {service.url} (reach it through the app at /scene)")
    service.run()
