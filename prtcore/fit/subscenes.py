"""Sub-scenes of the learnt transfer (thesis 4.1.5): a scene too large for one small
network is cut by a regular grid into cells, one network each; each network is trained
on the samples inside its cell grown by a band δ into the neighbours (``overlap``, a
share of the cell's size), so that on either side of a cell boundary both networks were
trained and the seam does not show. A point is shaded by the network of the cell it lies
in (:meth:`Grid.cell_of`; the GLSL does the same).

One cell (the default) is the plain thesis network: the same training rows, scaling and
seed as :func:`prtcore.fit.learnt_sh.fit_learnt_sh`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Scene
from prtcore.core.sdf import SdfScene
from prtcore.fit.learnt_sh import (
    LearntSh,
    evaluate,
    read_network,
    train_model,
    training_set,
    write_network,
)

#: a cell with fewer training samples than this gets a network that gives 0
MIN_CELL_SAMPLES = 16


@dataclass(frozen=True, eq=False)
class Grid:
    """A regular grid of ``cells`` (nx, ny, nz) over the box lo (3,) – hi (3,) float64;
    ``overlap`` δ: each cell's training box grows by δ × its size on every side."""

    cells: tuple[int, int, int]
    lo: np.ndarray
    hi: np.ndarray
    overlap: float

    @property
    def count(self) -> int:
        return int(np.prod(self.cells))

    def cell_of(self, p: np.ndarray) -> np.ndarray:
        """The cell index (n,) int64 (x fastest, then y, then z) of points (n, 3); points
        outside the box belong to the nearest cell."""
        n = np.asarray(self.cells)
        c = np.floor((np.asarray(p, np.float64) - self.lo) / (self.hi - self.lo) * n)
        c = np.clip(c, 0, n - 1).astype(np.int64)
        return c[:, 0] + n[0] * (c[:, 1] + n[1] * c[:, 2])

    def training_box(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Cell ``k``'s box grown by the overlap band: (lo (3,), hi (3,))."""
        n = np.asarray(self.cells)
        idx = np.array([k % n[0], (k // n[0]) % n[1], k // (n[0] * n[1])])
        size = (self.hi - self.lo) / n
        lo = self.lo + idx * size
        return lo - self.overlap * size, lo + size + self.overlap * size

    def to_dict(self) -> dict:
        return {"cells": list(self.cells), "lo": [float(v) for v in self.lo],
                "hi": [float(v) for v in self.hi], "overlap": self.overlap,
                "cell_index": "x + nx * (y + ny * z), (x, y, z) = clamp(floor((p - lo) / "
                              "(hi - lo) * cells), 0, cells - 1)"}


@dataclass(frozen=True, eq=False)
class LearntShScenes:
    """The learnt transfer of a scene: a grid and one network per cell (all of one
    size)."""

    grid: Grid
    models: tuple[LearntSh, ...]

    @property
    def bands(self) -> int:
        return self.models[0].bands

    @property
    def glossy(self) -> bool:
        return self.models[0].glossy

    @property
    def net(self):
        """The first cell's network (the sizes every cell shares)."""
        return self.models[0].net

    @property
    def diagnostics(self) -> dict:
        """Training figures: the cells' held-out MSE pooled by their held-out samples."""
        d = [m.diagnostics for m in self.models if m.diagnostics.get("holdout_samples")]
        n = sum(x["holdout_samples"] for x in d) or 1
        first = self.models[0].diagnostics
        return {**{k: v for k, v in first.items() if k not in ("rows", "train_seed")},
                "cells": self.grid.count,
                "holdout_mse": sum(x["holdout_mse"] * x["holdout_samples"] for x in d) / n,
                "holdout_mse_zero": sum(x["holdout_mse_zero"] * x["holdout_samples"]
                                        for x in d) / n,
                "holdout_samples": n,
                "seconds_training": sum(x.get("seconds_training", 0.0) for x in d),
                "rows_per_cell": [m.diagnostics.get("rows", 0) for m in self.models]}


def single(model: LearntSh) -> LearntShScenes:
    """One network as a one-cell :class:`LearntShScenes` (its box: the network's
    bounding sphere's cube)."""
    c, r = np.asarray(model.centre, np.float64), float(model.radius)
    return LearntShScenes(Grid((1, 1, 1), c - r, c + r, 0.0), (model,))


def evaluate_scenes(model: LearntShScenes, position: np.ndarray, normal: np.ndarray
                    ) -> np.ndarray:
    """Each point's outputs from its cell's network: (n, outputs) float64."""
    position = np.asarray(position, np.float64)
    cell = model.grid.cell_of(position)
    out = np.zeros((len(position), model.net.outputs))
    for k in np.unique(cell):
        rows = np.flatnonzero(cell == k)
        out[rows] = evaluate(model.models[k], position[rows], normal[rows])
    return out


def _zero_like(model: LearntSh, centre: np.ndarray, radius: float) -> LearntSh:
    """A network of ``model``'s sizes whose output is 0 (a cell without surface)."""
    from prtcore.core.mlp import Mlp

    net = model.net
    return LearntSh(Mlp(tuple(np.zeros_like(w) for w in net.weights),
                        tuple(np.zeros_like(b) for b in net.biases), net.slope, net.output),
                    centre, radius, model.scale, model.bands, model.position_frequencies,
                    model.normal_frequencies, {"rows": 0})


def fit_scenes(scene: Scene, tracer: RayTracer, *, cells: tuple[int, int, int] = (1, 1, 1),
               overlap: float = 0.1, samples: int = 20000, bands: int = 4, strata: int = 8,
               width: int = 64, layers: int = 4, steps: int = 3000, batch: int = 1024,
               seed: int = 0, glossy: bool = False, sdf: SdfScene | None = None
               ) -> LearntShScenes:
    """The scene's transfer as one network per grid cell (module docstring): the
    training set traced once (``samples`` in all), each cell's network trained on the
    samples in its grown box, scaled to that box (centre, half diagonal), seeded by
    ``seed`` + the cell index. One cell: exactly :func:`fit_learnt_sh`'s network."""
    data = training_set(scene, tracer, samples=samples, bands=bands, strata=strata,
                        seed=seed, glossy=glossy, sdf=sdf)
    kw = {"width": width, "layers": layers, "steps": steps, "batch": batch}
    if tuple(cells) == (1, 1, 1):
        model = train_model(data, np.arange(samples), np.asarray(scene.center, np.float64),
                            float(scene.radius) or 1.0, seed=seed, **kw)
        return single(model)
    lo, hi = (np.asarray(v, np.float64) for v in
              (data.position.min(axis=0), data.position.max(axis=0)))
    pad = 1e-6 * float(np.linalg.norm(hi - lo))
    grid = Grid(tuple(int(c) for c in cells), lo - pad, hi + pad, float(overlap))
    models: list[LearntSh | None] = []
    for k in range(grid.count):
        blo, bhi = grid.training_box(k)
        rows = np.flatnonzero(((data.position >= blo) & (data.position <= bhi)).all(axis=1))
        centre, radius = (blo + bhi) / 2, float(np.linalg.norm(bhi - blo) / 2)
        if len(rows) < MIN_CELL_SAMPLES:
            models.append(None)
            continue
        models.append(train_model(data, rows, centre, radius, seed=seed + k,
                                  desc=f"learnt SH cell {k + 1}/{grid.count}", **kw))
    template = next(m for m in models if m is not None)
    filled = []
    for k, m in enumerate(models):
        if m is None:
            blo, bhi = grid.training_box(k)
            m = _zero_like(template, (blo + bhi) / 2, float(np.linalg.norm(bhi - blo) / 2))
        filled.append(m)
    return LearntShScenes(grid, tuple(filled))


def network_file(k: int) -> str:
    """The raw file of cell ``k``'s network in a bundle."""
    return f"learnt_sh_net_{k}.bin"


def write_scenes(directory: Path, model: LearntShScenes) -> dict:
    """Write every cell's network (:func:`prtcore.fit.learnt_sh.write_network`) and return
    the manifest's ``networks`` description: {"grid", "networks": [...]}."""
    return {"grid": model.grid.to_dict(),
            "networks": [write_network(directory, m, network_file(k))
                         for k, m in enumerate(model.models)]}


def read_scenes(directory: Path, desc: dict) -> LearntShScenes:
    """The grid and networks a manifest's ``networks`` description names."""
    g = desc["grid"]
    grid = Grid(tuple(int(c) for c in g["cells"]), np.asarray(g["lo"], np.float64),
                np.asarray(g["hi"], np.float64), float(g["overlap"]))
    models = tuple(read_network(directory, d) for d in desc["networks"])
    if len(models) != grid.count:
        from prtcore.core.errors import BundleError

        raise BundleError(f"{directory}: learnt_sh.networks has {len(models)} networks for "
                          f"{grid.count} grid cells")
    return LearntShScenes(grid, models)
