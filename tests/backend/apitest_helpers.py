"""Helpers shared by the API tests (a module of its own so that test files can import it)."""

import io
from dataclasses import dataclass

import numpy as np
import soundfile
from PIL import Image

PASSWORD = "correct horse battery"


@dataclass
class Person:
    """A signed-in member: `client` sends the session cookie and the CSRF header like the pages do."""

    client: object
    user_id: int
    household_id: int
    username: str
    csrf: str


# --- content ------------------------------------------------------------------------------------------------


def make_wav(
    seconds: float = 1.0,
    rate: int = 16_000,
    channels: int = 1,
    subtype: str = "PCM_16",
    amplitude: float = 0.3,
    frequency: float = 440.0,
) -> bytes:
    t = np.arange(int(seconds * rate)) / rate
    tone = amplitude * np.sin(2 * np.pi * frequency * t)
    samples = np.repeat(tone[:, None], channels, axis=1)
    buffer = io.BytesIO()
    soundfile.write(buffer, samples, rate, subtype=subtype, format="WAV")
    return buffer.getvalue()


def make_png(width: int = 32, height: int = 24, seed: int = 0, fmt: str = "PNG") -> bytes:
    pixels = np.random.default_rng(seed).integers(0, 255, (height, width, 3), dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format=fmt)
    return buffer.getvalue()


def upload_clip(person: Person, wav: bytes | None = None, name: str | None = None, filename: str = "cmd.wav"):  # type: ignore[no-untyped-def]
    data = {"name": name} if name else {}
    return person.client.post(  # type: ignore[attr-defined]
        "/api/v1/clips",
        files={"file": (filename, wav if wav is not None else make_wav(), "audio/wav")},
        data=data,
    )


def make_robot(person: Person, kind: str = "kuka-sim", name: str = "arm") -> int:
    response = person.client.post("/api/v1/robots", json={"name": name, "kind": kind})  # type: ignore[attr-defined]
    assert response.status_code == 201, response.text
    return response.json()["id"]


def upload_snapshot(person: Person, robot_id: int, seed: int = 0, meta: str = "{}"):  # type: ignore[no-untyped-def]
    return person.client.post(  # type: ignore[attr-defined]
        f"/api/v1/robots/{robot_id}/snapshots",
        files={"image": ("frame.png", make_png(seed=seed), "image/png")},
        data={"state": "[0.6, 0.1]", "meta": meta},
    )


def queued_tasks(redis_client, queue: str) -> list[dict]:  # type: ignore[no-untyped-def,type-arg]
    """Celery messages waiting on a queue (kombu's Redis transport keeps them in a list named after it)."""
    import json

    return [json.loads(raw) for raw in redis_client.lrange(queue, 0, -1)]
