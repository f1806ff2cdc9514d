"""``dfc benchmark pixel-filter``: how much knowing the pixel filter is worth (issue 26).

One analytic piecewise-constant scene (``dfc.bench.pixel_filters.polygon_scene``) is rasterised four ways (point
samples at the pixel centres, box with 16 × 16 sub-samples, Mitsuba's Gaussian σ 0.5 radius 2, Cycles'
Blackman–Harris 1.5) and each raster is encoded assuming each of those filters and ``auto`` at one byte target:
the table gives the 1× PSNR against the raster and the 100× PSNR of windows centred on edges against the exact
scene. Small by default (96², 300 steps: about 10 minutes on one CPU thread) — the numbers compare filters, they
are not dfc's best rate.
"""

from __future__ import annotations

import click

from ...command import threads_option, write_json


@click.command()
@click.option("--size", type=click.IntRange(32, 1024), default=96, show_default=True, help="Raster side (px).")
@click.option("--steps", type=click.IntRange(min=1), default=300, show_default=True, help="Fit steps per encode.")
@click.option("--target-bytes", type=click.IntRange(min=1), default=8000, show_default=True,
              help="Byte target of every encode of the table (no refinement round).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Also write the results as JSON.")
@threads_option
def command(size, steps, target_bytes, json_path):
    """Encode one scene rasterised with each pixel filter, assuming each filter and auto: a 4 x 5 table of the 1x
    PSNR at equal bytes and the 100x PSNR on edges against the exact scene; then the point-sampled raster at the
    default rate assuming point and box."""
    from ..pixel_filters import pixel_filter_table

    click.echo(f"polygon scene {size}x{size}, one channel, six grey levels; {steps} steps per encode (small: filters "
               f"compared, not dfc's best rate); {target_bytes} bytes target, no refinement")

    def progress(row):
        click.echo(f"  {row['generation']:>20} assuming {row['assumed']:<20} {row['bytes']:>6} bytes  "
                   f"1x {row['psnr_1x']:6.2f} dB" + (f"  100x {row['psnr_zoom']:6.2f} dB" if "psnr_zoom" in row
                                                     else "  (default rate)"), err=True)

    result = pixel_filter_table(size, steps, target_bytes, progress)
    assumed = list(dict.fromkeys(r["assumed"] for r in result["rows"]))
    generations = list(dict.fromkeys(r["generation"] for r in result["rows"]))
    cell = {(r["generation"], r["assumed"]): r for r in result["rows"]}
    zoom_title = (f"{result['zoom']:g}x PSNR (dB) on {len(result['probes'])} edge windows against the exact "
                  "scene")
    tables = []
    for title, key in (("1x PSNR (dB) against the raster, at equal bytes", "psnr_1x"), (zoom_title, "psnr_zoom")):
        click.echo(f"\n{title}; rows: how the raster was made, columns: the filter the encode assumed")
        click.echo(f"{'':>20}" + "".join(f"{a:>21}" for a in assumed))
        for g in generations:
            click.echo(f"{g:>20}" + "".join(f"{cell[(g, a)][key]:>21.2f}" for a in assumed))
        tables.append({"title": f"{title}; rows: how the raster was made, columns: the filter the encode assumed",
                       "columns": ["made with", *assumed],
                       "rows": [[g, *(round(cell[(g, a)][key], 2) for a in assumed)] for g in generations]})
    tables.append({"title": "auto's choice and the point-sampled raster at the default rate",
                   "columns": ["raster", "assumed", "chosen", "bytes", "1x PSNR (dB)"],
                   "rows": [[g, "auto", cell[(g, "auto")]["chosen"], cell[(g, "auto")]["bytes"],
                             round(cell[(g, "auto")]["psnr_1x"], 2)] for g in generations]
                   + [["point (default rate)", r["assumed"], r["assumed"], r["bytes"], round(r["psnr_1x"], 2)]
                      for r in result["default_rate"]]})
    result = {"tables": tables, **result}
    click.echo("\nauto chose: " + ", ".join(f"{g} -> {cell[(g, 'auto')]['chosen']}" for g in generations))
    for r in result["default_rate"]:
        click.echo(f"point-sampled raster at the default rate assuming {r['assumed']}: {r['psnr_1x']:.2f} dB in "
                   f"{r['bytes']} bytes")
    if json_path:
        write_json(json_path, result)
