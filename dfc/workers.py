"""Encoding an image file out of core on worker ranks: ``encode_file_in_bands`` runs ``dfc.codec.encode_bands`` in
this process, as a rank of a ``torchrun`` run, or on ``settings.workers`` local ranks that it launches
(``dfc.train.distributed.launch``: torchrun's elastic agent), rank 0 writing the file. ``dfc encode --workers N``
and ``torchrun … -m dfc encode`` go through it."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, replace
from typing import Callable

from .errors import SettingsError
from .io.atomic import write_bytes_atomic

__all__ = ["BandJob", "encode_file_in_bands"]

Progress = Callable[[int, bool], contextlib.AbstractContextManager]
"""``progress(total_steps, shown)``: a context manager around the fit yielding its ``callback(step, loss, psnr)``
(or None); ``shown`` is False on ranks other than 0. Picklable (a module-level function or a ``functools.partial``
of one) when ranks are launched."""


@dataclass
class BandJob:
    """An out-of-core encode as each rank runs it: the input, its curves, the settings, where rank 0 writes (None:
    nowhere, the blob is returned), the progress display."""

    input_path: str
    channels: list[str] | None
    curves: object
    settings: object
    fit_curves: bool
    output: str | None
    progress: Progress | None = None


def encode_file_in_bands(input_path, curves, settings, output=None, *, channels: list[str] | None = None,
                         fit_curves: bool = False, progress: Progress | None = None):
    """Encode the image file ``input_path`` (EXR read band by band, other formats read whole) with ``curves`` and
    ``settings`` (a ``dfc.settings.EncodeSettings``) out of core: here, as a rank of this ``torchrun`` run, or with
    ``settings.workers`` > 1 on that many local ranks, whose rank 0 writes ``output`` (atomically; required then).
    A rank ends when the launching process does (Linux: the parent-death signal).

    Returns (blob, report): (None, report) when the ranks were launched here (the file is written); (None, None) on
    ranks other than 0 of a ``torchrun`` run. Raises what ``dfc.codec.encode_bands`` raises,
    ``dfc.train.distributed.RankError`` naming the rank that failed or died, ``SettingsError`` for workers without
    ``output``.
    """
    from .train import distributed

    job = BandJob(str(input_path), channels, curves, settings, fit_curves, output, progress)
    if settings.workers > 1:
        if output is None:
            raise SettingsError("workers > 1 write the file from their first rank: give output")
        return None, distributed.launch(settings.workers, rank_main, job)[0]
    if distributed.launched():
        return _as_rank(job)
    return _encode_bands(job)


def rank_main(job: BandJob):
    """Entry point of each local rank: rank 0 writes the file and returns the report."""
    from .command import sigterm_unwinds

    _end_with_parent()
    with sigterm_unwinds():  # unwinds, so the atomic writers remove their temporary files
        blob, report = _as_rank(job)
        if blob is not None:
            write_bytes_atomic(job.output, blob)
    return report


def _end_with_parent() -> None:
    """Linux sends this process SIGTERM when the parent dies (``prctl(PR_SET_PDEATHSIG)``)."""
    import ctypes
    import signal
    import sys

    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM), 0, 0, 0)


def _as_rank(job: BandJob):
    """``_encode_bands`` inside the process group of this run (joined here, left at the end). Progress bars lock
    with a thread lock: tqdm's default holds a named semaphore, which a killed rank would leave behind (and Python's
    resource tracker would warn about after the run's one error line)."""
    import threading

    from tqdm import tqdm

    from .errors import DfcError
    from .train import distributed

    tqdm.set_lock(threading.RLock())
    job = replace(job, settings=replace(job.settings, device=distributed.init(job.settings.device)))
    try:
        return _encode_bands(job)
    except RuntimeError as e:
        lost = None if isinstance(e, distributed.RankError) else distributed.lost_rank(e)
        if lost is None:
            raise
        raise lost from None
    except DfcError as e:  # the cause, recorded before leaving the group makes the others fail
        distributed.record_cause(e)
        raise
    finally:
        distributed.finish()


def _encode_bands(job: BandJob):
    from .codec import encode_bands
    from .io.bands import open_bands
    from .train.distributed import world

    source = open_bands(job.input_path, job.channels)
    shown = world()[0] == 0
    with job.progress(job.settings.steps, shown) if job.progress else contextlib.nullcontext() as callback:
        return encode_bands(source, job.curves, job.settings, fit_curves=job.fit_curves, callback=callback)
