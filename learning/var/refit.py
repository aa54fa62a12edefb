"""Move a trained VAR to another sound front end without moving its embedding space.

A policy trained on a VAR acts on where f_S puts each goal and f_I puts each view. To serve the same policy
from a cheaper front end, the student keeps the teacher's f_I as it is and learns only f_S: for every
training clip (and its recordings in simulated rooms) it is taught to give, from the new front end's
features, the unit vector the teacher gives from the old ones (loss: 1 − cosine). No label is used, so the
training clips of other corpora (`extra_sounds`, e.g. the multilingual Wordset) can teach it too: more
voices than the VAR's own corpus has. The student starts from the teacher's f_S where the two front ends
share a shape. Nothing here sees an unheard tier; the report measures the agreement on them afterwards.
"""

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from learning.front_ends import VALUES_PER_FRAME, check_front_end
from learning.sounds import load_corpus
from learning.var.dataset import room_recorded_features_in
from learning.var.evaluate import nearest_command_accuracy
from learning.var.model import VAR


@dataclass(frozen=True)
class RefitConfig:
    front_end: str  # the student's sound front end
    sounds: str  # the corpus whose training clips teach it
    steps: int = 3000
    batch_size: int = 256
    lr: float = 1e-3
    room_copies: int = 2  # recordings of every training clip in simulated rooms, taught as well
    extra_sounds: tuple[str, ...] = ()  # other corpora whose training clips are taught too (no labels used)
    seed: int = 0


@dataclass
class RefitResult:
    var: VAR
    report: dict[str, Any]


def refit_front_end(teacher: VAR, config: RefitConfig, progress: bool = True) -> RefitResult:
    """A VAR reading `config.front_end` features whose f_S agrees with the teacher's and whose f_I is the
    teacher's; the report gives the agreement on the training clips and on every unheard tier."""
    check_front_end(config.front_end)
    if config.front_end == teacher.front_end:
        raise ValueError(f"The VAR already reads '{teacher.front_end}' features: nothing to refit.")
    torch.manual_seed(config.seed)
    front_ends = (teacher.front_end, config.front_end)
    old, new = _corpora(config.sounds, front_ends, progress)
    old_train, new_train = old.subset("train"), new.subset("train")
    extra = [_corpora(name, front_ends, progress) for name in config.extra_sounds]
    pairs = [(old_train, new_train), *((one.subset("train"), other.subset("train")) for one, other in extra)]
    old_features, new_features = _teaching_features(pairs, config)
    targets = _embed(teacher, old_features)

    student = _student_of(teacher, config.front_end)
    student.set_sound_statistics(torch.from_numpy(new_features))
    _teach(student, new_features, targets, config, progress)
    student.eval()
    report = {
        "from_front_end": teacher.front_end,
        "to_front_end": config.front_end,
        "sounds": config.sounds,
        "settings": dataclasses.asdict(config),
        "taught_clips": len(new_features),
        "agreement": {
            tier: _agreement(teacher, student, (old_train, new_train), (old.subset(tier), new.subset(tier)))
            for tier in old.splits
        },
    }
    return RefitResult(student, report)


def _corpora(sounds: str, front_ends: tuple[str, str], progress: bool) -> tuple[Any, Any]:
    """One corpus's clips with each front end's features (the same rows in the same order)."""
    old, new = (load_corpus(sounds, front_end=name, progress=progress) for name in front_ends)
    return old, new


def _teaching_features(pairs: list[tuple[Any, ...]], config: RefitConfig) -> tuple[np.ndarray, np.ndarray]:
    """The training clips of each (old front end, new front end) pair of one corpus, each with its room
    recordings, in the old and the new front end's features (row for row the same sound)."""
    old_parts, new_parts = [], []
    for old_train, new_train in pairs:
        old_parts.append(old_train.features)
        new_parts.append(new_train.features)
        if config.room_copies:
            front_ends = (old_train.front_end, new_train.front_end)
            copies = room_recorded_features_in(
                old_train.clip, old_train.kind, config.room_copies, config.seed, front_ends
            )
            old_parts.append(copies[old_train.front_end])
            new_parts.append(copies[new_train.front_end])
    return np.concatenate(old_parts), np.concatenate(new_parts)


def _student_of(teacher: VAR, front_end: str) -> VAR:
    student = VAR(dataclasses.replace(teacher.config, front_end=front_end))
    student.image_encoder.load_state_dict(teacher.image_encoder.state_dict())
    if VALUES_PER_FRAME[front_end] == VALUES_PER_FRAME[teacher.front_end] and type(
        student.sound_encoder
    ) is type(teacher.sound_encoder):
        student.sound_encoder.load_state_dict(teacher.sound_encoder.state_dict())
    for parameter in student.image_encoder.parameters():
        parameter.requires_grad_(False)
    return student


def _teach(
    student: VAR, features: np.ndarray, targets: torch.Tensor, config: RefitConfig, progress: bool
) -> None:
    student.train()
    optimizer = torch.optim.Adam(student.sound_encoder.parameters(), lr=config.lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, config.steps)
    generator = torch.Generator().manual_seed(config.seed)
    inputs = torch.from_numpy(features)
    bar = tqdm(range(config.steps), desc=f"refit f_S to {config.front_end}", disable=not progress)
    for _ in bar:
        rows = torch.randint(0, len(inputs), (config.batch_size,), generator=generator)
        loss = (1 - F.cosine_similarity(student.encode_sound(inputs[rows]), targets[rows])).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
        bar.set_postfix(loss=f"{loss.item():.4f}", refresh=False)


@torch.no_grad()
def _embed(var: VAR, features: np.ndarray) -> torch.Tensor:
    var.eval()
    return torch.cat([var.encode_sound(torch.from_numpy(chunk)) for chunk in np.array_split(features, 16)])


def _agreement(teacher: VAR, student: VAR, known: tuple[Any, Any], clips: tuple[Any, Any]) -> dict[str, Any]:
    """Mean and lowest cosine between the two f_S on these clips (old and new front end's features), and
    each VAR's nearest-command accuracy against the training clips `known`."""
    cosines = (_embed(teacher, clips[0].features) * _embed(student, clips[1].features)).sum(dim=1)
    intents = len(clips[0].intent_names)
    return {
        "clips": len(cosines),
        "mean_cosine": round(float(cosines.mean()), 4),
        "lowest_cosine": round(float(cosines.min()), 4),
        "teacher_nearest_command": nearest_command_accuracy(teacher, known[0], clips[0], intents)[0],
        "student_nearest_command": nearest_command_accuracy(student, known[1], clips[1], intents)[0],
    }
