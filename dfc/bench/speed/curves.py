"""``dfc benchmark curves``: a hairball of about a million triangles -> visible curves, timed per stage.

The scene is made here: ``--tubes`` thin open tubes (``--sides``-gon cross sections, ``--segments`` rings along
each) following random smooth paths inside the unit ball, written as one PLY mesh in a temporary directory and seen
by a 1024 × 1024 perspective camera (``--size``). The default 400 × 80 × 16 × 2 is 1,024,000 triangles. The
strands pass through each other, but as one mesh (a hair model is one), so the intersection stage, which looks for
crossings between different meshes, has nothing to trace; most samples are hidden, which the depth bound settles.
Stage times are wall-clock; ``cpu`` is the processor time of all the process's threads.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import click
import numpy as np

from ...io.atomic import write_bytes_atomic

_SCENE = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 3.4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="{size}"/><integer name="height" value="{size}"/></film>
    </sensor>
    <shape type="ply"><string name="filename" value="hairball.ply"/></shape>
</scene>
"""


def hairball(tubes: int, segments: int, sides: int, radius: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (tubes (segments + 1) sides, 3) float64 and faces (2 tubes segments sides, 3) int64 of open tubes
    of ``radius`` around random smooth paths (a few random sine waves per axis) inside the unit ball."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, segments + 1)
    waves = 3
    freq = rng.uniform(0.5, 2.0, (tubes, 3, waves))
    phase = rng.uniform(0, 2 * np.pi, (tubes, 3, waves))
    amp = rng.uniform(0.2, 0.5, (tubes, 3, waves))
    path = (amp[..., None] * np.sin(2 * np.pi * freq[..., None] * s + phase[..., None])).sum(axis=2)  # (T, 3, S+1)
    path = path.transpose(0, 2, 1)
    path /= np.maximum(1.0, np.linalg.norm(path, axis=2, keepdims=True).max(axis=1, keepdims=True))
    tangent = np.gradient(path, axis=1)
    tangent /= np.linalg.norm(tangent, axis=2, keepdims=True)
    # rotation-minimising frames: carry the first normal along by projecting out the tangent at each ring
    normal = np.empty_like(path)
    first = np.cross(tangent[:, 0], rng.normal(size=(tubes, 3)))
    normal[:, 0] = first / np.linalg.norm(first, axis=1, keepdims=True)
    for k in range(1, segments + 1):
        n = normal[:, k - 1] - np.einsum("ij,ij->i", normal[:, k - 1], tangent[:, k])[:, None] * tangent[:, k]
        normal[:, k] = n / np.linalg.norm(n, axis=1, keepdims=True)
    binormal = np.cross(tangent, normal)
    angle = 2 * np.pi * np.arange(sides) / sides
    ring = np.cos(angle)[:, None] * normal[:, :, None] + np.sin(angle)[:, None] * binormal[:, :, None]
    vertices = (path[:, :, None] + radius * ring).reshape(-1, 3)
    t, k, j = np.meshgrid(np.arange(tubes), np.arange(segments), np.arange(sides), indexing="ij")
    a = (t * (segments + 1) + k) * sides + j
    b = (t * (segments + 1) + k) * sides + (j + 1) % sides
    c, d = a + sides, b + sides
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return vertices, faces


@click.command()
@click.option("--tubes", type=click.IntRange(1), default=400, show_default=True, help="Number of tubes.")
@click.option("--segments", type=click.IntRange(1), default=80, show_default=True, help="Rings along each tube.")
@click.option("--sides", type=click.IntRange(3), default=16, show_default=True, help="Sides of each tube.")
@click.option("--radius", type=click.FloatRange(0, min_open=True), default=0.008, show_default=True,
              help="Tube radius (the hairball fits in the unit ball).")
@click.option("--size", type=click.IntRange(16, 8192), default=1024, show_default=True, help="Film width = height.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed of the tube paths.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Also write the figures to this JSON file.")
def command(tubes, segments, sides, radius, size, seed, json_path) -> None:
    """Extract the curves of a generated hairball scene and time each stage (dfc.geometry.sources.scene)."""
    from ...geometry.sources.scene import read_scene
    from ...io.mitsuba import write_ply

    clock, cpu = time.perf_counter(), time.process_time()
    vertices, faces = hairball(tubes, segments, sides, radius, seed)
    with tempfile.TemporaryDirectory() as tmp:
        write_ply(Path(tmp) / "hairball.ply", vertices, faces)
        (Path(tmp) / "scene.xml").write_text(_SCENE.format(size=size))
        generate = time.perf_counter() - clock
        stats: dict = {"generate_s": generate}
        read_scene(Path(tmp) / "scene.xml", stats=stats)
    stats["cpu_s"] = time.process_time() - cpu  # all threads of this process, generation included
    for key, value in stats.items():
        if key.endswith("_s"):
            click.echo(f"{key[:-2]:>22}: {value:8.2f} s" + (" (processor time)" if key == "cpu_s" else ""))
        else:
            click.echo(f"{key.replace('_', ' '):>22}: {value:8d}")
    if json_path:
        write_bytes_atomic(json_path, (json.dumps(stats, indent=2) + "\n").encode())
