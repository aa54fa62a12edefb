"""Teaching an arm world's VAR where a block ends (base models, in simulation).

A VAR trained on random exploration calls the gripper "at the block" 2–4 cm past each end of the block's
long side (x, towards the camera), where the ray already says nothing: random jumps almost never put the
gripper there, and from the camera's low angle the image barely changes. Its reward then falls only gently
past an end, and a policy paid by it, or seeing through it, ends there (`bench/block_edges.py`). This
fine-tunes the VAR on views rendered around the blocks' ends (`sim.explore.block_end_views`), labelled by the
ray as every base view is, with as many random views of the same rooms replayed beside them.
"""

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from learning.var.model import VAR


@dataclass(frozen=True)
class BlockEndsConfig:
    world: str
    sounds: str = "wordset"
    views: int = 12_000  # views around the blocks' ends
    replay_views: int = 12_000  # random exploration views of the same rooms
    epochs: int = 8
    learning_rate: float = 1e-4
    patience: int = 3  # epochs without a better held-out accuracy before stopping
    seed: int = 0
    threads: int = 1

    def __post_init__(self) -> None:
        if self.views < 1 or self.replay_views < 1:
            raise ValueError(
                f"views and replay views must be positive, got {self.views}, {self.replay_views}"
            )
        if self.epochs < 1:
            raise ValueError(f"epochs must be positive, got {self.epochs}")


def check_world_has_blocks(world: str) -> None:
    """Refuse a world with no blocks to place the gripper around (the TurtleBot's arena) before rendering."""
    from sim import has_blocks

    if not has_blocks(world):
        raise ValueError(
            f"the {world} world has no blocks whose ends a VAR could learn: only the arm worlds (kuka, "
            f"kinova) have them"
        )


@dataclass
class BlockEndsResult:
    var: VAR
    report: dict[str, Any]


def teach_block_ends(
    base_var: Path, config: BlockEndsConfig, rooms: Any, folder: Path, progress: bool = True
) -> BlockEndsResult:
    """The base VAR fine-tuned on views around the blocks' ends in `rooms` (the base's room ranges, a room
    per scene) with random views of those rooms replayed as half of every batch; `folder` keeps the views and
    the fine-tune's run, one per starting VAR (an interrupted fine-tune of the same VAR resumes there)."""
    import hashlib

    from learning.var.checkpoint import load_var
    from learning.var.dataset import collect_dataset
    from learning.var.finetune import finetune_config
    from learning.var.train import train

    image_size = load_var(base_var).config.image_size
    ends, replay = (
        collect_dataset(
            config.world, count, folder / name, seed=config.seed + offset, image_size=image_size,
            domain=rooms, progress=progress, views=views,
        )
        for name, count, offset, views in (
            ("block_end_views", config.views, 0, "block_ends"),
            ("random_views", config.replay_views, 1, "random"),
        )
    )  # fmt: skip
    started_from = hashlib.sha256(Path(base_var).read_bytes()).hexdigest()[:12]
    training = finetune_config(
        base_var, str(ends.path), config.sounds, folder / f"finetune-{started_from}",
        replay_dataset=str(replay.path),
        replay_fraction=0.5, epochs=config.epochs, lr=config.learning_rate, patience=config.patience,
        seed=config.seed, threads=config.threads,
    )  # fmt: skip
    result = train(training)
    report = {
        "config": asdict(config),
        "block_end_views_heard": ends.meta["heard_counts"],
        "steps": result.steps,
        "epochs": result.epochs_completed,
        "seconds": round(result.seconds, 1),
        "best_held_out_accuracy": result.best_val_accuracy,
        "stopped_early": result.stopped_early,
    }
    return BlockEndsResult(load_var(result.checkpoint), report)
