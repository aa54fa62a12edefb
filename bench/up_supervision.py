"""`varbot up` under SIGKILL: while a fine-tune run is in progress, each child of the launcher is killed in
turn (the training worker, Redis, the API, the scene, the robot worker). Reported for each: how long until the
launcher says it is back, whether the API answered meanwhile (GET /robots, which needs no Redis), and for
Redis and the training worker how long until the run moved on again; then how the run ended (it should resume:
one run, one model version). Writes bench/results/up_supervision.json, with the load average before/after.

Everything runs on product defaults (a dead run's lease expires after 30 s, then a training worker sends it
again) in a fresh data directory, with a tiny 16 px base model and an espeak-ng household
(varbot/simulated_household.py). A few minutes on two cores.

    nice -n 10 .venv/bin/python bench/up_supervision.py [--policy-steps 1200]
"""

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
from conditions import Conditions, describe
from result_files import write_result
from rich.console import Console
from rich.table import Table

from varbot.launched import LaunchedUp
from varbot.services import varbot_argv, wait_until
from varbot.simulated_household import TINY, Household, install_tiny_base_model, spoken_commands

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "bench" / "results" / "up_supervision.json"
PASSWORD = "supervision bench password"
# Each child of `varbot up` by its name in the launcher's lines and a piece of its command line.
CHILDREN = {  # in the order they are killed: the run's own parts first, while it surely runs
    "worker-training": "--queue training",
    "redis": "redis-server",
    "api": "varbot.cli api",
    "scene": "varbot.cli scene",
    "worker-robot": "--queue robot",
}
RUN_NEEDS = {"redis", "worker-training"}  # the run stops with these and must move on again
ENDED = ("succeeded", "failed", "cancelled")
console = Console()


def make_household(launcher: LaunchedUp, root: Path, env: dict[str, str], wavs: dict) -> Household:  # type: ignore[type-arg]
    admin = ["admin", "create", "--username", "parent", "--household", "bench"]
    created = subprocess.run(
        varbot_argv(*admin), env={**env, "VARBOT_ADMIN_PASSWORD": PASSWORD}, check=True, capture_output=True,
        text=True,
    )  # fmt: skip
    household_id = int(created.stdout.rsplit("(id ", 1)[1].split(")")[0])
    return Household.sign_in(launcher.url, "parent", PASSWORD, household_id, wavs)


def progress_of(household: Household, run_id: int) -> tuple[str, float]:
    run = household.run(run_id)
    return run["status"], float(run["progress"])


def kill_and_watch(launcher: LaunchedUp, household: Household, name: str, run_id: int) -> dict:
    """SIGKILL one child; until the launcher says it is back, ask the API for the robots every 0.2 s."""
    victim = launcher.child(CHILDREN[name])
    offset = len(launcher.output())
    status_before, progress_before = progress_of(household, run_id)
    killed_at = time.monotonic()
    victim.kill()
    answers = {"answered": 0, "asked": 0}
    while not launcher.said(f"{name} is back", after=offset):
        answers["asked"] += 1
        with contextlib.suppress(httpx.HTTPError):  # the API itself may be the one away
            answers["answered"] += household.client.get("/api/v1/robots", timeout=2).status_code == 200
        assert time.monotonic() - killed_at < 300, f"{name} did not come back in 300 s"
        time.sleep(0.2)
    row = {
        "child": name,
        "run_status_at_kill": status_before,
        "back_after_s": round(time.monotonic() - killed_at, 1),
        "api_robots_list": answers,
    }
    if name in RUN_NEEDS:

        def moved_on() -> bool:
            status, progress = progress_of(household, run_id)
            return status in ENDED or progress > progress_before

        wait_until(moved_on, 600, f"run {run_id} to move on after {name} died", interval=0.5)
        row["run_moved_on_after_s"] = round(time.monotonic() - killed_at, 1)
    row["run_status_then"] = progress_of(household, run_id)[0]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy-steps", type=int, default=1200, help="the run's policy stage")
    parser.add_argument("--out", type=Path, default=RESULT)
    args = parser.parse_args()

    root = Path(tempfile.mkdtemp(prefix="vb-upsup-"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("VARBOT_")}
    env.update(
        VARBOT_DATA_DIR=str(root / "data"),
        VARBOT_ENVIRONMENT="development",
        VARBOT_BASE_MODELS_DIR=str(root / "base_models"),
        VARBOT_EVAL_NUM_ENVS="2",
        VARBOT_TORCH_THREADS="1",
        PYTHONUNBUFFERED="1",
    )
    conditions = Conditions()
    started = time.monotonic()
    wavs = spoken_commands(root / "wavs")
    install_tiny_base_model(wavs, root / "base-build", root / "base_models")
    launcher = LaunchedUp.start(root / "up.log", env)
    try:
        household = make_household(launcher, root, env, wavs)
        robot = household.new_robot("supervised arm")
        run = household.start_run(robot, **{**TINY, "policy_steps": args.policy_steps})
        wait_until(lambda: household.run(run["id"])["status"] == "running", 300, "the run to start")
        rows = []
        for name in CHILDREN:
            console.print(f"killing {name} …")
            rows.append(kill_and_watch(launcher, household, name, run["id"]))
        final = household.wait_run(run["id"], timeout=1800)
        runs = household.client.get("/api/v1/runs", params={"robot_id": robot}).json()
        versions = [v for v in household.versions(robot) if v["run_id"] == run["id"]]
        restarts = launcher.output().count(" restarted (restart ")
    finally:
        stopped_with = launcher.interrupt()
    result = {
        "kills": rows,
        "run": {
            "id": final["id"], "status": final["status"], "error": final["error"],
            "resumed": "resumed_at" in final["metrics"].get("latest", {}),
            "runs_of_the_robot": len(runs), "model_versions_of_the_run": len(versions),
            "policy_steps": args.policy_steps,
        },
        "launcher_restarts": restarts,
        "launcher_stopped_cleanly": stopped_with == 0,
        "wall_s": round(time.monotonic() - started, 1),
        **conditions.finish(),
        "command": " ".join(["python", "bench/up_supervision.py", *sys.argv[1:]]),
    }  # fmt: skip
    write_result(args.out, result)
    print_table(result)
    console.print(f"written to {args.out}")


def print_table(result: dict) -> None:
    table = Table(title="varbot up: each child SIGKILLed in turn while a fine-tune run is in progress")
    for column in (
        "child",
        "run",
        "back after",
        "API answered (GET /robots)",
        "run moved on after",
        "run then",
    ):
        table.add_column(column)
    for row in result["kills"]:
        answers = row["api_robots_list"]
        moved = row.get("run_moved_on_after_s")
        table.add_row(
            row["child"], row["run_status_at_kill"], f"{row['back_after_s']:.1f} s",
            f"{answers['answered']} of {answers['asked']}", "" if moved is None else f"{moved:.1f} s",
            row["run_status_then"],
        )  # fmt: skip
    console.print(table)
    run = result["run"]
    console.print(
        f"run {run['id']}: {run['status']}{' (resumed)' if run['resumed'] else ''}; "
        f"{run['runs_of_the_robot']} run(s), {run['model_versions_of_the_run']} model version(s) from it; "
        f"{result['launcher_restarts']} restarts; wall {result['wall_s']:.0f} s"
    )
    console.print(describe(result))


if __name__ == "__main__":
    main()
