"""A household of its own for a browser test (a fresh admin from `varbot admin create`, so that what other
tests recorded never shows), and the real rows its pages read: commands, camera views, answers, runs and
model versions as the workers would have left them."""

import itertools
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from browser_helpers import REPO, Stack, tone_wav, upload_clip, upload_views

from varbot.services import varbot_argv

_numbers = itertools.count(1)


@dataclass(frozen=True)
class Newcomers:
    username: str
    display_name: str
    household_id: int


def new_household(stack: Stack, name: str = "Nina") -> Newcomers:
    """A household with one admin and nothing else: what a family has right after `varbot admin create`."""
    number = next(_numbers)
    username = f"{name.lower()}{number}"
    created = subprocess.run(
        varbot_argv(
            "admin", "create", "--username", username, "--household", f"newcomers {number}",
            "--display-name", name,
        ),
        env=stack.env,
        capture_output=True,
        text=True,
        check=True,
    )  # fmt: skip
    household_id = int(created.stdout.rsplit("(id ", 1)[1].split(")")[0])
    return Newcomers(username, name, household_id)


def record_commands(stack: Stack, who: Newcomers, words: list[str], times: int, folder: Path) -> list[int]:
    """`times` recordings of each command word (distinct tones stand in for voices); their clip ids."""
    ids = []
    with stack.client(who.username) as client:
        for index, word in enumerate(words):
            for take in range(times):
                wav = tone_wav(folder / f"{word}-{take}.wav", amplitude=0.2 + 0.05 * index + 0.01 * take)
                ids.append(upload_clip(client, wav.read_bytes(), word))
    return ids


def add_robot(stack: Stack, who: Newcomers, name: str = "kitchen arm", kind: str = "kuka-sim") -> int:
    with stack.client(who.username) as client:
        response = client.post("/robots", json={"name": name, "kind": kind})
        response.raise_for_status()
        return int(response.json()["id"])


def capture_views(stack: Stack, who: Newcomers, robot: int, count: int) -> list[int]:
    with stack.client(who.username) as client:
        return upload_views(client, robot, count, seed=5)


def answer(stack: Stack, who: Newcomers, views: list[int], positive: int, negative: int) -> None:
    """Each view answered *is* for one clip and *is not* for another: one triplet per view."""
    with stack.client(who.username) as client:
        for view in views:
            for clip, verdict in ((positive, "is"), (negative, "is_not")):
                body = {"snapshot_id": view, "clip_id": clip, "verdict": verdict}
                client.post("/labels", json=body).raise_for_status()


# Rows as a training worker leaves them (worker/pipeline.py, worker/promotion.py): a run's stage, progress,
# metrics and timings, and model versions; written with the product's own models, in its database.
_WRITE_ROWS = """
import json, sys, uuid
from datetime import UTC, datetime, timedelta
from backend import models
from backend.db import get_session_factory
from backend.services import model_versions
order = json.loads(sys.argv[1])
with get_session_factory()() as session:
    robot = session.get_one(models.Robot, order["robot_id"])
    admin = session.query(models.User).filter_by(household_id=robot.household_id).first()
    made = []
    for run in order.get("runs", []):
        row = models.Run(household_id=robot.household_id, robot_id=robot.id, requested_by_id=admin.id,
                         task_id=uuid.uuid4().hex, started_at=datetime.now(UTC) - timedelta(minutes=3), **run)
        session.add(row)
        session.flush()
        made.append(row.id)
    for notes in order.get("versions", []):
        version = model_versions.create_version(session, robot, var_key="0" * 64, policy_key=None,
                                                metrics={"labels_used": 40, "triplet_accuracy": 0.75},
                                                notes=notes)
        model_versions.activate(session, version)
        made.append(version.id)
    session.commit()
    print(json.dumps(made))
"""


def write_rows(stack: Stack, robot: int, runs: list[dict] = (), versions: list[str] = ()) -> list[int]:  # type: ignore[assignment]
    order = {"robot_id": robot, "runs": list(runs), "versions": list(versions)}
    done = subprocess.run(
        [sys.executable, "-c", _WRITE_ROWS, json.dumps(order)],
        env=stack.env,
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])
