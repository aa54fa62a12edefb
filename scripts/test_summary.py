"""The end of a CI log: what pytest's runs came to, read from their `-ra` output.

    python scripts/test_summary.py PYTEST_LOG PYTEST_EXIT_CODE [PYTEST_LOG PYTEST_EXIT_CODE ...]

One log per pytest run (`make test` runs two streams side by side: scripts/run_tests.py). Prints each run's
counts (passed, failed, errors, skipped, …) and their total, then every skip, xfail and failure line of the
short summaries, and exits non-zero when a run failed, when one ran no test (pytest's exit code 5) or when
anything was skipped: a skip hides a missing part (PostgreSQL, Chromium, a synthesizer, a broken import), so
the suite has none and CI goes red on the first one."""

import re
import sys
from pathlib import Path

OUTCOMES = ("passed", "failed", "errors", "skipped", "xfailed", "xpassed", "warnings", "deselected")
SHORT_SUMMARY = re.compile(r"^(FAILED|ERROR|SKIPPED|XFAIL|XPASS) ")
# "=== 3 passed, 1 skipped in 2.1s ===" (or without the rules, under -q), "=== no tests ran in 0.1s ==="
FINAL_LINE = re.compile(r"^=* ?((?:\d+ \w+(?:, )?)+|no tests ran) in [\d.]+s\b.*?=*$")
NO_TESTS_RAN = 5


def counts(final_line: str) -> dict[str, int]:
    found = {outcome: 0 for outcome in OUTCOMES}
    for number, word in re.findall(r"(\d+) (\w+)", final_line):
        word = {"error": "errors", "warning": "warnings"}.get(word, word)
        if word in found:
            found[word] = int(number)
    return found


def problems_of(log_path: str, code: int, found: dict[str, int], ran: bool) -> list[str]:
    problems = []
    if code == NO_TESTS_RAN or (ran and sum(found.values()) == found["warnings"]):
        problems.append(f"no test ran in {log_path}")
    elif code != 0 or found["failed"] or found["errors"]:
        problems.append(f"pytest failed in {log_path}")
    if not ran:
        problems.append(f"no pytest result line in {log_path}")
    if found["skipped"]:
        problems.append(f"{found['skipped']} skipped (the goal is 0: each names what to install or fix)")
    return problems


def main(arguments: list[str]) -> int:
    total = {outcome: 0 for outcome in OUTCOMES}
    problems, short = [], []
    print("\n=== CI summary " + "=" * 60)
    for log_path, exit_code in zip(arguments[::2], arguments[1::2], strict=True):
        lines = Path(log_path).read_text(errors="replace").splitlines()
        finals = [m.group(1) for line in lines if (m := FINAL_LINE.match(line))]
        found = counts(finals[-1]) if finals else {outcome: 0 for outcome in OUTCOMES}
        code = int(exit_code)
        print(", ".join(f"{found[o]} {o}" for o in OUTCOMES) + f"   (pytest exit code {code}: {log_path})")
        total = {outcome: total[outcome] + found[outcome] for outcome in OUTCOMES}
        short += ["  " + line for line in lines if SHORT_SUMMARY.match(line)]
        problems += problems_of(log_path, code, found, bool(finals))
    if len(arguments) > 2:
        print(", ".join(f"{total[o]} {o}" for o in OUTCOMES) + "   (in all)")
    print("\n".join(short))
    print("CI: " + ("; ".join(problems) if problems else "every test ran and passed"))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
