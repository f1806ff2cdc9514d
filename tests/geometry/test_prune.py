"""``dfc.geometry.sources.prune``: curves that earn their bytes are kept, the others dropped, junctions intact."""

import numpy as np
import pytest
from scipy.special import erf

from dfc.errors import InputError
from dfc.geometry.curves import Curves, elevate
from dfc.geometry.sources.prune import curve_bytes, prune_curves
from dfc.geometry.triangulate import triangulate

W = H = 64


def _lines(segments, names):
    cp = np.stack([elevate(np.asarray(s, np.float64)[None], 1)[0] for s in segments])
    n = len(segments)
    return Curves((0.0, 0.0, float(W), float(H)), cp, [1] * n, np.arange(n), [[0.0, 1.0]] * n, names, [None] * n)


def _x():
    return (np.mgrid[0:H, 0:W][1] + 0.5).astype(np.float64)


def _rgb(v):
    return np.repeat(v[..., None], 3, axis=-1)


def test_a_soft_ramp_is_dropped_and_a_real_step_kept():
    x = _x()
    step = 0.2 + 0.6 * np.clip(x - 19.5, 0.0, 1.0)  # a box-filtered step at x = 20
    soft = 0.5 + 0.3 * 0.5 * (1 + erf((x - 44.0) / (3.0 * np.sqrt(2))))  # a soft shadow's edge at x = 44, σ 3 px
    pixels = _rgb(np.where(x < 32, step, soft))
    curves = _lines([[[20, 0], [20, 64]], [[44, 0], [44, 64]]], ["step", "soft"])
    pruned = prune_curves(pixels, curves)
    assert pruned.kept.tolist() == [True, False]
    assert pruned.curves.names == ["step"] and pruned.curves.n_curves == 1
    assert np.array_equal(pruned.curves.control_points, curves.control_points[:1])
    assert pruned.gain[0] > 100 * pruned.gain[1]
    assert "1 of 2 curves dropped" in pruned.summary()


def test_a_low_contrast_step_is_dropped_and_the_same_step_at_full_contrast_kept():
    x = _x()
    curves = _lines([[[20, 0], [20, 64]]], ["edge"])
    for contrast, kept in ((0.01, False), (0.5, True)):
        pixels = _rgb(0.2 + contrast * np.clip(x - 19.5, 0.0, 1.0))
        pixels[0, 0], pixels[-1, -1] = 0.0, 1.0  # the same value range in both images
        assert prune_curves(pixels, curves).kept.tolist() == [kept], contrast


def test_smaller_byte_targets_keep_fewer_curves_the_strongest_first():
    x = _x()
    contrasts = [0.1, 0.2, 0.4, 0.8]
    pixels = np.full((H, W), 0.1)
    for k, c in enumerate(contrasts):  # four steps of rising contrast at x = 8, 22, 36, 50
        pixels = pixels + c * np.clip(x - (8 + 14 * k - 0.5), 0.0, 1.0) * ((x < 8 + 14 * k + 7))
    pixels = _rgb(pixels)
    curves = _lines([[[8 + 14 * k, 0], [8 + 14 * k, 64]] for k in range(4)], [f"c{c}" for c in contrasts])
    cost = curve_bytes(curves, 6.0)
    counts = []
    for target in (None, 20000, int(3.2 * cost[0]), int(2.2 * cost[0])):
        pruned = prune_curves(pixels, curves, target_bytes=target)
        counts.append(int(pruned.kept.sum()))
        if target is not None and pruned.kept.any():
            assert pruned.cost[pruned.kept].sum() <= 0.5 * target
        assert pruned.kept[np.argmax(contrasts)] or not pruned.kept.any()  # the strongest goes last
    assert counts[0] == 4 and counts == sorted(counts, reverse=True) and counts[-1] < counts[1]


def test_junctions_stay_joined_after_pruning():
    """A T (a stem welded onto a bar) and a corner shared by two curves: after a faint curve is dropped, the kept
    curves' ends are where they were, the T's stem still ends on the bar, and the set triangulates."""
    y, x = np.mgrid[0:H, 0:W] + 0.5
    pixels = np.where(y < 32, 0.1, 0.9) + np.where((y > 32) & (x > 32), 0.3, 0.0)  # bar at y = 32, stem at x = 32
    pixels = pixels + 0.004 * np.clip(x - 11.5, 0.0, 1.0) * (y < 32)  # a faint step at x = 12 above the bar
    pixels = _rgb(pixels)
    curves = _lines([[[0, 32], [64, 32]], [[32, 32], [32, 64]], [[12, 0], [12, 32]]], ["bar", "stem", "faint"])
    pruned = prune_curves(pixels, curves)
    assert pruned.kept.tolist() == [True, True, False]
    kept = pruned.curves
    assert np.array_equal(kept.control_points, curves.control_points[:2])
    assert kept.curve.tolist() == [0, 1] and kept.names == ["bar", "stem"]
    stem_end = kept.control_points[1, 0]
    assert stem_end[1] == kept.control_points[0, 0, 1]  # still on the bar
    mesh = triangulate(kept, max_triangles=400)
    assert np.isclose(np.linalg.norm(mesh.vertices - stem_end, axis=1).min(), 0.0, atol=1e-9)


@pytest.mark.parametrize("bad", ["nan", "target", "triangles"])
def test_bad_input_raises(bad):
    pixels = _rgb(np.zeros((H, W)))
    curves = _lines([[[20, 0], [20, 64]]], ["edge"])
    if bad == "nan":
        pixels[3, 3] = np.nan
        with pytest.raises(InputError, match="NaN"):
            prune_curves(pixels, curves)
    else:
        with pytest.raises(ValueError, match="at least 1"):
            prune_curves(pixels, curves, **({"target_bytes": 0} if bad == "target" else {"n_triangles": 0}))
