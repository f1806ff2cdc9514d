"""Rate–distortion curves: the equal-size comparison (``dfc.bench.compare.run_bench``) at several byte budgets.

At each budget dfc's file is sized to it (``EncodeSettings.target_bytes``) and every other method gets dfc's
actual size, or the budget itself when dfc cannot meet it (its smallest file is larger: recorded under ``failed``,
as is any method that cannot). The reference renders of the windows are computed once for all budgets.

``results.json`` holds the curves — per method, one point per budget: bytes, 1× PSNR on every pixel and without
the mixed ones, the mean PSNR over the probes at each zoom and per probe kind, the configuration, and the
super-resolution PSNR (``super_psnr``) when it is measured, the input's own upsampled figures then under the record's
``super_resolution`` — and every budget's full record (``runs``). ``rd.png`` plots PSNR against bytes at 1× (all pixels, without mixed pixels) and at
every zoom above 1 (mean over the probes); ``rd_probes.png`` one panel per probe kind and zoom above 1.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import InputError
from .compare import LABELS, METHODS, BenchResult, BenchSettings, _zkey, config_label, run_bench, write_outputs
from .probes import PROBE_KINDS
from .report import markdown_table as table
from .report import write_report

__all__ = ["DEFAULT_BPP", "RdResult", "default_budgets", "rd_markdown", "rd_plots", "rd_record", "require_matplotlib",
           "run_rd", "write_rd"]

DEFAULT_BPP = (0.25, 0.5, 1.0, 2.0, 4.0)
"""Default budgets in bits per input pixel."""


def require_matplotlib():
    """``matplotlib.pyplot`` on the Agg backend; InputError naming the extra when it is missing."""
    try:
        import matplotlib
    except ImportError:
        raise InputError("the rate-distortion plots need matplotlib: pip install 'dfc[bench]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def default_budgets(width: int, height: int) -> list[int]:
    """Byte budgets of ``DEFAULT_BPP`` bits per pixel of a ``width × height`` input."""
    return [max(1, round(bpp * width * height / 8)) for bpp in DEFAULT_BPP]


@dataclass
class RdResult:
    """``results``: the RD record (``rd_record``); ``runs``: the equal-size result of every budget."""

    results: dict
    runs: list[BenchResult]


def run_rd(inputs: dict, budgets: list[int], settings: BenchSettings,
           progress: Callable[[str], None] | None = None) -> RdResult:
    """``run_bench(**inputs)`` at every budget (ascending), failures recorded rather than fatal."""
    budgets = sorted({int(b) for b in budgets})
    if not budgets or budgets[0] < 1:
        raise InputError(f"budgets must be positive byte counts, got {budgets}")
    progress = progress or (lambda message: None)
    cache: dict = {}
    runs = []
    for k, budget in enumerate(budgets):
        progress(f"budget {k + 1}/{len(budgets)}: {budget} bytes")
        runs.append(run_bench(**inputs, settings=replace(settings, target_bytes=budget, keep_going=True),
                              progress=progress, cache=cache))
    return RdResult(rd_record(runs, budgets), runs)


def _mean(values) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def rd_record(runs: list[BenchResult], budgets: list[int]) -> dict:
    """The RD record (module docstring) of the runs at ``budgets``."""
    first = runs[0].results
    kinds = first["probe_kinds"]
    curves: dict[str, list[dict]] = {}
    for m in METHODS:
        if not any(m in r.results["methods"] or m in r.results["failed"] for r in runs):
            continue
        points = []
        for budget, run in zip(budgets, runs):
            res = run.results
            if m not in res["methods"]:
                points.append({"budget": budget, "failed": res["failed"].get(m, "not run")})
                continue
            r = res["methods"][m]
            by_zoom = {z: _mean(v) for z, v in r["psnr"].items()}
            by_kind = {k: {z: _mean([x for x, kk in zip(v, kinds) if kk == k]) for z, v in r["psnr"].items()}
                       for k in dict.fromkeys(kinds)}
            points.append({"budget": budget, "bytes": r["bytes"], "image_psnr": r["image_psnr"], "psnr": by_zoom,
                           "psnr_by_kind": by_kind, "config": r["config"], "configuration": config_label(m, r),
                           **({"image_psnr_vs": r["image_psnr_vs"]} if "image_psnr_vs" in r else {}),
                           **({"super_psnr": res["super_resolution"]["methods"][m]}
                              if "super_resolution" in res else {})})
        curves[m] = points
    keep = ("input", "reference", "zoom_truth", "quality_scale", "data_range", "tonemap", "hdr", "image", "zooms",
            "probes", "probe_kinds", "windows")
    settings = {k: v for k, v in first["settings"].items() if k not in ("target_bytes", "keep_going")}
    record = {"rd": True, **{k: first[k] for k in keep}, "budgets": list(budgets), "settings": settings,
              "curves": curves, "runs": [r.results for r in runs]}
    if "super_resolution" in first:
        record["super_resolution"] = {k: v for k, v in first["super_resolution"].items() if k != "methods"}
    return record


def _panels(record: dict) -> list[tuple[str, Callable[[dict], float | None]]]:
    panels = [("1×, all pixels", lambda p: p["image_psnr"]["all"]),
              ("1×, without mixed pixels", lambda p: p["image_psnr"]["unmixed"])]
    if record["zoom_truth"]:
        for z in record["zooms"]:
            if z > 1:
                panels.append((f"{_zkey(z)}×, mean of the probes", lambda p, k=_zkey(z): p["psnr"][k]))
    return panels


def _axes(plt, n: int, cols: int):
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    return fig, axes.ravel()


def _plot(ax, record: dict, title: str, value: Callable[[dict], float | None]) -> None:
    for m, points in record["curves"].items():
        pts = [(p["bytes"], value(p)) for p in points if "bytes" in p and value(p) is not None]
        if not pts:
            continue
        x, y = zip(*pts)
        ax.plot(x, y, marker="o", label=LABELS[m], linewidth=2.5 if m == "dfc" else 1.2,
                color="black" if m == "dfc" else None)
    ax.set_xscale("log", base=2)
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("bytes")
    ax.set_ylabel("PSNR (dB)")
    ax.grid(True, which="both", alpha=0.3)


def _png(fig, plt) -> bytes:
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def rd_plots(record: dict) -> dict[str, bytes]:
    """{"rd.png": ..., "rd_probes.png": ...} PNG bytes (module docstring); the second only with a reference at every
    zoom (``zoom_truth``) and a zoom above 1."""
    plt = require_matplotlib()
    panels = _panels(record)
    fig, axes = _axes(plt, len(panels), min(4, len(panels)))
    for ax, (title, value) in zip(axes, panels):
        _plot(ax, record, title, value)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{record['input']}: PSNR against bytes", fontsize=11)
    out = {"rd.png": _png(fig, plt)}
    zooms = [_zkey(z) for z in record["zooms"] if z > 1]
    kinds = [k for k in PROBE_KINDS + ("given",) if k in record["probe_kinds"]]
    if record["zoom_truth"] and zooms:
        fig, axes = _axes(plt, len(zooms) * len(kinds), len(kinds))
        for i, (z, k) in enumerate((z, k) for z in zooms for k in kinds):
            _plot(axes[i], record, f"{z}×, {k} probes", lambda p, z=z, k=k: p["psnr_by_kind"][k][z])
        axes[0].legend(fontsize=8)
        fig.suptitle(f"{record['input']}: PSNR against bytes by probe kind", fontsize=11)
        out["rd_probes.png"] = _png(fig, plt)
    return out


def rd_markdown(record: dict) -> str:
    """``results.md`` of an RD sweep: per measure, PSNR (dB) and bytes of every method at every budget."""
    measures = [("1×, all pixels", lambda p: p["image_psnr"]["all"]),
                ("1×, without mixed pixels", lambda p: p["image_psnr"]["unmixed"])]
    if record["zoom_truth"]:
        measures += [(f"{_zkey(z)}×, mean of the probes", lambda p, k=_zkey(z): p["psnr"][k])
                     for z in record["zooms"] if z > 1]
    sr = record.get("super_resolution")
    if sr:
        measures.append((f"{sr['factor']}× super-resolution ({sr['width']}×{sr['height']}; the input upsampled: "
                         + ", ".join(f"{k} {v:.2f}" for k, v in sr["input"].items()) + " dB)",
                         lambda p: p.get("super_psnr")))
    header = ["method", *(f"{b} B" for b in record["budgets"])]
    notes = (f"{record['input']}. Cells: PSNR in dB (bytes used). Reference: {record['reference']}; 1× truth: "
             f"{record['image']['truth']}. Configurations per budget in results.json (`curves`).")
    parts = []
    for title, value in measures:
        rows = []
        for m, points in record["curves"].items():
            cells = ["–" if "bytes" not in p or value(p) is None else f"{value(p):.2f} ({p['bytes']})" for p in points]
            rows.append([LABELS[m], *cells])
        parts.append(table(f"dfc bench --rd, {title}", notes, header, rows))
    text = "\n".join(parts)
    failed = [(m, p) for m, points in record["curves"].items() for p in points if "failed" in p]
    if failed:
        text += "\n" + "\n".join(f"- {LABELS[m]} at {p['budget']} B: {p['failed']}" for m, p in failed) + "\n"
    return text


def write_rd(result: RdResult, directory: str | Path) -> list[Path]:
    """Write ``results.json``, ``results.md``, ``rd.png`` and ``rd_probes.png`` into ``directory`` and every budget's
    equal-size outputs (``write_outputs``) into ``directory/budget_<bytes>``. Returns the paths written."""
    out = Path(directory)
    plots = rd_plots(result.results)
    paths = []
    for budget, run in zip(result.results["budgets"], result.runs):
        paths += write_outputs(run, out / f"budget_{budget}")
    return paths + write_report(out, result.results, rd_markdown(result.results), None, None, plots)
