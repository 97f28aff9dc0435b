"""Bounded cost under clutter storms (issue 13 item 5) and the bounded modified K-means
(maggio2007 §3, issue 12): counts, not times — births capped, K-means iterations and split
attempts bounded, weights finite, and the local split trial behaves like the global one."""

import math

import numpy as np
import pytest
from pfscope.trackers.phd.clustering import kmeans_peaks
from pfscope.trackers.phd.filter import PHDFilter, PHDParams, obs_std
from pfscope.trackers.smc import ParticleSet


def _storm(rng, n_det, W=640.0, H=480.0):
    w = rng.uniform(15, 60, n_det)
    return np.c_[rng.uniform(0, W, n_det), rng.uniform(0, H, n_det), w,
                 w * rng.uniform(2, 3, n_det)]


def _cloud(rng, center, mass, n):
    c = np.asarray(center, dtype=np.float64)
    s = obs_std(c[4:6])
    std = np.array([s[0], s[1], 0.3, 0.3, s[2], s[3]])
    return ParticleSet(c + rng.standard_normal((n, 6)) * std, np.full(n, math.log(mass / n)))


@pytest.fixture(scope="module")
def storm_run():
    """A small storm: 400 clutter detections per frame for 6 frames, with the birth cap and the
    particle cap lowered so the test is quick; the same caps bind at 2,000 detections."""
    p = PHDParams.of(max_births_per_frame=8000, max_particles=12000)
    f = PHDFilter(p, np.random.default_rng(1))
    rng = np.random.default_rng(0)
    steps = []
    for _ in range(6):
        Z = _storm(rng, 400)
        r = f.step(Z)
        c = kmeans_peaks(r.resampled, Z)
        steps.append((r, c, Z))
    return p, steps


def test_storm_births_are_capped_and_weights_finite(storm_run):
    p, steps = storm_run
    cap = p.birth.max_births_per_frame
    for r, c, Z in steps:
        assert 0 < len(r.born) <= cap
        # the cap scales every J_z by the same factor: no detection gets more than j_max
        assert r.birth.j_per_det.max() <= p.birth.j_max
        assert len(r.resampled) <= p.resampling.max_particles
        for ps in (r.predicted, r.updated.particles, r.resampled):
            assert np.all(np.isfinite(ps.log_weights)) and np.all(np.isfinite(ps.states))
        assert math.isfinite(r.mass) and r.mass >= 0
        assert np.all(np.isfinite(c.masses)) and np.all(np.isfinite(c.centers))


def test_storm_kmeans_work_is_bounded(storm_run):
    _, steps = storm_run
    max_iter, max_splits = 50, 64                   # kmeans_peaks' defaults
    for r, c, Z in steps:
        assert len(c) >= len(Z)                     # a centre per detection, plus splits
        assert len(c) - len(Z) == c.n_splits <= max_splits
        # the first run and every split trial are each capped at max_iter iterations
        assert c.n_iter <= max_iter * (1 + max_splits)
        assert len(c.labels) == len(r.resampled)
        np.testing.assert_allclose(c.masses.sum(), r.resampled.mass, rtol=1e-9)


def test_max_iter_and_max_splits_cap_the_work():
    rng = np.random.default_rng(2)
    # eight clusters of three merged targets each, one detection per cluster
    parts, Z = [], []
    for i in range(8):
        a = np.array([80.0 * i, 100.0, 0.0, 0.0, 30.0, 70.0])
        for dx in (0.0, 25.0, 50.0):
            parts.append(_cloud(rng, a + [dx, 0, 0, 0, 0, 0], 1.0, 300))
        Z.append(a[[0, 1, 4, 5]])
    ps = parts[0]
    for q in parts[1:]:
        ps = ps.concat(q)
    Z = np.array(Z)
    full = kmeans_peaks(ps, Z)
    assert full.n_splits == 16 and full.kept.sum() == 24        # every target found
    few = kmeans_peaks(ps, Z, max_splits=3)
    assert few.n_splits <= 3
    one = kmeans_peaks(ps, Z, max_iter=1, max_splits=0)
    assert one.n_iter == 1 and one.n_splits == 0
    # a single iteration still returns each particle's nearest centre
    inv = 1.0 / obs_std(one.centers[:, 4:6]) ** 2
    X, C = ps.states[:, [0, 1, 4, 5]], one.centers[:, [0, 1, 4, 5]]
    d2 = sum((X[:, d, None] - C[None, :, d]) ** 2 * inv[None, :, d] for d in range(4))
    np.testing.assert_array_equal(one.labels, np.argmin(d2, axis=1))


def test_tolerance_stops_lloyd_without_moving_the_peaks():
    rng = np.random.default_rng(4)
    ps = _cloud(rng, [100, 100, 0, 0, 30, 60], 1.0, 2000).concat(
        _cloud(rng, [125, 100, 0, 0, 30, 60], 1.0, 2000))
    Z = np.array([[100.0, 100, 30, 60], [125, 100, 30, 60]])
    exact = kmeans_peaks(ps, Z, tol=0.0)
    loose = kmeans_peaks(ps, Z, tol=0.5)
    assert loose.n_iter <= exact.n_iter
    np.testing.assert_allclose(loose.kept_centers[:, [0, 1, 4, 5]],
                               exact.kept_centers[:, [0, 1, 4, 5]], atol=1.0)
    np.testing.assert_allclose(loose.masses, exact.masses, atol=0.05)


def test_a_split_only_moves_the_clusters_around_it():
    """The split trial runs on the heavy cluster and its nearest neighbours only: a merged pair
    is split into its two targets, and clusters far from it keep exactly their particles."""
    rng = np.random.default_rng(7)
    parts, Z = [], []
    for i in range(40):                                  # 40 single targets in a row
        a = np.array([100.0 + 120 * i, 300.0, 0.0, 0.0, 30.0, 70.0])
        parts.append(_cloud(rng, a, 0.8, 200))
        Z.append(a[[0, 1, 4, 5]])
    A = np.array([100.0, 600.0, 0.0, 0.0, 30.0, 70.0])  # and a merged pair, one detection
    parts += [_cloud(rng, A, 0.9, 400), _cloud(rng, A + [26, 0, 0, 0, 0, 0], 0.9, 400)]
    Z.append(A[[0, 1, 4, 5]])
    ps = parts[0]
    for q in parts[1:]:
        ps = ps.concat(q)
    Z = np.array(Z)
    c = kmeans_peaks(ps, Z)
    nosplit = kmeans_peaks(ps, Z, max_splits=0)
    assert c.n_splits == 1 and c.kept.sum() == 42
    np.testing.assert_allclose(np.sort(c.masses[[40, 41]]), [0.9, 0.9], atol=0.05)
    np.testing.assert_array_equal(c.labels[:8000], nosplit.labels[:8000])
    np.testing.assert_array_equal(c.masses[:40], nosplit.masses[:40])
