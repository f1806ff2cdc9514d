"""Curves of Mitsuba 3 scenes (``dfc.geometry.sources.scene``, ``dfc curves``), checked against geometry worked out
here and against Mitsuba's own renders. Skipped without the render extra (CI installs it)."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

mi = pytest.importorskip("mitsuba")

from dfc.errors import InputError  # noqa: E402
from dfc.geometry import bezier  # noqa: E402
from dfc.geometry.sources import read_curves  # noqa: E402
from dfc.geometry.sources.scene import read_scene  # noqa: E402
from dfc.io.mitsuba import Camera, load_scene, perspective_sensor, render_aovs, write_ply  # noqa: E402

from ..cli.test_cli import assert_one_line_error, run  # noqa: E402
from ..conftest import SAMPLES  # noqa: E402


def write_scene(directory: Path, shapes: str, *, width=64, height=48, fov=40, origin=(0.4, 1.2, 5.0),
                target=(0.0, 0.0, 0.0), crop=None, sensor="perspective", meshes=None, name="scene.xml") -> Path:
    """A Mitsuba scene file in ``directory`` with ``shapes`` (XML) seen by one sensor; ``meshes`` maps PLY file
    names to (vertices, faces); ``crop`` is (x, y, w, h) of the film's crop window."""
    for file, (v, f) in (meshes or {}).items():
        write_ply(directory / file, v, f)
    crop_xml = "" if crop is None else "".join(
        f'<integer name="{k}" value="{v}"/>'
        for k, v in zip(("crop_offset_x", "crop_offset_y", "crop_width", "crop_height"), crop))
    fov_xml = f'<float name="fov" value="{fov}"/>' if sensor == "perspective" else ""
    path = directory / name
    path.write_text(f"""<scene version="3.0.0">
        <sensor type="{sensor}">{fov_xml}
            <transform name="to_world"><lookat origin="{','.join(map(str, origin))}"
                target="{','.join(map(str, target))}" up="0,1,0"/></transform>
            <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
            <film type="hdrfilm"><integer name="width" value="{width}"/><integer name="height" value="{height}"/>
                {crop_xml}<rfilter type="box"/></film>
        </sensor>
        {shapes}
    </scene>""")
    return path


CUBE = """<shape type="cube" id="cube"><transform name="to_world"><scale value="0.5"/><rotate y="1" angle="30"/>
    <rotate x="1" angle="15"/><translate y="0.2"/></transform></shape>"""
BACKDROP = """<shape type="rectangle" id="backdrop"><transform name="to_world"><scale value="20"/>
    <translate z="-3"/></transform></shape>"""


def camera_of(path) -> Camera:
    return Camera.from_sensor(perspective_sensor(load_scene(path)))


def samples_of(curves, spacing=0.005) -> np.ndarray:
    """(N, 2) points along every piece, at most about ``spacing`` pixels apart."""
    longest = np.linalg.norm(np.diff(curves.control_points, axis=1), axis=2).sum(axis=1).max()
    return bezier.flatten(curves.control_points, int(np.ceil(longest / spacing))).reshape(-1, 2)


def segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) distances of points (N, 2) to segments a–b (M, 2)."""
    ab = b - a
    t = np.clip(np.einsum("nmk,mk->nm", points[:, None] - a, ab) / np.einsum("mk,mk->m", ab, ab), 0, 1)
    return np.linalg.norm(points[:, None] - a - t[..., None] * ab, axis=2)


def cube_edges(path):
    """World corners of the scene's cube, its 12 edges (pairs of corner indices) and, per edge, how many of its two
    faces face the eye; worked out from the corners Mitsuba loaded."""
    scene = load_scene(path)
    cube = next(s for s in scene.shapes() if s.id() == "cube")
    corners = np.unique(np.array(cube.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3), axis=0)
    assert len(corners) == 8
    centre = corners.mean(axis=0)
    d = np.linalg.norm(corners[:, None] - corners[None], axis=2)
    side = np.sort(d[d > 0])[0]
    edges = np.array([(i, j) for i in range(8) for j in range(i + 1, 8) if abs(d[i, j] - side) < 1e-5])
    assert len(edges) == 12
    eye = camera_of(path).eye
    axes = np.array([(corners[j] - corners[i]) / side for i, j in edges])
    frame = [axes[0]]
    for u in axes:  # the cube's three edge directions
        if all(abs(u @ f) < 1e-6 for f in frame):
            frame.append(u)
    facing = []
    for i, j in edges:
        along = corners[j] - corners[i]
        count = 0
        for u in frame:
            if abs(u @ along) > 1e-6:
                continue  # not a face normal of this edge
            normal = u * np.sign(u @ (corners[i] - centre))
            count += normal @ (eye - (centre + normal * side / 2)) > 0
        facing.append(count)
    return corners, edges, np.array(facing)


def assert_lines_cover(curves, segments: np.ndarray, atol=1e-6):
    """Every piece is a line on one of ``segments`` (S, 2, 2), and together they cover each segment exactly."""
    assert np.all(curves.degree == 1)
    ends = curves.control_points[:, [0, 3]]
    covered = np.zeros(len(segments))
    for a, b in ends:
        dist = segment_distance(np.stack([a, b]), segments[:, 0], segments[:, 1]).max(axis=0)
        k = int(np.argmin(dist))
        assert dist[k] < atol, (a, b)
        covered[k] += np.linalg.norm(b - a)
    np.testing.assert_allclose(covered, np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1), atol=1e-5)


@pytest.mark.parametrize("creases", [True, False])
def test_cube_in_front_of_a_plane(tmp_path, creases):
    path = write_scene(tmp_path, CUBE + BACKDROP)
    corners, edges, facing = cube_edges(path)
    want = edges[(facing == 1) | ((facing == 2) & creases)]  # silhouettes, and the creases between seen faces
    px, _ = camera_of(path).project(corners)
    curves = read_scene(path, creases=creases)
    assert curves.domain == (0.0, 0.0, 64.0, 48.0)
    assert_lines_cover(curves, px[want])
    assert len(want) == (9 if creases else 6)


def test_projected_points_land_where_mitsuba_renders_them(tmp_path):
    path = write_scene(tmp_path, CUBE, width=80, height=50, crop=(7, 5, 51, 38))
    scene = load_scene(path)
    sensor = perspective_sensor(scene)
    camera = Camera.from_sensor(sensor)
    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, (50, 3))
    px, depth = camera.project(points)
    assert np.all(depth > 0)
    for p, x in zip(points, px / camera.size):
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(*x), mi.Point2f(0.5, 0.5))
        d = np.array(ray.d, dtype=np.float64)
        to_point = p - camera.eye
        angle = np.arctan2(np.linalg.norm(np.cross(d, to_point)), d @ to_point)
        assert angle * abs(camera.intrinsics[0, 0]) < 0.01  # radians × focal length in pixels


def test_partly_hidden_edge_is_split_where_it_passes_behind(tmp_path):
    back = """<shape type="rectangle" id="back"><transform name="to_world"><scale x="2" y="0.6"/>
        <translate y="0.3" z="-1"/></transform></shape>"""
    plank = """<shape type="rectangle" id="plank"><transform name="to_world"><scale x="0.2" y="1.5"/>
        <rotate z="1" angle="12"/><translate x="0.3" z="0.5"/></transform></shape>"""
    path = write_scene(tmp_path, back + plank, width=96, height=64, origin=(0.1, 0.5, 4), target=(0, 0.4, 0))
    camera = camera_of(path)
    corner = {s.id(): np.unique(np.array(s.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3), axis=0)
              for s in load_scene(path).shapes()}
    back_top = camera.project(corner["back"][corner["back"][:, 1] > 0.5])[0]  # its upper edge, y = 0.9
    plank = corner["plank"]
    pairs = sorted(((np.linalg.norm(plank[i] - plank[j]), i, j) for i in range(4) for j in range(i + 1, 4)))
    long_sides = [camera.project(plank[[i, j]])[0] for _, i, j in pairs[2:4]]  # after the two short sides

    def cross2(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    def crossing(a, b):  # where line a (2, 2) meets line b (2, 2)
        da, db = a[1] - a[0], b[1] - b[0]
        return a[0] + cross2(b[0] - a[0], db) / cross2(da, db) * da

    expected = np.array([crossing(back_top, side) for side in long_sides])
    curves = read_scene(path)
    ends = curves.control_points[:, [0, 3]]
    direction = (back_top[1] - back_top[0]) / np.linalg.norm(back_top[1] - back_top[0])
    off_line = np.abs(cross2(ends - back_top[0], direction)).max(axis=1)
    cut = ends[off_line < 1e-6].reshape(-1, 2)
    cut = cut[np.linalg.norm(cut[:, None] - back_top[None], axis=2).min(axis=1) > 1e-6]  # not its own ends
    cut = cut[np.all((cut > 1e-6) & (cut < np.array(curves.domain[2:]) - 1e-6), axis=1)]  # nor the film's border
    assert len(cut) == 2
    dist = np.linalg.norm(cut[:, None] - expected[None], axis=2)
    assert dist.min(axis=1).max() <= 0.01 and dist.min(axis=0).max() <= 0.01


def test_open_mesh_gives_its_boundary_not_its_diagonal(tmp_path):
    uv = np.array([[-1.0, -0.6], [1.1, -0.5], [0.9, 0.7], [-0.8, 0.5]])
    quad = uv @ np.array([[1.0, 0.1, 0.3], [-0.2, 1.0, 0.2]])  # a flat, convex quad of two triangles
    shapes = '<shape type="ply" id="quad"><string name="filename" value="quad.ply"/></shape>'
    path = write_scene(tmp_path, shapes, meshes={"quad.ply": (quad, np.array([[0, 1, 2], [0, 2, 3]]))})
    px, _ = camera_of(path).project(quad)
    curves = read_scene(path)
    assert_lines_cover(curves, np.stack([px, np.roll(px, -1, axis=0)], axis=1))


def uv_sphere(radius, n_lon, n_lat):
    """A closed UV sphere: vertices (V, 3) and faces (F, 3)."""
    lat = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    lon = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    ring = np.stack([np.sin(lat)[:, None] * np.cos(lon), np.cos(lat)[:, None] + 0 * lon,
                     np.sin(lat)[:, None] * np.sin(lon)], axis=-1).reshape(-1, 3)
    v = radius * np.vstack([[0, 1, 0], ring, [0, -1, 0]])
    idx = 1 + np.arange(len(ring)).reshape(n_lat - 1, n_lon)
    nxt = np.roll(idx, -1, axis=1)
    faces = [np.stack([np.zeros(n_lon, int), nxt[0], idx[0]], 1),
             np.stack([np.full(n_lon, len(v) - 1), idx[-1], nxt[-1]], 1)]
    for r in range(n_lat - 2):
        faces += [np.stack([idx[r], nxt[r], nxt[r + 1]], 1), np.stack([idx[r], nxt[r + 1], idx[r + 1]], 1)]
    return v, np.concatenate(faces)


def exact_contour(camera, centre, radius, n=100_000):
    """(n, 2) image points of the exact contour of a sphere (the circle where eye rays touch it)."""
    offset = camera.eye - centre
    d = np.linalg.norm(offset)
    axis = offset / d
    e1 = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)[:, None]
    ring = radius * np.sqrt(1 - radius ** 2 / d ** 2)
    return camera.project(centre + axis * radius ** 2 / d + ring * (np.cos(t) * e1 + np.sin(t) * e2))[0]


def test_tessellated_sphere_contour_within_its_tessellation_error(tmp_path):
    v, f = uv_sphere(0.7, 160, 80)  # fine enough (1.3 px edges) for cubics to follow its outline within 0.05 px
    shapes = ('<shape type="ply" id="ball"><string name="filename" value="ball.ply"/>'
              '<transform name="to_world"><translate x="0.2" y="0.1"/></transform></shape>')
    path = write_scene(tmp_path, shapes, width=120, height=90, meshes={"ball.ply": (v, f)})
    camera = camera_of(path)
    centre = np.array([0.2, 0.1, 0.0])
    exact = exact_contour(camera, centre, 0.7)
    error = 0.7 * (1 - np.cos(np.pi / 80)) * abs(camera.intrinsics[0, 0]) / (np.linalg.norm(camera.eye - centre) - 0.7)
    curves = read_scene(path)
    got = samples_of(curves)
    assert cKDTree(exact).query(got)[0].max() <= error + 0.05
    assert cKDTree(got).query(exact)[0].max() <= error + 0.05
    assert np.sum(curves.degree == 3) > 0 and len(curves) < 40  # fitted: far fewer pieces than silhouette edges


@pytest.mark.parametrize("shape", ["sphere", "disk"])
def test_analytic_outline_within_a_hundredth_of_a_pixel(tmp_path, shape):
    if shape == "sphere":
        xml = '<shape type="sphere"><point name="center" x="0.2" y="0.1" z="0"/><float name="radius" value="0.7"/>'
        xml += "</shape>"
    else:
        xml = ('<shape type="disk"><transform name="to_world"><scale value="0.7"/><rotate x="1" angle="-70"/>'
               '<rotate y="1" angle="25"/><translate x="0.2" y="0.1"/></transform></shape>')
    path = write_scene(tmp_path, xml, width=120, height=90)
    camera = camera_of(path)
    centre = np.array([0.2, 0.1, 0.0])
    if shape == "sphere":
        exact = exact_contour(camera, centre, 0.7)
    else:
        to_world = np.array(mi.traverse(load_scene(path).shapes()[0])["to_world"].matrix, dtype=np.float64)
        t = np.linspace(0, 2 * np.pi, 100_000, endpoint=False)
        exact = camera.project(np.c_[np.cos(t), np.sin(t), 0 * t, 1 + 0 * t] @ to_world[:3].T)[0]
    curves = read_scene(path)
    assert curves.n_curves == 1 and np.all(curves.degree == 3)
    got = samples_of(curves)
    spacing = np.linalg.norm(np.diff(exact, axis=0), axis=1).max()
    assert cKDTree(exact).query(got)[0].max() <= 0.01 + spacing
    length = np.linalg.norm(np.diff(bezier.flatten(curves.control_points, 1000), axis=1), axis=2).sum()
    perimeter = np.linalg.norm(np.diff(np.vstack([exact, exact[:1]]), axis=0), axis=1).sum()
    assert abs(length - perimeter) < 1e-3 * perimeter


def test_crop_window_gives_the_same_curves_in_its_own_pixels(tmp_path):
    full = read_scene(write_scene(tmp_path, CUBE + BACKDROP, name="full.xml"))
    crop = read_scene(write_scene(tmp_path, CUBE + BACKDROP, crop=(20, 9, 30, 24), name="crop.xml"))
    assert crop.domain == (0.0, 0.0, 30.0, 24.0)
    full_ends = full.control_points[:, [0, 3]]
    shifted = crop.control_points[:, [0, 3]] + (20, 9)
    on = segment_distance(shifted.reshape(-1, 2), full_ends[:, 0], full_ends[:, 1]).min(axis=1)
    assert on.max() < 1e-4  # the two sensors' pinholes are read from Mitsuba's single-precision rays
    inside = samples_of(full)
    inside = inside[np.all((inside > (20.01, 9.01)) & (inside < (49.99, 32.99)), axis=1)]
    covered = segment_distance(inside, shifted[:, 0], shifted[:, 1]).min(axis=1)
    assert len(inside) and covered.max() < 1e-4


def aov_agreement(path, scale=4, crease_angle=30.0):
    """The issue's property check against Mitsuba: the share of the pixel boundaries of a ``scale``× AOV render
    where the shape index changes, the depth jumps (by 5 %) or the geometric normal turns by more than the crease
    angle that lie within 1 px (at that scale) of an emitted curve, and the share of the emitted curve length that
    lies within 1 px of such a boundary."""
    curves = read_scene(path, crease_angle=crease_angle)
    scene = load_scene(path)
    aov = render_aovs(scene, perspective_sensor(scene), "si:shape_index,dd:depth,nn:geo_normal", supersample=scale)
    index, depth, normal = aov[..., 0], aov[..., 1], aov[..., 2:5]
    hit = depth > 0
    mids = []
    for axis in (0, 1):
        a = (slice(None, -1), slice(None)) if axis == 0 else (slice(None), slice(None, -1))
        b = (slice(1, None), slice(None)) if axis == 0 else (slice(None), slice(1, None))
        both = hit[a] & hit[b]
        jump = both & (np.abs(depth[a] - depth[b]) > 0.05 * np.minimum(depth[a], depth[b]))
        turn = both & (np.einsum("ijk,ijk->ij", normal[a], normal[b]) < np.cos(np.radians(crease_angle)))
        row, col = np.nonzero((index[a] != index[b]) | (hit[a] != hit[b]) | jump | turn)
        mids.append(np.c_[col + 0.5 + 0.5 * axis, row + 0.5 + 0.5 * (1 - axis)])
    mids = np.concatenate(mids)
    cp = curves.control_points * scale
    n = int(np.ceil(np.linalg.norm(np.diff(cp, axis=1), axis=2).sum(axis=1).max() / 0.05))
    line = bezier.flatten(cp, n)
    points = 0.5 * (line[:, 1:] + line[:, :-1]).reshape(-1, 2)
    weight = np.linalg.norm(np.diff(line, axis=1), axis=2).ravel()
    near_curve = cKDTree(points).query(mids)[0] <= 1.0
    near_boundary = cKDTree(mids).query(points)[0] <= 1.0
    return near_curve.mean(), weight[near_boundary].sum() / weight.sum(), len(mids)


def test_curves_agree_with_mitsubas_shape_depth_and_normal_buffers(tmp_path):
    text = (SAMPLES / "scene" / "scene.xml").read_text()
    for mesh in ("torus.ply", "gem.ply"):
        text = text.replace(f'value="{mesh}"', f'value="{SAMPLES / "scene" / mesh}"')
    path = tmp_path / "scene.xml"
    path.write_text(text.replace('name="width" value="512"', 'name="width" value="160"')
                    .replace('name="height" value="512"', 'name="height" value="160"'))
    boundaries, length, count = aov_agreement(path)
    assert count > 3000
    assert boundaries >= 0.99
    assert length >= 0.98


def test_sensor_that_is_not_perspective_is_refused(tmp_path, capsys):
    path = write_scene(tmp_path, CUBE, sensor="orthographic")
    with pytest.raises(InputError, match="perspective"):
        read_scene(path)
    code, _, err = run(["curves", path, "-o", tmp_path / "c.json"], capsys)
    assert_one_line_error(code, err, "OrthographicCamera")
    assert not (tmp_path / "c.json").exists()


def test_bad_scenes_give_one_error_line(tmp_path, capsys):
    cases = []

    def scene(name, text):
        (tmp_path / name).write_text(text)
        return tmp_path / name

    cases.append((scene("other.xml", "<svg/>"), "not a Mitsuba 3 scene"))
    cases.append((scene("dc.xml", '<scene image_width="8" image_height="8"><curve_set/></scene>'), "diffusion-curve"))
    cases.append((scene("broken.xml", '<scene version="3.0.0"><shape type="cube">'), "not well-formed"))
    cases.append((scene("nosensor.xml", '<scene version="3.0.0"><shape type="cube"/></scene>'), "no sensor"))
    cases.append((write_scene(tmp_path, '<shape type="ply"><string name="filename" value="gone.ply"/></shape>',
                              name="missing.xml"), "gone.ply"))
    cases.append((write_scene(tmp_path, '<shape type="blorb"/>', name="plugin.xml"), "blorb"))
    (tmp_path / "hair.txt").write_text("0 0 0 0.1\n0 1 0 0.1\n")
    cases.append((write_scene(tmp_path, f'<shape type="linearcurve"><string name="filename" value="'
                                        f'{tmp_path / "hair.txt"}"/></shape>', name="curve.xml"), "LinearCurve"))
    cases.append((scene("notes.dat", "not really"), "not an input dfc can find curves in"))
    for path, match in cases:
        code, _, err = run(["curves", path, "-o", tmp_path / "out.json"], capsys)
        assert_one_line_error(code, err, match)
    code, _, err = run(["curves", write_scene(tmp_path, CUBE, name="two.xml"), "--sensor", "1", "-o",
                        tmp_path / "out.json"], capsys)
    assert_one_line_error(code, err, "no sensor 1")
    assert not (tmp_path / "out.json").exists()


def test_cli_writes_curves_summary_and_preview(tmp_path, capsys):
    path = write_scene(tmp_path, CUBE + BACKDROP)
    out, preview = tmp_path / "c.json", tmp_path / "p.png"
    code, stdout, err = run(["curves", path, "-o", out, "--preview", preview, "--json", "-", "-q"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    curves = read_curves(out)
    assert summary["pieces"] == len(curves) == 9 and summary["triangles"] == 14
    assert curves.domain == (0.0, 0.0, 64.0, 48.0)
    assert "wrote" in err
    from PIL import Image

    from dfc.io.mitsuba import flat_shaded

    with Image.open(preview) as image:
        assert image.size == (64, 48)
        drawn = np.asarray(image.convert("RGB")).astype(int)
    picture = np.round(255 * flat_shaded(str(path))).astype(int)  # the preview's background, without curves
    assert np.sum(np.abs(drawn - picture).max(axis=2) > 60) > 50  # the curves are drawn
