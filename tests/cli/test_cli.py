"""The dfc command line end to end: encode → stats → decode → zoom on the shipped sample, and every
error path giving one line on stderr with a non-zero exit and no output file."""

import json
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from dfc.bench.scenes import sample_scene
from dfc.cli import main
from dfc.codec import load
from dfc.geometry.pixels import edge_pixels
from dfc.io.image import read_image, write_exr
from dfc.metrics import psnr
from dfc.render import render

from ..conftest import SAMPLES
from ..io.test_container import join, split

STEPS = "150"


def run(argv, capsys):
    """Run ``dfc argv`` in-process; return (exit code, stdout, stderr)."""
    try:
        main([str(a) for a in argv])
        code = 0
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 1
    out = capsys.readouterr()
    return code, out.out, out.err


def assert_one_line_error(code, err, match):
    assert code != 0
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert lines and "Traceback" not in err, err
    assert match in lines[-1], err
    assert len([ln for ln in lines if "error" in ln.lower()]) == 1, err


@pytest.fixture(scope="module")
def encoded(tmp_path_factory):
    d = tmp_path_factory.mktemp("enc")
    out, report = d / "sample.dfield", d / "report.json"
    with pytest.MonkeyPatch.context():
        try:
            main(["encode", str(SAMPLES / "sample.exr"), "--curves", str(SAMPLES / "sample.json"), "-o", str(out),
                  "--steps", STEPS, "--batch-size", "8192", "--json", str(report), "-q"])
        except SystemExit as e:
            assert e.code in (0, None)
    return out, json.loads(report.read_text())


def test_encode_summary_and_stats(encoded, capsys):
    path, report = encoded
    assert report["total_bytes"] == path.stat().st_size
    assert report["psnr"] > 33.0  # 150 steps; the default 1000 reach about 44 dB
    # a clean image without --target-bytes: its default mesh's bytes are a target, shared with a residual
    assert report["total_bytes"] <= report["default_target"] and report["chunk_bytes"]["rESD"] > 0
    code, out, _ = run(["stats", path, "--json"], capsys)
    assert code == 0
    s = json.loads(out)
    assert s["file_bytes"] == report["total_bytes"]
    assert s["mesh"]["triangles"] == report["n_triangles"] and s["mesh"]["vertices"] == report["n_vertices"]
    assert s["mesh"]["curved_triangles"] >= 6 and s["mesh"]["discontinuous_edges"] >= 3
    assert s["mesh"]["discontinuous_vertices"] > 0
    assert s["parameters"]["feature_rows"] == report["n_features"]
    assert s["bits_per_pixel"] == pytest.approx(8 * report["total_bytes"] / (256 * 256))
    assert sum(s["chunk_bytes"].values()) + 16 == s["file_bytes"]
    assert s["channels"] == ["R", "G", "B"] and s["time_axis"] is None
    assert s["value_transform"] == "affine" and len(s["value_map"]["offset"]) == 3  # fitted in normalised units
    assert s["mesh"]["encoding"] == "derived" and s["mesh"]["free_vertex_bits"] < s["mesh"]["bits"] == 20
    bary = re.fullmatch(r"barycentric, (\d+) bits", s["mesh"]["control_points"])
    assert s["mesh"]["topology_chunk"] == "TOPC" and bary and 1 <= int(bary.group(1)) <= 24
    code, out, _ = run(["stats", path], capsys)
    assert code == 0 and "curved triangles" in out and str(report["n_triangles"]) in out and "offset + scale" in out
    assert "triangles derived" in out and f"{s['mesh']['control_points']} (TOPC)" in out


def test_encode_says_when_it_sets_a_byte_target_itself(tmp_path, capsys):
    from dfc.bench.pixel_filters import filtered_raster
    from dfc.bench.scenes import shapes_scene
    from dfc.geometry.sources.jsonfile import write_json

    scene = shapes_scene()
    image, curves, out = tmp_path / "shapes.exr", tmp_path / "shapes.json", tmp_path / "shapes.dfield"
    write_exr(image, filtered_raster(scene, 64, 64, "box:4"), ["R", "G", "B"], half=False)
    write_json(scene.curves, curves)
    base = ["encode", image, "--curves", curves, "--fit-curves-to-image", "-o", out, "--steps", "40",
            "--no-raster-mode"]  # forty steps: the raster mode's file would win (tests/test_raster_mode.py)
    code, text, err = run(base, capsys)
    assert code == 0, err
    assert "no --target-bytes: a clean image gets the bytes of its default mesh" in text and "rESD" in text
    code, text, err = run([*base, "--residual-bytes", "0"], capsys)
    assert code == 0, err
    assert "no --target-bytes" not in text and "rESD" not in text


def test_decode_matches_reported_psnr_and_is_deterministic(encoded, tmp_path, capsys):
    path, report = encoded
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    for out in (a, b):
        code, _, err = run(["decode", path, "-o", out, "--float", "-q"], capsys)
        assert code == 0, err
    assert a.read_bytes() == b.read_bytes()
    decoded = read_image(a).pixels
    truth = read_image(SAMPLES / "sample.exr").pixels
    assert decoded.shape == truth.shape
    assert psnr(truth, decoded, data_range=1.0) == pytest.approx(report["psnr"], abs=1e-3)


def test_decode_any_size_and_window_samples_pixel_centres(encoded, tmp_path, capsys):
    path, _ = encoded
    model = load(path)
    out = tmp_path / "w.exr"
    window = ["--size", "40x30", "--window", "100,50,140,80"]
    code, _, err = run(["decode", path, "-o", out, "--float", *window, "--edge-spp", "0", "-q"], capsys)
    assert code == 0, err
    img = read_image(out).pixels
    assert img.shape == (30, 40, 3)
    xs, ys = np.meshgrid(100 + np.arange(40) + 0.5, 50 + np.arange(30) + 0.5)
    with torch.no_grad():
        direct = model(torch.from_numpy(np.stack([xs.ravel(), ys.ravel()], 1))).numpy().reshape(30, 40, 3)
    np.testing.assert_allclose(img, direct, rtol=0, atol=1e-6)
    # on the input's grid (1 domain unit per pixel) the default filters the pixels an edge crosses with the file's
    # pixel filter (the sample's 4 x 4 sub-samples, found by the encoder)
    code, _, err = run(["decode", path, "-o", out, "--float", *window, "-q"], capsys)
    assert code == 0, err
    mixed = edge_pixels(model.field.mesh, 30, 40, (100, 50, 140, 80))
    boxed = read_image(out).pixels
    assert mixed.any() and not mixed.all()
    np.testing.assert_allclose(boxed[~mixed], direct[~mixed], rtol=0, atol=1e-6)
    assert np.abs(boxed[mixed] - direct[mixed]).max() > 0.05
    assert model.header["pixel_filter"] == "box:4"
    np.testing.assert_allclose(boxed, render(model, 40, 30, (100, 50, 140, 80), pixel_filter="box:4"), rtol=0,
                               atol=1e-6)
    png = tmp_path / "big.png"
    code, _, err = run(["decode", path, "-o", png, "--size", "1024x1024", "-q"], capsys)
    assert code == 0, err
    assert read_image(png).pixels.shape == (1024, 1024, 3)


def test_zoom_100x_across_an_edge_keeps_the_jump(encoded, tmp_path, capsys):
    """The triangle's edge from (150, 30) to (230, 60): at 100x both sides keep their own exact colour."""
    path, _ = encoded
    scene = sample_scene()
    out = tmp_path / "z.exr"
    centre = (190.0, 45.0)
    code, _, err = run(["zoom", path, "--center", "190,45", "--zoom", "100", "-o", out, "--float", "--size", "64x64",
                        "-q"], capsys)
    assert code == 0, err
    img = read_image(out).pixels.reshape(-1, 3)
    half = 256 / 100 / 2
    g = centre[0] - half + (np.arange(64) + 0.5) * (2 * half / 64)
    h = centre[1] - half + (np.arange(64) + 0.5) * (2 * half / 64)
    X, Y = np.meshgrid(g, h)
    xy = np.stack([X.ravel(), Y.ravel()], 1)
    truth = scene.value(xy)
    d = xy - [150.0, 30.0]
    side = 80.0 * d[:, 1] - 30.0 * d[:, 0] > 0
    assert 0.2 < side.mean() < 0.8
    jump = truth[side].mean(0) - truth[~side].mean(0)
    assert np.abs(jump).max() > 0.3
    got = img[side].mean(0) - img[~side].mean(0)
    np.testing.assert_allclose(got, jump, atol=0.08 * np.abs(jump).max())
    assert np.abs(img - truth).max() < 0.1


def test_input_errors_are_one_line(encoded, tmp_path, capsys):
    path, _ = encoded
    cases = []
    bad = tmp_path / "broken.dfield"
    bad.write_bytes(path.read_bytes()[:-40])
    cases.append((["decode", bad, "-o", tmp_path / "o1.exr"], "dfc: error:"))
    chunks = split(path.read_bytes())
    assert chunks[1][0] == b"MESH" and chunks[1][1][0] == 2  # the derived encoding, CRCs recomputed below
    chunks[1][1] = chunks[1][1][:-2]
    (tmp_path / "mesh.dfield").write_bytes(join(chunks))
    cases.append((["stats", tmp_path / "mesh.dfield"], "MESH: derived vertex stream truncated"))
    nan = read_image(SAMPLES / "sample.exr").pixels.copy()
    nan[3, 5, 1] = np.nan
    write_exr(tmp_path / "nan.exr", nan, ["R", "G", "B"], half=False)
    cases.append((["encode", tmp_path / "nan.exr", "--curves", SAMPLES / "sample.json", "-o", tmp_path / "o2.dfield"],
                  "NaN"))
    small = read_image(SAMPLES / "sample.exr").pixels[:100, :120]
    write_exr(tmp_path / "small.exr", small, ["R", "G", "B"])
    cases.append((["encode", tmp_path / "small.exr", "--curves", SAMPLES / "sample.json", "-o",
                   tmp_path / "o3.dfield"], "--fit-curves-to-image"))
    cases.append((["encode", SAMPLES / "sample.exr", "--curves", SAMPLES / "sample.json", "-o",
                   tmp_path / "missing" / "o4.dfield", "--steps", "1"], "dfc: error:"))
    (tmp_path / "c.json").write_text('{"format": "dfc-curves/1", "domain": [0, 0, 1]}')
    cases.append((["encode", SAMPLES / "sample.exr", "--curves", tmp_path / "c.json", "-o", tmp_path / "o5.dfield"],
                  "c.json"))
    cases.append((["decode", path, "-o", tmp_path / "o6.exr", "--size", "0x10"], "--size"))
    cases.append((["decode", path, "-o", tmp_path / "o7.exr", "--window", "5,5,1,1"], "--window"))
    cases.append((["decode", path, "-o", tmp_path / "o8.tif"], "-o"))
    cases.append((["zoom", path, "--center", "999,5", "--zoom", "10", "-o", tmp_path / "o9.png"], "--center"))
    cases.append((["decode", path, "-o", tmp_path / "o10.exr", "--time", "0.5"], "time axis"))
    cases.append((["encode", SAMPLES / "sample.exr", "--curves", SAMPLES / "sample.json", "-o", tmp_path / "o11.dfield",
                   "--device", "tpu"], "--device"))
    cases.append((["encode", SAMPLES / "sample.exr", "--curves", SAMPLES / "sample.json", "-o", tmp_path / "o12.dfield",
                   "--weight-bits", "1"], "--weight-bits"))
    cases.append((["encode", SAMPLES / "sample.exr", "--curves", SAMPLES / "sample.json", "-o", tmp_path / "o13.dfield",
                   "--refine", "1", "--epoch-pixels", "1000"], "--refine"))  # refinement needs the image whole
    cases.append((["encode", SAMPLES / "sample.exr", "--curves", SAMPLES / "sample.json", "-o", tmp_path / "o14.dfield",
                   "--target-psnr", "40", "--target-bytes", "9000"], "--target-psnr"))
    cases.append((["encode", SAMPLES / "sample.exr", "--curves", SAMPLES / "sample.json", "-o", tmp_path / "o15.dfield",
                   "--target-psnr", "40", "--epoch-pixels", "1000"], "--target-psnr"))
    for k, (extra, match) in enumerate([(["--residual-bytes", "-1"], "--residual-bytes"),
                                        (["--target-bytes", "3000", "--residual-bytes", "3000"], "leaves nothing"),
                                        (["--steps", "5", "--residual-bytes", "20"], "smallest stream")]):
        cases.append((["encode", SAMPLES / "sample.exr", "--curves", SAMPLES / "sample.json", "-o",
                       tmp_path / f"o{16 + k}.dfield", *extra], match))
    for argv, match in cases:
        code, _, err = run(argv, capsys)
        assert_one_line_error(code, err, match)
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith("o")]


@pytest.mark.shared
def test_damaged_exr_inputs(shared_data, tmp_path, capsys):
    files = sorted(p for p in (shared_data / "exr" / "damaged").iterdir() if p.is_file())[:12]
    for p in files:
        link = tmp_path / f"{p.name}.exr"
        link.symlink_to(p)
        code, _, err = run(["encode", link, "--curves", SAMPLES / "sample.json", "-o", tmp_path / "x.dfield"], capsys)
        assert_one_line_error(code, err, p.name)
    assert not (tmp_path / "x.dfield").exists()


def test_terminated_decode_leaves_no_file(encoded, tmp_path):
    path, _ = encoded
    out = tmp_path / "big.exr"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "dfc", "decode", str(path), "-o", str(out), "--size", "4096x4096"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    deadline = time.monotonic() + 120
    while not any(p.name.startswith(".big.exr.") for p in tmp_path.iterdir()):  # the writer has started
        assert proc.poll() is None and time.monotonic() < deadline, "decode ended before it was interrupted"
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(60) != 0
    assert list(tmp_path.iterdir()) == []


def test_help_for_every_command(capsys):
    for cmd in ("encode", "decode", "zoom", "stats", "mesh"):
        code, out, _ = run([cmd, "--help"], capsys)
        assert code == 0 and "Usage: dfc " + cmd in out and "--" in out


def test_encode_a_sample_set(tmp_path, capsys):
    from dfc.codec import sample_steps
    from dfc.io.samples import SampleSet, write_samples

    scene = sample_scene()
    rng = np.random.default_rng(0)
    xy = rng.random((20000, 2)) * 256
    noisy = scene.value(xy) + rng.normal(0, 0.05, (len(xy), 3))
    write_samples(tmp_path / "s.npz", SampleSet(xy, noisy.astype(np.float32), (0.0, 0.0, 256.0, 256.0),
                                                ["R", "G", "B"]))
    out = tmp_path / "s.dfield"
    code, stdout, err = run(["encode", tmp_path / "s.npz", "--curves", SAMPLES / "sample.json", "-o", out,
                             "--steps", "80", "--batch-size", "4096", "--max-triangles", "600", "-q"], capsys)
    assert code == 0, err
    assert "bits per sample" in stdout
    model = load(out)
    probe = rng.random((2000, 2)) * 256
    with torch.no_grad():
        got = model(torch.from_numpy(probe)).numpy()
    assert psnr(scene.value(probe), got, data_range=1.0) > 22.0  # the samples themselves are at 26 dB
    code, stdout, _ = run(["stats", out, "--json"], capsys)
    assert code == 0 and json.loads(stdout)["bits_per_pixel"] is None
    code, _, err = run(["encode", tmp_path / "s.npz", "--curves", SAMPLES / "sample.json", "-o", out,
                        "--channels", "R"], capsys)
    assert_one_line_error(code, err, "--channels")
    # without --steps a sample set runs SAMPLE_PASSES passes over its samples (here more than the default 1000)
    code, _, err = run(["encode", tmp_path / "s.npz", "--curves", SAMPLES / "sample.json", "-o", out,
                        "--batch-size", "200", "--max-triangles", "300", "-q"], capsys)
    assert code == 0, err
    assert load(out).header["encoder"]["steps"] == sample_steps(20000, 200) == 1200
