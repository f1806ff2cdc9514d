"""``dfc bench``: windows and sample points, and tiny end-to-end runs through the CLI."""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image as PILImage

from dfc.bench.report import LABEL_WIDTH, TILE
from dfc.bench.scenes import SCENES
from dfc.cli import cli
from dfc.errors import InputError
from dfc.render import window_points, zoom_window

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = ["--size", "32", "--steps", "4", "--batch-size", "512", "--render", "16", "--spp", "1", "-q"]


def test_zoom_windows_are_centred_and_inside_the_domain():
    domain = (0.0, 0.0, 200.0, 100.0)
    assert zoom_window(domain, (30.0, 70.0), 1) == domain
    x0, y0, x1, y1 = zoom_window(domain, (50.0, 40.0), 10)
    assert math.isclose(x1 - x0, 20.0) and math.isclose(y1 - y0, 10.0)
    assert math.isclose((x0 + x1) / 2, 50.0) and math.isclose((y0 + y1) / 2, 40.0)
    x0, y0, x1, y1 = zoom_window(domain, (199.0, 1.0), 4)  # near a corner: shifted inside
    assert (x1, y0) == (200.0, 0.0) and math.isclose(x1 - x0, 50.0)


def test_window_points_are_pixel_centres_at_one_spp():
    xy = window_points((10.0, 20.0, 14.0, 22.0), 4, 2, 1)
    assert xy.shape == (8, 2)
    np.testing.assert_allclose(xy[:4, 0], [10.5, 11.5, 12.5, 13.5])
    np.testing.assert_allclose(xy[::4, 1], [20.5, 21.5])
    many = window_points((0.0, 0.0, 1.0, 1.0), 3, 3, 8)
    assert many.shape == (72, 2) and many.min() > 0 and many.max() < 1
    first_pixel = many[:8]
    assert np.all(first_pixel < 1 / 3)


def test_list_scenes_names_every_scene():
    result = CliRunner().invoke(cli, ["bench", "--list-scenes"])
    assert result.exit_code == 0
    assert {line.split()[0] for line in result.output.splitlines()} == set(SCENES)


def test_bench_on_a_tiny_scene_writes_the_results(tmp_path):
    out = tmp_path / "bench"
    result = CliRunner().invoke(cli, ["bench", "--scene", "strokes", "--max-triangles", "300", *TINY, "-o", str(out)])
    assert result.exit_code == 0, result.output
    res = json.loads((out / "results.json").read_text())
    methods = res["methods"]
    assert set(methods) == {"dfc", "hashgrid", "relu", "raster"}
    budget = methods["dfc"]["bytes"]
    assert budget == res["budget_bytes"] == len((out / "dfc.dfield").read_bytes())
    for m in ("hashgrid", "relu"):
        assert 0.97 * budget <= methods[m]["bytes"] <= budget
    assert 0 < methods["raster"]["bytes"] <= budget
    n_probes = len(res["probes"])
    assert n_probes == 2 and res["reference"] == "analytic"
    for m, r in methods.items():
        assert isinstance(r["bytes"], int) and r["points_per_s"] > 0
        assert set(r["psnr"]) == {"1", "10", "33", "100"}
        for values in r["psnr"].values():
            assert len(values) == n_probes and all(0 < v < 100 for v in values)
        assert r["psnr"]["1"][0] == r["psnr"]["1"][1]  # zoom 1 is the whole domain for every probe
    table = (out / "results.md").read_text()
    assert all(f"| {m} | {methods[m]['bytes']} |" in table for m in methods)
    sheet = PILImage.open(out / "contact.png")
    assert sheet.size == (LABEL_WIDTH + 4 * TILE, n_probes * 5 * TILE + 20)
    assert "| dfc |" in result.output


def test_bench_on_a_user_image_measures_zoom_one_only(tmp_path):
    from dfc.bench.scenes import shapes_scene
    from dfc.io.image import write_exr

    image = shapes_scene().render(24, 24, spp=1)
    write_exr(tmp_path / "in.exr", image, ["R", "G", "B"])
    curves = {"domain": [0, 0, 24, 24], "curves": [{"pieces": [{"type": "line", "points": [[2, 3], [20, 18]]}]}]}
    (tmp_path / "c.json").write_text(json.dumps(curves))
    out = tmp_path / "bench"
    result = CliRunner().invoke(cli, ["bench", str(tmp_path / "in.exr"), "--curves", str(tmp_path / "c.json"),
                                      "--probe", "11,10.5", "--methods", "relu,raster", "--bytes", "1500",
                                      "--zoom", "1", "--zoom", "10", *TINY, "-o", str(out)])
    assert result.exit_code == 0, result.output
    res = json.loads((out / "results.json").read_text())
    assert "zoom 1 only" in res["reference"] and set(res["methods"]) == {"relu", "raster"}
    for r in res["methods"].values():
        assert r["bytes"] <= 1500
        assert r["psnr"]["1"][0] > 10 and r["psnr"]["10"] == [None]
    assert not (out / "dfc.dfield").exists()


@pytest.mark.parametrize("args,error", [
    (["--scene", "nope"], InputError),
    (["--scene", "shapes", "--methods", "relu"], InputError),  # no dfc and no --bytes: no budget
])
def test_bad_requests_fail_before_writing(tmp_path, args, error):
    result = CliRunner().invoke(cli, ["bench", *args, *TINY, "-o", str(tmp_path / "b")])
    assert result.exit_code == 1 and isinstance(result.exception, error)
    assert not (tmp_path / "b" / "results.json").exists()


def test_input_and_scene_are_exclusive(tmp_path):
    result = CliRunner().invoke(cli, ["bench", "--scene", "shapes", "--curves", __file__, "-o", str(tmp_path)])
    assert result.exit_code == 2 and "INPUT" in result.output


def test_run_measured_sees_a_childs_peak_memory():
    import sys

    from dfc.bench.timing import run_measured

    peak = run_measured([sys.executable, "-c", "import time; b = bytearray(300 << 20); time.sleep(1.0)"],
                        interval=0.05)
    assert 300 <= peak.hwm < 600 and peak.tree >= peak.hwm and peak.seconds >= 1.0
    with pytest.raises(RuntimeError, match="exit status 3"):
        run_measured([sys.executable, "-c", "raise SystemExit(3)"])


def test_scale_memory_targets_compare_larger_runs_with_the_smallest():
    from dfc.bench.speed.scale import memory_targets

    def run(size, hwm, tree=0.0, workers=1):
        return {"size": size, "encode_hwm_mb": hwm, "encode_tree_mb": tree, "workers": workers}

    lines = memory_targets([run(16384, 1500.0), run(32768, 1800.0)])
    assert lines == ["memory target: encode at 16384² peaks at 1500 MB <= 2048 MB: met",
                     "memory target: encode at 32768² peaks at 1.20x the 16384² run <= 1.25x: met"]
    lines = memory_targets([run(16384, 900.0, 2100.0, workers=2), run(32768, 1000.0, 2700.0, workers=2)])
    assert lines[0].endswith("2100 MB <= 2048 MB: MISSED") and lines[1].endswith("1.29x the 16384² run <= 1.25x: MISSED")
    assert memory_targets([run(65536, 3000.0)]) == []  # nothing to compare with
