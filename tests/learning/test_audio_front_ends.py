"""Sound front ends: the speech-embedding front end gives the wheel's own embeddings, fast and offline;
MFCC stays the default; a corpus's features are computed once per front end and cached beside its clips."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from learning.audio import (
    FEATURE_KINDS,
    SILENCE,
    decode_audio,
    feature_shape,
    features_from_bytes,
    features_from_waveform,
    silence,
    trim_silence,
)
from learning.front_ends import speech_embedding
from learning.sounds import engines, load_corpus
from learning.sounds.build import build_corpora
from learning.sounds.features import features_file

EMBEDDING = "speech-embedding"
FAST_EMBEDDING = "speech-embedding-fast"


def spoken(text: str, variant: str = "m3", pitch: int = 50) -> bytes:
    return engines.espeak(text, variant, "en-us", pitch, 160)


def test_mfcc_stays_the_default_front_end() -> None:
    clip = spoken("three")
    assert np.array_equal(features_from_bytes(clip), features_from_bytes(clip, "speech", "mfcc"))
    assert feature_shape() == SILENCE.shape == (100, 40)


@pytest.mark.parametrize(("kind", "frames"), [("speech", 11), ("phrase", 36), ("sound", 48)])
def test_speech_embedding_frames_are_96_values_every_80_ms_over_the_kinds_window(kind, frames) -> None:
    """The window a kind covers (1, 3 or 4 s), plus 320 ms of silence each side, in 775 ms windows 80 ms
    apart."""
    assert feature_shape(kind, EMBEDDING) == (frames, 96)
    assert speech_embedding.frames_for(FEATURE_KINDS[kind].max_samples) == frames


@pytest.mark.parametrize(("kind", "frames"), [("speech", 7), ("phrase", 32), ("sound", 44)])
def test_the_fast_speech_embedding_pads_only_before_the_clip_and_so_embeds_fewer_windows(
    kind, frames
) -> None:
    """The same 775 ms windows 80 ms apart, over 320 ms of silence and the kind's window: a 1 s clip costs
    7 embedding windows instead of 11."""
    assert feature_shape(kind, FAST_EMBEDDING) == (frames, 96)
    assert speech_embedding.frames_for(FEATURE_KINDS[kind].max_samples, FAST_EMBEDDING) == frames


@pytest.mark.parametrize("samples", [16_000, 9_000, 4_000])
def test_the_fast_front_ends_frames_are_the_full_ones_less_the_windows_reaching_into_trailing_silence(
    samples,
) -> None:
    """Both put 320 ms of silence before the clip, so the fast front end's windows are the full one's
    first windows, value for value, for long and short sounds (a short one is filled out after its end)."""
    sound = np.random.default_rng(1).uniform(-0.3, 0.3, samples).astype(np.float32)
    full = speech_embedding.embed(sound, EMBEDDING)
    fast = speech_embedding.embed(sound, FAST_EMBEDDING)
    assert len(fast) == speech_embedding.frames_for(samples, FAST_EMBEDDING) < len(full)
    np.testing.assert_allclose(fast, full[: len(fast)], atol=1e-6)


def test_a_word_gives_one_embedding_frame_per_80_ms_and_zero_frames_after_it() -> None:
    waveform, _ = decode_audio(spoken("zero"))
    features = features_from_waveform(waveform, "speech", EMBEDDING)
    heard = (features != 0).any(axis=1)
    sound_samples = len(trim_silence(waveform))
    assert features.dtype == np.float32 and features.shape == (11, 96)
    assert heard.sum() == speech_embedding.frames_for(sound_samples) < 11
    assert heard[: heard.sum()].all()  # the clip's frames first, then the padding
    assert np.isfinite(features).all()


def test_silence_is_all_zero_features_for_every_front_end() -> None:
    quiet = np.zeros(16_000, dtype=np.float32)
    for front_end in ("mfcc", EMBEDDING, FAST_EMBEDDING):
        features = features_from_waveform(quiet, "speech", front_end)
        assert np.array_equal(features, silence("speech", front_end)) and not features.any()


def test_the_batch_path_gives_the_wheels_streaming_embeddings_wherever_the_sound_is_loud() -> None:
    """The same melspectrogram and embedding models as the wheel's streaming interface, run once per clip.
    After the stream's 8 s of leading silence (100 chunks of 1280 samples) its embedding 100 + i is window i
    of the padded clip; the two agree for every window whose 110 ms mel chunks all lie inside the sound
    (elsewhere the model's 80 dB floor is relative to the clip here, to each chunk there)."""
    from pyopen_wakeword import OpenWakeWordFeatures

    noise = np.random.default_rng(0).uniform(-0.3, 0.3, 32_000)
    sound = np.round(noise * 32767) / 32767
    ours = speech_embedding.embed(sound)
    padding = speech_embedding.EDGE_PAD_SAMPLES[EMBEDDING][0]
    samples = np.pad(np.round(sound * 32767), (padding, padding)).astype(np.int16)
    samples = np.pad(samples, (0, -len(samples) % 1280))
    stream = OpenWakeWordFeatures.from_builtin()
    theirs = np.stack(
        [
            embedding.reshape(96)
            for start in range(0, len(samples), 1280)
            for embedding in stream.process_streaming(samples[start : start + 1280].tobytes())
        ]
    )
    end = padding + 32_000
    inside = [i for i in range(len(ours)) if 1280 * i >= padding and 1280 * (i + 9) + 1760 <= end]
    assert len(inside) >= 10
    np.testing.assert_allclose(ours[inside], theirs[100 + np.array(inside)], atol=1e-3, rtol=1e-3)


def test_nothing_is_fetched_over_the_network_at_import_or_first_use() -> None:
    """A fresh interpreter with no network at all (its own empty network namespace) and every Python socket
    refused loads the front end and embeds a clip, importing neither torch nor the wheel's Python package
    (its models and TFLite library are only read from where it is installed)."""
    script = textwrap.dedent(
        """
        import socket

        def refuse(*args, **kwargs):
            raise OSError("network use refused by the test")

        socket.socket = socket.create_connection = socket.getaddrinfo = refuse
        import numpy as np
        from learning.front_ends import speech_embedding

        tone = np.sin(np.arange(12_000) / 16_000 * 2 * np.pi * 220).astype(np.float32)
        print(speech_embedding.embed(tone).shape)
        import sys

        print(sorted({"torch", "pyopen_wakeword"} & set(sys.modules)))
        """
    )
    command = ["unshare", "--user", "--map-root-user", "--net", sys.executable, "-c", script]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("\n")[:2] == [f"({speech_embedding.frames_for(12_000)}, 96)", "[]"]


def test_the_front_end_loads_no_wake_word_head() -> None:
    """Only the wheel's melspectrogram and embedding models are read (its wake-word heads are not ours)."""
    models = speech_embedding._models()
    assert sorted(model.name for model in models) == ["embedding_model.tflite", "melspectrogram.tflite"]


@pytest.mark.speech
def test_a_corpus_computes_each_front_ends_features_once_and_caches_them(tmp_path) -> None:
    build_corpora(["wordset"], profile="small", root=tmp_path, progress=False, log=lambda _: None)
    folder = tmp_path / "sounds" / "wordset"
    mfcc = load_corpus("wordset", tmp_path)
    assert mfcc.front_end == "mfcc" and not (folder / features_file(EMBEDDING)).exists()

    embedded = load_corpus("wordset", tmp_path, front_end=EMBEDDING)
    cache = folder / features_file(EMBEDDING)
    assert embedded.front_end == EMBEDDING and cache.exists()
    assert embedded.features.shape == (len(mfcc), 11, 96)
    assert embedded.manifest_hash == mfcc.manifest_hash and np.array_equal(embedded.intent, mfcc.intent)
    with open(embedded.clip[3], "rb") as clip:
        recomputed = features_from_bytes(clip.read(), "speech", EMBEDDING)
    np.testing.assert_array_equal(embedded.features[3], recomputed)

    written = cache.stat().st_mtime_ns
    again = load_corpus("wordset", tmp_path, front_end=EMBEDDING)
    assert cache.stat().st_mtime_ns == written and np.array_equal(again.features, embedded.features)
