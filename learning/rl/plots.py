"""Training curves as PNG: one run's dashboard, and success-vs-steps for several runs on one axis."""

import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import FuncFormatter

THOUSANDS = FuncFormatter(lambda value, _: f"{value / 1000:.0f}k")  # env steps: 800k, not 800000

SuccessCurve = list[tuple[int, float]]  # (env steps, recent success rate) after each kept update


def read_metrics(run_dir: Path) -> list[dict]:
    path = Path(run_dir) / "metrics.jsonl"
    if not path.exists():
        raise FileNotFoundError(f"no metrics at {path}: is {run_dir} a `varbot rl train` run directory?")
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def plot_run(run_dir: Path, out: Path | None = None) -> Path | None:
    """success rate, episode return, PPO losses, throughput and where the time went, against env steps."""
    records = read_metrics(run_dir)
    if not records:
        return None
    out = Path(out or Path(run_dir) / "curves.png")
    steps = np.array([r["global_step"] for r in records])
    fig, axes = plt.subplots(2, 4, figsize=(18, 7))
    panels = [
        ("recent success rate", ["recent_success"]),
        ("episode return (intrinsic / task reward)", ["episode_return"]),
        ("losses", ["policy_loss", "value_loss", "aux_loss"]),
        ("approx. KL, clip fraction", ["approx_kl", "clipfrac"]),
        ("env steps / s", ["sps"]),
    ]
    for ax, (title, keys) in zip(axes.flat, panels, strict=False):
        for key in keys:
            ax.plot(steps, [r.get(key, np.nan) for r in records], label=key)
        ax.set_title(title)
        ax.set_xlabel("env steps")
        ax.xaxis.set_major_formatter(THOUSANDS)
        if len(keys) > 1:
            ax.legend(fontsize=8)
    ax = axes.flat[5]
    parts = ["env_s", "var_s", "policy_s", "update_s", "other_s"]
    totals = np.array([[r["time"][p] for p in parts] for r in records])
    shares = totals / totals.sum(axis=1, keepdims=True)
    ax.stackplot(steps, shares.T, labels=[p.removesuffix("_s") for p in parts])
    ax.set_title("share of update time")
    ax.set_xlabel("env steps")
    ax.xaxis.set_major_formatter(THOUSANDS)
    ax.legend(fontsize=8, loc="lower left")
    _plot_per_intent(axes.flat[0], steps, records, "recent_success_by_intent")
    _plot_target_weights(axes.flat[6], steps, records)
    axes.flat[7].axis("off")
    axes.flat[0].set_ylim(-0.02, 1.02)
    fig.suptitle(str(run_dir))
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def _plot_per_intent(ax: plt.Axes, steps: np.ndarray, records: list[dict], key: str) -> bool:
    """Thin lines, one per intent, of the per-intent list logged under `key` (older runs lack some keys).
    Returns whether there was anything to draw."""
    logged = [r.get(key) for r in records]
    width = max((len(values) for values in logged if values), default=0)
    for intent in range(width):
        line = [values[intent] if values else np.nan for values in logged]
        ax.plot(steps, line, linewidth=0.8, alpha=0.7, label=f"intent {intent}")
    if width:
        ax.legend(fontsize=7, ncol=2)
    return width > 0


def _plot_target_weights(ax: plt.Axes, steps: np.ndarray, records: list[dict]) -> None:
    """How often each target was asked for (the curriculum's probabilities); blank for uniform runs."""
    if not _plot_per_intent(ax, steps, records, "intent_weights"):
        ax.axis("off")
        return
    ax.set_title("target probabilities (curriculum)")
    ax.set_xlabel("env steps")
    ax.xaxis.set_major_formatter(THOUSANDS)
    ax.set_ylim(0, 1)


def success_curve(run_dir: Path, max_points: int = 400) -> SuccessCurve:
    """A run's recent success rate against env steps, thinned to at most `max_points` evenly spaced updates
    (the last one always kept): small enough to store beside the run's results."""
    records = read_metrics(run_dir)
    stride = max(1, math.ceil(len(records) / max_points))
    kept = records[::stride]
    if records and kept[-1] is not records[-1]:
        kept[-1] = records[-1]
    return [(int(r["global_step"]), float(r["recent_success"])) for r in kept]


def plot_success_curves(
    curves: dict[str, SuccessCurve], out: Path, title: str = "success rate vs env steps"
) -> Path:
    """One line per run (label → its success curve): recent success rate against env steps. Each run has its
    own colour (up to 20, then dashed), and with more than a few runs the legend sits beside the axes."""
    many = len(curves) > 6
    colours = plt.get_cmap("tab20" if len(curves) > 10 else "tab10").colors
    fig, ax = plt.subplots(figsize=(11, 4.5) if many else (7, 4.5))
    for i, (label, curve) in enumerate(curves.items()):
        style = "-" if i < len(colours) else "--"
        steps, success = [step for step, _ in curve], [rate for _, rate in curve]
        ax.plot(steps, success, label=label, color=colours[i % len(colours)], linestyle=style)
    ax.set_xlabel("env steps")
    ax.xaxis.set_major_formatter(THOUSANDS)
    ax.set_ylabel("success rate (last 100 training episodes)")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if many:
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    else:
        ax.legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
