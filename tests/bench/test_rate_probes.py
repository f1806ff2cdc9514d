"""Probe points of ``dfc benchmark rate`` (dfc.bench.speed.rate.rate_probes)."""

import numpy as np
from scipy.spatial import cKDTree

from dfc.bench.scenes import get_scene
from dfc.bench.speed.rate import rate_probes
from dfc.geometry.bezier import flatten


def test_probes_sit_on_curves_at_open_ends_and_far_from_every_curve():
    curves = get_scene("strokes").curves
    edge, tips, smooth = rate_probes(curves, n_smooth=3)
    line = cKDTree(flatten(curves.control_points, 256).reshape(-1, 2))
    assert len(edge) == len(curves.names) and line.query(edge)[0].max() < 0.1
    ends = np.concatenate([curves.control_points[:, 0], curves.control_points[:, 3]])
    x0, y0, x1, y1 = curves.domain
    assert len(tips) >= 1 and cKDTree(ends).query(tips)[0].max() < 1e-9
    assert np.all((tips > [x0, y0]) & (tips < [x1, y1]))
    assert len(smooth) == 3 and line.query(smooth)[0].min() > 20  # grid points far from the strokes
    assert min(np.hypot(*(smooth[i] - smooth[j])) for i in range(3) for j in range(i)) > 20
