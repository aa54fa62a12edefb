"""What a succeeded run concludes, inside the commit that ends it: what it trained on, how it scored, and
the model version it gives — created as a candidate (once: `model_versions.run_id` is unique) and promoted
or kept by the gate (`worker.evaluation.decide`)."""

from collections import Counter, defaultdict
from dataclasses import dataclass
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend import models
from backend.deps import get_blob_store
from backend.services import model_versions
from worker.evaluation import ModelScore, decide, summarise_scores
from worker.run_context import RunContext, RunState


@dataclass
class Conclusion:
    metrics: dict[str, Any]  # added to the run's metrics
    outcome: str  # for the worker log
    promoted: models.ModelVersion | None = None  # the version to make active, in the same commit


def conclude(session: Session, run: models.Run, context: RunContext, state: RunState) -> Conclusion:
    data = context.data
    metrics: dict[str, Any] = {
        "labels_used": data.labels_used,
        "triplets": {"train": len(data.train_triplets), "held_out": len(data.test_triplets)},
        "stages": {
            stage: {k: v for k, v in result.items() if k != "curve"}
            for stage, result in state.completed.items()
        },
    }
    scores = state.completed["evaluate"]
    active = ModelScore(**scores["active"]) if scores["active"] else None
    if not scores["candidate"]:
        metrics["evaluation"] = {"active": active.to_dict() if active else None}
        return Conclusion(metrics, "evaluated")
    candidate = ModelScore(**scores["candidate"])
    decision = decide(candidate, active, command_words(session, context))
    metrics["evaluation"] = summarise_scores(candidate, active)
    metrics["gate"] = {
        "promoted": decision.promote,
        "verdict": decision.verdict.value,
        "summary": decision.summary,
        "min_items_for_a_claim": decision.min_items,
        "reasons": decision.reasons,
    }
    version = _candidate_version(session, run, context, metrics)
    version.metrics = {
        **(version.metrics or {}),
        "evaluation": metrics["evaluation"],
        "gate": metrics["gate"],
    }
    kept = "promoted" if decision.promote else "kept as candidate"
    version.notes = (
        f"{decision.verdict.value}, {kept}: {decision.summary} (" + "; ".join(decision.reasons) + ")"
    )
    metrics["model_version_id"] = version.id
    return Conclusion(metrics, f"version {version.id} {kept}", version if decision.promote else None)


def command_words(session: Session, context: RunContext) -> dict[int, str]:
    """The household's word for each of the world's targets: the most common name among the recordings the
    simulator's account of the *is* answers ties to it (scoring only, never a label)."""
    data = context.data
    names = dict(
        session.execute(
            select(models.Clip.id, models.Clip.name).where(models.Clip.id.in_(data.clip_ids.tolist()))
        ).all()
    )
    votes: dict[int, Counter[str]] = defaultdict(Counter)
    for clip_id, intent in zip(data.clip_ids.tolist(), data.clip_intent.tolist(), strict=True):
        if intent >= 0:
            votes[intent][names.get(clip_id) or f"clip {clip_id}"] += 1
    return {intent: counter.most_common(1)[0][0] for intent, counter in votes.items()}


def _candidate_version(
    session: Session, run: models.Run, context: RunContext, metrics: dict[str, Any]
) -> models.ModelVersion:
    """The run's version: the one an earlier, interrupted finish already created, or a new candidate."""
    if context.kind == models.RunKind.EVALUATE:
        return session.get_one(models.ModelVersion, context.candidate_id)
    existing = session.scalar(select(models.ModelVersion).where(models.ModelVersion.run_id == run.id))
    if existing is not None:
        return existing
    blobs = get_blob_store()
    var_path, policy_path = context.candidate_var(), context.candidate_policy()
    return model_versions.create_version(
        session,
        session.get_one(models.Robot, context.robot_id),
        var_key=blobs.put(var_path.read_bytes()),
        policy_key=blobs.put(policy_path.read_bytes()) if policy_path else None,
        parent_id=context.parent_id,
        run_id=run.id,
        metrics={"labels_used": metrics["labels_used"], "triplets": metrics["triplets"]},
    )
