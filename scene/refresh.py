"""The household's data (clips, snapshots, the active model, running runs) re-read every few seconds in a
background thread, so that the simulation loop never waits for the database."""

import threading
from collections.abc import Callable

from scene.household import HouseholdView, load_view

REFRESH_S = 5.0


class HouseholdRefresh:
    """Calls `apply(view)` with a fresh `HouseholdView` every `REFRESH_S` until `stopping` is set."""

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

    def once(self) -> None:
        self.apply(load_view(self.household_id, self.robot_id))

    def start(self) -> None:
        threading.Thread(target=self._forever, name="scene-refresh", daemon=True).start()

    def _forever(self) -> None:
        while not self.stopping.wait(REFRESH_S):
            try:
                self.once()
            except Exception as exc:  # the loop must survive a database hiccup; say what happened
                self.failed(exc)
