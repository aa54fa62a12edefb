"""Pictures: the embedding sphere (the paper's Fig. 5) and training curves."""

import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from learning.var.evaluate import embed_images, embed_sounds
from learning.var.model import VAR

NOTHING_COLOUR = "0.55"
VIEWPOINTS = ((20, 35), (-25, 215))  # (elevation, azimuth) in degrees: front and back of the sphere


def _choose(count: int, limit: int, rng: np.random.Generator) -> np.ndarray:
    return np.sort(rng.choice(count, size=min(count, limit), replace=False))


def plot_sphere(
    var: VAR,
    images: Any,
    corpus: Any,
    path: str | Path,
    splits: list[str] | None = None,
    max_images: int = 600,
    max_clips: int = 300,
    seed: int = 0,
) -> Path:
    """Image embeddings (circles) and sound embeddings (triangles) on the unit sphere, coloured by intent."""
    rng = np.random.default_rng(seed)
    image_rows = _choose(len(images.heard), max_images, rng)
    image_points = embed_images(var, np.asarray(images.images[image_rows]))
    image_labels = np.asarray(images.heard)[image_rows]
    clips = corpus.subset(splits) if splits else corpus
    clip_rows = _choose(len(clips.intent), max_clips, rng)
    clip_points = embed_sounds(var, clips.features[clip_rows])
    clip_labels = clips.intent[clip_rows]
    silence = embed_sounds(var, np.zeros((1, *clips.features.shape[1:]), np.float32))

    colours = plt.get_cmap("tab10")
    figure = plt.figure(figsize=(12, 6))
    for panel, (elevation, azimuth) in enumerate(VIEWPOINTS, start=1):
        axes = figure.add_subplot(1, 2, panel, projection="3d")
        _draw_unit_sphere(axes)
        for k, name in enumerate(corpus.intent_names):
            mask = image_labels == k
            axes.scatter(
                *image_points[mask].T, marker="o", s=14, color=colours(k), alpha=0.5, label=f"image: {name}"
            )
            mask = clip_labels == k
            axes.scatter(
                *clip_points[mask].T,
                marker="^",
                s=40,
                color=colours(k),
                edgecolors="k",
                linewidths=0.3,
                label=f"sound: {name}",
            )
        nothing = image_labels < 0
        axes.scatter(
            *image_points[nothing].T,
            marker="o",
            s=14,
            color=NOTHING_COLOUR,
            alpha=0.4,
            label="image: nothing / several",
        )
        axes.scatter(
            *silence.T, marker="^", s=120, color=NOTHING_COLOUR, edgecolors="k", label="sound: silence"
        )
        axes.view_init(elev=elevation, azim=azimuth)
        axes.set_box_aspect((1, 1, 1))
        axes.set_axis_off()
        axes.set(
            xlim=(-1, 1), ylim=(-1, 1), zlim=(-1, 1), title=f"elevation {elevation}°, azimuth {azimuth}°"
        )
    handles, labels = figure.axes[0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="lower center", ncol=5, fontsize=8, frameon=False)
    world = images.meta.get("world", "?") if hasattr(images, "meta") else "?"
    figure.suptitle(f"VAR embeddings on the unit sphere ({world}, sounds: {', '.join(corpus.intent_names)})")
    figure.tight_layout(rect=(0, 0.08, 1, 0.95))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def _draw_unit_sphere(axes: Any) -> None:
    u, v = np.mgrid[0 : 2 * np.pi : 24j, 0 : np.pi : 12j]
    axes.plot_wireframe(np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v), color="0.85", linewidth=0.4)


def plot_metrics(metrics_path: str | Path, png_path: str | Path) -> Path | None:
    """Training loss and accuracies (train, held-out, replay held-out) against optimiser steps."""
    metrics_path = Path(metrics_path)
    if not metrics_path.is_file():
        return None
    records = [json.loads(line) for line in metrics_path.read_text().splitlines() if line]
    train = [r for r in records if r["kind"] == "train"]
    val = [r for r in records if r["kind"] == "val" and "val_accuracy" in r]
    replay = [r for r in records if r["kind"] == "val" and "replay_val_accuracy" in r]
    figure, (loss_axes, accuracy_axes) = plt.subplots(1, 2, figsize=(11, 4))
    loss_axes.plot([r["step"] for r in train], [r["loss"] for r in train], label="train")
    loss_axes.plot([r["step"] for r in val], [r["val_loss"] for r in val], "o-", label="held-out")
    loss_axes.set(xlabel="step", ylabel="triplet loss", title="loss")
    accuracy_axes.plot([r["step"] for r in train], [r["accuracy"] for r in train], label="train")
    accuracy_axes.plot([r["step"] for r in val], [r["val_accuracy"] for r in val], "o-", label="held-out")
    balanced = [r for r in val if "val_balanced_accuracy" in r]
    accuracy_axes.plot(
        [r["step"] for r in balanced],
        [r["val_balanced_accuracy"] for r in balanced],
        "^--",
        label="held-out, balanced (target in view / not)",
    )
    if replay:
        accuracy_axes.plot(
            [r["step"] for r in replay],
            [r["replay_val_accuracy"] for r in replay],
            "s-",
            label="held-out, original triplets",
        )
    accuracy_axes.set(xlabel="step", ylabel="triplet accuracy", title="accuracy", ylim=(0, 1.01))
    for axes in (loss_axes, accuracy_axes):
        axes.grid(alpha=0.3)
        axes.legend()
    figure.tight_layout()
    png_path = Path(png_path)
    figure.savefig(png_path, dpi=100)
    plt.close(figure)
    return png_path
