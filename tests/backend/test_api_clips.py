"""Clips: upload, normalisation, every rejection, playback with ranges, soft and hard delete."""

import io
import struct
from pathlib import Path

import numpy as np
import pytest
import soundfile
from apitest_helpers import make_png, make_robot, make_wav, upload_clip, upload_snapshot


@pytest.mark.parametrize(
    ("rate", "channels", "subtype"),
    [
        (16_000, 1, "PCM_16"),
        (44_100, 2, "PCM_24"),
        (48_000, 1, "FLOAT"),
        (8_000, 2, "PCM_U8"),
        (22_050, 1, "PCM_32"),
    ],
)
def test_common_wavs_are_stored_as_16k_mono_16bit(member, blob_store, rate, channels, subtype) -> None:
    original = make_wav(1.5, rate, channels, subtype)
    response = upload_clip(member, original, name="the red block")
    assert response.status_code == 201, response.text
    clip = response.json()
    assert clip["sample_rate"] == rate and clip["channels"] == channels
    assert clip["duration_s"] == pytest.approx(1.5, abs=1e-3)
    assert clip["speaker_id"] == member.user_id and clip["name"] == "the red block"
    import hashlib

    assert clip["checksum"] == hashlib.sha256(original).hexdigest()
    audio = member.client.get(f"/api/v1/clips/{clip['id']}/audio")
    assert audio.headers["content-type"] == "audio/wav"
    info = soundfile.info(io.BytesIO(audio.content))
    assert (info.samplerate, info.channels, info.subtype) == (16_000, 1, "PCM_16")
    assert info.frames == 24_000
    samples, _ = soundfile.read(io.BytesIO(audio.content))
    assert 0.25 < np.abs(samples).max() < 0.35  # the tone survives resampling at its level
    assert member.client.get(f"/api/v1/clips/{clip['id']}/audio?original=true").content == original


def _lying_wav() -> bytes:
    honest = make_wav(0.5)
    data_at = honest.index(b"data")
    claimed = 16_000 * 2 * 2  # says 2 s, holds 0.5 s
    return honest[: data_at + 4] + struct.pack("<I", claimed) + honest[data_at + 8 :]


def _mp3_named_wav() -> bytes:
    return b"ID3\x04\x00\x00\x00\x00\x00\x00" + b"\xff\xfb\x90\x64" + bytes(400)


@pytest.mark.parametrize(
    ("payload", "status", "words"),
    [
        (b"", 422, "empty"),
        (_mp3_named_wav(), 422, "MP3 file cannot be decoded"),
        (b"\xff\xfb\x90\x64" + bytes(800), 422, "MP3 file cannot be decoded"),
        (make_png(), 415, "PNG image"),
        (b"hello, this is text", 415, "not a sound recording"),
        (b"RIFF\x10\x00\x00\x00WAVEjunkjunkjunk", 422, "no audio data"),
        (_lying_wav(), 422, "cut off"),
        (make_wav(60.0), 422, "at most 10 s"),
        (make_wav(0.1), 422, "at least 0.3 s"),
        (make_wav(2.0, amplitude=0.0), 422, "silent"),
        (make_wav(2.0, amplitude=1e-4), 422, "silent"),
    ],
    ids=[
        "zero-byte",
        "mp3-id3",
        "mp3-frames",
        "png",
        "text",
        "no-data-chunk",
        "lying-length",
        "60s",
        "short",
        "zeros",
        "hiss",
    ],
)
def test_bad_uploads_are_refused_with_a_clear_reason(member, blob_store, payload, status, words) -> None:
    response = upload_clip(member, payload)
    assert response.status_code == status, response.text
    assert words in response.json()["detail"]
    assert member.client.get("/api/v1/clips").json() == []
    assert not any(blob_store.root.glob("??/??/*")), "a refused upload must leave no blob behind"


def test_uploads_over_5_mb_are_refused(member) -> None:
    response = upload_clip(member, make_wav(9.9, rate=96_000, channels=2, subtype="PCM_24"))
    assert response.status_code == 413
    assert "at most 5 MB" in response.json()["detail"]


@pytest.mark.parametrize("filename", ["../../etc/passwd.wav", "..\\..\\evil.wav", "/abs/x.wav", ".."])
def test_path_like_file_names_are_refused_and_never_touch_the_disk(member, blob_store, filename) -> None:
    response = upload_clip(member, make_wav(), filename=filename)
    assert response.status_code == 422
    assert "plain file name" in response.json()["detail"]
    assert not Path("/etc/passwd.wav").exists() and not any(blob_store.root.glob("??/??/*"))


def test_the_file_name_is_kept_for_display_only(member, blob_store) -> None:
    clip = upload_clip(member, make_wav(rate=44_100), filename="go left.wav").json()
    assert clip["original_filename"] == "go left.wav"
    names = {path.name for path in blob_store.root.glob("??/??/*")}
    assert all(len(name) == 64 for name in names) and len(names) == 2


def test_audio_supports_range_requests(member) -> None:
    clip_id = upload_clip(member).json()["id"]
    whole = member.client.get(f"/api/v1/clips/{clip_id}/audio")
    assert whole.headers["accept-ranges"] == "bytes"
    part = member.client.get(f"/api/v1/clips/{clip_id}/audio", headers={"Range": "bytes=0-99"})
    assert part.status_code == 206
    assert part.headers["content-range"] == f"bytes 0-99/{len(whole.content)}"
    assert part.content == whole.content[:100]
    tail = member.client.get(f"/api/v1/clips/{clip_id}/audio", headers={"Range": "bytes=-10"})
    assert tail.content == whole.content[-10:]
    open_ended = member.client.get(f"/api/v1/clips/{clip_id}/audio", headers={"Range": "bytes=100-"})
    assert open_ended.content == whole.content[100:]
    beyond = member.client.get(f"/api/v1/clips/{clip_id}/audio", headers={"Range": "bytes=999999-"})
    assert beyond.status_code == 416 and beyond.headers["content-range"] == f"bytes */{len(whole.content)}"


def test_list_get_and_rename(member, admin) -> None:
    mine = upload_clip(member, name="one").json()
    upload_clip(admin, make_wav(frequency=300))
    assert len(member.client.get("/api/v1/clips").json()) == 2
    assert [c["id"] for c in member.client.get(f"/api/v1/clips?speaker_id={member.user_id}").json()] == [
        mine["id"]
    ]
    assert member.client.get(f"/api/v1/clips/{mine['id']}").json()["name"] == "one"
    assert member.client.patch(f"/api/v1/clips/{mine['id']}", json={"name": "two"}).json()["name"] == "two"


def test_only_the_speaker_or_an_admin_changes_a_clip(make_person, admin, member) -> None:
    carol = make_person("carol")
    clip_id = upload_clip(member).json()["id"]
    assert carol.client.delete(f"/api/v1/clips/{clip_id}").status_code == 403
    assert carol.client.patch(f"/api/v1/clips/{clip_id}", json={"name": "x"}).status_code == 403
    assert admin.client.delete(f"/api/v1/clips/{clip_id}").status_code == 204


def test_deleting_an_unlabelled_clip_removes_row_and_blobs(member, blob_store) -> None:
    clip_id = upload_clip(member).json()["id"]
    assert member.client.delete(f"/api/v1/clips/{clip_id}").status_code == 204
    assert member.client.get(f"/api/v1/clips/{clip_id}").status_code == 404
    assert not any(blob_store.root.glob("??/??/*"))


def test_a_labelled_clip_is_soft_deleted_and_leaves_training(admin, member, blob_store) -> None:
    robot = make_robot(admin)
    snapshot_id = upload_snapshot(member, robot).json()["id"]
    clip_id = upload_clip(member).json()["id"]
    member.client.post(
        "/api/v1/labels", json={"snapshot_id": snapshot_id, "clip_id": clip_id, "verdict": "is"}
    )
    assert member.client.delete(f"/api/v1/clips/{clip_id}").status_code == 204
    kept = member.client.get(f"/api/v1/clips/{clip_id}").json()
    assert kept["deleted_at"] is not None
    assert member.client.get("/api/v1/clips").json() == []
    assert len(member.client.get("/api/v1/clips?include_deleted=true").json()) == 1
    assert (
        member.client.get(f"/api/v1/clips/{clip_id}/audio").status_code == 200
    )  # history can still be heard
    assert member.client.get("/api/v1/triplets/stats").json()["labels"] == 0
    assert member.client.get("/api/v1/labels/next").json()["clip"] is None


def test_the_same_recording_twice_shares_blobs_and_survives_one_delete(member, blob_store) -> None:
    wav = make_wav()
    first, second = upload_clip(member, wav).json()["id"], upload_clip(member, wav).json()["id"]
    member.client.delete(f"/api/v1/clips/{first}")
    assert member.client.get(f"/api/v1/clips/{second}/audio").status_code == 200


def test_a_failed_insert_leaves_no_blob(db, blob_store, member) -> None:
    from sqlalchemy.exc import IntegrityError

    from backend import models
    from backend.services.clips import create_clip
    from backend.settings import get_settings

    ghost = models.User(
        id=987654,
        household_id=member.household_id,
        username="ghost",
        display_name="g",
        password_hash="x",
        role="member",
    )  # never inserted: the foreign key fails
    with pytest.raises(IntegrityError):
        create_clip(db, blob_store, get_settings(), ghost, "a.wav", make_wav(), None)
    assert not any(blob_store.root.glob("??/??/*"))


def test_clips_of_another_household_are_404(member, stranger) -> None:
    clip_id = upload_clip(member).json()["id"]
    for method, path in [
        ("GET", f"/api/v1/clips/{clip_id}"),
        ("GET", f"/api/v1/clips/{clip_id}/audio"),
        ("PATCH", f"/api/v1/clips/{clip_id}"),
        ("DELETE", f"/api/v1/clips/{clip_id}"),
    ]:
        response = stranger.client.request(method, path, json={"name": "x"} if method == "PATCH" else None)
        assert response.status_code == 404, (method, path)
    assert stranger.client.get("/api/v1/clips").json() == []


def test_control_characters_in_file_names_are_refused() -> None:
    from backend.errors import Invalid
    from backend.services.clips import clean_filename

    with pytest.raises(Invalid):
        clean_filename("a\x00b.wav")
    assert clean_filename(None) == "recording.wav"
