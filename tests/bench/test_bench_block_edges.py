"""bench/block_edges.py: its scan puts the gripper where it says, so the ray's verdict traces the real block,
and each try's end falls in the class its last view and offset say."""

import json

import block_edges as bench
import numpy as np
import pytest

from learning.audio import feature_shape
from learning.rl.ppo import load_policy
from learning.rl.rewards import ClipBank
from learning.var.checkpoint import load_var
from sim.blocks import BLOCK_SIZE_M
from worker.base_models import find_base

BLOCK = BLOCK_SIZE_M[:2]


@pytest.fixture(scope="module")
def models() -> bench.Models:
    """The shipped Kuka base with made-up clips: the VAR's calls mean nothing, the ray and the tries do."""
    base = find_base("kuka")
    var = load_var(base.var_path)
    policy, _ = load_policy(base.policy_path)
    rng = np.random.default_rng(0)
    frames, values = feature_shape("speech", var.front_end)
    bank = ClipBank(rng.normal(size=(8, frames, values)).astype(np.float32), np.arange(8) % 4)
    return bench.models_from(var, policy, bank, temperature=0.25)


def test_an_end_is_success_another_block_past_an_end_beside_or_elsewhere() -> None:
    assert bench.classify_end(np.array([0.07, 0.0]), heard=2, intent=2, block_m=BLOCK) == "success"
    assert bench.classify_end(np.array([0.0, 0.1]), heard=3, intent=2, block_m=BLOCK) == "another block"
    assert bench.classify_end(np.array([0.07, 0.005]), -1, 2, BLOCK) == "past an end of the target"
    assert bench.classify_end(np.array([-0.07, -0.01]), -1, 2, BLOCK) == "past an end of the target"
    assert bench.classify_end(np.array([0.01, 0.045]), -1, 2, BLOCK) == "beside the target"
    assert bench.classify_end(np.array([0.2, 0.05]), -1, 2, BLOCK) == "elsewhere"


def test_the_extent_spans_the_offsets_where_at_least_half_the_views_are_on_it() -> None:
    rows = [
        {"offset_cm": -2, "ray": 0.2}, {"offset_cm": -1, "ray": 0.5}, {"offset_cm": 0, "ray": 1.0},
        {"offset_cm": 1, "ray": 0.9}, {"offset_cm": 2, "ray": None},
    ]  # fmt: skip
    assert bench.extent_cm(rows, "ray") == [-1, 1]
    assert bench.extent_cm([{"offset_cm": 0, "ray": 0.0}], "ray") is None


def test_the_scan_traces_the_target_block_where_the_ray_finds_it(models: bench.Models) -> None:
    env = bench.make_world("kuka", "training", 96)
    try:
        profile = bench.scan(env, models, layouts=1, reach_cm=9, seed=3)
    finally:
        env.close()
    across = {row["offset_cm"]: row for row in profile["y"]}
    along = {row["offset_cm"]: row for row in profile["x"]}
    assert across[0]["views"] == 4 and across[0]["ray_on_target"] == 1.0
    assert across[-5]["ray_on_target"] == 0.0 and across[5]["ray_on_target"] == 0.0  # between the blocks
    assert along[4]["ray_on_target"] == 1.0 and along[-4]["ray_on_target"] == 1.0  # the long side
    assert all(
        row["ray_on_target"] == 0.0 for row in profile["x"] if abs(row["offset_cm"]) >= 8 and row["views"]
    )
    assert all(0.0 <= row["reward_mean"] <= 1.0 for row in profile["x"] if row["views"])


def test_each_try_ends_in_one_class_with_its_offset_from_the_target(models: bench.Models) -> None:
    env = bench.make_world("kuka", "training", 96)
    try:
        tries = bench.play(env, models, bench.protocol_tries(models, per_intent=1, seed=5))
    finally:
        env.close()
    assert sorted(t["intent"] for t in tries) == [0, 1, 2, 3]
    for end in tries:
        dx, dy = np.array(end["offset_cm"]) / 100
        assert end["end"] in bench.END_CLASSES
        if end["end"] == "success":
            assert abs(dy) <= BLOCK[1] / 2 + 0.01 and abs(dx) <= BLOCK[0] / 2 + 0.01 and end["touched_target"]
    summary = bench.summarise_tries(tries)
    assert sum(summary["ends"].values()) == 4


def test_a_gripper_driven_into_a_corner_of_the_workspace_is_at_its_edge() -> None:
    env = bench.make_world("kuka", "training", 32)
    try:
        env.reset(seed=0, options={"intent": 0})
        arm = env.unwrapped.arm
        assert not bench.at_workspace_edge(arm.target_xy), "the gripper starts inside the workspace"
        for _ in range(40):
            env.step(np.array([1.0, 1.0], dtype=np.float32))
        assert bench.at_workspace_edge(arm.target_xy)
    finally:
        env.close()


def test_the_summary_counts_the_failed_tries_that_ended_at_the_workspace_edge() -> None:
    tries = [
        {"intent": 0, "end": "success", "offset_cm": [0.0, 0.0], "touched_target": True,
         "at_workspace_edge": True},
        {"intent": 1, "end": "elsewhere", "offset_cm": [9.0, 16.0], "touched_target": False,
         "at_workspace_edge": True},
        {"intent": 2, "end": "beside the target", "offset_cm": [1.0, 2.5], "touched_target": True,
         "at_workspace_edge": False},
    ]  # fmt: skip
    summary = bench.summarise_tries(tries)
    assert summary["failed_at_workspace_edge"] == 1 and summary["failed_after_touching_target"] == 1


def test_a_recorded_evaluation_is_replayed_try_by_try_and_compared_with_its_record(
    models: bench.Models, tmp_path
) -> None:  # type: ignore[no-untyped-def]
    recorded = [
        {"intent": 2, "seed": 11, "goal_clip": 2, "success": True},
        {"intent": 0, "seed": 12, "goal_clip": 4, "success": False},
    ]
    path = tmp_path / "bench-eval-unheard-easy.json"
    path.write_text(json.dumps({"split": "unheard-easy", "episodes": recorded}))
    schedule = bench.stored_tries(path, "unheard-easy")
    assert [(t.intent, t.layout_seed, t.goal_clip) for t in schedule] == [(2, 11, 2), (0, 12, 4)]
    env = bench.make_world("kuka", "training", 96)
    try:
        tries = bench.play(env, models, schedule)
    finally:
        env.close()
    assert [t["intent"] for t in tries] == [2, 0]
    assert all(len(t["start_xy_m"]) == 2 for t in tries)
    agreeing = sum((t["end"] == "success") == r["success"] for t, r in zip(tries, recorded, strict=True))
    assert bench.summarise_tries(tries)["agrees_with_stored"] == agreeing


def test_a_recorded_evaluation_of_another_tier_is_refused(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "bench-eval-unheard-real-voices.json"
    path.write_text(json.dumps({"split": "unheard-real-voices", "episodes": []}))
    with pytest.raises(SystemExit, match="pass --tier unheard-real-voices"):
        bench.stored_tries(path, "unheard-easy")


def test_tries_not_replayed_from_a_record_say_nothing_about_agreement() -> None:
    tries = [{"intent": 0, "end": "success", "offset_cm": [0.0, 0.0], "touched_target": True}]
    assert "agrees_with_stored" not in bench.summarise_tries(tries)


def test_recorded_tries_are_replayed_only_in_the_room_they_were_played_in(capsys) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(SystemExit):
        bench.parse_args(
            ["--episodes-from", "bench-eval-unheard-easy.json", "--rooms", "training,unseen_room"]
        )
    assert "pass --rooms training" in capsys.readouterr().err
    args = bench.parse_args(["--episodes-from", "bench-eval-unheard-easy.json", "--rooms", "training"])
    assert args.episodes_from.name == "bench-eval-unheard-easy.json"


def test_the_summary_counts_tries_and_failures_by_where_the_gripper_started() -> None:
    tries = [
        {"intent": 0, "end": "success", "offset_cm": [0.0, 0.0], "touched_target": True,
         "start_xy_m": [0.6, 0.27]},
        {"intent": 3, "end": "elsewhere", "offset_cm": [9.0, 16.0], "touched_target": False,
         "start_xy_m": [0.55, 0.29]},
        {"intent": 1, "end": "success", "offset_cm": [0.0, 0.0], "touched_target": True,
         "start_xy_m": [0.6, -0.03]},
    ]  # fmt: skip
    assert bench.summarise_tries(tries)["by_start_y"] == {
        "-5 to +0 cm": {"tries": 1, "failed": 0},
        "+25 to +30 cm": {"tries": 2, "failed": 1},
    }


def test_sampled_actions_repeat_with_their_seed_and_leave_the_mean_path(models: bench.Models) -> None:
    schedule = [bench.Try(intent=1, layout_seed=21, goal_clip=1)]
    env = bench.make_world("kuka", "training", 96)
    try:
        mean_end = bench.play(env, models, schedule)[0]["offset_cm"]
        sampled_ends = [bench.play(env, models, schedule, sampled_seed=7)[0]["offset_cm"] for _ in range(2)]
    finally:
        env.close()
    assert sampled_ends[0] == sampled_ends[1]
    assert sampled_ends[0] != mean_end


def test_the_actions_default_to_the_evaluation_protocols_mean() -> None:
    assert bench.parse_args(["--rooms", "training"]).actions == "mean"
    assert bench.parse_args(["--rooms", "training", "--actions", "sampled"]).actions == "sampled"


def test_sampled_replays_are_not_compared_with_the_record_of_the_mean(models: bench.Models) -> None:
    schedule = [bench.Try(intent=2, layout_seed=11, goal_clip=2, stored_success=True)]
    env = bench.make_world("kuka", "training", 96)
    try:
        mean_tries = bench.play(env, models, schedule)
        sampled_tries = bench.play(env, models, schedule, sampled_seed=3)
    finally:
        env.close()
    assert "agrees_with_stored" in bench.summarise_tries(mean_tries)
    assert "agrees_with_stored" not in bench.summarise_tries(sampled_tries)
