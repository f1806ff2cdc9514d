"""Write a 2D wave sequence diffracted by a slit barrier: ``wave.npz`` (frames, times) and its curves ``wave.json``.

    python samples/make_wave.py [-o DIR] [--size 256] [--frames 32] [--slits 3]

Solves ``u_tt = c² Δu`` (c = 1 pixel per time unit) by finite differences on the pixel centres of a
``size × size`` grid (domain [0, size]², y down, as for an image), leapfrog in time with dt = 0.5:

- a point source at (size / 2, size / 4) oscillating with a period of ``WAVELENGTH`` time units (so the
  wavelength is ``WAVELENGTH`` pixels), switched on smoothly;
- a sound-hard barrier along the pixel boundary y = size / 2 across the whole width, open only at ``--slits``
  evenly spaced slits of ``SLIT_WIDTH`` pixels: the stencil does not couple the rows on its two sides, so the
  field is discontinuous across it and diffracts through the slits (the setting of the paper's Fig. 13);
- an absorbing sponge ``SPONGE`` pixels wide along the outer border.

Frames are recorded at ``--frames`` evenly spaced times once the wave has crossed the barrier, scaled so that
max |u| = 1, and written uncompressed (``spec/samples.md``, "Frame sequences"); the curves file holds the wall
pieces between the slits. The default runs in a few seconds and writes about 8 MB.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

WAVELENGTH = 24.0
SLIT_WIDTH = 8
SPONGE = 24
DT = 0.5


def wall_pieces(size: int, slits: int) -> list[tuple[float, float]]:
    """x-intervals of the wall on the line y = size / 2 (the gaps between them are the slits)."""
    centres = (np.arange(slits) + 0.5) * size / slits
    edges = [0.0] + [v for c in centres for v in (round(c - SLIT_WIDTH / 2), round(c + SLIT_WIDTH / 2))] + [size]
    return [(float(a), float(b)) for a, b in zip(edges[::2], edges[1::2])]


def simulate(size: int, n_frames: int, slits: int) -> tuple[np.ndarray, np.ndarray]:
    """Frames (T, size, size) float32 and their times (T,) float64."""
    wall_row = size // 2
    # coupling of each vertical pixel pair (row j, row j + 1): 0 across the wall, except at the slits
    cy = np.ones((size - 1, size))
    x = np.arange(size) + 0.5
    for a, b in wall_pieces(size, slits):
        cy[wall_row - 1, (x > a) & (x < b)] = 0.0
    d = np.minimum.reduce([np.arange(size), np.arange(size)[::-1]]).astype(np.float64)
    ramp = np.clip((SPONGE - d) / SPONGE, 0.0, 1.0)
    damping = 1.0 - 0.1 * np.maximum(ramp[:, None], ramp[None, :]) ** 2
    sx, sy = size // 2, size // 4
    omega = 2.0 * np.pi / WAVELENGTH
    t_start, t_end = 1.1 * (size / 2), 1.1 * (size / 2) + 2.0 * size / 2
    times = np.linspace(t_start, t_end, n_frames)
    record = np.round(times / DT).astype(int)
    u_prev, u = np.zeros((size, size)), np.zeros((size, size))
    frames = []
    for step in range(record[-1] + 1):
        lap = np.zeros_like(u)
        dxu = np.diff(u, axis=1)  # zero-flux outer border
        lap[:, :-1] += dxu
        lap[:, 1:] -= dxu
        dyu = cy * np.diff(u, axis=0)
        lap[:-1] += dyu
        lap[1:] -= dyu
        t = step * DT
        u_next = 2.0 * u - u_prev + DT**2 * lap
        u_next[sy, sx] += DT**2 * np.sin(omega * t) * min(1.0, t / WAVELENGTH)
        u_prev, u = u * damping, u_next * damping
        if step in record:
            frames.append(u.astype(np.float32))
    frames = np.stack(frames)
    return frames / np.abs(frames).max(), record * DT


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--out", default=".", help="output directory")
    ap.add_argument("--size", type=int, default=256, help="pixels per side (even)")
    ap.add_argument("--frames", type=int, default=32, help="frames recorded")
    ap.add_argument("--slits", type=int, default=3, help="slits in the barrier")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames, times = simulate(args.size, args.frames, args.slits)
    np.savez(out / "wave.npz", frames=frames[..., None], times=times, channels=np.array(["u"]))
    y = args.size / 2
    walls = [{"name": f"wall {i}", "pieces": [{"type": "line", "points": [[a, y], [b, y]]}]}
             for i, (a, b) in enumerate(wall_pieces(args.size, args.slits))]
    curves = {"format": "dfc-curves/1", "domain": [0.0, 0.0, float(args.size), float(args.size)], "curves": walls}
    (out / "wave.json").write_text(json.dumps(curves, indent=1) + "\n")
    print(f"wrote {out / 'wave.npz'} ({len(frames)} frames of {args.size}x{args.size}) and {out / 'wave.json'}")


if __name__ == "__main__":
    main()
