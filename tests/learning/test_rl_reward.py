"""The rewards of the RL stage, checked against values worked out by hand: the functions, the reward
strategies a run is given, and the intrinsic reward of a real VAR."""

import math

import numpy as np
import pytest
import torch

from learning.rl.rewards import (
    ClipBank,
    CurrentSound,
    IntrinsicReward,
    IntrinsicRewardAgainstOtherCommands,
    IntrinsicRewardWithCurrentSound,
    ShapedReward,
    SharpenedIntrinsicReward,
    SparseReward,
    StepOutcome,
    intrinsic_reward_from_embeddings,
    make_reward,
    shaped_reward,
    sparse_reward,
)
from learning.var.model import VAR, VARConfig


def unit(*values: float) -> list[float]:
    norm = math.sqrt(sum(v * v for v in values))
    return [v / norm for v in values]


def test_intrinsic_reward_is_the_dot_product_of_image_and_goal_embeddings() -> None:
    image = torch.tensor([[1.0, 0.0, 0.0], unit(1, 1, 0), [0.0, 0.0, -1.0]])
    goal = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    reward = intrinsic_reward_from_embeddings(image, goal)
    assert reward.tolist() == pytest.approx([1.0, math.sqrt(0.5), -1.0])


def test_current_sound_adds_its_dot_product_with_the_goal() -> None:
    image = torch.tensor([[0.0, 1.0, 0.0], [0.6, 0.8, 0.0]])
    goal = torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    current = torch.tensor([[0.0, 0.0, 1.0], [0.8, 0.6, 0.0]])
    reward = intrinsic_reward_from_embeddings(image, goal, current)
    assert reward.tolist() == pytest.approx([1.0 + 0.0, 0.6 + 0.8])


def test_on_a_real_var_the_reward_is_the_cosine_of_image_and_goal_embeddings() -> None:
    torch.manual_seed(0)
    var = VAR(VARConfig(image_size=32)).eval()
    images = torch.randint(0, 256, (5, 32, 32, 3), dtype=torch.uint8)
    with torch.inference_mode():
        goal = var.encode_sound(torch.randn(5, 100, 40))
        embedded = var.encode_image(images)
    ours = intrinsic_reward_from_embeddings(embedded, goal)
    rows = zip(embedded.tolist(), goal.tolist(), strict=True)
    by_hand = [sum(i * g for i, g in zip(a, b, strict=True)) for a, b in rows]
    assert ours.tolist() == pytest.approx(by_hand, abs=1e-6)
    assert ours.abs().max() <= 1.0 + 1e-6  # unit vectors: the reward is a cosine


def test_a_zero_current_sound_row_adds_nothing() -> None:
    image = torch.tensor([[0.6, 0.8, 0.0], [0.6, 0.8, 0.0]])
    goal = torch.tensor([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    current = torch.tensor([[0.0, 0.5, 0.5], [0.0, 0.0, 0.0]])  # heard something at step 0, nothing at step 1
    base = intrinsic_reward_from_embeddings(image, goal)
    with_sound = intrinsic_reward_from_embeddings(image, goal, current)
    torch.testing.assert_close(with_sound - base, torch.tensor([0.5, 0.0]))


def test_reward_of_a_real_image_encoder_pinned_to_a_known_direction() -> None:
    torch.manual_seed(0)
    var = VAR(VARConfig(image_size=32)).eval()
    last = var.image_encoder.head[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.copy_(torch.tensor([3.0, 4.0, 0.0]))  # every image embeds to (0.6, 0.8, 0)
        embedded = var.encode_image(torch.randint(0, 256, (3, 32, 32, 3), dtype=torch.uint8))
    goals = torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [-0.6, -0.8, 0.0]])
    torch.testing.assert_close(
        intrinsic_reward_from_embeddings(embedded, goals), torch.tensor([0.8, 0.6, -1.0])
    )
    goal, current = torch.tensor([[0.0, 0.6, 0.8]] * 3), torch.tensor([[0.0, 0.0, 1.0]] * 3)
    torch.testing.assert_close(
        intrinsic_reward_from_embeddings(embedded, goal, current), torch.tensor([1.28, 1.28, 1.28])
    )


def outcome(**fields: object) -> StepOutcome:
    """Three environments after a step; each test overrides what its reward reads."""
    settings: dict = {
        "image_embedding": torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.6, 0.8, 0.0]]),
        "goal_clips": np.array([0, 1, 1]),
        "heard": np.array([-1, 0, 1]),
        "distance_before": np.array([0.10, 0.10, 0.05]),
        "distance_after": np.array([0.08, 0.13, 0.05]),
        "done": np.array([False, False, True]),
        "success": np.array([False, False, True]),
        "target": np.array([0, 1, 1]),
    }
    return StepOutcome(**{**settings, **fields})


def embedded_bank(embeddings: list[list[float]], intents: list[int]) -> ClipBank:
    bank = ClipBank(np.zeros((len(intents), 100, 40), np.float32), np.array(intents))
    bank.embeddings = torch.tensor(embeddings)
    return bank


GOALS = [[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]]  # clip 0 (intent 0), clip 1 (intent 1)


def test_the_intrinsic_reward_strategy_pairs_each_image_with_its_own_goal() -> None:
    reward = IntrinsicReward(embedded_bank(GOALS, [0, 1]))
    # env 0: (1,0,0)·(1,0,0); env 1: (0,1,0)·(0,.6,.8); env 2: (.6,.8,0)·(0,.6,.8)
    assert reward(outcome()).tolist() == pytest.approx([1.0, 0.6, 0.48])
    assert reward(outcome()).dtype == np.float64 and not reward.queries_simulator


def test_the_current_sound_strategy_adds_what_is_heard_now_against_the_goal() -> None:
    goals = embedded_bank(GOALS, [0, 1])
    heard_clips = embedded_bank([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]], [0, 1])  # one clip per intent
    silence = torch.tensor([0.6, 0.0, 0.8])
    reward = IntrinsicRewardWithCurrentSound(
        goals, CurrentSound(heard_clips, silence), np.random.default_rng(0)
    )
    # env 0 hears nothing: + silence·(1,0,0) = 0.6; env 1 hears 0: + (0,0,1)·(0,.6,.8) = 0.8;
    # env 2 hears 1: + (0,1,0)·(0,.6,.8) = 0.6
    assert reward(outcome()).tolist() == pytest.approx([1.0 + 0.6, 0.6 + 0.8, 0.48 + 0.6])


# the geometry that trapped policies: command 1 sits beside command 0, "nothing" a little away from both
THREE_COMMANDS = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], unit(0.0, -0.6, 0.8), [0.0, 0.0, 1.0]]


def test_against_other_commands_a_neighbouring_block_pays_less_than_no_block() -> None:
    goals = embedded_bank(THREE_COMMANDS, [0, 1, 2, 2])  # command 2 has two clips
    plain, against = IntrinsicReward(goals), IntrinsicRewardAgainstOtherCommands(goals)
    at_goal, at_neighbour, at_nothing = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], unit(-0.3, 0.0, -1.0)
    step = outcome(
        image_embedding=torch.tensor([at_goal, at_neighbour, at_nothing]), goal_clips=np.array([0] * 3)
    )
    plain_pays, against_pays = plain(step), against(step)
    assert plain_pays[1] > plain_pays[2]  # the trap: the neighbour beats no block
    assert against_pays[1] < against_pays[2] < against_pays[0]
    # command 2's prototype: the unit mean of (0,-.6,.8) and (0,0,1); at the neighbour: 0 - max(1, ·) = -1
    prototype_2 = np.array(unit(0.0, -0.6 + 0.0, 0.8 + 1.0))
    nothing = np.array(unit(-0.3, 0.0, -1.0))
    assert against_pays.tolist() == pytest.approx(
        [1.0 - 0.0, 0.0 - 1.0, nothing[0] - max(nothing[1], float(nothing @ prototype_2))], abs=1e-6
    )


def test_against_other_commands_each_clip_is_compared_with_the_commands_other_than_its_own() -> None:
    goals = embedded_bank(THREE_COMMANDS, [0, 1, 2, 2])
    view = torch.tensor([[0.0, 0.0, 1.0]] * 2)
    pays = IntrinsicRewardAgainstOtherCommands(goals)(
        outcome(image_embedding=view, goal_clips=np.array([3, 0]))
    )
    prototype_2 = np.array(unit(0.0, -0.6, 1.8))
    # goal clip 3 (command 2): 1 - max(0, 0); goal clip 0 (command 0): 0 - max(0, (0,0,1)·p_2)
    assert pays.tolist() == pytest.approx([1.0, -prototype_2[2]], abs=1e-6)


def test_the_reward_against_other_commands_needs_two_commands_and_every_clips_own_command() -> None:
    with pytest.raises(ValueError, match="at least two commands"):
        IntrinsicRewardAgainstOtherCommands(embedded_bank([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [0, 0]))
    with pytest.raises(ValueError, match="at least two commands"):
        IntrinsicRewardAgainstOtherCommands(embedded_bank([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [-1, -1]))
    with pytest.raises(ValueError, match="1 clips have none"):  # whose other commands would be unknown
        IntrinsicRewardAgainstOtherCommands(embedded_bank(THREE_COMMANDS, [0, 1, 2, -1]))


def test_a_sharpened_reward_keeps_the_order_of_the_matches_and_widens_the_gap_to_the_goals_block() -> None:
    goals = embedded_bank(THREE_COMMANDS, [0, 1, 2, 2])
    at_goal, at_neighbour, at_nothing = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], unit(-0.3, 0.0, -1.0)
    step = outcome(
        image_embedding=torch.tensor([at_goal, at_neighbour, at_nothing]), goal_clips=np.array([0] * 3)
    )
    plain, sharp = IntrinsicReward(goals)(step), SharpenedIntrinsicReward(goals, temperature=0.25)(step)
    assert sharp.tolist() == pytest.approx(np.exp((plain - 1.0) / 0.25).tolist())
    assert sharp[0] > sharp[1] > sharp[2]
    share = lambda pays: (pays[1] - pays[2]) / (pays[0] - pays[2])  # noqa: E731
    assert share(sharp) < share(plain) / 5  # the neighbour's pull, against the goal's block


def test_the_extrinsic_strategies_read_the_simulator_and_count_its_queries() -> None:
    assert SparseReward()(outcome()).tolist() == [0.0, 0.0, 1.0]
    # 2 cm closer = one step; 3 cm further = -1.5 steps; at the target = +1
    assert ShapedReward()(outcome()).tolist() == pytest.approx([1.0, -1.5, 1.0])
    assert SparseReward.queries_simulator and ShapedReward.queries_simulator


def test_a_runs_settings_choose_its_reward() -> None:
    goals = embedded_bank(GOALS, [0, 1])
    var = VAR(VARConfig(image_size=32)).eval()
    heard_clips = ClipBank(np.zeros((2, 100, 40), np.float32), np.array([0, 1]))
    assert type(make_reward("var", goals)) is IntrinsicReward
    with_sound = make_reward("var", goals, var, heard_clips, np.random.default_rng(0))
    assert type(with_sound) is IntrinsicRewardWithCurrentSound
    assert heard_clips.embeddings is not None  # the heard clips are embedded once, by the run's VAR
    against = make_reward("var", goals, against_others=True)
    assert type(against) is IntrinsicRewardAgainstOtherCommands
    sharpened = make_reward("var", goals, temperature=0.25)
    assert type(sharpened) is SharpenedIntrinsicReward and sharpened.temperature == 0.25
    with pytest.raises(ValueError, match="positive"):
        make_reward("var", goals, temperature=0.0)
    assert type(make_reward("sparse", goals)) is SparseReward
    assert type(make_reward("shaped", goals)) is ShapedReward


def test_sparse_reward_is_one_on_every_step_that_ends_at_the_target_as_the_reference_pays() -> None:
    heard = np.array([2, 2, -1, 1, 0])
    target = np.array([2, 1, 1, 1, 0])
    assert sparse_reward(heard, target).tolist() == [1.0, 0.0, 0.0, 1.0, 1.0]
    assert SparseReward()(outcome(target=np.array([1, 0, 1]))).tolist() == [0.0, 1.0, 1.0]


def test_shaped_reward_counts_progress_in_action_steps_plus_one_on_every_step_at_the_target() -> None:
    before = np.array([0.10, 0.10, 0.05, 0.0])
    after = np.array([0.08, 0.13, 0.05, 0.0])
    heard = np.array([-1, 1, 1, 2])
    target = np.array([0, 0, 1, 2])
    # 2 cm closer = one full step; 3 cm further = -1.5 steps; staying on the target pays 1 every step
    assert shaped_reward(before, after, heard, target).tolist() == pytest.approx([1.0, -1.5, 1.0, 1.0])


def test_goals_are_drawn_from_the_clips_of_the_requested_intent() -> None:
    bank = ClipBank(np.zeros((6, 100, 40), np.float32), np.array([0, 0, 1, 1, 2, 3]))
    rng = np.random.default_rng(0)
    picks = bank.sample(np.array([0, 1, 2, 3] * 25), rng)
    assert (bank.intents[picks] == np.array([0, 1, 2, 3] * 25)).all()
    assert set(picks[::4].tolist()) == {0, 1}  # both clips of intent 0 get used


def test_a_goal_list_missing_an_intent_is_refused_with_a_clear_message() -> None:
    bank = ClipBank(np.zeros((2, 100, 40), np.float32), np.array([0, 1]))
    with pytest.raises(ValueError, match="no goal clip for intent 3"):
        bank.sample(np.array([3]), np.random.default_rng(0))


def test_current_sound_is_silence_when_nothing_is_heard() -> None:
    bank = ClipBank(np.zeros((2, 100, 40), np.float32), np.array([0, 1]))
    bank.embeddings = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    silence = torch.tensor([0.0, 0.0, 1.0])
    current = CurrentSound(bank, silence).embeddings(np.array([-1, 1, 0]), np.random.default_rng(0))
    assert current.tolist() == [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
