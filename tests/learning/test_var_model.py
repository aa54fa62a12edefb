"""The VAR's encoders and checkpoints: shapes, normalisation, refusals, hand-made values (the intrinsic
reward is tested with the RL rewards, tests/learning/test_rl_reward.py)."""

import numpy as np
import pytest
import torch

from learning.var.checkpoint import CheckpointMismatchError, load_var, read_checkpoint, save_var
from learning.var.dataset import SILENCE_ID, SoundBank, triplet_sound_ids
from learning.var.loss import triplet_correct, triplet_loss
from learning.var.model import VAR, VARConfig

SMALL = VARConfig(image_size=32)


@pytest.fixture
def var() -> VAR:
    torch.manual_seed(0)
    return VAR(SMALL).eval()


def test_embeddings_have_dimension_d_and_unit_length(var: VAR) -> None:
    images = torch.randint(0, 256, (5, 32, 32, 3), dtype=torch.uint8)
    sounds = torch.randn(7, 100, 40) * 20
    image_embeddings, sound_embeddings = var.encode_image(images), var.encode_sound(sounds)
    assert image_embeddings.shape == (5, 3) and sound_embeddings.shape == (7, 3)
    torch.testing.assert_close(image_embeddings.norm(dim=1), torch.ones(5))
    torch.testing.assert_close(sound_embeddings.norm(dim=1), torch.ones(7))


def test_silence_has_a_well_defined_unit_embedding(var: VAR) -> None:
    silence = var.encode_sound(torch.zeros(2, 100, 40))
    assert torch.isfinite(silence).all()
    torch.testing.assert_close(silence.norm(dim=1), torch.ones(2))


def test_other_embedding_dimensions_are_possible() -> None:
    var = VAR(VARConfig(image_size=32, embedding_dim=8)).eval()
    assert var.encode_image(torch.zeros(1, 32, 32, 3, dtype=torch.uint8)).shape == (1, 8)


def test_f_s_may_be_wider_than_f_i_and_a_checkpoint_from_before_keeps_f_i_s_width(tmp_path) -> None:
    for front_end in ("mfcc", "speech-embedding-fast"):
        wide = VAR(VARConfig(image_size=32, front_end=front_end, sound_hidden=256))
        assert wide.sound_encoder.head[-1].in_features == 256
        assert wide.image_encoder.head[-1].in_features == 128
        assert load_var(save_var(wide, tmp_path / "wide.pt")).config.sound_hidden == 256
    older = {k: v for k, v in VARConfig(image_size=32).to_dict().items() if k != "sound_hidden"}
    assert VAR(VARConfig.from_dict(older)).sound_encoder.head[-1].in_features == 128
    with pytest.raises(ValueError, match="width must be 1 or more, not 0"):
        VARConfig(sound_hidden=0)


def test_a_copy_with_its_batch_norms_folded_sees_as_the_vars_f_i_does(var: VAR) -> None:
    """What the trainer embeds views with while acting: no batch norm left, the same f_I and hidden layer up
    to rounding, frozen; the VAR itself is untouched."""
    for norm in (m for m in var.modules() if isinstance(m, torch.nn.BatchNorm2d)):  # statistics a VAR learnt
        norm.running_mean.uniform_(-1, 1)
        norm.running_var.uniform_(0.5, 2)
        norm.weight.data.uniform_(0.5, 1.5)
        norm.bias.data.uniform_(-1, 1)
    before = {name: weights.clone() for name, weights in var.state_dict().items()}
    folded = var.with_batch_norms_folded()
    images = torch.randint(0, 256, (6, 32, 32, 3), dtype=torch.uint8)
    pairs = zip(var.encode_image_and_hidden(images), folded.encode_image_and_hidden(images), strict=True)
    for mine, theirs in pairs:
        torch.testing.assert_close(theirs, mine, atol=1e-5, rtol=1e-5)
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in folded.image_encoder.modules())
    assert not any(p.requires_grad for p in folded.parameters())
    assert all(torch.equal(var.state_dict()[name], weights) for name, weights in before.items())


def test_images_are_normalised_inside_the_model(var: VAR) -> None:
    """The encoder takes raw uint8 pixels, maps them to [-1, 1] itself, and refuses floats."""
    captured = {}
    first_conv = var.image_encoder.features[0][0]
    handle = first_conv.register_forward_hook(lambda module, inputs, output: captured.update(x=inputs[0]))
    var.encode_image(torch.tensor([[[[0, 255, 128]]]], dtype=torch.uint8).expand(1, 32, 32, 3).contiguous())
    handle.remove()
    pixel = captured["x"][0, :, 0, 0]
    torch.testing.assert_close(pixel, torch.tensor([-1.0, 1.0, 128 / 127.5 - 1]))
    with pytest.raises(ValueError, match="uint8"):
        var.encode_image(torch.zeros(1, 32, 32, 3))


def test_sound_statistics_standardise_each_coefficient(var: VAR) -> None:
    features = torch.randn(50, 100, 40) * torch.linspace(1, 300, 40) + 17
    var.set_sound_statistics(features)
    standardised = (features - var.sound_encoder.mfcc_mean) / var.sound_encoder.mfcc_std
    torch.testing.assert_close(standardised.mean(dim=(0, 1)), torch.zeros(40), atol=0.02, rtol=0)
    torch.testing.assert_close(standardised.std(dim=(0, 1)), torch.ones(40), atol=0.02, rtol=0)


def test_wrong_input_shapes_are_refused_with_the_expected_shape(var: VAR) -> None:
    with pytest.raises(ValueError, match=r"\(B, 32, 32, 3\)"):
        var.encode_image(torch.zeros(1, 96, 96, 3, dtype=torch.uint8))
    with pytest.raises(ValueError, match=r"\(B, 100, 40\)"):
        var.encode_sound(torch.zeros(1, 40, 100))


def test_triplet_loss_matches_the_paper_formula() -> None:
    anchor = torch.tensor([[1.0, 0, 0], [0, 1.0, 0]])
    positive = torch.tensor([[1.0, 0, 0], [1.0, 0, 0]])
    negative = torch.tensor([[0, 1.0, 0], [0, 1.0, 0]])
    # row 0: max(0, 0 - 2 + 1) = 0; row 1: max(0, 2 - 0 + 1) = 3
    assert triplet_loss(anchor, positive, negative, margin=1.0).item() == pytest.approx(1.5)
    assert triplet_correct(anchor, positive, negative).tolist() == [True, False]


def test_positives_match_heard_and_negatives_never_do() -> None:
    rng = np.random.default_rng(0)
    heard = rng.integers(-1, 4, 5000)
    positive, negative = triplet_sound_ids(heard, 4, rng)
    assert (positive[heard >= 0] == heard[heard >= 0]).all()
    assert (positive[heard < 0] == SILENCE_ID).all()
    assert (negative != positive).all()
    assert set(negative[heard < 0].tolist()) == {0, 1, 2, 3}
    assert set(negative[heard >= 0].tolist()) == {SILENCE_ID, 0, 1, 2, 3}


def test_sound_bank_draws_a_clip_of_the_asked_intent_and_zeros_for_silence() -> None:
    features = np.arange(8, dtype=np.float32)[:, None, None] * np.ones((8, 100, 40), np.float32)
    intent = np.array([3, 0, 1, 2, 0, 1, 2, 3])
    bank = SoundBank.build(features, intent, 4)
    drawn = bank.draw(np.array([0, 3, SILENCE_ID, 2]), np.random.default_rng(0))
    assert intent[int(drawn[0, 0, 0])] == 0 and intent[int(drawn[1, 0, 0])] == 3
    assert intent[int(drawn[3, 0, 0])] == 2 and not drawn[2].any()


def test_a_sound_selection_missing_an_intent_is_refused() -> None:
    with pytest.raises(ValueError, match=r"no clip for intent\(s\) \[2\]"):
        SoundBank.build(np.zeros((3, 100, 40), np.float32), np.array([0, 1, 3]), 4)


def test_checkpoint_round_trip_keeps_weights_config_and_extras(var: VAR, tmp_path) -> None:
    path = save_var(var, tmp_path / "var.pt", manifest_hash="abc", sound_set="wordset")
    loaded = load_var(path)
    assert loaded.config == var.config and not loaded.training
    images = torch.randint(0, 256, (3, 32, 32, 3), dtype=torch.uint8)
    torch.testing.assert_close(loaded.encode_image(images), var.encode_image(images))
    assert read_checkpoint(path)["sound_set"] == "wordset"


def test_a_checkpoint_refuses_a_model_of_another_shape(var: VAR, tmp_path) -> None:
    path = save_var(var, tmp_path / "var.pt")
    with pytest.raises(CheckpointMismatchError, match="image_size: model has 96, checkpoint has 32"):
        load_var(path, config=VARConfig(image_size=96))
    with pytest.raises(CheckpointMismatchError, match="embedding_dim"):
        load_var(path, config=VARConfig(image_size=32, embedding_dim=8))


def test_a_checkpoint_refuses_another_sound_corpus(var: VAR, tmp_path) -> None:
    path = save_var(var, tmp_path / "var.pt", manifest_hash="a" * 64, sound_set="wordset")
    with pytest.raises(CheckpointMismatchError, match="manifest hash"):
        load_var(path, manifest_hash="b" * 64)
    assert load_var(path, manifest_hash="a" * 64).config == var.config


def test_a_file_that_is_not_a_var_checkpoint_is_refused(tmp_path) -> None:
    torch.save({"something": 1}, tmp_path / "other.pt")
    with pytest.raises(CheckpointMismatchError, match="not a VAR checkpoint"):
        load_var(tmp_path / "other.pt")
    with pytest.raises(FileNotFoundError, match="varbot var train"):
        load_var(tmp_path / "missing.pt")
