"""Following a training run: while a run publishes its rollouts (`scene.live`) the scene shows its env 0, and
keeps showing the same run while it keeps coming; when its messages stop the scene goes back to its own."""

from scene.live import FOLLOW_TIMEOUT_S, LiveRollout, RolloutFeed


class RunFollowing:
    """The household's rollout feed and the rollout on show (`current`, None while not following)."""

    def __init__(self, household_id: int, timeout_s: float = FOLLOW_TIMEOUT_S) -> None:
        self.feed = RolloutFeed(household_id, timeout_s)
        self.current: LiveRollout | None = None

    def start(self) -> None:
        self.feed.start()

    def stop(self) -> None:
        self.feed.stop()

    def newest(self) -> LiveRollout | None:
        """The rollout to show now: the followed run's newest while it keeps coming, else any fresh one."""
        return self.feed.latest(self.current.run_id if self.current is not None else None)

    def starts_with(self, live: LiveRollout) -> bool:
        """True when `live` begins following a run (none was followed, or another one)."""
        return self.current is None or self.current.run_id != live.run_id

    def is_new(self, live: LiveRollout) -> bool:
        return self.current is None or live.sequence != self.current.sequence
