"""Stopping a long training run from outside without losing it: `kill` (SIGTERM, e.g. a session ending) or
Ctrl-C in its terminal.

The first signal asks the run to stop after its current update, which then writes a checkpoint, so `--resume`
continues exactly; a second one stops it at once (KeyboardInterrupt), losing the steps since the last
checkpoint. The env workers ignore Ctrl-C themselves (`sim.vector.worker_ignoring_ctrl_c`): the trainer closes
them.
"""

import signal
import sys
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


class StopRequest:
    """A context that catches the stop signals; pass it to the trainer as `on_update` (True: stop now)."""

    def __init__(self) -> None:
        self.signal: int | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> "StopRequest":
        for signum in STOP_SIGNALS:
            self._previous[signum] = signal.signal(signum, self._request)
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)

    def __call__(self, record: dict[str, Any]) -> bool:
        return self.signal is not None

    def _request(self, signum: int, frame: FrameType | None) -> None:
        if self.signal is not None:
            raise KeyboardInterrupt
        self.signal = signum
        print(
            f"{self.signal_name}: stopping after the current update, with a checkpoint (send it again to "
            "stop at once, losing the steps since the last checkpoint)",
            file=sys.stderr,
            flush=True,
        )

    @property
    def signal_name(self) -> str:
        return signal.Signals(self.signal).name if self.signal is not None else ""

    @property
    def exit_code(self) -> int:
        """The shell's convention for a process stopped by a signal."""
        return 128 + (self.signal or 0)

    def explain(self, summary: dict[str, Any], run_dir: Path) -> str:
        return (
            f"stopped by {self.signal_name} at {summary['env_steps']:,} env steps; the checkpoint is "
            f"{Path(run_dir) / 'checkpoint.pt'}: the same command with --resume continues from there"
        )
