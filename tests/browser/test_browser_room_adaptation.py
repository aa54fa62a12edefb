"""On the Admin page an admin adapts the picked robot's model to its room with one button: the robot worker
tunes the shipped base model to the robot's newest camera views, the page says which version is active now,
and the versions table says where that version came from. A robot with too few views is told how many more
to send."""

from collections.abc import Iterator

import pytest
from browser_helpers import ConsoleWatch, Stack, open_page, upload_views

from core.rooms import MIN_ROOM_VIEWS
from varbot.services import Service, worker_service

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def robot_worker(stack: Stack) -> Iterator[Service]:
    worker = stack.start(worker_service("robot", stack.data_dir, "worker-robot-adapting"))
    yield worker
    worker.stop()


def _robot_with_views(stack: Stack, name: str, kind: str, views: int) -> int:
    with stack.client() as alice:
        robot = int(alice.post("/robots", json={"name": name, "kind": kind}).json()["id"])
        upload_views(alice, robot, views, seed=5)
    return robot


def test_an_admin_adapts_a_robot_to_its_room_and_the_versions_say_so(
    page, stack: Stack, robot_worker: Service
) -> None:  # type: ignore[no-untyped-def]
    robot = _robot_with_views(stack, "moved arm", "kuka-sim", 0)  # it looks around by itself
    open_page(page, f"{stack.url}/admin")
    page.select_option("#robot", str(robot))
    page.click("#adapt")
    message = page.locator("#models-message")
    try:
        message.filter(has_text="is active").wait_for(timeout=60_000)
    except Exception:
        pytest.fail(f"{message.inner_text()!r}; worker log: {stack.log('worker-robot-adapting')[-3000:]}")
    assert "adapted to 400 camera views of this room" in message.inner_text()
    page.locator("#models", has_text="adapted to its room").wait_for()
    rows = page.locator("#models tr")
    assert rows.count() == 2, "the base model it started from, and the adapted version"
    in_use = rows.filter(has_text="in use").first.inner_text()
    assert "adapted to its room (400 views)" in in_use


def test_a_real_robot_with_too_few_frames_is_told_how_many_more_to_send(
    page, stack: Stack, console: ConsoleWatch
) -> None:  # type: ignore[no-untyped-def]
    console.expect("status of 409 (Conflict)")
    robot = _robot_with_views(stack, "frames-only arm", "kinova-real", 4)
    open_page(page, f"{stack.url}/admin")
    page.select_option("#robot", str(robot))
    page.click("#adapt")
    message = page.locator("#models-message")
    message.filter(has_text="send").wait_for()
    assert f"send {MIN_ROOM_VIEWS - 4} more of its camera frames first" in message.inner_text()
    assert "error" in (message.get_attribute("class") or "").split()
