"""Wall-clock timing for the benchmarks."""

from __future__ import annotations

import time
from collections.abc import Callable

import torch

__all__ = ["best_seconds"]


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
