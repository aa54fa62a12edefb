"""Coaching by voice in the learner (`learning.rl.coaching`) on the shipped Kuka base: the coach's voice is
the current sound of eq. 3 for the frames it overlaps and nothing else, steps are paced, and a stop between
two steps ends the session."""

import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

from learning.audio import feature_shape
from learning.rl.coaching import (
    CoachingSettings,
    CoachingStopped,
    LiveCoach,
    SilentCoach,
    SpokenClip,
    StepMoment,
    coaching_trainer,
)
from learning.rl.rewards import ClipBank
from learning.var.checkpoint import load_var

BASE = Path(__file__).resolve().parents[2] / "worker" / "base_models" / "kuka"


def _moment(start: float) -> StepMoment:
    return StepMoment(start, start + 0.2, -1, 0, -1)


def test_a_live_clip_is_the_voice_over_exactly_the_frames_it_overlaps() -> None:
    voice = torch.ones(4)
    arrived = [[SpokenClip(10.3, 10.7, voice)], []]
    coach = LiveCoach(lambda: arrived.pop(0))
    moments = [_moment(10.0 + 0.2 * i) for i in range(5)]  # 10.0-10.2, 10.2-10.4, ... 10.8-11.0
    heard = coach.voice_over(moments)
    assert [h is not None for h in heard] == [False, True, True, True, False]
    assert coach.voice_over(moments)[1] is voice, "a clip keeps counting for later rollouts' frames"


def test_a_session_shorter_than_one_update_is_refused_in_words() -> None:
    with pytest.raises(ValueError, match="shorter than one update"):
        CoachingSettings(steps=10, steps_per_update=25)


@pytest.fixture(scope="module")
def goals() -> ClipBank:
    var = load_var(BASE / "var.pt").eval()
    features = np.random.default_rng(0).random((1, *feature_shape("speech", var.front_end)), dtype=np.float32)
    return ClipBank(features, np.array([-1])).embed(var)


class GoalVoice:
    """Says the goal clip itself over every frame: the largest current-sound term there is."""

    def __init__(self, goals: ClipBank) -> None:
        self.goals = goals

    def voice_over(self, moments):  # type: ignore[no-untyped-def]
        return [self.goals.embeddings[m.goal_clip] for m in moments]


def _session(goals: ClipBank, coach, steps_per_s: float | None, stop=lambda: False):  # type: ignore[no-untyped-def]
    settings = CoachingSettings(steps=25, steps_per_s=steps_per_s, steps_per_update=25, seed=3)
    run_dir = Path(tempfile.mkdtemp(prefix="coaching-test-")) / "run"
    return coaching_trainer(BASE / "policy.pt", BASE / "var.pt", goals, coach, settings, run_dir, None, stop)


def test_the_coachs_voice_adds_its_term_to_every_step_it_was_heard_over(goals: ClipBank) -> None:
    with _session(goals, GoalVoice(goals), steps_per_s=20.0) as trainer:
        trainer.coach_session()
        moments = trainer.moments
        voice = trainer.voice_term(moments)
        assert trainer.voiced_steps == 25 and len(moments) == 25
        assert np.all(voice > 0), "the goal's own clip is closer to the goal than silence"
        gaps = np.diff([m.shown_from for m in moments])
        assert gaps.min() >= 1 / 20.0 - 0.005, "steps are paced at steps_per_s"
    with _session(goals, SilentCoach(), steps_per_s=None) as trainer:
        trainer.coach_session()
        assert trainer.voiced_steps == 0 and np.all(trainer.voice_term(trainer.moments) == 0)


def test_a_stop_asked_for_ends_the_session_between_two_steps(goals: ClipBank) -> None:
    asked = iter([False] * 5 + [True])  # asked to stop while the sixth step is on its way
    with _session(goals, SilentCoach(), steps_per_s=None, stop=lambda: next(asked)) as trainer:
        with pytest.raises(CoachingStopped):
            trainer.coach_session()
        assert len(trainer.moments) == 5
