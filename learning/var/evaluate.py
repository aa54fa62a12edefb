"""How good a VAR is: triplet accuracy on held-out images per unheard tier of the corpus, and retrieval.

Ground-truth intents are used here only to score and to group, never to train.
"""

from typing import Any

import numpy as np
import torch

from learning.var.dataset import ImageDataset, SoundBank, draw_triplet_sounds
from learning.var.loss import triplet_correct
from learning.var.model import VAR

TRAIN_SPLIT = "train"


@torch.inference_mode()
def embed_images(var: VAR, images: np.ndarray, batch_size: int = 512) -> np.ndarray:
    var.eval()
    parts = [
        var.encode_image(torch.from_numpy(np.array(images[i : i + batch_size]))).numpy()
        for i in range(0, len(images), batch_size)
    ]
    return np.concatenate(parts) if parts else np.zeros((0, var.config.embedding_dim), np.float32)


@torch.inference_mode()
def embed_sounds(var: VAR, features: np.ndarray, batch_size: int = 1024) -> np.ndarray:
    var.eval()
    parts = [
        var.encode_sound(torch.from_numpy(np.ascontiguousarray(features[i : i + batch_size]))).numpy()
        for i in range(0, len(features), batch_size)
    ]
    return np.concatenate(parts) if parts else np.zeros((0, var.config.embedding_dim), np.float32)


def unheard_tiers(corpus: Any) -> list[str]:
    return [split for split in dict.fromkeys(corpus.split.tolist()) if split != TRAIN_SPLIT]


def _centroids(embeddings: np.ndarray, labels: np.ndarray, num_intents: int) -> np.ndarray:
    centroids = np.stack([embeddings[labels == k].mean(axis=0) for k in range(num_intents)])
    return centroids / np.linalg.norm(centroids, axis=1, keepdims=True).clip(min=1e-9)


def command_similarities(var: VAR, known: Any, unknown: Any, num_intents: int) -> np.ndarray:
    """(clips of `unknown`, intents): cosine of each clip's embedding to the mean direction of each command
    among the `known` clips. `known` and `unknown` have `features` and `intent` (corpus subsets)."""
    centroids = _centroids(embed_sounds(var, known.features), known.intent, num_intents)
    return embed_sounds(var, unknown.features) @ centroids.T  # the VAR's embeddings are unit vectors


def command_margins(similarity: np.ndarray, intent: np.ndarray) -> np.ndarray:
    """Per clip: cosine to its own command minus the best other command's (`command_similarities` rows)."""
    own = similarity[np.arange(len(intent)), intent]
    others = np.where(np.eye(similarity.shape[1], dtype=bool)[intent], -np.inf, similarity)
    return own - others.max(axis=1)


def nearest_command_accuracy(
    var: VAR, known: Any, unknown: Any, num_intents: int
) -> tuple[float, np.ndarray]:
    """How often a clip embeds nearest its own command (what a goal clip must do for the policy to head for
    the right object); returns the rate and the per-clip hits."""
    hits = command_similarities(var, known, unknown, num_intents).argmax(axis=1) == unknown.intent
    return float(hits.mean()), hits


def triplet_accuracy(
    image_embeddings: np.ndarray, heard: np.ndarray, var: VAR, bank: SoundBank, seed: int, repeats: int = 2
) -> dict[str, float]:
    """Accuracy of ‖v_i − v+‖ < ‖v_i − v−‖ with sounds drawn from `bank` (each image `repeats` times)."""
    rng = np.random.default_rng([seed, 11])
    heard = np.tile(heard, repeats)
    anchors = torch.from_numpy(np.tile(image_embeddings, (repeats, 1)))
    positive, negative = draw_triplet_sounds(heard, bank, rng)
    v_pos = torch.from_numpy(embed_sounds(var, positive))
    v_neg = torch.from_numpy(embed_sounds(var, negative))
    correct = triplet_correct(anchors, v_pos, v_neg).numpy()
    in_view = heard >= 0
    return {
        "triplet_accuracy": float(correct.mean()),
        "triplet_accuracy_in_view": float(correct[in_view].mean()) if in_view.any() else float("nan"),
        "triplet_accuracy_nothing_in_view": float(correct[~in_view].mean())
        if (~in_view).any()
        else float("nan"),
        "triplets": len(correct),
    }


def evaluate_var(var: VAR, images: ImageDataset, corpus: Any, seed: int = 0) -> dict[str, Any]:
    """Per tier: triplet accuracy and clip → image-cluster retrieval; overall: image → command retrieval.

    `images` should be views the VAR was not trained on (a dataset collected with another seed).
    """
    num_intents = len(corpus.intent_names)
    image_embeddings = embed_images(var, images.images)
    heard = np.asarray(images.heard)
    in_view = heard >= 0
    missing = [k for k in range(num_intents) if not (heard == k).any()]
    if missing:
        raise ValueError(f"The evaluation images never show intent(s) {missing}; collect more views.")

    train = corpus.subset(TRAIN_SPLIT)
    command_centroids = _centroids(embed_sounds(var, train.features), train.intent, num_intents)
    nearest_command = (image_embeddings[in_view] @ command_centroids.T).argmax(axis=1)
    image_clusters = _centroids(image_embeddings[in_view], heard[in_view], num_intents)

    result: dict[str, Any] = {
        "images": len(heard),
        "images_in_view": int(in_view.sum()),
        "image_to_command": float((nearest_command == heard[in_view]).mean()),
        "tiers": {},
    }
    for tier in [TRAIN_SPLIT, *unheard_tiers(corpus)]:
        clips = corpus.subset(tier)
        bank = SoundBank.build(clips.features, clips.intent, num_intents)
        scores = triplet_accuracy(image_embeddings, heard, var, bank, seed)
        clip_embeddings = embed_sounds(var, clips.features)
        scores["clip_to_image"] = float(
            ((clip_embeddings @ image_clusters.T).argmax(axis=1) == clips.intent).mean()
        )
        scores["clips"] = len(clips.intent)
        result["tiers"][tier] = scores
    return result
