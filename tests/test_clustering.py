"""trackers.phd.clustering: the modified K-means of maggio2007 §3 on hand-made PHD clouds."""

import math

import numpy as np
import pytest

from pfscope.trackers.phd.clustering import ORIGIN_EXTRA, ORIGIN_SPLIT, kmeans_peaks
from pfscope.trackers.phd.filter import obs_std
from pfscope.trackers.smc import ParticleSet


def cloud(rng, center, mass, n=1500):
    """Gaussian cloud of total weight ``mass`` around a state, as wide as the observation noise."""
    c = np.asarray(center, dtype=np.float64)
    s = obs_std(c[4:6])
    std = np.array([s[0], s[1], 0.3, 0.3, s[2], s[3]])
    return ParticleSet(c + rng.standard_normal((n, 6)) * std, np.full(n, math.log(mass / n)))


def line_cloud(center, mass, n=20, half_width=6.0):
    """Deterministic, mirror-symmetric cloud along y1: K-means cuts it into equal halves."""
    c = np.asarray(center, dtype=np.float64)
    s = np.tile(c, (n, 1))
    s[:, 0] += np.linspace(-half_width, half_width, n)
    return ParticleSet(s, np.full(n, math.log(mass / n)))


A = [100.0, 100.0, 1.0, 0.0, 30.0, 60.0]
B = [130.0, 100.0, 0.0, 1.0, 30.0, 60.0]     # one box width to the right of A


def obs(*states):
    return np.array([[s[0], s[1], s[4], s[5]] for s in states])


def test_literal_split_rule_cuts_a_single_target_and_loses_it():
    # Steady-state mass of one target without clutter is 1/(1 - p_M e) ≈ 1.05 > 1.
    ps = line_cloud(A, 1.05)
    lit = kmeans_peaks(ps, obs(A), split_rule="literal")
    # two near-halves (Lloyd stops within a sample spacing of the middle), both below T
    assert len(lit) == 2 and lit.masses.sum() == pytest.approx(1.05)
    assert np.all(np.abs(lit.masses - 0.525) < 0.06)
    assert not lit.kept.any()                                   # the target vanished
    # Same on a random cloud: always fragmented, some of the target's mass discarded.
    g = cloud(np.random.default_rng(0), A, 1.05)
    lit = kmeans_peaks(g, obs(A), split_rule="literal")
    assert lit.n_splits >= 1 and np.all(lit.masses <= 1.0)
    assert lit.kept_masses.sum() < 1.05 - 0.2


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_guarded_split_keeps_a_single_target_whole(seed):
    for ps in (line_cloud(A, 1.05), cloud(np.random.default_rng(seed), A, 1.05)):
        c = kmeans_peaks(ps, obs(A))
        assert len(c) == 1 and c.kept.all() and c.n_splits == 0
        assert c.masses[0] == pytest.approx(1.05)
        assert np.all(c.labels == 0)


@pytest.mark.parametrize("rule", ["guarded", "literal"])
def test_two_merged_targets_split_into_two(rule):
    # Only one detection (on A) for two adjacent targets of mass ~1 each.
    rng = np.random.default_rng(3)
    ps = cloud(rng, A, 1.0).concat(cloud(rng, B, 1.0))
    c = kmeans_peaks(ps, obs(A), split_rule=rule)
    assert c.n_splits == 1 and c.kept.sum() == 2
    np.testing.assert_allclose(np.sort(c.masses), [1.0, 1.0], atol=0.03)
    order = np.argsort(c.centers[:, 0])
    np.testing.assert_allclose(c.centers[order][:, [0, 1, 4, 5]], obs(A, B), atol=1.5)
    # the velocity is averaged into the centres (the paper initialises it at zero)
    np.testing.assert_allclose(c.centers[order][:, 2:4], [A[2:4], B[2:4]], atol=0.05)
    np.testing.assert_array_equal(c.origin, [0, ORIGIN_SPLIT])


def test_literal_rule_iterates_until_every_mass_is_at_most_one():
    rng = np.random.default_rng(4)
    C = [115.0, 150.0, 0.0, 0.0, 30.0, 60.0]
    ps = cloud(rng, A, 1.0).concat(cloud(rng, B, 1.0)).concat(cloud(rng, C, 1.0))
    c = kmeans_peaks(ps, np.zeros((0, 4)), split_rule="literal")
    assert np.all(c.masses <= 1.0 + 1e-9)
    assert c.masses.sum() == pytest.approx(3.0)
    g = kmeans_peaks(ps, np.zeros((0, 4)))
    assert g.kept.sum() == 3 and g.n_splits == 2
    assert g.origin[0] == ORIGIN_EXTRA                  # no detection: weighted-mean start


def test_clusters_below_T_are_discarded():
    rng = np.random.default_rng(5)
    far = [400.0, 300.0, 0.0, 0.0, 20.0, 40.0]
    ps = cloud(rng, A, 0.7).concat(cloud(rng, far, 0.4))
    c = kmeans_peaks(ps, obs(A, far), T=0.6)
    np.testing.assert_allclose(c.masses, [0.7, 0.4])
    np.testing.assert_array_equal(c.kept, [True, False])
    np.testing.assert_allclose(c.kept_centers[:, [0, 1, 4, 5]], obs(A), atol=1.0)
    assert len(kmeans_peaks(ps, obs(A, far), T=0.3).kept_centers) == 2


def test_centres_are_mass_weighted_means():
    # Two particles of one cluster, the heavier one pulls the centre three quarters of the way.
    s = np.array([[100.0, 100.0, 0, 0, 30, 60], [104.0, 100.0, 2.0, 0, 30, 60]])
    ps = ParticleSet(s, np.log([0.2, 0.6]))
    c = kmeans_peaks(ps, obs(A))
    np.testing.assert_allclose(c.centers[0], [103.0, 100.0, 1.5, 0, 30, 60])
    assert c.masses[0] == pytest.approx(0.8)


def test_centres_start_on_observations_with_zero_velocity():
    Z = obs(A, B)
    c = kmeans_peaks(ParticleSet.empty(6), Z)
    np.testing.assert_allclose(c.centers[:, [0, 1, 4, 5]], Z)
    assert np.all(c.centers[:, 2:4] == 0)
    assert not c.kept.any() and len(c.labels) == 0
    np.testing.assert_allclose(c.boxes()[0], [85.0, 70.0, 30.0, 60.0])


def test_distance_is_scaled_by_size():
    # A particle 12 px from a small box and 16 px from a big one belongs to the big one:
    # the metric is the observation noise, which grows with the box.
    small = [100.0, 100.0, 0, 0, 10.0, 20.0]
    big = [128.0, 100.0, 0, 0, 60.0, 120.0]
    s = np.array([[112.0, 100.0, 0, 0, 35.0, 70.0]])
    c = kmeans_peaks(ParticleSet(s, np.zeros(1)), obs(small, big))
    assert c.labels[0] == 1


def test_clustering_is_deterministic_and_survives_tiny_weights():
    rng = np.random.default_rng(6)
    ps = cloud(rng, A, 1.0).concat(cloud(rng, B, 1.0))
    a = kmeans_peaks(ps, obs(A))
    b = kmeans_peaks(ps, obs(A))
    np.testing.assert_array_equal(a.centers, b.centers)
    np.testing.assert_array_equal(a.labels, b.labels)
    tiny = ParticleSet(ps.states, ps.log_weights - 800.0)   # masses ~1e-348 underflow
    t = kmeans_peaks(tiny, obs(A))
    np.testing.assert_allclose(t.centers, kmeans_peaks(ps, obs(A), split_above=np.inf).centers)
    assert not t.kept.any()
    with pytest.raises(ValueError):
        kmeans_peaks(ps, obs(A), split_rule="bogus")


def _precheck_one(centers, masses, dmin, far_of, j, lk, need):
    """The guarded pre-check of one split candidate, as kmeans_peaks took it one at a time."""
    from pfscope.trackers.phd.clustering import _split_neighbours

    far = int(far_of[j])
    if far < 0 or dmin[far] <= 0.0:
        return False
    return not masses[_split_neighbours(centers, j, dmin[far], lk)].sum() < need


@pytest.mark.parametrize("seed", range(6))
def test_split_prechecks_of_all_candidates_match_one_at_a_time(seed):
    # the batched pre-check must give every candidate the answer (and the floats) of the
    # one-at-a-time loop: nearest neighbours by distance then index (ties from duplicated
    # centres), masses summed in index order, members on the centre, empty clusters, NaN
    from pfscope.trackers.phd.clustering import _split_neighbours, _split_prechecks
    from pfscope.trackers.phd.filter import LikelihoodParams

    rng = np.random.default_rng(seed)
    lk = LikelihoodParams()
    K = int(rng.integers(8, 40))
    centers = np.zeros((K, 6))
    centers[:, :2] = rng.uniform(0, 40, (K, 2))          # crowded: several neighbours in reach
    centers[:, 4:6] = rng.uniform(10, 40, (K, 2))
    dup = rng.integers(0, K, K // 3)
    centers[dup[1:]] = centers[dup[0]]                  # equal distances: ties
    masses = rng.choice([0.3, 0.35, 0.4, 0.6, 1.05, 2.0], K)
    dmin = rng.choice([0.0, 0.5, 2.0, 9.0, 40.0, 400.0, np.nan, np.inf], 3 * K)
    far_of = rng.integers(-1, 3 * K, K)
    for j in rng.integers(0, K, K // 2):                # reaches exactly on a neighbour
        far_of[j] = int(rng.integers(0, 3 * K))
        e = int(rng.integers(0, K))
        inv_j = 1.0 / obs_std(centers[j, 4:6]) ** 2
        dmin[far_of[j]] = np.sum((centers[e, [0, 1, 4, 5]] - centers[j, [0, 1, 4, 5]]) ** 2
                                 * inv_j) / 4.0
    order = rng.permutation(K)[: int(rng.integers(1, K + 1))]
    for need in (1.2, 1.3, 2.0, -np.inf):
        got, nears = _split_prechecks(centers, masses, dmin, far_of, order, lk, need)
        want = [_precheck_one(centers, masses, dmin, far_of, j, lk, need) if need > -np.inf
                else bool(far_of[j] >= 0 and not dmin[far_of[j]] <= 0.0) for j in order]
        assert got.tolist() == want
        for j, near in zip(order, nears):      # the trials' neighbours, when given
            if near is not None:
                assert near.tolist() == _split_neighbours(centers, j, dmin[far_of[j]],
                                                          lk).tolist()
        if need > -np.inf:
            assert all(n is not None for n, g in zip(nears, got) if g)


@pytest.mark.parametrize("rule", ["literal", "guarded"])
def test_every_split_candidate_of_a_crowd_is_looked_at(rule):
    # more split candidates than one pre-check batch, the heaviest ones impossible to split
    # (every member on the centre): every candidate is still looked at -- literal: every
    # other mass ends at most 1; guarded: every pair of merged targets is split
    rng = np.random.default_rng(7)
    n_pairs, n_points = 24, 24
    states, Z = [], []
    for k in range(n_pairs + n_points):
        a = [60.0 + 200.0 * (k % 8), 100.0 + 300.0 * (k // 8), 0.0, 0.0, 30.0, 60.0]
        if k < n_pairs:         # two targets one box width apart, one detection between them
            b = [a[0] + 30.0, a[1], 0.0, 0.0, 30.0, 60.0]
            states += [cloud(rng, a, 1.0, n=200), cloud(rng, b, 1.0, n=200)]
            Z.append([a[0] + 15.0, a[1], 30.0, 60.0])
        else:                   # mass 3+ on one point: a heavier candidate with nothing to split
            m = 3.0 + 0.01 * k
            states.append(ParticleSet(np.tile(a, (50, 1)), np.full(50, math.log(m / 50))))
            Z.append([a[0], a[1], a[4], a[5]])
    ps = states[0]
    for s in states[1:]:
        ps = ps.concat(s)
    c = kmeans_peaks(ps, np.array(Z), split_rule=rule, max_splits=1000)
    if rule == "literal":
        assert np.all((c.masses <= 1.0 + 1e-9) | (c.masses >= 3.0))
    else:
        assert c.n_splits == n_pairs and c.kept.sum() == 2 * n_pairs + n_points
