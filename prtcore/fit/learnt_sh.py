"""Learnt SH transfer (thesis ch. 4, issue 18): an MLP σ(p, n̂) → the L² SH coefficients
of the shadowed diffuse transfer at a surface point, so that geometry without vertices or
UVs to store transfer in can still be shaded with PRT.

* **Training data.** Area-uniform surface samples (Turk's square-root rule:
  :func:`prtcore.intake.points.sample_surface`), their shadowed transfer ray-traced with
  :func:`prtcore.transport.sh_transfer.shadowed_transfer` at unit albedo (the runtime
  multiplies by the material's albedo): visibility × clamped cosine / π projected on SH.
* **Network.** Inputs: the position scaled to the scene's bounding sphere (centre 0,
  radius 1) and the shading normal, each through :func:`prtcore.core.mlp.positional_encoding`;
  ``layers`` hidden layers of ``width`` leaky-ReLU neurons; tanh on the output, scaled by
  ``scale`` (the largest |coefficient| of the training set × :data:`SCALE_MARGIN`) —
  thesis Fig. 4.2. Sizes k = 64, l = 4 and k = 128, l = 4 (:data:`SIZES`).
* **Glossy.** With ``glossy`` the network has 2 L² outputs: the diffuse transfer, then
  the SH of the visibility over the whole sphere
  (:func:`prtcore.transport.sh_transfer.visibility_transfer`), the stored vector the
  triple product multiplies by the light for a Phong lobe at runtime (the SH-PRT TP
  machinery, :func:`prtcore.methods.sh_prt.glossy_tp`). Each block has its own output
  scale (``scale`` (outputs,)).
* **Training.** :func:`prtcore.fit.train.train_network`: AdamW on seeded minibatches,
  deterministic; a seeded tenth of the samples is held back and its error reported.

SDF scenes (:mod:`prtcore.core.sdf`): the samples of the marching-cubes mesh are projected
onto the zero level set, with the field's gradient as normal. The method that writes the
network into a bundle is :mod:`prtcore.methods.learnt_sh`; its GLSL evaluation
:mod:`prtcore.runtime.learnt_sh`; sub-scenes (one network per grid cell)
:mod:`prtcore.fit.subscenes`. Samples avoid the vertices' neighbourhoods
(:data:`VERTEX_MARGIN`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prtcore.core.errors import BundleError
from prtcore.core.geometry import face_normals, shading_normals
from prtcore.core.materials import albedo_at, clamp_albedo
from prtcore.core.mlp import Mlp, forward, positional_encoding
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Scene
from prtcore.core.sdf import SdfScene
from prtcore.fit.train import train_network
from prtcore.intake.points import sample_surface
from prtcore.io.bundle import load_raw, raw_file
from prtcore.transport.sh_transfer import (
    SurfaceSamples,
    shadowed_transfer,
    visibility_transfer,
)

#: the thesis' network sizes: name → (neurons per layer k, hidden layers l)
SIZES = {"k64_l4": (64, 4), "k128_l4": (128, 4)}
#: positional-encoding frequencies of the position and of the normal
POSITION_FREQUENCIES = 6
NORMAL_FREQUENCIES = 2
#: the tanh output spans ± this × the largest training |coefficient|
SCALE_MARGIN = 1.1
#: share of the samples held back to report the error on
HOLDOUT_SHARE = 0.1
#: Samples avoid the vertices' neighbourhoods (thesis 4.1.2: shading normals and the
#: mesh's own tessellation are least like the surface there): the corner regions of each
#: triangle where one barycentric weight exceeds 1 − VERTEX_MARGIN (3·margin² of its area)
VERTEX_MARGIN = 0.05


@dataclass(frozen=True, eq=False)
class LearntSh:
    """A trained σ(p, n̂).

    net : the network (outputs L², or 2 L² with the visibility block, tanh); centre (3,),
    radius : the position's scaling; scale : (outputs,) float64 the outputs' scale;
    bands : L; position_frequencies, normal_frequencies : the encoding; diagnostics :
    training figures (JSON data)
    """

    net: Mlp
    centre: np.ndarray
    radius: float
    scale: np.ndarray
    bands: int
    position_frequencies: int
    normal_frequencies: int
    diagnostics: dict[str, Any]

    @property
    def glossy(self) -> bool:
        """The network also gives the visibility SH (the glossy layer's stored vector)."""
        return self.net.outputs == 2 * self.bands ** 2


def encode(position: np.ndarray, normal: np.ndarray, centre: np.ndarray, radius: float,
           position_frequencies: int, normal_frequencies: int) -> np.ndarray:
    """The network's input for points (n, 3) and unit normals (n, 3): (n, d) float64."""
    p = (np.asarray(position, np.float64) - centre) / radius
    return np.concatenate([positional_encoding(p, position_frequencies),
                           positional_encoding(normal, normal_frequencies)], axis=1)


def evaluate(model: LearntSh, position: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The network at points (n, 3) with unit normals (n, 3): (n, outputs) float64 — the
    diffuse transfer (:func:`transfer_of`), then with ``glossy`` the visibility SH
    (:func:`visibility_of`)."""
    x = encode(position, normal, model.centre, model.radius, model.position_frequencies,
               model.normal_frequencies)
    return np.asarray(model.scale, np.float64) * forward(model.net, x)


def transfer_of(model: LearntSh, outputs: np.ndarray) -> np.ndarray:
    """The diffuse transfer block (n, L²) of :func:`evaluate`'s outputs."""
    return outputs[:, :model.bands ** 2]


def visibility_of(model: LearntSh, outputs: np.ndarray) -> np.ndarray:
    """The visibility block (n, L²) of :func:`evaluate`'s outputs (glossy networks)."""
    if not model.glossy:
        raise ValueError("learnt SH: the network has no visibility outputs (not glossy)")
    return outputs[:, model.bands ** 2:]


def area_samples(scene: Scene, count: int, seed: int,
                 vertex_margin: float = VERTEX_MARGIN) -> SurfaceSamples:
    """``count`` area-uniform surface samples with their shading and geometric normals and
    albedo (seeded), none in a vertex's neighbourhood (thesis 4.1.2): a sample whose
    barycentric weight of one corner exceeds 1 − ``vertex_margin`` is drawn again (from
    the same stream), so the rest of each triangle stays uniformly covered."""
    rng = np.random.default_rng(seed)
    tri, bary = sample_surface(scene, count, rng)
    for _ in range(64):  # each round keeps all but ~3·margin² of the redrawn ones
        near = np.flatnonzero(bary.max(axis=1) > 1.0 - vertex_margin)
        if not len(near):
            break
        tri[near], bary[near] = sample_surface(scene, len(near), rng)
    v = scene.positions[scene.faces[tri]]
    position = np.einsum("nk,nkj->nj", bary, v)
    gn = face_normals(scene, tri)
    return SurfaceSamples(position, shading_normals(scene, tri, bary, gn), gn,
                          albedo_at(scene, tri, bary))


def level_set_samples(scene: Scene, count: int, seed: int, sdf: SdfScene
                      ) -> tuple[SurfaceSamples, np.ndarray]:
    """Training samples of an SDF scene (``scene`` its marching-cubes mesh, thesis 4.1.3):
    area-uniform samples of the mesh, projected onto the field's zero level set. Returns
    the samples rays are traced from — on the mesh (so that no origin starts inside it,
    where the level set bulges inward between vertices) with the field's normal at the
    projected point as shading normal — and the projected points (count, 3), the network's
    input positions."""
    pts = area_samples(scene, count, seed)
    on_level_set = sdf.project(pts.position)
    return (SurfaceSamples(pts.position, sdf.normal(on_level_set), pts.geometric_normal,
                           pts.albedo), on_level_set)


def unit_albedo_transfer(scene: Scene, tracer: RayTracer, samples: SurfaceSamples,
                         bands: int, strata: int, seed: int) -> np.ndarray:
    """Shadowed diffuse transfer at unit albedo: (n, L²) float64."""
    ones = np.ones((samples.count, 3))
    rho, _ = clamp_albedo(ones)
    unit = SurfaceSamples(samples.position, samples.normal, samples.geometric_normal, ones)
    return shadowed_transfer(scene, tracer, unit, bands, strata, seed).coeffs[:, 0] / rho[:, :1]


def _holdout_mse(net: Mlp, x: np.ndarray, target: np.ndarray, scale: np.ndarray) -> float:
    """Mean squared error of the trained network on held-back rows, in target units."""
    return float(np.mean((scale * forward(net, x) - target) ** 2))


@dataclass(frozen=True, eq=False)
class TrainingSet:
    """The network's training data (:func:`training_set`).

    position : (n, 3) float64 the network's input positions (on the level set for SDFs);
    normal : (n, 3) unit shading normals; target : (n, outputs) float64 the ray-traced
    transfer (then the visibility SH with ``glossy``); scale : (outputs,) the tanh
    output's scale per output (SCALE_MARGIN × the largest |target| of its block);
    diagnostics : how it was made (JSON data)
    """

    position: np.ndarray
    normal: np.ndarray
    target: np.ndarray
    scale: np.ndarray
    bands: int
    diagnostics: dict[str, Any]


def training_set(scene: Scene, tracer: RayTracer, *, samples: int, bands: int, strata: int,
                 seed: int, glossy: bool = False, sdf: SdfScene | None = None
                 ) -> TrainingSet:
    """``samples`` area-uniform points (on an SDF's zero level set with ``sdf``,
    :func:`level_set_samples`), their unit-albedo transfer with ``strata²`` rays each,
    and with ``glossy`` their visibility SH."""
    t0 = time.perf_counter()
    if sdf is None:
        pts = area_samples(scene, samples, seed)
        position = pts.position
    else:
        pts, position = level_set_samples(scene, samples, seed, sdf)
    blocks = [unit_albedo_transfer(scene, tracer, pts, bands, strata, seed)]
    if glossy:
        blocks.append(visibility_transfer(tracer, pts, bands, strata, seed))
    scale = np.concatenate([np.full(b.shape[1], SCALE_MARGIN * float(np.abs(b).max()) or 1.0)
                            for b in blocks])
    return TrainingSet(position, pts.normal, np.concatenate(blocks, axis=1), scale, bands,
                       {"samples": samples, "strata": strata, "bands": bands, "seed": seed,
                        "glossy": glossy, "seconds_data": time.perf_counter() - t0})


def train_model(data: TrainingSet, rows: np.ndarray, centre: np.ndarray, radius: float, *,
                width: int, layers: int, steps: int, batch: int, seed: int,
                desc: str = "learnt SH") -> LearntSh:
    """Train σ on the training rows ``rows`` (int indices) of ``data``, positions scaled by
    ``centre`` (3,) and ``radius``: a seeded tenth held back and its error reported,
    ``steps`` AdamW steps on minibatches of ``batch`` (module docstring)."""
    t1 = time.perf_counter()
    rows = np.asarray(rows, np.int64)
    x = encode(data.position[rows], data.normal[rows], centre, radius,
               POSITION_FREQUENCIES, NORMAL_FREQUENCIES)
    target, scale = data.target[rows], data.scale
    perm = np.random.default_rng(seed).permutation(len(rows))
    n_hold = max(1, round(HOLDOUT_SHARE * len(rows)))
    hold, fit = np.sort(perm[:n_hold]), np.sort(perm[n_hold:])
    net, _ = train_network(x[fit], target[fit] / scale, (width,) * layers, steps, seed,
                           val=(x[hold], target[hold] / scale), desc=desc,
                           output="tanh", batch=batch)
    diag = {**data.diagnostics, "rows": len(rows), "width": width, "layers": layers,
            "steps": steps, "batch": batch, "train_seed": seed,
            "holdout_samples": int(n_hold),
            "holdout_mse": _holdout_mse(net, x[hold], target[hold], scale),
            "holdout_mse_zero": float(np.mean(target[hold] ** 2)),
            "seconds_training": time.perf_counter() - t1}
    return LearntSh(net, np.asarray(centre, np.float64), float(radius), scale, data.bands,
                    POSITION_FREQUENCIES, NORMAL_FREQUENCIES, diag)


def fit_learnt_sh(scene: Scene, tracer: RayTracer, *, samples: int = 20000, bands: int = 4,
                  strata: int = 8, width: int = 64, layers: int = 4, steps: int = 3000,
                  batch: int = 1024, seed: int = 0, glossy: bool = False,
                  sdf: SdfScene | None = None) -> LearntSh:
    """Train one σ(p, n̂) for the whole ``scene`` (module docstring): ``samples``
    area-uniform points, ``strata²`` rays each, ``steps`` AdamW steps on minibatches of
    ``batch``; ``glossy`` adds the visibility outputs; ``sdf``: the network's samples lie
    on its zero level set (:func:`level_set_samples`)."""
    data = training_set(scene, tracer, samples=samples, bands=bands, strata=strata,
                        seed=seed, glossy=glossy, sdf=sdf)
    return train_model(data, np.arange(samples), np.asarray(scene.center, np.float64),
                       float(scene.radius) or 1.0, width=width, layers=layers, steps=steps,
                       batch=batch, seed=seed)


# ---------------------------------------------------------------------------------------
# The network in a bundle (docs/learnt_sh.md)

def write_network(directory: Path, model: LearntSh, name: str) -> dict:
    """Write the network to ``directory``/``name`` (little-endian float32: per layer its
    weights (out, in) row-major, then its biases (out,)) and return its manifest
    description (shapes, offsets in floats, encoding, scales)."""
    values, layers, at = [], [], 0
    for w, b in zip(model.net.weights, model.net.biases, strict=True):
        layers.append({"inputs": int(w.shape[1]), "outputs": int(w.shape[0]),
                       "weights_offset": at, "bias_offset": at + w.size})
        values += [np.asarray(w).ravel(), np.asarray(b).ravel()]
        at += w.size + b.size
    desc = raw_file(directory / name, np.concatenate(values))
    return {**desc, "layers": layers, "hidden_activation": "leaky_relu",
            "slope": float(model.net.slope), "output_activation": model.net.output,
            "scale": [float(s) for s in np.broadcast_to(model.scale, (model.net.outputs,))],
            "centre": [float(c) for c in model.centre], "radius": float(model.radius),
            "bands": model.bands, "glossy": model.glossy,
            "position_frequencies": model.position_frequencies,
            "normal_frequencies": model.normal_frequencies,
            "encoding": "x = [e((p - centre) / radius, F_p), e(n, F_n)], e(v, F) = [v, "
                        "sin(2^k pi v) for k < F, cos(2^k pi v) for k < F] (each 3 wide, k "
                        "ascending); y = scale * tanh(W_L h + b_L), h = leaky_relu(W_j h + "
                        "b_j)"}


def read_network(directory: Path, desc: dict) -> LearntSh:
    """The network a manifest's network description (:func:`write_network`) names, in
    bundle ``directory``: float32 weights as stored, evaluated in float64."""
    flat = load_raw(directory, desc)
    weights, biases = [], []
    for k, layer in enumerate(desc["layers"]):
        n_in, n_out = int(layer["inputs"]), int(layer["outputs"])
        w0, b0 = int(layer["weights_offset"]), int(layer["bias_offset"])
        if b0 + n_out > flat.size or w0 + n_in * n_out > flat.size:
            raise BundleError(f"{directory}: {desc['file']}: layer {k} reaches past the "
                              f"file's {flat.size} values")
        weights.append(flat[w0:w0 + n_in * n_out].reshape(n_out, n_in))
        biases.append(flat[b0:b0 + n_out])
    net = Mlp(tuple(weights), tuple(biases), float(desc["slope"]), desc["output_activation"])
    return LearntSh(net, np.asarray(desc["centre"], np.float64), float(desc["radius"]),
                    np.asarray(desc["scale"], np.float64), int(desc["bands"]),
                    int(desc["position_frequencies"]), int(desc["normal_frequencies"]), {})
