"""Property-based (hypothesis): random point lights of the training family, at random
intensities, reconstruct within fixed, measured bounds (issues 8 and 21).

Setup: the Cornell box with the room family of the example spec (point lights in
ROOM_BOX), 256 training + 32 held-out lights, 128 measurement points, 32 basis elements,
ridge "auto" — the pipeline's transport and fit. The bounds are fixed numbers, not
multiples of the same bake's held-out error (a fit that got worse everywhere would raise
such a bound with it):
* against the path tracer (the ground truth), 16 seeded lights at 64 spp, its Monte Carlo
  noise removed per light (rmse_c = sqrt(max(rmse² − noise², 0)), noise from the tracer's
  standard error; two independent seeds agree with it: 0.109–0.124 against 0.116–0.118):
  mean ≤ PT_MEAN, max ≤ PT_MAX. Measured 0.189 / 0.252 (noise 0.120): the 32² atlas and
  16 gather rays of this tiny bake set that floor (the fast transport alone is 0.189 / 0.274
  off the path tracer), so a fit error that grows shows up above it;
* against the fast transport (cheap, so hypothesis can search the family), per light
  drawn anywhere in the family's box at intensity in [1e-6, 1e6]: ≤ PER_LIGHT_MAX. The
  held-out set does not see the family's tail: lights on the box's bottom face sit 10 cm
  above the tall block (a hot spot whose bounce is not low-rank); a 60 × 60 search there
  measured 0.670 (hypothesis's 100 examples: 0.611; held-out max 0.126);
* over 256 seeded uniform draws, the mean error against the fast transport is ≤ MEAN_MAX
  (measured 0.0507; held-out mean 0.0467);
* the error does not depend on the intensity (≤ 1e-4 relative change over 12 decades).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from stab_helpers import CORNELL, ROOM_BOX, Transport, spec_with

from prtcore.core.scene import Light
from prtcore.fit.model import relative_rmse
from prtcore.fit.transfer import fit_transfer, reconstruct
from prtcore.reference.pathtracer import reference_lightmaps

PER_LIGHT_MAX = 0.80   # measured 0.670 (+20 %)
MEAN_MAX = 0.065       # measured 0.0507 (+28 %)
PT_MEAN = 0.23         # measured 0.189 (+22 %), noise-corrected, against the path tracer
PT_MAX = 0.30          # measured 0.252 (+19 %)
INTENSITY_RTOL = 1e-4

LO, HI = (np.array(c, dtype=np.float64) for c in ROOM_BOX)


class Baked:
    def __init__(self):
        spec = spec_with(lights={"count": 256, "holdout": 32},
                         measurement_points={"count": 128, "supersample": 4})
        self.tr = Transport(CORNELL, spec)
        train, hold = self.tr.configurations()
        D, I = self.tr.dataset(train)
        Dh, Ih = self.tr.dataset(hold)
        self.model = fit_transfer(D, I, basis=32, ridge="auto")
        errs = [self.error(Dh[:, h], Ih[:, h]) for h in range(Dh.shape[1])]
        self.heldout_mean, self.heldout_max = float(np.mean(errs)), float(np.max(errs))

    def error(self, x, ref) -> float:
        y = reconstruct(self.model, x)
        assert np.isfinite(y).all()
        return relative_rmse(y, ref)

    def errors(self, lights) -> np.ndarray:
        D, I = self.tr.dataset(lights)
        return np.array([self.error(D[:, k], I[:, k]) for k in range(len(lights))])


@pytest.fixture(scope="module")
def baked():
    return Baked()


def _light(pos, intensity) -> Light:
    return Light(type="point", color=np.ones(3), intensity=float(intensity),
                 position=np.asarray(pos, dtype=np.float64))


coord = st.floats(0.0, 1.0)


@settings(max_examples=100, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(u=st.tuples(coord, coord, coord), log_i=st.floats(-6.0, 6.0))
def test_random_family_lights_within_bound_of_heldout(baked, u, log_i):
    pos = LO + (HI - LO) * np.array(u)
    err_a, err_b = baked.errors([_light(pos, 10.0**log_i), _light(pos, 1.0)])
    assert err_a <= PER_LIGHT_MAX, (pos, err_a, baked.heldout_max)
    assert err_a == pytest.approx(err_b, rel=INTENSITY_RTOL)


def test_mean_error_of_random_family_lights_matches_heldout(baked):
    rng = np.random.default_rng(0)
    lights = [_light(LO + (HI - LO) * rng.random(3), 10.0 ** rng.uniform(-6, 6))
              for _ in range(256)]
    errs = baked.errors(lights)
    assert errs.mean() <= MEAN_MAX, (errs.mean(), baked.heldout_mean)


def noise_corrected_rmse(y: np.ndarray, ref: np.ndarray, stderr: np.ndarray) -> float:
    """Relative RMSE of ``y`` against a Monte Carlo ``ref`` with its noise removed:
    sqrt(max(mean((y − ref)²) − mean(stderr²), 0)) / rms(ref)."""
    y, ref = np.asarray(y, np.float64), np.asarray(ref, np.float64)
    ms = float(((y - ref) ** 2).mean())
    noise2 = float((np.asarray(stderr, np.float64) ** 2).mean())
    return float(np.sqrt(max(ms - noise2, 0.0) / (ref ** 2).mean()))


def test_random_family_lights_against_the_path_tracer(baked):
    """16 seeded lights of the family, reconstructed vs path-traced (64 spp, seed 0)."""
    rng = np.random.default_rng(0)
    lights = [_light(LO + (HI - LO) * rng.random(3), 10.0 ** rng.uniform(-6, 6))
              for _ in range(16)]
    sc, tx = baked.tr.intake.scene, baked.tr.intake.texels
    ref, stderr = reference_lightmaps(sc, tx, [[lt] for lt in lights], 64, seed=0,
                                      tracer=baked.tr.tracer)
    D, _ = baked.tr.dataset(lights)
    errs = np.array([noise_corrected_rmse(reconstruct(baked.model, D[:, k]), ref[k],
                                          stderr[k]) for k in range(len(lights))])
    noise = np.sqrt((stderr ** 2).mean(axis=(1, 2)) / (ref ** 2).mean(axis=(1, 2)))
    assert noise.max() < 0.2, noise  # measured 0.113–0.131
    assert errs.mean() <= PT_MEAN and errs.max() <= PT_MAX, (errs.mean(), errs.max())
