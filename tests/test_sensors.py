"""Sensor selection by pivoted QR / Q-DEIM (prtcore.intake.sensors, issue 13): analytic
cases where the informative rows are known."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from prtcore.intake.sensors import (
    concat_points,
    farthest_fill,
    prepare_direct,
    qdeim,
    restrict_points,
    select_sensors,
    stack_coefficients,
)


def _orthonormal(rng, n, r):
    q, _ = np.linalg.qr(rng.normal(size=(n, r)))
    return q


def test_qdeim_finds_the_only_informative_rows():
    # modes supported on 4 rows only: any other row is zero, so Q-DEIM must pick those
    rng = np.random.default_rng(0)
    rows = np.array([3, 17, 41, 58])
    psi = np.zeros((64, 4))
    psi[rows] = _orthonormal(rng, 4, 4)
    assert sorted(qdeim(psi).tolist()) == rows.tolist()


def test_qdeim_prefers_strong_copies_of_each_direction():
    # each latent direction j appears in one strong row (norm 1) and in weak copies
    # (norm ≤ 0.5): pivoting takes the strong row of every direction
    rng = np.random.default_rng(1)
    r, n = 5, 60
    strong = rng.choice(n, r, replace=False)
    latent = np.eye(r)
    psi = np.zeros((n, r))
    owner = rng.integers(r, size=n)
    psi[:] = latent[owner] * rng.uniform(0.05, 0.5, size=(n, 1))
    psi[strong] = latent
    assert sorted(qdeim(psi).tolist()) == sorted(strong.tolist())


def test_qdeim_submatrix_is_well_conditioned_and_recovers_a_low_rank_field():
    rng = np.random.default_rng(2)
    n, r, k = 400, 12, 50
    psi = _orthonormal(rng, n, r)
    sel = qdeim(psi)
    assert sel.dtype == np.int64 and len(set(sel.tolist())) == r
    # Drmač & Gugercin 2016, Theorem 2.1: ‖(Ψ_S)⁻¹‖₂ ≤ √(n − r + 1)·√(4^r + 6r − 1)/3
    smin = scipy.linalg.svdvals(psi[sel])[-1]
    assert 1.0 / smin <= np.sqrt(n - r + 1) * np.sqrt(4.0**r + 6 * r - 1) / 3
    # in practice far better than random rows
    rand = [1.0 / scipy.linalg.svdvals(psi[rng.choice(n, r, replace=False)])[-1]
            for _ in range(20)]
    assert 1.0 / smin < np.median(rand)
    # an exactly rank-r field is recovered everywhere from its values at the r rows
    field = psi @ rng.normal(size=(r, k))
    z = scipy.linalg.lstsq(psi[sel], field[sel])[0]
    np.testing.assert_allclose(psi @ z, field, atol=1e-10)


def test_qdeim_refuses_more_pivots_than_modes():
    with pytest.raises(ValueError, match="count"):
        qdeim(np.ones((10, 3)), 4)
    assert qdeim(np.ones((10, 3)), 0).shape == (0,)


def _low_rank_direct(rng, informative, n=200, k=40):
    """Direct values (n, k): r informative rows carry independent signals, every other row
    a weak (≤ 0.1) copy of one of them."""
    r = len(informative)
    sig = rng.normal(size=(r, k)) + 3.0  # positive-ish, like light
    d = np.empty((n, k))
    src = rng.integers(r, size=n)
    d[:] = sig[src] * rng.uniform(0.01, 0.1, size=(n, 1))
    d[informative] = sig
    return d


def test_select_sensors_recovers_the_informative_candidates():
    rng = np.random.default_rng(3)
    informative = rng.choice(200, 6, replace=False)
    d = _low_rank_direct(rng, informative)
    sel = select_sensors(d, 6, energy=1.0, qr_fraction=1.0)
    assert sel.method == "qdeim" and sel.fill == "none" and sel.qr_count == 6
    assert sel.rank == 6  # centred rank-6 signals with independent centred parts
    assert sorted(sel.indices.tolist()) == sorted(informative.tolist())
    # oversampling: P beyond the rank is filled, the QR part is unchanged
    pos = rng.normal(size=(200, 3))
    big = select_sensors(d, 20, energy=1.0, qr_fraction=1.0, positions=pos)
    assert big.qr_count == 6 and big.fill == "farthest"
    assert sorted(big.indices[:6].tolist()) == sorted(informative.tolist())
    assert len(set(big.indices.tolist())) == 20
    again = select_sensors(d, 20, energy=1.0, qr_fraction=1.0, positions=pos)
    np.testing.assert_array_equal(big.indices, again.indices)


def test_select_sensors_defaults_leave_half_to_coverage():
    rng = np.random.default_rng(4)
    d = rng.random((300, 80))
    sel = select_sensors(d, 40, positions=rng.normal(size=(300, 3)))
    assert sel.qr_count == 20 and sel.fill == "farthest"
    assert sel.indices.shape == (40,) and sel.indices.dtype == np.int64
    assert len(set(sel.indices.tolist())) == 40
    # the energy cut: a rank-3 signal plus tiny noise needs 3 modes for 99.9 %
    base = rng.random((300, 3)) @ rng.random((3, 80)) * 10.0
    noisy = base + 1e-4 * rng.random((300, 80))
    sel3 = select_sensors(noisy, 40)
    assert sel3.qr_count == 3 and sel3.fill == "random"
    r1 = select_sensors(noisy, 40, seed=7).indices
    r2 = select_sensors(noisy, 40, seed=7).indices
    np.testing.assert_array_equal(r1, r2)


def test_goal_oriented_modes_follow_the_targets():
    # two spatially separate modes: A (rows 0-9) strong, B (rows 10-19) weak. Targets
    # depend on B only: plain Q-DEIM with one point takes A, the goal-oriented one B.
    rng = np.random.default_rng(5)
    k = 60
    a, b = rng.normal(size=k), rng.normal(size=k)
    a -= a.mean()
    b -= b.mean()
    b -= (a @ b) / (a @ a) * a  # a ⟂ b: the modes are exactly a and b
    d = np.zeros((40, k))
    d[:10] = 10.0 * rng.uniform(0.5, 1.0, (10, 1)) * a
    d[10:20] = 1.0 * rng.uniform(0.5, 1.0, (10, 1)) * b
    d += 100.0  # a constant offset, removed by centring
    kw = {"normalise": False, "energy": 1.0, "qr_fraction": 1.0}
    plain = select_sensors(d, 1, **kw)
    goal = select_sensors(d, 1, 2.0 * b[None, :], **kw)
    assert plain.indices[0] < 10
    assert 10 <= goal.indices[0] < 20
    assert goal.method == "goal" and goal.target_energy[0] == pytest.approx(1.0)


def test_channels_are_stacked_like_the_mono_fit():
    rng = np.random.default_rng(6)
    d = rng.random((7, 5, 3))
    a = prepare_direct(d, normalise=False, centre=False)
    assert a.shape == (7, 15) and a.dtype == np.float64
    np.testing.assert_array_equal(a[:, 2 * 5 + 4], d[:, 4, 2])
    c = rng.random((4, 5, 3))
    np.testing.assert_array_equal(stack_coefficients(c)[:, 1 * 5 + 3], c[:, 3, 1])
    # normalisation: each configuration's Frobenius norm over points and channels is 1
    n = prepare_direct(d, centre=False).reshape(7, 3, 5)
    np.testing.assert_allclose(np.sqrt(np.sum(n**2, axis=(0, 1))), 1.0)
    # centring: every row has zero mean over the configurations of each channel
    m = prepare_direct(d).reshape(7, 3, 5)
    np.testing.assert_allclose(m.mean(axis=2), 0.0, atol=1e-15)
    # a zero configuration stays zero (never divided by)
    d[:, 2] = 0.0
    assert np.all(prepare_direct(d, centre=False).reshape(7, 3, 5)[:, :, 2] == 0.0)
    # per-channel selection works on (N, K, C) with matching (m, K, C) targets
    sel = select_sensors(rng.random((30, 5, 3)), 4, rng.random((2, 5, 3)))
    assert sel.indices.shape == (4,)
    with pytest.raises(ValueError, match="K·C"):
        select_sensors(rng.random((30, 5, 3)), 4, rng.random((2, 5)))


def test_select_sensors_refuses_bad_input():
    d = np.ones((10, 4))
    with pytest.raises(ValueError, match="count"):
        select_sensors(d, 11)
    with pytest.raises(ValueError, match="count"):
        select_sensors(d, 0)
    with pytest.raises(ValueError, match="non-finite"):
        select_sensors(np.full((10, 4), np.nan), 2)
    with pytest.raises(ValueError, match="positions"):
        select_sensors(d, 2, positions=np.zeros((9, 3)))
    with pytest.raises(ValueError, match="energy"):
        select_sensors(d, 2, energy=0.0)


def test_farthest_fill_spreads_points():
    pos = np.array([[0.0, 0, 0], [1, 0, 0], [0.1, 0, 0], [0.5, 0, 0], [0.9, 0, 0]])
    assert farthest_fill(pos, np.array([0]), 2).tolist() == [1, 3]
    assert farthest_fill(pos, np.array([0, 1]), 0).shape == (0,)
    with pytest.raises(ValueError):
        farthest_fill(pos, np.array([0]), 5)


def test_restrict_and_concat_points_keep_each_cluster(tmp_path):
    from prtcore.core.spec import PointsSpec
    from prtcore.intake.points import place_measurement_points
    from prtcore.io.gltf.loader import load_asset
    from prtcore.scenes.cornell import write_cornell_box

    scene = load_asset(write_cornell_box(tmp_path / "box.glb"))
    pts = place_measurement_points(scene, PointsSpec(count=40, supersample=3, seed=1))
    vals = np.random.default_rng(0).random((len(pts.cluster_owner), 2))
    full = pts.average_clusters(vals)
    rows = np.array([5, 0, 33, 12])
    sub = restrict_points(pts, rows)
    assert sub.count == 4 and np.all(np.diff(sub.cluster_owner) >= 0)
    np.testing.assert_array_equal(sub.position, pts.position[rows])
    # the same samples, owner by owner, in the new order
    sub_vals = np.concatenate([vals[pts.cluster_owner == r] for r in rows])
    np.testing.assert_allclose(sub.average_clusters(sub_vals), full[rows])
    with pytest.raises(ValueError, match="distinct"):
        restrict_points(pts, np.array([1, 1]))
    other = place_measurement_points(scene, PointsSpec(count=7, supersample=2, seed=2))
    both, rows2 = concat_points(pts, other)
    assert both.count == 47 and rows2 == [slice(0, 40), slice(40, 47)]
    assert np.all(np.diff(both.cluster_owner) >= 0)
    v2 = np.random.default_rng(1).random((len(other.cluster_owner), 2))
    avg = both.average_clusters(np.concatenate([vals, v2]))
    np.testing.assert_allclose(avg[rows2[0]], full)
    np.testing.assert_allclose(avg[rows2[1]], other.average_clusters(v2))


def test_fill_skips_candidates_no_light_reaches():
    rng = np.random.default_rng(8)
    d = rng.random((50, 20))
    dark = np.array([3, 4, 5, 40])
    d[dark] = 0.0  # buried or facing away: no training light reaches them
    pos = rng.normal(size=(50, 3))
    pos[dark] *= 100.0  # far away: the farthest-point fill would take them first
    sel = select_sensors(d, 30, positions=pos)
    assert not np.isin(dark, sel.indices).any()
    sel = select_sensors(d, 30, seed=1)
    assert not np.isin(dark, sel.indices).any()
    # unless nothing else is left
    assert np.isin(dark, select_sensors(d, 50, positions=pos).indices).all()
    picked = farthest_fill(pos, np.array([0]), 46 - 1, exclude=dark)
    assert len(set(picked.tolist())) == 45 and not np.isin(dark, picked).any()
    with pytest.raises(ValueError, match="excluded"):
        farthest_fill(pos, np.array([0]), 46, exclude=dark)
