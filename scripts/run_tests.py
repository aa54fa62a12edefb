"""`make test`: the suite as two pytest runs side by side, one per CPU core, then one summary of both.

    python scripts/run_tests.py LOG_DIR [extra pytest arguments for both runs]

The browser tests (Chromium, the app), the scene tests, the bench tests and the PPO training tests run in one
stream and everything else in the other: the browser tests alone took 672 s of a quiet run against 1,200 s for
all the rest, and the scene, bench and PPO training tests took 162 s and 133 s with a core to themselves. Each
stream runs in its own process with its own temporary data directory, Redis and database, and in pytest's
usual order, so no session fixture is shared between them. (tests/worker cannot join the first stream: its
modules import their own `conftest` by that name, and when several areas are named on pytest's command line
that name finds the last area's conftest, not theirs.)
Each run's output goes to LOG_DIR/pytest-<stream>.log; a line every half minute says how far each has
got, and at the end both logs are printed whole, then scripts/test_summary.py judges them together (a
failure, a skip or no tests at all fails the run)."""

import re
import subprocess
import sys
import time
from pathlib import Path

FIRST_STREAM = ["tests/browser", "tests/scene", "tests/bench", "tests/learning/test_rl_training.py"]
STREAMS = {
    "browser-scene-bench-ppo": FIRST_STREAM,
    "the-rest": ["tests", *(f"--ignore={area}" for area in FIRST_STREAM)],
}
PERCENT = re.compile(r"\[\s*(\d+)%\]")
REPORT_EVERY_S = 30


def progress(log: Path) -> str:
    found = PERCENT.findall(log.read_text(errors="replace")) if log.exists() else []
    return f"{found[-1]} %" if found else "starting"


def main(log_dir: str, *extra: str) -> int:
    Path(log_dir).mkdir(parents=True, exist_ok=True)
    logs = {name: Path(log_dir) / f"pytest-{name}.log" for name in STREAMS}
    started = time.monotonic()
    runs = {}
    for name, targets in STREAMS.items():
        with logs[name].open("w") as out:
            command = [sys.executable, "-m", "pytest", *targets, *extra]
            runs[name] = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
    while any(run.poll() is None for run in runs.values()):
        time.sleep(REPORT_EVERY_S)
        minutes = (time.monotonic() - started) / 60
        states = ", ".join(
            f"{name} {'finished' if run.poll() is not None else progress(logs[name])}"
            for name, run in runs.items()
        )
        print(f"[{minutes:5.1f} min] {states}", flush=True)
    for name, log in logs.items():
        print(f"\n{'=' * 30} pytest, {name} stream ({log}) {'=' * 30}\n{log.read_text(errors='replace')}")
    summary = [sys.executable, str(Path(__file__).with_name("test_summary.py"))]
    for name, run in runs.items():
        summary += [str(logs[name]), str(run.returncode)]
    return subprocess.run(summary).returncode


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
