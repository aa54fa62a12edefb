"""The pieces of a run that need no worker process: the triplet rule, the refusal, divergence, the gate."""

import numpy as np
import pytest

from backend import models
from varbot.services import wait_until
from worker.evaluation import MIN_ITEMS, ModelScore, Verdict, compare, decide
from worker.household import SILENCE_ROW, HouseholdData, TooFewTriplets, derive_triplets


def test_triplets_follow_the_backends_rule_including_nothing_i_said_images() -> None:
    commands = {1: "name:zero", 2: "name:one", 3: "name:one"}
    answers = {
        10: [(1, models.Verdict.IS), (2, models.Verdict.IS_NOT), (3, models.Verdict.IS_NOT)],  # 1 × 2
        11: [(1, models.Verdict.IS_NOT), (2, models.Verdict.IS_NOT)],  # every command is "not": silence
        12: [(1, models.Verdict.IS_NOT)],  # command "one" not asked about: no triplet yet
        13: [(2, models.Verdict.IS)],  # no "is not": no triplet
    }
    assert derive_triplets(answers, commands) == [
        (10, 1, 2),
        (10, 1, 3),
        (11, SILENCE_ROW, 1),
        (11, SILENCE_ROW, 2),
    ]


def test_the_triplet_count_agrees_with_the_api_and_too_few_are_refused_with_how_many_more(
    household,
    stack,  # type: ignore[no-untyped-def]
) -> None:
    from backend.db import get_session_factory
    from backend.deps import get_blob_store
    from backend.services.triplets import triplet_stats
    from worker.household import load_household

    robot_id = household.new_robot("count-arm", views=12)
    with get_session_factory()() as session:
        robot = session.get_one(models.Robot, robot_id)
        expected = triplet_stats(session, robot.household_id, robot.id).triplets
        data = load_household(session, get_blob_store(), robot, 16, "speech", 0.25, 0, min_triplets=2)
        assert len(data.triplets) == expected
        assert data.images.shape[1:] == (16, 16, 3) and data.features.shape[1:] == (100, 40)
        assert data.held_out.any() and (~data.held_out).any()
        held_snapshots = set(data.triplets[data.held_out, 0]) & set(data.triplets[~data.held_out, 0])
        assert not held_snapshots, "held-out triplets come from images never trained on"
        with pytest.raises(TooFewTriplets, match="5 more are needed"):
            load_household(session, get_blob_store(), robot, 16, "speech", 0.25, 0, min_triplets=expected + 5)


def test_a_command_is_known_from_an_is_answer_on_a_view_that_gives_no_triplet_and_attempts_favour_others(
    household,
    stack,  # type: ignore[no-untyped-def]
) -> None:
    """Simulated success is measured once every command has an *is* answer, even one on a view with no *is
    not* answer yet (such a view gives no triplet); until then the robot's attempts favour the commands that
    have none."""
    from backend.db import get_session_factory
    from backend.deps import get_blob_store
    from backend.services.attempts import commands_with_an_is_answer, household_commands
    from varbot.simulated_household import VOICES, WORDS
    from worker.attempts import attempt_cycle
    from worker.household import load_household

    robot = household.client.post("/api/v1/robots", json={"name": "is-only", "kind": "kuka-sim"}).json()
    robot_id = robot["id"]
    by_target = views_at_two_targets(household, robot_id)
    first, second = sorted(by_target)[:2]
    answers = [(by_target[first], (WORDS[first], VOICES[0]), "is"),
               *((by_target[first], (WORDS[second], voice), "is_not") for voice in VOICES),
               (by_target[second], (WORDS[second], VOICES[0]), "is")]  # fmt: skip
    for snapshot, recording, verdict in answers:
        body = {"snapshot_id": snapshot["id"], "clip_id": household.clip_ids[recording], "verdict": verdict}
        assert household.client.post("/api/v1/labels", json=body).status_code == 201
    with get_session_factory()() as session:
        robot = session.get_one(models.Robot, robot_id)
        data = load_household(session, get_blob_store(), robot, 16, "speech", 0.0, 0, min_triplets=1)
        answered = commands_with_an_is_answer(session, robot_id)
        commands = list(household_commands(session, robot.household_id).values())
    intent_of = dict(zip(data.clip_ids.tolist(), data.clip_intent.tolist(), strict=True))
    assert intent_of[household.clip_ids[(WORDS[second], VOICES[1])]] == second, "known from the lone 'is'"
    assert intent_of[household.clip_ids[(WORDS[first], VOICES[1])]] == first
    assert answered == {f"name:{WORDS[first]}", f"name:{WORDS[second]}"}
    missing = [command for command in commands if command.key not in answered]
    assert len(missing) == 2
    assert attempt_cycle(commands, answered) == [*missing, *commands], "the robot tries those first, twice"


def views_at_two_targets(household, robot_id: int) -> dict:  # type: ignore[no-untyped-def]
    """Captured views by the target each shows, captured 40 at a time until two targets are shown (random
    views seldom show the gripper at a block: one batch of 40 has shown only one)."""
    by_target: dict = {}
    for batch in range(1, 6):
        household.client.post(f"/api/v1/robots/{robot_id}/snapshots:capture", json={"count": 40})
        wait_until(lambda n=40 * batch: len(household.snapshots(robot_id)) >= n, 120, "captured snapshots")
        snapshots = household.snapshots(robot_id)
        by_target = {s["meta"]["sim_heard"]: s for s in snapshots if s["meta"]["sim_heard"] is not None}
        if len(by_target) >= 2:
            return by_target
    raise AssertionError(f"200 captured views showed targets {sorted(by_target)} only")


def _toy_data(features: np.ndarray) -> HouseholdData:
    rng = np.random.default_rng(0)
    triplets = np.array([[i % 4, i % 2, 1 - i % 2] for i in range(8)], dtype=np.int64)
    return HouseholdData(
        snapshot_ids=np.arange(4),
        images=rng.integers(0, 255, (4, 16, 16, 3), dtype=np.uint8),
        sim_heard=np.full(4, -2),
        clip_ids=np.arange(2),
        features=features,
        clip_intent=np.full(2, -1),
        triplets=triplets,
        held_out=np.zeros(8, dtype=bool),
        labels_used=16,
    )


def test_a_diverging_loss_stops_the_var_stage_with_the_step_it_happened_at(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import torch

    from learning.var.checkpoint import save_var
    from learning.var.model import VAR, VARConfig
    from worker.var_stage import Diverged, finetune_var

    init = save_var(VAR(VARConfig(image_size=16)), tmp_path / "init.pt")
    poisoned = np.full((2, 100, 40), np.nan, dtype=np.float32)
    with pytest.raises(Diverged, match="step 1"):
        finetune_var(_toy_data(poisoned), init, tmp_path / "run", 2, 4, 1e-3, 0, lambda *_: False)
    healthy = np.random.default_rng(1).normal(size=(2, 100, 40)).astype(np.float32)
    result = finetune_var(_toy_data(healthy), init, tmp_path / "ok", 2, 4, 1e-3, 0, lambda *_: False)
    assert result.epochs == 2 and result.checkpoint.is_file()
    resumed = finetune_var(_toy_data(healthy), init, tmp_path / "ok", 3, 4, 1e-3, 0, lambda *_: False)
    assert resumed.epochs == 3 and resumed.steps == 3 * 2, "a resumed stage continues from its checkpoint"
    assert torch.load(resumed.checkpoint, weights_only=True)["kind"] == "varbot-var"


def test_an_adapted_vars_fine_tune_sees_replayed_training_room_views_by_the_base_statistics() -> None:
    import torch

    from learning.var.model import VAR, VARConfig
    from learning.var.room_adaptation import adapt_to_room, with_statistics
    from worker.var_stage import encode_views, keep_room_statistics

    torch.manual_seed(0)
    var = VAR(VARConfig(image_size=16))
    rng = np.random.default_rng(0)
    adaptation = adapt_to_room(var.image_encoder, rng.integers(0, 90, (64, 16, 16, 3), dtype=np.uint8), 1.0)
    var.train()
    keep_room_statistics(var)
    base = with_statistics(var, adaptation.statistics_before).eval()
    images = torch.from_numpy(rng.integers(0, 256, (4, 16, 16, 3), dtype=np.uint8))
    replayed = np.array([True, False, True, False])

    seen, hidden = encode_views(var, images, replayed, adaptation.statistics_before)

    with torch.no_grad():
        torch.testing.assert_close(hidden[replayed], base.image_encoder.hidden(images[replayed]))
        torch.testing.assert_close(seen[replayed], base.encode_image(images[replayed]))
        torch.testing.assert_close(seen[~replayed], var.encode_image(images[~replayed]))
        assert not torch.allclose(seen[replayed], var.encode_image(images[replayed]))
    seen.sum().backward()
    assert var.image_encoder.features[0][0].weight.grad is not None, "it trains through both"
    unadapted, _ = encode_views(var, images, replayed, None)
    torch.testing.assert_close(unadapted, var.encode_image(images))


def test_the_view_anchor_pulls_only_the_replayed_views_hidden_layer_back_to_the_starts() -> None:
    import copy

    import torch

    from learning.var.model import VAR, VARConfig
    from worker.var_stage import ViewAnchor

    torch.manual_seed(0)
    start = VAR(VARConfig(image_size=16)).eval()
    moved = copy.deepcopy(start)
    with torch.no_grad():
        for parameter in moved.image_encoder.parameters():
            parameter.add_(0.05 * torch.randn_like(parameter))
    images = torch.from_numpy(np.random.default_rng(1).integers(0, 256, (6, 16, 16, 3), dtype=np.uint8))
    replayed = np.array([True, False, True, False, True, False])
    anchor = ViewAnchor(start, weight=2.0)

    with torch.no_grad():
        assert float(anchor.drift(images, start.image_encoder.hidden(images), replayed)) < 1e-9
        household_moved = start.image_encoder.hidden(images)
        household_moved[~replayed] += 5.0
        assert float(anchor.drift(images, household_moved, replayed)) < 1e-9, (
            "the household's views move freely"
        )
    hidden = moved.image_encoder.hidden(images)
    loss = anchor.weight * anchor.drift(images, hidden, replayed)
    assert float(loss) > 1e-3
    loss.backward()
    assert moved.image_encoder.features[0][0].weight.grad.abs().sum() > 0
    assert all(parameter.grad is None for parameter in start.parameters()), "the start stays as it was"


def _score(
    accuracy: float | None, success: float | None, triplets: int = 50, episodes: int = 40
) -> ModelScore:
    return ModelScore(accuracy, triplets, success, episodes if success is not None else 0)


def test_the_gate_promotes_only_a_measurably_better_candidate() -> None:
    better = decide(_score(0.90, 0.60), _score(0.70, 0.50))
    assert better.promote and better.verdict == Verdict.BETTER, better.reasons
    same = decide(_score(0.80, 0.50), _score(0.80, 0.50))
    assert not same.promote and same.verdict == Verdict.NO_CHANGE
    assert same.summary.startswith("No measurable change") and "kept the old version" in same.summary
    slightly = decide(_score(0.84, 0.50), _score(0.80, 0.50))
    assert slightly.verdict == Verdict.NO_CHANGE, "four points on 50 triplets is within the noise"
    worse = decide(_score(0.95, 0.20), _score(0.80, 0.50))
    assert worse.verdict == Verdict.WORSE and not worse.promote, "worse on either measure is worse"
    assert "simulated success" in worse.reasons[1] and "(worse" in worse.reasons[1]
    assert worse.summary.startswith("Worse") and "kept the old version" in worse.summary
    unmeasured_sim = decide(_score(0.95, None), _score(0.70, None))
    assert unmeasured_sim.promote and unmeasured_sim.reasons[1].endswith("not measured")
    no_goals = _score(0.90, None)
    no_goals.sim_note = "no 'is' answer yet"
    explained = decide(no_goals, _score(0.80, None))
    assert explained.reasons[1].endswith("not measured (no 'is' answer yet)")
    assert not decide(_score(None, None), _score(None, None)).promote, "nothing measured: nothing promoted"
    assert decide(_score(0.1, 0.0), None).promote, "the first version of a robot becomes active"


def test_a_gain_is_never_claimed_from_fewer_held_out_triplets_than_the_rule_needs() -> None:
    assert MIN_ITEMS == 50, "2 standard errors of a difference at p = 1/2 clear a 20-point gain from 50 items"
    assert compare(1.0, 0.0, MIN_ITEMS - 1) == Verdict.NO_CHANGE, "even the largest gain, from 49 triplets"
    assert compare(1.0, 0.0, MIN_ITEMS) == Verdict.BETTER
    assert compare(0.70, 0.50, MIN_ITEMS) == Verdict.BETTER, "20 points at the worst-case spread"
    assert compare(0.65, 0.50, MIN_ITEMS) == Verdict.NO_CHANGE
    assert compare(0.0, 1.0, 7) == Verdict.WORSE, "a clear loss needs no minimum: it only keeps the old"
    seven = decide(_score(1.0, None, triplets=7), _score(0.71, None, triplets=7))
    assert seven.verdict == Verdict.NO_CHANGE and not seven.promote
    assert "needs at least 50 held-out answers or tries; this run had 7" in seven.summary


def test_the_gate_says_what_changed_in_the_households_own_command_words() -> None:
    candidate, active = _score(0.80, 0.55, episodes=80), _score(0.80, 0.30, episodes=80)
    candidate.sim_success_by_intent = [0.5, 0.5, 0.8, 0.4]
    active.sim_success_by_intent = [0.5, 0.3, 0.3, 0.1]
    decision = decide(candidate, active, {0: "zero", 1: "one", 2: "two", 3: "three"})
    assert decision.verdict == Verdict.BETTER
    assert "*two* now works in 16 of 20 tries, was 6 of 20" in decision.summary
    assert "*zero*" not in decision.summary, "an unchanged command is not mentioned"
    assert "the new version is active. Measured on 50 held-out answers and 80 tries." in decision.summary
    worse = decide(_score(0.95, 0.20), _score(0.80, 0.50)).summary
    assert worse.endswith("kept the old version. Measured on 50 held-out answers and 40 tries."), worse
    assert decide(_score(0.80, None), _score(0.80, None)).summary.endswith("Measured on 50 held-out answers.")


def test_a_verdict_is_explained_by_the_measure_that_gave_it_not_by_changes_within_the_noise() -> None:
    candidate, active = (
        _score(0.995, 0.06, triplets=201, episodes=100),
        _score(0.965, 0.03, triplets=201, episodes=100),
    )
    candidate.sim_success_by_intent = [0.08, 0.08, 0.04, 0.04]
    active.sim_success_by_intent = [0.08, 0.04, 0.0, 0.0]
    decision = decide(candidate, active, {0: "zero", 1: "one", 2: "two", 3: "three"})
    assert decision.verdict == Verdict.BETTER, decision.reasons
    assert "(no measurable change)" in decision.reasons[1], (
        "3 more successes in 100 tries is within the noise"
    )
    assert decision.summary.startswith("Better: it now matches 200 of 201 held-out answers, was 194 of 201;")
    assert "now works in" not in decision.summary, "the commands' tries did not give the verdict"
    worse = decide(_score(0.95, 0.20), _score(0.80, 0.50)).summary
    assert worse.startswith("Worse: it now succeeds in 8 of 40 tries, was 20 of 40;"), worse


def test_a_gain_in_answers_does_not_promote_a_robot_whose_success_slipped_beyond_one_standard_error() -> None:
    before = _score(0.90, 0.25, triplets=200, episodes=100)
    slipped = decide(_score(0.99, 0.18, triplets=200, episodes=100), before)
    assert "(better" in slipped.reasons[0] and "(no measurable change)" in slipped.reasons[1], slipped.reasons
    assert slipped.verdict == Verdict.NO_CHANGE and not slipped.promote, "25 -> 18 in 100 tries is -1.2 SE"
    assert "fell by more than one standard error" in slipped.reasons[2]
    assert slipped.summary.startswith(
        "No measurable change: it now matches 198 of 200 held-out answers, was 180 of 200, but it now "
        "succeeds in 18 of 100 tries, was 25 of 100; kept the old version"
    ), slipped.summary
    held = decide(
        _score(0.99, 0.20, triplets=200, episodes=100), _score(0.90, 0.23, triplets=200, episodes=100)
    )
    assert held.verdict == Verdict.BETTER and held.promote, (
        "3 fewer in 100 tries is within one standard error"
    )


def test_replay_joins_views_of_the_training_room_paired_by_what_is_in_view_and_never_held_out() -> None:
    from learning.sounds import SoundCorpus
    from worker.replay import joined_with_replay

    data = _toy_data(np.ones((2, 100, 40), dtype=np.float32))
    data.held_out[:2] = True
    corpus = SoundCorpus(
        name="wordset", kind="speech", features=np.random.default_rng(1).random((8, 100, 40), np.float32),
        intent=np.arange(8) % 4, speaker=np.array(["a"] * 8), split=np.array(["train"] * 8),
        clip=np.array([f"{i}.wav" for i in range(8)]), intent_names=["a", "b", "c", "d"], manifest_hash="x",
    )  # fmt: skip
    heard = np.array([-1, 0, 3, -1, 2, 1])
    images = np.zeros((6, 16, 16, 3), dtype=np.uint8)
    joined = joined_with_replay(data, corpus, images, heard, np.random.default_rng(2))

    replayed = joined.triplets[len(data.triplets) :]
    assert len(replayed) == 6 and not joined.held_out[len(data.triplets) :].any()
    assert (joined.test_triplets == data.test_triplets).all(), "the held-out triplets stay the household's"
    for image_row, positive, negative in replayed:
        seen = joined.sim_heard[image_row]
        if seen < 0:
            assert positive == SILENCE_ROW and negative >= len(data.features), "nothing in view: silence"
        else:
            assert joined.clip_intent[positive] == seen and positive >= len(data.features)
            assert negative == SILENCE_ROW or joined.clip_intent[negative] != seen


def test_replay_can_place_a_share_of_its_views_around_the_blocks_ends_in_a_world_with_blocks() -> None:
    from sim.explore import block_end_views, random_views
    from worker.replay import replay_views

    images, heard = replay_views("kuka", 8, 16, seed=3, block_ends_share=0.5)
    random_part = list(random_views("kuka", 4, seed=3 + 4099, image_size=16))
    placed_part = list(block_end_views("kuka", 4, seed=3 + 8191, image_size=16))
    expected = random_part + placed_part
    assert images.shape == (8, 16, 16, 3)
    assert all((image == view[0]).all() for image, view in zip(images, expected, strict=True))
    assert heard.tolist() == [-1 if view[1] is None else view[1] for view in expected], "the ray labels them"

    plain, _ = replay_views("kuka", 8, 16, seed=3)
    assert (plain[:4] == images[:4]).all() and not (plain[4:] == images[4:]).all()
    rover, _ = replay_views("turtlebot", 4, 16, seed=3, block_ends_share=0.5)
    rover_random = [view[0] for view in random_views("turtlebot", 4, seed=3 + 4099, image_size=16)]
    assert all((a == b).all() for a, b in zip(rover, rover_random, strict=True)), "no blocks: random views"


def test_a_fine_tune_whose_replay_corpus_is_missing_says_what_to_do(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from learning.var.checkpoint import save_var
    from learning.var.model import VAR, VARConfig
    from worker.replay import ReplayMissing, with_replay

    data = _toy_data(np.ones((2, 100, 40), dtype=np.float32))
    unnamed = save_var(VAR(VARConfig(image_size=16)), tmp_path / "unnamed.pt")
    same, added = with_replay(data, unnamed, "kuka", 0.0, 0)
    assert same is data and added == 0, "no replay asked: none needed"
    with pytest.raises(ReplayMissing, match="names no sound corpus to replay"):
        with_replay(data, unnamed, "kuka", 0.25, 0)
    retired = save_var(VAR(VARConfig(image_size=16)), tmp_path / "retired.pt", sound_set="retired-set")
    with pytest.raises(ReplayMissing, match=r"could not be built here .*Unknown sound set 'retired-set'"):
        with_replay(data, retired, "kuka", 0.25, 0)
