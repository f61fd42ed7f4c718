"""The surface inter-reflection gather as a transport operator (registered as "surface").

:mod:`prtcore.transport.gather` traces the texel → texel operator G;
:mod:`prtcore.transport.direct` gives the near field's first bounce. This module states
what the solver gets from them (:class:`prtcore.transport.base.TransportOperator`): G as
the term's matrix, the texels' direct sample points, the near-field correction and the
memory G costs.
"""

from __future__ import annotations

from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Scene
from prtcore.core.spec import TransportSpec
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.base import TransportOperator, register
from prtcore.transport.direct import near_field_correction
from prtcore.transport.gather import GATHER_BATCH, GATHER_WORKERS, Gather, spec_gather

#: Memory of the gather (bytes; part of the bake's model,
#: :func:`prtcore.transport.dataset.estimate_bake_bytes`): per texel and gather ray, and
#: per gather ray in flight (GATHER_BATCH rays per batch, GATHER_WORKERS batches at once).
MEM_PER_TEXEL_RAY = 64
MEM_PER_GATHER_RAY_IN_FLIGHT = 150


@register
class SurfaceGather(TransportOperator):
    """Inter-reflection between surfaces: G (:func:`prtcore.transport.gather.gather_operator`)
    with the spec's gather rays, seed, near field and direct samples."""

    name = "surface"
    stage = "gather operator"
    stats_key = "gather"

    def build(self, scene: Scene, receiver: TexelSpace, tracer: RayTracer,
              spec: TransportSpec, timer: StageTimer | None = None) -> Gather:
        return spec_gather(scene, receiver, tracer, spec, timer)

    def estimate_bytes(self, receivers, configurations, spec):
        return int(receivers) * MEM_PER_TEXEL_RAY * int(spec.gather_rays) \
            + GATHER_WORKERS * GATHER_BATCH * MEM_PER_GATHER_RAY_IN_FLIGHT

    def direct_position(self, term: Gather):
        return term.direct_position

    def first_bounce(self, term: Gather, scene, tracer, lights, direct, timer):
        if term.near is None or not term.near.count:
            return None
        with timer.stage("near field"):
            return near_field_correction(scene, tracer, term.near, lights, direct, timer)
