"""Hair bundles drawn on the CPU (prtcore/runtime/strands.py): the manifest's sampling rule."""

from __future__ import annotations

import numpy as np

from prtcore.receivers.strands import build_strand_space
from prtcore.runtime.strands import sample_strands
from prtcore.scenes.hair import hairball


def test_sampling_rule_reads_texel_centres_and_stays_in_its_strand():
    s = build_strand_space(hairball(strands=23, segments=4, seed=2), 5)
    layout = s.layout()
    values = np.stack([s.strand * 100.0 + s.slot, np.ones(s.count)], axis=1)
    img = s.to_image(values)[:, :, :2]
    rng = np.random.default_rng(1)
    strand = np.repeat(s.strand[::5], 3)
    # at the centre of texel j (a = (j + 0.5)/n) the sample is that texel's value
    j = rng.integers(0, 5, len(strand))
    got = sample_strands(img, layout, strand, (j + 0.5) / 5)
    np.testing.assert_allclose(got[:, 0], strand * 100.0 + j, atol=1e-4)
    # anywhere along the strand, ends included: a blend of the strand's own texels only
    a = np.concatenate([rng.random(len(strand) - 2), [0.0, 1.0]])
    got = sample_strands(img, layout, strand, a)
    assert np.all(np.floor(got[:, 0] / 100.0 + 1e-6) == strand)
    np.testing.assert_allclose(got[:, 1], 1.0)  # weights sum to one, no empty texel read
    np.testing.assert_allclose(got[:, 0] - strand * 100.0, np.clip(a * 5 - 0.5, 0, 4),
                               atol=1e-4)
