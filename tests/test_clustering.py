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


@pytest.mark.parametrize("T", [0.3, 0.6, 2.0])
def test_kept_centers_are_the_kept_rows_in_a_new_array_each_read(T):
    """``kept_centers`` (made by the K-means kernel on the first read) is ``centers[kept]``
    byte for byte, and each read is a new array (a caller may change its copy)."""
    rng = np.random.default_rng(6)
    far = [400.0, 300.0, 0.0, 0.0, 20.0, 40.0]
    ps = cloud(rng, A, 0.7).concat(cloud(rng, far, 0.4)).concat(cloud(rng, B, 1.3))
    c = kmeans_peaks(ps, obs(A, far, B), T=T)
    want = c.centers[c.kept]
    first = c.kept_centers
    assert first.shape == want.shape and first.tobytes() == want.tobytes()
    first[:] = -1.0
    second = c.kept_centers
    assert second is not first and second.tobytes() == want.tobytes()


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


def _split_one_at_a_time(ps, Z, T, rule, max_splits=64, max_iter=50, tol=0.01):
    """kmeans_peaks' split loop spelt out in numpy, one candidate at a time (module docstring
    of trackers.phd.clustering): the heaviest non-final candidate, its farthest member, its
    nearest neighbours within twice its reach (by distance, then index), the guarded
    pre-check (the candidate's own mass), the local trial and its guarded acceptance."""
    from pfscope.trackers.phd import _kmeans_kernels
    from pfscope.trackers.phd.clustering import SPLIT_NEIGHBOURS, _lloyd
    from pfscope.trackers.phd.filter import PHDParams

    params = PHDParams()
    lk = params.likelihood
    guarded = rule == "guarded"
    init = np.zeros((len(Z), 6))
    init[:, [0, 1, 4, 5]] = Z
    _, w, shift, S, X, runs = _kmeans_kernels.prepare(ps.states.copy(),
                                                      ps.log_weights.copy())
    scale = np.exp(ps.log_weights.max())
    centers, labels, masses, dmin, n_iter = _lloyd(X, S, w, init - shift, params, max_iter, tol)
    masses = masses * scale
    final = np.zeros(len(centers), dtype=bool)
    n_splits = 0
    for _ in range(max_splits):
        cand = np.flatnonzero((masses > 1.0) & ~final)
        if not len(cand):
            break
        j = int(cand[np.argmax(masses[cand])])
        if guarded and masses[j] < 2.0 * T:         # its own mass cannot give two halves T
            final[j] = True
            continue
        members = np.flatnonzero(labels == j)
        far = int(members[np.argmax(dmin[members])]) if len(members) else -1
        if far < 0 or dmin[far] <= 0.0:
            final[j] = True
            continue
        inv_j = 1.0 / obs_std(centers[j, 4:6], lk) ** 2
        cols = [0, 1, 4, 5]
        dc = np.sum((centers[:, cols] - centers[j, cols]) ** 2 * inv_j, axis=1)
        near = np.flatnonzero(dc <= 4.0 * dmin[far])
        near = np.sort(near[np.argsort(dc[near], kind="stable")][:SPLIT_NEIGHBOURS])
        sel = np.flatnonzero(np.isin(labels, near))
        t_c, t_lab, t_m, t_d, it = _lloyd(X[sel], S[sel], w[sel],
                                          np.concatenate([centers[near], S[far][None]]),
                                          params, max_iter, tol)
        n_iter += it
        t_m = t_m * scale
        pos = int(np.searchsorted(near, j))
        if guarded and not (t_m[pos] >= T and t_m[-1] >= T):
            final[j] = True
            continue
        centers = np.concatenate([centers, t_c[-1:]])
        centers[near] = t_c[:-1]
        masses = np.append(masses, t_m[-1])
        masses[near] = t_m[:-1]
        labels[sel] = np.append(near, len(centers) - 1)[t_lab]
        dmin[sel] = t_d
        final = np.append(final, False)
        n_splits += 1
    # (runs of identical rows were merged: every particle gets its row's label)
    return centers + shift, masses, np.repeat(labels, runs), n_splits, n_iter


def _neighbours_reference(centers, j, reach2, n_max):
    """A split's neighbourhood (j and its nearest clusters within twice j's reach, at most
    n_max, by distance then index; ascending), in numpy."""
    inv_j = 1.0 / obs_std(centers[j, 4:6]) ** 2
    cols = [0, 1, 4, 5]
    dc = np.sum((centers[:, cols] - centers[j, cols]) ** 2 * inv_j, axis=1)
    near = np.flatnonzero(dc <= 4.0 * reach2)
    return np.sort(near[np.argsort(dc[near], kind="stable")][:n_max])


@pytest.mark.parametrize("seed", range(6))
def test_split_neighbours_are_the_nearest_within_reach(seed):
    # crowded and duplicated centres (distance ties), reaches exactly on a neighbour, NaN,
    # inf and 0 reaches: the kernel's neighbourhood is the numpy one
    from pfscope.trackers.phd._kmeans_kernels import split_neighbours
    from pfscope.trackers.phd.filter import LikelihoodParams

    rng = np.random.default_rng(seed)
    lk = LikelihoodParams()
    K = int(rng.integers(8, 40))
    centers = np.zeros((K, 6))
    centers[:, :2] = rng.uniform(0, 40, (K, 2))
    centers[:, 4:6] = rng.uniform(10, 40, (K, 2))
    dup = rng.integers(0, K, K // 3)
    centers[dup[1:]] = centers[dup[0]]
    out = np.empty(4, dtype=np.int64)
    for j in range(K):
        e = int(rng.integers(0, K))
        inv_j = 1.0 / obs_std(centers[j, 4:6]) ** 2
        on_e = np.sum((centers[e, [0, 1, 4, 5]] - centers[j, [0, 1, 4, 5]]) ** 2 * inv_j) / 4.0
        for reach2 in (on_e, 0.5, 9.0, 400.0, 0.0, np.nan, np.inf):
            n = split_neighbours(centers, K, j, reach2, 4, lk.sigma_obs, lk.sigma_obs_min,
                                 lk.sigma_obs_pos_ratio, out)
            assert out[:n].tolist() == _neighbours_reference(centers, j, reach2, 4).tolist()


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("rule", ["literal", "guarded"])
def test_split_loop_matches_the_one_at_a_time_rule(seed, rule):
    # the split loop's kernel must give the numpy loop's answer float for float: crowds with
    # more neighbours in reach than a trial takes (nearest by distance, then index), merged
    # targets (accepted splits), single heavy targets (rejected), duplicated detections
    # (equal masses and distances: ties), a cloud all on one point (no member off the centre)
    rng = np.random.default_rng(seed)
    parts, Z = [], []
    for _ in range(int(rng.integers(6, 14))):
        c = [rng.uniform(0, 50), rng.uniform(0, 50), 0.0, 0.0, rng.uniform(8, 20),
             rng.uniform(16, 40)]
        k = int(rng.integers(0, 4))
        if k == 0:                                   # two targets, one detection
            d = list(c)
            d[0] += c[4]
            parts += [cloud(rng, c, 1.0, n=150), cloud(rng, d, 1.0, n=150)]
        elif k == 1:                                 # one heavy target
            parts.append(cloud(rng, c, float(rng.choice([1.05, 1.3, 1.8])), n=200))
        elif k == 2:                                 # everything on the centre
            parts.append(ParticleSet(np.tile(c, (40, 1)), np.full(40, math.log(1.5 / 40))))
        else:
            parts.append(cloud(rng, c, 0.7, n=100))
        Z.append([c[0], c[1], c[4], c[5]])
        if rng.random() < 0.3:
            Z.append(Z[-1])                          # a duplicated detection
    ps = parts[0]
    for p in parts[1:]:
        ps = ps.concat(p)
    Z = np.array(Z)
    for max_splits in (64, 2):
        got = kmeans_peaks(ps, Z, 0.6, split_rule=rule, max_splits=max_splits)
        centers, masses, labels, n_splits, n_iter = _split_one_at_a_time(ps, Z, 0.6, rule,
                                                                         max_splits)
        np.testing.assert_array_equal(got.centers, centers)
        np.testing.assert_array_equal(got.masses, masses)
        np.testing.assert_array_equal(got.labels, labels)
        assert (got.n_splits, got.n_iter) == (n_splits, n_iter)
        assert got.origin.tolist()[len(Z):] == [ORIGIN_SPLIT] * n_splits


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


def test_subsample_runs_on_every_nth_equal_weight_particle():
    # equal weights (after resampling): K-means on every 2nd particle, each weighing twice
    # as much -- the masses keep their total, the peaks stay where the full run puts them,
    # the labels (taken when first read) are every particle's nearest centre
    from pfscope.trackers.phd.filter import PHDParams

    rng = np.random.default_rng(3)
    ps = cloud(rng, A, 1.0, n=1001).concat(cloud(rng, B, 1.0, n=1001))
    ps = ParticleSet(ps.states, np.full(len(ps), math.log(2.0 / len(ps))))
    full = kmeans_peaks(ps, obs(A, B))
    sub = kmeans_peaks(ps, obs(A, B), subsample=2)
    assert sub._labels is None                          # not taken before they are read
    assert sub.masses.sum() == pytest.approx(full.masses.sum(), rel=1e-12)
    assert sub.kept.tolist() == full.kept.tolist() == [True, True]
    np.testing.assert_allclose(sub.centers, full.centers, atol=1.0)
    assert not np.array_equal(sub.centers, full.centers)          # (it did subsample)
    inv = 1.0 / obs_std(sub.centers[:, 4:6], PHDParams().likelihood) ** 2
    d2 = (((ps.states[:, None, [0, 1, 4, 5]] - sub.centers[None, :, [0, 1, 4, 5]]) ** 2)
          * inv[None]).sum(-1)
    assert sub.labels.tolist() == np.argmin(d2, axis=1).tolist()
    # unequal weights: no subsample, the full run's answer
    uneq = ParticleSet(ps.states, ps.log_weights + rng.uniform(0, 1e-3, len(ps)))
    a, b = kmeans_peaks(uneq, obs(A, B)), kmeans_peaks(uneq, obs(A, B), subsample=2)
    np.testing.assert_array_equal(a.centers, b.centers)
    np.testing.assert_array_equal(a.labels, b.labels)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_guarded_split_is_tried_only_on_a_cluster_of_twice_min_split_mass(seed):
    # a single target of mass 1.15 beside another (their masses together pass the
    # neighbourhood pre-check): its own mass cannot give two halves of
    # min_split_mass (0.6), so no trial Lloyd runs (n_iter = the first run's) and it stays
    # whole; at 1.3 (and with min_split_mass 0.5 at 1.15) the trial runs; literal: always
    from pfscope.trackers.phd.clustering import _lloyd
    from pfscope.trackers.phd._kmeans_kernels import prepare
    from pfscope.trackers.phd.filter import PHDParams

    rng = np.random.default_rng(seed)
    far = [A[0] + 15.0] + A[1:]    # half a box width away: in the split's neighbourhood
    for mass, msm, tried in ((1.15, None, False), (1.3, None, True), (1.15, 0.5, True)):
        ps = cloud(rng, A, mass).concat(cloud(rng, far, 1.0))
        _, w, shift, S, X, _ = prepare(ps.states.copy(), ps.log_weights.copy())
        init = np.zeros((2, 6))
        init[:, [0, 1, 4, 5]] = obs(A, far)
        first = _lloyd(X, S, w, init - shift, PHDParams(), 50, 0.01)[4]
        c = kmeans_peaks(ps, obs(A, far), min_split_mass=msm)
        assert (c.n_iter > first) == tried, (mass, msm, c.n_iter, first)
        if not tried:
            assert c.n_splits == 0 and c.kept.all()
        lit = kmeans_peaks(ps, obs(A, far), split_rule="literal")
        assert lit.n_iter > first


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_copies_side_by_side_are_merged_with_the_same_clusters_and_labels(seed):
    # resampling lays an ancestor's copies side by side as identical rows: K-means runs on
    # the distinct rows with summed weights -- the same clusters (up to summation round-off)
    # as on the same particles shuffled so that no two copies are adjacent (nothing merged),
    # and every particle's label is its row's (taken when first read); a merged target
    # split in two (the split trials on merged rows), and the subsample option on top
    from pfscope.trackers.phd.filter import PHDParams

    rng = np.random.default_rng(seed)
    Bc = [A[0] + 20.0] + A[1:]                      # merged with A: one detection, a split
    C = [A[0] + 300.0] + A[1:]
    base = cloud(rng, A, 1.0, n=300).concat(cloud(rng, Bc, 1.0, n=300)).concat(
        cloud(rng, C, 1.1, n=300))
    copies = rng.integers(1, 5, len(base))
    states = np.repeat(base.states, copies, axis=0)
    n = len(states)
    lw = np.full(n, math.log(3.1 / n))
    side = ParticleSet(states, lw)
    while True:
        perm = rng.permutation(n)
        if np.all(np.any(states[perm][1:] != states[perm][:-1], axis=1)):
            break
    spread = ParticleSet(states[perm], lw)
    Z = obs(A, C)
    a = kmeans_peaks(side, Z)
    b = kmeans_peaks(spread, Z)
    assert a._labels is None and b._labels is not None          # a merged, b not
    assert a.n_splits == b.n_splits == 1 and (a.n_iter, a.kept.tolist()) == (b.n_iter,
                                                                             b.kept.tolist())
    np.testing.assert_allclose(a.centers, b.centers, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.masses, b.masses, rtol=1e-12)
    assert len(a.labels) == n
    assert a.labels[perm].tolist() == b.labels.tolist()
    # subsample: every 2nd particle (merged too), then every particle's nearest centre
    s = kmeans_peaks(side, Z, subsample=2)
    assert s.kept.tolist() == a.kept.tolist() and s.masses.sum() == pytest.approx(3.1)
    inv = 1.0 / obs_std(s.centers[:, 4:6], PHDParams().likelihood) ** 2
    d2 = (((states[:, None, [0, 1, 4, 5]] - s.centers[None, :, [0, 1, 4, 5]]) ** 2)
          * inv[None]).sum(-1)
    assert s.labels.tolist() == np.argmin(d2, axis=1).tolist()
