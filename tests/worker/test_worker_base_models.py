"""Base models: checkpoints trained by the benchmarks become a world's base model with their record."""

import json
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

from varbot.cli import app
from worker.base_models import SHIPPED_DIR, find_base

SHIPPED = SHIPPED_DIR / "kuka"


def adopt(world: str, out: Path, record: Path) -> object:
    return CliRunner().invoke(
        app,
        [
            *("models", "adopt", "--world", world, "--out", str(out)),
            *(
                "--var",
                str(SHIPPED / "var.pt"),
                "--policy",
                str(SHIPPED / "policy.pt"),
                "--record",
                str(record),
            ),
        ],
    )


@pytest.fixture
def record(tmp_path: Path) -> Path:
    path = tmp_path / "record.json"
    path.write_text(json.dumps({"command": "bench/reproduce.py --rows kuka-wordset:var", "success": 0.5}))
    return path


def test_adopted_checkpoints_become_the_base_model_with_their_record(
    tmp_path: Path, record: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    result = adopt("kuka", tmp_path / "models", record)
    assert result.exit_code == 0, result.output
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(tmp_path / "models"))
    base = find_base("kuka")
    assert base.folder == tmp_path / "models" / "kuka"
    assert base.record["success"] == 0.5 and base.record["image_size"] == 96
    assert base.record["adopted_from"]["policy"].endswith("policy.pt")
    assert set(base.record["file_bytes"]) == {"var.pt", "policy.pt"}


def test_a_policy_of_another_world_is_refused(tmp_path: Path, record: Path) -> None:
    result = adopt("turtlebot", tmp_path / "models", record)
    assert result.exit_code == 2 and "trained in the kuka world" in result.output
    assert not (tmp_path / "models" / "turtlebot").exists()


def test_a_base_build_over_randomised_rooms_resumes_from_its_checkpoints(tmp_path: Path) -> None:
    """The long base-model run is resumable: the same recipe run again (here: with more policy steps) reuses
    the views, does not retrain the VAR and continues the policy from its checkpoint."""
    from learning.sounds.build import build_corpora
    from worker.base_models import BaseModel, BaseRecipe, build_base

    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    tiny_ppo = {
        "num_envs": 2, "env_groups": 1, "num_steps": 12, "num_minibatches": 2, "update_epochs": 1,
        "checkpoint_every": 1, "max_episode_steps": 5, "policy_image_size": 16,
    }  # fmt: skip
    recipe = BaseRecipe(
        views=200, image_size=16, var_max_steps=3, policy_steps=24, eval_episodes_per_intent=1,
        eval_rooms=("training", "unseen_room"), ppo_settings=tiny_ppo,
    )  # fmt: skip
    first = build_base(recipe, tmp_path / "models", progress=False)
    again = build_base(replace(recipe, policy_steps=48), tmp_path / "models", progress=False)

    assert (first["policy_env_steps"], again["policy_env_steps"]) == (24, 48)
    assert again["var_steps"] == first["var_steps"] == 3, "the VAR was not trained again"
    assert again["timings"]["collect_s"] < first["timings"]["collect_s"] * 1.5, "the views were reused"
    assert again["timings"]["policy_train_s"] > first["timings"]["policy_train_s"], "stage times add up"
    policy_dir = _work(recipe) / recipe.policy_folder
    updates = [json.loads(line)["update"] for line in (policy_dir / "metrics.jsonl").open()]
    assert updates == [1, 2], "one update of 24 steps, then the second run continued with update 2"
    assert again["recipe"]["room"] == "randomised" and again["room_ranges"]["camera_jitter_m"] > 0
    assert again["policy_config"]["room"] == "randomised", "the policy's worlds drew rooms from the ranges"
    assert json.loads((policy_dir / "config.json").read_text())["room"] == "randomised"
    assert set(again["evaluation"]) == {"training", "unseen_room"}
    assert set(again["evaluation"]["unseen_room"]) >= {"unheard-easy", "unheard-real-voices"}
    for cell in (cell for cells in again["evaluation"].values() for cell in cells.values()):
        ended = cell["final_view_by_intent"]
        assert [len(row) for row in ended] == [5] * 4, "each goal: ended at block 0..3 or at none"
        assert sum(map(sum, ended)) == cell["episodes"], "every episode ended somewhere"
    record = BaseModel("kuka", tmp_path / "models" / "kuka").record
    assert record["front_end"] == "mfcc" and record["timings"]["total_s"] > 0


def _work(recipe) -> Path:  # type: ignore[no-untyped-def]
    from core.paths import data_dir

    return data_dir() / "base_build" / recipe.name


def test_show_names_each_worlds_base_model_with_its_rooms_and_front_end(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # nothing built on this machine, so the shipped models are what a household starts from
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(tmp_path / "built"))
    monkeypatch.setenv("VARBOT_DATA_DIR", str(tmp_path / "data"))
    result = CliRunner().invoke(app, ["models", "show"])
    assert result.exit_code == 0, result.output
    kuka = json.loads((SHIPPED / "base.json").read_text())
    front_end = (
        f"speech-embedding-fast, refitted {kuka['refit']['refitted_at']} from speech-embedding; "
        f"policy replaced {kuka['policy_replaced']['replaced_at']}; "
        f"taught room invariance {kuka['room_invariance']['taught_at']}; "
        f"taught block ends {kuka['block_ends']['taught_at']}"
    )
    shown = f"kuka: {SHIPPED} ({kuka['built_at']}; trained in rooms: randomised; front end: {front_end})"
    assert shown in result.output
    turtlebot = SHIPPED_DIR / "turtlebot"
    record = json.loads((turtlebot / "base.json").read_text())
    front_end = (
        f"speech-embedding-fast, refitted {record['refit']['refitted_at']} from speech-embedding; "
        f"policy replaced {record['policy_replaced']['replaced_at']}"
    )
    shown = (
        f"turtlebot: {turtlebot} ({record['built_at']}; trained in rooms: randomised; front end: {front_end})"
    )
    assert shown in result.output
    kinova = SHIPPED_DIR / "kinova"
    record = json.loads((kinova / "base.json").read_text())
    front_end = "speech-embedding-fast"  # built on it: no refit
    shown = f"kinova: {kinova} ({record['built_at']}; trained in rooms: randomised; front end: {front_end})"
    assert shown in result.output


def test_show_says_how_to_build_a_world_that_has_no_base_model(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A deployment without the shipped folder (an image built without it, say) and nothing built here."""
    import worker.base_models

    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(tmp_path / "built"))
    monkeypatch.setenv("VARBOT_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setattr(worker.base_models, "SHIPPED_DIR", tmp_path / "not-shipped")
    result = CliRunner().invoke(app, ["models", "show"])
    assert result.exit_code == 0, result.output
    for world in ("kuka", "kinova", "turtlebot"):
        assert f"{world}: no base model for the {world} world" in result.output
        assert f"build one with `varbot models build-base --world {world}`" in result.output


def test_a_base_model_moves_to_the_fast_front_end_keeping_its_policy_and_image_encoder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`varbot models refit-front-end`: the same policy file and f_I, an f_S that reads the new front end's
    features and agrees with the old one on the training clips, evaluated again in the record's rooms; the
    old record is kept beside the new one."""
    import torch

    from learning.sounds.build import build_corpora
    from learning.var.checkpoint import load_var
    from worker.base_models import BaseRecipe, build_base

    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    tiny_ppo = {
        "num_envs": 2, "env_groups": 1, "num_steps": 12, "num_minibatches": 2, "update_epochs": 1,
        "max_episode_steps": 5, "policy_image_size": 16,
    }  # fmt: skip
    recipe = BaseRecipe(
        front_end="speech-embedding", views=200, image_size=16, var_max_steps=5, policy_steps=24,
        eval_episodes_per_intent=1, eval_rooms=("unseen_room",), ppo_settings=tiny_ppo,
    )  # fmt: skip
    build_base(recipe, tmp_path / "built", progress=False)
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(tmp_path / "built"))
    refit = [
        *("models", "refit-front-end", "--world", "kuka", "--front-end", "speech-embedding-fast"),
        *("--steps", "300", "--room-copies", "0", "--out", str(tmp_path / "refit")),
    ]
    result = CliRunner().invoke(app, refit)
    assert result.exit_code == 0, result.output

    old, new = tmp_path / "built" / "kuka", tmp_path / "refit" / "kuka"
    record = json.loads((new / "base.json").read_text())
    assert record["front_end"] == "speech-embedding-fast"
    assert record["before_refit"]["front_end"] == "speech-embedding"
    assert set(record["evaluation"]) == set(record["before_refit"]["evaluation"]) == {"unseen_room"}
    assert (new / "policy.pt").read_bytes() == (old / "policy.pt").read_bytes()
    teacher, student = load_var(old / "var.pt"), load_var(new / "var.pt", front_end="speech-embedding-fast")
    for name, weights in teacher.image_encoder.state_dict().items():
        assert torch.equal(student.image_encoder.state_dict()[name], weights), name
    assert record["refit"]["agreement"]["train"]["mean_cosine"] > 0.95
    assert record["refit"]["agreement"]["unheard-easy"]["clips"] > 0

    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(tmp_path / "refit"))
    again = CliRunner().invoke(app, [*refit[:6], "--out", str(tmp_path / "again")])
    assert again.exit_code == 2 and "already reads 'speech-embedding-fast' features" in again.output


def test_a_recipe_that_changes_only_the_policy_settings_shares_views_and_var_but_not_the_policy() -> None:
    from worker.base_models import BaseRecipe

    shipped_like = BaseRecipe()
    var_view = BaseRecipe(ppo_settings={"policy_view": "var", "goal_match": True})
    same_again = BaseRecipe(ppo_settings={"goal_match": True, "policy_view": "var"})
    assert var_view.name == shipped_like.name, "the views and the VAR are reused"
    assert shipped_like.policy_folder == "policy", "a recipe of the PPO defaults keeps its folder"
    assert var_view.policy_folder not in {
        "policy",
        BaseRecipe(ppo_settings={"goal_match": True}).policy_folder,
    }
    assert same_again.policy_folder == var_view.policy_folder


def test_a_recipe_over_changed_room_ranges_renders_new_views_and_trains_a_new_var(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import worker.base_models
    from core.rooms import RoomRanges
    from worker.base_models import BaseRecipe

    today = BaseRecipe().name
    assert today == BaseRecipe().name, "the same ranges resume the same work folder"
    assert BaseRecipe(room="training").room_label == "training"
    monkeypatch.setattr(worker.base_models, "world_room", lambda _: RoomRanges(object_textures=(None,)))
    assert BaseRecipe().name != today, "other ranges never resume the views or VAR of these"


def test_build_base_takes_ppo_settings_as_name_value_pairs_and_refuses_what_ppo_would() -> None:
    import typer

    from worker.cli import ppo_settings

    settings = ppo_settings(["policy_view=var", "goal_match=true", "reward_temperature=0.25"])
    assert settings == {"policy_view": "var", "goal_match": True, "reward_temperature": 0.25}
    with pytest.raises(typer.BadParameter, match="not NAME=VALUE with NAME a PPO setting"):
        ppo_settings(["policy_eyes=var"])
    with pytest.raises(typer.BadParameter, match="sees the real view"):
        ppo_settings(["policy_view=var", "policy_colour_jitter=0.3"])


TINY_PPO = {
    "num_envs": 2, "env_groups": 1, "num_steps": 12, "num_minibatches": 2, "update_epochs": 1,
    "max_episode_steps": 5, "policy_image_size": 16,
}  # fmt: skip


def _tiny_policy_run(run_dir: Path, var: Path, image_size: int, **settings: object) -> Path:
    from learning.rl.ppo import PPOConfig
    from learning.rl.run import train_run

    config = PPOConfig(image_size=image_size, total_steps=24, room="randomised", **TINY_PPO, **settings)
    train_run(config, run_dir, var, progress=False)
    return run_dir


def _tiny_base(out: Path) -> None:
    """A Kuka base at 16 px with a pixel policy, evaluated in `unseen_room` only, written to `out/kuka`."""
    from learning.sounds.build import build_corpora
    from worker.base_models import BaseRecipe, build_base

    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    recipe = BaseRecipe(
        views=200, image_size=16, var_max_steps=3, policy_steps=24, eval_episodes_per_intent=1,
        eval_rooms=("unseen_room",), ppo_settings=TINY_PPO,
    )  # fmt: skip
    build_base(recipe, out, progress=False)


def _tiny_base_seeing_through_var(out: Path, work: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`_tiny_base` with a policy that sees through its VAR, written to `out/kuka` and found there."""
    _tiny_base(work / "built")
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(work / "built"))
    run = _tiny_policy_run(work / "run", work / "built" / "kuka" / "var.pt", 16, policy_view="var")
    replace = ["models", "replace-policy", "--world", "kuka", "--run-dir", str(run)]
    assert CliRunner().invoke(app, [*replace, "--out", str(out)]).exit_code == 0
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(out))


def test_a_base_model_takes_a_policy_trained_on_its_var_and_keeps_the_old_policys_figures(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`varbot models replace-policy`: the same VAR file, the run's policy and curves, evaluated again in the
    record's rooms with its seed; the old policy's settings and evaluation stay in the record."""
    from learning.rl.checkpoints import read_policy_checkpoint

    _tiny_base(tmp_path / "built")
    old = tmp_path / "built" / "kuka"
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(tmp_path / "built"))
    run = _tiny_policy_run(tmp_path / "run", old / "var.pt", 16, policy_view="var", goal_match=True)
    replace = ["models", "replace-policy", "--world", "kuka", "--run-dir", str(run)]
    result = CliRunner().invoke(app, [*replace, "--out", str(tmp_path / "new")])
    assert result.exit_code == 0, result.output

    new = tmp_path / "new" / "kuka"
    assert (new / "var.pt").read_bytes() == (old / "var.pt").read_bytes()
    assert read_policy_checkpoint(new / "policy.pt")["policy_config"]["view_var"] is not None
    assert (new / "policy_curves.png").read_bytes() == (run / "curves.png").read_bytes()
    record = json.loads((new / "base.json").read_text())
    before = json.loads((old / "base.json").read_text())
    assert record["policy_config"]["policy_view"] == "var" and "var_path" not in record["policy_config"]
    assert record["before_policy_replaced"]["policy_config"] == before["policy_config"]
    assert record["before_policy_replaced"]["evaluation"] == before["evaluation"]
    assert set(record["evaluation"]["unseen_room"]) == set(before["evaluation"]["unseen_room"])
    assert record["policy_env_steps"] == 24 and record["var_steps"] == before["var_steps"]
    assert record["policy_replaced"]["trained_with"]["var_path"] == str(old / "var.pt")
    assert record["policy_replaced"]["policy_room_ranges"] == record["room_ranges"], "today's ranges both"
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(tmp_path / "new"))
    shown = CliRunner().invoke(app, ["models", "show"]).output
    assert f"policy replaced {record['policy_replaced']['replaced_at']}" in shown


def test_a_policy_trained_on_another_var_or_not_finished_is_refused_and_nothing_is_written(
    tmp_path: Path,
) -> None:
    """The shipped base is the one found here; a policy trained beside another VAR would be paid by a
    reward its VAR no longer gives."""
    from learning.sounds.build import build_corpora

    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    other_var = tmp_path / "other_var.pt"
    other_var.write_bytes((SHIPPED_DIR / "turtlebot" / "var.pt").read_bytes())
    run = _tiny_policy_run(tmp_path / "run", other_var, 96)
    replace = ["models", "replace-policy", "--world", "kuka", "--out", str(tmp_path / "new")]
    result = CliRunner().invoke(app, [*replace, "--run-dir", str(run)], env={"COLUMNS": "300"})
    assert result.exit_code == 2 and "was trained with the VAR" in result.output
    assert "train it with `varbot rl train --var" in result.output
    (tmp_path / "unfinished").mkdir()
    result = CliRunner().invoke(app, [*replace, "--run-dir", str(tmp_path / "unfinished")])
    assert result.exit_code == 2 and "no finished policy run" in result.output
    assert not (tmp_path / "new" / "kuka").exists()


def test_a_replacement_that_fails_half_way_leaves_no_half_written_base(tmp_path: Path) -> None:
    """A run folder whose checkpoint is not a policy: refused while the new base is being written, and
    neither the base's folder nor its staging copy is left behind."""
    import torch

    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(
        json.dumps({"world": "kuka", "room": "randomised", "var_path": str(find_base("kuka").var_path)})
    )
    (run / "summary.json").write_text(json.dumps({"env_steps": 24, "recent_success": 0.0}))
    torch.save({"kind": "varbot-var"}, run / "checkpoint.pt")
    replace = ["models", "replace-policy", "--world", "kuka", "--run-dir", str(run)]
    result = CliRunner().invoke(app, [*replace, "--out", str(tmp_path / "new")], env={"COLUMNS": "300"})
    assert result.exit_code == 2 and "not a varbot policy checkpoint" in result.output
    assert list((tmp_path / "new").iterdir()) == [], "nothing half-written"


def test_a_base_model_learns_to_see_any_room_of_its_ranges_as_its_training_room(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`varbot models room-invariance`: the image encoder, taught on pairs of renders of one scene (a drawn
    room, the world's own look), agrees better with what it gave for the own look; the VAR and the policy's
    frozen view get the same new weights, while f_S, the sphere's last layer and the rest of the policy stay;
    the evaluation before is kept."""
    import torch

    from learning.rl.checkpoints import read_policy_checkpoint
    from learning.var.checkpoint import load_var

    _tiny_base_seeing_through_var(tmp_path / "viewing", tmp_path, monkeypatch)
    teach = ["models", "room-invariance", "--world", "kuka", "--views", "480", "--steps", "80"]
    result = CliRunner().invoke(app, [*teach, "--out", str(tmp_path / "new")])
    assert result.exit_code == 0, result.output

    old, new = tmp_path / "viewing" / "kuka", tmp_path / "new" / "kuka"
    record, before = (json.loads((folder / "base.json").read_text()) for folder in (new, old))
    taught = record["room_invariance"]
    assert (
        taught["agreement_after"]["other_rooms_hidden_error"]
        < taught["agreement_before"]["other_rooms_hidden_error"]
    )
    assert record["before_room_invariance"]["evaluation"] == before["evaluation"]
    pair_ranges = taught["pairs_recipe"]["room_ranges"]
    assert "checker" not in pair_ranges["floor_textures"] + pair_ranges["object_textures"], "held out"
    assert set(record["evaluation"]) == {"unseen_room"}
    teacher, student = load_var(old / "var.pt"), load_var(new / "var.pt")
    policy = read_policy_checkpoint(new / "policy.pt")["policy"]
    old_policy = read_policy_checkpoint(old / "policy.pt")["policy"]
    for name, weights in student.image_encoder.state_dict().items():
        assert torch.equal(policy[f"var_view.encoder.{name}"], weights), "the policy sees through the student"
    assert not torch.equal(
        student.image_encoder.features[0][0].weight, teacher.image_encoder.features[0][0].weight
    )
    assert torch.equal(student.image_encoder.head[-1].weight, teacher.image_encoder.head[-1].weight)
    for name, weights in teacher.sound_encoder.state_dict().items():
        assert torch.equal(student.sound_encoder.state_dict()[name], weights), name
    for name, weights in old_policy.items():
        if not name.startswith("var_view."):
            assert torch.equal(policy[name], weights), name
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(tmp_path / "new"))
    shown = CliRunner().invoke(app, ["models", "show"]).output
    assert f"taught room invariance {taught['taught_at']}" in shown


def test_a_base_model_learns_where_its_blocks_end_in_its_var_and_its_policys_view_alike(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`varbot models block-ends`: the VAR is fine-tuned on views around the blocks' ends (and random ones
    replayed) in the rooms the base was trained over; the policy sees through the new image encoder and keeps
    everything else; the evaluation before is kept, and `models show` says when it was taught."""
    import torch

    from learning.rl.checkpoints import read_policy_checkpoint
    from learning.var.checkpoint import load_var

    _tiny_base_seeing_through_var(tmp_path / "viewing", tmp_path, monkeypatch)
    teach = [
        "models",
        "block-ends",
        "--world",
        "kuka",
        "--views",
        "96",
        "--replay-views",
        "96",
        "--epochs",
        "1",
    ]
    result = CliRunner().invoke(app, [*teach, "--out", str(tmp_path / "new")])
    assert result.exit_code == 0, result.output

    old, new = tmp_path / "viewing" / "kuka", tmp_path / "new" / "kuka"
    record, before = (json.loads((folder / "base.json").read_text()) for folder in (new, old))
    taught = record["block_ends"]
    assert taught["config"]["views"] == 96 and taught["best_held_out_accuracy"] is not None
    assert sum(taught["block_end_views_heard"].values()) == 96 and "-1" in taught["block_end_views_heard"]
    assert record["before_block_ends"]["evaluation"] == before["evaluation"]
    assert set(record["evaluation"]) == {"unseen_room"}
    teacher, student = load_var(old / "var.pt"), load_var(new / "var.pt")
    assert not torch.equal(
        student.image_encoder.features[0][0].weight, teacher.image_encoder.features[0][0].weight
    )
    policy = read_policy_checkpoint(new / "policy.pt")["policy"]
    old_policy = read_policy_checkpoint(old / "policy.pt")["policy"]
    for name, weights in student.image_encoder.state_dict().items():
        assert torch.equal(policy[f"var_view.encoder.{name}"], weights), "the policy sees through the new VAR"
    for name, weights in old_policy.items():
        if not name.startswith("var_view."):
            assert torch.equal(policy[name], weights), name
    monkeypatch.setenv("VARBOT_BASE_MODELS_DIR", str(tmp_path / "new"))
    shown = CliRunner().invoke(app, ["models", "show"]).output
    assert f"taught block ends {taught['taught_at']}" in shown
    again = CliRunner().invoke(app, [*teach, "--out", str(tmp_path / "again")])
    assert again.exit_code == 0, again.output
    retaught = load_var(tmp_path / "again" / "kuka" / "var.pt")
    assert not torch.equal(  # a fine-tune of the taught VAR, not the first run's result found again
        retaught.image_encoder.features[0][0].weight, student.image_encoder.features[0][0].weight
    )


@pytest.mark.parametrize(
    ("world", "reason"), [("turtlebot", "has no blocks whose ends"), ("kinova", "sees through its own CNN")]
)
def test_block_ends_are_refused_where_they_cannot_work_before_anything_is_rendered(
    world: str, reason: str, tmp_path: Path
) -> None:
    """The TurtleBot's arena has no blocks; the shipped Kinova policy has its own CNN, which the VAR's new
    weights would not reach."""
    from core.paths import data_dir

    teach = ["models", "block-ends", "--world", world, "--out", str(tmp_path / "new")]
    result = CliRunner().invoke(app, teach, env={"COLUMNS": "300"})
    assert result.exit_code == 2 and reason in result.output
    assert not (tmp_path / "new").exists()
    assert not (data_dir() / "block_ends" / world).exists(), "refused before rendering"


@pytest.mark.parametrize(
    ("world", "reason"),
    [("turtlebot", "cannot render a scene in another room"), ("kinova", "sees through its own CNN")],
)
def test_room_invariance_is_refused_where_it_cannot_work_before_anything_is_rendered(
    world: str, reason: str, tmp_path: Path
) -> None:
    """The TurtleBot's env cannot render one scene in two rooms; the shipped Kinova policy has its own CNN,
    which the VAR's new weights would not reach."""
    from core.paths import data_dir

    teach = ["models", "room-invariance", "--world", world, "--out", str(tmp_path / "new")]
    result = CliRunner().invoke(app, teach, env={"COLUMNS": "300"})
    assert result.exit_code == 2 and reason in result.output
    assert not (tmp_path / "new").exists()
    assert not (data_dir() / "room_pairs" / world).exists(), "refused before rendering"
