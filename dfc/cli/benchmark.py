"""``dfc benchmark NAME``: run one of the benchmarks in ``dfc.bench.speed``."""

import importlib
import pkgutil

import click

from ..bench import speed as benchmarks
from ..bench.results import ARGS_KEY, publishing


class _BenchGroup(click.Group):
    """One command per module of ``dfc.bench.speed``; a module ``a_b`` is the command ``a-b``, whose ``--json PATH``
    is a result file (``dfc.bench.results``)."""

    def parse_args(self, ctx, args):
        ctx.meta[ARGS_KEY] = list(args)
        return super().parse_args(ctx, args)

    def list_commands(self, ctx):
        return sorted(m.name.replace("_", "-") for m in pkgutil.iter_modules(benchmarks.__path__))

    def get_command(self, ctx, name):
        if name not in self.list_commands(ctx):
            return None
        return publishing(importlib.import_module(f"dfc.bench.speed.{name.replace('-', '_')}").command, name)


@click.group(cls=_BenchGroup)
def command():
    """Measure dfc's own stages: speed, memory and quality figures of one capability each, printed (see each
    benchmark's --help). Comparisons with other methods at equal size: dfc bench."""
