"""bench/view_probe.py: its targets are the gripper-to-block offsets of the rendered world, and its probe
reads a linear signal off features and nothing off noise."""

import numpy as np
import view_probe as bench


def test_each_frame_comes_with_the_offsets_from_the_gripper_to_the_four_blocks() -> None:
    images, offsets = bench.frames("training", count=3, seed=4, image_size=32)
    assert images.shape == (3, 32, 32, 3) and images.dtype == np.uint8
    assert offsets.shape == (3, 8)
    slot_steps = np.diff(offsets.reshape(3, 4, 2), axis=1)  # blocks stand in a row along y, evenly spaced
    assert np.allclose(slot_steps[..., 0], 0.0) and np.allclose(slot_steps[..., 1], slot_steps[0, 0, 1])


def test_the_probe_reads_a_linear_signal_and_finds_nothing_in_noise() -> None:
    rng = np.random.default_rng(0)
    features = rng.normal(size=(400, 12))
    targets = features[:, :3] @ rng.normal(size=(3, 8))
    predict = bench.fit_ridge(features[:300], targets[:300], penalty=1.0)
    assert bench.scores(predict(features[300:]), targets[300:])["r2"] > 0.99
    noise = rng.normal(size=(400, 12))
    predict = bench.fit_ridge(noise[:300], targets[:300], penalty=1.0)
    assert bench.scores(predict(noise[300:]), targets[300:])["r2"] < 0.1
