"""Render the sample 3D scene with Mitsuba 3: ``python samples/make_render.py [--spp N] [-o FILE]``.

Writes ``samples/scene/render.exr`` (1024 × 1024, float RGB, linear), the image ``dfc curves`` and ``dfc encode``
take in the README's walkthrough. Needs the render extra (``pip install 'dfc[render]'``); run
``samples/make_scene.py`` first if ``samples/scene/`` is missing. 256 samples per pixel take a few minutes on two
cores.
"""

import argparse
import time
from pathlib import Path

from dfc.io.image import write_exr
from dfc.io.mitsuba import render_window

SCENE = Path(__file__).parent / "scene" / "scene.xml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=256, help="samples per pixel (default 256)")
    parser.add_argument("-o", "--output", default=str(SCENE.parent / "render.exr"))
    args = parser.parse_args()
    clock = time.perf_counter()
    image = render_window(SCENE, (0, 0, 1024, 1024), 1024, 1024, args.spp)
    write_exr(args.output, image, ["R", "G", "B"], half=False)
    print(f"wrote {args.output} ({args.spp} spp, {time.perf_counter() - clock:.0f} s)")


if __name__ == "__main__":
    main()
