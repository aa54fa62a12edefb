"""The household's data (clips, snapshots, the active model, running runs) re-read every few seconds in a
background thread, so that the simulation loop never waits for the database, and at once when the app says
something changed (`wake`: a model version was activated) or a member chose another robot (`show_robot`)."""

import threading
from collections.abc import Callable

from scene.household import HouseholdView, load_view

REFRESH_S = 5.0


class HouseholdRefresh:
    """Calls `apply(view)` with a fresh `HouseholdView` every `REFRESH_S` (or when woken) until `stopping` is
    set."""

    def __init__(
        self,
        household_id: int,
        robot_id: int | None,
        apply: Callable[[HouseholdView], None],
        failed: Callable[[Exception], None],
        stopping: threading.Event,
    ) -> None:
        self.household_id, self.robot_id = household_id, robot_id
        self.apply, self.failed, self.stopping = apply, failed, stopping
        self.woken = threading.Event()
        self.reading = threading.Lock()  # the inbox's thread reads too: one reading at a time, in order

    def once(self) -> None:
        with self.reading:
            self.apply(load_view(self.household_id, self.robot_id))

    def wake(self) -> None:
        """Re-read now rather than at the next period."""
        self.woken.set()

    def show_robot(self, robot_id: int) -> None:
        """From now on show this robot of the household (read at once, in the caller's thread)."""
        self.robot_id = robot_id
        self.once()

    def start(self) -> None:
        threading.Thread(target=self._forever, name="scene-refresh", daemon=True).start()

    def _forever(self) -> None:
        while not self.stopping.is_set():
            self.woken.wait(REFRESH_S)
            self.woken.clear()
            if self.stopping.is_set():
                return
            try:
                self.once()
            except Exception as exc:  # the loop must survive a database hiccup; say what happened
                self.failed(exc)
