"""Policy self-improvement happens where the household's robot is: in its own room, whatever rooms the base
model was trained in."""

import json
from dataclasses import asdict

from backend.services.runs import resolve_params
from core.rooms import ROOM_PRESETS, DomainShift, RoomRanges, room_setting, world_room
from learning.rl.ppo import PPOConfig
from worker.base_models import SHIPPED_DIR, BaseModel
from worker.policy_stage import improvement_config, own_room_success
from worker.run_context import recorded_ranges, run_param


def test_a_robot_in_a_held_out_room_improves_its_policy_in_that_room_not_in_the_base_models_rooms() -> None:
    base = PPOConfig(room="randomised", learning_rate=3e-4)
    room = ROOM_PRESETS["lamplit_room"]()
    config = improvement_config(base, steps=1600, seed=3, room=room, robot_env_context=None)
    assert world_room(config.room) == room
    assert (config.total_steps, config.seed, config.goal_split) == (1600, 3, "household")
    assert config.learning_rate == base.learning_rate / 3


def test_every_fine_tune_of_a_household_runs_at_a_third_of_the_base_models_learning_rate() -> None:
    base = PPOConfig(learning_rate=3e-4)
    first = improvement_config(base, 800, 0, None, None)
    second = improvement_config(first, 800, 1, None, None)
    third = improvement_config(second, 800, 2, None, None)
    assert first.learning_rate == second.learning_rate == third.learning_rate == base.learning_rate / 3


def test_a_run_can_ask_for_another_share_of_the_base_models_learning_rate_and_fine_tunes_keep_it() -> None:
    base = PPOConfig(learning_rate=3e-4)
    first = improvement_config(base, 800, 0, None, None, learning_rate_scale=1.0)
    second = improvement_config(first, 800, 1, None, None, learning_rate_scale=0.5)
    assert first.learning_rate == second.learning_rate == base.learning_rate
    assert resolve_params("standard", {}).policy_learning_rate_scale == 1 / 3, "a third by default"


def test_a_robot_in_the_training_room_improves_there() -> None:
    config = improvement_config(PPOConfig(room="randomised"), 800, 0, None, None)
    assert config.room == "training" and world_room(config.room) is None


def test_a_robots_own_room_survives_the_run_folder_so_a_resumed_run_has_the_same_settings() -> None:
    room = DomainShift(object_rgb=(0.2, 0.3, 0.9), light_direction=(0.3, -0.2, 0.9), floor_texture="noise")
    config = improvement_config(PPOConfig(), 800, 0, room, None)
    assert PPOConfig.from_dict(json.loads(json.dumps(asdict(config)))) == config
    assert world_room(room_setting(room)) == room


def test_a_quarter_of_the_environments_keep_practising_in_the_base_models_rooms() -> None:
    base = PPOConfig(room="randomised", num_envs=8)
    config = improvement_config(base, 800, 0, ROOM_PRESETS["unseen_room"](), None, replay_share=0.25)
    assert (config.replay_envs, config.replay_room) == (2, "randomised")
    assert world_room(config.room) == ROOM_PRESETS["unseen_room"]()


def test_a_second_fine_tune_replays_the_base_models_rooms_not_the_first_fine_tunes_room() -> None:
    lamplit = ROOM_PRESETS["lamplit_room"]()
    first = improvement_config(PPOConfig(room="randomised"), 800, 0, lamplit, None, 0.25)
    second = improvement_config(first, 800, 1, lamplit, None, 0.25)
    assert second.replay_room == "randomised" and second.replay_envs == 2


def test_a_base_model_is_replayed_in_the_ranges_its_record_keeps_not_in_todays_ranges() -> None:
    recorded = RoomRanges(object_textures=(None, "noise"), floor_textures=(None, "noise"))
    unseen = ROOM_PRESETS["unseen_room"]()
    first = improvement_config(PPOConfig(room="randomised"), 800, 0, unseen, None, 0.25, recorded)
    assert world_room(first.replay_room) == recorded != RoomRanges()
    assert (
        PPOConfig.from_dict(json.loads(json.dumps(asdict(first)))) == first
    )  # a resumed run replays them too
    second = improvement_config(first, 800, 1, unseen, None, 0.25)
    assert world_room(second.replay_room) == recorded


def test_a_base_model_trained_in_the_training_room_is_replayed_there() -> None:
    config = improvement_config(PPOConfig(room="training"), 800, 0, ROOM_PRESETS["unseen_room"](), None, 0.25)
    assert config.replay_room == "training"


def test_a_real_robot_has_no_simulated_rooms_to_replay() -> None:
    config = improvement_config(PPOConfig(room="randomised"), 800, 0, None, "in-process:arm-1", 0.25)
    assert (config.num_envs, config.replay_envs) == (1, 0)


def test_a_base_model_versions_record_gives_the_ranges_it_was_trained_over() -> None:
    shipped_record = BaseModel("kuka", SHIPPED_DIR / "kuka").record  # not find_base: tests ship their own
    shipped = recorded_ranges({"base_model": shipped_record})
    assert shipped is not None and shipped.object_textures == (None, "noise")  # before stripes and speckle
    assert recorded_ranges({"base_model": {"room_ranges": None}}) is None  # trained in the training room
    assert recorded_ranges({"var_finetune": {}}) is None  # a household's version: its config keeps them


def test_a_var_view_policy_follows_the_households_var_unless_told_not_to_and_a_cnn_is_unaffected() -> None:
    var_view = PPOConfig(room="randomised", policy_view="var", goal_match=True)
    assert improvement_config(var_view, 800, 0, None, None).policy_view_follows_var, "on by default"
    frozen = improvement_config(var_view, 800, 0, None, None, view_follows_var=False)
    assert not frozen.policy_view_follows_var
    assert resolve_params("standard", {}).policy_view_follows_var, "and so is the run parameter"
    pixels = improvement_config(PPOConfig(room="randomised"), 800, 0, None, None)
    assert not pixels.policy_view_follows_var
    pixels.validate()


def test_a_run_stored_before_a_parameter_existed_runs_with_todays_default_for_it() -> None:
    today = resolve_params("standard", {})
    for name in (
        "replay_fraction",
        "policy_replay_share",
        "policy_view_follows_var",
        "policy_learning_rate_scale",
    ):
        assert run_param({}, name) == getattr(today, name), name
    assert run_param({"policy_view_follows_var": False}, "policy_view_follows_var") is False, "a stored value"


def test_an_updates_success_in_the_households_room_leaves_out_the_replayed_rooms() -> None:
    split = {"recent_success": 0.6, "recent_success_by_room": {"own_room": 0.7, "replay_room": 0.3}}
    assert own_room_success(split) == 0.7
    assert own_room_success({"recent_success": 0.6}) == 0.6, "without replay every environment is its own"
