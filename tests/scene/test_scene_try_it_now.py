"""What the app asks of a running scene, through a real Redis and database: a live voice ("try it now") is
carried out by the robot and reported in the household's words without the clip being kept; a model version
made active reaches the scene by an event, not by the next poll; a member's robot choice is shown."""

import io
import json
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import soundfile
from scene_helpers import (
    SceneHousehold,
    activate_untrained_model,
    add_named_clip,
    eventually,
    untrained_model_bytes,
)

from backend import scene_requests
from scene import refresh
from scene.service import SceneService
from scene.trial import COMMAND_STEPS

ARTIFACT = Path(__file__).resolve().parents[1] / "artifacts" / "scene-events.json"  # not in git


def tone(frequency: float, seconds: float = 1.0, rate: int = 16_000) -> bytes:
    t = np.arange(int(seconds * rate)) / rate
    buffer = io.BytesIO()
    signal = 0.4 * np.sin(2 * np.pi * frequency * t) * np.hanning(len(t))
    soundfile.write(buffer, signal, rate, format="WAV", subtype="PCM_16")
    return buffer.getvalue()


@contextmanager
def running_scene(household_id: int) -> Iterator[SceneService]:
    service = SceneService(household_id, fps=30)
    thread = threading.Thread(target=service.run, name="scene-under-test", daemon=True)
    thread.start()
    try:
        eventually(lambda: service.world is not None, 60, "the scene's world")
        yield service
    finally:
        service.stop()
        thread.join(30)


@pytest.fixture
def scene_with_a_model(scene_household: SceneHousehold) -> Iterator[SceneService]:
    """The household's scene with two recorded commands and an active (untrained) model."""
    add_named_clip(scene_household.household_id, "zero", tone(300))
    add_named_clip(scene_household.household_id, "three", tone(900))
    activate_untrained_model(scene_household.robot_id)
    with running_scene(scene_household.household_id) as scene:
        yield scene


def clips_stored(household_id: int) -> int:
    from sqlalchemy import func, select

    from backend import models
    from backend.db import get_session_factory

    with get_session_factory()() as session:
        return int(
            session.scalar(select(func.count(models.Clip.id)).where(models.Clip.household_id == household_id))
        )


def test_a_live_voice_is_carried_out_and_reported_in_the_households_words_and_not_kept(
    scene_with_a_model: SceneService, scene_household: SceneHousehold
) -> None:
    scene = scene_with_a_model
    home = scene_household.household_id
    eventually(lambda: scene.model.has_policy and scene.sphere is not None, 60, "the model and sphere")
    legend = scene.legend.html.content
    assert "“zero”" in legend and "“three”" in legend, "the sphere's legend speaks the household's words"
    before = clips_stored(home)
    try_id = scene_requests.ask_to_try(home, scene_household.robot_id, tone(320, 1.2))
    assert scene_requests.read_try(try_id, home)["state"] == "starting", "the page can say so at once"
    assert scene_requests.read_try(try_id, home + 1) is None, "another household cannot read it"

    seen: list[dict] = []

    def finished() -> bool:
        status = scene_requests.read_try(try_id, home)
        if status and (not seen or status != seen[-1]):
            seen.append(status)
        return bool(status) and status["state"] in scene_requests.FINISHED

    eventually(finished, 120, "the robot to finish what was said")
    final = seen[-1]
    assert final["state"] == "done", final
    assert "what you said (it sounds most like “" in final["message"]
    assert "“zero”" in final["message"] or "“three”" in final["message"], "the household's own words"
    assert "looks most like" in final["message"], "where it ended, in the household's words"
    assert any(s["state"] == "running" and 0 < s["step"] < COMMAND_STEPS for s in seen), "progress on the way"
    assert "Done with what you said" in scene.panel.command_status.content, "the scene's panel says it too"
    assert clips_stored(home) == before, "the live clip is not kept as a recording"


def test_a_live_voice_without_an_active_model_is_refused_saying_what_to_do(
    scene_household: SceneHousehold,
) -> None:
    with running_scene(scene_household.household_id) as scene:
        try_id = scene_requests.ask_to_try(scene_household.household_id, None, tone(400))
        eventually(
            lambda: scene_requests.read_try(try_id, scene_household.household_id)["state"] == "refused",
            60,
            "the refusal",
        )
        status = scene_requests.read_try(try_id, scene_household.household_id)
        assert "no active model yet" in status["message"] and "Admin page" in status["message"]
        assert scene.trial is None


def test_a_model_made_active_reaches_the_scene_by_an_event_not_the_next_poll(
    scene_household: SceneHousehold, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(refresh, "REFRESH_S", 600.0)  # no poll within the test: only the event can bring it
    with running_scene(scene_household.household_id) as scene:
        model = untrained_model_bytes()
        started = time.monotonic()
        version = activate_untrained_model(scene_household.robot_id, model)
        eventually(lambda: scene.model.version_id == version, 30, "the scene to load the new model")
        loaded = time.monotonic() - started
        eventually(lambda: f"model version {version}" in scene.panel.status.content, 10, "the status line")
        shown = time.monotonic() - started
    ARTIFACT.parent.mkdir(parents=True, exist_ok=True)  # a fresh clone has no tests/artifacts
    timings = {"activation_to_model_loaded_s": round(loaded, 3), "to_status_line_s": round(shown, 3)}
    ARTIFACT.write_text(json.dumps(timings))
    print(f"activation reached the scene in {loaded:.2f} s (status line {shown:.2f} s)")


def test_a_members_robot_choice_is_shown(scene_household: SceneHousehold) -> None:
    from backend import models
    from backend.db import get_session_factory

    with get_session_factory()() as session:
        second = models.Robot(
            household_id=scene_household.household_id, name="hall rover", kind="turtlebot-sim"
        )
        session.add(second)
        session.commit()
        second_id = second.id
    with running_scene(scene_household.household_id) as scene:
        eventually(lambda: scene.view.robot is not None, 30, "the first robot")
        first = scene.view.robot.id
        assert scene_requests.read_shown_robot(scene_household.household_id) == first
        scene_requests.ask(scene_household.household_id, {"type": "show_robot", "robot_id": second_id})
        eventually(
            lambda: scene.world is not None and scene.world.world == "turtlebot", 60, "the rover's arena"
        )
        assert scene.view.robot.name == "hall rover"
        assert scene_requests.read_shown_robot(scene_household.household_id) == second_id
        eventually(lambda: "hall rover" in scene.panel.status.content, 10, "the status line to name it")
