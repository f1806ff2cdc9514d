"""Mitsuba 3 scenes (the ``render`` extra): load one with its errors as ``InputError``, model its perspective
sensor as a pinhole camera, and render any window of its film.

Mitsuba runs in its CPU variant ``scalar_rgb``. Film coordinates follow ``spec/conventions.md``: the rendered
image (the film's crop window when it has one) covers ``[0, W] × [0, H]`` pixels, y down, pixel centres at +0.5.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ExtraError, InputError

__all__ = ["VARIANT", "Camera", "check_scene_file", "flat_shaded", "import_mitsuba", "load_scene", "ordered_shapes",
           "perspective_sensor", "render_aovs", "render_window", "window_sensor", "write_ply"]

VARIANT = "scalar_rgb"
_INSTALL = "pip install 'dfc[render]'"


def import_mitsuba():
    """The ``mitsuba`` module set to ``VARIANT`` with its log quiet (errors still raise);
    ``ExtraError`` naming the extra when it is not installed."""
    try:
        import mitsuba as mi
    except ImportError:
        raise ExtraError(f"Mitsuba 3 scenes need the render extra: {_INSTALL}") from None
    if mi.variant() != VARIANT:
        mi.set_variant(VARIANT)
    mi.set_log_level(mi.LogLevel.Error)
    return mi


def check_scene_file(path: str | Path) -> None:
    """Raise ``InputError`` unless ``path`` is an XML file whose root is a Mitsuba ``<scene version="…">``.

    A diffusion-curve XML file (root ``<curve_set>``, or ``<scene image_width=… image_height=…>``) gets a message
    saying it already is a curves file."""
    path = Path(path)
    root = None
    try:
        for event, element in ET.iterparse(path, events=("start", "end")):
            if root is None:
                root = element
            elif event == "end" and element is not root:
                element.clear()  # the whole file is read for its syntax, without keeping it
    except ET.ParseError as e:
        line, column = e.position
        raise InputError(f"{path}: line {line}, column {column + 1}: not well-formed XML") from None
    if root.tag == "curve_set" or (root.tag == "scene" and {"image_width", "image_height"} & set(root.attrib)):
        raise InputError(f"{path}: this is a diffusion-curve XML file, already a curves file: "
                         "give it to 'dfc mesh' or 'dfc encode --curves' as it is")
    if root.tag != "scene" or "version" not in root.attrib:
        what = f"<{root.tag}>" if root.tag != "scene" else "<scene> without a version attribute"
        raise InputError(f'{path}: not a Mitsuba 3 scene: the root element is {what}, expected <scene version="3.0.0">')


def load_scene(path: str | Path):
    """Load a Mitsuba 3 scene file (``check_scene_file`` first); Mitsuba's errors (missing mesh file, unknown
    plugin, bad parameter) become one-line ``InputError``s."""
    mi = import_mitsuba()
    path = Path(path)
    check_scene_file(path)
    try:
        return mi.load_file(str(path))
    except Exception as e:  # Mitsuba raises RuntimeError, and TypeError/ValueError from its bindings
        raise InputError(f"{path}: {_one_line(str(e))}") from None


def _loaded(scene) -> tuple[str | Path, object]:
    """(name for messages, Mitsuba scene) of a scene file or an already loaded scene."""
    return (scene, load_scene(scene)) if isinstance(scene, (str, Path)) else ("scene", scene)


def _one_line(message: str) -> str:
    """A Mitsuba message without its source locations (``[parser.cpp:1718]``), on one line."""
    return " ".join(re.sub(r"\[[\w.]+\.cpp:\d+\]\s*", "", message).split())


def ordered_shapes(scene) -> list:
    """The scene's shapes in an order that does not change from one load to the next (``scene.shapes()`` lists
    them in a different order each time): by id, type, bounding box and size."""
    def key(shape):
        box = shape.bbox()
        return (shape.id(), shape.class_name(), tuple(box.min), tuple(box.max), shape.primitive_count())

    return sorted(scene.shapes(), key=key)


def perspective_sensor(scene, index: int = 0, path: str | Path = "scene"):
    """Sensor ``index`` of ``scene``; ``InputError`` when there is none or it is not a perspective camera."""
    sensors = scene.sensors()
    if not sensors:
        raise InputError(f'{path}: the scene has no sensor; add a <sensor type="perspective">')
    if not 0 <= index < len(sensors):
        raise InputError(f"{path}: no sensor {index}: the scene has {len(sensors)} sensor(s), numbered from 0")
    sensor = sensors[index]
    if sensor.class_name() != "PerspectiveCamera":
        raise InputError(f"{path}: sensor {index} is a {sensor.class_name()}; only perspective sensors are supported")
    return sensor


@dataclass(frozen=True)
class Camera:
    """A perspective sensor as a pinhole camera, in the rendered image's pixels.

    intrinsics : (3, 3) float64, camera-space slopes ``(x/z, y/z, 1)`` -> film pixel ``(u, v, 1)``
    world_to_camera : (4, 4) float64, the inverse of the sensor's ``to_world``
    eye : (3,) float64, the centre of projection in world space
    near, far : the clip distances along the camera's z axis (camera units)
    size : (W, H), the rendered image (the crop window when the film has one)
    """

    intrinsics: np.ndarray
    world_to_camera: np.ndarray
    eye: np.ndarray
    near: float
    far: float
    size: tuple[int, int]

    @classmethod
    def from_sensor(cls, sensor) -> Camera:
        """Read the pinhole from Mitsuba's own rays: the intrinsics are the affine map that takes the slopes of the
        rays ``sensor.sample_ray`` shoots through a 3 × 3 grid of film positions to those positions."""
        mi = import_mitsuba()
        to_world = np.array(sensor.world_transform().matrix, dtype=np.float64)
        world_to_camera = np.linalg.inv(to_world)
        width, height = (int(v) for v in sensor.film().crop_size())
        grid = np.array([(u, v) for u in (0.0, 0.5, 1.0) for v in (0.0, 0.5, 1.0)])
        slopes = []
        for u, v in grid:
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(u, v), mi.Point2f(0.5, 0.5))
            c = world_to_camera[:3, :3] @ np.array(ray.d, dtype=np.float64)
            slopes.append((c[0] / c[2], c[1] / c[2], 1.0))
        fit, *_ = np.linalg.lstsq(np.array(slopes), grid * (width, height), rcond=None)  # (3, 2)
        intrinsics = np.vstack([fit.T, (0.0, 0.0, 1.0)])
        return cls(intrinsics, world_to_camera, to_world[:3, 3].copy(), float(sensor.near_clip()),
                   float(sensor.far_clip()), (width, height))

    @property
    def matrix(self) -> np.ndarray:
        """(3, 4) float64: world point ``[X, 1]`` -> ``(u w, v w, w)``, ``(u, v)`` film pixels, ``w`` the depth."""
        return self.intrinsics @ self.world_to_camera[:3]

    def homogeneous(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> (N, 3) float64 ``(u w, v w, w)``."""
        m, p = self.matrix, np.asarray(points, dtype=np.float64)
        # written out rather than a matrix product, so that a point's image does not depend on its batch
        return p[:, :1] * m[:, 0] + p[:, 1:2] * m[:, 1] + p[:, 2:3] * m[:, 2] + m[:, 3]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) -> film pixels (N, 2) float64 and depths ``w`` (N,) (> 0 in front of the eye)."""
        h = self.homogeneous(points)
        return h[:, :2] / h[:, 2:], h[:, 2]


def window_sensor(base, window, width: int, height: int, *, sampler=None, rfilter=None):
    """A perspective sensor whose film is exactly the window ``(x0, y0, x1, y1)`` (pixels of ``base``'s rendered
    image) at ``width × height``: ``base``'s pose and clip distances, its field of view and principal point set from
    ``base``'s intrinsics. ``sampler`` and ``rfilter`` (Mitsuba objects or plugin dicts) default to ``base``'s.
    Output pixels must be square: ``width / (x1 - x0) == height / (y1 - y0)``; ``ValueError`` else."""
    mi = import_mitsuba()
    x0, y0, x1, y1 = (float(v) for v in window)
    if not (np.isfinite([x0, y0, x1, y1]).all() and x1 > x0 and y1 > y0):
        raise ValueError(f"window must be finite (x0, y0, x1, y1) with x1 > x0 and y1 > y0, got {tuple(window)}")
    if width < 1 or height < 1:
        raise ValueError(f"width and height must be at least 1, got {width}, {height}")
    kx, ky = width / (x1 - x0), height / (y1 - y0)
    if abs(kx - ky) > 1e-6 * max(kx, ky):
        raise ValueError(f"pixels must be square: {width}/{x1 - x0:g} != {height}/{y1 - y0:g}")
    k = Camera.from_sensor(base).intrinsics
    x_extent = -(x1 - x0) / k[0, 0]  # slope range across the window; Mitsuba's frames have k[0, 0] < 0
    return mi.load_dict({
        "type": "perspective",
        "fov_axis": "x",
        "fov": float(np.degrees(2.0 * np.arctan(0.5 * x_extent))),
        "principal_point_offset_x": 0.5 - (k[0, 2] - x0) / (x1 - x0),
        "principal_point_offset_y": 0.5 - (k[1, 2] - y0) / (y1 - y0),
        "near_clip": float(base.near_clip()),
        "far_clip": float(base.far_clip()),
        "to_world": base.world_transform(),
        "film": {"type": "hdrfilm", "width": int(width), "height": int(height), "pixel_format": "rgb",
                 "rfilter": base.film().rfilter() if rfilter is None else rfilter},
        "sampler": base.sampler() if sampler is None else sampler,
    })


MITSUBA_FILTERS = ("box", "gaussian", "tent", "mitchell")
"""dfc pixel filters (``dfc.pixel_filter``) that Mitsuba 3 renders with a reconstruction filter of its own."""


def rfilter_plugin(pixel_filter) -> dict:
    """The Mitsuba ``rfilter`` plugin dict of a dfc pixel filter (``PixelFilter`` or spec string): ``box``,
    ``gaussian:S`` (stddev S; Mitsuba's radius 4S), ``tent``, ``mitchell``. Raises ``InputError`` for the others."""
    from ..pixel_filter import parse

    f = parse(pixel_filter) if isinstance(pixel_filter, str) else pixel_filter
    if f.name not in MITSUBA_FILTERS or (f.name == "box" and f.param is not None):
        raise InputError(f"Mitsuba renders with box, gaussian[:STDDEV], tent or mitchell, not {f}")
    plugin = {"type": f.name}
    if f.name == "gaussian":
        plugin["stddev"] = float(f.param)
    elif f.name == "mitchell":
        plugin.update(B=1.0 / 3.0, C=1.0 / 3.0)
    return plugin


def rfilter_spec(rfilter) -> str:
    """The dfc pixel filter spec (``dfc.pixel_filter``) of a Mitsuba reconstruction filter (object or plugin
    dict) — what a render made with it states; ``"unknown"`` for filters dfc has no kernel of."""
    from ..pixel_filter import parse

    if isinstance(rfilter, dict):
        kind, stddev = rfilter.get("type"), rfilter.get("stddev", 0.5)
    else:
        text = str(rfilter)
        kind = text.split("[")[0].strip().lower().replace("filter", "")
        kind = {"box": "box", "gaussian": "gaussian", "tent": "tent", "mitchellnetravali": "mitchell"}.get(kind)
        if kind == "mitchell" and not ("B=0.333333" in text and "C=0.333333" in text):
            kind = None  # dfc's mitchell is B = C = 1/3
        found = re.search(r"stddev\s*=\s*([0-9.eE+-]+?)(?:[,\s\]]|$)", text)
        stddev = float(found.group(1)) if found else 0.5
    if kind not in MITSUBA_FILTERS:
        return "unknown"
    return str(parse(f"gaussian:{stddev:g}" if kind == "gaussian" else kind))


def render_window(scene, window, width: int, height: int, spp: int, *, sensor: int = 0, seed: int = 0,
                  rfilter=None) -> np.ndarray:
    """Render the window ``(x0, y0, x1, y1)`` (film pixels of the rendered image, y down) at ``width × height``.

    The exact reference of a zoom: Mitsuba renders the scene through ``window_sensor``, so the whole
    ``[0, W] × [0, H]`` window at ``W × H`` is the scene's own render, and any other window is what a film scaled
    up with a crop window would show. ``scene`` is a scene file or a loaded Mitsuba scene; ``sensor`` the index of
    a perspective sensor; ``spp`` samples per pixel; ``seed`` the sampler's seed; ``rfilter`` the pixel filter (a
    Mitsuba object or plugin dict, e.g. ``{"type": "box"}``; default the sensor's film's).

    Returns (height, width, C) float32 linear values, the film's channels (C = 3, RGB, for the usual integrators).
    Raises ``ValueError`` for a malformed window, size or spp, ``InputError`` for a scene that cannot be used.
    """
    mi = import_mitsuba()
    path, scene = _loaded(scene)
    if spp < 1:
        raise ValueError(f"spp must be at least 1, got {spp}")
    view = window_sensor(perspective_sensor(scene, sensor, path), window, width, height, rfilter=rfilter)
    return np.array(mi.render(scene, sensor=view, spp=int(spp), seed=int(seed)), dtype=np.float32)


def render_aovs(scene, sensor, aovs: str, *, supersample: int = 1) -> np.ndarray:
    """Mitsuba's ``aov`` integrator (``aovs`` as it takes them, e.g. ``"dd:depth,nn:geo_normal"``) through
    ``sensor`` at ``supersample`` × its rendered image's size, one sample at each pixel centre, box filter.

    Returns (supersample H, supersample W, C) float64, C the AOVs' channels in order.
    """
    mi = import_mitsuba()
    width, height = Camera.from_sensor(sensor).size
    view = window_sensor(sensor, (0, 0, width, height), width * supersample, height * supersample,
                         sampler={"type": "stratified", "sample_count": 1, "jitter": False}, rfilter={"type": "box"})
    aov = mi.load_dict({"type": "aov", "aovs": aovs})
    return np.array(mi.render(scene, sensor=view, integrator=aov, spp=1), dtype=np.float64)


def flat_shaded(scene, *, sensor: int = 0, supersample: int = 2) -> np.ndarray:
    """A quick picture of the rendered image's frame: every shape in its own colour, shaded by its geometric
    normal, the background grey; ``supersample``² pixel centres per pixel, averaged.

    ``scene`` is a scene file or a loaded Mitsuba scene. Returns (H, W, 3) float32 display values in [0, 1].
    """
    path, scene = _loaded(scene)
    base = perspective_sensor(scene, sensor, path)
    width, height = Camera.from_sensor(base).size
    s = int(supersample)
    out = render_aovs(scene, base, "si:shape_index,dd:depth,nn:geo_normal", supersample=s)
    index, hit, normal = out[..., 0].astype(np.int64), out[..., 1] > 0, out[..., 2:5]
    palette = np.random.default_rng(7).uniform(0.35, 0.95, (int(index.max()) + 1, 3))
    light = np.array([0.35, 0.8, 0.5]) / np.linalg.norm([0.35, 0.8, 0.5])
    shade = 0.45 + 0.55 * np.abs(normal @ light)
    picture = np.where(hit[..., None], palette[index] * shade[..., None], 0.8)
    return picture.reshape(height, s, width, s, 3).mean(axis=(1, 3)).astype(np.float32)


def write_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """A triangle mesh as a binary little-endian PLY that Mitsuba's ``ply`` plugin reads, written atomically.

    vertices : (V, 3) float, stored as float32; faces : (F, 3) int, stored as int32 indices
    """
    from .atomic import write_bytes_atomic

    vertices = np.asarray(vertices, dtype="<f4").reshape(-1, 3)
    faces = np.asarray(faces).reshape(-1, 3)
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertices)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    rows = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", 3)])
    rows["n"], rows["i"] = 3, faces
    write_bytes_atomic(path, header.encode() + vertices.tobytes() + rows.tobytes())
