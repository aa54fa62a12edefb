"""The conditions a bench measured under, written beside its figures and printed with its table: the machine
(CPU cores, memory, torch threads, Python and torch versions, the GPU if torch sees one) and the load average
from /proc/loadavg just before and just after the measurement. Other people's jobs may share the machine; the
load average says how much, so two runs are compared only at a similar load.

    conditions = Conditions()        # reads the load average before
    ...                              # the measurement
    result.update(conditions.finish())  # {"machine": ..., "load_average": {"before": ..., "after": ...}}
    console.print(describe(result))
"""

import os
import platform
import sys
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.table import Table

LOADAVG = Path("/proc/loadavg")
MEMINFO = Path("/proc/meminfo")


def load_average() -> dict[str, float]:
    """Runnable (and uninterruptible) processes averaged over the last 1, 5 and 15 minutes."""
    one, five, fifteen = LOADAVG.read_text().split()[:3]
    return {"1_min": float(one), "5_min": float(five), "15_min": float(fifteen)}


def memory_gib() -> float:
    for line in MEMINFO.read_text().splitlines():
        if line.startswith("MemTotal:"):
            return round(int(line.split()[1]) / 2**20, 1)
    raise RuntimeError(f"no MemTotal in {MEMINFO}")


def torch_threads() -> int | None:
    """The bench's torch thread count, or None when it never loaded torch (not imported here for that)."""
    torch = sys.modules.get("torch")
    return None if torch is None else torch.get_num_threads()


def gpu_name() -> str | None:
    """The GPU torch sees, or None (no GPU, or torch not loaded by the bench)."""
    torch = sys.modules.get("torch")
    return torch.cuda.get_device_name() if torch is not None and torch.cuda.is_available() else None


def installed_version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def machine() -> dict[str, object]:
    return {
        "cpu_cores": os.cpu_count(),
        "memory_gib": memory_gib(),
        "torch_threads": torch_threads(),
        "python": platform.python_version(),
        "torch": installed_version("torch"),
        "gpu": gpu_name(),
        "platform": platform.platform(),
    }


class Conditions:
    """Reads the load average when made; `finish()` reads it again and describes the machine (at the end, so
    the torch threads are the ones the measurement used)."""

    def __init__(self) -> None:
        self.load_before = load_average()

    def finish(self) -> dict[str, object]:
        return {"machine": machine(), "load_average": {"before": self.load_before, "after": load_average()}}


def describe(record: dict) -> str:
    """One line for under a bench's table, from a record holding `Conditions.finish()`'s fields."""
    if not isinstance(record.get("load_average"), dict) or "before" not in record["load_average"]:
        return "machine and load average not recorded (measured before the bench recorded them)"
    found = record["machine"]
    threads = found["torch_threads"]
    load = record["load_average"]
    gpu = f"GPU {found['gpu']}, " if found.get("gpu") else ""
    return (
        f"{found['cpu_cores']} CPU cores, {found['memory_gib']} GiB, {gpu}"
        f"{'no torch' if threads is None else f'{threads} torch threads'}, "
        f"Python {found['python']}, torch {found['torch']}; load average (1 min) "
        f"{load['before']['1_min']:.1f} before, {load['after']['1_min']:.1f} after"
    )


def measure_and_publish(
    benchmark: str,
    measure: Callable[[], dict],
    table: "Callable[[dict], Table]",
    out: Path,
    argv: list[str] | None,
) -> dict:
    """The single-result benches' whole run: the measurement under recorded conditions, its JSON at `out`
    (with when and by which command), then its table and the conditions line."""
    import time

    from result_files import write_result
    from rich.console import Console

    conditions = Conditions()
    result = {"benchmark": benchmark, **measure()}
    result.update(conditions.finish())
    result["measured"] = time.strftime("%Y-%m-%d %H:%M", time.gmtime())
    result["command"] = " ".join([f"bench/{benchmark}.py", *(argv if argv is not None else sys.argv[1:])])
    write_result(out, result)
    console = Console()
    console.print(table(result))
    console.print(describe(result))
    return result
