"""A policy that sees through the VAR (`--policy-view var`): it reads a frozen copy of the VAR's image encoder
up to its hidden layer instead of training a CNN of its own, keeps that copy through updates, checkpoints
and a later VAR, and acts and is evaluated like any other policy."""

from pathlib import Path

import numpy as np
import pytest
import torch
from rl_helpers import IMAGE, tiny_config

from learning.rl.checkpoints import load_initial_policy, load_policy
from learning.rl.evaluate import evaluate
from learning.rl.frozen_var import load_frozen_var
from learning.rl.ppo import PPOConfig, PPOTrainer
from learning.rl.rewards import ClipBank
from learning.var.checkpoint import save_var
from learning.var.model import VAR, VARConfig
from learning.var.room_adaptation import CHECKPOINT_KEY, adapt_to_room, with_statistics

pytestmark = [pytest.mark.slow, pytest.mark.speech]


def var_file(folder: Path, seed: int) -> Path:
    torch.manual_seed(seed)
    return save_var(VAR(VARConfig(image_size=IMAGE)).eval(), folder / f"var-{seed}.pt")


def adapted_var_file(folder: Path) -> Path:
    """A VAR adapted to a dark room, keeping the base's statistics as `worker.room_adaptation` does."""
    torch.manual_seed(0)
    var = VAR(VARConfig(image_size=IMAGE)).eval()
    room = np.random.default_rng(0).integers(0, 90, (64, IMAGE, IMAGE, 3), dtype=np.uint8)
    adaptation = adapt_to_room(var.image_encoder, room, share=1.0)
    record = {**adaptation.to_dict(), "statistics_before": adaptation.statistics_before}
    return save_var(var, folder / "adapted.pt", **{CHECKPOINT_KEY: record})


def started(
    config: PPOConfig, run_dir: Path, var_path: Path, clips: ClipBank, **kwargs: object
) -> PPOTrainer:
    trainer = PPOTrainer(
        config, run_dir, load_frozen_var(var_path), ClipBank(clips.features, clips.intents), **kwargs
    )
    trainer.start()
    return trainer


def frozen_copy(trainer: PPOTrainer) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in trainer.policy.var_view.encoder.state_dict().items()}


def test_the_policy_reads_the_vars_hidden_layer_and_never_changes_its_copy(
    tmp_path: Path, goal_clips: ClipBank
) -> None:
    var_path = var_file(tmp_path, 0)
    var = load_frozen_var(var_path).model
    views = torch.randint(0, 256, (3, IMAGE, IMAGE, 3), dtype=torch.uint8)
    trainer = started(tiny_config(policy_view="var"), tmp_path / "run", var_path, goal_clips)
    try:
        trainer.reset_envs()
        before = frozen_copy(trainer)
        buf, _ = trainer.collect_rollout()
        with torch.no_grad():  # the update sees what the rollout acted on
            goal = trainer.goal_source.features(trainer.policy, buf.goal)
            mean, _, _ = trainer.policy.evaluate_sequences(
                buf.images, buf.var_embedding, buf.state, goal, buf.initial_hidden, buf.episode_start
            )
            logprob = trainer.policy.distribution(mean).log_prob(buf.actions).sum(-1)
        trainer.update(buf)
    finally:
        trainer.close()
    assert buf.images.dtype == torch.float32 and buf.images.shape[2:] == (VARConfig().hidden,)
    torch.testing.assert_close(logprob, buf.logprobs, atol=1e-4, rtol=0)
    after = frozen_copy(trainer)
    assert all(torch.equal(before[k], after[k]) for k in before)  # weights and batch-norm statistics
    with torch.no_grad():
        torch.testing.assert_close(trainer.policy.view_of(views), var.image_encoder.hidden(views))


def test_one_pass_of_its_own_var_gives_the_reward_embedding_and_the_policys_view(
    tmp_path: Path, goal_clips: ClipBank
) -> None:
    var_path = var_file(tmp_path, 0)
    shared = started(tiny_config(policy_view="var"), tmp_path / "shared", var_path, goal_clips)
    apart = started(tiny_config(policy_view="var"), tmp_path / "apart", var_path, goal_clips)
    apart._policy_sees_this_var = lambda: False  # type: ignore[method-assign]
    try:
        shared.reset_envs()
        apart.reset_envs()
    finally:
        shared.close()
        apart.close()
    assert shared.policy_sees_var and not apart.policy_sees_var
    torch.testing.assert_close(shared.next_policy_images, apart.next_policy_images)
    torch.testing.assert_close(shared.next_var, apart.next_var)


def test_its_checkpoint_keeps_the_copy_it_was_trained_with_when_a_later_var_drives_the_run(
    tmp_path: Path, goal_clips: ClipBank
) -> None:
    base = started(tiny_config(policy_view="var"), tmp_path / "base", var_file(tmp_path, 0), goal_clips)
    try:
        base.reset_envs()
        base.update(base.collect_rollout()[0])
        base.save_checkpoint()
    finally:
        base.close()
    policy, _ = load_policy(base.checkpoint_path)
    household_var = var_file(tmp_path, 1)  # a household's fine-tuned VAR: other weights, same shape
    later = started(
        tiny_config(policy_view="var", seed=4), tmp_path / "later", household_var, goal_clips,
        init_policy=base.checkpoint_path,
    )  # fmt: skip
    later.close()
    for name, value in policy.var_view.encoder.state_dict().items():
        assert torch.equal(later.policy.var_view.encoder.state_dict()[name], value)
    views = torch.randint(0, 256, (3, IMAGE, IMAGE, 3), dtype=torch.uint8)
    torch.testing.assert_close(policy.view_of(views), base.policy.view_of(views))
    load_initial_policy(later.policy, base.checkpoint_path)  # the same network: accepted


def test_told_to_follow_the_run_s_var_a_loaded_policy_sees_through_the_household_s_var(
    tmp_path: Path, goal_clips: ClipBank
) -> None:
    base = started(tiny_config(policy_view="var"), tmp_path / "base", var_file(tmp_path, 0), goal_clips)
    base.close()
    base.save_checkpoint()
    household_var = var_file(tmp_path, 1)
    follows = started(
        tiny_config(policy_view="var", policy_view_follows_var=True), tmp_path / "follows", household_var,
        goal_clips, init_policy=base.checkpoint_path,
    )  # fmt: skip
    try:
        follows.reset_envs()
    finally:
        follows.close()
    assert follows.policy_sees_var, "one f_I pass again: the policy's view is the run's VAR"
    views = torch.randint(0, 256, (3, IMAGE, IMAGE, 3), dtype=torch.uint8)
    with torch.no_grad():
        wanted = load_frozen_var(household_var).model.image_encoder.hidden(views)
        torch.testing.assert_close(follows.policy.view_of(views), wanted)
    for name, value in base.policy.state_dict().items():  # everything after the view is the base policy's
        if not name.startswith("var_view."):
            assert torch.equal(follows.policy.state_dict()[name], value), name


def test_replay_environments_are_seen_through_an_adapted_var_by_the_base_statistics(
    tmp_path: Path, goal_clips: ClipBank
) -> None:
    var_path = adapted_var_file(tmp_path)
    config = tiny_config(
        policy_view="var", num_envs=4, env_groups=2, room="unseen_room", replay_envs=1,
        replay_room="randomised",
    )  # fmt: skip
    trainer = started(config, tmp_path / "run", var_path, goal_clips)
    views = np.random.default_rng(1).integers(0, 256, (4, IMAGE, IMAGE, 3), dtype=np.uint8)
    envs = np.array([3, 0, 3, 1])  # environment 3 is the replay one
    try:
        trainer.reset_envs()
        trainer.update(trainer.collect_rollout()[0])
        with torch.inference_mode():
            embedded, hidden = trainer._see(views, envs)
    finally:
        trainer.close()
    loaded = load_frozen_var(var_path)
    base = with_statistics(loaded.model, loaded.base_statistics)
    pixels = torch.from_numpy(views)
    with torch.no_grad():
        own_embedded, own_hidden = loaded.model.encode_image_and_hidden(pixels)
        base_embedded, base_hidden = base.encode_image_and_hidden(pixels)
    replayed = envs == 3
    for seen, own, by_base in ((embedded, own_embedded, base_embedded), (hidden, own_hidden, base_hidden)):
        torch.testing.assert_close(seen[replayed], by_base[replayed], atol=1e-4, rtol=1e-4)
        torch.testing.assert_close(seen[~replayed], own[~replayed], atol=1e-4, rtol=1e-4)
        assert not torch.allclose(own[replayed], by_base[replayed], atol=1e-3)


def test_it_is_evaluated_like_any_policy(tmp_path: Path, goal_clips: ClipBank) -> None:
    var_path = var_file(tmp_path, 0)
    trainer = started(tiny_config(policy_view="var"), tmp_path / "run", var_path, goal_clips)
    trainer.close()
    var = load_frozen_var(var_path).model
    bank = ClipBank(goal_clips.features, goal_clips.intents).embed(var)
    result = evaluate(
        trainer.policy, var, bank, "kuka", IMAGE, split="train",
        episodes_per_intent=1, num_envs=2, max_steps=3, progress=False,
    )  # fmt: skip
    assert len(result.episodes) == 4


def test_a_policy_that_sees_through_the_var_refuses_changes_of_its_pixels() -> None:
    with pytest.raises(ValueError, match="sees the real view"):
        PPOConfig(policy_view="var", policy_colour_jitter=0.3).validate()
    with pytest.raises(ValueError, match="needs the VAR"):
        PPOConfig(policy_view="var", goal_encoder="learned", reward="sparse").validate()
    with pytest.raises(ValueError, match="'pixels' or 'var'"):
        PPOConfig(policy_view="eyes").validate()
    with pytest.raises(ValueError, match="for a policy that sees through the VAR"):
        PPOConfig(policy_view_follows_var=True).validate()
