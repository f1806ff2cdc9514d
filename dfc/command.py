"""What every ``dfc`` command shares, in ``dfc.cli`` and in the benchmark commands of ``dfc.bench`` alike:
``--threads``, ``-q``, ``--json`` and its writer, notes and warnings on standard error, OpenMP's idle policy, and
SIGTERM unwinding like Ctrl-C. Torch-free (``--threads`` imports torch only when it is given a value)."""

from __future__ import annotations

import contextlib
import json
import os
import signal

import click


def _terminate(signum, frame):
    """SIGTERM unwinds like Ctrl-C, so atomic writers remove their temporary files. Once: a second SIGTERM while
    unwinding (a launcher stopping its ranks may send more than one) would interrupt the clean-up, or an exit
    handler, with a traceback."""
    signal.signal(signum, signal.SIG_IGN)
    raise SystemExit(128 + signum)


@contextlib.contextmanager
def sigterm_unwinds():
    """While the block runs, SIGTERM unwinds like Ctrl-C (``_terminate``). After it, SIGTERM takes its default
    action again: the work is done or unwound, and a SIGTERM that raised inside an exit handler (a launcher stopping
    a rank that is already exiting) would print a traceback instead of ending the process."""
    signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


OPENMP_ENVIRONMENT = {"OMP_WAIT_POLICY": "PASSIVE"}
"""Set (unless the user set them) before torch is loaded. OpenMP's idle worker threads otherwise spin, waiting
for the next parallel region: two such programs on the same cores (a batch encoded in parallel, tests beside a
build, a shared CI runner) take turns spinning instead of working: a 60-step encode of the sample with two threads
took 43.5 s spinning and 8.3 s sleeping on the busy development machine (README, "Threads")."""


def quiet_openmp() -> None:
    """Apply ``OPENMP_ENVIRONMENT``; only effective before the OpenMP runtime (torch) is loaded."""
    for name, value in OPENMP_ENVIRONMENT.items():
        os.environ.setdefault(name, value)


# -- threads ------------------------------------------------------------------------------------------------------
THREADS_ENV = "DFC_THREADS"
DEFAULT_THREADS = 1
"""torch and BLAS CPU threads of a computing command unless ``--threads`` or ``DFC_THREADS`` says otherwise.
Measured on the 2-core development machine (README, "Threads"): with idle threads sleeping, one thread is within a
few per cent of two on the busy shared machine and 1.6× faster beside a program whose threads spin; two are up to
1.4× faster only on an idle machine."""


def set_threads(n: int) -> None:
    """Set torch's CPU threads and those of every BLAS numpy and SciPy load (their OpenBLAS, ``threadpoolctl``) to
    ``n``: the idle threads of either spin beside other programs (docs/cli.md, "Threads")."""
    import scipy.sparse.linalg  # noqa: F401  (loads SciPy's BLAS, so that the limit reaches it too)
    import torch
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(n)
    threadpool_limits(n, user_api="blas")


def _set_threads(ctx, param, value):
    set_threads(value)
    return value


threads_option = click.option(
    "--threads", type=click.IntRange(1, 4096), default=DEFAULT_THREADS, show_default=True, envvar=THREADS_ENV,
    show_envvar=True, expose_value=False, callback=_set_threads,
    help="CPU threads for torch and for the BLAS numpy and SciPy use. More help only on an otherwise idle machine "
         "with cores to spare.")
"""``--threads N`` (env ``DFC_THREADS``) of every command that computes: sets torch's and BLAS's CPU threads before it
runs (``set_threads``).
(The entry point has already told OpenMP to sleep rather than spin while idle, ``dfc.cli.main``.)"""


# -- quiet, json, warnings ---------------------------------------------------------------------------------------
quiet_option = click.option("-q", "--quiet", is_flag=True,
                            help="No progress bar, warnings or notes (errors and the summary remain).")
json_option = click.option("--json", "json_path", type=click.Path(dir_okay=False, allow_dash=True),
                           help="Also write the summary as JSON to this file (- for standard output; the text "
                                "summary then goes to standard error).")


def write_json(path: str, data: dict) -> None:
    """``data`` as indented JSON to ``path`` (atomically), or to standard output when ``path`` is ``-``."""
    from .io.atomic import write_bytes_atomic

    text = json.dumps(data, indent=2) + "\n"
    if path == "-":
        click.echo(text, nl=False)
    else:
        write_bytes_atomic(path, text.encode())


def shown(path: str) -> str:
    """A path as a summary names it: ``-`` is standard output."""
    return "standard output" if path == "-" else path


def stdout_taken(*paths) -> bool:
    """True when one of ``paths`` (outputs, the ``--json`` path) is ``-``: standard output carries data, so the
    text summary goes to standard error (``click.echo(..., err=stdout_taken(...))``)."""
    return any(p == "-" for p in paths)


def warn(message: str, quiet: bool) -> None:
    """One ``dfc: warning:`` line on standard error (the run goes on), unless ``quiet``."""
    if not quiet:
        click.echo(f"dfc: warning: {message}", err=True)


def note(message: str, quiet: bool) -> None:
    """One ``dfc: note:`` line on standard error, unless ``quiet``."""
    if not quiet:
        click.echo(f"dfc: note: {message}", err=True)
