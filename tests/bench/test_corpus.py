"""``dfc bench --corpus``: the BD-rate, the case selection, a tiny end-to-end run and its bad options."""

import json

import numpy as np
import pytest

from dfc.bench import codecs
from dfc.bench.corpus import CASES, CORPUS_BPP, bd_rate, select_cases
from dfc.bench.results import validate
from dfc.errors import InputError

from ..cli.test_cli import assert_one_line_error, run

pytestmark = pytest.mark.usefixtures("one_thread")

RATES = np.array([1000.0, 2000.0, 4000.0, 8000.0])
PSNRS = np.array([30.0, 34.0, 37.0, 39.5])


@pytest.fixture(autouse=True)
def fast_avif(monkeypatch):
    monkeypatch.setattr(codecs, "AVIF_SPEED", 8)


def test_bd_rate_of_equal_curves_is_zero():
    assert bd_rate(RATES, PSNRS, RATES, PSNRS) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("factor,expected", [(0.5, -50.0), (2.0, 100.0), (0.9, -10.0)])
def test_bd_rate_of_a_curve_at_a_constant_rate_ratio(factor, expected):
    assert bd_rate(factor * RATES, PSNRS, RATES, PSNRS) == pytest.approx(expected, rel=1e-9)


def test_bd_rate_integrates_over_the_overlapping_psnr_range_only():
    # log rate linear in PSNR (PCHIP then exact): the test curve covers 33..39 dB at half the rate, the anchor
    # 30..39 dB; only the common 33..39 counts: -50 %, while over 30..33 the anchor's rate alone would not matter
    p, r = np.array([30.0, 33.0, 36.0, 39.0]), 1000.0 * 2.0 ** np.arange(4)
    assert bd_rate(0.5 * r[1:], p[1:], r, p) == pytest.approx(-50.0, rel=1e-9)
    assert bd_rate(r[1:], p[1:], r, p) == pytest.approx(0.0, abs=1e-9)
    # two straight lines in (PSNR, log rate) with a rate ratio growing linearly from 1 to 4 across 30..40 dB:
    # the mean log ratio is log 2, so +100 %
    p = np.array([30.0, 40.0])
    assert bd_rate(np.array([1000.0, 4000.0 * 4]), p, np.array([1000.0, 4000.0]), p) == pytest.approx(100.0)


def test_bd_rate_without_overlap_or_points_is_none():
    assert bd_rate(RATES, PSNRS + 20, RATES, PSNRS) is None
    assert bd_rate(RATES[:1], PSNRS[:1], RATES, PSNRS) is None
    assert bd_rate([1000.0, 2000.0], [30.0, float("inf")], RATES, PSNRS) is None  # a lossless point is left out


def test_cases_cover_the_issues_corpus():
    summaries = " ".join(c.summary for c in CASES.values())
    assert sum(c.auto and "mitsuba" in n for n, c in CASES.items()) >= 2
    assert all(w in summaries for w in ("box filter", "Gaussian filter", "HDR", "point-sampled", "noise"))
    assert all(w in summaries for w in ("glass", "gold", "textured"))  # issue 31's renders without their scene
    assert all(not c.zoom_truth for n, c in CASES.items() if n.startswith(("exr-", "dc-")))
    assert CORPUS_BPP == (0.25, 0.5, 1.0, 2.0)


def test_select_cases_skips_what_needs_the_absent_data(tmp_path):
    cases, skipped = select_cases(None, tmp_path / "absent")
    assert len(cases) + len(skipped) == len(CASES)
    assert set(skipped) == {n for n, c in CASES.items() if c.needs == "shared"}
    assert all("not found" in why for why in skipped.values())
    cases, skipped = select_cases(["point-shapes", "dc-sunset", "point-shapes"], tmp_path / "absent")
    assert [c.name for c in cases] == ["point-shapes"] and list(skipped) == ["dc-sunset"]
    cases, skipped = select_cases(["dc-sunset"], tmp_path)  # present
    assert [c.name for c in cases] == ["dc-sunset"] and not skipped
    with pytest.raises(InputError, match="nope"):
        select_cases(["point-shapes", "nope"], tmp_path)


def test_default_encode_leaves_steps_and_batch_to_the_encoder(monkeypatch):
    import dfc.codec
    from dfc.bench.compare import BenchSettings, _fit_dfc
    from dfc.bench.scenes import shapes_scene

    seen = {}

    def encode_image(image, curves, settings, **kw):
        seen["settings"] = settings
        raise RuntimeError("stop")

    monkeypatch.setattr(dfc.codec, "encode_image", encode_image)
    scene = shapes_scene()
    for default, steps, batch in ((True, None, None), (False, 7, 512)):
        with pytest.raises(RuntimeError, match="stop"):
            _fit_dfc(scene.render(16, 16), scene.curves, scene.channels,
                     BenchSettings(steps=7, batch_size=512, default_encode=default), lambda m: None)
        assert (seen["settings"].steps, seen["settings"].batch_size) == (steps, batch)


def test_noisy_diffusion_case_measures_against_the_clean_solve_too(shared_data):
    from dfc.bench.compare import BenchSettings

    clean = CASES["dc-sunset"].build(32, BenchSettings(), lambda m: None, shared_data)
    noisy = CASES["dc-sunset-noisy"].build(32, BenchSettings(), lambda m: None, shared_data)
    assert clean["pixels"].shape == noisy["pixels"].shape == (32, 32, 3)
    np.testing.assert_array_equal(noisy["other_truths"]["clean"], clean["pixels"])
    codes = noisy["pixels"] * 255
    assert np.allclose(codes, np.round(codes), atol=1e-4)  # 8-bit
    assert 0.01 < float(np.std(noisy["pixels"] - clean["pixels"])) < 0.03


def test_tiny_corpus_run_prints_bd_rates_and_writes_a_result_file(tmp_path, capsys):
    path = tmp_path / "corpus.json"
    code, out, err = run(["bench", "--corpus", "--corpus-cases", "point-shapes,dc-sunset", "--corpus-data",
                          tmp_path / "absent", "--size", "48", "--corpus-bpp", "12,24", "--steps", "30",
                          "--batch-size", "1024", "--render", "16", "--spp", "1", "--zoom", "1", "--zoom", "10",
                          "--methods", "dfc,jpegxl,jpeg2k", "--corpus-own-rate", "--json", path, "-o", tmp_path / "out"],
                         capsys)
    assert code == 0, err
    assert "skipping corpus case dc-sunset" in err and "BD-rate" in out and "point-shapes" in out
    assert "The default encode at its own size" in out
    doc = json.loads(path.read_text())
    assert validate(doc) == [] and doc["page"] == "corpus" and doc["skipped"] == {"dc-sunset": doc["skipped"]["dc-sunset"]}
    case = doc["cases"]["point-shapes"]
    assert case["budgets"] == [round(b * 48 * 48 / 8) for b in (12, 24)]
    assert set(case["curves"]) == {"dfc", "jpegxl", "jpeg2k"} and case["settings"]["pixel_grid"] == 1
    for m in ("jpegxl", "jpeg2k"):
        def curve(name):
            pts = [p for p in case["curves"][name] if "bytes" in p]
            return [p["bytes"] for p in pts], [p["image_psnr"]["all"] for p in pts]

        expected = bd_rate(*curve("dfc"), *curve(m))
        assert case["bd_rate"][m] == (None if expected is None else pytest.approx(expected))
    assert all(p["bytes"] <= p["budget"] for pts in case["curves"].values() for p in pts if "bytes" in p)
    assert "10" in case["zoom_margins"] and case["checks"]["zoom_min"] == case["zoom_margins"]["10"]["min"]
    assert {s["panel"] for s in doc["series"]} == {"point-shapes"}
    own = case["own_rate"]  # dfc without a target (its own 30 steps), each codec at most that file's size
    assert own["bpp"] == pytest.approx(8 * own["bytes"] / (48 * 48), abs=1e-4) and set(own["codecs"]) == {"jpegxl", "jpeg2k"}
    assert all(c["bytes"] <= own["bytes"] for c in own["codecs"].values())
    assert case["checks"]["own_rate_margin"] == pytest.approx(own["psnr"] - max(c["psnr"] for c in own["codecs"].values()))
    assert json.loads((tmp_path / "out" / "results.json").read_text())["cases"].keys() == {"point-shapes"}
    sr = case["super_resolution"]  # point-shapes has a reference: 2x of the 48² input, the input itself upsampled
    assert (sr["factor"], sr["width"], sr["height"]) == (2, 96, 96) and set(sr["input"]) == {"bicubic", "lanczos"}
    margins = case["checks"]["super_margins"]
    for i, g in enumerate(margins):
        dfc, codecs = case["curves"]["dfc"][i], [case["curves"][m][i]["super_psnr"] for m in ("jpegxl", "jpeg2k")]
        assert g["vs_input"] == pytest.approx(dfc["super_psnr"] - max(sr["input"].values()))
        assert g["vs_codecs"] == pytest.approx(dfc["super_psnr"] - max(codecs))
    assert case["checks"]["super_above"] == all(g["vs_input"] >= 0 and g["vs_codecs"] >= 0 for g in margins)
    assert "2× super-resolution" in out and "the input, " in out


@pytest.mark.parametrize("args,match", [
    (["--corpus-cases", "point-shapes,nope"], "unknown corpus case(s) nope"),
    (["--corpus-bpp", "1,x"], "bits per pixel"),
    (["--corpus-cases", "dc-sunset", "--corpus-data", "{absent}"], "no corpus case can run here"),
    (["--scene", "shapes"], "--corpus takes none of"),
])
def test_bad_corpus_options_are_one_error_line(tmp_path, capsys, args, match):
    args = [a.format(absent=tmp_path / "absent") for a in args]
    code, out, err = run(["bench", "--corpus", *args, "--json", tmp_path / "c.json"], capsys)
    assert_one_line_error(code, err, match)
    assert not (tmp_path / "c.json").exists()


@pytest.mark.parametrize("option", [["--corpus-cases", "point-shapes"], ["--no-prune-curves"], ["--no-refine-curves"],
                                    ["--corpus-own-rate"]])
def test_corpus_options_need_corpus(tmp_path, capsys, option):
    code, _, err = run(["bench", "--scene", "shapes", *option, "-o", tmp_path], capsys)
    assert_one_line_error(code, err, "apply to --corpus")


def test_cases_in_worker_processes_give_what_one_process_gives(tmp_path):
    from dfc.bench.compare import BenchSettings
    from dfc.bench.corpus import run_corpus

    cases, _ = select_cases(["point-shapes", "mitsuba-shapes-hdr"], tmp_path)
    cases = cases[:1] * 2  # the same case twice: no Mitsuba render needed
    settings = BenchSettings(methods=("jpegxl",), zooms=(1,), render=16, spp=1, keep_going=True)
    one = run_corpus(cases[:1], settings, size=32, bpp=(8.0,), progress=None)
    two = run_corpus(cases, settings, size=32, bpp=(8.0,), progress=None, jobs=2)
    assert list(two) == ["point-shapes"]
    assert two["point-shapes"]["curves"] == one["point-shapes"]["curves"]
