"""Do a base model's image features say where the blocks are, in the held-out rooms too? (issue 25)

A base policy fails in the held-out rooms by not arriving at the block it understood (bench/rooms.py). This
asks which image features still carry the geometry there. Frames of the Kuka world are rendered with the
gripper at random places; the target is the offset from the gripper to each of the four blocks (8 numbers,
metres, simulator ground truth: a bench, not the product). Linear ridge probes are fit on frames from the
randomised training rooms and scored on new frames of each room of `--rooms`, for two feature sets of the
same base model: the VAR image encoder's hidden layer (trained on triplets over the randomised rooms) and the
policy's own image encoder (trained by PPO's reward alone). R² and mean absolute error per room.
Prints a table and writes bench/results/view_probe.json with the load average it ran under.

    nice -n 5 .venv/bin/python bench/view_probe.py [--base worker/base_models/kuka] [--frames 600]
        [--rooms randomised,training,unseen_room,lamplit_room] [--ridge 10]
"""

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from conditions import measure_and_publish
from result_files import relative_path
from rich.table import Table
from tqdm import tqdm

RESULTS = Path(__file__).resolve().parent / "results" / "view_probe.json"
FIT_ROOM = "randomised"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--base", type=Path, default=None, help="Kuka base model folder (default: find_base)")
    parser.add_argument("--frames", type=int, default=600, help="fit frames; each scored room gets a third")
    parser.add_argument("--rooms", default="randomised,training,unseen_room,lamplit_room")
    parser.add_argument("--ridge", type=float, default=10.0, help="penalty per 100 fit frames")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=RESULTS)
    return parser.parse_args(argv)


def frames(room: str, count: int, seed: int, image_size: int = 96) -> tuple[np.ndarray, np.ndarray]:
    """`count` views of the Kuka world in `room`, each after 0-3 random jumps of the gripper, and the offsets
    (x, y) from the gripper to each block, blocks in slot order."""
    from core.rooms import world_room
    from sim.kuka_blocks import KukaBlocksEnv

    env = KukaBlocksEnv(image_size=image_size, domain=world_room(room))
    rng = np.random.default_rng(seed)
    images, offsets = [], []
    try:
        for index in tqdm(range(count), desc=room, leave=False):
            obs, _ = env.reset(seed=seed * 1_000_003 + index)
            for _ in range(int(rng.integers(0, 4))):
                obs, *_ = env.random_view_step(rng)
            gripper = np.asarray(env.arm.gripper_xy())
            offsets.append(np.concatenate([np.asarray(env.slot_position(s)[:2]) - gripper for s in range(4)]))
            images.append(obs["image"])
    finally:
        env.close()
    return np.stack(images), np.stack(offsets)


def fit_ridge(
    features: np.ndarray, targets: np.ndarray, penalty: float
) -> Callable[[np.ndarray], np.ndarray]:
    """A linear map from standardised features to targets, ridge-penalised; returns its predictor."""
    mean, scale = features.mean(0), features.std(0) + 1e-6
    x = (features - mean) / scale
    weights = np.linalg.solve(x.T @ x + penalty * np.eye(x.shape[1]), x.T @ (targets - targets.mean(0)))
    return lambda new: ((new - mean) / scale) @ weights + targets.mean(0)


def scores(predicted: np.ndarray, targets: np.ndarray) -> dict[str, float]:
    residual = ((predicted - targets) ** 2).sum()
    spread = ((targets - targets.mean(0)) ** 2).sum()
    return {
        "r2": round(float(1 - residual / spread), 3),
        "mae_cm": round(float(100 * np.abs(predicted - targets).mean()), 2),
    }


def encoders(base_folder: Path) -> dict[str, Callable[[np.ndarray], np.ndarray]]:
    import torch

    from learning.rl.checkpoints import load_policy
    from learning.rl.frozen_var import load_frozen_var

    var = load_frozen_var(base_folder / "var.pt").model  # type: ignore[union-attr]
    policy, _ = load_policy(base_folder / "policy.pt")

    def var_hidden(images: np.ndarray) -> np.ndarray:  # the head's first layer, before the embedding
        with torch.no_grad():
            return var.image_encoder.hidden(torch.from_numpy(images)).numpy()

    def policy_encoder(images: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return policy.image_encoder(policy.view_of(torch.from_numpy(images))).numpy()

    return {"VAR image encoder (hidden layer)": var_hidden, "policy image encoder": policy_encoder}


def measure(args: argparse.Namespace) -> dict:
    import torch

    from worker.base_models import BaseModel, find_base

    torch.set_num_threads(1)
    base = BaseModel("kuka", args.base) if args.base else find_base("kuka")
    rooms = [room for room in args.rooms.split(",") if room]
    fit_images, fit_targets = frames(FIT_ROOM, args.frames, args.seed)
    scored = {room: frames(room, args.frames // 3, args.seed + 1 + k) for k, room in enumerate(rooms)}
    rows = []
    for name, encode in encoders(base.folder).items():
        predict = fit_ridge(encode(fit_images), fit_targets, args.ridge * args.frames / 100)
        rows.append(
            {"features": name, **{room: scores(predict(encode(i)), t) for room, (i, t) in scored.items()}}
        )
    return {
        "base": relative_path(base.folder),
        "fit_room": FIT_ROOM,
        "fit_frames": args.frames,
        "scored_frames_per_room": args.frames // 3,
        "rooms": rooms,
        "ridge": args.ridge,
        "rows": rows,
    }


def table(result: dict) -> Table:
    view = Table(
        title=f"{result['base']}: gripper-to-block offsets read linearly off image features (R² / MAE)"
    )
    view.add_column("features")
    for room in result["rooms"]:
        view.add_column(room, justify="right")
    for row in result["rows"]:
        view.add_row(
            row["features"], *(f"{row[r]['r2']:.2f} / {row[r]['mae_cm']:.1f} cm" for r in result["rooms"])
        )
    return view


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    measure_and_publish("view_probe", lambda: measure(args), table, args.out, argv)


if __name__ == "__main__":
    main()
