"""The end of a CI log: what pytest's run came to, read from its `-ra` output.

    python scripts/test_summary.py PYTEST_LOG PYTEST_EXIT_CODE

Prints the counts (passed, failed, errors, skipped, …), then every skip, xfail and failure line of the short
summary, and exits non-zero when the run failed, when no test ran (pytest's exit code 5) or when anything was
skipped: a skip hides a missing part (PostgreSQL, Chromium, a synthesizer, a broken import), so the suite has
none and CI goes red on the first one."""

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


def main(log_path: str, exit_code: str) -> int:
    lines = Path(log_path).read_text(errors="replace").splitlines()
    finals = [m.group(1) for line in lines if (m := FINAL_LINE.match(line))]
    found = counts(finals[-1]) if finals else {outcome: 0 for outcome in OUTCOMES}
    code = int(exit_code)
    print("\n=== CI summary " + "=" * 60)
    print(", ".join(f"{found[o]} {o}" for o in OUTCOMES) + f"   (pytest exit code {code})")
    for line in lines:
        if SHORT_SUMMARY.match(line):
            print("  " + line)
    problems = []
    if code == NO_TESTS_RAN or (finals and sum(found.values()) == found["warnings"]):
        problems.append("no test ran")
    elif code != 0 or found["failed"] or found["errors"]:
        problems.append("pytest failed")
    if not finals:
        problems.append(f"no pytest result line in {log_path}")
    if found["skipped"]:
        problems.append(f"{found['skipped']} skipped (the goal is 0: each names what to install or fix)")
    print("CI: " + ("; ".join(problems) if problems else "every test ran and passed"))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
