"""Property-based (hypothesis): random point lights of the training family, at random
intensities, reconstruct within a stated bound of the bake's held-out figure (issue 8).

Setup: the Cornell box with the room family of the example spec (point lights in
ROOM_BOX), 256 training + 32 held-out lights, 128 measurement points, 32 basis elements,
ridge "auto" — the pipeline's transport and fit. Stated bounds, per light drawn anywhere
in the family's box with intensity in [1e-6, 1e6]:
* relative RMSE ≤ PER_LIGHT_FACTOR × the held-out maximum. The held-out set does not see
  the family's tail: lights on the box's bottom face sit 10 cm above the tall block (a hot
  spot whose bounce is not low-rank); a search over 6845 positions there found 4.3× the
  held-out maximum (0.74 against 0.17);
* the error does not depend on the intensity (≤ 1e-4 relative change over 12 decades);
* over 256 seeded uniform draws, the mean error is ≤ MEAN_FACTOR × the held-out mean.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from stab_helpers import CORNELL, ROOM_BOX, Transport, spec_with

from prtcore.core.scene import Light
from prtcore.fit.transfer import fit_transfer, reconstruct, relative_rmse

PER_LIGHT_FACTOR = 5.0
MEAN_FACTOR = 1.25
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
    assert err_a <= PER_LIGHT_FACTOR * baked.heldout_max, (pos, err_a, baked.heldout_max)
    assert err_a == pytest.approx(err_b, rel=INTENSITY_RTOL)


def test_mean_error_of_random_family_lights_matches_heldout(baked):
    rng = np.random.default_rng(0)
    lights = [_light(LO + (HI - LO) * rng.random(3), 10.0 ** rng.uniform(-6, 6))
              for _ in range(256)]
    errs = baked.errors(lights)
    assert errs.mean() <= MEAN_FACTOR * baked.heldout_mean, (errs.mean(), baked.heldout_mean)
