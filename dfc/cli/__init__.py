"""The ``dfc`` command line. One module per command lives beside this file in ``dfc.cli``; this file only
assembles the group and turns library errors into one-line messages (exit 1), the way rasterio's
``rio`` does. Commands are imported lazily so that ``dfc --help`` and ``dfc stats`` start fast."""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import os
import signal

import click

# command name -> module of dfc.cli exposing a click command called ``command``
COMMANDS = {
    "mesh": "mesh",
    "encode": "encode",
    "decode": "decode",
    "zoom": "zoom",
    "stats": "stats",
    "benchmark": "benchmark",
    "bench": "bench",
    "wos": "wos",
    "solve": "solve",
    "curves": "curves",
}


class LazyGroup(click.Group):
    def list_commands(self, ctx):
        return sorted(name for name, mod in COMMANDS.items() if _available(mod))

    def get_command(self, ctx, name):
        if name not in COMMANDS or not _available(COMMANDS[name]):
            return None
        return importlib.import_module(f"dfc.cli.{COMMANDS[name]}").command


def _available(module: str) -> bool:
    return importlib.util.find_spec(f"dfc.cli.{module}") is not None


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="dfc")
def cli():
    """dfc — discontinuity-aware field codec.

    Fits a compact neural field to an image (or samples) whose discontinuities are given as curves,
    and stores it in a resolution-independent .dfield file that stays sharp at any zoom.
    """


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
build, a shared CI runner) take turns spinning instead of working (docs/cli.md, "Threads"; measured:
docs/results.md, "Threads and OpenMP wait policy")."""


def quiet_openmp() -> None:
    """Apply ``OPENMP_ENVIRONMENT``; only effective before the OpenMP runtime (torch) is loaded."""
    for name, value in OPENMP_ENVIRONMENT.items():
        os.environ.setdefault(name, value)


def main(argv: list[str] | None = None):
    """Console entry point: library errors become one line on stderr and exit status 1.

    ``argv`` defaults to ``sys.argv[1:]``. SIGTERM exits through the same clean-up as Ctrl-C, so an
    interrupted encode or decode leaves neither the output nor a temporary file. OpenMP is told to let idle
    threads sleep before anything loads torch (``quiet_openmp``); each computing command's ``--threads`` sets
    torch's thread count (``dfc.cli.options.threads_option``).
    """
    quiet_openmp()
    from ..errors import DfcError

    with sigterm_unwinds():
        try:
            cli.main(args=argv, prog_name="dfc", standalone_mode=False)
        except click.exceptions.Abort:
            click.echo("Aborted!", err=True)
            raise SystemExit(1)
        except click.ClickException as e:
            e.show()
            raise SystemExit(e.exit_code)
        except DfcError as e:
            click.echo(f"dfc: error: {e}", err=True)
            raise SystemExit(1)
        except OSError as e:
            where = f": {e.filename}" if getattr(e, "filename", None) else ""
            click.echo(f"dfc: error: {e.strerror or e}{where}", err=True)
            raise SystemExit(1)
        except MemoryError:
            click.echo("dfc: error: out of memory (try a smaller --size, --batch-size or mesh)", err=True)
            raise SystemExit(1)
        except KeyboardInterrupt:
            click.echo("Aborted!", err=True)
            raise SystemExit(130)
