"""A coarse texel grid for the later bounces of the indirect solve (issue 20).

Multi-bounce light is smooth, so the solve need not iterate at full resolution: the
texels are grouped into cells of ``s × s`` atlas texels (:func:`coarsen_texels`), the
first bounce ``b`` (with its near-field correction) is restricted to the cells, all
bounces are solved there on a coarse operator, and one full-resolution product brings
them back: ``E ≈ b + A·P·(I − A_c)⁻¹·R·b`` (:func:`prtcore.transport.solve.solve_indirect`).
The full-resolution product is a gather, an integral over each texel's hemisphere, so the
cells' piecewise-constant prolongation ``P`` does not show: what reaches the result is its
integral, and its error is damped by the spectral radius of ``A`` once more.

The coarse operator ``A_c = G_c·diag(ρ_c)`` takes, per cell, the gather row of one
representative texel with its columns summed into cells (``G_c = S·G·P``; one Monte Carlo
estimate of the cell's gather from that texel's rays: the bounces it carries are 2 and
later, the noise is averaged by the fine product); ``ρ_c`` is the cell's mean albedo
weighted by coverage, as is the restriction ``R``.

Against the path tracer the grid costs nothing measurable: Duck.glb at 512² (auto: 4 × 4
cells), M = 64, a point light and a spot, reference 128 spp with its noise removed
(``tests/test_transport.py``'s ``compare``): 15.9 % / 5.22 % relative RMSE at full
resolution, 16.0 % / 5.24 % on the grid (bias −0.5 % / −0.2 % both), although the grid
differs from the full solve of the same system by 2.6 % (benchmarks/coarse_solve.py): on an
exterior object few gather rays hit anything (5 per texel), and the cells' means at the
hit points are another estimate of the same light, not a further error.

A cell holds only texels that are neighbours on the surface: texels of one atlas block
that lie within a few texel footprints of the block's first texel and face its way;
the others (chart borders, other charts sharing the block) are cells of their own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

#: A texel joins its block's cell if within this many block sizes (in world texel
#: footprints) of the block's first texel …
CELL_REACH = 1.5
#: … and its normal is within this cosine of the first texel's.
CELL_COS = 0.5
#: ``coarse_grid: "auto"``: cells of 1/AUTO_CELLS of the atlas side (the grid's error
#: follows the cells' size on the surface, not their texel count: 4 × 4 cells at 512² err
#: as 2 × 2 at 256², benchmarks/coarse_solve.py), at most MAX_FACTOR texels; none below
#: 2 × AUTO_CELLS texels.
AUTO_CELLS = 128
MAX_FACTOR = 8


def grid_factor(setting: int | str, width: int) -> int:
    """The cell side in texels for the spec's ``transport.coarse_grid`` on an atlas
    ``width`` texels wide."""
    if setting == "auto":
        return int(min(MAX_FACTOR, max(1, width // AUTO_CELLS)))
    return int(setting)


@dataclass(frozen=True)
class Coarsening:
    """Texels grouped into coarse cells.

    cell : (T,) int64 the cell of each texel, 0 … C − 1
    representative : (C,) int64 the texel whose gather row stands for the cell
    restriction : (C, T) CSR float32, rows summing to 1: the cell's coverage-weighted mean
    factor : the block size s in texels
    """

    cell: np.ndarray
    representative: np.ndarray
    restriction: sp.csr_matrix
    factor: int

    @property
    def cells(self) -> int:
        return len(self.representative)

    def restrict(self, x: np.ndarray) -> np.ndarray:
        """(T, ...) → (C, ...) float64 coverage-weighted cell means."""
        x2 = np.asarray(x).reshape(len(x), -1)
        return np.asarray(self.restriction @ x2, dtype=np.float64).reshape(
            (self.cells, *x.shape[1:]))

    def operator(self, matrix: sp.csr_matrix) -> sp.csr_matrix:
        """(C, C) float32 CSR: the representatives' rows of ``matrix`` (T, T) with their
        columns summed into cells."""
        rows = matrix[self.representative]
        g = sp.csr_matrix((rows.data.astype(np.float32), self.cell[rows.indices],
                           rows.indptr), shape=(self.cells, self.cells))
        g.sum_duplicates()
        return g


def coarsen_texels(xy: np.ndarray, position: np.ndarray, normal: np.ndarray,
                   footprint: np.ndarray, coverage: np.ndarray, factor: int
                   ) -> Coarsening | None:
    """Group texels into cells of ``factor × factor`` atlas texels.

    xy : (T, 2) int texel coordinates; position, normal : (T, 3) float64; footprint :
    (T, 2, 3) float64 world extent of one texel step in x and y; coverage : (T,) float
    (restriction weights). Returns None for factor ≤ 1 or no texels.
    """
    t = len(xy)
    if factor <= 1 or t == 0:
        return None
    xy = np.asarray(xy, dtype=np.int64)
    block = (xy[:, 1] // factor) * ((int(xy[:, 0].max()) // factor) + 1) + xy[:, 0] // factor
    order = np.argsort(block, kind="stable")
    sb = block[order]
    starts = np.flatnonzero(np.r_[True, sb[1:] != sb[:-1]])
    anchor = order[starts][np.searchsorted(sb[starts], block)]  # (T,) the block's first
    step = np.linalg.norm(np.asarray(footprint, dtype=np.float64), axis=2).max(axis=1)
    reach = CELL_REACH * factor * np.maximum(step, step[anchor])
    near = np.linalg.norm(position - position[anchor], axis=1) <= reach
    facing = np.einsum("ij,ij->i", normal, normal[anchor]) >= CELL_COS
    joins = near & facing
    key = np.where(joins, anchor, np.arange(t))  # a texel that does not join: its own cell
    _, first, cell = np.unique(key, return_index=True, return_inverse=True)
    cell = cell.reshape(-1).astype(np.int64)
    representative = np.asarray(key[first], dtype=np.int64)
    w = np.asarray(coverage, dtype=np.float64)
    wsum = np.bincount(cell, weights=w, minlength=len(first))
    r = sp.csr_matrix(((w / wsum[cell]).astype(np.float32), (cell, np.arange(t))),
                      shape=(len(first), t))
    return Coarsening(cell=cell, representative=representative, restriction=r,
                      factor=int(factor))
