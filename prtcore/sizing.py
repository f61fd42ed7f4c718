"""Automatic sizing of a static bake (issue 13): how many measurement points P and
training lights K the scene needs, chosen from the data.

The plan (:func:`prtcore.intake.plan.decide_sizing`) fixes what is tried: P doubles from
256 up to ``sizing.max_points`` (or the spec's P), K starts at ``sizing.lights_start`` and
may double up to ``sizing.max_lights`` (or the spec's K). The intake places dense
blue-noise candidates; transport lights them once, with K training and the held-out
lights. Then, for each P:

1. choose P of the candidates (placement "qdeim": pivoted QR on their training direct
   light, :func:`prtcore.intake.sensors.select_sensors`; "surface" / "hull": nested
   farthest-point subsets of the blue-noise candidates, the blue-noise baseline),
2. fit exactly as the method will (denoised lightmaps, the spec's basis, ridge, channels,
   gamma),
3. measure the held-out error at the fitted n and its projection bound, pooled over the
   held-out lights (:func:`prtcore.report.heldout_metrics`, the verdict's own figures).

P is tried in increasing order; the first P whose error is within
``validate.target_ratio`` × the bound ships. Candidates are placed lazily: 2P blue-noise
candidates for the largest P tried so far (only their direct light is computed again: the
texels' transport does not depend on the points). When none is, and K may grow,
the next K lights are transported (the operators are not traced again: only the new
lights, :func:`prtcore.transport.dataset.light_configurations`) unless the memory limit
or the time budget (``sizing.max_seconds``, extrapolated from the last pass) says no;
then the whole scan repeats. When the budget ends first, the P with the lowest error
ships, and the report says why.

The held-out lights both choose P and K and judge the bake (as ``fit.basis: "auto"``
chooses n on them): the verdict of a sized bake is on the lights that sized it.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from prtcore.core.progress import StageTimer, bar
from prtcore.core.scene import Light
from prtcore.core.spec import BakeSpec
from prtcore.intake.plan import Sizing
from prtcore.intake.points import MeasurementPoints, place_measurement_points
from prtcore.intake.sensors import (
    direct_svd,
    farthest_fill,
    prepare_direct,
    restrict_points,
    select_sensors,
)
from prtcore.receivers.smoothing import denoise_lightmaps
from prtcore.report import fit_for_table, heldout_metrics
from prtcore.transport.dataset import (
    LIGHT_STAGES,
    Dataset,
    Transport,
    add_training,
    direct_at_points,
    estimate_bake_bytes,
    light_configurations,
)

#: when no P meets the target, a larger P ships only when it lowers the held-out error by
#: more than this fraction
CLOSE_TO_BEST = 0.05


@dataclass(frozen=True)
class Trial:
    """One (P, K) tried: the fitted n, the pooled held-out error and projection bound at
    n (None without held-out light), their ratio, and the seconds selection + fit took."""

    points: int
    lights: int
    n: int
    error: float | None
    bound: float | None
    ratio: float | None
    seconds: float


@dataclass(frozen=True, eq=False)
class Sized:
    """What sizing chose.

    points : the chosen P measurement points (a restriction of the candidates)
    data : the dataset with the chosen points' direct rows and every training light lit
    train : the training lights used, (K,)
    indirect : (I (T, K, 3), I_h (T, H, 3)) float32 lightmaps as the fit sees them
        (denoised when ``fit.denoise`` > 0), so the method does not filter them again
    trials : every (P, K) tried, in order; chosen : the one that ships
    stop : why the search ended; record : :meth:`to_dict` for the manifest and report
    models : the chosen trial's (model, full) fit, the one the bake ships
    """

    points: MeasurementPoints
    data: Dataset
    train: tuple[Light, ...]
    indirect: tuple[np.ndarray, np.ndarray]
    trials: tuple[Trial, ...]
    chosen: Trial
    stop: str
    models: tuple = ()

    def to_dict(self, sizing: Sizing) -> dict[str, Any]:
        return {"points": self.chosen.points, "lights": self.chosen.lights,
                "n": self.chosen.n, "placement": sizing.placement,
                "candidates": sizing.candidates, "tried_points": list(sizing.points),
                "lights_start": sizing.lights_start, "lights_max": sizing.lights_max,
                "reason": self.stop,
                "trials": [dataclasses.asdict(t) for t in self.trials]}


def choose(trials: list[Trial], target_ratio: float) -> Trial | None:
    """The trial that ships among ``trials`` of one K: the smallest P meeting
    ``target_ratio``; None when none does."""
    ok = [t for t in trials if t.ratio is not None and t.ratio <= target_ratio]
    return min(ok, key=lambda t: t.points) if ok else None


def fallback(trials: list[Trial]) -> Trial:
    """The trial that ships when none meets the target: the smallest P within
    :data:`CLOSE_TO_BEST` of the lowest error (the smallest P when none could be judged)."""
    judged = [t for t in trials if t.error is not None]
    if not judged:
        return min(trials, key=lambda t: t.points)
    best = min(t.error for t in judged)
    return min((t for t in judged if t.error <= best * (1 + CLOSE_TO_BEST)),
               key=lambda t: t.points)


def select_points(candidates: MeasurementPoints, direct_train: np.ndarray, count: int,
                  placement: str, seed: int, svd=None) -> np.ndarray:
    """(count,) int64 rows of ``candidates`` to keep. direct_train : (N, K, 3) their
    training direct light. "qdeim": pivoted QR (intake/sensors.py; ``svd`` its SVD when
    already computed); otherwise the first ``count`` of a farthest-point order of the
    blue-noise candidates (nested in P)."""
    count = min(int(count), candidates.count)
    if placement == "qdeim":
        return select_sensors(direct_train, count, positions=candidates.position,
                              seed=seed, svd=svd).indices
    return farthest_fill(candidates.position, np.zeros(0, np.int64), count)


def size_bake(spec: BakeSpec, sizing: Sizing, transport: Transport, data: Dataset,
              train_pool: tuple[Light, ...], n_hold: int, limit_bytes: int,
              timer: StageTimer) -> Sized:
    """Choose P and K for a static bake (module docstring).

    transport : the operators traced once (:func:`~prtcore.transport.dataset.open_transport`)
        on the candidate points; data : their dataset for the first
        ``sizing.lights_start`` training lights and the ``n_hold`` held-out ones;
    train_pool : (≥ sizing.lights_max,) training lights, a prefix-stable draw
    limit_bytes : the bake's memory limit (growing K stops before it)
    Timed stages: "select points" (selection and trial fits), "points" and "direct points"
    when candidates grow, and the transport stages of every pass that adds lights.
    ``spec.fit.denoise`` must be a radius (:func:`prtcore.transport.noise.with_denoise`).
    """
    if spec.fit.denoise == "auto":
        raise ValueError("size_bake: fit.denoise 'auto' must be resolved to a radius first "
                         "(prtcore.transport.noise.measure_noise / with_denoise)")
    fit, target = spec.fit, spec.validate.target_ratio
    t_start = time.perf_counter()
    candidates = transport.points
    K = data.stats["train"]
    svd_of: dict[tuple[int, int], tuple] = {}

    def ensure_candidates(p: int) -> None:
        """More candidates when P outgrows them: a fresh blue-noise set of 2P, lit by the
        lights so far (direct light at points only: the texels' transport does not depend
        on the points)."""
        nonlocal candidates, data, transport
        if not sizing.grow_candidates or candidates.count >= 2 * p:
            return
        with timer.stage("points"):
            candidates = place_measurement_points(transport.scene, dataclasses.replace(
                spec.measurement_points, placement=sizing.candidate_placement, count=2 * p))
        transport = dataclasses.replace(transport, points=candidates)
        data = dataclasses.replace(data, direct_points=direct_at_points(
            transport.scene, transport.tracer, data.lights, candidates, timer))

    def rows_for(p: int) -> np.ndarray:
        svd = None
        if sizing.select and sizing.placement == "qdeim":
            key = (candidates.count, K)
            if key not in svd_of:  # one SVD of the candidates' direct light per (C, K)
                svd_of.clear()
                svd_of[key] = direct_svd(prepare_direct(data.direct_points[:, :K]))
            svd = svd_of[key]
        return _rows(candidates, data, K, p, sizing, spec, svd)

    I, Ih = _lightmaps(transport, data, fit.denoise, timer)
    trials: list[Trial] = []
    transport_seconds = sum(data.stats["seconds"].values())
    pass_seconds = sum(data.stats["seconds"].get(s, 0.0) for s in LIGHT_STAGES)
    pass_lights = len(data.lights)
    tried = sorted(sizing.points if sizing.grow_candidates else
                   {min(p, candidates.count) for p in sizing.points})
    while True:
        scan, rows_of = [], {}
        for p in bar(tried, f"sizing: P at K = {K}", total=len(tried)):
            ensure_candidates(p)
            with timer.stage("select points"):
                rows = rows_for(p)
                trial, models = _trial(spec, data, K, I, Ih, rows)
                # the pool these rows index (candidates may grow later in the scan)
                rows_of[p] = (candidates, rows, data.direct_points[rows], models)
                scan.append(trial)
            if scan[-1].ratio is not None and scan[-1].ratio <= target:
                break  # the smallest P that meets the target ships
            if scan[-1].error is None:
                break  # nothing to judge a larger P by
        trials.extend(scan)
        if scan[-1].error is None:  # no held-out light gives indirect light at the texels
            chosen = scan[0]
            stop = (f"P = {chosen.points}, K = {K}: no held-out light gives indirect light "
                    "(a convex object, or lights.holdout = 0), so there is nothing to size "
                    "on; the smallest P ships")
            break
        chosen = choose(scan, target)
        if chosen is not None:
            stop = (f"P = {chosen.points}, K = {K}: held-out error {_pct(chosen.error)} is "
                    f"{chosen.ratio:.2f}× the projection bound (target {target:g}×)")
            break
        grow = min(2 * K, sizing.lights_max)
        why_not = None
        if grow <= K:
            why_not = (f"K = {K} is the most allowed ("
                       + ("lights.count" if sizing.lights_max == sizing.lights_start
                          else "sizing.max_lights") + ")")
        elif estimate_bake_bytes(transport.texels.count, grow + n_hold, transport.spec
                                 ) > limit_bytes:
            why_not = f"K = {grow} would exceed the memory limit ({limit_bytes} bytes)"
        else:
            need = pass_seconds / max(pass_lights, 1) * (grow - K)
            if sizing.max_seconds > 0 and transport_seconds + need > sizing.max_seconds:
                why_not = (f"K = {grow} would take transport to about "
                           f"{transport_seconds + need:.0f} s (sizing.max_seconds "
                           f"{sizing.max_seconds:g})")
        if why_not is not None:
            chosen = fallback(scan)
            stop = (f"no P reached {target:g}× the projection bound at K = {K} and {why_not}: "
                    f"shipping P = {chosen.points} (held-out error {_pct(chosen.error)}, "
                    + (f"{chosen.ratio:.2f}× the bound)" if chosen.ratio is not None
                       else "no held-out light)"))
            break
        extra = light_configurations(transport, train_pool[K:grow], grow - K, timer,
                                     keep_direct_texels=data.direct_texels is not None)
        pass_seconds = sum(extra.stats["seconds"].get(s, 0.0) for s in LIGHT_STAGES)
        pass_lights = grow - K
        transport_seconds += pass_seconds
        data = add_training(data, extra)
        I = np.concatenate([I, _denoised(transport, extra.indirect, fit.denoise, timer)],
                           axis=1)
        K = grow
    pool, rows, direct, models = rows_of[chosen.points]
    points = dataclasses.replace(restrict_points(pool, rows), placement=sizing.placement)
    data = dataclasses.replace(data, direct_points=direct, stats={
        **data.stats, "sizing_seconds": time.perf_counter() - t_start})
    return Sized(points=points, data=data, train=tuple(train_pool[:K]), indirect=(I, Ih),
                 trials=tuple(trials), chosen=chosen, stop=stop, models=models)


def _pct(v: float | None) -> str:
    return "n/a" if v is None else f"{100 * v:.1f} %"


def _denoised(transport: Transport, I: np.ndarray, radius: float,
              timer: StageTimer) -> np.ndarray:
    if radius <= 0:
        return I
    with timer.stage("denoise"):
        return denoise_lightmaps(transport.texels, I, radius)


def _lightmaps(transport: Transport, data: Dataset, radius: float, timer: StageTimer
               ) -> tuple[np.ndarray, np.ndarray]:
    K = data.stats["train"]
    both = _denoised(transport, data.indirect, radius, timer)
    return both[:, :K], both[:, K:]


def _rows(candidates: MeasurementPoints, data: Dataset, K: int, p: int, sizing: Sizing,
          spec: BakeSpec, svd=None) -> np.ndarray:
    if not sizing.select:  # the intake placed exactly these points
        return np.arange(candidates.count, dtype=np.int64)
    return select_points(candidates, data.direct_points[:, :K], p, sizing.placement,
                         spec.measurement_points.seed, svd)


def _trial(spec: BakeSpec, data: Dataset, K: int, I: np.ndarray, Ih: np.ndarray,
           rows: np.ndarray) -> tuple[Trial, tuple]:
    """One (P, K): the method's own fit (:func:`prtcore.report.fit_for_table`) of the
    points ``rows`` and its held-out figures at the shipped n; returns the trial and the
    (model, full) fit, which the bake ships when the trial is chosen."""
    t0 = time.perf_counter()
    D = data.direct_points[rows]
    Dt, Dh = D[:, :K], D[:, K:]
    model, full = fit_for_table(Dt, I, spec.fit, (Dh, Ih) if Ih.shape[1] else None)
    m = heldout_metrics(model, Dh, Ih, [model.n_basis])[0] if Ih.shape[1] else {}
    error, bound = m.get("heldout_rmse_pooled"), m.get("projection_bound_pooled")
    ratio = None if error is None or not bound else error / bound
    return (Trial(points=len(rows), lights=K, n=model.n_basis, error=error, bound=bound,
                  ratio=ratio, seconds=time.perf_counter() - t0), (model, full))
