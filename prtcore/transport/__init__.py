"""Transport: the dataset of the bake (paper 4.1).

Light transport is linear and all K lighting configurations share one geometry, so the
geometry is traced once, into transport operators, and every configuration is solved
against them at once:

1. **Operators** (:mod:`~prtcore.transport.base`: the interface and registry; each member
   registers itself when imported below, one line per member): the surface gather G
   (:mod:`~prtcore.transport.surface` on :mod:`~prtcore.transport.gather`), rows =
   receiving texel, ``E_ind = G · (ρ ∘ (E_d + E_ind))``.
2. **Direct light** for every configuration at texels and measurement points with shadow
   rays, and the near field's first bounce (:mod:`~prtcore.transport.direct`).
3. **All bounces for all configurations at once**: ``(I − Gρ)⁻¹ Gρ E_d`` for all K × 3
   right-hand sides together (:mod:`~prtcore.transport.solve`).

:mod:`~prtcore.transport.dataset` is the stage: :func:`~prtcore.transport.dataset.bake_dataset`
runs the operators, the direct light and the solve, and the memory check before it.

Radiometry (docs/bundle.md): every stored value is outgoing radiance ``L = ρ/π · E``;
the indirect counts light that bounced at least once (all bounces).
"""

from prtcore.transport import fibre, subsurface, surface  # noqa: F401  (registration)
