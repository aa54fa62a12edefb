"""bench/results/reproduce.json, read and written only here (through `bench/reproduce.py`), and the edits
made to its records after their runs: `bench/reproduce.py records list|move|relabel|drop|hand-edit|…`.
Every edit is logged inside the file under "edits": what changed, when, why, and the command that changed it.

Sections: "rows" (the table: one record per world-sounds:method), "earlier_runs" (a row's previous results),
"interrupted_runs" (runs that stopped before their evaluation), "experiments" (variants beside a row) and
"diagnostics". A record's id is its section and its key or position: `rows/kuka-wordset:var`,
`earlier_runs/3`, `experiments/kuka-wordset:var (var4800-1m-seed2)`; `records list` prints them.
"""

import argparse
import fcntl
import json
import shlex
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from result_files import ABSOLUTE_PATH, write_result

RESULTS = Path(__file__).resolve().parent / "results"
OUTPUT = RESULTS / "reproduce.json"
KEYED_SECTIONS = ("rows", "experiments", "diagnostics")
LISTED_SECTIONS = ("earlier_runs", "interrupted_runs")
SECTIONS = KEYED_SECTIONS + LISTED_SECTIONS
LONG_TEXT = 120  # characters of a changed field's old and new value together, above which the log says less


class RecordError(ValueError):
    """A records command that cannot be carried out as asked (unknown id, missing field, taken slot)."""


def load_results() -> dict:
    return json.loads(OUTPUT.read_text()) if OUTPUT.exists() else {"benchmark": "reproduce", "rows": {}}


def save_results(results: dict) -> None:
    write_result(OUTPUT, results)


@contextmanager
def updated_results() -> Iterator[dict]:
    """The file as it is now, read under an exclusive lock and written back when the block ends: what another
    run (another seed, another row) saved meanwhile is kept, and no two runs write at once."""
    with OUTPUT.with_name(f".{OUTPUT.name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        results = load_results()
        yield results
        save_results(results)


def record_ids(results: dict) -> list[str]:
    ids = []
    for section in SECTIONS:
        entries = results.get(section, {})
        keys = entries if section in KEYED_SECTIONS else range(len(entries))
        ids += [f"{section}/{key}" for key in keys]
    return ids


def find(results: dict, record_id: str) -> tuple[str, str | int, dict]:
    section, _, key = record_id.partition("/")
    entries = results.get(section)
    if section not in SECTIONS or entries is None:
        raise RecordError(f"no section {section!r}: choose from {', '.join(SECTIONS)}")
    if section in LISTED_SECTIONS:
        if not key.isdigit() or int(key) >= len(entries):
            raise RecordError(f"{section} has {len(entries)} records; no {key!r}")
        return section, int(key), entries[int(key)]
    if key not in entries:
        raise RecordError(f"no record {key!r} under {section}")
    return section, key, entries[key]


def describe_record(record: dict) -> str:
    seed = (record.get("config") or {}).get("seed")
    parts = [f"{record.get('row')}:{record.get('method')}", f"tag {record.get('tag')}"]
    parts += [f"seed {seed}" if seed is not None else "seed ?", str(record.get("status"))]
    return ", ".join(parts)


def slot_key(section: str, record: dict) -> str:
    """The key the bench itself gives a record in a keyed section (see reproduce.record_slot)."""
    if "method" not in record or ":" in str(record.get("row")):
        raise RecordError("the record needs 'row' (world-sounds) and 'method' first: use relabel --set")
    key = f"{record['row']}:{record['method']}"
    if section == "rows":
        return key
    if section == "experiments":
        return f"{key} ({record.get('tag')})"
    targets = ",".join(map(str, (record.get("config") or {}).get("target_intents") or []))
    return f"{key} targets {targets} ({record.get('tag')})"


def take_out(results: dict, section: str, key: str | int) -> dict:
    entries = results[section]
    record = entries.pop(key)
    if not entries and section != "rows":
        del results[section]
    return record


def put(results: dict, section: str, record: dict) -> str:
    """Stores `record` in `section` and returns its new id; a row's previous record goes to earlier_runs (as
    when the bench runs a row again)."""
    if section in LISTED_SECTIONS:
        entries = results.setdefault(section, [])
        entries.append(record)
        return f"{section}/{len(entries) - 1}"
    key = slot_key(section, record)
    entries = results.setdefault(section, {})
    if key in entries:
        if section != "rows":
            raise RecordError(f"{section}/{key} is taken; move or drop that record first")
        put(results, "earlier_runs", entries[key])
    entries[key] = record
    return f"{section}/{key}"


def move(results: dict, record_id: str, section: str) -> str:
    if section not in SECTIONS:
        raise RecordError(f"no section {section!r}: choose from {', '.join(SECTIONS)}")
    source, key, record = find(results, record_id)
    new_key = slot_key(section, record) if section in KEYED_SECTIONS else None  # fails before any change
    occupant = results["rows"].get(new_key) if section == "rows" else None
    take_out(results, source, key)
    new_id = put(results, section, record)
    moved = f"moved {record_id} ({describe_record(record)}) to {new_id}"
    if occupant is None:
        return moved
    return f"{moved}; the row's previous record ({describe_record(occupant)}) went to earlier_runs"


def parse_assignments(texts: list[str]) -> dict[str, str]:
    pairs = {}
    for text in texts:
        name, separator, value = text.partition("=")
        if not separator or not name:
            raise RecordError(f"{text!r}: write FIELD=VALUE")
        pairs[name] = value
    return pairs


def change_of(name: str, old: object, new: str) -> str:
    """A changed field as the log shows it; a long text is not repeated (git keeps the earlier one)."""
    if len(json.dumps(old)) + len(new) > LONG_TEXT:
        return f"{name} rewritten (the earlier text stays in the file's git history)"
    return f"{name}: {json.dumps(old)} -> {json.dumps(new)}"


def relabel(results: dict, record_id: str, values: dict[str, str], renames: dict[str, str]) -> str:
    """Sets text fields (tag, status, note, row, method …) and renames fields; a keyed record whose key
    depends on a changed field is stored under its new key."""
    section, key, record = find(results, record_id)
    changes = []
    for old, new in renames.items():
        if old not in record:
            raise RecordError(f"{record_id} has no field {old!r}")
        if new in record:
            raise RecordError(f"{record_id} already has a field {new!r}")
        record[new] = record.pop(old)
        changes.append(f"field {old} renamed {new}")
    for name, value in values.items():
        changes.append(change_of(name, record.get(name), value))
        record[name] = value
    new_id = record_id
    if section in KEYED_SECTIONS and slot_key(section, record) != key:
        take_out(results, section, key)
        new_id = put(results, section, record)
    moved = f" (now {new_id})" if new_id != record_id else ""
    return f"relabelled {record_id}{moved}: " + "; ".join(changes)


def drop(results: dict, record_id: str, field: str | None) -> str:
    """Removes a record, or one field of it; what was removed stays in the git history of the file."""
    section, key, record = find(results, record_id)
    if field is None:
        take_out(results, section, key)
        return f"dropped {record_id} ({describe_record(record)})"
    if field not in record:
        raise RecordError(f"{record_id} has no field {field!r}")
    del record[field]
    return f"dropped field {field} of {record_id} ({describe_record(record)})"


def absolute_path_count(results: dict) -> int:
    return len(ABSOLUTE_PATH.findall(json.dumps(results)))


def log_edit(results: dict, what: str, why: str, arguments: list[str]) -> None:
    results.setdefault("edits", []).append(
        {
            "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "what": what,
            "why": why,
            "command": shlex.join(["bench/reproduce.py", "records", *arguments]),
        }
    )


def parse_records_arguments(arguments: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="bench/reproduce.py records", description=__doc__.splitlines()[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    verbs.add_parser("list", help="every record with its id")
    verbs.add_parser(
        "table", help="print the table again from the stored records and redraw the figures (storing both)"
    )
    edits = {
        "move": "move a record to another section",
        "relabel": "set text fields of a record, or rename its fields",
        "drop": "remove a record, or one field of it",
        "hand-edit": "log an edit made by hand, outside the bench, in a git commit (changes no record)",
        "relativise-paths": "write this machine's absolute paths relative to the data dir or the repository",
    }
    for verb, text in edits.items():
        command = verbs.add_parser(verb, help=text)
        if verb in ("move", "relabel", "drop"):
            command.add_argument("record", help="record id, as `records list` prints it")
        if verb == "move":
            command.add_argument("--to", required=True, choices=SECTIONS)
        if verb == "relabel":
            command.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
            command.add_argument("--rename", action="append", default=[], metavar="FIELD=NEW_NAME")
        if verb == "drop":
            command.add_argument("--field", help="drop only this field of the record")
        if verb == "hand-edit":
            command.add_argument("commit", help="the git commit that holds the hand edit")
            command.add_argument("--what", required=True, help="what the hand edit changed")
        command.add_argument("--why", required=True, help="the reason, kept in the log")
    return parser.parse_args(arguments)


def apply_edit(results: dict, args: argparse.Namespace) -> str:
    if args.verb == "move":
        return move(results, args.record, args.to)
    if args.verb == "relabel":
        return relabel(results, args.record, parse_assignments(args.set), parse_assignments(args.rename))
    if args.verb == "drop":
        return drop(results, args.record, args.field)
    if args.verb == "hand-edit":
        return f"edited by hand outside the bench in commit {args.commit}: {args.what}"
    return f"{absolute_path_count(results)} absolute paths written relative to the data dir or the repository"


def records_command(arguments: list[str], show_results) -> None:
    """`bench/reproduce.py records …`; `show_results` prints (and stores) the table from the records, and
    redraws the figures."""
    args = parse_records_arguments(arguments)
    if args.verb == "list":
        results = load_results()
        for record_id in record_ids(results):
            print(f"{record_id}\t{describe_record(find(results, record_id)[2])}")
        return
    with updated_results() as results:
        if args.verb != "table":
            try:
                what = apply_edit(results, args)
            except RecordError as error:
                raise SystemExit(f"records {args.verb}: {error}") from None
            log_edit(results, what, args.why, arguments)
            print(what)
        show_results(results)
