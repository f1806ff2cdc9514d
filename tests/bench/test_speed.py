"""Held-out truth in the encoders' benchmarks: FEM element centroids against the finite element interpolant, and a
walk-on-spheres encode against the reference solve."""

import json

import meshio
import numpy as np
import pytest

from dfc.bench.speed.fem import interior_points
from dfc.physics.fem import sample_fem

from ..cli.test_cli import run
from ..conftest import SAMPLES
from ..physics.test_fem import grid_mesh, write_curves

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture
def wall(tmp_path):
    pts, tris = grid_mesh(9)
    u = np.where(pts[:, 0] < 0.5, 0.2, 0.7) + 0.1 * pts[:, 1]
    path = tmp_path / "sol.vtu"
    meshio.write(path, meshio.Mesh(np.c_[pts, np.zeros(len(pts))], [("triangle", tris)], point_data={"u": u}))
    return path, write_curves(tmp_path / "wall.json", [[[0.5, 0.0], [0.5, 1.0]]])


def test_interior_points_are_centroids_no_training_sample_hits(wall):
    from dfc.geometry.sources import read_curves
    from dfc.io.fem import read_fem

    sol = read_fem(wall[0])
    xy, tri, bary = interior_points(sol, 50)
    assert len(xy) == 50 and len(np.unique(tri)) == 50 and np.allclose(bary, 1 / 3)
    np.testing.assert_allclose(xy, sol.points[sol.triangles[tri]].mean(axis=1))
    train, _ = sample_fem(sol, read_curves(wall[1]))
    assert np.min(np.linalg.norm(xy[:, None] - train[None], axis=2)) > 1e-9
    assert len(interior_points(sol, 10**6)[0]) == len(sol.triangles)


def test_fem_benchmark_reports_held_out_psnr_and_equal_steps(wall, tmp_path, capsys):
    out = tmp_path / "fem.json"
    code, stdout, err = run(["benchmark", "fem", wall[0], "--curves", wall[1], "--max-triangles", "200", "--steps",
                             "40", "--batch-size", "1024", "--interior-points", "60", "--json", out], capsys)
    assert code == 0, err
    figures = json.loads(out.read_text())
    assert figures["held_out_points"] == 60 and figures["hash_steps"] == figures["dfc_steps"] == 40
    for key in ("dfc_psnr_held_out", "hash_psnr_held_out"):
        assert 5 < figures[key] < 100
    assert "held out" in stdout
    # the same field in three units (x1, x1e-4, x1e4 by default) fits the same
    units = figures["units"]
    assert [row["factor"] for row in units] == [1.0, 1e-4, 1e4]
    assert max(row["psnr"] for row in units) - min(row["psnr"] for row in units) < 0.5
    assert all(abs(row["bytes"] - units[0]["bytes"]) <= 0.02 * units[0]["bytes"] for row in units)
    assert 0 <= figures["leakage"]["dfc"]["share"] == units[0]["leakage_share"]
    assert "x0.0001" in stdout and "max / max |u|" in stdout


def test_wos_benchmark_measures_the_encode_against_the_reference(tmp_path, capsys):
    out = tmp_path / "wos.json"
    code, stdout, err = run(["benchmark", "wos", SAMPLES / "diffusion_small.json", "--resolution", "12", "--spp", "1",
                             "--steps", "5", "--batch-size", "256", "--max-triangles", "600", "--encode", "--json",
                             out], capsys)
    assert code == 0, err
    row = json.loads(out.read_text())["rows"][0]
    enc = row["encode"]
    assert enc["bytes"] > 0 and enc["triangles"] > 0 and np.isfinite(enc["encoder_psnr"])
    assert 0 < enc["psnr"] < 100 and enc["mse_all"] >= 0 and 0 < row["raw_psnr"] < 100
    assert "encode" in stdout


def test_training_psnr_is_the_last_epochs_mean_error_and_convergence_time_the_last_crossing():
    from dfc.bench.speed.encode import time_to_within, training_psnr

    # batches of 2 out of 4 points: an epoch is 2 steps; MSEs 1e-1, 1e-3, 1e-3, 1e-3
    curve = training_psnr(np.array([10.0, 30.0, 30.0, 30.0]), 2, 4)
    np.testing.assert_allclose(curve, [10.0, -10 * np.log10((0.1 + 0.001) / 2), 30.0, 30.0])
    seconds = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    assert time_to_within(np.array([20.0, 29.95, 29.0, 29.95, 30.0]), seconds) == (4.0, 3)
    assert time_to_within(np.array([30.0, 30.0]), seconds[:2]) == (1.0, 0)


def test_encode_benchmark_times_the_fit_and_breaks_a_step_down(tmp_path, capsys):
    out = tmp_path / "encode.json"
    code, stdout, err = run(["benchmark", "encode", "--steps", "30", "--batch-size", "4096", "--profile-steps", "10",
                             "--threads", "1", "--no-neighbour", "--json", out], capsys)
    assert code == 0, err
    figures = json.loads(out.read_text())
    (r,) = figures["runs"]
    assert (r["threads"], r["neighbour"], r["steps"], r["qat_steps"]) == (1, "none", 30, 3)
    assert 0 < r["within_0.1dB_s"] <= r["fit_s"] and 0 <= r["within_0.1dB_step"] < 27
    assert 5 < r["psnr"] < 100 and r["bytes"] > 0 and r["step_ms"] > 0 and r["qat_step_ms"] > 0
    parts = {row["part"]: row["ms_per_step"] for row in figures["breakdown"]}
    assert set(parts) == {"sampling", "interpolation", "MLP forward", "loss", "MLP backward",
                          "interpolation backward", "optimiser"}
    assert min(parts.values()) >= 0 and parts["MLP forward"] > 0 and parts["MLP backward"] > 0
    assert "within 0.1 dB" in stdout and "per step" in stdout


def test_encode_benchmark_wants_image_and_curves_together(capsys):
    code, _, err = run(["benchmark", "encode", SAMPLES / "sample.exr", "--no-neighbour"], capsys)
    assert code == 2 and "--curves" in err


def test_pixel_filter_benchmark_writes_its_tables(tmp_path, capsys):
    from dfc.bench.pixel_filters import ASSUMED, GENERATIONS
    from dfc.bench.results import validate

    out = tmp_path / "pf.json"
    code, stdout, err = run(["benchmark", "pixel-filter", "--size", "32", "--steps", "3", "--target-bytes", "6000",
                             "--json", out], capsys)
    assert code == 0, err
    doc = json.loads(out.read_text())
    assert validate(doc) == [] and doc["source"] == "measured"
    one_x, zoom, auto = doc["tables"]
    assert one_x["columns"] == ["made with", *ASSUMED] and [r[0] for r in one_x["rows"]] == list(GENERATIONS)
    assert all(np.isfinite(v) for r in one_x["rows"] + zoom["rows"] for v in r[1:])
    assert len(auto["rows"]) == len(GENERATIONS) + 2 and "auto chose" in stdout


def test_gpu_benchmark_without_cuda_says_so_in_one_line(monkeypatch, capsys):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    code, stdout, err = run(["benchmark", "gpu"], capsys)
    assert code == 0, err
    assert len((stdout + err).strip().splitlines()) == 1 and "no CUDA device" in stdout


def test_gpu_benchmark_table_on_cpu(tmp_path, capsys):
    out = tmp_path / "gpu.json"
    code, stdout, err = run(["benchmark", "gpu", "--device", "cpu", "--sides", "32", "--fit-steps", "2",
                             "--batch-size", "256", "--render-side", "64", "--encode-steps", "2", "--json", out],
                            capsys)
    assert code == 0, err
    rows = json.loads(out.read_text())["rows"]
    whats = [r["what"] for r in rows]
    assert whats[:3] == ["decode 32², anti-aliased (box)", "decode 32², point", "decode 32², point, on the device alone"]
    assert sum(w.startswith("fit ") for w in whats) == 2 and sum(w.startswith("encode ") for w in whats) == 2
    assert all(r["value"] > 0 and r["cpu_value"] is None and r["peak_mb"] is None for r in rows)
    assert "missed" in stdout or "met" in stdout


def test_gpu_table_ratio_and_targets():
    from dfc.bench.speed.gpu import format_table

    lines = format_table([
        {"what": "decode", "device": "cuda", "value": 0.5, "unit": "ms/MP", "cpu_value": 50.0, "target": 1.0},
        {"what": "fit", "device": "cuda", "value": 5e7, "unit": "samples/s", "cpu_value": 1e6, "target": 1e8,
         "peak_mb": 1234.0},
        {"what": "encode", "device": "cuda", "value": 4.0, "unit": "s"},
    ])
    assert len(lines) == 4
    assert "100.0x" in lines[1] and "met (<= 1)" in lines[1]
    assert "50.0x" in lines[2] and "missed (>= 1e+08)" in lines[2] and "1234" in lines[2]
    assert lines[3].rstrip().endswith("s")


def test_curves_auto_distances_run_to_the_curves_not_to_their_samples():
    """``compare``: the same geometry cut into other pieces (each piece split in two, so no sample of one set lies
    on a sample of the other) is 0 px away, at every zoom window too, and a copy moved 0.003 px sideways measures
    at most that."""
    from dataclasses import replace

    from dfc.bench.scenes import get_scene
    from dfc.bench.speed.curves_auto import compare
    from dfc.geometry import bezier

    curves = get_scene("shapes").curves
    halves = np.concatenate(bezier.split(curves.control_points, np.full(len(curves), 0.37)))
    split = replace(curves, control_points=halves, degree=np.tile(curves.degree, 2), curve=np.tile(curves.curve, 2),
                    t_range=np.tile(curves.t_range, (2, 1)))
    same = compare(curves, split)
    assert same["mean_px"] < 1e-5 and same["p95_px"] < 1e-5 and same["recall"] == 1.0 and same["false"] == 0.0
    assert len(same["probe_px"]) == curves.n_curves and max(same["probe_px"]) < 1e-5
    shifted = compare(curves, replace(curves, control_points=curves.control_points + [0.003, 0.0]))
    assert 0.0005 < shifted["mean_px"] < 0.003 + 1e-6
    assert 0.0005 < max(shifted["probe_px"]) <= 0.003 + 1e-5


def test_curves_auto_benchmark_measures_before_and_after_refinement(tmp_path, capsys):
    """``dfc benchmark curves-auto --pixel-filter F``: a row per stage (found, refined, and the exact curves refined:
    exact) with its localisation."""
    pytest.importorskip("skimage")
    from dfc.bench.results import validate

    out = tmp_path / "ca.json"
    code, stdout, err = run(["benchmark", "curves-auto", "--scene", "shapes", "--size", "96", "--pixel-filter",
                             "box:4", "--json", out], capsys)
    assert code == 0, err
    doc = json.loads(out.read_text())
    assert validate(doc) == []
    found, refined, exact = doc["localisation"]
    assert (found["stage"], refined["stage"], exact["stage"]) == ("found", "refined", "exact")
    assert found["filter"] == exact["filter"] == "box:4" and exact["detected"] == refined["detected"]
    assert found["pieces"] == refined["pieces"] and refined["mean_px"] < 0.8 * found["mean_px"]
    # the exact curves refined through the filter the raster was made with stay near themselves, nearer than the
    # found ones come (at 96 px a 4 x 4 box moves them 0.02 px on average, the found ones end 0.13 px off); they
    # are the scene's own pieces
    assert exact["recall"] == 1.0 and exact["mean_px"] < min(0.05, 0.5 * refined["mean_px"])
    assert exact["pieces"] != found["pieces"]
    assert " refined " in stdout and " exact " in stdout
    assert all(len(row["probe_px"]) == 4 for row in doc["localisation"])  # the middle of each of the 4 curves


def test_curves_auto_benchmark_measures_a_render_against_its_scene_curves(tmp_path, capsys):
    """``--render CASE``: the Mitsuba case rendered at --size, its found and refined curves measured against the
    scene's own curves (no analytic scene runs without --scene)."""
    pytest.importorskip("skimage")
    pytest.importorskip("mitsuba")

    out = tmp_path / "ca.json"
    code, stdout, err = run(["benchmark", "curves-auto", "--render", "mitsuba-shapes-hdr", "--size", "64", "--json",
                             out], capsys)
    assert code == 0, err
    rows = json.loads(out.read_text())["localisation"]
    assert [(r["scene"], r["filter"], r["stage"]) for r in rows] == [("mitsuba-shapes-hdr", "render", "found"),
                                                                      ("mitsuba-shapes-hdr", "render", "refined")]
    found = rows[0]
    assert (found["width"], found["height"]) == (64, 64) and found["curves"] >= 1
    assert found["matched_mean_px"] is not None and found["matched_mean_px"] < 0.5 and found["recall"] > 0.2
    code, _, err = run(["benchmark", "curves-auto", "--render", "no-such-case"], capsys)
    assert code != 0 and "no-such-case" in err


def test_curves_auto_zoom_row_encodes_three_curve_sets_at_equal_bytes():
    """``zoom_row``: the extracted curves' file sets the byte target of the true and the refined curves' files (and
    of the exact curves' refined, when given)."""
    from dataclasses import replace

    from dfc.bench.pixel_filters import filtered_raster
    from dfc.bench.speed.curves_auto import zoom_row

    from ..geometry.test_refine import _quad_and_disc

    scene = _quad_and_disc()
    pixels = filtered_raster(scene, 56, 56, "box")
    moved = replace(scene.curves, control_points=scene.curves.control_points + 0.2)
    row = zoom_row(scene, pixels, moved, scene.curves, steps=2)
    assert row["true_bytes"] <= row["auto_bytes"] and row["refined_bytes"] <= row["auto_bytes"]
    assert all(np.isfinite(row[f"{k}_{z}x"]) for k in ("true", "auto", "refined") for z in (33, 100))
    for k in ("true", "auto", "refined"):  # one window per curve, the middle of the quadrilateral's and the disc's
        assert len(row[f"{k}_100x_windows"]) == 2 and abs(np.mean(row[f"{k}_100x_windows"]) - row[f"{k}_100x"]) < 0.01
    assert not any(k.startswith("exact") for k in row)
    with_exact = zoom_row(scene, pixels, moved, scene.curves, steps=2, exact=scene.curves)
    assert with_exact["exact_bytes"] <= with_exact["auto_bytes"] and np.isfinite(with_exact["exact_100x"])
