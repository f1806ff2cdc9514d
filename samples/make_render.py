"""Render the sample 3D scene with Mitsuba 3: ``python samples/make_render.py [--spp N] [-o FILE]``.

Writes ``samples/scene/render.exr`` (the film's 512 × 512, float RGB, linear, box pixel filter as ``dfc bench``'s
references), the image ``dfc curves`` and ``dfc encode`` take in the README's walkthrough. Needs the render extra
(``pip install 'dfc[render]'``); run ``samples/make_scene.py`` first if ``samples/scene/`` is missing. The default
1024 samples per pixel take about 3 minutes on two cores.
"""

import argparse
import time
from pathlib import Path

from dfc.io.image import write_exr
from dfc.io.mitsuba import Camera, load_scene, perspective_sensor, render_window, rfilter_plugin

SCENE = Path(__file__).parent / "scene" / "scene.xml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=1024, help="samples per pixel (default 1024)")
    parser.add_argument("-o", "--output", default=str(SCENE.parent / "render.exr"))
    parser.add_argument("--filter", default="box", help="pixel filter: box (default) or gaussian[:STDDEV], tent, "
                        "mitchell (dfc encode --pixel-filter finds it again)")
    args = parser.parse_args()
    clock = time.perf_counter()
    scene = load_scene(SCENE)
    width, height = Camera.from_sensor(perspective_sensor(scene)).size
    image = render_window(scene, (0, 0, width, height), width, height, args.spp, rfilter=rfilter_plugin(args.filter))
    write_exr(args.output, image, ["R", "G", "B"], half=False)
    print(f"wrote {args.output} ({width}x{height}, {args.spp} spp, pixel filter {args.filter}, "
          f"{time.perf_counter() - clock:.0f} s)")


if __name__ == "__main__":
    main()
