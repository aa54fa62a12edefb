"""`varbot up` started as a child process and watched from outside, for the tests and benches that check it:
what it said, its children by command line, Ctrl-C."""

import signal
import subprocess
from dataclasses import dataclass
from pathlib import Path

import psutil

from varbot.services import free_port, varbot_argv, wait_until


@dataclass
class LaunchedUp:
    process: subprocess.Popen[bytes]
    log: Path
    url: str

    @classmethod
    def start(cls, log: Path, env: dict[str, str], timeout: float = 300) -> "LaunchedUp":
        """`varbot up --no-demo` on a free port, its output in `log`; returns once it says it is running."""
        port = free_port()
        with log.open("wb") as out:
            process = subprocess.Popen(
                varbot_argv("up", "--port", str(port), "--no-demo"),
                env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
            )  # fmt: skip
        launched = cls(process, log, f"http://127.0.0.1:{port}")
        wait_until(lambda: launched.said("varbot is running at"), timeout, "varbot up to say it is running")
        return launched

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def said(self, text: str, after: int = 0) -> bool:
        """Whether it said `text` (past the first `after` characters of its output); fails once it exited."""
        assert self.process.poll() is None, f"varbot up exited:\n{self.output()[-3000:]}"
        return text in self.output()[after:]

    def child(self, fragment: str) -> psutil.Process:
        """The one direct child whose command line contains `fragment`."""
        found = [c for c in psutil.Process(self.process.pid).children() if fragment in " ".join(_cmdline(c))]
        assert len(found) == 1, f"{fragment!r}: {[_cmdline(c) for c in found]}"
        return found[0]

    def children(self) -> list[psutil.Process]:
        return psutil.Process(self.process.pid).children(recursive=True)

    def interrupt(self, timeout: float = 120) -> int:
        """What Ctrl-C in its terminal does; returns its exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        return self.process.wait(timeout)


def alive(process: psutil.Process) -> bool:
    try:
        return process.is_running() and process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _cmdline(process: psutil.Process) -> list[str]:
    try:
        return process.cmdline()
    except psutil.Error:
        return []
