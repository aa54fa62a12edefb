"""Raw vector-env stepping is measured one way (bench/raw_stepping.py) for both benches that cite it, with
the CPU the envs used beside the wall-clock speed: the CPU figure counts the worker processes too."""

import subprocess
import sys

import psutil
from raw_stepping import CpuClock, raw_stepping

# burns half a second of CPU, says so, then waits (alive, so its CPU can be read) until its input closes
BURN_THEN_WAIT = (
    "import sys, time\nend = time.process_time() + 0.5\nwhile time.process_time() < end: pass\n"
    "print('burnt', flush=True)\nsys.stdin.read()"
)


def test_the_cpu_clock_counts_the_worker_processes_it_watches() -> None:
    worker = subprocess.Popen(
        [sys.executable, "-c", BURN_THEN_WAIT], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        clock = CpuClock([psutil.Process(worker.pid)])
        clock.start()
        assert worker.stdout is not None and worker.stdout.readline() == "burnt\n"  # this process waits
        clock.stop()
    finally:
        worker.communicate(timeout=60)
    assert clock.cpu_s >= 0.2 and clock.wall_s > 0  # most of the half second falls in the window


def test_raw_stepping_reports_wall_speed_cpu_per_step_and_memory() -> None:
    figures = raw_stepping("kuka", 2, 16, steps=6, warmup=1)
    assert figures["steps_per_s"] > 0 and figures["wall_s"] > 0
    assert figures["cpu_ms_per_step"] > 0 and figures["rss_mb_per_env"] > 0
