"""Benchmarks: commands that measure and print numbers (``dfc benchmark NAME``), never asserted in tests.
Each module exposes a click command named ``command``; results are printed and, with ``--json``, written to a file."""
