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
* **Training.** :func:`prtcore.fit.train.train_network`: AdamW on seeded minibatches,
  deterministic; a seeded tenth of the samples is held back and its error reported.

What is not here yet (issue 18, said in its note): the bundle, the GLSL evaluation with
mat4 blocks, SDF input, sub-scene splitting, and avoiding vertex neighbourhoods when
sampling.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from prtcore.core.geometry import face_normals, shading_normals
from prtcore.core.materials import albedo_at, clamp_albedo
from prtcore.core.mlp import Mlp, forward, positional_encoding
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Scene
from prtcore.fit.train import train_network
from prtcore.intake.points import sample_surface
from prtcore.transport.sh_transfer import SurfaceSamples, shadowed_transfer

#: the thesis' network sizes: name → (neurons per layer k, hidden layers l)
SIZES = {"k64_l4": (64, 4), "k128_l4": (128, 4)}
#: positional-encoding frequencies of the position and of the normal
POSITION_FREQUENCIES = 6
NORMAL_FREQUENCIES = 2
#: the tanh output spans ± this × the largest training |coefficient|
SCALE_MARGIN = 1.1
#: share of the samples held back to report the error on
HOLDOUT_SHARE = 0.1


@dataclass(frozen=True, eq=False)
class LearntSh:
    """A trained σ(p, n̂).

    net : the network (outputs L², tanh); centre (3,), radius : the position's scaling;
    scale : the output's scale; bands : L; position_frequencies, normal_frequencies : the
    encoding; diagnostics : training figures (JSON data)
    """

    net: Mlp
    centre: np.ndarray
    radius: float
    scale: float
    bands: int
    position_frequencies: int
    normal_frequencies: int
    diagnostics: dict[str, Any]


def encode(position: np.ndarray, normal: np.ndarray, centre: np.ndarray, radius: float,
           position_frequencies: int, normal_frequencies: int) -> np.ndarray:
    """The network's input for points (n, 3) and unit normals (n, 3): (n, d) float64."""
    p = (np.asarray(position, np.float64) - centre) / radius
    return np.concatenate([positional_encoding(p, position_frequencies),
                           positional_encoding(normal, normal_frequencies)], axis=1)


def evaluate(model: LearntSh, position: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The learnt transfer at points (n, 3) with unit normals (n, 3): (n, L²) float64."""
    x = encode(position, normal, model.centre, model.radius, model.position_frequencies,
               model.normal_frequencies)
    return model.scale * forward(model.net, x)


def area_samples(scene: Scene, count: int, seed: int) -> SurfaceSamples:
    """``count`` area-uniform surface samples with their shading and geometric normals and
    albedo (seeded)."""
    tri, bary = sample_surface(scene, count, np.random.default_rng(seed))
    v = scene.positions[scene.faces[tri]]
    position = np.einsum("nk,nkj->nj", bary, v)
    gn = face_normals(scene, tri)
    return SurfaceSamples(position, shading_normals(scene, tri, bary, gn), gn,
                          albedo_at(scene, tri, bary))


def unit_albedo_transfer(scene: Scene, tracer: RayTracer, samples: SurfaceSamples,
                         bands: int, strata: int, seed: int) -> np.ndarray:
    """Shadowed diffuse transfer at unit albedo: (n, L²) float64."""
    ones = np.ones((samples.count, 3))
    rho, _ = clamp_albedo(ones)
    unit = SurfaceSamples(samples.position, samples.normal, samples.geometric_normal, ones)
    return shadowed_transfer(scene, tracer, unit, bands, strata, seed).coeffs[:, 0] / rho[:, :1]


def fit_learnt_sh(scene: Scene, tracer: RayTracer, *, samples: int = 20000, bands: int = 4,
                  strata: int = 8, width: int = 64, layers: int = 4, steps: int = 3000,
                  batch: int = 1024, seed: int = 0) -> LearntSh:
    """Train σ(p, n̂) for ``scene`` (module docstring): ``samples`` area-uniform points,
    ``strata²`` rays each, ``steps`` AdamW steps on minibatches of ``batch``."""
    t0 = time.perf_counter()
    pts = area_samples(scene, samples, seed)
    target = unit_albedo_transfer(scene, tracer, pts, bands, strata, seed)
    t1 = time.perf_counter()
    centre, radius = np.asarray(scene.center, np.float64), float(scene.radius) or 1.0
    x = encode(pts.position, pts.normal, centre, radius, POSITION_FREQUENCIES,
               NORMAL_FREQUENCIES)
    scale = SCALE_MARGIN * float(np.abs(target).max()) or 1.0
    perm = np.random.default_rng(seed).permutation(samples)
    n_hold = max(1, round(HOLDOUT_SHARE * samples))
    hold, fit = np.sort(perm[:n_hold]), np.sort(perm[n_hold:])
    net, curve = train_network(x[fit], target[fit] / scale, (width,) * layers, steps, seed,
                               val=(x[hold], target[hold] / scale), desc="learnt SH",
                               output="tanh", batch=batch)
    diag = {"samples": samples, "strata": strata, "bands": bands, "width": width,
            "layers": layers, "steps": steps, "batch": batch, "seed": seed,
            "holdout_samples": int(n_hold),
            "holdout_mse": float(curve[-1, 1]) * scale**2,
            "holdout_mse_zero": float(curve[0, 1]) * scale**2,
            "seconds_data": t1 - t0, "seconds_training": time.perf_counter() - t1}
    return LearntSh(net, centre, radius, scale, bands, POSITION_FREQUENCIES,
                    NORMAL_FREQUENCIES, diag)
