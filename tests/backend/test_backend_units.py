"""The pieces under the API: resampler, WAV length check, blob store and its orphan sweep, settings, the
bounds of a seed."""

import os
import time

import numpy as np
import pytest
from apitest_helpers import make_wav


def test_resampling_keeps_a_tone_and_removes_what_cannot_be_represented() -> None:
    from backend.audio import resample

    rate = 44_100
    t = np.arange(rate) / rate
    kept = resample(np.sin(2 * np.pi * 1000 * t).astype(np.float32), rate, 16_000)
    assert len(kept) == 16_000
    reference = np.sin(2 * np.pi * 1000 * np.arange(16_000) / 16_000)
    assert np.abs(kept[100:-100] - reference[100:-100]).max() < 1e-3
    above_nyquist = resample(np.sin(2 * np.pi * 12_000 * t).astype(np.float32), rate, 16_000)
    assert np.abs(above_nyquist[100:-100]).max() < 0.01  # would alias to 4 kHz without the low-pass


def test_a_wav_claiming_more_data_than_it_holds_is_refused() -> None:
    from backend.audio import AudioRejected, check_wav_header

    honest = make_wav(1.0)
    check_wav_header(honest)
    with pytest.raises(AudioRejected, match="cut off"):
        check_wav_header(honest[: len(honest) // 2])


def test_the_normalised_wav_is_16k_mono_16bit() -> None:
    import io

    import soundfile

    from backend.audio import validate_and_normalise

    clip = validate_and_normalise(
        make_wav(2.0, 48_000, 2), min_seconds=0.3, max_seconds=10, max_bytes=5 << 20
    )
    info = soundfile.info(io.BytesIO(clip.wav))
    assert (info.samplerate, info.channels, info.subtype, info.frames) == (16_000, 1, "PCM_16", 32_000)
    assert (clip.sample_rate, clip.channels, clip.duration_s) == (48_000, 2, 2.0)


def test_blobs_are_content_addressed_and_never_named_by_users(tmp_path) -> None:
    from backend.blobs import BlobNotFound, LocalBlobStore, sha256_hex

    store = LocalBlobStore(tmp_path)
    key = store.put(b"hello")
    assert key == sha256_hex(b"hello") and store.put(b"hello") == key
    assert store.get(key) == b"hello" and store.exists(key)
    assert not list((tmp_path / "tmp").iterdir()), "no temp file is left after the rename"
    for evil in ("../../etc/passwd", "/etc/passwd", "a" * 63 + "/"):
        with pytest.raises(BlobNotFound):
            store.get(evil)
    store.delete(key)
    assert not store.exists(key)


def test_the_sweep_removes_old_orphans_only(tmp_path, db, admin) -> None:
    from apitest_helpers import make_png

    from backend import models
    from backend.blobs import LocalBlobStore, sweep_orphans
    from backend.services.snapshots import create_snapshot

    store = LocalBlobStore(tmp_path)
    robot = models.Robot(household_id=admin.household_id, name="arm", kind="kuka-sim")
    db.add(robot)
    db.commit()
    kept = create_snapshot(db, store, robot, make_png(), [0.0], "upload").image_key
    old_orphan, young_orphan = store.put(b"crashed before commit"), store.put(b"upload in flight")
    long_ago = time.time() - 7200
    for key in (kept, old_orphan):
        os.utime(store.path(key), (long_ago, long_ago))
    assert sweep_orphans(db, store, grace_seconds=3600) == [old_orphan]
    assert store.exists(kept) and store.exists(young_orphan) and not store.exists(old_orphan)


def test_default_secrets_are_refused_outside_development(monkeypatch) -> None:
    from pydantic import ValidationError

    from backend.settings import Settings

    monkeypatch.delenv("VARBOT_SECRET_KEY", raising=False)
    assert Settings(environment="development").secret_key == "changethis"
    with pytest.raises(ValidationError, match="VARBOT_SECRET_KEY"):
        Settings(environment="production")
    with pytest.raises(ValidationError, match="database password"):
        Settings(
            environment="production", secret_key="s3cret", database_url="postgresql://u:changethis@db/varbot"
        )


@pytest.mark.parametrize("request_kind", ["run", "attempts", "room adaptation"])
def test_every_request_that_takes_a_seed_takes_the_same_range(request_kind: str) -> None:
    from pydantic import ValidationError

    from backend.api.routes.attempts import AttemptsRequest
    from backend.api.routes.models import AdaptRequest
    from backend.schemas import MAX_SEED, RunParams
    from backend.services import runs

    def request(seed: int) -> object:
        if request_kind == "run":
            return RunParams(**{**runs.PRESETS["standard"], "seed": seed})
        if request_kind == "attempts":
            return AttemptsRequest(count=1, seed=seed)
        return AdaptRequest(seed=seed)

    assert request(0).seed == 0 and request(MAX_SEED).seed == MAX_SEED
    for out_of_range in (-1, MAX_SEED + 1):
        with pytest.raises(ValidationError, match="seed"):
            request(out_of_range)
