"""bench/household.py on a tiny world (16 px VAR, a one-update policy) through the real API, Redis and Celery
workers: a household's own WAV folder becomes its members and recordings, the robot sits in the room asked
for, each labelling mode collects and answers its views, a fine-tune runs, and every figure lands in the
JSON. A SIGTERM mid fine-tune stops the bench and every process it started. And a badly named clip folder
says what is wrong."""

import contextlib
import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import household as bench
import psutil
import pytest
from result_files import relative_paths

from core.rooms import MIN_ROOM_VIEWS
from varbot.services import wait_until
from varbot.simulated_household import TINY, WORDS, install_tiny_base_model, spoken_commands

TINY_PARAMS = [f"--run-param={key}={json.dumps(value)}" for key, value in TINY.items()]


@pytest.fixture(scope="module")
def folders() -> Iterator[tuple[Path, Path]]:
    """(a household's clip folder: two members, every command once each; the tiny base models)."""
    root = Path(tempfile.mkdtemp(prefix="vb-household-test-"))
    wavs = spoken_commands(root / "spoken")
    clips = root / "clips"
    clips.mkdir()
    for (word, voice), wav in wavs.items():
        (clips / f"{voice}_{WORDS.index(word)}.wav").write_bytes(wav)
    install_tiny_base_model(wavs, root / "build", root / "base_models")
    yield clips, root / "base_models"


@pytest.fixture(scope="module")
def stack(folders: tuple[Path, Path]) -> Iterator[bench.Stack]:
    started = bench.Stack(Path(tempfile.mkdtemp(prefix="vb-household-stack-")), folders[1])
    yield started
    started.stop()


def _run(stack: bench.Stack, clips: Path, out: Path, *options: str) -> dict:
    argv = ["--clips", str(clips), "--triplets", "60", "--preset", "quick", *TINY_PARAMS, "--out", str(out)]
    result = bench.main([*argv, *options], stack=stack)
    assert json.loads(out.read_text()) == relative_paths(json.loads(json.dumps(result))), "what it printed"
    assert result["run"]["status"] == "succeeded", result["run"]["error"]
    assert result["run"]["gate"]["verdict"] in {"better", "no_change", "worse"}
    assert result["load_average"]["before"] and result["machine"]["cpu_cores"]
    base = Path(stack.env["VARBOT_BASE_MODELS_DIR"]) / "kuka"
    assert result["base_model"] == {
        "world": "kuka", "source": "--base-models",
        "var_sha256": hashlib.sha256((base / "var.pt").read_bytes()).hexdigest(),
        "policy_sha256": hashlib.sha256((base / "policy.pt").read_bytes()).hexdigest(),
    }, "which base model the household started from"  # fmt: skip
    training = result["run"]["policy_training"]
    assert training["env_steps"] > 0 and training["recent_success_by_room"] is not None
    assert len(training["own_room_success_by_quarter"]) == 4  # None: no episode ended in a quarter
    for row in result["per_command"]:
        for when in ("before", "after"):
            success, nowhere = row[f"success_{when}"], row[f"ended_at_no_object_{when}"]
            assert (success is None) == (nowhere is None), row
            assert success is None or 0 <= nowhere <= 1 - success + 1e-9, "a success ended at its object"
            missed_by = row[f"missed_by_cm_{when}"]
            assert (missed_by is None) == (not nowhere), "measured where some try ended at no object"
            assert missed_by is None or missed_by > 0, "no object lies where its own object is"
    return result


def test_a_households_own_clips_in_a_held_out_room_with_mixed_labelling(
    stack: bench.Stack, folders: tuple[Path, Path], tmp_path: Path
) -> None:
    options = ["--room", "lamplit_room", "--labelling", "mixed", "--attempts", "8", "--attempt-seed", "3"]
    result = _run(stack, folders[0], tmp_path / "mixed.json", *options)
    household = result["household"]
    assert sorted(household["speakers"]) == ["en", "en-us"], "members from the file names"
    assert household["members"] == 2
    assert household["recordings"] == 8 and household["room"] == "lamplit_room"
    labelled = result["labelling"]
    assert (
        labelled["attempt_answers"] >= 1
        and sum(labelled["attempt_outcomes"].values()) == labelled["attempt_answers"]
    )
    assert labelled["labels"] == labelled["labels_is"] + labelled["labels_is_not"]
    assert labelled["answers"] == labelled["pair_answers"] + labelled["attempt_answers"]
    assert 0 <= labelled["is_share"] <= 1 and labelled["triplets"] > 0
    assert labelled["attempts_skipped"] <= labelled["views_collected"] - labelled["attempt_answers"]
    every_command_shown = labelled["commands_with_an_is_answer"] == 4
    one_more_pair_might_pass = labelled["triplets"] + household["recordings"] > 60
    attempts_used_up = labelled["attempt_answers"] + labelled["attempts_skipped"] == 8
    assert (every_command_shown and one_more_pair_might_pass) or attempts_used_up, "stopped too early"
    assert 0 <= labelled["commands_with_an_is_answer"] <= 4
    assert [row["command"] for row in result["per_command"]] == WORDS


def test_the_training_room_is_scored_before_and_after_by_evaluate_runs_each_adapted_to_its_room(
    stack: bench.Stack, folders: tuple[Path, Path], tmp_path: Path
) -> None:
    options = ["--room", "unseen_room", "--labelling", "views", "--views", "20", "--household", "checking"]
    adapted = ["--adapt-views", str(MIN_ROOM_VIEWS), "--adapt-seed", "5"]
    options += ["--check-room", "training", *adapted]
    result = _run(stack, folders[0], tmp_path / "checked.json", *options)
    adaptation = result["room_adaptation"]
    assert adaptation["state"] == "done" and adaptation["views"] == MIN_ROOM_VIEWS
    unadapted = adaptation["unadapted"]
    assert unadapted["model"] == "active" and unadapted["run_id"] < result["run"]["id"]
    check = result["other_rooms"]["training"]
    assert check["before"]["model"] == "active", "before the fine-tune only the base model is there"
    assert check["after"]["run_id"] > result["run"]["id"] > check["before"]["run_id"]
    for when in ("before", "after"):
        measured = check[when]["sim_success"] is not None
        assert measured == (result["success_after"] is not None), check[when]["note"]
        assert not measured or check[when]["episodes"] == result["episodes"], "the fine-tune's episode count"
    assert result["household"]["robot_settings_at_end"] == {"domain": "unseen_room"}, "back in its own room"
    parent = bench.sign_in(stack.url, "checking-parent")
    robot = parent.get("/api/v1/robots").json()[0]["id"]
    versions = parent.get(f"/api/v1/robots/{robot}/models").json()
    parent.close()
    active = next(v for v in versions if v["status"] == "active")
    candidate = next(v for v in versions if v["run_id"] == result["run"]["id"])
    assert active["id"] in (adaptation["version_id"], candidate["id"]), "the versions before, given back"
    adapted_version = next(v for v in versions if v["id"] == adaptation["version_id"])
    assert adaptation["seed"] == adapted_version["metrics"]["room_adaptation"]["views_from"]["seed"] == 5


def test_attempts_alone_and_views_alone_in_the_other_rooms(
    stack: bench.Stack, folders: tuple[Path, Path], tmp_path: Path
) -> None:
    attempts = _run(stack, folders[0], tmp_path / "attempts.json", "--labelling", "attempts",
                    "--room", "unseen_room", "--attempts", "8", "--household", "attempting")  # fmt: skip
    assert attempts["labelling"]["pair_answers"] == 0 and attempts["labelling"]["attempt_answers"] >= 1
    assert attempts["household"]["room"] == "unseen_room"
    views = _run(stack, folders[0], tmp_path / "views.json", "--labelling", "views", "--views", "20",
                 "--room", "training", "--household", "viewing")  # fmt: skip
    assert views["labelling"]["attempt_answers"] == 0 and views["labelling"]["pair_answers"] >= 1
    assert views["labelling"]["views_collected"] == 20 and views["household"]["room"] == "training"


def test_each_commands_failures_are_told_apart_by_whether_the_robot_ended_at_no_object_at_all() -> None:
    final_views = [[6, 1, 0, 3], [0, 0, 0, 0], [0, 2, 8, 0]]  # rows: commands; last column: no object
    assert bench.share_at_no_object(final_views, 0) == 0.3
    assert bench.share_at_no_object(final_views, 1) is None, "no tries"
    assert bench.share_at_no_object(final_views, 2) == 0.0, "its two failures ended at another object"
    assert bench.share_at_no_object(None, 0) is None, "not measured"
    assert bench.missed_by_cm([0.0412, None], 0) == 4.1, "the median miss in cm"
    assert bench.missed_by_cm([0.0412, None], 1) is None, "every try ended at an object"
    assert bench.missed_by_cm(None, 0) is None, "not measured"


def test_labelling_goes_on_past_the_triplet_target_until_every_command_has_an_is_answer() -> None:
    plan = bench.Labelling(
        "mixed", 60, 0, 30, 4, 0.25, triplets_per_is_answer=108, triplets_per_pair_answer=24
    )
    answers = bench.Answers(commands=4)
    answers.shown.update({0, 1, 3})
    assert not plan.enough(1000, answers), "no example of command 2 yet"
    assert plan.answer_attempt(1000, answers), "so the robot's attempts are still answered"
    answers.shown.add(2)
    assert plan.enough(1000, answers) and not plan.enough(36, answers)
    assert answers.to_dict()["commands_with_an_is_answer"] == 4


def test_labelling_stops_where_one_more_answer_might_carry_the_labels_past_the_target() -> None:
    mixed = bench.Labelling(
        "mixed", 1000, 0, 30, 4, 0.25, triplets_per_is_answer=108, triplets_per_pair_answer=24
    )
    answers = bench.Answers(commands=4)
    answers.shown.update({0, 1, 2, 3})
    assert not mixed.enough(976, answers) and mixed.enough(977, answers), "a pair answer adds at most 24"
    assert mixed.answer_attempt(892, answers), "a yes (up to 108 triplets) still fits"
    assert not mixed.answer_attempt(893, answers), "it might not: pairs fill what is left"
    attempts_only = bench.Labelling("attempts", 1000, 0, 30, 4, 0.25, 7, 108, 24)
    assert not attempts_only.enough(892, answers) and attempts_only.enough(893, answers), "no pairs to fill"


def test_near_the_target_a_household_skips_the_attempts_that_show_no_command_it_still_lacks() -> None:
    plan = bench.Labelling(
        "mixed", 1000, 0, 30, 4, 0.25, 7, triplets_per_is_answer=108, triplets_per_pair_answer=24
    )
    answers = bench.Answers(commands=4)
    answers.shown.update({0, 1, 3})
    assert plan.worth_answering(892, answers, shows=0), "its answer fits under the target"
    assert not plan.worth_answering(893, answers, shows=0), "command 0 was shown: skipped, it might not fit"
    assert plan.worth_answering(976, answers, None) and not plan.worth_answering(977, answers, None), "24"
    assert plan.worth_answering(1000, answers, shows=2), "the command never shown is always answered"


def test_attempts_come_in_rounds_and_past_the_target_only_the_commands_never_shown_are_tried() -> None:
    plan = bench.Labelling("mixed", target=1000, views=0, attempts=30, attempts_per_request=4,
                           random_share=0.25, seed=7)  # fmt: skip
    answers = bench.Answers(commands=4)
    answers.shown.update({0, 3})
    below = plan.next_request(asked=8, triplets=999, answers=answers, names=WORDS)
    assert below == {"count": 4, "random_share": 0.25, "seed": 15}, "a round, random views beside it"
    at_target = plan.next_request(asked=12, triplets=1000, answers=answers, names=WORDS)
    assert at_target == {"count": 2, "random_share": 0.0, "commands": [WORDS[1], WORDS[2]], "seed": 19}
    last = plan.next_request(asked=29, triplets=1200, answers=answers, names=WORDS)
    assert last["count"] == 1, "never past --attempts"
    attempts_only = bench.Labelling("attempts", 1000, 0, 30, 4, 0.25)
    assert attempts_only.next_request(0, 0, answers, WORDS) == {"count": 4, "random_share": 0.0, "seed": None}


def test_near_the_target_only_the_commands_never_shown_are_tried_so_their_answers_stay_within_it() -> None:
    six_clips_each = {clip: clip % 4 for clip in range(24)}
    assert bench.triplets_per_is_answer(six_clips_each) == 6 * 18, "a yes: 6 positives, each against 18"
    assert bench.triplets_per_is_answer({1: 0, 2: 0, 3: 1}) == 2, "the command with the most recordings"
    plan = bench.Labelling("mixed", 1000, 0, 30, 4, 0.25, triplets_per_is_answer=108)
    answers = bench.Answers(commands=4)
    answers.shown.update({0, 3})
    assert not plan.near_target(783, answers) and plan.near_target(784, answers), "1000 - 2 x 108"
    near = plan.next_request(asked=8, triplets=800, answers=answers, names=WORDS)
    assert near["commands"] == [WORDS[1], WORDS[2]] and near["random_share"] == 0.0
    answers.shown.update({1, 2})
    assert not plan.near_target(999, answers), "every command shown: on to the target itself"
    assert plan.next_request(asked=10, triplets=999, answers=answers, names=WORDS)["count"] == 4


def test_the_policys_training_curve_is_summed_up_by_the_mean_of_each_quarter_of_its_updates() -> None:
    assert bench.mean_by_quarter([0.2, 0.4, 0.5, 0.5, 0.6, None, 0.8, 1.0]) == [0.3, 0.5, 0.6, 0.9]
    assert bench.mean_by_quarter([0.7]) == [None, None, None, 0.7], "one update: its point is the last"
    assert bench.mean_by_quarter([]) == [None] * 4


def test_a_run_that_does_not_end_in_time_says_where_to_look(
    stack: bench.Stack, folders: tuple[Path, Path], tmp_path: Path
) -> None:
    options = ["--labelling", "views", "--views", "20", "--household", "waiting", "--run-timeout-s", "0"]
    with pytest.raises(
        SystemExit, match=r"run \d+ was still (queued|running) .* after 0 s: see the training"
    ):
        _run(stack, folders[0], tmp_path / "late.json", *options)
    assert not (tmp_path / "late.json").exists(), "no result is written for a run that did not end"


def test_a_sigterm_mid_fine_tune_stops_the_bench_and_every_process_it_started(
    folders: tuple[Path, Path], tmp_path: Path
) -> None:
    clips, base_models = folders
    still_training = "--run-param=policy_steps=5000000"  # after TINY's, so it wins
    options = ["--clips", str(clips), "--triplets", "60", "--preset", "quick", *TINY_PARAMS, still_training]
    options += ["--base-models", str(base_models), "--out", str(tmp_path / "never.json")]
    launched = subprocess.Popen(
        [sys.executable, "bench/household.py", *options],
        cwd=Path(__file__).resolve().parents[2],
        env={**os.environ, "TMPDIR": str(tmp_path)},  # where the bench makes its stack's folder
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        wait_until(
            lambda: _policy_training(launched.pid) or launched.poll() is not None,
            240,
            "the fine-tune's policy stage (its environment workers)",
        )
        assert launched.poll() is None, launched.stderr.read().decode()
        started = psutil.Process(launched.pid).children(recursive=True)
        assert any(p.cmdline()[-2:] == ["--queue", "training"] for p in started)
        launched.send_signal(signal.SIGTERM)
        assert launched.wait(60) != 0
        _, alive = psutil.wait_procs(started, timeout=30)
        assert not alive, f"still running after the bench stopped: {[p.cmdline() for p in alive]}"
        assert "stopped by signal 15" in launched.stderr.read().decode()
    finally:
        launched.kill()


def _policy_training(bench_pid: int) -> bool:
    """The training worker's environment workers run (forkserver children, the policy stage)."""
    with contextlib.suppress(psutil.Error):
        return any(
            "multiprocessing.forkserver" in " ".join(p.cmdline())
            for p in psutil.Process(bench_pid).children(True)
        )
    return False


@pytest.mark.parametrize(
    ("names", "said"),
    [
        ([], "no .wav files in it"),
        (["anna.wav"], "anna.wav is not named <member>_<intent index>.wav"),
        (["anna_0.wav", "anna_7.wav"], "names intent 7, but the world has intents 0 to 3"),
        (["anna_0.wav", "bob_1_2.wav"], "no recording of intent 2, 3"),
    ],
)
def test_a_badly_named_clip_folder_says_what_is_wrong(tmp_path: Path, names: list[str], said: str) -> None:
    for name in names:
        (tmp_path / name).write_bytes(b"RIFF")
    with pytest.raises(SystemExit, match=said):
        bench.recordings_from_folder(tmp_path, 4)


def test_a_good_clip_folder_gives_members_and_takes(tmp_path: Path) -> None:
    for name in ("anna_0.wav", "anna_1_2.wav", "big_bob_2.wav", "big_bob_3.WAV", "notes.txt"):
        (tmp_path / name).write_bytes(b"RIFF")
    found = bench.recordings_from_folder(tmp_path, 4)
    assert [(r.member, r.intent) for r in found] == [("anna", 0), ("anna", 1), ("big_bob", 2), ("big_bob", 3)]
