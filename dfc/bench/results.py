"""Result files: what a benchmark run measured, as data that ``docs/`` is generated from.

A result file is one JSON object (schema ``dfc-result/1``, documented in ``benchmarks/README.md``):

- ``schema``: ``"dfc-result/1"``; ``title``: one line; ``page``: the ``docs/results.md`` section it belongs to;
- ``command``: the command line that produced it (null if unknown); ``date``: ISO date (or date and time);
  ``commit``: the git commit of the code that ran (null if unknown); ``machine``: a note on the machine and its
  load; ``source``: ``"measured"`` or how the numbers got here (``"transcribed from README at commit …"``);
- ``notes``: markdown paragraphs shown before the tables (optional);
- ``tables``: ``[{"title", "columns": [str], "rows": [[cell, ...]], "notes"?}]``, cells as printed (str or number);
- ``series`` (optional): ``[{"figure", "panel", "label", "x": [..], "y": [..], "x_label", "y_label", "x_log2"?}]``,
  one line of a figure's panel; ``docs/figures/<figure>.png`` is drawn from them (``dfc.bench.docs``);
- ``images`` (optional): committed pictures the run produced that are not drawn from data (contact sheets),
  as repository paths;
- any other keys: the command's own record, as it wrote it.

``dfc bench`` writes its ``results.json`` in this form (``publish_record``), ``dfc benchmark NAME --json PATH`` too
(``publishing``).
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import re
import subprocess
import sys
from pathlib import Path

__all__ = ["ARGS_KEY", "SCHEMA", "git_commit", "machine_note", "publish_file", "publish_record", "publishing",
           "rd_series", "tables_from_markdown", "tables_from_record", "validate"]

SCHEMA = "dfc-result/1"
"""The ``schema`` value of every result file."""
REQUIRED = ("schema", "title", "command", "date", "commit", "machine", "source", "tables")
"""Keys every result file has (values may be null where unknown, ``tables`` may be empty)."""


def git_commit() -> str | None:
    """The short commit hash of the checkout this package runs from (suffix ``+dirty`` with uncommitted changes to
    tracked files), or None outside a git checkout."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "-C", str(here), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, timeout=10, check=False)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def machine_note() -> str:
    """Operating system, architecture, CPU count, torch version and GPU (if torch is loaded), and the load average
    (a run's thread counts are its own figures)."""
    parts = [f"{platform.system()} {platform.machine()}", f"{os.cpu_count()} CPUs"]
    torch = sys.modules.get("torch")
    if torch is not None:
        parts.append(f"torch {torch.__version__}")
        if torch.cuda.is_available():
            parts.append(torch.cuda.get_device_name(0))
    if hasattr(os, "getloadavg"):
        parts.append(f"load average {os.getloadavg()[0]:.1f}")
    return ", ".join(parts)


def _row(line: str) -> list[str]:
    cells = re.split(r"(?<!\\)\|", line.strip())
    return [c.strip().replace("\\|", "|") for c in cells[1:-1]]


def tables_from_markdown(text: str) -> list[dict]:
    """Every pipe table of a markdown text as ``{"title", "columns", "rows"}``; the title is the last ``#`` heading
    before the table ("" if none). Cells stay text, as printed."""
    tables, title, lines = [], "", text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("#"):
            title = line.lstrip("#").strip()
        if line.startswith("|") and i + 1 < len(lines) and set(lines[i + 1].replace("|", "").strip()) <= set("-: "):
            columns = _row(line)
            i += 2
            rows = []
            while i < len(lines) and lines[i].startswith("|"):
                rows.append(_row(lines[i]))
                i += 1
            tables.append({"title": title, "columns": columns, "rows": rows})
            continue
        i += 1
    return tables


def tables_from_record(record: dict) -> list[dict]:
    """``record``'s top-level numbers and strings as one table (figure, value), then every list of flat dicts in it
    (one level deep, e.g. a benchmark's ``runs``) as a table: the keys as columns (in first-seen order), one row per
    dict, nested values as JSON text."""
    scalars = [[k, v] for k, v in record.items() if isinstance(v, (int, float, str)) and not isinstance(v, bool)]
    tables = [{"title": "figures", "columns": ["figure", "value"], "rows": scalars}] if scalars else []
    for key, value in record.items():
        if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            columns = list(dict.fromkeys(k for v in value for k in v))
            rows = [[v.get(c) if not isinstance(v.get(c), (dict, list)) else json.dumps(v.get(c)) for c in columns]
                    for v in value]
            tables.append({"title": key, "columns": columns, "rows": rows})
    return tables


def rd_series(record: dict, figure: str) -> list[dict]:
    """The lines of an RD sweep's plot (``dfc.bench.rd.rd_record``'s ``curves``): per method and measure (1× on all
    pixels and without the mixed ones, then each zoom's mean over the probes), bytes against PSNR, for the figure
    named ``figure``; each method labelled as its budgets' records label it."""
    labels = {m: r.get("label", m) for run in record.get("runs", []) for m, r in run.get("methods", {}).items()}
    points = [p for pts in record["curves"].values() for p in pts]
    zooms = [z for z in dict.fromkeys(k for p in points for k in p.get("psnr", {})) if float(z) > 1]
    measures = [("1×, all pixels", lambda p: p["image_psnr"]["all"]),
                ("1×, without mixed pixels", lambda p: p["image_psnr"]["unmixed"])]
    if record.get("zoom_truth"):
        measures += [(f"{z}×, mean of the probes", lambda p, k=z: p["psnr"].get(k)) for z in zooms]
    series = []
    for panel, value in measures:
        for method, pts in record["curves"].items():
            xy = [(p["bytes"], value(p)) for p in pts if "bytes" in p and value(p) is not None]
            series.append({"figure": figure, "panel": panel, "label": labels.get(method, method),
                           "x": [x for x, _ in xy], "y": [round(y, 2) for _, y in xy], "x_label": "bytes",
                           "y_label": "PSNR (dB)", "x_log2": True})
    return series


def publish_record(record: dict, markdown: str, command: str | None = None) -> dict:
    """``record`` (a ``dfc bench`` record) with the result-file keys added: the tables of its ``results.md``
    (``markdown``), the RD series when it is an RD sweep, and this run's command, date, commit and machine. The
    record's own keys are kept."""
    title = f"dfc bench{' --rd' if record.get('rd') else ''}: {record['input']}" if "input" in record else next(
        (line.lstrip("#").strip() for line in markdown.splitlines() if line.startswith("#")), "dfc bench")
    extra = {"schema": SCHEMA, "title": title, "page": "bench", "command": command or _command_line(),
             "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"), "commit": git_commit(),
             "machine": machine_note(), "source": "measured", "tables": tables_from_markdown(markdown)}
    if record.get("rd") and "curves" in record:
        slug = "".join(c if c.isalnum() else "_" for c in Path(str(record.get("input", "rd"))).stem).strip("_")
        extra["series"] = rd_series(record, f"rd_{slug}")
    return {**extra, **{k: v for k, v in record.items() if k not in extra}}


ARGS_KEY = "dfc.bench.results.args"
"""``click.Context.meta`` key under which ``dfc benchmark`` keeps its arguments (the command line of its results)."""


def _command_line(prefix: str = "dfc benchmark") -> str | None:
    """This run's command line: ``prefix`` and the arguments ``dfc benchmark`` kept, else ``dfc`` and the process's
    arguments when it is the ``dfc`` entry point, else None."""
    import shlex

    import click

    ctx = click.get_current_context(silent=True)
    if ctx is not None and ARGS_KEY in ctx.meta:
        return f"{prefix} {shlex.join(ctx.meta[ARGS_KEY])}"
    if Path(sys.argv[0]).name in ("dfc", "__main__.py"):
        return shlex.join(["dfc", *sys.argv[1:]])
    return None


def publish_file(path: str | os.PathLike, title: str, page: str = "benchmark") -> None:
    """Rewrite the JSON object a benchmark wrote to ``path`` as a result file: its keys kept, the result-file keys
    added (its own ``tables`` when it wrote them, else its lists of flat dicts as tables)."""
    from ..io.atomic import write_bytes_atomic

    data = json.loads(Path(path).read_text())
    if not isinstance(data, dict):
        data = {"data": data}
    extra = {"schema": SCHEMA, "title": title, "page": page, "command": _command_line(),
             "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"), "commit": git_commit(),
             "machine": machine_note(), "source": "measured", "tables": data.get("tables") or tables_from_record(data)}
    write_bytes_atomic(path, (json.dumps({**extra, **{k: v for k, v in data.items() if k not in extra}},
                                         indent=2) + "\n").encode())


def publishing(command, name: str):
    """A copy of the click ``command`` of ``dfc benchmark NAME`` whose ``--json PATH`` file (not ``-``) is a result
    file (``publish_file``) once the benchmark has written it."""
    import copy
    import functools

    wrapped = copy.copy(command)
    run = command.callback

    @functools.wraps(run)
    def callback(*args, **kwargs):
        out = run(*args, **kwargs)
        path = kwargs.get("json_path")
        if path and path != "-" and Path(path).is_file():
            publish_file(path, f"dfc benchmark {name}")
        return out

    wrapped.callback = callback
    return wrapped


def validate(doc: dict) -> list[str]:
    """The problems of a result file (empty when it follows the schema): missing keys, a wrong schema, tables whose
    rows do not match their columns, series whose x and y differ in length."""
    problems = [f"missing key {k!r}" for k in REQUIRED if k not in doc]
    if doc.get("schema") != SCHEMA:
        problems.append(f"schema is {doc.get('schema')!r}, expected {SCHEMA!r}")
    for t in doc.get("tables") or []:
        bad = [r for r in t.get("rows", []) if len(r) != len(t.get("columns", []))]
        if bad:
            problems.append(f"table {t.get('title')!r}: {len(bad)} row(s) do not match its {len(t['columns'])} columns")
    for s in doc.get("series") or []:
        if len(s.get("x", [])) != len(s.get("y", [])):
            problems.append(f"series {s.get('figure')}/{s.get('label')}: x and y differ in length")
    return problems
