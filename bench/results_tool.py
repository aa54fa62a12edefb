"""Maintenance of bench/results/*.json written before the benches did it themselves: loads each file and
writes it again through the benches' own writer (bench/result_files.py), so it is never edited by hand.

    .venv/bin/python bench/results_tool.py relativise-paths   # this machine's absolute paths -> relative
    .venv/bin/python bench/results_tool.py drop-load-claims   # "shared with other agents": never measured

reproduce.json is left to its own bench, which logs every edit: `bench/reproduce.py records relativise-paths`.
"""

import argparse
import json
import re
from pathlib import Path

from result_files import map_strings, write_result

RESULTS = Path(__file__).resolve().parent / "results"
OWNED_ELSEWHERE = {"reproduce.json": "bench/reproduce.py records relativise-paths --why …"}
# A sentence the benches once wrote whatever the load was; the load average they record now replaces it.
LOAD_CLAIM = re.compile(r",? *shared with other (?:agents'? ?)?(?:jobs)?(?: while measured)?")


def without_load_claims(value: object) -> object:
    return map_strings(value, lambda text: LOAD_CLAIM.sub("", text))


def rewrite(path: Path, change) -> bool:
    """Writes `path` again through the benches' writer, after `change`; True when its text changed."""
    before = path.read_text()
    write_result(path, change(json.loads(before)))
    return path.read_text() != before


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("verb", choices=("relativise-paths", "drop-load-claims"))
    args = parser.parse_args()
    change = without_load_claims if args.verb == "drop-load-claims" else (lambda result: result)
    for path in sorted(RESULTS.glob("*.json")):
        if path.name in OWNED_ELSEWHERE:
            print(f"{path.name}: left to its bench ({OWNED_ELSEWHERE[path.name]})")
            continue
        print(f"{path.name}: {'rewritten' if rewrite(path, change) else 'unchanged'}")


if __name__ == "__main__":
    main()
