"""bench/blocked_tries.py: a failed TurtleBot try is sorted by how it ended, read off the real arena."""

import math

import blocked_tries as bench
import numpy as np
import pytest

from sim.turtlebot_arena import OBJECTS, ROBOT_RADIUS_M, STAND_STILL_ACTION, TurtleBotArenaEnv

FORWARD = np.array([1.0, 0.0], dtype=np.float32)
STAND_STILL = STAND_STILL_ACTION.astype(np.float32)
CUBE, SPHERE = 0, 1
# the sphere straight ahead of a robot at the origin facing +x, the cube beyond it, the others behind
SPHERE_BEFORE_THE_CUBE = [(0.75, 0.0), (0.35, 0.0), (-0.7, 0.7), (-0.7, -0.7)]


def drive(contact: str, target: int, heading: float, steps: int = 40) -> list[dict]:
    arena = TurtleBotArenaEnv(image_size=32, contact=contact)
    try:
        arena.reset(seed=0, options={"intent": target})
        arena.arrange((0.0, 0.0, heading), SPHERE_BEFORE_THE_CUBE)
        return [bench.where_the_try_is(arena, arena.step(FORWARD)[0], target) for _ in range(steps)]
    finally:
        arena.close()


def test_a_robot_driving_on_into_another_object_is_pressed_against_it() -> None:
    steps = drive("stop", CUBE, heading=0.0)
    assert steps[-1]["target_share"] > 0.0, "the cube stays in view past the sphere's sides"
    assert bench.classify(steps, success=False) == "pressed against something else"


def test_a_robot_standing_still_facing_its_object_out_of_reach_stopped_short() -> None:
    arena = TurtleBotArenaEnv(image_size=32)
    try:
        arena.reset(seed=0, options={"intent": SPHERE})
        sphere_face = SPHERE_BEFORE_THE_CUBE[SPHERE][0] - OBJECTS[SPHERE].footprint_radius_m
        arena.arrange((sphere_face - ROBOT_RADIUS_M - 0.45, 0.0, 0.0), SPHERE_BEFORE_THE_CUBE)
        creep_back = STAND_STILL - np.array([0.002, 0.0], dtype=np.float32)  # a learnt "stop" is seldom exact
        steps = [bench.where_the_try_is(arena, arena.step(creep_back)[0], SPHERE) for _ in range(25)]
    finally:
        arena.close()
    assert (
        steps[-1]["target_clearance_m"] == pytest.approx(0.45, abs=0.01)
        and steps[-1]["target_clearance_m"] > 0.45
    )
    assert bench.classify(steps, success=False) == "stopped short of its object"


def test_a_robot_that_never_faced_its_object_never_saw_it() -> None:
    steps = drive("stop", CUBE, heading=math.pi, steps=10)  # away from both, towards the empty -x side
    assert bench.classify(steps, success=False) == "never saw its object"


def test_a_robot_at_its_object_but_not_facing_it_is_off_centre() -> None:
    steps = drive("stop", SPHERE, heading=0.0)
    steps[-1] = {**steps[-1], "target_bearing_deg": 35.0}  # the same place, turned away from the sphere
    assert bench.classify(steps, success=False) == "at its object, off-centre"


def test_a_success_has_no_ending_and_a_moving_robot_is_elsewhere() -> None:
    steps = drive("stop", CUBE, heading=0.0, steps=3)  # still driving towards the sphere
    assert bench.classify(steps, success=True) is None
    assert bench.classify(steps, success=False) == "elsewhere"


def test_a_run_of_another_world_is_refused(tmp_path) -> None:  # type: ignore[no-untyped-def]
    (tmp_path / "config.json").write_text('{"world": "kuka"}')
    with pytest.raises(SystemExit, match="kuka run; this bench replays TurtleBot runs"):
        bench.replay(tmp_path, "unheard-easy", "stop")


def test_the_summary_counts_endings_per_command_and_gives_their_final_clearances() -> None:
    tries = [
        {"intent": 0, "success": True, "stored_success": True, "ended": None, "final_clearance_m": 0.1},
        {"intent": 0, "success": False, "stored_success": False, "ended": "stopped short of its object",
         "final_clearance_m": 0.4},
        {"intent": 1, "success": False, "stored_success": True, "ended": "stopped short of its object",
         "final_clearance_m": 0.5},
    ]  # fmt: skip
    summary = bench.summarise(tries, ["cube", "sphere"])
    assert summary["success_rate"] == pytest.approx(1 / 3) and summary["agrees_with_stored"] == 2
    assert summary["by_intent"]["cube"]["stopped short of its object"] == 1
    assert summary["final_clearance_m_by_ending"]["stopped short of its object"] == {
        "min": 0.4,
        "median": 0.45,
        "max": 0.5,
    }
    assert summary["final_clearance_m_by_ending"]["elsewhere"] is None
