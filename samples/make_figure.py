"""Regenerate the README picture: ``python samples/make_figure.py`` (from the repository root).

Encodes ``sample.exr`` with its curves (default settings) into ``sample.dfield`` unless that file exists, then
writes ``zoom_comparison.png``: a 100× zoom window at the triangle's corner (230, 60), left the input raster
upsampled bicubically, right the ``.dfield`` rendered at the window's own pixel centres.
"""

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as nnf
from PIL import Image as PILImage

from dfc.codec import EncodeSettings, encode_image, load
from dfc.geometry.sources import read_any
from dfc.io.image import linear_to_srgb, read_image

HERE = Path(__file__).parent
CENTRE, ZOOM, SIDE = (229.0, 60.5), 100.0, 384


def bicubic(pixels: np.ndarray, window, side: int) -> np.ndarray:
    """Bicubic samples (side, side, C) of a raster covering [0, W] x [0, H] at the window's pixel centres."""
    h, w, _ = pixels.shape
    x0, y0, x1, y1 = window
    u = x0 + (np.arange(side) + 0.5) * (x1 - x0) / side
    v = y0 + (np.arange(side) + 0.5) * (y1 - y0) / side
    gx, gy = np.meshgrid(2 * u / w - 1, 2 * v / h - 1)  # align_corners=False: pixel centres at +0.5
    grid = torch.from_numpy(np.stack([gx, gy], -1)[None]).float()
    src = torch.from_numpy(pixels).permute(2, 0, 1)[None]
    out = nnf.grid_sample(src, grid, mode="bicubic", padding_mode="border", align_corners=False)
    return out[0].permute(1, 2, 0).numpy()


def main() -> None:
    image = read_image(HERE / "sample.exr")
    path = HERE / "sample.dfield"
    if not path.exists():
        blob, report = encode_image(image, read_any(HERE / "sample.json"), EncodeSettings())
        path.write_bytes(blob)
        print(f"encoded {path.name}: {report.total_bytes} bytes, {report.psnr:.2f} dB")
    model = load(path)
    half = 256.0 / ZOOM / 2
    window = (CENTRE[0] - half, CENTRE[1] - half, CENTRE[0] + half, CENTRE[1] + half)
    left = bicubic(image.pixels, window, SIDE)
    right = model.render(SIDE, SIDE, window, spp=4)
    gap = np.ones((SIDE, 8, 3), np.float32)
    both = np.concatenate([left, gap, right], axis=1)
    PILImage.fromarray(np.rint(linear_to_srgb(both) * 255).astype(np.uint8)).save(HERE / "zoom_comparison.png")


if __name__ == "__main__":
    main()
