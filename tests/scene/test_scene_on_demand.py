"""A scene per household, on demand: asking for a household's scene starts one process for it (asking again
while it comes up starts no second one), it announces itself in that household's own endpoint file, and it
stops by itself, withdrawing the file, once nobody has watched it for the idle time."""

import pytest
from scene_helpers import SceneHousehold, eventually

from scene import on_demand
from scene.endpoint import alive, announced, endpoint_file, hold_scene_lock

IDLE_STOP_S = 4.0


def test_a_household_has_one_scene_lock_at_a_time(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv("VARBOT_DATA_DIR", str(tmp_path))
    held = hold_scene_lock(1)
    assert held is not None
    assert hold_scene_lock(1) is None, "a second scene for the same household must leave"
    other = hold_scene_lock(2)
    assert other is not None, "another household's scene runs alongside"
    held.close()
    again = hold_scene_lock(1)
    assert again is not None, "once the first scene is gone, a new one may start"
    again.close()
    other.close()


def test_a_started_scene_runs_at_the_frame_rate_and_idle_time_the_settings_give(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv(on_demand.IDLE_STOP_ENV, raising=False)
    monkeypatch.delenv(on_demand.FPS_ENV, raising=False)
    assert on_demand.scene_argv(3)[-4:] == ["--stop-when-unwatched-s", "300.0", "--fps", "15.0"]
    monkeypatch.setenv(on_demand.IDLE_STOP_ENV, "20")
    monkeypatch.setenv(on_demand.FPS_ENV, "5")
    assert on_demand.scene_argv(3)[-4:] == ["--stop-when-unwatched-s", "20.0", "--fps", "5.0"]


def test_a_scene_starts_on_demand_once_and_stops_when_nobody_watches(
    scene_household: SceneHousehold, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(on_demand.IDLE_STOP_ENV, str(IDLE_STOP_S))
    home = scene_household.household_id
    assert announced(home) is None
    assert on_demand.start_for(home), "the first ask starts the household's scene"
    assert not on_demand.start_for(home), "a second ask while it comes up starts no other one"
    eventually(lambda: announced(home) is not None, 120, "the scene to announce itself")
    scene = announced(home)
    assert scene is not None and scene.household_id == home and scene.url.startswith("http://127.0.0.1:")
    assert announced(home + 1) is None, "another household's scene is its own"

    eventually(lambda: not alive(scene.pid), 60, f"the unwatched scene to stop after {IDLE_STOP_S} s")
    assert not endpoint_file(home).exists(), "a scene that stops withdraws its endpoint file"
    log = on_demand.log_file(home).read_text(errors="replace")
    assert "Traceback" not in log, log[-3000:]
