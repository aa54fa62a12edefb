"""Seconds per answer on the Label page, by keyboard, in a real Chromium, in both labelling modes (pairs:
Y / N; "did it do what I said?": Y, or N and a number), and what a household's answers then take.

Runs tests/browser/test_browser_label_speed.py (it answers each item once the view is shown and the command
has played to its end, as a person must) and writes its figures to bench/results/label_speed.json with the
machine and the load average. What is measured is the page's part of an answer: the command's playback and
the page's turn-around. A person's own thinking time is not measured here; `--think-seconds` adds an assumed
one (stated as an assumption in the JSON). With `--household FILE` (a bench/household.py result) it also says
how long that household's answers take: answers × seconds per answer, in each mode the run used.

    nice -n 10 .venv/bin/python bench/label_speed.py [--think-seconds 1.5]
        [--household bench/results/household.json]
"""

import argparse
import json
import subprocess
import sys
from pathlib import Path

from conditions import Conditions, describe
from result_files import relative_path, write_result
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "bench" / "results" / "label_speed.json"
TEST = "tests/browser/test_browser_label_speed.py"
ARTIFACT = ROOT / "tests" / "artifacts" / "label_speed.json"


def measure() -> dict:
    ARTIFACT.unlink(missing_ok=True)
    done = subprocess.run(
        [sys.executable, "-m", "pytest", TEST, "-x", "-q", "-p", "no:cacheprovider"], cwd=ROOT
    )
    if done.returncode != 0 or not ARTIFACT.is_file():
        raise SystemExit(f"label speed: {TEST} failed (exit {done.returncode}); run it alone to see why")
    return json.loads(ARTIFACT.read_text())


def household_hours(path: Path, modes: dict, think_seconds: float) -> dict:
    """How long the answers of a bench/household.py run take a person, by the seconds measured here."""
    labelled = json.loads(path.read_text()).get("labelling")
    if not labelled:
        raise SystemExit(
            f"label speed: {path} has no 'labelling' figures (made before bench/household.py kept them)"
        )
    seconds = {
        kind: labelled[f"{kind}_answers"] * (modes[mode]["seconds_per_answer"] + think_seconds)
        for kind, mode in (("pair", "pairs"), ("attempt", "attempts"))
    }
    return {
        "household_result": relative_path(path),
        "pair_answers": labelled["pair_answers"],
        "attempt_answers": labelled["attempt_answers"],
        "hours": round(sum(seconds.values()) / 3600, 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--think-seconds", type=float, default=0.0, help="an assumed thinking time per answer"
    )
    parser.add_argument("--household", type=Path, default=None, help="a bench/household.py result")
    args = parser.parse_args()
    conditions = Conditions()
    modes = measure()
    result: dict = {
        "what": "seconds per Label page answer by keyboard in Chromium: command playback + page turn-around",
        "command": " ".join(["python", "bench/label_speed.py", *sys.argv[1:]]),
        "modes": modes,
        "think_seconds_assumed": args.think_seconds,
        "think_seconds_note": "not measured: an assumption added to every answer (0 = the page's part alone)",
    }
    if args.household is not None:
        result["household"] = household_hours(args.household, modes, args.think_seconds)
    result.update(conditions.finish())
    write_result(RESULT, result)
    table = Table(title="Seconds per answer on the Label page (keyboard, Chromium)")
    for column in ("mode", "answers", "seconds per answer", "of which playback", "of which the page"):
        table.add_column(column)
    for mode, figures in modes.items():
        seconds = (figures[f"{part}seconds_per_answer"] for part in ("", "playback_", "page_"))
        table.add_row(mode, str(figures["answers"]), *(f"{value:.2f}" for value in seconds))
    console = Console()
    console.print(table)
    if "household" in result:
        found = result["household"]
        console.print(
            f"{found['household_result']}: {found['pair_answers']} pair + {found['attempt_answers']} attempt "
            f"answers take {found['hours']:.2f} h (think time assumed {args.think_seconds} s per answer)"
        )
    console.print(describe(result))


if __name__ == "__main__":
    main()
