"""Teach a VAR's image encoder to see any room as the training room, so the policy that sees through it acts
in a room it never saw as it does at home (issue 25: a base model that survives a new room).

The shipped policy reads f_I's hidden layer. Trained over randomised rooms it still does far better in the
world's own look than in a new one (the Kuka base: 86.5 % at home, 37 % in `unseen_room`, whose checkered
table alone costs most of it). Here the student, a copy of the teacher's f_I, is taught on pairs of renders
of one scene (the same block row, gripper and camera): its input is the scene in a room drawn from
`RoomRanges` (for a share of pairs, the training room itself), its target the teacher's hidden layer for the
scene in the world's own look (loss: mean squared error over the target's spread, plus 1 − cosine of the
embeddings). f_S is unchanged, so goals keep their place on the sphere; the policy's frozen view is given the
student too. No held-out room is ever rendered here: the ranges leave them out (`core.rooms`), and the
evaluation of the result is the base's usual one.
"""

import copy
import dataclasses
import json
import math
import multiprocessing
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from learning.var.model import VAR

PAIRS_PER_CHUNK = 200  # views a worker renders between progress reports


@dataclass(frozen=True)
class InvarianceConfig:
    world: str = "kuka"
    views: int = 20_000  # scenes rendered twice: in a drawn room and in the world's own look
    views_per_scene: int = 8  # gripper moves between new block rows and rooms
    training_room_share: float = 0.25  # pairs whose input is the own look: what it sees at home stays
    steps: int = 3000
    batch_size: int = 128
    lr: float = 3e-4
    embedding_weight: float = 1.0
    desaturate_share: float = 0.0  # inputs moved part of the way to grey while teaching
    held_out_share: float = 0.05  # pairs kept back to report the agreement on
    workers: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        if self.views < 20:
            raise ValueError(f"views must be at least 20 (some are held out to measure on), not {self.views}")
        if not 0.0 <= self.training_room_share <= 1.0 or not 0.0 < self.held_out_share < 0.5:
            raise ValueError("training_room_share is in [0, 1] and held_out_share in (0, 0.5)")
        if self.steps < 1 or self.batch_size < 1 or self.views_per_scene < 1 or self.workers < 1:
            raise ValueError("steps, batch_size, views_per_scene and workers are 1 or more")


@dataclass
class InvarianceResult:
    var: VAR
    report: dict[str, Any]


# --- pairs of renders ---------------------------------------------------------------------------------------


def check_world_renders_rooms(world: str) -> None:
    """Refuse a world whose env cannot render one scene in another room (`render_as`): the TurtleBot's."""
    from sim import world_class

    if not hasattr(world_class(world), "render_as"):
        raise ValueError(
            f"the {world} world cannot render a scene in another room (its env has no render_as): room "
            f"invariance is taught on the block worlds (kuka, kinova)"
        )


def render_pairs(config: InvarianceConfig, image_size: int, folder: Path, progress: bool = True) -> Path:
    """`folder/inputs.npy` (each scene in a drawn room) and `folder/targets.npy` (the same scene in the
    world's own look), rendered by `config.workers` spawned processes; a complete folder of the same recipe
    is reused."""
    wanted = {**_pair_recipe(config), "image_size": image_size}
    meta = folder / "meta.json"
    if meta.is_file() and json.loads(meta.read_text()).get("recipe") == wanted:
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    meta.unlink(missing_ok=True)
    shape = (config.views, image_size, image_size, 3)
    for name in ("inputs.npy", "targets.npy"):
        np.lib.format.open_memmap(folder / name, "w+", np.uint8, shape).flush()
    chunks = [
        (str(folder), config, image_size, start, min(PAIRS_PER_CHUNK, config.views - start))
        for start in range(0, config.views, PAIRS_PER_CHUNK)
    ]
    started = time.perf_counter()
    bar = tqdm(
        total=config.views, desc=f"render {config.world} room pairs", unit="pair", disable=not progress
    )
    with multiprocessing.get_context("spawn").Pool(config.workers) as pool:  # no torch threads in a fork
        for done in pool.imap_unordered(_render_chunk, chunks):
            bar.update(done)
    bar.close()
    seconds = time.perf_counter() - started
    meta.write_text(json.dumps({"recipe": wanted, "render_s": round(seconds, 1)}, indent=2) + "\n")
    return folder


def _pair_recipe(config: InvarianceConfig) -> dict[str, Any]:
    """What the pairs are made of, as their meta.json keeps it (the ranges as JSON gives them back)."""
    from core.plain import as_lists
    from core.rooms import RoomRanges

    fields = ("world", "views", "views_per_scene", "training_room_share", "seed")
    ranges = as_lists(dataclasses.asdict(RoomRanges()))
    return {**{name: getattr(config, name) for name in fields}, "room_ranges": ranges}


def _render_chunk(args: tuple[str, InvarianceConfig, int, int, int]) -> int:
    """Render pairs [start, start + count): a new scene and room every `views_per_scene` views, the gripper
    moved as random exploration moves it."""
    import gymnasium as gym

    from core.rooms import RoomRanges
    from sim import world_id
    from sim.domain import DomainShift

    folder, config, image_size, start, count = args
    inputs = np.load(Path(folder) / "inputs.npy", mmap_mode="r+")
    targets = np.load(Path(folder) / "targets.npy", mmap_mode="r+")
    rng = np.random.default_rng([config.seed, start])
    env = gym.make(world_id(config.world), image_size=image_size, domain=RoomRanges(), render_images=False)
    world = env.unwrapped
    try:
        for row in range(start, start + count):
            if (row - start) % config.views_per_scene == 0:
                env.reset(seed=int(rng.integers(2**31 - 1)))
            world.random_view_step(rng)
            targets[row] = world.render_as(DomainShift())
            at_home = rng.random() < config.training_room_share
            inputs[row] = targets[row] if at_home else world.render()
        inputs.flush()
        targets.flush()
    finally:
        env.close()
    return count


# --- teaching ----------------------------------------------------------------------------------------------


def teach_room_invariance(
    teacher: VAR, folder: Path, config: InvarianceConfig, progress: bool = True
) -> InvarianceResult:
    """A VAR whose f_I gives, for a scene in any room of the pairs, what the teacher's gives for it in the
    world's own look; f_S is the teacher's. The report gives the agreement on held-out pairs before and
    after."""
    torch.manual_seed(config.seed)
    inputs = np.load(folder / "inputs.npy", mmap_mode="r")
    targets = np.load(folder / "targets.npy", mmap_mode="r")
    teacher = teacher.eval()
    target_hidden = _hidden(teacher, targets, progress)
    held_out = _held_out_rows(len(inputs), config)
    taught = np.setdiff1d(np.arange(len(inputs)), held_out)
    scale = float(target_hidden[torch.from_numpy(taught)].var(dim=0).mean())

    student = copy.deepcopy(teacher)
    before = _agreement(student, inputs, targets, target_hidden, held_out, scale)
    started = time.perf_counter()
    losses = _teach(student, inputs, target_hidden, taught, scale, config, progress)
    seconds = time.perf_counter() - started
    student.eval().requires_grad_(False)
    report = {
        "settings": dataclasses.asdict(config),
        "pairs": len(inputs),
        "pairs_recipe": json.loads((folder / "meta.json").read_text())["recipe"],
        "held_out_pairs": len(held_out),
        "target_spread": scale,
        "teach_s": round(seconds, 1),
        "final_loss": losses[-1] if losses else None,
        "agreement_before": before,
        "agreement_after": _agreement(student, inputs, targets, target_hidden, held_out, scale),
    }
    return InvarianceResult(student, report)


def _teach(
    student: VAR,
    inputs: np.ndarray,
    target_hidden: torch.Tensor,
    rows: np.ndarray,
    scale: float,
    config: InvarianceConfig,
    progress: bool,
) -> list[float]:
    """Adam on f_I up to its hidden layer; the last layer (hidden → sphere) stays the teacher's, so the same
    hidden layer gives the same embedding. Batch norms keep the teacher's statistics (eval mode), so a batch
    of odd rooms never moves what the policy's copy will normalise with."""
    encoder = student.image_encoder
    student.eval()
    student.requires_grad_(False)
    encoder.requires_grad_(True)
    encoder.head[-1].requires_grad_(False)  # the sphere stays where f_S's goals are: the hidden layer moves
    optimizer = torch.optim.Adam([p for p in encoder.parameters() if p.requires_grad], lr=config.lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, config.steps)
    rng = np.random.default_rng(config.seed)
    losses: list[float] = []
    bar = tqdm(range(config.steps), desc="teach f_I room invariance", disable=not progress)
    for _ in bar:
        batch = np.sort(rng.choice(rows, size=min(config.batch_size, len(rows)), replace=False))
        images = _desaturated(torch.from_numpy(inputs[batch]), config.desaturate_share, rng)
        loss = _loss(encoder, images, target_hidden[batch], scale, config)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
        losses.append(loss.item())
        bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}", refresh=False)
    return losses


def _desaturated(images: torch.Tensor, share: float, rng: np.random.Generator) -> torch.Tensor:
    """A `share` of the views moved part of the way to grey (by a random amount each): the same scene with
    less colour, so the encoder leans on shapes more than on hues (it adds no hue the ranges leave out)."""
    if share <= 0:
        return images
    amount = torch.from_numpy(rng.uniform(0, 1, len(images)) * (rng.random(len(images)) < share)).float()
    colour = images.float()
    grey = (colour @ torch.tensor([0.299, 0.587, 0.114])).unsqueeze(-1)
    amount = amount.view(-1, 1, 1, 1)
    return colour * (1 - amount) + grey * amount


def _loss(
    encoder: torch.nn.Module,
    images: torch.Tensor,
    target: torch.Tensor,
    scale: float,
    config: InvarianceConfig,
) -> torch.Tensor:
    hidden = encoder.hidden(images)
    head = encoder.head[-1]
    embedding_gap = 1 - F.cosine_similarity(head(hidden), head(target), dim=1)
    return F.mse_loss(hidden, target) / scale + config.embedding_weight * embedding_gap.mean()


@torch.no_grad()
def _hidden(var: VAR, images: np.ndarray, progress: bool = False, batch: int = 512) -> torch.Tensor:
    parts = [
        var.image_encoder.hidden(torch.from_numpy(np.array(images[start : start + batch])))
        for start in tqdm(range(0, len(images), batch), desc="teacher's view", disable=not progress)
    ]
    return torch.cat(parts)


def _held_out_rows(count: int, config: InvarianceConfig) -> np.ndarray:
    """Whole scenes held out (views of one scene are alike), spread over the pairs."""
    scenes = math.ceil(count / config.views_per_scene)
    every = max(2, round(1 / config.held_out_share))
    rows = [
        row
        for scene in range(0, scenes, every)
        for row in range(scene * config.views_per_scene, min(count, (scene + 1) * config.views_per_scene))
    ]
    return np.asarray(rows, dtype=np.int64)


@torch.no_grad()
def _agreement(
    var: VAR,
    inputs: np.ndarray,
    targets: np.ndarray,
    target_hidden: torch.Tensor,
    rows: np.ndarray,
    scale: float,
) -> dict[str, float]:
    """How close f_I's view of the held-out pairs' inputs is to the teacher's view of the world's own look:
    hidden-layer error over the target's spread, and the embeddings' mean cosine; split by whether the input
    was drawn in another room or is the world's own look."""
    var.eval()
    hidden = _hidden(var, inputs[rows])
    target = target_hidden[torch.from_numpy(rows)]
    head = var.image_encoder.head[-1]
    error = ((hidden - target) ** 2).mean(dim=1) / scale
    cosine = F.cosine_similarity(head(hidden), head(target), dim=1)
    at_home = torch.from_numpy(
        np.array([np.array_equal(inputs[row], targets[row]) for row in rows], dtype=bool)
    )
    result = {}
    for name, where in (("other_rooms", ~at_home), ("training_room", at_home)):
        if bool(where.any()):
            result[f"{name}_hidden_error"] = round(float(error[where].mean()), 4)
            result[f"{name}_embedding_cosine"] = round(float(cosine[where].mean()), 4)
            result[f"{name}_pairs"] = int(where.sum())
    return result
