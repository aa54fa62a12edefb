"""Live rollouts from the worker: about ten messages a second whatever the training speed, episode ends are
not lost between messages, nothing that goes wrong with publishing ever stops training, and a real run's
policy stage publishes what the scene reads."""

import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY, Household, Stack, wait_until

from learning.rl.ppo import RolloutStep
from worker.live import RolloutPublisher


@pytest.fixture
def redis_away(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The broker URL points at a socket nobody listens on."""
    from backend import broker, settings

    monkeypatch.setenv("VARBOT_BROKER_URL", f"redis+socket://{tmp_path / 'nobody.sock'}")
    monkeypatch.setenv("VARBOT_SECRET_KEY", "worker-live-tests-secret-key")
    settings.get_settings.cache_clear()
    broker.redis_client.cache_clear()
    yield
    monkeypatch.undo()
    settings.get_settings.cache_clear()
    broker.redis_client.cache_clear()


def empty_pose() -> dict:
    return {"base": [[0, 0, 0], [0, 0, 0, 1]], "joints": {}, "bodies": []}


def step(global_step: int, ended: bool = False, mirror: Callable[[], dict] = empty_pose) -> RolloutStep:
    image = np.full((16, 16, 3), global_step % 256, np.uint8)
    return RolloutStep(global_step, image, 0.5, ended, 0, mirror)


def test_messages_are_throttled_to_the_rate_and_remember_episode_ends_in_between() -> None:
    sent: list[tuple[str, dict]] = []
    publisher = RolloutPublisher(
        4, 2, 3, "kuka", "policy_improve", rate_hz=10, send=lambda c, m: sent.append((c, m)) is None
    )
    started, n = time.monotonic(), 0
    with publisher:
        while time.monotonic() - started < 0.55:
            n += 1
            publisher(step(n, ended=n == 3))
            time.sleep(0.001)
    assert n > 100, "the loop ran far faster than the rate"
    assert 5 <= len(sent) <= 7 and publisher.published == len(sent)
    assert {channel for channel, _ in sent} == {"varbot:rollouts:4"}
    messages = [message for _, message in sent]
    assert messages[0]["step"] == 1 and not messages[0]["episode_ended"]
    assert messages[1]["episode_ended"], "the end at step 3 travels with the next message"
    assert not any(m["episode_ended"] for m in messages[2:])
    assert all(m["run_id"] == 2 and m["robot_id"] == 3 and m["world"] == "kuka" for m in messages)


def test_training_goes_on_when_redis_is_away_or_the_message_cannot_be_made(redis_away: None) -> None:
    publisher = RolloutPublisher(1, 2, 3, "kuka", "policy_improve", rate_hz=1000)
    with publisher:
        publisher(step(1))
    assert publisher.published == 0 and not publisher.failed, "Redis away: nothing published, no error"

    def broken_mirror() -> dict:
        raise RuntimeError("environment 0 failed in mirror_state()")

    time.sleep(0.002)
    with publisher:
        publisher(step(2, mirror=broken_mirror))
    assert publisher.failed
    with pytest.raises(ValueError, match="rate_hz must be positive"):
        RolloutPublisher(1, 2, 3, "kuka", "policy_improve", rate_hz=0)


@pytest.mark.slow
@pytest.mark.speech
def test_a_running_policy_stage_publishes_env_0_at_most_ten_times_a_second_for_the_scene(
    stack: Stack, household: Household, training_worker
) -> None:  # type: ignore[no-untyped-def]
    from backend import broker
    from scene.live import decode_rollout

    robot = household.new_robot("live-arm", views=12)
    pubsub = broker.redis_client().pubsub(ignore_subscribe_messages=True)
    pubsub.subscribe(broker.rollout_channel(household.household_id))
    run = household.start_run(robot, "policy_improve", **{**TINY, "policy_steps": 24 * 400})
    try:
        first = wait_until(lambda: pubsub.get_message(timeout=0.5), 240, "a live rollout", interval=0)
        started, more = time.monotonic(), []
        while time.monotonic() - started < 3.0:
            more.append(pubsub.get_message(timeout=0.2))
    finally:
        household.client.post(f"/api/v1/runs/{run['id']}:cancel")
        household.wait_run(run["id"], timeout=120)
        pubsub.close()
    live = decode_rollout(first["data"], sequence=1, received_at=0.0)
    assert (live.run_id, live.robot_id, live.world) == (run["id"], robot, "kuka")
    assert live.stage == "policy_improve"
    assert live.image.shape == (16, 16, 3) and live.goal_clip_id in household.clip_ids.values()
    assert {f"J{j}" for j in range(7)} <= set(live.mirror["joints"]) and len(live.mirror["bodies"]) == 5
    sent = [json.loads(m["data"])["sent_at"] for m in [first, *more] if m is not None]
    assert len(sent) >= 3, "messages keep coming while the policy trains"
    assert min(np.diff(sent)) > 0.09, "at most ten a second, however fast the learner steps"
