"""The candidate's policy is the best of the self-improvement's checkpoints on validation episodes of their
own, not simply the last update's: one that forgot the simulator's training room is out, the rest compete
in the robot's room."""

import math

import pytest
from conftest import TINY, Household, wait_until

from backend.services.runs import minutes_here, resolve_params, selection_episodes
from worker.policy_selection import PolicyScore, choose, policies_to_compare


def _scores(*rows: tuple[float, float | None]) -> list[PolicyScore]:
    return [
        PolicyScore(25 * i, f"checkpoint_{25 * i:06d}.pt", own, home) for i, (own, home) in enumerate(rows)
    ]


def test_the_policy_best_in_the_robots_room_is_kept_even_when_it_is_not_the_last() -> None:
    selection = choose(_scores((0.60, 0.85), (0.70, 0.85), (0.80, 0.84), (0.72, 0.86)), episodes=100)
    assert selection.chosen.update == 50
    assert "kept the policy of update 50 of 75: 80% in the household's room" in selection.reason
    assert "(the last update's: 72%)" in selection.reason


def test_a_policy_that_forgot_the_training_room_is_out_however_well_it_does_in_the_robots_room() -> None:
    selection = choose(_scores((0.60, 0.85), (0.70, 0.84), (0.90, 0.55)), episodes=100)
    assert selection.chosen.update == 25 and selection.excluded_updates == [50]
    assert "updates 50 fell in the simulator's training room below the start's 85%" in selection.reason


def test_a_drop_within_the_noise_of_the_validation_episodes_does_not_rule_a_policy_out() -> None:
    selection = choose(_scores((0.60, 0.85), (0.90, 0.75)), episodes=40)
    assert selection.chosen.update == 25 and not selection.excluded_updates


def test_a_tie_goes_to_the_later_policy_and_the_start_wins_when_nothing_beat_it() -> None:
    assert choose(_scores((0.6, 0.8), (0.7, 0.8), (0.7, 0.8)), episodes=100).chosen.update == 50
    start_best = choose(_scores((0.8, 0.8), (0.6, 0.8)), episodes=100)
    assert start_best.chosen.update == 0 and "did not beat the policy it started from" in start_best.reason


def test_a_robot_in_the_training_room_is_scored_once_and_nothing_is_ruled_out_for_forgetting() -> None:
    selection = choose(_scores((0.6, None), (0.5, None), (0.7, None)), episodes=40)
    assert selection.chosen.update == 50 and not selection.excluded_updates


def test_the_start_every_numbered_checkpoint_and_a_final_one_between_them_compete(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import torch

    from learning.rl.checkpoints import CHECKPOINT_KIND, FORMAT_VERSION

    def checkpoint(name: str, update: int) -> None:
        payload = {"kind": CHECKPOINT_KIND, "format_version": FORMAT_VERSION, "update_index": update}
        torch.save(payload, tmp_path / name)

    for update in (25, 50):
        checkpoint(f"checkpoint_{update:06d}.pt", update)
    checkpoint("checkpoint.pt", 60)  # 60 updates: the last one is not a multiple of 25
    (tmp_path / "checkpoint_000025.pt.tmp").write_bytes(b"")  # a write cut short is no candidate
    start = tmp_path / "checkpoint_000000.pt"  # the trainer keeps the policy it starts from
    checkpoint(start.name, 0)
    assert policies_to_compare(tmp_path) == [
        (0, start),
        (25, tmp_path / "checkpoint_000025.pt"),
        (50, tmp_path / "checkpoint_000050.pt"),
        (60, tmp_path / "checkpoint.pt"),
    ]
    checkpoint("checkpoint.pt", 50)  # it ended on a numbered one: that file stands for it
    assert [update for update, _ in policies_to_compare(tmp_path)] == [0, 25, 50]


def test_the_thorough_presets_budget_counts_its_validation_episodes() -> None:
    thorough = resolve_params("thorough", {})
    assert thorough.policy_selection_episodes == 40
    # the start, 5 numbered checkpoints over 100,000 steps, 2 rooms
    assert selection_episodes(thorough) == 6 * 2 * 40
    unscored = resolve_params("thorough", {"policy_selection_episodes": 0})
    assert selection_episodes(unscored) == 0 and minutes_here(unscored) < minutes_here(thorough)
    assert resolve_params("quick", {}).policy_selection_episodes == 0


def _answer_views_until_every_command_was_seen(household: Household, robot: int, batches: int = 12) -> None:
    """Random views show a block about one time in ten: more of them, answered, until each command has an
    'is' answer (simulated success, and so the choice, needs one)."""
    answered = {snapshot["id"] for snapshot in household.snapshots(robot)}
    for _ in range(batches):
        seen = {snapshot["meta"].get("sim_heard") for snapshot in household.snapshots(robot)}
        if seen >= {0, 1, 2, 3}:
            return
        asked = household.client.post(f"/api/v1/robots/{robot}/snapshots:capture", json={"count": 60})
        assert asked.status_code == 202, asked.text

        def captured(wanted: int = len(answered) + 60) -> list[dict] | None:
            found = household.snapshots(robot)
            return found if len(found) >= wanted else None

        fresh = wait_until(captured, 120, "the new views")
        for snapshot in fresh:
            if snapshot["id"] not in answered:
                household.answer(snapshot)
                answered.add(snapshot["id"])
    raise AssertionError(f"{len(answered)} random views never showed every block")


def _succeeded(household: Household, robot: int, **params: object) -> dict:
    """A tiny fine-tune of `robot`, run to its end: it must succeed."""
    run = household.wait_run(household.start_run(robot, **TINY, **params)["id"], timeout=300)
    assert run["status"] == "succeeded", run["error"]
    return run


@pytest.mark.slow
@pytest.mark.speech
def test_a_fine_tune_in_a_held_out_room_chooses_its_policy_on_validation_episodes_in_both_rooms(
    household: Household, training_worker
) -> None:  # type: ignore[no-untyped-def]
    robot = household.new_robot("choosing-arm")
    _answer_views_until_every_command_was_seen(household, robot)
    household.client.patch(f"/api/v1/robots/{robot}", json={"settings": {"domain": "unseen_room"}})
    run = _succeeded(household, robot, policy_selection_episodes=4)
    selection = run["metrics"]["stages"]["policy_improve"]["selection"]
    # the tiny base keeps a checkpoint at every update: the start and both updates of 48 steps compete
    assert isinstance(selection, dict), selection
    assert [score["update"] for score in selection["scores"]] == [0, 1, 2]
    for score in selection["scores"]:
        for rate in (score["own_room"], score["training_room"]):
            assert 0 <= rate <= 1 and math.isclose(rate * 4, round(rate * 4)), "4 episodes a room"
    assert selection["chosen"] in selection["scores"] and selection["reason"].startswith("kept the policy")
    assert 0 < selection["wall_s"] < run["timings"]["stages_s"]["policy_improve"]
    assert run["metrics"]["stages"]["policy_improve"]["checkpoint"].endswith("final.pt")


@pytest.mark.slow
@pytest.mark.speech
def test_a_fine_tune_without_validation_episodes_keeps_the_last_update_and_says_so(
    household: Household, training_worker
) -> None:  # type: ignore[no-untyped-def]
    run = _succeeded(household, household.new_robot("last-update-arm"))
    assert run["metrics"]["stages"]["policy_improve"]["selection"] == (
        "the last update's policy was kept: policy_selection_episodes is 0"
    )
