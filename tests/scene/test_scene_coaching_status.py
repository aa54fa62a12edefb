"""The scene's status line names what it follows: a coaching session by voice in words (its rollouts carry no
training run), a training run by its number and stage."""

import numpy as np

from backend.broker import COACHING_STAGE
from scene.household import HouseholdView
from scene.live import LiveRollout
from scene.panel import status_line


def _rollout(stage: str, run_id: int) -> LiveRollout:
    image = np.zeros((8, 8, 3), dtype=np.uint8)
    return LiveRollout(run_id, 1, "kuka", stage, 42, image, 0.5, False, None, {}, 1, 0.0)


def test_a_coaching_session_is_followed_in_words_and_a_run_by_its_number() -> None:
    view = HouseholdView(household_id=1, robot=None)
    coaching = status_line(view, False, None, _rollout(COACHING_STAGE, 0), 5.0)
    assert coaching.endswith("Following a coaching session by voice live, step 42")
    training = status_line(view, False, None, _rollout("policy_improve", 7), 5.0)
    assert training.endswith("Following training run 7 live (policy stage), step 42")
