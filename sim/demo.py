"""What `make run` shows until the web application exists: every world and intent as PNG contact sheets."""

import numpy as np

from core.paths import data_subdir
from sim import WORLDS
from sim.render import render_world_frame, save_png

DEMO_SIZE_PX = 128
ORACLE_STEPS = 60


def run_demo() -> None:
    """Render each world: per intent, the start frame and the frame after the oracle drove for a while."""
    folder = data_subdir("demo")
    print(f"varbot demo: rendering the simulated worlds into {folder}")
    for world in WORLDS:
        for domain, room in (("none", "training room"), ("unseen", "unseen room")):
            try:
                sheet, heard = _contact_sheet(world, domain)
            except Exception as error:  # one broken world must not hide the others
                print(f"  {world:9s} {room:13s}: could not render: {type(error).__name__}: {error}")
                continue
            path = folder / f"{world}_{room.replace(' ', '_')}.png"
            save_png(path, sheet)
            print(
                f"  {world:9s} {room:13s}: wrote {path.name} (top: start of each intent, bottom: after "
                f"{ORACLE_STEPS} oracle steps; heard {heard})"
            )
    print("done: open the PNGs to see what the robots' cameras see.")


def _contact_sheet(world: str, domain: str) -> tuple[np.ndarray, list]:
    starts, ends, heard = [], [], []
    for intent in range(4):
        start, _ = render_world_frame(world, intent, DEMO_SIZE_PX, seed=intent, domain=domain)
        end, info = render_world_frame(world, intent, DEMO_SIZE_PX, intent, domain, oracle_steps=ORACLE_STEPS)
        starts.append(start)
        ends.append(end)
        heard.append(info["heard"])
    return np.concatenate([np.concatenate(starts, axis=1), np.concatenate(ends, axis=1)], axis=0), heard
