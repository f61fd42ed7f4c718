"""Light in hair with the diffuse fibre model (paper 6.3): direct light with self-shadowing
and fibre-to-fibre multiple scattering as a sparse operator over strand texels
(registered as ``"fibre"``).

**The diffuse fibre.** A fibre is a cylinder whose surface is Lambertian with albedo ρ:
at a surface point with (radial) normal n the outgoing radiance is ``ρ/π · E(n)``. A strand
texel stores it averaged over the fibre's azimuth and over the texel's arc interval
(:mod:`prtcore.receivers.strands`): ``L̄ = ρ/π · Ē``. For one unshadowed fibre under a
directional light of illuminance E⊥ at angle θ to the fibre, the azimuthal mean of
``max(0, n·ω)`` is ``sin θ / π``, so ``L̄ = ρ E⊥ sin θ / π²`` (the closed form the tests
check).

**Geometry.** The fibres are traced as triangulated tubes (:mod:`prtcore.core.fibres`,
benchmarked against ribbons in ``benchmarks/hair_geometry.py``); rays leave a fibre from
its tube's circumscribed cylinder, so they never hit their own segment.
:func:`hair_tracer` builds the one tracer of a hair bake: the scene's triangles (a head,
when hair and mesh are baked together) first, then the fibre tubes.

**Direct light** (:func:`fibre_direct`): per texel, J points on the fibre surface,
stratified in azimuth and jittered in arc length, each with its radial normal; the mean of
their shadowed irradiance is Ē (the same light evaluation as surfaces,
:func:`prtcore.emitters.punctual.irradiance` through
:func:`prtcore.transport.direct.direct_radiance`).

**Multiple scattering** (:class:`FibreGather`): from each texel, M cosine-distributed
rays about the radial normal at M surface points (azimuths stratified); a ray that hits
fibre texel j adds 1/M to ``G[i, j]``: the incident radiance it brings is the hit fibre's
outgoing radiance, which the receiver stores radially constant (the paper's
approximation; the project's path tracer, :mod:`prtcore.reference.fibres`, does not make
it). ``E_ind = G · (ρ ∘ (E_d + E_ind))`` is then solved by
:func:`prtcore.transport.solve.solve_indirect` exactly as for surfaces.

Not yet: rays that hit the mesh of a hair + mesh bake bring no light (the mesh occludes
and shadows the hair, but light bounced off the mesh does not reach the hair yet).
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from prtcore.core.fibres import DEFAULT_SIDES, FibreMesh, fibre_tubes
from prtcore.core.geometry import directions_around
from prtcore.core.progress import StageTimer, bar
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.core.spec import TransportSpec
from prtcore.receivers.strands import StrandSpace, texel_of_hit
from prtcore.transport.base import TransportOperator, register
from prtcore.transport.direct import direct_radiance

#: rays per intersect call of the fibre gather
FIBRE_BATCH = 1 << 18
#: Memory of the fibre gather (bytes): per texel and gather ray (the (row, column) pairs
#: before they are summed into CSR, and the CSR), and per ray in flight.
MEM_PER_TEXEL_RAY = 24
MEM_PER_RAY_IN_FLIGHT = 200


def hair_tracer(space: StrandSpace, scene: Scene | None = None, sides: int = DEFAULT_SIDES,
                threads: int | None = None) -> tuple[RayTracer, FibreMesh]:
    """The tracer of a hair bake and its fibre tubes: ``scene``'s triangles (if any) with
    indices [0, F), then the tubes' with indices F + their own. The scale (ray offsets,
    "infinite" distance) is the radius of everything's bounds."""
    mesh = fibre_tubes(space.hair, sides)
    if scene is not None and scene.triangle_count:
        positions = np.concatenate([scene.positions, mesh.positions])
        faces = np.concatenate([scene.faces, mesh.faces + len(scene.positions)])
    else:
        positions, faces = mesh.positions, mesh.faces
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    scale = float(np.linalg.norm(hi - lo) / 2)
    return RayTracer(positions, faces, scale=scale, threads=threads), mesh


def fibre_direct(space: StrandSpace, tracer: RayTracer, lights: Sequence[Light],
                 samples: int, seed: int, block: int = 1 << 14) -> np.ndarray:
    """Direct outgoing radiance ``L̄_d = ρ/π · Ē_d`` (T, K, 3) float32 of every strand
    texel for every light: the mean over ``samples`` (J) surface points per texel
    (:meth:`~prtcore.receivers.strands.StrandSpace.surface_samples`), each shadowed by
    everything in ``tracer`` (other fibres, the mesh)."""
    origin, normal, _ = space.surface_samples(samples, seed)
    t, j = space.count, samples
    out = np.empty((t, len(lights), 3), dtype=np.float32)
    blocks = range(0, t, block)
    for a in bar(blocks, "direct fibres", total=len(blocks)):
        b = min(a + block, t)
        rad = direct_radiance(None, tracer, lights, origin[a:b].reshape(-1, 3),
                              normal[a:b].reshape(-1, 3),
                              np.repeat(space.albedo[a:b], j, axis=0))
        out[a:b] = rad.reshape(b - a, j, len(lights), 3).mean(axis=1)
    return out


@dataclass(frozen=True)
class FibreTerm:
    """The fibre gather: ``matrix`` (T, T) float32 CSR, rows receive, 1/M per ray from
    texel i that hits texel j; ``stats``: rays, fibre hits, mesh hits, misses."""

    matrix: sp.csr_matrix
    stats: dict = field(default_factory=dict)


def fibre_gather(space: StrandSpace, tracer: RayTracer, mesh: FibreMesh, mesh_faces: int,
                 rays: int, seed: int) -> FibreTerm:
    """Trace the fibre-to-fibre operator G with ``rays`` (M) cosine rays per texel.
    ``mesh_faces``: the number of scene triangles before the fibre tubes in ``tracer``."""
    t = space.count
    origin, normal, _ = space.surface_samples(rays, seed)
    origin, normal = origin.reshape(-1, 3), normal.reshape(-1, 3)
    rng = np.random.default_rng([seed, 1])
    rows_all, cols_all = [], []
    n_fibre = n_mesh = 0
    total = t * rays
    starts = range(0, total, FIBRE_BATCH)
    for a in bar(starts, "fibre gather", total=len(starts)):
        b = min(a + FIBRE_BATCH, total)
        u = rng.random(b - a)
        d = directions_around(normal[a:b], np.sqrt(u), 2 * np.pi * rng.random(b - a))
        hits = tracer.intersect(origin[a:b], d)
        fib = hits.triangle >= mesh_faces
        n_fibre += int(fib.sum())
        n_mesh += int((hits.hit & ~fib).sum())
        src = np.arange(a, b, dtype=np.int64)[fib] // rays
        dst = texel_of_hit(space, mesh, hits.triangle[fib] - mesh_faces,
                           hits.barycentric[fib])
        rows_all.append(src.astype(np.int32))
        cols_all.append(dst.astype(np.int32))
    rows = np.concatenate(rows_all) if rows_all else np.zeros(0, np.int32)
    cols = np.concatenate(cols_all) if cols_all else np.zeros(0, np.int32)
    g = sp.csr_matrix((np.full(len(rows), 1.0 / rays, dtype=np.float32), (rows, cols)),
                      shape=(t, t))
    g.sum_duplicates()
    g.sort_indices()
    return FibreTerm(matrix=g, stats={"rays": total, "fibre_hits": n_fibre,
                                      "mesh_hits": n_mesh,
                                      "misses": total - n_fibre - n_mesh})


@register
class FibreGather(TransportOperator):
    """Multiple scattering among diffuse fibres (see the module docstring). ``receiver``
    is a :class:`~prtcore.receivers.strands.StrandSpace`; ``tracer`` is the one
    :func:`hair_tracer` built for it and ``scene`` (None for hair alone)."""

    name = "fibre"
    stage = "fibre gather"
    stats_key = "fibre"

    def build(self, scene: Scene | None, receiver: StrandSpace, tracer: RayTracer,
              spec: TransportSpec, timer: StageTimer | None = None) -> FibreTerm:
        mesh = fibre_tubes(receiver.hair, DEFAULT_SIDES)
        offset = scene.triangle_count if scene is not None else 0
        with timer.stage(self.stage) if timer is not None else nullcontext():
            return fibre_gather(receiver, tracer, mesh, offset, spec.gather_rays, spec.seed)

    def estimate_bytes(self, receivers, configurations, spec):
        return int(receivers) * MEM_PER_TEXEL_RAY * int(spec.gather_rays) \
            + FIBRE_BATCH * MEM_PER_RAY_IN_FLIGHT
