"""One-hot pre-training of the baselines' encoders (the paper's NoAux+SparseR starts from these).

The paper's sparse-reward baseline does not learn its image and sound encoders from the sparse reward alone:
they are first trained as classifiers on 50,000 one-hot labels. Here:

- the policy's image CNN (`ImageEncoder`, at the policy's image size) learns what is in view — one of the
  intents or "nothing" — from a collected triplet dataset's `heard` ids (each view = one label);
- the policy's goal CNN (`SoundEncoder`) learns which intent a clip commands, from the corpus's training
  split (each clip = one label).

Both heads are thrown away; the encoder weights are loaded into a `Policy` before PPO starts
(`PPOConfig.init_encoders`), and the labels are counted with the run's.
"""

from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F
from tqdm import tqdm

from learning.rl.policy import GOAL_FEATURES, ImageEncoder, Policy, SoundEncoder, downsample_images

if TYPE_CHECKING:
    from learning.var.dataset import ImageDataset

ENCODERS_KIND = "varbot-onehot-encoders"


@dataclass
class PretrainConfig:
    dataset: str  # a collected triplet dataset (`varbot var collect`): its views and heard ids
    sounds: str = "wordset"  # corpus whose training split teaches the goal encoder
    policy_image_size: int = 32
    hidden: int = 128  # the policy's image-feature size (PolicyConfig.hidden)
    steps: int = 2000  # per encoder
    batch_size: int = 128
    learning_rate: float = 1e-3
    validation_fraction: float = 0.05
    seed: int = 0
    threads: int = 1


def _views_at_policy_size(dataset: "ImageDataset", size: int, chunk: int = 2048) -> np.ndarray:
    out = np.empty((len(dataset), size, size, 3), dtype=np.uint8)
    for start in range(0, len(dataset), chunk):
        block = torch.from_numpy(np.array(dataset.images[start : start + chunk]))  # a writable copy
        out[start : start + chunk] = downsample_images(block, size).numpy()
    return out


def _fit(
    encoder: nn.Module,
    head: nn.Linear,
    inputs: torch.Tensor,
    labels: torch.Tensor,
    config: PretrainConfig,
    generator: torch.Generator,
    what: str,
    progress: bool,
    augment: Callable[[torch.Tensor, torch.Generator], torch.Tensor] | None = None,
) -> dict[str, float]:
    """Cross-entropy on a random split, batches drawn class-balanced; returns training and held-out
    accuracy."""
    order = torch.randperm(len(labels), generator=generator)
    held = max(1, int(len(labels) * config.validation_fraction))
    val, train = order[:held], order[held:]
    counts = torch.bincount(labels[train])
    weights = 1.0 / counts[labels[train]].float()
    model = nn.Sequential(encoder, head)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    bar = tqdm(range(config.steps), desc=f"one-hot {what}", disable=not progress, unit="step")
    for _ in bar:
        batch = train[torch.multinomial(weights, config.batch_size, replacement=True, generator=generator)]
        x = inputs[batch] if augment is None else augment(inputs[batch], generator)
        loss = F.cross_entropy(model(x), labels[batch])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        bar.set_postfix(loss=f"{loss.item():.3f}")
    model.eval()
    with torch.inference_mode():
        return {
            **_accuracies(model, inputs[train[:4096]], labels[train[:4096]], "train"),
            **_accuracies(model, inputs[val], labels[val], "val"),
        }


def _accuracies(model: nn.Module, inputs: torch.Tensor, labels: torch.Tensor, part: str) -> dict[str, float]:
    """Accuracy, and the mean of per-class recalls (most views show nothing, so plain accuracy flatters)."""
    right = model(inputs).argmax(dim=1) == labels
    recalls = [right[labels == k].float().mean() for k in labels.unique()]
    return {
        f"{part}_accuracy": float(right.float().mean()),
        f"{part}_balanced_accuracy": float(torch.stack(recalls).mean()),
    }


def pretrain_encoders(config: PretrainConfig, out: Path, progress: bool = True) -> dict[str, Any]:
    """Train both encoders as classifiers and save their weights, accuracies and label counts to `out`."""
    from learning.augment import augment_features
    from learning.sounds import load_corpus
    from learning.var.dataset import NOTHING_HEARD, open_dataset

    torch.set_num_threads(config.threads)
    generator = torch.Generator().manual_seed(config.seed)
    torch.manual_seed(config.seed)
    corpus = load_corpus(config.sounds).subset("train")
    num_intents = len(corpus.intent_names)

    dataset = open_dataset(config.dataset)
    images = torch.from_numpy(_views_at_policy_size(dataset, config.policy_image_size))
    in_view = torch.from_numpy(np.where(dataset.heard == NOTHING_HEARD, num_intents, dataset.heard))
    image_encoder = ImageEncoder(config.policy_image_size, config.hidden)
    image_scores = _fit(image_encoder, nn.Linear(config.hidden, num_intents + 1), images, in_view,
                        config, generator, "image", progress)  # fmt: skip

    features = torch.from_numpy(np.asarray(corpus.features, dtype=np.float32))
    intents = torch.from_numpy(np.asarray(corpus.intent, dtype=np.int64))
    goal_encoder = SoundEncoder(GOAL_FEATURES)
    sound_scores = _fit(goal_encoder, nn.Linear(GOAL_FEATURES, num_intents), features, intents,
                        config, generator, "sound", progress, augment=augment_features)  # fmt: skip

    payload = {
        "kind": ENCODERS_KIND,
        "config": asdict(config),
        "num_intents": num_intents,
        "image_encoder": image_encoder.state_dict(),
        "goal_encoder": goal_encoder.state_dict(),
        "labels": {"onehot_image_labels": len(dataset), "onehot_sound_labels": len(intents)},
        "accuracy": {"image": image_scores, "sound": sound_scores},
    }
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(payload, out)
    return {k: payload[k] for k in ("labels", "accuracy", "num_intents")}


def read_encoders(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"no pre-trained encoders at {path}; make them with `varbot rl pretrain DATASET --out {path}`"
        )
    payload = torch.load(path, map_location="cpu", weights_only=True)
    if payload.get("kind") != ENCODERS_KIND:
        raise ValueError(f"{path} is not a file of one-hot pre-trained encoders")
    return payload


def load_encoders_into(policy: Policy, path: str | Path) -> dict[str, int]:
    """Copy pre-trained image and goal encoders into a baseline policy; returns the labels they used."""
    payload = read_encoders(path)
    config = policy.config
    made_for = payload["config"]
    if (made_for["policy_image_size"], made_for["hidden"]) != (config.policy_image_size, config.hidden):
        raise ValueError(
            f"{path} holds encoders for {made_for['policy_image_size']} px images and {made_for['hidden']} "
            f"features; this policy sees {config.policy_image_size} px and has {config.hidden}"
        )
    policy.image_encoder.load_state_dict(payload["image_encoder"])
    policy.goal_encoder.load_state_dict(payload["goal_encoder"])
    return dict(payload["labels"])
