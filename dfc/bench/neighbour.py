"""A busy neighbour for the speed benchmarks: another dfc encode fitting beside the timed code, as when a batch of
files is encoded in parallel or tests run beside a build on the same cores.

``busy_neighbour(threads)`` starts ``python -m dfc.bench.neighbour THREADS`` (an encode of the shipped sample with
an endless step count, OpenMP threads sleeping when idle as the ``dfc`` entry point sets them) and returns once its
fit has started; the neighbour is stopped when the block ends.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
from pathlib import Path

__all__ = ["NEIGHBOUR_STEPS", "SAMPLES", "busy_neighbour"]

SAMPLES = Path(__file__).resolve().parents[2] / "samples"
"""The shipped sample (``sample.exr``, ``sample.json``) the neighbour encodes."""
NEIGHBOUR_STEPS = 10**9
"""The neighbour's steps: more than any benchmark lasts."""
START_TIMEOUT_S = 600
"""Longest wait for the neighbour's fit to start (seconds; a loaded machine imports torch slowly)."""


@contextlib.contextmanager
def busy_neighbour(threads: int):
    """Run a dfc encode with ``threads`` torch threads in a child process for the duration of the block."""
    proc = subprocess.Popen([sys.executable, "-m", "dfc.bench.neighbour", str(threads)], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    try:
        line = _read_line(proc, START_TIMEOUT_S)
        if line.strip() != "fitting":
            raise RuntimeError(f"the busy neighbour did not start (exit status {proc.poll()})")
        yield proc
    finally:
        proc.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(30)
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _read_line(proc: subprocess.Popen, timeout: float) -> str:
    """The child's first line of standard output, or '' when none comes within ``timeout`` seconds."""
    import selectors

    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        return proc.stdout.readline() if sel.select(timeout) else ""


def _encode_forever(threads: int) -> None:
    """The neighbour's work: print "fitting" once the fit has started, then fit until stopped."""
    import torch

    from ..codec import EncodeSettings, encode_image
    from ..geometry.sources import read_curves
    from ..io.image import read_image

    torch.set_num_threads(threads)

    def callback(step, *_):
        if step == 0:
            print("fitting", flush=True)

    encode_image(read_image(SAMPLES / "sample.exr"), read_curves(SAMPLES / "sample.json"),
                 EncodeSettings(steps=NEIGHBOUR_STEPS), callback=callback)


if __name__ == "__main__":
    from ..command import quiet_openmp

    quiet_openmp()
    _encode_forever(int(sys.argv[1]))
