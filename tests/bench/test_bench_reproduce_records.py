"""bench/reproduce.py is the only writer of reproduce.json: records are moved, relabelled and dropped by its
`records` command, each edit logged in the file; its table gives each recipe's mean and spread over seeds and
lists every seed."""

import json
import multiprocessing
import shlex
import time
from multiprocessing.synchronize import Event
from pathlib import Path

import pytest
import reproduce_records
from reproduce_table import print_table, table_lines


def run_record(tag: str, seed: int, easy: float, var: str = "data/var/a/final.pt") -> dict:
    return {
        "row": "kuka-wordset",
        "method": "var",
        "tag": tag,
        "status": "complete",
        "env_steps": 1000,
        "success": {"unheard-easy": easy, "unheard-real-voices": easy / 2},
        "labels": {"total": 10},
        "paper_success": 97.0,
        "var_checkpoint": var,
        "config": {"seed": seed, "total_steps": 1000, "torch_threads": seed, "goal_match": None},
    }


@pytest.fixture
def stored(tmp_path, monkeypatch):
    """A reproduce.json in a temporary place, and a way to run `records …` on it and read it back."""
    output = tmp_path / "reproduce.json"
    monkeypatch.setattr(reproduce_records, "OUTPUT", output)
    results = {
        "benchmark": "reproduce",
        "rows": {"kuka-wordset:var": run_record("seed2", 2, 0.9)},
        "earlier_runs": [run_record("seed1", 1, 0.3)],
        "interrupted_runs": [{"row": "kuka-wordset:var", "tag": "fusion", "quick_check": {"success": 0.5}}],
    }
    output.write_text(json.dumps(results))

    def records(*arguments: str) -> dict:
        reproduce_records.records_command(list(arguments), print_table)
        return json.loads(output.read_text())

    return records


def test_moving_a_run_into_the_table_sends_the_row_it_replaces_to_earlier_runs_and_logs_it(stored):
    results = stored("move", "earlier_runs/0", "--to", "rows", "--why", "seed 1 is the recipe's first run")
    assert results["rows"]["kuka-wordset:var"]["tag"] == "seed1"
    assert [r["tag"] for r in results["earlier_runs"]] == ["seed2"]
    [edit] = results["edits"]
    assert edit["why"] == "seed 1 is the recipe's first run"
    assert edit["what"].startswith("moved earlier_runs/0 (kuka-wordset:var, tag seed1, seed 1, complete)")
    assert "went to earlier_runs" in edit["what"]
    assert shlex.split(edit["command"]) == [
        "bench/reproduce.py", "records", "move", "earlier_runs/0", "--to", "rows",
        "--why", "seed 1 is the recipe's first run",
    ]  # fmt: skip
    assert edit["when"].endswith("Z")


def test_a_hand_made_record_is_relabelled_into_the_benchs_shape_then_moved(stored):
    results = stored(
        "relabel", "interrupted_runs/0", "--set", "row=kuka-wordset", "--set", "method=var",
        "--set", "status=interrupted", "--why", "the bench's own fields",
    )  # fmt: skip
    assert results["interrupted_runs"][0]["method"] == "var"
    assert 'status: null -> "interrupted"' in results["edits"][0]["what"]
    results = stored("move", "interrupted_runs/0", "--to", "experiments", "--why", "an experiment")
    assert "interrupted_runs" not in results
    assert results["experiments"]["kuka-wordset:var (fusion)"]["tag"] == "fusion"
    results = stored("relabel", "experiments/kuka-wordset:var (fusion)", "--set", "tag=fusion2", "--why", "x")
    assert list(results["experiments"]) == ["kuka-wordset:var (fusion2)"]
    assert len(results["edits"]) == 3


def test_dropping_a_field_keeps_the_record_and_logs_what_went(stored):
    results = stored("drop", "interrupted_runs/0", "--field", "quick_check", "--why", "not the protocol")
    assert results["interrupted_runs"][0] == {"row": "kuka-wordset:var", "tag": "fusion"}
    assert results["edits"][0]["what"].startswith("dropped field quick_check of interrupted_runs/0")


def test_an_edit_that_cannot_be_made_changes_nothing(stored, tmp_path):
    before = (tmp_path / "reproduce.json").read_text()
    with pytest.raises(SystemExit, match="the record needs 'row'"):
        stored("move", "interrupted_runs/0", "--to", "rows", "--why", "x")
    with pytest.raises(SystemExit, match="no record"):
        stored("drop", "rows/turtlebot-notes:var", "--why", "x")
    assert (tmp_path / "reproduce.json").read_text() == before


def test_a_hand_edit_found_in_git_is_logged_without_changing_a_record(stored):
    results = stored("hand-edit", "abc1234", "--what", "moved a run by hand", "--why", "the log covers it")
    what = results["edits"][0]["what"]
    assert what == "edited by hand outside the bench in commit abc1234: moved a run by hand"
    assert results["rows"]["kuka-wordset:var"]["tag"] == "seed2"


def test_each_line_of_the_table_is_one_recipe_over_its_seeds_with_every_seed_listed(stored):
    results = stored("table")
    [line] = results["table"]["lines"]
    assert [(s["seed"], s["tag"], s["record"]) for s in line["seeds"]] == [
        (1, "seed1", "earlier_runs/0"),
        (2, "seed2", "rows/kuka-wordset:var"),
    ]
    assert line["success_mean"]["unheard-easy"] == pytest.approx(0.6)
    assert line["success_spread"]["unheard-easy"] == pytest.approx(0.4242640687)  # sample sd of 0.3, 0.9


def test_a_run_with_another_var_is_another_recipe_and_one_seed_has_no_spread():
    results = {
        "rows": {"kuka-wordset:var": run_record("seed2", 2, 0.9)},
        "earlier_runs": [run_record("other-var", 1, 0.3, var="data/var/b/final.pt")],
    }
    [line] = table_lines(results)
    assert [s["tag"] for s in line["seeds"]] == ["seed2"]
    assert line["success_spread"] == {"unheard-easy": None, "unheard-real-voices": None}


def test_runs_whose_reward_paid_differently_are_never_seeds_of_one_recipe():
    per_step = {**run_record("per-step", 2, 0.8), "reward_revision": 2}
    relabelled = {**run_record("relabelled", 3, 0.7), "reward_revision": "2"}  # `records relabel` sets text
    at_the_end = run_record("at-the-end", 1, 0.0)  # stored before revisions: revision 1
    results = {"rows": {"kuka-wordset:var": per_step}, "earlier_runs": [at_the_end, relabelled]}
    [line] = table_lines(results)
    assert [s["tag"] for s in line["seeds"]] == ["per-step", "relabelled"]


def test_a_run_stopped_by_a_signal_is_stored_as_interrupted_with_how_to_take_it_up_again():
    from reproduce import mark_interrupted

    running = {"row": "kuka-wordset", "tag": "t", "status": "running", "progress": {"global_step": 16000},
               "config": {"total_steps": 400000, "seed": 2}}  # fmt: skip
    store = {"kuka-wordset:var": running, "done": {"status": "complete"}}
    mark_interrupted(store, "kuka-wordset:var")
    mark_interrupted(store, "done")
    assert store["kuka-wordset:var"]["status"] == "interrupted"
    assert "stopped at 16,000 env steps of 400,000, seed 2" in store["kuka-wordset:var"]["note"]
    assert store["kuka-wordset:var"]["config"]["seed"] == 2, "its records list shows the seed"
    assert "--resume" in store["kuka-wordset:var"]["note"]
    assert store["done"] == {"status": "complete"}


def save_progress_many_times(output: str, entry: str, start: Event) -> None:
    """One run of a seed saving its progress, as bench/reproduce.py does every 10 updates; each save takes a
    moment between reading the file and writing it back, so the two runs' saves overlap."""
    reproduce_records.OUTPUT = Path(output)
    start.wait()
    for step in range(20):
        with reproduce_records.updated_results() as results:
            time.sleep(0.005)
            results.setdefault("experiments", {})[entry] = {"progress": {"global_step": step}}


def test_two_seeds_running_at_once_each_keep_their_record(stored, tmp_path):
    """Runs of several seeds at once each read the file afresh under a lock, so neither writes the other's
    record away (each used to hold the whole file in memory and write it back)."""
    output = str(tmp_path / "reproduce.json")
    context = multiprocessing.get_context("spawn")
    start = context.Event()
    seeds = [
        context.Process(target=save_progress_many_times, args=(output, f"seed{k}", start)) for k in (1, 2)
    ]
    for seed in seeds:
        seed.start()
    start.set()
    for seed in seeds:
        seed.join(timeout=60)
    assert [seed.exitcode for seed in seeds] == [0, 0]
    results = json.loads(Path(output).read_text())
    assert results["experiments"] == {
        "seed1": {"progress": {"global_step": 19}},
        "seed2": {"progress": {"global_step": 19}},
    }
    assert results["rows"]["kuka-wordset:var"]["tag"] == "seed2"  # what was there before is kept


def test_one_var_recipe_built_in_two_data_directories_is_one_var():
    in_the_repository = run_record("made-here", 2, 0.8, var="data/bench/var/a/final.pt")
    elsewhere = run_record("made-elsewhere", 3, 0.6, var="$VARBOT_DATA_DIR/bench/var/a/final.pt")
    another = run_record("another-var", 1, 0.1, var="$VARBOT_DATA_DIR/bench/var/b/final.pt")
    results = {"experiments": {"a": in_the_repository}, "earlier_runs": [elsewhere, another]}
    [line] = table_lines(results)
    assert [s["tag"] for s in line["seeds"]] == ["made-here", "made-elsewhere"]


def test_a_setting_added_later_at_the_value_that_trains_as_before_leaves_the_recipe_unchanged():
    before = run_record("before", 2, 0.8)
    after = run_record("after", 3, 0.6)
    after["config"] |= {
        "replay_envs": 0,
        "replay_room": "randomised",
        "room": "training",
        "reward_against_others": False,
        "policy_colour_jitter": 0.0,
        "contact": "stop",
        "hard_start_share": 0.0,
        "policy_view": "pixels",
        "policy_view_follows_var": False,
    }
    elsewhere = run_record("unseen-room", 1, 0.1)
    elsewhere["config"] |= {"room": "unseen_room"}
    with_replay = run_record("replay", 4, 0.1)
    with_replay["config"] |= {"replay_envs": 2, "replay_room": "randomised"}
    against_others = run_record("against-others", 5, 0.9)
    against_others["config"] |= {"reward_against_others": True}
    jittered = run_record("colour-jitter", 6, 0.9)
    jittered["config"] |= {"policy_colour_jitter": 0.3}
    sliding = run_record("slide", 7, 0.9)
    sliding["config"] |= {"contact": "slide"}
    hard_starts = run_record("start-curriculum", 8, 0.9)
    hard_starts["config"] |= {"hard_start_share": 0.3}
    through_the_var = run_record("var-view", 9, 0.9)
    through_the_var["config"] |= {"policy_view": "var"}
    results = {
        "experiments": {"before": before},
        "earlier_runs": [
            after,
            elsewhere,
            with_replay,
            against_others,
            jittered,
            sliding,
            hard_starts,
            through_the_var,
        ],
    }
    [line] = table_lines(results)
    assert [s["tag"] for s in line["seeds"]] == ["before", "after"]


def test_the_mean_takes_the_complete_seeds_and_lists_a_partial_one_beside_them():
    partial = {**run_record("cut-short", 1, 0.5), "status": "partial"}
    again = run_record("again", 1, 0.7)
    other = run_record("other-seed", 2, 0.9)
    stopped = {**run_record("stopped", 3, 0.1), "status": "partial"}
    results = {"experiments": {"a": other, "b": stopped}, "earlier_runs": [partial, again]}
    [line] = table_lines(results)
    assert [(s["tag"], s["in_mean"]) for s in line["seeds"]] == [
        ("again", True),
        ("other-seed", True),
        ("stopped", False),
    ]
    assert line["success_mean"]["unheard-easy"] == pytest.approx(0.8)
    assert line["seeds_in_mean"] == 2


def test_a_recipe_of_only_partial_seeds_is_their_mean_each_marked_partial():
    results = {"experiments": {"a": {**run_record("a", 1, 0.4), "status": "partial"}}}
    [line] = table_lines(results)
    assert line["seeds"][0]["in_mean"] and line["success_mean"]["unheard-easy"] == pytest.approx(0.4)
