"""Regenerate the shipped sample: ``python samples/make_sample.py`` (from the repository root).

Writes ``sample.exr`` (256 × 256, half-float RGB, each pixel the 4 × 4 box-filtered exact value) and
``sample.json`` (its curves: a closed chain of four cubics, a triangle of lines, a quadratic arch on
the border and an open cubic stroke whose jump ends inside the image), from ``dfc.bench.scenes.sample_scene``.
"""

from pathlib import Path

from dfc.bench.scenes import sample_scene
from dfc.geometry.sources.jsonfile import write_json
from dfc.io.image import write_exr

HERE = Path(__file__).parent


def main() -> None:
    scene = sample_scene()
    w, h = int(scene.domain[2]), int(scene.domain[3])
    write_exr(HERE / "sample.exr", scene.render(w, h, spp=4), scene.channels, half=True)
    write_json(scene.curves, HERE / "sample.json")


if __name__ == "__main__":
    main()
