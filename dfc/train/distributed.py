"""Data-parallel training on PyTorch's own engine (docs/design.md §10): ``torch.distributed``,
``DistributedDataParallel`` and ``torchrun``'s elastic launcher.

A run of N ranks is N processes: started by ``torchrun --nproc-per-node N -m dfc encode …`` (any number of nodes,
see docs/gigapixel.md), or by ``launch`` (``dfc encode --workers N``: the same elastic agent, local ranks, a free port).
Each rank calls ``init`` (gloo on CPU ranks, NCCL on GPUs, one GPU per local rank), builds the same model from the
same seed, reads and samples its own share of the bands, and trains through ``dfc.train.loop.train``, which wraps
the model in ``DistributedDataParallel`` (``parallel``) so that every step all-reduces the gradients. The feature
bank's gradient is dense (``embedding_bag`` on a dense table), so DDP all-reduces it in full every step:
``4 · n_features · dim`` bytes per rank and step, ring all-reduce moving about twice that over each link.

Failures: a rank that raises or dies makes the launcher stop the others; a rank whose peer vanished mid-collective
gets a gloo / NCCL error, which ``lost_rank`` turns into one line. Only rank 0 writes output, after a barrier.
"""

from __future__ import annotations

import contextlib
import datetime
import logging
import os
import tempfile
import uuid

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

from ..errors import DfcError

__all__ = ["TIMEOUT", "RankError", "barrier", "broadcast_object", "check_replicas", "finish", "gather_rows", "init",
           "launch", "launched", "lost_rank", "parallel", "rank_seed", "reduce", "world"]

TIMEOUT = datetime.timedelta(minutes=30)
"""Longest wait of a collective (a rank reading its bands at an epoch's start keeps the others waiting)."""
RANK_SEED_STRIDE = 1_000_003
"""Rank r draws its samples with the generator seeded ``seed + r · RANK_SEED_STRIDE`` (``rank_seed``)."""


class RankError(DfcError, RuntimeError):
    """A rank of a data-parallel run failed, died or lost contact with the others."""


def launched() -> bool:
    """Whether this process is a rank of a multi-process run (``torchrun`` or ``launch`` set WORLD_SIZE > 1)."""
    return int(os.environ.get("WORLD_SIZE", "1")) > 1


def world() -> tuple[int, int]:
    """(rank, number of ranks); (0, 1) outside a data-parallel run."""
    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def rank_seed(seed: int, rank: int) -> int:
    """The sampling seed of ``rank`` (rank 0 keeps ``seed``, so one rank samples as a single process does)."""
    return int(seed) + RANK_SEED_STRIDE * int(rank)


def init(device: str) -> str:
    """Join the process group of this run (env:// rendezvous as torchrun sets it up) and return this rank's device:
    ``cuda:LOCAL_RANK`` for CUDA runs (NCCL), else ``device`` (gloo). Without ``OMP_NUM_THREADS``, a CPU rank uses
    its share of the cores."""
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    local_ranks = int(os.environ.get("LOCAL_WORLD_SIZE", os.environ.get("WORLD_SIZE", "1")))
    if torch.device(device).type == "cuda":
        if local_rank >= torch.cuda.device_count():
            raise RankError(f"local rank {local_rank} needs its own GPU, but {torch.cuda.device_count()} are visible")
        device = f"cuda:{local_rank}"
        torch.cuda.set_device(device)
        backend = "nccl"
    else:
        backend = "gloo"
        if "OMP_NUM_THREADS" not in os.environ:
            torch.set_num_threads(max(1, (os.cpu_count() or 1) // local_ranks))
    dist.init_process_group(backend, timeout=TIMEOUT, device_id=torch.device(device) if backend == "nccl" else None)
    return device


def finish() -> None:
    """Leave the process group (no-op outside a run)."""
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def parallel(model: nn.Module, *, sync: bool = True) -> nn.Module:
    """``model`` wrapped in ``DistributedDataParallel`` inside a run (else ``model`` itself). Buffers (mesh tables)
    are equal on every rank and never broadcast per step; ``sync`` broadcasts rank 0's parameters first."""
    if world()[1] == 1:
        return model
    device = next(model.parameters()).device
    return nn.parallel.DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None,
                                               forward_sync_buffers=False, init_sync=sync)


def _device() -> torch.device:
    """The device collectives run on: the current GPU for NCCL, else the CPU."""
    return torch.device("cuda", torch.cuda.current_device()) if dist.get_backend() == "nccl" else torch.device("cpu")


def reduce(values: np.ndarray, op: str = "sum") -> np.ndarray:
    """``values`` (any shape, float64) combined over the ranks with ``op`` ("sum", "min" or "max")."""
    values = np.asarray(values, dtype=np.float64)
    if world()[1] == 1:
        return values
    t = torch.from_numpy(values.copy()).to(_device())
    dist.all_reduce(t, op={"sum": dist.ReduceOp.SUM, "min": dist.ReduceOp.MIN, "max": dist.ReduceOp.MAX}[op])
    return t.cpu().numpy()


def gather_rows(rows: np.ndarray) -> np.ndarray | None:
    """Rank 0: every rank's ``rows`` (k_r, ...) stacked in rank order; other ranks: None."""
    rank, size = world()
    if size == 1:
        return rows
    parts = [None] * size if rank == 0 else None
    dist.gather_object(rows, parts, dst=0)
    return np.concatenate(parts) if rank == 0 else None


def broadcast_object(obj):
    """Rank 0's ``obj`` on every rank (pickled)."""
    if world()[1] == 1:
        return obj
    box = [obj]
    dist.broadcast_object_list(box, src=0, device=_device())
    return box[0]


def barrier() -> None:
    """Wait for every rank (no-op outside a run)."""
    if world()[1] > 1:
        dist.barrier()


def check_replicas(model: nn.Module) -> None:
    """Raise ``RankError`` unless every rank holds exactly rank 0's parameters (compares float64 checksums)."""
    rank, size = world()
    if size == 1:
        return
    flat = torch.cat([p.detach().reshape(-1).double() for p in model.parameters()])
    weights = torch.arange(1, len(flat) + 1, dtype=torch.float64, device=flat.device).remainder(997) + 1
    mine = torch.stack([flat.sum(), (flat * weights).sum(), flat.abs().max()]).to(_device())
    every = [torch.empty_like(mine) for _ in range(size)]
    dist.all_gather(every, mine)
    differ = [r for r in range(size) if not torch.equal(every[r], every[0])]
    if differ:
        raise RankError(f"ranks {differ} hold parameters different from rank 0's after training")


def lost_rank(exc: BaseException) -> RankError | None:
    """A ``RankError`` for a collective that failed because another rank failed, died or timed out; else None."""
    text = str(exc)
    if isinstance(exc, getattr(dist, "DistError", ())) or any(k in text for k in ("gloo", "NCCL", "Connection closed")):
        rank, _ = world()
        return RankError(f"rank {rank} stopped: another rank failed or left ({text.strip().splitlines()[0][:200]})")
    return None


CAUSE_ENV = "DFC_RANK_CAUSE"
"""Environment variable naming the file where the first rank that fails with dfc's own error writes it
(``record_cause``), read by ``launch``."""


def record_cause(error: DfcError) -> None:
    """Write ``error`` as the run's cause, unless another rank wrote one first. A rank calls this before it leaves
    the process group: the others then fail only as a consequence, and whichever exit the launcher sees first, its
    line names the real cause."""
    path = os.environ.get(CAUSE_ENV)
    if path:
        with contextlib.suppress(FileExistsError), open(path, "x", encoding="utf-8") as f:
            f.write(f"rank {world()[0]} failed: {error}")


def launch(n: int, entrypoint, *args, log_dir: str | None = None) -> dict:
    """Run ``entrypoint(*args)`` in ``n`` local ranks with torchrun's elastic agent (standalone rendezvous on a free
    port, no restarts) and return ``{rank: return value}``. Ranks above 0 write their output to log files in
    ``log_dir`` (by default a temporary directory, removed at the end); rank 0's goes to this process's terminal.

    Raises ``RankError`` with the cause a rank recorded (``record_cause``), else naming the first rank that failed
    or died (the agent stops the others).
    """
    from torch.distributed.elastic.multiprocessing import DefaultLogsSpecs, Std
    from torch.distributed.elastic.multiprocessing.errors import ChildFailedError
    from torch.distributed.launcher.api import LaunchConfig, elastic_launch

    for name in list(logging.root.manager.loggerDict) + ["torch"]:  # the agent's warnings are not dfc's errors
        if name.startswith("torch"):
            logging.getLogger(name).setLevel(logging.CRITICAL)
    with tempfile.TemporaryDirectory(prefix="dfc-ranks-") as tmp, _environ(CAUSE_ENV, os.path.join(tmp, "cause")):
        # removed however the run ends: the default log directory and the cause's file, whose path the ranks inherit
        config = LaunchConfig(
            min_nodes=1, max_nodes=1, nproc_per_node=n, run_id=str(uuid.uuid4()), rdzv_backend="c10d",
            rdzv_endpoint="localhost:0", max_restarts=0, monitor_interval=0.1, start_method="spawn",
            logs_specs=DefaultLogsSpecs(log_dir=log_dir or tmp, redirects={r: Std.ALL for r in range(1, n)}),
        )
        try:
            return elastic_launch(config, entrypoint)(*args)
        except ChildFailedError as e:
            cause = os.path.join(tmp, "cause")
            if os.path.exists(cause):
                with open(cause, encoding="utf-8") as f:
                    raise RankError(f.read()) from None
            raise RankError(_first_failure(e.failures)) from None


@contextlib.contextmanager
def _environ(name: str, value: str):
    """Set the environment variable ``name`` to ``value`` for the block (restored after)."""
    old = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = old


def _first_failure(failures: dict) -> str:
    """One line for the failed ranks: a rank killed by a signal, else the earliest failure that is not only the
    consequence of another rank's (``lost_rank``); dfc's own error types are left out of the line."""
    def message(f) -> str:
        m = f.message
        text = str(m.get("message", m) if isinstance(m, dict) else m).strip()
        text = text.splitlines()[0] if text else f"exit code {f.exitcode}"
        kind, _, rest = text.partition(": ")
        return rest if rest and kind in _DFC_ERRORS else text

    rank, f = min(failures.items(), key=lambda kv: (kv[1].exitcode >= 0, "another rank" in message(kv[1]),
                                                     kv[1].timestamp))
    if f.exitcode < 0:
        return f"rank {rank} died ({message(f)}); nothing was written"
    return f"rank {rank} failed: {message(f)}"


def _subclasses(cls) -> set[str]:
    return {cls.__name__}.union(*(_subclasses(c) for c in cls.__subclasses__()))


_DFC_ERRORS = _subclasses(DfcError)
"""Names of dfc's error types (left out of a failed rank's line, as the CLI leaves them out of its own)."""
