"""A VAR's image encoder adapted to a room from the room's own views (adaptive batch normalisation): the
statistics move, by the share asked, and nothing else does; too few views, or views that are not images,
are refused with what to do. Views of the training room can still be seen by the base's statistics, and
trained through."""

import copy

import numpy as np
import pytest
import torch

from core.rooms import MIN_ROOM_VIEWS
from learning.var.model import VAR, VARConfig
from learning.var.room_adaptation import adapt_to_room, batch_norm_statistics, seeing_by

SIZE = 16


def _encoder() -> torch.nn.Module:
    torch.manual_seed(0)
    var = VAR(VARConfig(image_size=SIZE))
    var.train()
    training_room = torch.randint(0, 256, (64, SIZE, SIZE, 3), dtype=torch.uint8)
    with torch.no_grad():
        for _ in range(20):  # statistics of a "training room": uniform colours
            var.image_encoder.hidden(training_room)
    return var.image_encoder.eval()


def _room(views: int = MIN_ROOM_VIEWS, seed: int = 1) -> np.ndarray:
    """A darker, warmer room than the training one."""
    rng = np.random.default_rng(seed)
    return (rng.integers(0, 120, (views, SIZE, SIZE, 3)) * np.array([1.0, 0.6, 0.4])).astype(np.uint8)


def test_the_statistics_move_toward_the_rooms_and_no_weight_changes() -> None:
    encoder = _encoder()
    weights = {k: v.clone() for k, v in encoder.named_parameters()}
    before = batch_norm_statistics(encoder)

    adaptation = adapt_to_room(encoder, _room(), share=1.0)

    assert all(torch.equal(weights[k], v) for k, v in encoder.named_parameters())
    after = batch_norm_statistics(encoder)
    assert all(not torch.allclose(after[k], before[k]) for k in before)
    assert adaptation.views == MIN_ROOM_VIEWS and len(adaptation.mean_shift) == len(before) // 2
    assert adaptation.mean_shift[0] > 0.1 and min(adaptation.mean_shift) > 0
    assert not encoder.training, "left ready to act"
    first = encoder.features[0]
    with torch.no_grad():
        x = torch.from_numpy(_room()).permute(0, 3, 1, 2).float().div(127.5).sub(1.0)
        normalised = (first[0](x) - first[1].running_mean[None, :, None, None]) / first[1].running_var[
            None, :, None, None
        ].add(first[1].eps).sqrt()
    assert normalised.mean(dim=(0, 2, 3)).abs().max() < 1e-3, "the room's first layer is centred"


def test_half_the_share_moves_the_statistics_half_the_way() -> None:
    full, half = _encoder(), _encoder()
    before = batch_norm_statistics(full)
    adapt_to_room(full, _room(), share=1.0)
    adapt_to_room(half, _room(), share=0.5)
    room, halfway = batch_norm_statistics(full), batch_norm_statistics(half)
    for key in before:
        torch.testing.assert_close(halfway[key], (before[key] + room[key]) / 2)


def test_a_robot_moved_again_adapts_from_the_base_statistics_not_the_last_rooms() -> None:
    encoder = _encoder()
    first = adapt_to_room(encoder, _room(seed=1), share=0.5)
    adapt_to_room(encoder, _room(seed=2) // 2, share=0.5, statistics_before=first.statistics_before)
    fresh = _encoder()
    adapt_to_room(fresh, _room(seed=2) // 2, share=0.5)
    moved, direct = batch_norm_statistics(encoder), batch_norm_statistics(fresh)
    for key in moved:
        torch.testing.assert_close(moved[key], direct[key])


def test_share_zero_gives_back_the_base_statistics_without_views() -> None:
    encoder = _encoder()
    base = batch_norm_statistics(encoder)
    first = adapt_to_room(encoder, _room(), share=0.5)
    back = adapt_to_room(encoder, _room(views=0), share=0.0, statistics_before=first.statistics_before)
    assert back.views == 0 and back.mean_shift == [0.0] * (len(base) // 2)
    assert all(torch.equal(base[k], v) for k, v in batch_norm_statistics(encoder).items())


def test_too_few_views_or_views_that_are_not_images_are_refused_with_what_to_do() -> None:
    encoder = _encoder()
    before = batch_norm_statistics(encoder)
    refusal = f"at least {MIN_ROOM_VIEWS} of its camera views, got 10: capture more"
    with pytest.raises(ValueError, match=refusal):
        adapt_to_room(encoder, _room(views=10))
    with pytest.raises(ValueError, match="must be uint8"):
        adapt_to_room(encoder, _room().astype(np.float32))
    with pytest.raises(ValueError, match="share must be from 0 to 1"):
        adapt_to_room(encoder, _room(), share=1.5)
    assert all(torch.equal(before[k], v) for k, v in batch_norm_statistics(encoder).items()), "nothing moved"


def test_training_room_views_are_seen_by_the_base_statistics_for_a_while_and_trained_through() -> None:
    encoder = _encoder()
    adaptation = adapt_to_room(encoder, _room(), share=0.5)
    adapted = batch_norm_statistics(encoder)
    base = copy.deepcopy(encoder)
    base.load_state_dict(adaptation.statistics_before, strict=False)
    views = torch.from_numpy(_room(views=4, seed=3))

    with seeing_by(encoder, adaptation.statistics_before):
        seen = encoder(views).square().sum()
    seen.backward()  # after the room's statistics came back
    expected = base(views).square().sum()
    expected.backward()

    torch.testing.assert_close(seen, expected)
    for (name, parameter), (_, reference) in zip(
        encoder.named_parameters(), base.named_parameters(), strict=True
    ):
        torch.testing.assert_close(parameter.grad, reference.grad, msg=name)
    assert all(torch.equal(adapted[k], v) for k, v in batch_norm_statistics(encoder).items())
    with torch.no_grad():
        assert not torch.allclose(encoder(views), base(views)), "the room's statistics see otherwise"
