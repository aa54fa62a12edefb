"""Scenes started on demand: the API process that serves a member's Scene page starts their household's scene
when none runs (`start_for`), and the scene stops by itself once nobody has watched it for `idle_stop_s()`
(`SceneService`). An idle product therefore runs no scene at all.

Several API processes may ask at once: a start is recorded in `household-<id>.starting` under a file lock, so
only one of them starts a scene while the last one started is still coming up, and a scene that finds the
household's scene lock taken (`scene.endpoint.hold_scene_lock`) leaves at once. A started scene stays in the
API's process group, so it stops with the API that started it; another API starts a new one when asked.
This module imports no Viser, torch or PyBullet."""

import fcntl
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from core.paths import data_subdir
from scene.endpoint import alive

IDLE_STOP_ENV = "VARBOT_SCENE_IDLE_STOP_S"
DEFAULT_IDLE_STOP_S = 300.0  # five minutes without a viewer, then the scene stops
FPS_ENV = "VARBOT_SCENE_FPS"
DEFAULT_FPS = 15.0
STARTING_FOR_S = 120.0  # how long a started scene may take to announce itself before another start is tried


def idle_stop_s() -> float:
    return float(os.environ.get(IDLE_STOP_ENV, DEFAULT_IDLE_STOP_S))


def scene_fps() -> float:
    """Simulation and camera frames per second of a started scene: a slow machine may ask for fewer."""
    return float(os.environ.get(FPS_ENV, DEFAULT_FPS))


def starting_file(household_id: int) -> Path:
    return data_subdir("scene") / f"household-{household_id}.starting"


def log_file(household_id: int) -> Path:
    return data_subdir("scene") / f"household-{household_id}.log"


def scene_argv(household_id: int) -> list[str]:
    return [
        sys.executable,
        "-m",
        "varbot.cli",
        "scene",
        "--household",
        str(household_id),
        "--stop-when-unwatched-s",
        str(idle_stop_s()),
        "--fps",
        str(scene_fps()),
    ]


def start_for(household_id: int) -> bool:
    """Start the household's scene unless one is already coming up; True when this call started it."""
    with starting_file(household_id).open("a+") as record:
        fcntl.flock(record, fcntl.LOCK_EX)  # held for milliseconds: other API processes wait their turn
        record.seek(0)
        if _still_coming_up(record.read()):
            return False
        process = _spawn(household_id)
        record.seek(0)
        record.truncate()
        record.write(json.dumps({"pid": process.pid, "at": time.time()}))
    return True


def _still_coming_up(recorded: str) -> bool:
    try:
        last = json.loads(recorded)
        return alive(int(last["pid"])) and time.time() - float(last["at"]) < STARTING_FOR_S
    except (ValueError, KeyError, TypeError):
        return False


def _spawn(household_id: int) -> subprocess.Popen[bytes]:
    with log_file(household_id).open("ab") as log:
        process = subprocess.Popen(scene_argv(household_id), stdout=log, stderr=subprocess.STDOUT)
    # Reap it when it ends (an idle scene stops by itself), so that no zombie keeps its pid "alive".
    threading.Thread(target=process.wait, name=f"scene-{household_id}-reaper", daemon=True).start()
    return process
