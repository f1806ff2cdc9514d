"""Wall-clock timing and peak memory for the benchmarks."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch

__all__ = ["PeakMemory", "best_seconds", "run_measured"]


def best_seconds(fn: Callable[[], object], repeat: int, device) -> float:
    """Best wall time in seconds of ``fn()`` over ``repeat`` runs after one warm-up run, synchronising CUDA devices
    around each run."""
    device = torch.device(device)
    fn()
    best = float("inf")
    for _ in range(repeat):
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        clock = time.perf_counter()
        fn()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        best = min(best, time.perf_counter() - clock)
    return best


@dataclass
class PeakMemory:
    """Peak memory of a child process run by ``run_measured``, MB: ``hwm`` its own ``VmHWM`` (Linux's high-water
    mark of its resident memory), ``tree`` the largest total ``VmRSS`` of it and its descendants seen at once
    (sampled; counts worker processes), and the wall time in seconds."""

    hwm: float
    tree: float
    seconds: float


def _status(pid: int, key: str) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError):
        pass
    return 0.0


def _descendants(pid: int) -> list[int]:
    """Processes below ``pid`` (Linux ``/proc``; empty elsewhere)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parent = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            children.setdefault(parent, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        kids = children.get(todo.pop(), [])
        out += kids
        todo += kids
    return out


def run_measured(cmd: list[str], interval: float = 0.2, *, quiet: bool = False) -> PeakMemory:
    """Run ``cmd`` and measure its peak memory (``PeakMemory``) by polling ``/proc`` (Linux). (A child's
    ``ru_maxrss`` would also count the memory of this process, which it starts as a copy of.) ``quiet`` drops its
    standard output. Raises ``RuntimeError`` when the command fails."""
    clock = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL if quiet else None)
    hwm = tree = 0.0
    try:
        while proc.poll() is None:
            hwm = max(hwm, _status(proc.pid, "VmHWM:"))
            tree = max(tree, _status(proc.pid, "VmRSS:") + sum(_status(p, "VmRSS:") for p in _descendants(proc.pid)))
            time.sleep(interval)
    finally:  # interrupted: the child goes too
        if proc.poll() is None:
            proc.terminate()
            proc.wait()
    if proc.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed with exit status {proc.returncode}")
    return PeakMemory(hwm, max(tree, hwm), time.perf_counter() - clock)
