"""Per-budget tuning of the neural baselines: every candidate meets the budget, the sweep keeps the candidate it
measured best, the final run is time-matched, and the plateau figure."""

import math

import numpy as np
import pytest

from dfc.bench import tuning
from dfc.bench.scenes import shapes_scene
from dfc.bench.tuning import HASHGRID_SWEEP, candidates, plateau_db, tune_baseline
from dfc.metrics import QualityScale

pytestmark = pytest.mark.usefixtures("one_thread")

DOMAIN = (0.0, 0.0, 256.0, 256.0)
RGB = ["R", "G", "B"]
SMALL = {"steps": 12, "sweep_steps": 4, "batch_size": 256, "pixel_grid": 1, "scale": QualityScale(1.0),
         "loss": "mse"}


@pytest.fixture(scope="module")
def image():
    return shapes_scene().render(24, 24, spp=2)


def test_candidates_cover_the_knobs_the_issue_names():
    hashgrid = candidates("hashgrid", 3)
    for knob in ("levels", "features", "hidden", "dense_levels"):
        assert len({c.get(knob) for c in hashgrid}) >= 2, knob
    assert hashgrid[0] == HASHGRID_SWEEP[0]
    assert [c["features"] for c in candidates("relu", 3)] == [3, 1, 2, 6]
    assert [c["features"] for c in candidates("relu", 1)] == [1, 2]


@pytest.mark.parametrize("name,budget", [("hashgrid", 9000), ("relu", 6000)])
def test_the_sweep_keeps_the_measured_best(name, budget, image, monkeypatch):
    """Scores are made up (a known order) so the test checks the choice, not the training noise; every candidate
    is sized to the budget."""
    fake = iter([20.0, 31.0, 25.0, 30.5, 12.0, 29.0, 18.0, 30.9])
    monkeypatch.setattr(tuning, "_score", lambda *args: next(fake))
    tuned = tune_baseline(name, image, DOMAIN, RGB, budget, **SMALL)
    tried = [c for c in tuned.sweep if "psnr_1x" in c]
    assert len(tried) == len(candidates(name, 3))
    for c in tried:
        assert 0.97 * budget <= c["bytes"] <= budget, c
    best = max(tried, key=lambda c: c["psnr_1x"])
    assert best["psnr_1x"] == 31.0
    assert tuned.config["candidate"] == best["config"]
    assert tuned.model.describe() == best["architecture"] and tuned.model.stored_bytes() == best["bytes"]
    assert tuned.train["steps"] == SMALL["steps"] and tuned.train["matched_s"] is None


def test_candidates_that_do_not_fit_are_recorded(image):
    tuned = tune_baseline("hashgrid", image, DOMAIN, RGB, 1200, **SMALL)
    errors = [c for c in tuned.sweep if "error" in c]
    assert errors and all("budget" in c["error"] for c in errors)
    assert tuned.model.stored_bytes() <= 1200
    with pytest.raises(ValueError, match="no hashgrid configuration fits"):
        tune_baseline("hashgrid", image, DOMAIN, RGB, 100, **SMALL)


def test_the_final_run_lasts_at_least_dfcs_time(image):
    match = 2.0
    tuned = tune_baseline("relu", image, DOMAIN, RGB, 3000, sweep=False, match_seconds=match, **{**SMALL, "steps": 2})
    run = tuned.train
    assert len(tuned.sweep) == 1  # no sweep: the default candidate, timed
    assert run["matched_s"] == match and run["steps"] == max(2, math.ceil(match / run["step_s"]))
    assert run["steps"] > 2  # the time goes by the measured step time, not wall-clock asserts (load varies)


def test_plateau_is_the_rise_over_the_last_tenth():
    assert plateau_db([1.0] * 15) is None
    assert plateau_db([0.0] * 80 + [1.0] * 10 + [3.0] * 10) == pytest.approx(2.0)
    assert plateau_db(list(np.full(100, 7.0))) == 0.0
