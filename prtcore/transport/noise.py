"""The fast transport's own error, measured, and the lightmap filter it calls for (issue 13).

The gather estimates each texel's indirect light with M rays of its own, so the bake's
lightmaps carry Monte Carlo error; the seam-aware filter (:mod:`prtcore.receivers.smoothing`)
removes some of it, and blurs real detail with it. How much of each depends on the asset:
on the exterior house (256²) a radius of 1.5 texels takes the held-out lightmaps from 13.5 %
to 7.3 % expected error, while on CesiumMilkTruck (doubled, coincident faces, parts a few
texels wide) the same filter takes them from 10 % to 30 %. So the radius is chosen from
data, per bake.

A second transport of the held-out lights, traced with an independent seed, gives g, an
estimate of the same noiseless lightmaps t as the bake's own f, with independent error. For
any linear filter W, because E⟨Wf − t, g − t⟩ = 0 and E‖g − t‖² = E‖f − g‖² / 2,

    R(W) = ½ (‖W f − g‖² + ‖W g − f‖²) − ½ ‖f − g‖²

is an unbiased estimate of E‖W f − t‖², the error of the filtered bake lightmaps against
the noiseless truth (W = I gives the transport's own noise). The radius with the least R
ships. Measured against the path tracer with its noise removed (exterior house, truck,
256², three held-out lights): R tracks the true error to within 0.4–2.3 % points at every
radius and picks the best one on both (``benchmarks/transport_noise.py``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from prtcore.core.progress import StageTimer
from prtcore.emitters.base import Light
from prtcore.receivers.smoothing import smooth_texels, smoothing_operators
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.dataset import Transport, light_texels, trace_operators

#: Filter radii (texels) the bake chooses from; 0 is no filter.
DENOISE_RADII = (0.0, 0.75, 1.5, 2.5)
#: The radius of ``fit.denoise = "auto"`` where no second transport is traced (keyframe
#: bakes; hair bakes do not filter).
DENOISE_FALLBACK = 1.5
#: Held-out lights traced the second time (the first ones): the estimate sums over every
#: texel, channel and light, so a few lights suffice, and the second solve's cost grows
#: with their number.
NOISE_LIGHTS = 8


@dataclass(frozen=True)
class TransportNoise:
    """What the second transport measured.

    radius : the chosen filter radius (texels); radii : the candidates; expected_error :
    per candidate, sqrt(R(W)) / ‖g‖ pooled over the held-out lights and channels (the
    expected relative error of the filtered bake lightmaps against the noiseless truth;
    the unfiltered one is the transport's own noise); lights : held-out lights used;
    seed : the second transport's seed; seconds : its wall time; operator : the chosen
    radius's filter W (T × T CSR, :func:`~prtcore.receivers.smoothing.smoothing_operator`'s
    matrix, bit for bit), for the denoise stage to apply rather than build again; None for
    radius 0 (not in :meth:`to_dict`).
    """

    radius: float
    radii: tuple[float, ...]
    expected_error: tuple[float, ...]
    lights: int
    seed: int
    seconds: float
    operator: Any = field(default=None, repr=False, compare=False)

    @property
    def noise(self) -> float:
        """Relative error of the unfiltered fast transport (radius 0)."""
        return self.expected_error[self.radii.index(0.0)] if 0.0 in self.radii else float("nan")

    @property
    def chosen_error(self) -> float:
        return self.expected_error[self.radii.index(self.radius)]

    def to_dict(self) -> dict:
        def num(e: float) -> float | None:
            return None if e != e else round(e, 6)

        return {"radius": self.radius, "radii": list(self.radii),
                "expected_error": [num(e) for e in self.expected_error],
                "transport_noise": num(self.noise), "lights": self.lights,
                "seed": self.seed, "seconds": round(self.seconds, 3)}


def noise_line(record: dict) -> str:
    """One line for the terminal and report.txt from :meth:`TransportNoise.to_dict`."""
    def pct(e: float | None) -> str:  # to_dict writes an unmeasured error as None
        return "—" if e is None else f"{100 * e:.1f} %"

    if record["transport_noise"] is None:
        return (f"not measured: no indirect light in the {record['lights']} held-out lights; "
                f"lightmap filter radius {record['radius']:g} texels")
    errs = ", ".join(f"{r:g}: {pct(e)}" for r, e in
                     zip(record["radii"], record["expected_error"], strict=True))
    return (f"{pct(record['transport_noise'])} (second transport of "
            f"{record['lights']} held-out lights); lightmap filter radius "
            f"{record['radius']:g} texels, expected error by radius {errs}")


def with_denoise(spec, radius: float):
    """``spec`` (a :class:`~prtcore.core.spec.BakeSpec`) with ``fit.denoise`` = ``radius``
    where it is "auto"; a number given in the spec stays."""
    if spec.fit.denoise != "auto":
        return spec
    return dataclasses.replace(spec, fit=dataclasses.replace(spec.fit, denoise=float(radius)))


def second_seed(seed: int) -> int:
    """The independent transport's seed, derived from the bake's transport seed."""
    return int(np.random.SeedSequence([int(seed), 0x6e6f6973]).generate_state(1)[0])


def independent_lightmaps(transport: Transport, lights: Sequence[Light],
                          timer: StageTimer | None = None) -> np.ndarray:
    """Indirect lightmaps (T, H, 3) float32 of ``lights`` from the same operators traced
    again with :func:`second_seed` (gather rays, direct samples, near field: all
    independent of the bake's). The operators are dropped on return."""
    spec = dataclasses.replace(transport.spec, seed=second_seed(transport.spec.seed))
    quiet = StageTimer(quiet=True)
    names = transport.operators
    traced = trace_operators(transport.scene, transport.texels, transport.tracer, spec,
                             quiet, names)
    return light_texels(transport.scene, transport.texels, transport.tracer, traced,
                        tuple(lights), spec, quiet).indirect


def filters(texels: TexelSpace, radii: Sequence[float]) -> dict:
    """radius → the filter W (T × T CSR) for each radius > 0 of ``radii``, from one
    neighbour search (:func:`~prtcore.receivers.smoothing.smoothing_operators`)."""
    positive = tuple(r for r in radii if r > 0)
    return dict(zip(positive, smoothing_operators(texels, positive), strict=True)) \
        if positive else {}


def choose_radius(texels: TexelSpace, f: np.ndarray, g: np.ndarray,
                  radii: Sequence[float] = DENOISE_RADII,
                  operators: dict | None = None) -> tuple[float, tuple[float, ...]]:
    """The radius of ``radii`` with the least expected error R (module docstring), and every
    candidate's sqrt(R) / ‖g‖. f, g : (T, H, 3) two independent estimates of the same
    lightmaps (the bake's and :func:`independent_lightmaps`). Ties go to the smaller radius.
    operators : :func:`filters` of ``radii``, built here when None."""
    f = np.asarray(f, dtype=np.float64)
    g = np.asarray(g, dtype=np.float64)
    h = f.shape[1]
    norm2 = float((g * g).sum())
    if norm2 <= 0.0:  # no indirect light to judge by: the smallest radius, error unknown
        return float(min(radii)), tuple(float("nan") for _ in radii)
    half_gap = 0.5 * float(((f - g) ** 2).sum())
    ops = operators if operators is not None else filters(texels, radii)
    errors = []
    for r in radii:
        if r <= 0:
            risk = half_gap
        else:
            both = smooth_texels(texels, np.concatenate([f, g], axis=1), operator=ops[r])
            wf, wg = both[:, :h], both[:, h:]
            risk = 0.5 * (float(((wf - g) ** 2).sum()) + float(((wg - f) ** 2).sum())) \
                - half_gap
        errors.append(float(np.sqrt(max(risk, 0.0) / norm2)))
    best = min(range(len(radii)), key=lambda k: (errors[k], radii[k]))
    return float(radii[best]), tuple(errors)


def measure_noise(transport: Transport, lights: Sequence[Light], f: np.ndarray,
                  timer: StageTimer | None = None,
                  radii: Sequence[float] = DENOISE_RADII) -> TransportNoise:
    """Trace the first :data:`NOISE_LIGHTS` of the held-out ``lights`` a second time
    (:func:`independent_lightmaps`) and choose the filter radius (:func:`choose_radius`).
    f : (T, H, 3) the bake's own indirect lightmaps of ``lights``. Timed as the stage
    "transport noise"."""
    timer = timer or StageTimer(quiet=True)
    t0 = time.perf_counter()
    lights = tuple(lights)[:NOISE_LIGHTS]
    f = f[:, :len(lights)]
    with timer.stage("transport noise"), ThreadPoolExecutor(1) as ex:
        # the filters need only the texels: built while the second transport traces
        pending = ex.submit(filters, transport.texels, radii)
        g = independent_lightmaps(transport, lights, timer)
        ops = pending.result()
        radius, errors = choose_radius(transport.texels, f, g, radii, ops)
    return TransportNoise(radius=radius, radii=tuple(float(r) for r in radii),
                          expected_error=errors, lights=len(lights),
                          seed=second_seed(transport.spec.seed),
                          seconds=time.perf_counter() - t0, operator=ops.get(radius))
