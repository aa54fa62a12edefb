"""The VAR's sound front end: f_S is chosen by it, every checkpoint records it, a checkpoint is refused for
features of another front end (saying what differs), and one written before front ends existed is MFCC."""

import numpy as np
import pytest
import torch

from learning.rl.rewards import CurrentSound, corpus_bank, intrinsic_reward_from_embeddings
from learning.sounds import load_corpus
from learning.sounds.build import build_corpora
from learning.var.checkpoint import (
    CheckpointMismatchError,
    load_state_into,
    load_var,
    read_checkpoint,
    save_var,
)
from learning.var.dataset import collect_dataset
from learning.var.evaluate import nearest_command_accuracy
from learning.var.finetune import finetune_config
from learning.var.model import VAR, EmbeddingSoundEncoder, SoundEncoder, VARConfig
from learning.var.train import TrainConfig, train

EMBEDDING = "speech-embedding"
MFCC_VAR = VARConfig(image_size=32)
EMBEDDING_VAR = VARConfig(image_size=32, front_end=EMBEDDING)


def embedding_features(clips: int = 6, frames: int = 11, heard: int = 7, seed: int = 0) -> torch.Tensor:
    """Speech-embedding-like features: `heard` frames of values, then all-zero padding frames."""
    features = torch.zeros(clips, frames, 96)
    features[:, :heard] = torch.randn(clips, heard, 96, generator=torch.Generator().manual_seed(seed)) * 3 + 1
    return features


@pytest.fixture
def embedding_var() -> VAR:
    torch.manual_seed(0)
    var = VAR(EMBEDDING_VAR)
    var.set_sound_statistics(embedding_features(clips=40))
    return var.eval()


def test_the_front_end_chooses_the_sound_encoder_and_mfcc_is_the_default() -> None:
    assert VARConfig().front_end == "mfcc"
    assert isinstance(VAR(MFCC_VAR).sound_encoder, SoundEncoder)
    assert isinstance(VAR(EMBEDDING_VAR).sound_encoder, EmbeddingSoundEncoder)
    with pytest.raises(ValueError, match=r"Unknown sound front end 'wav2vec'.*mfcc, speech-embedding"):
        VARConfig(front_end="wav2vec")


def test_the_embedding_head_gives_unit_vectors_whatever_the_number_of_frames(embedding_var: VAR) -> None:
    for frames in (11, 36, 48):
        embeddings = embedding_var.encode_sound(embedding_features(frames=frames))
        assert embeddings.shape == (6, 3)
        torch.testing.assert_close(embeddings.norm(dim=1), torch.ones(6))


def test_padding_frames_change_nothing_and_silence_is_one_fixed_embedding(embedding_var: VAR) -> None:
    short = embedding_features(frames=7, heard=7)
    padded = torch.cat([short, torch.zeros(6, 29, 96)], dim=1)
    torch.testing.assert_close(embedding_var.encode_sound(short), embedding_var.encode_sound(padded))
    silence = embedding_var.encode_sound(torch.zeros(2, 11, 96))
    torch.testing.assert_close(silence[0], silence[1])
    torch.testing.assert_close(embedding_var.encode_silence()[0], silence[0])
    assert not torch.allclose(silence[0], embedding_var.encode_sound(short)[0])


def test_embedding_statistics_come_from_heard_frames_only() -> None:
    var = VAR(EMBEDDING_VAR)
    features = embedding_features(clips=200, heard=5)
    var.set_sound_statistics(features)
    heard = features[:, :5].reshape(-1, 96)
    torch.testing.assert_close(var.sound_encoder.feature_mean, heard.mean(dim=0))
    torch.testing.assert_close(var.sound_encoder.feature_std, heard.std(dim=0))


def test_features_of_the_other_front_end_are_refused_naming_the_front_end(embedding_var: VAR) -> None:
    with pytest.raises(ValueError, match=r"speech-embedding features shaped \(B, frames, 96\).*front_end="):
        embedding_var.encode_sound(torch.zeros(1, 100, 40))
    with pytest.raises(ValueError, match=r"mfcc features shaped \(B, 100, 40\)"):
        VAR(MFCC_VAR).encode_sound(torch.zeros(1, 11, 96))


def test_a_checkpoint_records_its_front_end_and_serves_the_same_embeddings(embedding_var, tmp_path) -> None:
    path = save_var(embedding_var, tmp_path / "var.pt")
    assert read_checkpoint(path)["config"]["front_end"] == EMBEDDING
    loaded = load_var(path, front_end=EMBEDDING)
    assert loaded.front_end == EMBEDDING
    features = embedding_features(seed=3)
    torch.testing.assert_close(loaded.encode_sound(features), embedding_var.encode_sound(features))
    images = torch.randint(0, 256, (6, 32, 32, 3), dtype=torch.uint8)
    reward = intrinsic_reward_from_embeddings(loaded.encode_image(images), loaded.encode_sound(features))
    assert reward.shape == (6,) and torch.isfinite(reward).all()


def test_a_checkpoint_is_refused_for_features_of_another_front_end(embedding_var, tmp_path) -> None:
    path = save_var(embedding_var, tmp_path / "var.pt")
    expected = (
        "the checkpoint's f_S reads 'speech-embedding' features, but 'mfcc' features are used here "
        r"\(compute the clips' features with front_end='speech-embedding', or train a VAR on 'mfcc'\)"
    )
    with pytest.raises(CheckpointMismatchError, match=expected):
        load_var(path, front_end="mfcc")
    with pytest.raises(CheckpointMismatchError, match=expected):
        load_var(path, config=VARConfig(image_size=32))
    with pytest.raises(CheckpointMismatchError, match=expected):
        load_state_into(VAR(MFCC_VAR), read_checkpoint(path), path)


def test_the_full_and_fast_speech_embedding_checkpoints_refuse_each_others_features(
    embedding_var, tmp_path
) -> None:
    """Both give 96 values a frame, so only the recorded name tells them apart: a VAR trained on the full
    front end's frames must not read the fast one's, which drop the edge windows its statistics counted."""
    path = save_var(embedding_var, tmp_path / "var.pt")
    with pytest.raises(
        CheckpointMismatchError, match="reads 'speech-embedding' features, but 'speech-embedding-fast'"
    ):
        load_var(path, front_end="speech-embedding-fast")


def test_a_checkpoint_from_before_front_ends_loads_as_mfcc_and_serves(tmp_path) -> None:
    torch.manual_seed(1)
    var = VAR(MFCC_VAR).eval()
    path = save_var(var, tmp_path / "old.pt")
    payload = read_checkpoint(path)
    del payload["config"]["front_end"]  # what every checkpoint written before issue 22 holds
    torch.save(payload, path)

    old = load_var(path, front_end="mfcc")
    assert old.front_end == "mfcc"
    mfcc = torch.from_numpy(np.random.default_rng(0).normal(size=(4, 100, 40)).astype(np.float32))
    torch.testing.assert_close(old.encode_sound(mfcc), var.encode_sound(mfcc))
    with pytest.raises(CheckpointMismatchError, match="reads 'mfcc' features, but 'speech-embedding'"):
        load_var(path, front_end=EMBEDDING)


# ---------------------------------------------------------------- end to end, on a real small corpus


@pytest.fixture(scope="module")
def wordset_embedded():
    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    return load_corpus("wordset", front_end=EMBEDDING)


@pytest.fixture(scope="module")
def trained(wordset_embedded, tmp_path_factory):
    """A tiny speech-embedding VAR: the views and settings of test_var_training's MFCC run."""
    collect_dataset("kuka", 1500, "test-var-kuka-train", seed=0, image_size=40, workers=2, progress=False)
    config = TrainConfig(
        dataset="test-var-kuka-train", sounds="wordset", run_dir=str(tmp_path_factory.mktemp("embedding")),
        model=VARConfig(front_end=EMBEDDING), max_steps=250, batch_size=64, lr=3e-3, warmup_steps=10,
        log_every_steps=5, checkpoint_every_steps=50, threads=1, progress=False,
    )  # fmt: skip
    return train(config)


def test_a_speech_embedding_var_trains_and_reads_unheard_voices(trained, wordset_embedded) -> None:
    var = load_var(trained.checkpoint, manifest_hash=wordset_embedded.manifest_hash, front_end=EMBEDDING)
    train_clips = wordset_embedded.subset("train")
    for tier in ("unheard-easy", "unheard-real-voices"):
        accuracy, _ = nearest_command_accuracy(var, train_clips, wordset_embedded.subset(tier), 4)
        assert accuracy > 0.6, (tier, accuracy)  # chance: 0.25
    assert trained.final_val_accuracy > 0.8


def test_the_goal_clips_of_a_run_are_featurised_with_the_vars_front_end(trained) -> None:
    """corpus → features → VAR → goal embeddings and S_t, as `varbot rl train` builds them."""
    var = load_var(trained.checkpoint)
    goals = corpus_bank("wordset", "unheard-easy", front_end=var.front_end).embed(var)
    assert goals.features.shape[1:] == (11, 96)
    torch.testing.assert_close(goals.embeddings.norm(dim=1), torch.ones(len(goals.features)))
    heard_now = CurrentSound(
        corpus_bank("wordset", "train", front_end=var.front_end).embed(var), var.encode_silence()
    )
    nothing_heard = heard_now.embeddings(np.array([-1, 2]), np.random.default_rng(0))
    torch.testing.assert_close(nothing_heard[0], var.encode_silence()[0])
    assert nothing_heard[1] in heard_now.bank.embeddings
    with pytest.raises(ValueError, match="this VAR's sound front end is 'speech-embedding'"):
        corpus_bank("wordset", "unheard-easy").embed(var)


def test_fine_tuning_keeps_the_checkpoints_front_end(trained, tmp_path) -> None:
    config = finetune_config(
        trained.checkpoint, "test-var-kuka-train", "wordset", tmp_path / "finetune", max_steps=20,
        threads=1, progress=False,
    )  # fmt: skip
    assert config.model.front_end == EMBEDDING
    result = train(config)
    assert load_var(result.checkpoint, front_end=EMBEDDING).front_end == EMBEDDING
