"""Regenerate the README's picture of curves found in an image: ``python samples/make_curves_preview.py EXR``.

EXR is ``SquaresSwirls.exr`` of the OpenEXR project's test images (BSD-3-Clause, Industrial Light & Magic).
Writes ``curves_preview.png``: the curves ``dfc curves`` finds (default settings) in the window x 80..620,
y 80..420 of the image, each curve in its own colour over the image (tone-mapped), piece ends as dots.
"""

import sys
from pathlib import Path

from dfc.io.preview import draw_curves
from dfc.geometry.sources.raster import image_curves
from dfc.io.image import read_image

HERE = Path(__file__).parent
WINDOW = (80, 80, 620, 420)  # x0, y0, x1, y1 in pixels

if __name__ == "__main__":
    image = read_image(sys.argv[1])
    x0, y0, x1, y1 = WINDOW
    pixels = image.pixels[y0:y1, x0:x1]
    curves = image_curves(pixels)
    draw_curves(curves, HERE / "curves_preview.png", background=pixels, hdr=image.hdr, size=800)
    print(f"{curves.n_curves} curves, {len(curves)} pieces: wrote {HERE / 'curves_preview.png'}")
