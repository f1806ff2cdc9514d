"""Write a Helmholtz FEM solution with a sound-hard barrier: ``helmholtz.vtu`` and its barrier ``helmholtz.json``.

    python samples/make_helmholtz.py [-o DIR] [--n 256] [--k 40] [--peak 1]

Solves ``−Δu − k² u = f`` on the unit square (y down) with scikit-fem, P1 elements on an ``n × n`` grid of
squares split into triangles:

- absorbing outer boundary, first-order Robin ``∂u/∂n − i k u = 0``;
- a point-like source, ``f`` a Gaussian of standard deviation ``SOURCE_SIGMA`` at ``SOURCE``;
- a sound-hard straight barrier ``BARRIER`` (zero Neumann on both faces): the nodes strictly inside the barrier
  segment are duplicated and the elements on its right take the copies, so the mesh is cut there and the
  solution is genuinely discontinuous across it.

The solution is complex; it is scaled so that max |u| = ``--peak`` (default 1; physical units are arbitrary, e.g.
``--n 160 --k 35 --peak 4e-4`` gives values of order 1e-4) and written as the two real point-data arrays
``p.re`` and ``p.im`` (VTK XML has no complex type; dfc reads the pair as the channels ``p.re``, ``p.im``, exactly
as it reads a complex array ``p`` in a ``meshio.Mesh``). Needs ``scikit-fem`` and ``meshio``
(``pip install -e '.[samples]'``). The default takes a few seconds and writes about 2.4 MB (``--n 512``: 9.7 MB, 30 s).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

SOURCE = (0.3, 0.5)
SOURCE_SIGMA = 0.01
BARRIER = ((0.5, 0.25), (0.5, 0.75))
"""The barrier segment: on grid lines for any ``n`` divisible by 4."""


def cut_mesh(n: int):
    """``skfem.MeshTri`` of the unit square (n × n squares, 2 triangles each) cut along ``BARRIER``."""
    from skfem import MeshTri

    if n % 4:
        raise SystemExit(f"--n must be divisible by 4 (the barrier lies on grid lines), got {n}")
    grid = np.linspace(0.0, 1.0, n + 1)
    mesh = MeshTri.init_tensor(grid, grid)
    p, t = mesh.p.copy(), mesh.t.copy()
    (bx, by0), (_, by1) = BARRIER
    on_cut = np.flatnonzero(np.isclose(p[0], bx) & (p[1] > by0 + 0.5 / n) & (p[1] < by1 - 0.5 / n))
    copy = np.full(p.shape[1], -1)
    copy[on_cut] = p.shape[1] + np.arange(len(on_cut))
    right = p[0, t].mean(axis=0) > bx
    moved = right[None, :] & (copy[t] >= 0)
    t[moved] = copy[t[moved]]
    return MeshTri(np.concatenate([p, p[:, on_cut]], axis=1), t)


def solve(n: int, k: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (V, 2), triangles (T, 3) and the complex nodal solution (V,) scaled to max |u| = 1."""
    from scipy.sparse.linalg import spsolve
    from skfem import Basis, BilinearForm, ElementTriP1, FacetBasis, LinearForm
    from skfem.helpers import dot, grad

    mesh = cut_mesh(n)
    basis = Basis(mesh, ElementTriP1())
    outer = mesh.facets_satisfying(lambda x: np.isclose(x[0], 0) | np.isclose(x[0], 1) | np.isclose(x[1], 0)
                                   | np.isclose(x[1], 1))
    fbasis = FacetBasis(mesh, ElementTriP1(), facets=outer)

    @BilinearForm
    def stiffness(u, v, w):
        return dot(grad(u), grad(v))

    @BilinearForm
    def mass(u, v, w):
        return u * v

    @LinearForm
    def source(v, w):
        r2 = (w.x[0] - SOURCE[0]) ** 2 + (w.x[1] - SOURCE[1]) ** 2
        return np.exp(-r2 / (2 * SOURCE_SIGMA**2)) / (2 * np.pi * SOURCE_SIGMA**2) * v

    A = stiffness.assemble(basis) - k**2 * mass.assemble(basis) - 1j * k * mass.assemble(fbasis)
    u = spsolve(A.tocsc(), source.assemble(basis).astype(complex))
    return mesh.p.T.copy(), mesh.t.T.copy(), u / np.abs(u).max()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--out", default=".", help="output directory")
    ap.add_argument("--n", type=int, default=256, help="grid squares per side (divisible by 4)")
    ap.add_argument("--k", type=float, default=40.0, help="wavenumber")
    ap.add_argument("--peak", type=float, default=1.0, help="max |u| of the written solution")
    args = ap.parse_args()
    import meshio

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    points, triangles, u = solve(args.n, args.k)
    u = u * args.peak
    mesh = meshio.Mesh(np.c_[points, np.zeros(len(points))], [("triangle", triangles)],
                       point_data={"p.re": u.real, "p.im": u.imag})
    meshio.write(out / "helmholtz.vtu", mesh, binary=True)
    (a, b) = BARRIER
    curves = {"format": "dfc-curves/1", "domain": [0.0, 0.0, 1.0, 1.0],
              "curves": [{"name": "barrier", "pieces": [{"type": "line", "points": [list(a), list(b)]}]}]}
    (out / "helmholtz.json").write_text(json.dumps(curves, indent=1) + "\n")
    print(f"wrote {out / 'helmholtz.vtu'} ({len(points)} nodes, {len(triangles)} triangles) and "
          f"{out / 'helmholtz.json'}")


if __name__ == "__main__":
    main()
