"""What a tile server shows: a ``.dfield`` file (``FieldSource``: tiles rendered by ``dfc.tiles.render_tile``, values
at points, the curves) and an input raster to compare it with (``RasterSource``: the raster upsampled bicubically
onto the same tile grid). Both answer ``pixels(region, size)`` with (h, w, C) linear float32 values."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..tiles import LEVELS_BEYOND, TileGrid, default_time, render_tile, tile_grid

__all__ = ["FieldSource", "RasterSource", "identifiers"]


class FieldSource:
    """A loaded ``.dfield`` file: the model (loaded once, its point-location grid built once) and its tile grid;
    a time-varying file is shown at its first time (``dfc.tiles.default_time``).

    ident : the identifier in URLs; path : the file; levels_beyond : ``dfc.tiles.tile_grid``'s depth
    Raises ``InputError`` naming ``path`` when it is not a readable ``.dfield`` file.
    """

    def __init__(self, ident: str, path, *, levels_beyond: int = LEVELS_BEYOND):
        from ..codec import load
        from ..errors import DfcError, InputError
        from ..render_file import is_hdr

        self.ident, self.name = ident, Path(path).name
        try:
            self.model = load(path)
        except DfcError as e:  # several files may be served: name the one that failed
            raise InputError(f"{path}: {e}") from None
        self.grid: TileGrid = tile_grid(self.model, levels_beyond)
        self.hdr = is_hdr(self.model)
        self.channels = list(self.model.channels)

    def pixels(self, region, size) -> np.ndarray:
        """(h, w, C) float32: ``region`` (x, y, w, h grid pixels) rendered at ``size`` (w, h)."""
        return render_tile(self.model, region, size, grid=self.grid)

    def value(self, x: float, y: float) -> list[float]:
        """The decoded value (C channels) at the domain point (x, y); points outside take the nearest border's."""
        import torch

        t = default_time(self.model)
        xy = torch.tensor([[x, y]], dtype=torch.float64, device=self.model.field.bank.device)
        with torch.no_grad():
            values = self.model(xy) if t is None else self.model(xy, t)
        return [float(v) for v in values[0]]

    def curves(self) -> dict:
        """The file's discontinuities in domain units: ``segments`` [[x0, y0, x1, y1], …] (straight edges) and
        ``cubics`` [[x0, y0, …, x3, y3], …] (Bézier control points of curved pieces)."""
        mesh = self.model.field.mesh
        v = mesh.vertices
        segments = np.concatenate([v[mesh.disc_edges[:, 0]], v[mesh.disc_edges[:, 1]]], axis=1)
        cubics = np.asarray(mesh.curve_control_points, dtype=np.float64).reshape(-1, 8)
        return {"domain": list(mesh.domain), "segments": segments.round(6).tolist(), "cubics": cubics.round(6).tolist()}


class RasterSource:
    """An image (EXR, PNG or JPEG; ``dfc.io.image.read_image``) stretched over ``like``'s domain and shown on its tile
    grid, sampled bicubically at the output pixels' centres (values beyond the border repeat it), as the README's
    comparison figure samples it. Reads the whole image into memory."""

    def __init__(self, ident: str, path, like: FieldSource):
        from ..io.image import read_image

        image = read_image(path)
        self.ident, self.name = ident, Path(path).name
        self.pixels_in = np.ascontiguousarray(image.pixels, dtype=np.float32)
        self.grid, self.hdr, self.channels = like.grid, like.hdr, list(image.channels)

    def pixels(self, region, size) -> np.ndarray:
        """(h, w, C) float32: bicubic samples of the raster at the centres of ``size`` pixels over ``region``."""
        import torch
        import torch.nn.functional as nnf

        x, y, w, h = (float(v) for v in region)
        ow, oh = size
        u = (x + (np.arange(ow) + 0.5) * w / ow) / self.grid.width  # fraction of the image, 0..1
        v = (y + (np.arange(oh) + 0.5) * h / oh) / self.grid.height
        gx, gy = np.meshgrid(2 * u - 1, 2 * v - 1)  # align_corners=False: the image's edges at ±1
        grid = torch.from_numpy(np.stack([gx, gy], -1)[None]).float()
        src = torch.from_numpy(self.pixels_in).permute(2, 0, 1)[None]
        with torch.no_grad():
            out = nnf.grid_sample(src, grid, mode="bicubic", padding_mode="border", align_corners=False)
        return out[0].permute(1, 2, 0).numpy()


def identifiers(paths) -> list[str]:
    """URL-safe identifiers of ``paths``: each file's stem (letters, digits, ``-``, ``_``, ``.``), numbered when two
    agree (``sample``, ``sample-2``)."""
    out: list[str] = []
    for p in paths:
        stem = re.sub(r"[^A-Za-z0-9_.-]+", "-", Path(p).stem).strip("-.") or "file"
        ident, k = stem, 2
        while ident in out:
            ident, k = f"{stem}-{k}", k + 1
        out.append(ident)
    return out
