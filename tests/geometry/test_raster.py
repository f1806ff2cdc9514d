"""The raster curve extractor on images whose edges are known exactly: box-filtered (each pixel the mean of the
scene over its square), as a renderer with a box pixel filter or a camera sensor makes them."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from dfc.errors import InputError
from dfc.geometry import bezier
from dfc.geometry.sources.raster import RasterSettings, image_curves

pytest.importorskip("skimage")


def half_plane(width: int, height: int, angle: float, offset: float, centre) -> np.ndarray:
    """(H, W) exact share of each pixel's area where ``n · (p - centre) > offset``, n = (cos angle, sin angle)."""
    n = np.array([np.cos(angle), np.sin(angle)])
    swap = abs(n[0]) > abs(n[1])  # integrate along the axis the edge runs along
    a, b = (n[1], n[0]) if swap else (n[0], n[1])
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float64)
    u0, v0 = (rows, cols) if swap else (cols, rows)  # u along the edge, v across
    cu, cv = (centre[1], centre[0]) if swap else (centre[0], centre[1])
    # for u in [u0, u0 + 1]: the share of v in [v0, v0 + 1] with a (u - cu) + b (v - cv) > offset
    t0 = (offset - a * (u0 - cu)) / b + cv - v0  # v - v0 where the edge crosses, at u = u0
    t1 = t0 - a / b
    sign = 1.0 if b > 0 else -1.0

    def ramp(t):  # antiderivative of clamp(t, 0, 1)
        return np.where(t <= 0, 0.0, np.where(t >= 1, t - 0.5, 0.5 * t * t))

    with np.errstate(divide="ignore", invalid="ignore"):
        below = np.where(np.abs(t1 - t0) > 1e-12, (ramp(t1) - ramp(t0)) / (t1 - t0), np.clip(t0, 0, 1))
    return 1.0 - below if sign > 0 else below


def supersampled(width: int, height: int, inside, ss: int = 16) -> np.ndarray:
    """(H, W) share of each pixel inside ``inside(x, y) -> bool array``, from ss × ss points per pixel."""
    y, x = (np.mgrid[0: height * ss, 0: width * ss] + 0.5) / ss
    return inside(x, y).reshape(height, ss, width, ss).mean(axis=(1, 3))


def sample(curves, n: int = 64) -> np.ndarray:
    """Points (P n + P, 2) along every piece."""
    return bezier.flatten(curves.control_points, n).reshape(-1, 2)


def test_half_plane_helper_is_exact():
    fine = supersampled(8, 8, lambda x, y: (x - 4.3) * np.cos(0.4) + (y - 3.7) * np.sin(0.4) > 0.1, ss=256)
    assert np.abs(half_plane(8, 8, 0.4, 0.1, (4.3, 3.7)) - fine).max() < 3e-3


@settings(max_examples=6, deadline=None)
@given(angle=st.floats(0.0, 2 * np.pi), dx=st.floats(0.0, 1.0), dy=st.floats(0.0, 1.0))
@example(angle=5.5078125, dx=0.0, dy=0.5)  # a diagonal end 4.5 px from both borders: 6.4 px from the corner
def test_straight_step_found_within_two_hundredths_of_a_pixel(angle, dx, dy):
    centre = (24.0 + dx, 24.0 + dy)
    image = 0.2 + 0.6 * half_plane(48, 48, angle, 0.0, centre)
    curves = image_curves(image[..., None])
    assert curves.n_curves == 1
    n = np.array([np.cos(angle), np.sin(angle)])
    distance = np.abs((sample(curves) - centre) @ n)
    assert distance.max() <= 0.02
    # it crosses the whole image: both ends on the border
    ends = curves.control_points[[0, -1], [0, 3]]
    assert np.all(np.any(np.isclose(ends, 0.0) | np.isclose(ends, 48.0), axis=1))


def test_hdr_step_from_one_to_a_thousand():
    centre, angle = (20.4, 19.8), 0.3
    image = 1.0 + 999.0 * half_plane(40, 40, angle, 0.0, centre)
    rgb = image[..., None] * np.array([1.0, 0.9, 0.8])
    curves = image_curves(rgb)
    assert curves.n_curves == 1
    n = np.array([np.cos(angle), np.sin(angle)])
    assert np.abs((sample(curves) - centre) @ n).max() <= 0.02


def test_circle_radius_within_five_hundredths():
    cx, cy, r = 24.3, 23.6, 12.7
    image = 0.3 + 0.5 * supersampled(48, 48, lambda x, y: (x - cx) ** 2 + (y - cy) ** 2 < r * r, ss=32)
    curves = image_curves(np.repeat(image[..., None], 3, axis=2) * np.array([1.0, 0.5, 0.2]))
    assert curves.n_curves == 1
    cp = curves.control_points
    assert np.array_equal(cp[0, 0], cp[-1, 3])  # closed
    radius = np.linalg.norm(sample(curves) - (cx, cy), axis=1)
    assert np.abs(radius - r).max() <= 0.05


def test_point_sampled_circle_is_smoothed_out_of_its_staircase():
    """A point sample holds no mixed pixel: the edge points follow a staircase, which the fit must not take for
    shape (a circle found as a few smooth pieces, not a polygon of dozens)."""
    from dfc.pixel_filter import parse

    cx, cy, r = 32.3, 31.6, 20.7
    y, x = np.mgrid[0:64, 0:64] + 0.5
    image = (0.3 + 0.5 * ((x - cx) ** 2 + (y - cy) ** 2 < r * r))[..., None]
    point = parse("point")
    smoothed = image_curves(image, pixel_filter=point)
    jagged = image_curves(image, pixel_filter=point, point_sigma=0.0, point_tolerance=0.05)
    error = [np.abs(np.linalg.norm(sample(c) - (cx, cy), axis=1) - r) for c in (smoothed, jagged)]
    assert smoothed.n_curves == 1 and len(smoothed) <= 8 < len(jagged)
    assert error[0].mean() <= 0.15 and error[0].max() <= 0.4
    assert error[0].mean() < error[1].mean()


def test_noisy_edge_points_are_smoothed_and_clean_ones_left_alone():
    """A chain whose edge points scatter (noise, as in a path-traced render) is smoothed and fitted loosely: far
    fewer pieces, no farther from the circle on average and much nearer at worst; a clean raster's chains are fitted
    as they are."""
    cx, cy, r = 32.3, 31.6, 20.7
    clean = 0.3 + 0.5 * supersampled(64, 64, lambda x, y: (x - cx) ** 2 + (y - cy) ** 2 < r * r, ss=16)
    noisy = clean + np.random.default_rng(1).normal(0.0, 0.03, clean.shape)
    raw = {"max_scatter": np.inf}
    assert np.array_equal(image_curves(clean[..., None]).control_points,
                          image_curves(clean[..., None], **raw).control_points)
    smoothed, jagged = image_curves(noisy[..., None]), image_curves(noisy[..., None], **raw)
    error = [np.abs(np.linalg.norm(sample(c) - (cx, cy), axis=1) - r) for c in (smoothed, jagged)]
    assert smoothed.n_curves == 1 and 2 * len(smoothed) <= len(jagged)
    assert error[0].mean() <= error[1].mean() + 0.01 and error[0].max() < 0.6 * error[1].max()


@pytest.mark.parametrize("width", [4.0, 8.0])
def test_smooth_ramp_is_not_a_curve(width):
    x = (np.arange(48) + 0.5 - 24.0) / width
    image = np.broadcast_to(0.2 + 0.6 * np.clip(x + 0.5, 0.0, 1.0), (48, 48))[..., None]
    assert len(image_curves(image)) == 0
    # the same contrast as a step is found
    step = np.broadcast_to(np.where(x > 0, 0.8, 0.2), (48, 48))[..., None]
    assert image_curves(step).n_curves == 1


def test_blurred_step_is_not_a_curve():
    from scipy.special import ndtr

    image = supersampled(48, 48, lambda x, y: ndtr((x - 24.3) / 1.5), ss=4)
    assert len(image_curves(image[..., None] * 0.6 + 0.2)) == 0


def test_t_junction_is_welded():
    bar, stem = 20.3, 24.6
    top = supersampled(48, 48, lambda x, y: y < bar)
    right = supersampled(48, 48, lambda x, y: (y >= bar) & (x > stem))
    image = 0.15 * top + 0.9 * right + 0.45 * (1.0 - top - right)
    curves = image_curves(image[..., None])
    assert curves.n_curves == 2
    lengths = [np.ptp(sample(curves)[np.repeat(curves.curve, 65) == c], axis=0) for c in range(2)]
    b = int(np.argmax([extent[0] for extent in lengths]))  # the bar spans the image's width
    bar_points = sample(curves)[np.repeat(curves.curve, 65) == b]
    assert bar_points[:, 0].min() == 0.0 and bar_points[:, 0].max() == 48.0
    assert np.abs(bar_points[:, 1] - bar).max() <= 0.03
    stem_cp = curves.control_points[curves.curve == 1 - b]
    ends = stem_cp[[0, -1], [0, 3]]
    tip = ends[np.argmin(np.abs(ends[:, 1] - bar))]  # the stem's end at the bar
    bar_cp = curves.control_points[curves.curve == b]
    t = np.linspace(0, 1, 9)
    many = np.repeat(bar_cp, len(t), axis=0)
    params = bezier.closest_parameter(many, np.broadcast_to(tip, (len(many), 2)), np.tile(t, len(bar_cp)))
    assert np.linalg.norm(bezier.evaluate(many, params) - tip, axis=1).min() < 1e-9  # exactly on the bar
    other = ends[np.argmax(np.abs(ends[:, 1] - bar))]
    assert other[1] == 48.0  # the stem's other end is on the border
    assert np.abs(sample(curves)[np.repeat(curves.curve, 65) == 1 - b][:, 0] - stem).max() <= 0.03


def test_noise_alone_is_no_curve():
    rng = np.random.default_rng(7)
    image = 0.5 + 0.05 * rng.standard_normal((64, 64, 3))
    assert len(image_curves(image)) == 0


def test_constant_image_gives_the_empty_set_and_bad_images_raise():
    curves = image_curves(np.full((16, 16, 3), 0.4))
    assert len(curves) == 0 and curves.domain == (0.0, 0.0, 16.0, 16.0)
    with pytest.raises(InputError, match="1 × 1"):
        image_curves(np.ones((1, 1, 1)))
    bad = np.ones((8, 8, 1))
    bad[2, 3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        image_curves(bad)
    with pytest.raises(ValueError, match="low"):
        image_curves(np.ones((8, 8, 1)), low=0.5, high=0.1)


def test_settings_are_a_plain_dict():
    d = RasterSettings(tolerance=0.1).to_dict()
    assert d["tolerance"] == 0.1 and RasterSettings(**d) == RasterSettings(tolerance=0.1)
