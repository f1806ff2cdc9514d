"""``dfc benchmark wos SCENE``: denoising walk-on-spheres samples with a fitted field (paper Fig. 11).

One stratified sample set of ``max(spp)`` walks per pixel is drawn (``dfc.physics.wos.sample_scene``); its first
``s`` passes are the ``s``-spp set. For each ``s`` the benchmark measures, against the finite-difference
reference (``dfc.physics.reference``, solved ``--reference-scale`` times finer so that a reference node sits at every
pixel centre), the MSE of

(a) the raw per-pixel mean of the samples (what a Monte Carlo renderer shows), and
(b) a dfc field fitted to the same samples (``dfc.train.fit.fit_samples`` on ``triangulate(curves)``; the best of
    ``--restarts`` seeds by MSE over the samples themselves), rendered
    at the pixel centres (``dfc.render.render``),

and prints their ratio, the variance-reduction factor (paper: 19.21× at 11 spp), and the PSNR of each against the
reference (data range ``dfc.metrics.data_range`` of the reference).

With ``--encode`` it also measures what ``dfc encode SAMPLES.npz`` writes (``dfc.codec.encode_samples`` with the
codec's own mesh sizing and step count, ``dfc.codec.sample_steps``, and ``--batch-size`` and ``--seed``): the
file decoded, rendered at the pixel centres, against the reference — the held-out figure — beside the PSNR the
encoder itself reports (``EncodeReport.psnr``, measured on the samples).

Curved pieces are cut as ``dfc encode SAMPLES.npz`` cuts the largest sample set (``dfc.codec.sample_piece_length``
of ``max(spp)`` walks per pixel; ``--piece-length`` overrides, in pixels); the mesh size is ``--max-triangles``.
A curved piece lies in one triangle whose sliver between chord and curve carries a single curve feature, so
a long piece leaves a wide band along the curve with little freedom; on the shipped pepper at 128², cutting
at 4 px roughly halves the error within 2 px of the curves.

The fits converge slowly on noisy targets: on the pepper at 256² and 11 spp, 400 steps (lr 5e-3 → 1e-3) give
a factor of 7.6, 1,500 or 3,000 steps decaying to 1e-4 give 21.5. What remains is the fit's bias, about
5e-6, mostly near the curves; the variance part shrinks with the pixel count, which is why the paper's
resolution, 500, is the default.

The MSE is taken over the pixels that no curve crosses (``dfc.geometry.pixels.edge_pixels``): the raw mean estimates
a pixel's box average, which equals the centre value up to O(h⁴) for a harmonic function but not in a
pixel cut by a discontinuity, where it blends both sides. The MSE over all pixels is printed too; there
(a) also carries that blend.
"""

from __future__ import annotations

import time

import click
import numpy as np

from ...command import quiet_option, stdout_taken, threads_option, write_json


def _spp_list(ctx, param, value):
    try:
        spp = sorted({int(v) for v in value.split(",")})
    except ValueError:
        raise click.BadParameter(f"expected comma-separated integers, got {value!r}") from None
    if not spp or spp[0] < 1:
        raise click.BadParameter("sample counts must be ≥ 1")
    return spp


def _odd(ctx, param, value):
    if value % 2 == 0:
        raise click.BadParameter("must be odd (a reference node then sits at every pixel centre)")
    return value


@click.command()
@click.argument("scene_path", metavar="SCENE", type=click.Path(exists=True, dir_okay=False))
@click.option("--resolution", type=click.IntRange(min=8), default=500, show_default=True,
              help="Pixels on the long side (the paper's 500).")
@click.option("--spp", "spp_list", default="1,4,11,32", show_default=True, callback=_spp_list,
              help="Comma-separated walks per pixel.")
@click.option("--steps", type=click.IntRange(min=1), default=2000, show_default=True,
              help="Fit steps per spp.")
@click.option("--max-triangles", type=click.IntRange(min=2), default=2000, show_default=True,
              help="Mesh size of the fitted field.")
@click.option("--piece-length", type=click.FloatRange(min=0.0), default=None,
              help="Cut curved pieces longer than this many pixels before meshing (0: keep them)  "
                   "[default: as dfc encode cuts the largest sample set].")
@click.option("--qat/--no-qat", default=False, show_default=True,
              help="Quantisation-aware final fit steps (8-bit features, as a .dfield file would store).")
@click.option("--lr", type=click.FloatRange(min=0.0, min_open=True), default=5e-3, show_default=True,
              help="Initial Adam learning rate of the fits (decays geometrically to --final-lr; "
                   "1e-2 sometimes diverges near the curves on noisy samples).")
@click.option("--final-lr", type=click.FloatRange(min=0.0, min_open=True), default=1e-4, show_default=True,
              help="Learning rate at the last fit step.")
@click.option("--restarts", type=click.IntRange(min=1), default=1, show_default=True,
              help="Fits per spp (seeds seed, seed + 1, ...); the one with the lowest MSE over its own samples is "
                   "kept (an unlucky start sometimes leaves a whole smooth region offset).")
@click.option("--batch-size", type=click.IntRange(min=1), default=1 << 14, show_default=True, help="Fit batch size.")
@click.option("--reference-scale", type=click.IntRange(min=1), default=3, show_default=True, callback=_odd,
              help="The reference grid is this many times finer than the pixel grid (odd).")
@threads_option
@click.option("--device", default="cpu", show_default=True, help="torch device of the fits.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the walks and the fits.")
@click.option("--encode", "measure_encode", is_flag=True,
              help="Also encode each sample set as dfc encode does and measure the file against the reference.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, allow_dash=True),
              help="Also write the figures to this JSON file (- for standard output; the text then goes to "
                   "standard error).")
@quiet_option
def command(scene_path, resolution, spp_list, steps, max_triangles, piece_length, qat, lr, final_lr, restarts,
            batch_size, reference_scale, device, seed, measure_encode, json_path, quiet):
    """Variance reduction of a dfc fit over the raw mean of walk-on-spheres samples, per sample count."""
    from ...codec import sample_piece_length
    from ...geometry.curves import split_pieces
    from ...geometry.sources import read_curves
    from ...geometry.pixels import edge_pixels
    from ...geometry.triangulate import triangulate
    from ...io.samples import SampleSet
    from ...metrics import data_range, psnr
    from ...physics.reference import solve_reference
    from ...physics.wos import Scene, grid_size, sample_scene
    from ...render import render
    from ...train.fit import fit_samples

    text_err = stdout_taken(json_path)
    curves = read_curves(scene_path)
    scene = Scene(curves)
    width, height = grid_size(scene.domain, resolution)
    k = reference_scale
    clock = time.perf_counter()
    reference = solve_reference(scene, k * width, k * height).values[k // 2 :: k, k // 2 :: k]
    reference_s = time.perf_counter() - clock
    clock = time.perf_counter()
    capped = [0]
    samples = sample_scene(scene, resolution, max(spp_list), seed=seed,
                           callback=lambda done, total, n: capped.__setitem__(0, n))
    wos_s = time.perf_counter() - clock
    pixel = (scene.domain[2] - scene.domain[0]) / width
    if piece_length is None:
        piece_length = sample_piece_length(scene.domain, max(spp_list) * width * height) / pixel
    mesh = triangulate(split_pieces(curves, piece_length * pixel) if piece_length > 0 else curves,
                       max_triangles=max_triangles)
    clean = ~edge_pixels(mesh, height, width)
    n_pix = width * height
    peak = data_range(reference)
    stats: dict = {"scene": str(scene_path), "width": width, "height": height, "reference_scale": k,
                   "triangles": mesh.n_triangles, "steps": steps, "batch_size": batch_size, "qat": qat, "lr": lr,
                   "final_lr": final_lr, "restarts": restarts, "piece_length_px": piece_length,
                   "clean_pixel_fraction": float(clean.mean()), "walks": len(samples), "capped_walks": capped[0],
                   "reference_s": reference_s, "wos_s": wos_s, "rows": []}
    click.echo(f"{scene_path}: {width} × {height} pixels ({clean.mean():.1%} not crossed by a curve), "
               f"reference {k * width} × {k * height} in {reference_s:.1f} s; {len(samples)} walks in {wos_s:.1f} s "
               f"({capped[0]} capped); mesh {mesh.n_triangles} triangles, {steps} steps", err=text_err)
    click.echo(f"{'spp':>4} {'raw MSE':>10} {'fit MSE':>10} {'factor':>7}   {'all: raw':>10} {'fit':>10} "
               f"{'factor':>7} {'fit s':>6}   PSNR against the reference (data range {peak:.3g}): raw / fit"
               + (" / encode (encoder's own, on the samples)" if measure_encode else ""), err=text_err)
    for spp in spp_list:
        n = spp * n_pix
        subset = SampleSet(samples.xy[:n], samples.values[:n], samples.domain, samples.channels)
        cell = np.tile(np.arange(n_pix), spp)  # pass p covers every pixel once, in order
        raw = np.stack([np.bincount(cell, subset.values[:, c], n_pix) for c in range(subset.n_channels)], 1)
        raw = (raw / spp).reshape(height, width, -1)
        clock = time.perf_counter()
        fits = [fit_samples(subset, mesh, steps=steps, batch_size=batch_size, seed=seed + r, device=device,
                            qat_steps=None if qat else 0, lr=lr, final_lr=final_lr) for r in range(restarts)]
        model = min(fits, key=lambda m: _sample_mse(m, subset))
        fit_s = time.perf_counter() - clock
        image = render(model, width, height)
        err_raw, err_fit = (raw - reference) ** 2, (image - reference) ** 2
        row = {"spp": spp, "raw_mse": float(err_raw[clean].mean()), "fit_mse": float(err_fit[clean].mean()),
               "raw_mse_all": float(err_raw.mean()), "fit_mse_all": float(err_fit.mean()), "fit_s": fit_s}
        row["factor"] = row["raw_mse"] / row["fit_mse"]
        row["factor_all"] = row["raw_mse_all"] / row["fit_mse_all"]
        row["raw_psnr"] = psnr(reference, raw, data_range=peak)
        row["fit_psnr"] = psnr(reference, image, data_range=peak)
        line = f"{row['raw_psnr']:.2f} / {row['fit_psnr']:.2f} dB"
        if measure_encode:
            row["encode"] = _encode(subset, curves, batch_size, seed, device, reference, clean, peak)
            line += f" / {row['encode']['psnr']:.2f} dB ({row['encode']['encoder_psnr']:.2f})"
        stats["rows"].append(row)
        click.echo(f"{spp:>4} {row['raw_mse']:10.3e} {row['fit_mse']:10.3e} {row['factor']:6.2f}×   "
                   f"{row['raw_mse_all']:10.3e} {row['fit_mse_all']:10.3e} {row['factor_all']:6.2f}× {fit_s:6.1f}   "
                   + line, err=text_err)
    if json_path:
        write_json(json_path, stats)


def _encode(samples, curves, batch_size, seed, device, reference, clean, peak) -> dict:
    """``dfc.codec.encode_samples`` of ``samples`` decoded and rendered at the pixel centres, against ``reference``
    (H, W, C): PSNR on every pixel, MSE on every pixel and on the ``clean`` ones, the encoder's own PSNR, bytes,
    triangles and seconds."""
    from ...codec import EncodeSettings, encode_samples, loads, sample_steps
    from ...metrics import psnr
    from ...render import render

    clock = time.perf_counter()
    settings = EncodeSettings(steps=sample_steps(len(samples), batch_size), batch_size=batch_size, seed=seed,
                              device=device)
    blob, report = encode_samples(samples, curves, settings)
    seconds = time.perf_counter() - clock
    height, width = reference.shape[:2]
    image = render(loads(blob), width, height)
    err = (image - reference) ** 2
    return {"psnr": psnr(reference, image, data_range=peak), "mse": float(err[clean].mean()),
            "mse_all": float(err.mean()), "encoder_psnr": report.psnr, "bytes": len(blob),
            "triangles": report.n_triangles, "steps": settings.steps, "seconds": seconds}


def _sample_mse(model, samples, chunk: int = 1 << 16) -> float:
    """Mean squared error of a fitted model over the samples it was fitted to (no reference involved)."""
    import torch

    total = 0.0
    with torch.no_grad():
        for s in range(0, len(samples), chunk):
            xy = torch.from_numpy(samples.xy[s : s + chunk]).to(model.field.bank.device)
            pred = model(xy).cpu().numpy()
            total += float(((pred - samples.values[s : s + chunk]) ** 2).sum())
    return total / samples.values.size
