"""Write the sample 3D scene: ``python samples/make_scene.py`` (from the repository root).

``samples/scene/scene.xml`` is a Mitsuba 3 scene (512 × 512, perspective camera, a rectangular area light):
a floor, a smooth torus and a faceted gem (binary PLY meshes written here), a cube sunk into the floor, an
analytic sphere and an open analytic cylinder. It exercises everything ``dfc curves`` extracts: silhouettes of a
tessellated smooth surface, creases, boundaries, exact sphere contours and cylinder rims, and mesh intersections.
Render it with ``python samples/make_render.py``.
"""

from pathlib import Path

import numpy as np

from dfc.io.mitsuba import write_ply

HERE = Path(__file__).parent / "scene"


def torus(major: float, minor: float, n_major: int, n_minor: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n_major n_minor, 3) and faces (2 n_major n_minor, 3) of a torus around the y axis."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n_major, endpoint=False),
                       np.linspace(0, 2 * np.pi, n_minor, endpoint=False), indexing="ij")
    ring = major + minor * np.cos(v)
    vertices = np.stack([ring * np.cos(u), minor * np.sin(v), ring * np.sin(u)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    d = i * n_minor + (j + 1) % n_minor
    faces = np.concatenate([np.stack([a, d, b], -1).reshape(-1, 3), np.stack([b, d, c], -1).reshape(-1, 3)])
    return vertices, faces


def gem(sides: int) -> tuple[np.ndarray, np.ndarray]:
    """A faceted gem: a ``sides``-gon girdle, a flat table on top and a pointed pavilion below."""
    t = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    girdle = np.stack([np.cos(t), np.zeros(sides), np.sin(t)], 1)
    table = np.stack([0.6 * np.cos(t + np.pi / sides), np.full(sides, 0.45), 0.6 * np.sin(t + np.pi / sides)], 1)
    vertices = np.concatenate([girdle, table, [[0.0, 0.45, 0.0], [0.0, -1.1, 0.0]]])
    k, k1 = np.arange(sides), (np.arange(sides) + 1) % sides
    top, bottom = 2 * sides, 2 * sides + 1
    faces = np.concatenate([
        np.stack([k, sides + k, k1], 1),  # crown: girdle edge up to the table
        np.stack([k1, sides + k, sides + k1], 1),
        np.stack([sides + k, np.full(sides, top), sides + k1], 1),  # table
        np.stack([k, k1, np.full(sides, bottom)], 1),  # pavilion
    ])
    return vertices, faces


SCENE = """<scene version="3.0.0">
    <!-- written by samples/make_scene.py -->
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="38"/>
        <transform name="to_world"><lookat origin="0.3, 3.2, 7.5" target="0, 0.35, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="64"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="512"/><integer name="height" value="512"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.15"/></emitter>
    <shape type="rectangle" id="light">
        <transform name="to_world"><rotate x="1" angle="90"/><scale value="1.2"/><translate x="-2" y="5" z="2"/></transform>
        <emitter type="area"><rgb name="radiance" value="9"/></emitter>
    </shape>
    <shape type="rectangle" id="floor">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.55, 0.55, 0.5"/></bsdf>
    </shape>
    <shape type="ply" id="torus">
        <string name="filename" value="torus.ply"/>
        <transform name="to_world"><rotate x="1" angle="60"/><translate x="-1.2" y="0.95" z="0.2"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.75, 0.3, 0.2"/></bsdf>
    </shape>
    <shape type="ply" id="gem">
        <string name="filename" value="gem.ply"/>
        <boolean name="face_normals" value="true"/>
        <transform name="to_world"><scale value="0.7"/><rotate y="1" angle="20"/><translate x="1.5" y="0.74" z="-0.6"/></transform>
        <bsdf type="roughplastic"><rgb name="diffuse_reflectance" value="0.2, 0.35, 0.8"/></bsdf>
    </shape>
    <shape type="cube" id="box">
        <transform name="to_world"><scale value="0.45"/><rotate y="1" angle="35"/><translate x="0.5" y="0.3" z="1.3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.85, 0.8, 0.3"/></bsdf>
    </shape>
    <shape type="sphere" id="ball">
        <point name="center" x="-0.3" y="0.51" z="2.2"/><float name="radius" value="0.5"/>
        <bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.25, 0.7, 0.35"/></bsdf>
    </shape>
    <shape type="cylinder" id="pipe">
        <point name="p0" x="2.1" y="0.41" z="1.4"/><point name="p1" x="1.3" y="0.41" z="2.1"/>
        <float name="radius" value="0.4"/>
        <bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.7, 0.75"/></bsdf></bsdf>
    </shape>
</scene>
"""


def main() -> None:
    HERE.mkdir(exist_ok=True)
    write_ply(HERE / "torus.ply", *torus(0.8, 0.3, 64, 24))
    write_ply(HERE / "gem.ply", *gem(10))
    (HERE / "scene.xml").write_text(SCENE)


if __name__ == "__main__":
    main()
