"""Training curves: a run's success curve is small enough to keep with its results, and redraws without it."""

import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

from learning.rl.plots import plot_success_curves, success_curve


def write_metrics(run_dir: Path, updates: int) -> None:
    run_dir.mkdir(parents=True)
    records = [{"global_step": 800 * (u + 1), "recent_success": u / updates} for u in range(updates)]
    lines = [json.dumps(record) for record in records]
    (run_dir / "metrics.jsonl").write_text("\n".join(lines) + "\n")


def test_a_long_run_is_thinned_to_evenly_spaced_points_ending_at_its_last_update(tmp_path: Path) -> None:
    write_metrics(tmp_path / "run", updates=1250)

    curve = success_curve(tmp_path / "run", max_points=400)

    assert len(curve) <= 400
    steps = [step for step, _ in curve]
    assert steps[0] == 800 and steps[-1] == 1_000_000
    assert steps == sorted(steps)
    assert curve[1][0] - curve[0][0] == 4 * 800  # every fourth update
    assert curve[-1][1] == 1249 / 1250


def test_a_short_run_keeps_every_update(tmp_path: Path) -> None:
    write_metrics(tmp_path / "run", updates=30)

    assert len(success_curve(tmp_path / "run")) == 30


def test_stored_curves_are_drawn_after_the_run_directories_are_gone(tmp_path: Path) -> None:
    write_metrics(tmp_path / "a", updates=50)
    write_metrics(tmp_path / "b", updates=80)
    stored = json.loads(json.dumps({"a": success_curve(tmp_path / "a"), "b": success_curve(tmp_path / "b")}))
    for run in ("a", "b"):
        (tmp_path / run / "metrics.jsonl").unlink()

    out = plot_success_curves(stored, tmp_path / "figure.png", title="two runs")

    pixels = np.asarray(Image.open(out).convert("RGB")).reshape(-1, 3).astype(int)
    for first_colours in ((31, 119, 180), (255, 127, 14)):  # matplotlib's first two line colours: one per run
        assert (np.abs(pixels - first_colours).sum(axis=1) < 10).sum() > 100


def test_every_run_of_a_crowded_figure_has_a_colour_of_its_own(tmp_path: Path) -> None:
    runs = 14  # more than matplotlib's ten default colours, which would repeat
    curves = {f"run {i}": [[step, i / runs] for step in range(0, 100_000, 1_000)] for i in range(runs)}

    out = plot_success_curves(curves, tmp_path / "crowded.png", title="fourteen runs")

    pixels = np.asarray(Image.open(out).convert("RGB")).reshape(-1, 3).astype(int)
    for colour in plt.get_cmap("tab20").colors[:runs]:
        rgb = np.array([round(255 * c) for c in colour])
        assert (np.abs(pixels - rgb).sum(axis=1) < 10).sum() > 100, f"no line drawn in {rgb}"
