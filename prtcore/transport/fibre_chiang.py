"""Light in hair with the Chiang et al. 2016 fibre (``hair.fibre = "chiang"``): the fast
path, checked against :mod:`prtcore.reference.chiang`.

**What a texel stores** (:mod:`prtcore.core.bcsdf`): the paper's radially constant value,
the fibre's outgoing radiance averaged over every direction with the weight of its
projected width, ``L̄ = (1/π²) ∫ L_o(ω) cos θ dω`` over the texel's arc. It equals
``(1/π²) ∫ L_i(ωi) Ā(θi) cos θi dωi``: the diffuse fibre's formula
(:mod:`prtcore.transport.fibre`) with the albedo ρ replaced by the fibre's directional
albedo Ā at the angle θi the light comes from (:class:`prtcore.core.bcsdf.FibreAlbedo`,
one table per bake; channels independent, so σ_a may differ per texel and channel). For a
non-absorbing fibre Ā ≈ 1 (the white furnace holds).

* **Direct light** (:func:`chiang_direct`): the diffuse fibre's J stratified surface
  samples and shadow rays, each sample's ``E/π · max(0, n·ωl) · V`` weighted by
  ``Ā(t·ωl, σ)`` at its own tangent t: ``L̄_d = Ā E⊥ cos θl V̄ / π²``, V̄ the cosine-weighted
  visibility over the fibre's surface.
* **Multiple scattering** (:func:`chiang_gather`): the diffuse fibre's gather rays (density
  cos θ / π² over the sphere), each weighted by ``Ā(t·d, σ_i)`` of its own direction and
  the receiving texel's σ, one CSR per colour channel, solved by
  :func:`prtcore.transport.solve.solve_indirect` with them as its per-channel matrices.

**The approximation** (the paper's, "radially constant illumination at each point on the
fiber"): a gather ray that hits fibre j brings ``L̄_j``, not the BCSDF's outgoing radiance
toward the ray. Hair scatters forward (TT) and back (R, TRT) unevenly, so this is where
the fast path departs from the reference; docs/hair.md has the measured error. The
direct light's azimuthal harmonics of the diffuse fibre have no counterpart here: the
fibre's radiance is already averaged over every direction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from prtcore.core.bcsdf import (
    ChiangParams,
    FibreAlbedo,
    fibre_albedo,
    sigma_a_from_color,
    sigma_a_from_melanin,
)
from prtcore.core.fibres import FibreMesh
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.core.spec import ChiangSpec
from prtcore.emitters.punctual import unshadowed_irradiance
from prtcore.receivers.strands import StrandSpace, axis_frame
from prtcore.transport.fibre import FibreTerm, _direct_of, _direct_samples, fibre_gather

#: light types whose direct light the Chiang fibre evaluates (one direction per point)
CHIANG_LIGHT_TYPES = ("point", "spot", "directional")


@dataclass(frozen=True)
class ChiangFibre:
    """The fibre of a Chiang bake: ``params`` (its sigma_a unused), ``albedo`` the
    directional albedo table, ``sigma_texels`` (T, 3) float64 and ``sigma_points`` (p, 3)
    float64 the absorption per unit radius at every strand texel and hair point."""

    params: ChiangParams
    albedo: FibreAlbedo
    sigma_texels: np.ndarray
    sigma_points: np.ndarray


def chiang_fibre(spec: ChiangSpec, space: StrandSpace) -> ChiangFibre:
    """The fibre of ``spec`` on ``space``: σ_a from the melanin concentrations, or (with
    ``eumelanin`` null) from every texel's and point's colour as the hair volume's colour
    (:func:`prtcore.core.bcsdf.sigma_a_from_color`)."""
    params = ChiangParams(beta_m=spec.beta_m, beta_n=spec.beta_n,
                          alpha=float(np.radians(spec.alpha_deg)), eta=spec.eta)
    if spec.eumelanin is None:
        sig_t = sigma_a_from_color(space.albedo, spec.beta_n)
        sig_p = sigma_a_from_color(space.hair.color, spec.beta_n)
    else:
        one = sigma_a_from_melanin(spec.eumelanin, spec.pheomelanin)
        sig_t = np.tile(one, (space.count, 1))
        sig_p = np.tile(one, (space.hair.point_count, 1))
    return ChiangFibre(params=params, albedo=fibre_albedo(params), sigma_texels=sig_t,
                       sigma_points=sig_p)


def check_lights(lights: Sequence[Light]) -> None:
    """Refuse lights the Chiang fibre cannot shade yet (environment lights), by name."""
    bad = sorted({li.type for li in lights if li.type not in CHIANG_LIGHT_TYPES})
    if bad:
        raise ValueError(f"hair.fibre 'chiang' shades {', '.join(CHIANG_LIGHT_TYPES)} lights; "
                         f"this bake has {', '.join(bad)} lights (use hair.fibre 'diffuse')")


def chiang_direct(space: StrandSpace, tracer: RayTracer, lights: Sequence[Light],
                  samples: int, seed: int, fibre: ChiangFibre) -> np.ndarray:
    """Direct ``L̄_d`` (T, K, 3) float32 of every strand texel for every light, from the
    same surface samples as :func:`prtcore.transport.fibre.fibre_direct`."""
    check_lights(lights)
    drawn = _direct_samples(space, samples, seed)
    arc, _ = space.surface_sample_params(samples, seed)  # the samples' arcs, as drawn
    tangent = axis_frame(space.hair, np.repeat(space.strand, samples),
                         arc.reshape(-1))[1].reshape(space.count, samples, 3)

    def weight(idx: np.ndarray, origin: np.ndarray, lights_: Sequence[Light]) -> np.ndarray:
        n, j = origin.shape[:2]
        pts = origin.reshape(-1, 3)
        tg = tangent[idx].reshape(-1, 3)
        sig = np.repeat(fibre.sigma_texels[idx], j, axis=0)
        out = np.empty((n * j, len(lights_), 3), dtype=np.float32)
        for k, light in enumerate(lights_):
            _, to_light, _ = unshadowed_irradiance(light, pts, tg)
            out[:, k] = fibre.albedo(np.einsum("ij,ij->i", tg, to_light), sig)
        return out.reshape(n, j, len(lights_), 3)

    return _direct_of(space, tracer, lights, drawn, 0, 1 << 14, progress=True,
                      weight=weight).mean


def chiang_gather(space: StrandSpace, tracer: RayTracer, mesh: FibreMesh, mesh_faces: int,
                  rays: int, seed: int, fibre: ChiangFibre) -> FibreTerm:
    """:func:`prtcore.transport.fibre.fibre_gather` with every ray weighted by
    ``Ā(t·d, σ_i)`` (``FibreTerm.channels``); the same rays as the diffuse fibre's."""
    hair = space.hair

    def ray_weight(texel: np.ndarray, arc: np.ndarray, d: np.ndarray) -> np.ndarray:
        tg = axis_frame(hair, space.strand[texel], arc)[1]
        return fibre.albedo(np.einsum("ij,ij->i", tg, d), fibre.sigma_texels[texel])

    return fibre_gather(space, tracer, mesh, mesh_faces, rays, seed, harmonics=0,
                        ray_weight=ray_weight)


def channel_operator(term: FibreTerm) -> tuple[sp.csr_matrix, tuple, np.ndarray]:
    """``solve_indirect``'s (shared matrix, per-channel matrices, albedo) for the weighted
    gather W_c: the solver computes ``L = ρ ∘ (G + C_c)(L_d + L)``; with an empty G,
    ``C_c = 2 W_c`` and ρ = 1/2 (below the solver's albedo clamp) that is ``L = W_c (L_d +
    L)``."""
    t = term.matrix.shape[0]
    shared = sp.csr_matrix((t, t), dtype=np.float32)
    channels = tuple((2 * m).astype(np.float32) for m in term.channels)
    return shared, channels, np.full((t, 3), 0.5)
