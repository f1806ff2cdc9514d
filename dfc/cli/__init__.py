"""The ``dfc`` command line. One module per command lives beside this file in ``dfc.cli``; this file only
assembles the group and turns library errors into one-line messages (exit 1), the way rasterio's
``rio`` does. Commands are imported lazily so that ``dfc --help`` and ``dfc stats`` start fast."""

from __future__ import annotations

import importlib
import importlib.util

import click

from ..command import OPENMP_ENVIRONMENT as OPENMP_ENVIRONMENT
from ..command import _terminate as _terminate
from ..command import quiet_openmp as quiet_openmp
from ..command import sigterm_unwinds as sigterm_unwinds

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
    "serve": "serve",
    "view": "view",
    "tiles": "tiles",
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


def main(argv: list[str] | None = None):
    """Console entry point: library errors become one line on stderr and exit status 1.

    ``argv`` defaults to ``sys.argv[1:]``. SIGTERM exits through the same clean-up as Ctrl-C, so an
    interrupted encode or decode leaves neither the output nor a temporary file. OpenMP is told to let idle
    threads sleep before anything loads torch (``quiet_openmp``); each computing command's ``--threads`` sets
    torch's thread count (``dfc.command.threads_option``).
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
