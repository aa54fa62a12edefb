"""Where a training worker's torch work runs (`VARBOT_DEVICE`: auto, cpu or cuda) and how it shares the
machine's cores with its environment processes.

- `resolve_device`: "auto" takes the GPU when torch sees one, "cpu" never does, "cuda" insists (and says
  what is missing when there is none).
- `core_plan`: the learner's torch threads and a core for each environment worker. With the GPU doing the
  learner's work, the learner keeps one thread and every environment gets a core of its own; on the CPU the
  learner keeps the threads its run asks for (`PPOConfig.torch_threads`). Workers are pinned only when each
  can have a core the learner does not use; on a small machine the operating system places them.
"""

import os
from collections.abc import Iterable
from dataclasses import dataclass

import psutil
import torch

DEVICE_CHOICES = ("auto", "cpu", "cuda")


class DeviceUnavailable(RuntimeError):
    """VARBOT_DEVICE asks for a device this machine does not have."""


def resolve_device(requested: str) -> torch.device:
    """The torch device `requested` ("auto", "cpu" or "cuda") means on this machine."""
    if requested not in DEVICE_CHOICES:
        raise ValueError(f"VARBOT_DEVICE must be one of {', '.join(DEVICE_CHOICES)}, got {requested!r}")
    if requested == "cpu":
        return torch.device("cpu")
    if torch.cuda.is_available():
        return torch.device("cuda")
    if requested == "auto":
        return torch.device("cpu")
    built_with = f"built with CUDA {torch.version.cuda}" if torch.version.cuda else "built without CUDA"
    raise DeviceUnavailable(
        f"VARBOT_DEVICE=cuda but torch sees no CUDA GPU here (torch {torch.__version__}, {built_with}): "
        "install a CUDA build of torch and the NVIDIA driver, or set VARBOT_DEVICE=auto (use a GPU when "
        "there is one) or cpu"
    )


@dataclass(frozen=True)
class CorePlan:
    learner_threads: int
    learner_cores: tuple[int, ...]  # empty: not pinned
    env_cores: tuple[int, ...]  # one per environment worker, in order; empty: not pinned


def core_plan(cores: int, num_envs: int, device: torch.device, cpu_threads: int) -> CorePlan:
    """How `num_envs` environment workers and the learner share `cores` cores; `cpu_threads`: the learner's
    threads when it trains on the CPU."""
    threads = 1 if device.type == "cuda" else max(1, cpu_threads)
    if cores < threads + num_envs:
        return CorePlan(threads, (), ())
    return CorePlan(threads, tuple(range(threads)), tuple(range(threads, threads + num_envs)))


def spread_processes(plan: CorePlan, workers: Iterable[psutil.Process]) -> None:
    """Pins this process and `workers` as `plan` says: nothing when it pins nothing, or when the envs are not
    one worker process each (a real robot's env runs in this process)."""
    workers = list(workers)
    if not plan.env_cores or len(workers) != len(plan.env_cores):
        return
    os.sched_setaffinity(0, plan.learner_cores)
    for worker, core in zip(workers, plan.env_cores, strict=True):
        worker.cpu_affinity([core])
