"""A run's progress bar: each stage fills its own share, in order, from 0 at the start to 1 at the end."""

import pytest

from worker.progress import STAGE_WEIGHTS, Progress


def at(progress: Progress, stage: str, fraction: float) -> float:
    progress.stage, progress.fraction = stage, fraction
    return progress.overall()


def finish(progress: Progress, stage: str) -> None:
    progress.stage = stage
    progress.finish_stage()


def test_a_run_that_has_not_started_a_stage_is_at_zero() -> None:
    assert Progress(1, "finetune").overall() == 0.0


def test_each_stage_fills_its_share_after_the_stages_before_it() -> None:
    progress = Progress(1, "finetune")  # var_finetune 0.3, policy_improve 0.5, evaluate 0.2
    assert at(progress, "var_finetune", 0.0) == 0.0
    assert at(progress, "var_finetune", 0.5) == pytest.approx(0.15)
    finish(progress, "var_finetune")
    assert at(progress, "policy_improve", 0.0) == pytest.approx(0.3)
    assert at(progress, "policy_improve", 0.5) == pytest.approx(0.55)
    finish(progress, "policy_improve")
    assert at(progress, "evaluate", 0.5) == pytest.approx(0.9)
    finish(progress, "evaluate")
    assert at(progress, "promoting", 0.0) == 1.0


@pytest.mark.parametrize("kind", list(STAGE_WEIGHTS))
def test_progress_never_jumps_past_what_is_done(kind: str) -> None:
    progress = Progress(1, kind)
    seen = [progress.overall()]
    for stage, _weight in STAGE_WEIGHTS[kind]:
        seen += [at(progress, stage, fraction) for fraction in (0.0, 0.25, 0.75, 1.0)]
        finish(progress, stage)
    seen.append(at(progress, "promoting", 0.0))
    assert seen == sorted(seen) and seen[0] == 0.0 and seen[-1] == pytest.approx(1.0)
    assert len(set(seen)) > len(STAGE_WEIGHTS[kind]) + 1


def test_a_resumed_run_counts_the_stages_finished_before_the_crash() -> None:
    progress = Progress(1, "finetune")
    progress.restore({"var_finetune": {"seconds": 12.0}})
    assert progress.overall() == pytest.approx(0.3)
    assert at(progress, "policy_improve", 0.5) == pytest.approx(0.55)
