"""``dfc benchmark gpu``: every GPU figure in one command and one table.

Rows, each on ``--device`` (a CUDA device) and, for the ratio, on the CPU where it takes reasonable time:

- decode: milliseconds per megapixel of a whole-domain render of the shipped sample at each ``--sides`` (anti-aliased
  with the ``box`` filter in the pixels a curve crosses, and ``point``), end to end as ``dfc decode`` renders (pixel
  positions made on the host, values copied back) and on the device alone (positions made there, values kept);
- fit: samples per second of the image fit (``dfc.train.fit.fit_image``, ``--fit-steps`` steps of
  ``--batch-size`` samples) and the time of a default encode, of the README sample and of a ``--render-side``²
  render (the sample's file decoded at that size with its curves scaled, so its truth is known);
- peak device memory of each row (``torch.cuda.max_memory_allocated``).

On a machine without CUDA it prints one line and exits 0. ``--device cpu`` runs the same table on the CPU (small
``--sides`` advised): the code path the tests exercise.
"""

from __future__ import annotations

import time

import click

from ...command import json_option, quiet_option, stdout_taken, write_json

__all__ = ["DECODE_TARGET_MS_PER_MP", "FIT_TARGET_SAMPLES_PER_S", "command", "format_table"]

DECODE_TARGET_MS_PER_MP = 1.0
"""Target of a GPU decode: milliseconds per megapixel."""
FIT_TARGET_SAMPLES_PER_S = 1e8
"""Target of a GPU fit: training samples per second."""
CPU_DECODE_MAX_SIDE = 1024
"""The CPU ratio is measured on renders no larger than this side (a 16k² CPU render takes many minutes)."""


def format_table(rows: list[dict]) -> list[str]:
    """Lines of the table of ``rows`` (dicts with ``what``, ``device``, ``value``, ``unit`` and optional
    ``cpu_value``, ``peak_mb``, ``target``): one line per row; the ratio is device speed over CPU speed (for a
    time, CPU / device; for a rate, device / CPU), blank without a CPU figure; a target is marked met or missed."""
    lines = [f"{'measure':<50} {'device':<8} {'value':>12} {'unit':<10} {'CPU':>12} {'ratio':>8} {'peak MB':>8}  target"]
    for r in rows:
        cpu = r.get("cpu_value")
        ratio = ""
        if cpu:
            ratio = f"{(cpu / r['value']) if r['unit'] in ('ms/MP', 's') else (r['value'] / cpu):.1f}x"
        target = ""
        if r.get("target") is not None:
            ok = r["value"] <= r["target"] if r["unit"] in ("ms/MP", "s") else r["value"] >= r["target"]
            target = f"{'met' if ok else 'missed'} ({'<=' if r['unit'] in ('ms/MP', 's') else '>='} {r['target']:g})"
        peak = "" if r.get("peak_mb") is None else f"{r['peak_mb']:.0f}"
        lines.append(f"{r['what']:<50} {r['device']:<8} {_num(r['value']):>12} {r['unit']:<10} "
                     f"{'' if cpu is None else _num(cpu):>12} {ratio:>8} {peak:>8}  {target}")
    return lines


def _num(v: float) -> str:
    return f"{v:.3g}" if abs(v) >= 1e5 or abs(v) < 0.01 else f"{v:.2f}"


def _sync(device) -> None:
    import torch

    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _peak_reset(device) -> None:
    import torch

    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)


def _peak_mb(device) -> float | None:
    import torch

    return torch.cuda.max_memory_allocated(device) / 2**20 if device.type == "cuda" else None


def decode_ms_per_mp(model, side: int, pixel_filter: str, device, on_device: bool) -> float:
    """Milliseconds per megapixel of a ``side``² render of the whole domain of ``model`` (on ``device``) with
    ``pixel_filter`` (end to end through ``dfc.render.render_region`` in bands of rows, or, ``on_device``, the
    field at the pixel centres evaluated on the device in blocks and kept there)."""
    import torch

    from ...geometry.pixels import EdgeMask
    from ...render import MAX_POINTS, render_region
    from ..timing import best_seconds

    band = max(1, MAX_POINTS // side)
    if on_device:
        x0, y0, x1, y1 = model.field.mesh.domain
        u = (torch.arange(side, device=device, dtype=torch.float64) + 0.5) / side

        def run():
            with torch.no_grad():
                for a in range(0, side, band):
                    ys = y0 + u[a:a + band] * (y1 - y0)
                    xy = torch.stack(torch.meshgrid(ys, x0 + u * (x1 - x0), indexing="ij")[::-1], -1).reshape(-1, 2)
                    model(xy)
    else:
        def run():  # one edge mask per render, shared by its bands, as dfc decode does
            mixed = EdgeMask(model.field.mesh, side, side) if pixel_filter != "point" else None
            for a in range(0, side, band):
                render_region(model, side, side, rows=(a, min(side, a + band)), cols=(0, side), mixed=mixed,
                              pixel_filter=pixel_filter)
    return 1e3 * best_seconds(run, 1, device) / (side * side / 1e6)


def fit_samples_per_s(image, mesh, device, steps: int, batch_size: int) -> float:
    """Training samples per second of an image fit of ``steps`` (≥ 2) steps of ``batch_size`` samples on
    ``device``, from the end of its first step to the end of its last (the sampler's set-up left out)."""
    from ...settings import FitSettings
    from ...train.fit import fit_image

    marks = {}

    def mark(step, loss, psnr):
        if step in (0, steps - 1):
            _sync(device)
            marks[step] = time.perf_counter()

    fit_image(image, mesh, FitSettings(steps=max(2, steps), batch_size=batch_size, device=str(device), qat_steps=0),
              callback=mark)
    return (max(2, steps) - 1) * batch_size / (marks[max(2, steps) - 1] - marks[0])


def encode_seconds(image, curves, device, steps: int | None) -> tuple[float, float]:
    """(seconds, PSNR) of an encode of ``image`` with ``curves`` on ``device`` (default settings but ``steps``)."""
    from ...codec import EncodeSettings, encode_image

    _sync(device)
    clock = time.perf_counter()
    _, report = encode_image(image, curves, EncodeSettings(device=str(device), steps=steps))
    _sync(device)
    return time.perf_counter() - clock, report.psnr


@click.command()
@click.option("--device", default="cuda", show_default=True, help="The device measured (a CUDA device; cpu for "
                                                                   "a dry run of the same table).")
@click.option("--sides", default="1024,4096,16384", show_default=True, help="Comma-separated decode sides (px).")
@click.option("--fit-steps", type=click.IntRange(1), default=200, show_default=True,
              help="Steps of each fit-throughput run.")
@click.option("--batch-size", type=click.IntRange(1), default=1 << 18, show_default=True,
              help="Samples per step of the fit-throughput runs.")
@click.option("--render-side", type=click.IntRange(64, 16384), default=4096, show_default=True,
              help="Side of the render whose fit and encode are measured besides the README sample's.")
@click.option("--encode-steps", type=click.IntRange(1), default=None,
              help="Steps of the timed encodes [default: the encoder's default].")
@click.option("--cpu/--no-cpu", "with_cpu", default=True, show_default=True,
              help="Also measure on the CPU for the ratio (decodes up to 1024², the fit, the README sample's encode).")
@json_option
@quiet_option
def command(device, sides, fit_steps, batch_size, render_side, encode_steps, with_cpu, json_path, quiet):
    """Every GPU figure in one table: decode ms per megapixel at each side (anti-aliased and point), fit samples per
    second and encode time of the README sample and a large render, peak GPU memory, and the CPU's figures for the
    ratio. Without a CUDA device: one line, exit 0."""
    import torch

    from ...codec import load
    from ...geometry.curves import fit_curves_to_domain
    from ...geometry.sources import read_any
    from ...io.image import read_image
    from ...codec import EncodeSettings
    from ...rate import sized_mesh
    from ...render import render
    from ..neighbour import SAMPLES

    err = stdout_taken(json_path)
    dev = torch.device(device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        click.echo("dfc benchmark gpu: no CUDA device on this machine (torch.cuda.is_available() is false); "
                   "nothing measured")
        return
    try:
        side_list = [int(s) for s in sides.split(",") if s.strip()]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated integers, got {sides!r}", param_hint="--sides")
    if not side_list or min(side_list) < 16:
        raise click.BadParameter("give at least one side, each >= 16", param_hint="--sides")
    cpu = torch.device("cpu")
    measure_cpu = with_cpu and dev.type != "cpu"
    name = torch.cuda.get_device_name(dev) if dev.type == "cuda" else "CPU"
    click.echo(f"dfc benchmark gpu on {device} ({name}); CPU threads {torch.get_num_threads()}", err=err)
    rows = []

    def add(what, value, unit, cpu_value=None, target=None):
        rows.append({"what": what, "device": device, "value": value, "unit": unit, "cpu_value": cpu_value,
                     "peak_mb": _peak_mb(dev), "target": target})
        if not quiet:
            click.echo("  " + format_table([rows[-1]])[1].strip(), err=True)

    sample_file = SAMPLES / "sample.dfield"
    model, cpu_model = load(sample_file, device=device), load(sample_file)
    for side in side_list:
        for filt in ("box", "point"):
            _peak_reset(dev)
            ms = decode_ms_per_mp(model, side, filt, dev, on_device=False)
            ref = decode_ms_per_mp(cpu_model, side, filt, cpu, False) if measure_cpu and side <= CPU_DECODE_MAX_SIDE \
                else None
            add(f"decode {side}², {'anti-aliased (box)' if filt == 'box' else 'point'}", ms, "ms/MP", ref,
                DECODE_TARGET_MS_PER_MP)
        _peak_reset(dev)
        add(f"decode {side}², point, on the device alone", decode_ms_per_mp(model, side, "point", dev, True), "ms/MP",
            None, DECODE_TARGET_MS_PER_MP)

    curves = read_any(SAMPLES / "sample.json")
    image = read_image(SAMPLES / "sample.exr")
    big = render(model, render_side, render_side)
    big_curves = fit_curves_to_domain(curves, (0.0, 0.0, float(render_side), float(render_side)))
    for label, pixels, crv in (("README sample 256²", image.pixels, curves),
                               (f"render {render_side}²", big, big_curves)):
        mesh = sized_mesh(crv, EncodeSettings(), ["R", "G", "B"])[1]
        _peak_reset(dev)
        rate = fit_samples_per_s(pixels, mesh, dev, fit_steps, batch_size)
        ref = fit_samples_per_s(pixels, mesh, cpu, max(2, fit_steps // 20), batch_size) if measure_cpu else None
        add(f"fit {label}, batch {batch_size}", rate, "samples/s", ref, FIT_TARGET_SAMPLES_PER_S)
        _peak_reset(dev)
        seconds, psnr = encode_seconds(pixels, crv, dev, encode_steps)
        ref = encode_seconds(pixels, crv, cpu, encode_steps)[0] if measure_cpu and pixels is image.pixels else None
        add(f"encode {label} (default, {psnr:.2f} dB)", seconds, "s", ref)
    click.echo("", err=err)
    for line in format_table(rows):
        click.echo(line, err=err)
    if json_path:
        write_json(json_path, {"title": "dfc benchmark gpu", "page": "speed", "device": device, "device_name": name,
                               "rows": rows, "tables": [{"title": f"on {name}",
                                                         "columns": ["measure", "value", "unit", "CPU", "peak MB"],
                                                         "rows": [[r["what"], round(r["value"], 4), r["unit"],
                                                                   r["cpu_value"], r["peak_mb"]] for r in rows]}]})
