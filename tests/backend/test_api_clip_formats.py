"""Clips in every format people record in (WAV, FLAC, Ogg Vorbis/Opus, MP3, WebM/Opus as browsers record it,
MP4/AAC as Safari does) become the same 16 kHz mono 16-bit clip; damaged headers get a plain reason."""

import io
import struct

import av
import numpy as np
import pytest
import soundfile
from apitest_helpers import make_png, make_wav, upload_clip

RATE, SECONDS, LEVEL = 48_000, 1.5, 0.3
TONE = LEVEL * np.sin(2 * np.pi * 440 * np.arange(int(RATE * SECONDS)) / RATE)


def with_soundfile(container: str, subtype: str) -> bytes:
    buffer = io.BytesIO()
    soundfile.write(buffer, TONE, RATE, format=container, subtype=subtype)
    return buffer.getvalue()


def with_ffmpeg(container: str, codec: str, repeat: int = 1) -> bytes:
    """What a browser's MediaRecorder sends: one mono track, encoded by FFmpeg (PyAV)."""
    samples = np.tile(TONE, repeat).astype(np.float32)
    buffer = io.BytesIO()
    with av.open(buffer, mode="w", format=container) as media:
        stream = media.add_stream(codec, rate=RATE, layout="mono")
        frame = av.AudioFrame.from_ndarray(samples[None, :], format="flt", layout="mono")
        frame.sample_rate = RATE
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            media.mux(packet)
    return buffer.getvalue()


RECORDINGS = {
    "flac": (lambda: with_soundfile("FLAC", "PCM_16"), "audio/flac"),
    "ogg-vorbis": (lambda: with_soundfile("OGG", "VORBIS"), "audio/ogg"),
    "ogg-opus": (lambda: with_soundfile("OGG", "OPUS"), "audio/ogg"),
    "mp3": (lambda: with_soundfile("MP3", "MPEG_LAYER_III"), "audio/mpeg"),
    "webm-opus": (lambda: with_ffmpeg("webm", "libopus"), "audio/webm"),
    "mp4-aac": (lambda: with_ffmpeg("mp4", "aac"), "audio/mp4"),
}


def normalised(person, clip_id: int) -> np.ndarray:  # type: ignore[no-untyped-def]
    audio = person.client.get(f"/api/v1/clips/{clip_id}/audio")
    info = soundfile.info(io.BytesIO(audio.content))
    assert (info.samplerate, info.channels, info.subtype) == (16_000, 1, "PCM_16")
    return soundfile.read(io.BytesIO(audio.content))[0]


def dominant_hz(signal: np.ndarray) -> float:
    spectrum = np.abs(np.fft.rfft(signal * np.hanning(len(signal))))
    return float(np.fft.rfftfreq(len(signal), 1 / 16_000)[spectrum.argmax()])


def test_a_flac_becomes_exactly_the_clip_its_wav_becomes(member) -> None:
    wav = upload_clip(member, with_soundfile("WAV", "PCM_16"), filename="go.wav").json()["id"]
    flac = upload_clip(member, with_soundfile("FLAC", "PCM_16"), filename="go.flac")
    assert flac.status_code == 201, flac.text
    # Lossless: the same samples, give or take the last bit of libsndfile's integer-to-float scaling.
    assert np.abs(normalised(member, flac.json()["id"]) - normalised(member, wav)).max() <= 2 / 32768


@pytest.mark.parametrize("recording", list(RECORDINGS))
def test_each_format_decodes_to_the_same_normalised_clip(member, recording: str) -> None:
    make, media_type = RECORDINGS[recording]
    original = make()
    response = upload_clip(member, original, filename=f"command.{recording}")
    assert response.status_code == 201, response.text
    clip = response.json()
    assert (clip["sample_rate"], clip["channels"]) == (RATE, 1)
    assert clip["duration_s"] == pytest.approx(SECONDS, abs=0.05)  # lossy codecs pad a frame or so
    signal = normalised(member, clip["id"])
    assert len(signal) == pytest.approx(16_000 * SECONDS, abs=0.05 * 16_000)
    middle = signal[2000:-2000]
    assert dominant_hz(middle) == pytest.approx(440, abs=5)
    assert np.sqrt(np.mean(middle**2)) == pytest.approx(LEVEL / np.sqrt(2), rel=0.1)
    kept = member.client.get(f"/api/v1/clips/{clip['id']}/audio?original=true")
    assert kept.content == original and kept.headers["content-type"] == media_type


def _wav_with(rate: int | None = None, channels: int | None = None) -> bytes:
    wav = bytearray(make_wav(1.0))
    fmt = wav.index(b"fmt ") + 8
    if channels is not None:
        struct.pack_into("<H", wav, fmt + 2, channels)
    if rate is not None:
        struct.pack_into("<I", wav, fmt + 4, rate)
    return bytes(wav)


@pytest.mark.parametrize(
    ("payload", "status", "words"),
    [
        (_wav_with(rate=4_000_000_000), 422, "sample rate of 4,000,000,000 Hz"),
        (_wav_with(rate=1), 422, "sample rate of 1 Hz, but"),
        (_wav_with(channels=0), 422, "0 channels"),
        (b"hello, this is text", 415, "not a sound recording we can read"),
        (make_png(), 415, "this is a PNG image, not a sound recording"),
        (b"fLaC" + bytes(60), 422, "the FLAC file cannot be decoded"),
        (b"OggS" + bytes(60), 422, "the Ogg file cannot be decoded"),
        (b"\x1aE\xdf\xa3" + bytes(60), 422, "the WebM file cannot be decoded"),
        (b"ID3\x04" + bytes(6) + b"\xff\xfb\x90\x64" + bytes(400), 422, "the MP3 file cannot be decoded"),
        (with_ffmpeg("webm", "libopus", repeat=8), 422, "at most 10 s"),
    ],
    ids=["4-GHz", "1-Hz", "no-channels", "text", "png", "flac", "ogg", "webm", "mp3", "webm-12s"],
)
def test_damaged_or_foreign_files_get_a_plain_reason(member, blob_store, payload, status, words) -> None:
    response = upload_clip(member, payload)
    assert response.status_code == status, response.text
    detail = response.json()["detail"]
    assert words in detail
    assert any(advice in detail for advice in ("record", "upload", "say just")), "it says what to do"
    for internal in ("BytesIO", "0x", "SF_INFO", "Error opening", "WAV recording"):
        assert internal not in detail, detail
    assert member.client.get("/api/v1/clips").json() == []
    assert not any(blob_store.root.glob("??/??/*"))


def test_a_file_name_with_markup_is_refused_for_what_it_is(member, blob_store) -> None:
    response = upload_clip(member, make_wav(), filename="<script>alert(1)</script>.wav")
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert "'<' and '>'" in detail and "folder" not in detail and "<script>" not in detail
    assert "rename the file" in detail and not any(blob_store.root.glob("??/??/*"))
