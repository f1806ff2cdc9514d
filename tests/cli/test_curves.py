"""``dfc curves IMAGE -o CURVES.json``: the JSON it writes, the preview, the summary, and every bad input giving
one error line and no output file."""

import json
import re
from dataclasses import replace

import numpy as np
import pytest
from PIL import Image

from dfc.geometry.sources import read_json
from dfc.io.image import write_exr, write_png

from .test_cli import assert_one_line_error, run

pytest.importorskip("skimage")


@pytest.fixture
def disc_exr(tmp_path):
    y, x = (np.mgrid[0:40 * 8, 0:48 * 8] + 0.5) / 8
    inside = ((x - 24.2) ** 2 + (y - 19.7) ** 2 < 11.5 ** 2).reshape(40, 8, 48, 8).mean(axis=(1, 3))
    pixels = (0.05 + 40.0 * inside)[..., None] * np.array([1.0, 0.6, 0.3])
    path = tmp_path / "disc.exr"
    write_exr(path, pixels.astype(np.float32), ["R", "G", "B"], half=False)
    return path


def test_curves_of_an_exr(disc_exr, tmp_path, capsys):
    out, preview = tmp_path / "disc.json", tmp_path / "disc.png"
    code, stdout, err = run(["curves", disc_exr, "-o", out, "--preview", preview, "--json", "-"], capsys)
    assert code == 0, err
    curves = read_json(out)
    assert curves.domain == (0.0, 0.0, 48.0, 40.0) and curves.n_curves == 1
    radius = np.linalg.norm(curves.control_points[:, [0, 3]].reshape(-1, 2) - (24.2, 19.7), axis=1)
    assert np.abs(radius - 11.5).max() < 0.05
    summary = json.loads(stdout)
    assert summary["curves"] == 1 and summary["pieces"] == len(curves) and summary["width"] == 48
    assert summary["settings"]["tolerance"] == 0.05
    with Image.open(preview) as im:
        assert im.format == "PNG" and im.size == (1024, round(1024 * 40 / 48))


def test_constant_png_writes_the_empty_set(tmp_path, capsys):
    path, out = tmp_path / "flat.png", tmp_path / "flat.json"
    write_png(path, np.full((12, 10, 3), 0.3, np.float32))
    code, _, err = run(["curves", path, "-o", out], capsys)
    assert code == 0 and "empty curve set" in err
    curves = read_json(out)
    assert len(curves) == 0 and curves.domain == (0.0, 0.0, 10.0, 12.0)


@pytest.mark.parametrize("case", ["one_pixel", "nan", "not_an_image", "bad_output", "low_above_high"])
def test_bad_input_is_one_error_line_and_no_file(case, tmp_path, capsys):
    out = tmp_path / "out.json"
    args = []
    if case == "one_pixel":
        path, match = tmp_path / "one.exr", "1 × 1"
        write_exr(path, np.ones((1, 1, 3), np.float32), ["R", "G", "B"])
    elif case == "nan":
        pixels = np.ones((8, 8, 3), np.float32)
        pixels[2, 5, 1] = np.nan
        path, match = tmp_path / "nan.exr", "NaN"
        write_exr(path, pixels, ["R", "G", "B"], half=False)
    elif case == "not_an_image":
        path, match = tmp_path / "notes.txt", "not an input"
        path.write_text("hello")
    else:
        path = tmp_path / "ok.png"
        write_png(path, np.full((8, 8, 1), 0.5, np.float32))
        if case == "bad_output":
            out, match = tmp_path / "out.svg", ".json"
        else:
            args, match = ["--low", "0.5", "--high", "0.2"], "--low"
    code, _, err = run(["curves", path, "-o", out, *args], capsys)
    assert_one_line_error(code, err, match)
    assert not out.exists()


def test_encode_with_auto_curves_records_the_extraction(disc_exr, tmp_path, capsys):
    """``dfc encode IMAGE --curves auto``: the curves ``dfc curves`` finds with its defaults, and the file says so."""
    from dfc.cli.stats import file_stats
    from dfc.geometry.sources.raster import image_curves_filtered
    from dfc.io.image import read_image

    out = tmp_path / "disc.dfield"
    code, stdout, err = run(["encode", disc_exr, "--curves", "auto", "-o", out, "--steps", "4", "--batch-size", "256",
                             "--no-raster-mode", "--json", tmp_path / "s.json"], capsys)  # the field's file
    assert code == 0, err
    expected, used, detection = image_curves_filtered(read_image(disc_exr).pixels)  # the encoder's filter detection
    record = file_stats(out)["encoder"]
    assert record["source"] == "auto" and record["curves"]["pixel_filter"] == str(used)
    assert "settings" not in record["curves"]  # the extractor's defaults: implied by the software version
    assert record["curves"]["curves"] == expected.n_curves == 1 and record["curves"]["pieces"] == len(expected)
    assert "found in the image" in stdout and "1 curves" in stdout
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["curves"]["pieces"] == len(expected)
    # the fit's filter is the one detected along every curve found, with that detection's evidence
    assert summary["pixel_filter"] == str(used) and summary["pixel_evidence"] == detection.evidence()
    code, table, _ = run(["stats", out], capsys)
    assert code == 0 and "1 curves" in table and "from the image (--curves auto)" in table
    assert f"pixel filter {used}" in table and "tolerance" not in table


def test_encode_fits_the_filter_detected_again_along_the_refined_curves(disc_exr, tmp_path, capsys, monkeypatch):
    """When the refined curves show another filter (``refine_detected``; measured on analytic rasters in the
    refinement tests), the encode fits and records that one and says why."""
    from dfc.cli.stats import file_stats
    from dfc.geometry.sources import auto
    from dfc.geometry.sources.raster import image_curves_filtered
    from dfc.io.image import read_image

    first = str(image_curves_filtered(read_image(disc_exr).pixels)[1])
    other = "box:3" if first != "box:3" else "box:5"
    real = auto.refine_detected
    monkeypatch.setattr(auto, "refine_detected", lambda *a: replace(real(*a), pixel_filter=other))
    out = tmp_path / "disc.dfield"
    code, _, err = run(["encode", disc_exr, "--curves", "auto", "-o", out, "--steps", "4", "--batch-size", "256",
                        "--no-raster-mode", "--json", tmp_path / "s.json"], capsys)
    assert code == 0, err
    record = file_stats(out)["encoder"]
    assert record["pixel_filter"] == record["curves"]["pixel_filter"] == other
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["pixel_filter"] == other and summary["pixel_evidence"].endswith(f"; {other} along the refined curves")


def test_encode_without_curves_still_asks(disc_exr, tmp_path, capsys):
    code, _, err = run(["encode", disc_exr, "-o", tmp_path / "x.dfield"], capsys)
    assert code == 2 and "Missing option '--curves'" in err and "--curves auto" in err
    assert not (tmp_path / "x.dfield").exists()


def test_auto_curves_apply_to_images_only(tmp_path, capsys):
    xy = np.random.default_rng(0).random((200, 2)) * 8
    np.savez(tmp_path / "s.npz", xy=xy, values=xy[:, :1], domain=[0, 0, 8, 8])
    code, _, err = run(["encode", tmp_path / "s.npz", "--curves", "auto", "-o", tmp_path / "x.dfield"], capsys)
    assert code == 2 and "--curves auto finds curves in an image" in err
    code, _, err = run(["encode", tmp_path / "s.npz", "--curves", tmp_path / "gone.json", "-o", tmp_path / "x.dfield"],
                       capsys)
    assert code == 2 and "does not exist" in err


def test_auto_curves_need_the_image_in_memory(disc_exr, tmp_path, capsys):
    code, _, err = run(["encode", disc_exr, "--curves", "auto", "--epoch-pixels", "1000", "-o", tmp_path / "x.dfield"],
                       capsys)
    assert code == 2 and "--curves auto reads the whole image" in err and "dfc curves" in err
    assert not (tmp_path / "x.dfield").exists()


def test_auto_curves_without_the_extra_name_it(disc_exr, tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "dfc.geometry.sources.raster", None)  # as if scikit-image were missing
    code, _, err = run(["encode", disc_exr, "--curves", "auto", "-o", tmp_path / "x.dfield"], capsys)
    assert_one_line_error(code, err, "pip install 'dfc[curves]'")
    assert not (tmp_path / "x.dfield").exists()


def test_refine_writes_the_refined_curves_and_a_before_after_preview(disc_exr, tmp_path, capsys):
    """``dfc curves IMAGE --refine``: the disc's curves end closer to its circle than the extractor put them."""
    from dfc.geometry import bezier

    def off_circle(curves):
        points = bezier.flatten(curves.control_points, 32).reshape(-1, 2)
        return float(np.abs(np.linalg.norm(points - (24.2, 19.7), axis=1) - 11.5).mean())

    plain, refined, preview = tmp_path / "plain.json", tmp_path / "refined.json", tmp_path / "p.png"
    assert run(["curves", disc_exr, "-o", plain, "-q"], capsys)[0] == 0
    code, stdout, err = run(["curves", disc_exr, "-o", refined, "--refine", "--preview", preview, "--json", "-"],
                            capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["refined"]["pixels"] > 50 and "warning" not in summary["refined"]
    assert summary["refined"]["misfit_after"] < summary["refined"]["misfit_before"]
    assert "mixed pixels" in err  # the human summary goes to standard error beside --json -
    before, after = read_json(plain), read_json(refined)
    assert len(after) == len(before) and off_circle(after) < min(0.01, off_circle(before))
    with Image.open(preview) as im:
        assert im.format == "PNG"
        grey = (np.asarray(im.convert("RGB")) == (128, 128, 128)).all(axis=2)
        assert grey.sum() > 100  # the curves before refinement, drawn over the refined ones


def test_encode_with_auto_curves_refines_them_by_default(disc_exr, tmp_path, capsys):
    from dfc.cli.stats import file_stats

    out = tmp_path / "disc.dfield"
    args = ["encode", disc_exr, "--curves", "auto", "-o", out, "--steps", "2", "--batch-size", "256",
            "--no-raster-mode"]  # two steps: the raster mode's file would win, and it stores no curves
    code, stdout, err = run(args, capsys)
    assert code == 0, err
    assert "curves refined against the pixels" in stdout
    assert file_stats(out)["encoder"]["curves"]["refined"]["pixels"] > 50
    assert re.search(r"^time: curves \d+\.\d s, detect", stdout, re.M)  # finding and refining them is timed too
    code, stdout, err = run([*args, "--no-refine-curves"], capsys)
    assert code == 0 and "refined" not in stdout and "refined" not in file_stats(out)["encoder"]["curves"]


def test_encode_warns_once_when_refinement_leaves_crossing_curves(disc_exr, tmp_path, capsys):
    """A curve crossing the disc's edge where they share no point: the encode refines the rest, says so in one warning
    line (after the curves' progress, not inside it) and writes the file."""
    found, crossing, out = tmp_path / "found.json", tmp_path / "crossing.json", tmp_path / "disc.dfield"
    assert run(["curves", disc_exr, "-o", found, "-q"], capsys)[0] == 0
    doc = json.loads(found.read_text())
    doc["curves"].append({"name": "bar", "pieces": [{"type": "line", "points": [[4.0, 19.0], [20.0, 21.0]]}]})
    crossing.write_text(json.dumps(doc))
    code, stdout, err = run(["encode", disc_exr, "--curves", crossing, "--refine-curves", "-o", out, "--steps", "2",
                             "--batch-size", "256"], capsys)
    assert code == 0 and out.exists(), err
    warnings = [line for line in err.splitlines() if line.startswith("dfc: warning:")]
    assert len(warnings) == 1 and "'bar'" in warnings[0] and "left those pieces as given" in warnings[0]
    assert "crossing pieces left as given" in stdout


@pytest.mark.parametrize("kind", ["samples", "fem", "frames", "outside"])
def test_refine_curves_bad_input_is_one_error_line(kind, disc_exr, tmp_path, capsys):
    """--refine-curves on a sample set, FEM or frames input, or with curves reaching outside the image: one line."""
    from dfc.geometry.curves import Curves
    from dfc.geometry.sources import write_json

    curves = tmp_path / "c.json"
    write_json(Curves((0.0, 0.0, 48.0, 40.0), np.array([[[5.0, 5.0], [20.0, 10.0], [35.0, 15.0], [50.0, 20.0]]]),
                      [1], [0], [[0.0, 1.0]], ["stroke"], [None]), curves)
    inputs = [disc_exr]
    if kind == "samples":
        xy = np.random.default_rng(0).random((200, 2)) * 8
        np.savez(tmp_path / "s.npz", xy=xy, values=xy[:, :1], domain=[0, 0, 8, 8])
        inputs, match = [tmp_path / "s.npz"], "not samples input"
    elif kind == "fem":
        (tmp_path / "m.vtu").write_text("<VTKFile/>")
        inputs, match = [tmp_path / "m.vtu"], "not fem input"
    elif kind == "frames":
        inputs, match = [disc_exr, disc_exr, "--times", "0,1"], "not frames input"
    else:
        match = "'stroke' reaches outside the image"
    out = tmp_path / "x.dfield"
    code, _, err = run(["encode", *inputs, "--curves", curves, "--refine-curves", "-o", out, "--steps", "2"], capsys)
    assert_one_line_error(code, err, match)
    assert not out.exists()


def test_prune_curves_keeps_the_disc_and_drops_it_under_a_tiny_target(disc_exr, tmp_path, capsys):
    """``dfc curves IMAGE --prune-curves``: the disc's sharp edge earns its bytes; for a 100-byte file it does not."""
    out = tmp_path / "c.json"
    code, stdout, err = run(["curves", disc_exr, "-o", out, "--prune-curves", "--json", "-"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["pruned"]["dropped"] == 0 and summary["curves"] == 1 and "0 of 1 curves dropped" in err
    code, stdout, err = run(["curves", disc_exr, "-o", out, "--prune-curves", "--target-bytes", "100", "--json", "-"],
                            capsys)
    assert code == 0, err
    assert json.loads(stdout)["pruned"]["dropped"] == 1 and len(read_json(out)) == 0


def test_encode_with_auto_curves_prunes_them_by_default(disc_exr, tmp_path, capsys):
    from dfc.cli.stats import file_stats

    out = tmp_path / "disc.dfield"
    summary = tmp_path / "summary.json"
    args = ["encode", disc_exr, "--curves", "auto", "-o", out, "--steps", "2", "--batch-size", "256",
            "--no-refine-curves", "--no-raster-mode", "--json", summary]
    code, stdout, err = run(args, capsys)
    assert code == 0, err
    assert "curves pruned: 0 of 1 curves dropped" in stdout
    assert file_stats(out)["encoder"]["curves"]["pruned"]["dropped"] == 0
    assert json.loads(summary.read_text())["pruned_curves"]["curves"] == 1
    code, stdout, err = run([*args, "--no-prune-curves"], capsys)
    assert code == 0 and "pruned" not in stdout and "pruned" not in file_stats(out)["encoder"]["curves"]
    assert json.loads(summary.read_text())["pruned_curves"] is None


def test_encode_prunes_a_curves_file_only_when_the_target_is_too_small_for_it(tmp_path, capsys):
    """Eleven steps and their lines, whose smallest file is over 2000 bytes: under a 2000-byte target the curves
    file is pruned by default (the summary and ``--json`` say so) and the file fits; ``--no-prune-curves`` keeps every
    curve and the target is refused; a target below any file is refused saying what was left out; without a target,
    or under one that the curves fit, nothing is pruned."""
    from dfc.cli.stats import file_stats
    from dfc.geometry.curves import Curves, elevate
    from dfc.geometry.sources import write_json

    h, w, xs = 48, 64, [5 + 5 * k for k in range(11)]
    x = np.mgrid[0:h, 0:w][1] + 0.5
    pixels = 0.1 + sum(0.07 * np.clip(x - (c - 0.5), 0.0, 1.0) for c in xs)
    write_exr(tmp_path / "s.exr", np.repeat(pixels[..., None], 3, axis=-1).astype(np.float32), ["R", "G", "B"],
              half=False)
    cp = np.stack([elevate(np.array([[c, 0.0], [c, float(h)]])[None], 1)[0] for c in xs])
    write_json(Curves((0.0, 0.0, float(w), float(h)), cp, [1] * len(xs), np.arange(len(xs)), [[0.0, 1.0]] * len(xs),
                      [f"s{k}" for k in range(len(xs))], [None] * len(xs)), tmp_path / "s.json")
    out = tmp_path / "s.dfield"
    args = ["encode", tmp_path / "s.exr", "--curves", tmp_path / "s.json", "-o", out, "--steps", "2",
            "--batch-size", "256", "--residual-bytes", "0"]
    code, stdout, err = run([*args, "--target-bytes", "2000", "--json", tmp_path / "s.json.out"], capsys)
    assert code == 0, err
    dropped = int(re.search(r"curves pruned: (\d+) of 11 curves left out", stdout).group(1))
    assert 0 < dropped < 11 and "too small for all of them" in stdout
    assert json.loads((tmp_path / "s.json.out").read_text())["pruned_curves"]["dropped"] == dropped
    assert out.stat().st_size <= 2000
    kept_vertices = file_stats(out)["mesh"]["discontinuous_vertices"]
    out.unlink()
    code, _, err = run([*args, "--target-bytes", "2000", "--no-prune-curves"], capsys)
    assert_one_line_error(code, err, "too small for these curves")
    assert not out.exists()
    code, _, err = run([*args, "--target-bytes", "500"], capsys)  # below the smallest file, whatever is left out
    assert_one_line_error(code, err, "of 11 curves left out")
    assert not out.exists()
    for more in ([], ["--target-bytes", "3000"]):
        code, stdout, err = run([*args, *more], capsys)
        assert code == 0 and "pruned" not in stdout, err
        assert file_stats(out)["mesh"]["discontinuous_vertices"] > kept_vertices


@pytest.mark.parametrize("case", ["zero_target", "target_alone", "samples"])
def test_prune_curves_bad_options_are_one_error_line(case, disc_exr, tmp_path, capsys):
    out = tmp_path / "x.json"
    if case == "zero_target":
        argv, match = ["curves", disc_exr, "-o", out, "--prune-curves", "--target-bytes", "0"], "--target-bytes"
    elif case == "target_alone":
        argv, match = ["curves", disc_exr, "-o", out, "--target-bytes", "500"], "give it with --prune-curves"
    else:
        from dfc.geometry.curves import Curves
        from dfc.geometry.sources import write_json

        write_json(Curves((0.0, 0.0, 8.0, 8.0), np.array([[[1.0, 1.0], [3.0, 3.0], [5.0, 5.0], [7.0, 7.0]]]), [1], [0],
                          [[0.0, 1.0]], ["stroke"], [None]), tmp_path / "c.json")
        xy = np.random.default_rng(0).random((200, 2)) * 8
        np.savez(tmp_path / "s.npz", xy=xy, values=xy[:, :1], domain=[0, 0, 8, 8])
        out = tmp_path / "x.dfield"
        argv, match = (["encode", tmp_path / "s.npz", "--curves", tmp_path / "c.json", "--prune-curves", "-o", out],
                       "not samples input")
    code, _, err = run(argv, capsys)
    assert_one_line_error(code, err, match)
    assert not out.exists()
