"""``dfc benchmark NAME``: run one of the benchmarks in ``dfc.bench.speed``."""

import importlib
import pkgutil

import click

from ..bench import speed as benchmarks


class _BenchGroup(click.Group):
    """One command per module of ``dfc.bench.speed``; a module ``a_b`` is the command ``a-b``."""

    def list_commands(self, ctx):
        return sorted(m.name.replace("_", "-") for m in pkgutil.iter_modules(benchmarks.__path__))

    def get_command(self, ctx, name):
        if name not in self.list_commands(ctx):
            return None
        return importlib.import_module(f"dfc.bench.speed.{name.replace('-', '_')}").command


@click.group(cls=_BenchGroup)
def command():
    """Measure dfc's own stages: speed, memory and quality figures of one capability each, printed (see each
    benchmark's --help). Comparisons with other methods at equal size: dfc bench."""
