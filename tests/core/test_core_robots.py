"""Which simulated world serves each robot kind (core.robots)."""

import pytest

from core.robots import WORLD_OF_KIND, RobotKind, worker_drives, world_of_kind


def test_every_robot_kind_has_a_simulated_world() -> None:
    assert set(WORLD_OF_KIND) == set(RobotKind)
    assert world_of_kind("kuka-sim") == "kuka" and world_of_kind("turtlebot-sim") == "turtlebot"


def test_the_real_arm_is_trained_and_evaluated_in_its_simulated_twin() -> None:
    assert world_of_kind("kinova-real") == world_of_kind("kinova-sim") == "kinova"
    assert not RobotKind.KINOVA_REAL.simulated and RobotKind.KINOVA_SIM.simulated


def test_the_robot_worker_drives_simulated_robots_and_real_arms_that_say_where_they_are() -> None:
    assert worker_drives("kuka-sim", {}) and worker_drives("kinova-real", {"arm_ip": "192.168.1.10"})
    assert not worker_drives("kinova-real", {}) and not worker_drives("kinova-real", {"arm_ip": ""})


def test_an_unknown_kind_is_refused_naming_the_known_ones() -> None:
    with pytest.raises(ValueError, match="no simulated world for robot kind 'roomba'; known kinds: kuka-sim"):
        world_of_kind("roomba")
