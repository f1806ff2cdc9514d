"""A 64 × 64 analytic scene for the training tests: a line, a quadratic ending on it, an S-shaped cubic and an open
stroke, with its exact value, curves and box-filtered raster."""

from math import comb

import numpy as np

from dfc.bench.scenes import subtended
from dfc.geometry.curves import Curves, elevate

LINE = [(44.0, 0.0), (36.0, 64.0)]  # x = 44 - y / 8, splits left / right
QUAD = [(0.0, 40.0), (19.5, 20.0), (39.0, 40.0)]  # ends on the line; control x equally spaced: a graph
CUBIC = [(48.0, 0.0), (48 + 16 / 3, 30.0), (48 + 32 / 3, 10.0), (64.0, 40.0)]  # top border → right border
STROKE = [(8.0, 12.0), (24.0, 16.0)]  # open, both tips inside: the jump fades out around them


def graph(ctrl, x):
    """y on a Bézier whose control points' x are equally spaced (x linear in t), at abscissae x."""
    c = np.asarray(ctrl)
    t = np.clip((x - c[0, 0]) / (c[-1, 0] - c[0, 0]), 0, 1)
    n = len(c) - 1
    return sum(comb(n, k) * (1 - t) ** (n - k) * t**k * c[k, 1] for k in range(n + 1))


def scene_value(xy):
    x, y = xy[:, 0], xy[:, 1]
    u, v = x / 64, y / 64
    right = x > 44 - y / 8
    wedge = right & (x >= 48) & (y < graph(CUBIC, x))
    lower_left = ~right & (x <= 39) & (y > graph(QUAD, x))
    out = np.stack([0.2 + 0.3 * u, 0.5 - 0.2 * v, 0.3 + 0.2 * u * v], 1)
    out += 0.3 * subtended(xy, np.asarray(STROKE))[:, None] * np.array([1.0, -0.5, 0.5])
    out[lower_left] = np.stack([0.8 - 0.2 * v, 0.3 + 0.3 * u * u, 0.6 + 0 * u], 1)[lower_left]
    out[right] = np.stack([0.1 + 0.4 * v, 0.8 - 0.3 * u, 0.2 + 0.2 * v * v], 1)[right]
    out[wedge] = np.stack([0.9 + 0 * u, 0.6 + 0.2 * v, 0.1 + 0.3 * u], 1)[wedge]
    return out


def scene_curves() -> Curves:
    pieces = [(1, LINE), (2, QUAD), (3, CUBIC), (1, STROKE)]
    cp = np.stack([elevate(np.asarray([p]), d)[0] for d, p in pieces])
    return Curves((0.0, 0.0, 64.0, 64.0), cp, [d for d, _ in pieces], [0, 1, 2, 3], [(0, 1)] * 4,
                  names=["line", "quad", "cubic", "stroke"], sides=[None] * 4)


def scene_image(spp=4):
    """Box-filtered 64 × 64 raster (spp × spp samples per pixel), (64, 64, 3) float32."""
    s = (np.arange(64 * spp) + 0.5) / spp
    X, Y = np.meshgrid(s, s)
    vals = scene_value(np.stack([X.ravel(), Y.ravel()], 1))
    return vals.reshape(64, spp, 64, spp, 3).mean(axis=(1, 3)).astype(np.float32)
