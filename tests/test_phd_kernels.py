"""The numba kernels of the PHD filter and its K-means (trackers/phd/_kernels.py, _kmeans_kernels.py) against
brute-force numpy references on random inputs: dense matrices, every pair, every centre."""


import _libm as libm
import numpy as np
import pytest
from numba import njit
from pfscope.trackers.phd import _kernels as K
from pfscope.trackers.phd import _kmeans_kernels as KM
from pfscope.trackers.phd.filter import (
    GatedGaussian,
    LikelihoodParams,
    PHDFilter,
    PHDParams,
    _NO_GRID,
    _grid_cell,
    _birth_weight_terms,
    _weight_consts,
    as_observations,
    detection_noise,
    log_birth_weight,
    log_likelihood,
    mass_near,
    obs_std,
    observations_noise,
    update,
)
from pfscope.trackers.phd.gating import tail_radius2
from pfscope.trackers.smc import ParticleSet
from pfscope.trackers.smc import random as R
from pfscope.trackers.smc.resampling import _systematic_index, _systematic_take

_NO_F = np.zeros(0, np.float64)
_NO_LOGS = np.zeros((0, 4), np.float64)


def _birth_consts(j_max, complement, cap, lk, spread, speed_mean, speed_std, min_size, lw_c):
    """:func:`K.birth_alloc_fill`'s settings array (read-only, as the filter makes it)."""
    c = np.array([j_max, 1.0 if complement else 0.0, cap, lk.sigma_obs, lk.sigma_obs_min,
                  lk.sigma_obs_pos_ratio, spread, speed_mean, speed_std, min_size, *lw_c],
                 dtype=np.float64)
    assert K.BIRTH_LW_C == 10
    c.setflags(write=False)
    return c

OBS = [0, 1, 4, 5]


def _states(rng, n, spread=300.0, far=0):
    x = np.empty((n, 6))
    x[:, :2] = rng.uniform(-spread, spread, (n, 2))
    x[:, 2:4] = rng.normal(0, 2, (n, 2))
    x[:, 4] = rng.uniform(10, 60, n)
    x[:, 5] = x[:, 4] * rng.uniform(1.5, 3, n)
    if far:
        x[:far, :2] += rng.uniform(-1e5, 1e5, (far, 2))
    return x


def _dets_near(rng, states, nz, clutter=3):
    """Detections on some particles (noisy) plus a few anywhere."""
    pick = rng.choice(len(states), nz, replace=False)
    Z = states[pick][:, OBS] + rng.normal(0, 2, (nz, 4))
    Z[:clutter, :2] = rng.uniform(-400, 400, (min(clutter, nz), 2))
    Z[:, 2:4] = np.abs(Z[:, 2:4]) + 2
    return Z


# ----------------------------------------------------------------------------- predict, birth

def test_propagate_kernel_is_the_numpy_model_bit_for_bit():
    rng = np.random.default_rng(0)
    x = _states(rng, 500)
    x[:10, 4:6] = 0.5                                  # clipped to min_size
    out = np.empty_like(x)
    lw = rng.normal(-7, 2, 500)
    lw[:3] = [-np.inf, 0.0, 1e-300]
    lw_out = np.full(505, np.nan)
    K.propagate_into(x, R.stream(123), 0.03, 0.1, 0.5, 1.0, out, lw, np.log(0.99), lw_out,
                      np.empty(0))
    np.testing.assert_array_equal(lw_out[:500], lw + np.log(0.99))   # numpy's add
    assert np.isnan(lw_out[500:]).all()
    out2 = np.empty_like(x)                            # without weights: the same states
    K.propagate_into(x, R.stream(123), 0.03, 0.1, 0.5, 1.0, out2, np.empty(0), 0.0, lw_out,
                      np.empty(0))
    np.testing.assert_array_equal(out2, out)
    eps = np.empty(500 * 4)                            # the same stream, 4 normals a particle
    R.fill_normal(R.stream(123), eps)
    eps = eps.reshape(500, 4)
    want = x.copy()
    size = x[:, 4:6]
    acc = 0.03 * size * eps[:, 0:2]
    want[:, 0:2] += x[:, 2:4] + 0.5 * acc
    want[:, 2:4] += acc
    want[:, 4:6] = np.maximum(size + 0.1 * size * eps[:, 2:4], 1.0)
    np.testing.assert_array_equal(out, want)
    assert np.all(out[:, 4:6] >= 1.0)


def _birth(Z, j, lw_det, key, spread=1.3, mean=0.05, std=0.1, min_size=4.0):
    lk = LikelihoodParams()
    n = int(j.sum())
    states, log_w, det = np.empty((n, 6)), np.empty(n), np.empty(n, np.int64)
    K.birth_fill(Z, j, lw_det, R.stream(key), lk.sigma_obs, lk.sigma_obs_min,
                 lk.sigma_obs_pos_ratio, spread, mean, std, min_size, states, log_w, det)
    return states, log_w, det


def test_birth_fill_draws_the_newborn_distribution():
    """Each detection's newborn: (y, w, h) ~ N(z, (spread σ(z))²), speed / sqrt(w h) ~
    N(mean, std²) along a uniform direction; det and weights exact; same key, same newborn."""
    rng = np.random.default_rng(1)
    Z = np.c_[rng.uniform(0, 600, 4), rng.uniform(0, 400, 4), rng.uniform(20, 60, 4),
              rng.uniform(40, 150, 4)]
    j = np.array([0, 20000, 1, 30000])
    lw_det = rng.normal(-5, 1, 4)
    states, log_w, det = _birth(Z, j, lw_det, 7)
    d = np.repeat(np.arange(4), j)
    np.testing.assert_array_equal(det, d)
    np.testing.assert_array_equal(log_w, lw_det[d])
    lk = LikelihoodParams()
    for z in (1, 3):
        s = states[d == z]
        q = (s[:, OBS] - Z[z]) / (1.3 * obs_std(Z[z, 2:4], lk))
        assert np.abs(q.mean(0)).max() < 4 / np.sqrt(j[z])          # ~4 standard errors
        assert np.abs(q.std(0) - 1).max() < 0.03
        v = s[:, 2:4] / np.sqrt(Z[z, 2] * Z[z, 3])
        speed = np.hypot(v[:, 0], v[:, 1])
        # a signed Gaussian amplitude along a uniform direction: E|v| = E|N(0.05, 0.1²)|,
        # E v = 0, E cos² θ = 1/2
        assert abs(np.mean(speed ** 2) - (0.05 ** 2 + 0.1 ** 2)) < 0.05 * 0.0125
        assert np.abs(v.mean(0)).max() < 4 * 0.112 / np.sqrt(j[z])
        c2 = v[:, 0] ** 2 / speed ** 2
        assert abs(c2.mean() - 0.5) < 4 * 0.354 / np.sqrt(j[z])
    again, _, _ = _birth(Z, j, lw_det, 7)
    np.testing.assert_array_equal(again, states)
    other, _, _ = _birth(Z, j, lw_det, 8)
    assert not np.array_equal(other, states)
    small = Z.copy()
    small[:, 2:4] = 3.0                                # boxes below min_size get clipped
    s, _, _ = _birth(small, j, lw_det, 7)
    assert s[:, 4:6].min() == 4.0


@njit(cache=False)
def _subkey(key, j):
    return R.subkey(key, j)


def test_birth_fill_is_its_numpy_model_on_the_generators_draws():
    """Newborn k (counted over every detection) takes normals 4k … 4k + 3 of the key for ε,
    normal k of subkey 0 for the speed, the direction of word k of subkey 1 for θ: the kernel's
    chunked loops (newborn counts across chunk boundaries, odd ones, an empty detection) give
    numpy's arithmetic on those draws bit for bit."""
    rng = np.random.default_rng(4)
    Z = np.c_[rng.uniform(0, 600, 5), rng.uniform(0, 400, 5), rng.uniform(2, 60, 5),
              rng.uniform(3, 150, 5)]
    Z[4, 2:4] = 4.2, 4.5                               # some of its newborn clipped
    j = np.array([3, 0, 301, 1, 500])
    lw_det = rng.normal(-5, 1, 5)
    key = 2 ** 63 + 12345
    states, log_w, det = _birth(Z, j, lw_det, key, min_size=4.0)
    n = int(j.sum())
    d = np.repeat(np.arange(5), j)
    eps = np.empty(4 * n)
    R.fill_normal(R.stream(key), eps)
    eps = eps.reshape(n, 4)
    nn = np.empty(n)
    R.fill_normal(R.stream(int(_subkey(np.uint64(key), 0))), nn)
    dc, ds = np.empty(n), np.empty(n)
    R.fill_direction(R.stream(int(_subkey(np.uint64(key), 1))), dc, ds)
    lk = LikelihoodParams()
    sig = np.maximum(lk.sigma_obs * Z[d, 2:4], lk.sigma_obs_min)
    spread = np.c_[1.3 * (lk.sigma_obs_pos_ratio * sig), 1.3 * sig]
    want = np.empty((n, 6))
    want[:, [0, 1, 4, 5]] = Z[d] + spread * eps
    want[:, 4:6] = np.where(want[:, 4:6] < 4.0, 4.0, want[:, 4:6])
    speed = (0.05 + 0.1 * nn) * np.sqrt(Z[d, 2] * Z[d, 3])
    want[:, 2] = speed * dc
    want[:, 3] = speed * ds
    np.testing.assert_array_equal(states, want)
    np.testing.assert_array_equal(det, d)
    np.testing.assert_array_equal(log_w, lw_det[d])
    assert (states[:, 4:6] == 4.0).any()


def _numpy_births(m_near, j_max, complement, cap, lw_base, revive, log_revive):
    """J_z and the newborn log-weights as the birth computed them in numpy."""
    if complement:
        j = np.rint(j_max * np.maximum(0.0, 1.0 - m_near)).astype(np.int64)
    else:
        j = np.full(len(m_near), int(j_max), dtype=np.int64)
    total = int(j.sum())
    if total > cap:
        j = np.floor(j * (cap / total)).astype(np.int64)
    lw_det = lw_base - np.log(np.maximum(j, 1))
    if revive is not None:
        lw_det = lw_det + np.where(revive, log_revive, 0.0)
    return j, lw_det


def test_grid_cell_kernel_is_numpys_median_cell():
    """The grid cells' kernel gives the floats of the numpy spelling (np.sort of the first two
    std columns, the middle value or the mean of the two middle ones: np.median's without
    NaN) on odd and even counts, ties, zeros (-> 1), inf, NaN (sorted last), bit for bit."""
    rng = np.random.default_rng(3)
    for t in range(3000):
        n = int(rng.integers(1, K.GRID_CELL_MAX + 1))
        std = rng.random((n, 4)) * 10.0 ** rng.uniform(-3, 3)
        if t % 5 == 0:
            std[:, :2] = np.round(std[:, :2], 1)                    # ties
        if t % 7 == 0:
            std[rng.integers(0, n)] = 0.0
        if t % 11 == 0:
            std[rng.integers(0, n), 0] = np.inf
        if t % 13 == 0:
            std[rng.integers(0, n, 1 + t % 3), 1] = np.nan
        r2 = float(rng.uniform(1, 70))
        srt, h = np.sort(std[:, :2], axis=0), n // 2
        cell = 2.0 * np.sqrt(r2) * (srt[h] if n % 2 else (srt[h - 1] + srt[h]) / 2.0)
        want = np.where(cell > 0, cell, 1.0)
        if not np.isnan(std[:, :2]).any():
            np.testing.assert_array_equal(cell, 2.0 * np.sqrt(r2) * np.median(std[:, :2], 0))
        np.testing.assert_array_equal(K.grid_cell(std, r2).view(np.int64), want.view(np.int64))
    for n in (K.GRID_CELL_MAX + 1, 300):              # more detections: numpy's own sort
        std = rng.random((n, 4))
        srt = np.sort(std[:, :2], axis=0)
        np.testing.assert_array_equal(_grid_cell(std, 9.0),
                                      6.0 * (srt[n // 2] if n % 2 else
                                             (srt[n // 2 - 1] + srt[n // 2]) / 2.0))


@pytest.mark.parametrize("seed", range(6))
def test_birth_alloc_fill_is_numpys_allocation_and_birth_fill(seed):
    """The one-call birth (J_z, the newborn log-weights, the fill) gives numpy's J_z and
    log-weights bit for bit (rint ties, the per-frame cap's floor, revive odds, M(z) above 1,
    NaN) and birth_fill's newborn for them, into the first J rows of larger buffers."""
    rng = np.random.default_rng(seed)
    lk = LikelihoodParams()
    nz = int(rng.integers(1, 30))
    Z = np.c_[rng.uniform(0, 600, nz), rng.uniform(0, 400, nz), rng.uniform(5, 60, nz),
              rng.uniform(10, 150, nz)]
    m_near = rng.choice([0.0, 0.25, 0.5, 0.9995, 1.0, 1.7, 0.0005, 0.0015],
                        nz) + (rng.random(nz) if seed % 2 else 0.0)
    lw_base = rng.normal(-4, 2, nz)
    for complement, j_max, cap, rev in ((True, 1000, 50_000, False), (True, 1000, 1234, True),
                                        (False, 300, 50_000, True), (False, 300, 777, False),
                                        (True, 7, 50_000, True)):
        revive = rng.random(nz) < 0.4 if rev else None
        j_np, lw_np = _numpy_births(m_near, j_max, complement, cap, lw_base, revive, 0.7)
        n_max = min(nz * j_max, cap)
        states, log_w = np.full((n_max + 5, 6), np.nan), np.full(n_max + 5, np.nan)
        det = np.full(n_max + 5, -1, np.int64)
        c = _birth_consts(j_max, complement, cap, lk, 1.3, 0.05, 0.1, 4.0, _NO_F)
        j, n = K.birth_alloc_fill(m_near, c, lw_base, 0, _NO_LOGS,
                                  revive if rev else np.zeros(0, np.bool_), 0.7, Z,
                                  R.stream(11), states, log_w, det)
        np.testing.assert_array_equal(j, j_np)
        assert n == j_np.sum() <= n_max
        want, want_lw, want_det = _birth(Z, j_np, lw_np, 11)
        np.testing.assert_array_equal(states[:n], want)
        np.testing.assert_array_equal(log_w[:n].view(np.int64), want_lw.view(np.int64))
        np.testing.assert_array_equal(det[:n], want_det)
        assert np.isnan(states[n:]).all() and (det[n:] == -1).all()     # nothing past J
    m_nan = m_near.copy()
    m_nan[0] = np.nan                     # rint(NaN) as int64: whatever numpy makes of it
    with np.errstate(invalid="ignore"):
        j_np, _ = _numpy_births(m_nan, 1000, False, 50_000, lw_base, None, 0.0)
    np.testing.assert_array_equal(K.birth_counts(m_nan, 1000, False, 50_000), j_np)
    # complement reads M(z): a NaN one gives a negative J_z, and nothing is written (J = -1);
    # so does a total larger than the buffers
    for m, rows in ((m_nan, 50_000), (m_near * 0.0, 10)):
        states, log_w = np.full((rows, 6), np.nan), np.full(rows, np.nan)
        det = np.full(rows, -1, np.int64)
        with np.errstate(invalid="ignore"):
            _, n = K.birth_alloc_fill(m, _birth_consts(1000, True, 50_000, lk, 1.3, 0.05, 0.1,
                                                       4.0, _NO_F),
                                      lw_base, 0, _NO_LOGS, np.zeros(0, np.bool_), 0.0, Z,
                                      R.stream(11), states, log_w, det)
        assert n == -1 and np.isnan(states).all() and (det == -1).all()


@pytest.mark.parametrize("odds", [0.0, 0.05, 3.0])
def test_birth_alloc_fill_makes_log_birth_weights_bit_for_bit(odds):
    """The newborn log-weights made in the kernel from log κ and Σ log σ (birth_odds) or the
    constant birth intensity are numpy's log_birth_weight, then the per-newborn division;
    a flipped or reordered operation in the kernel shows as an ulp here."""
    rng = np.random.default_rng(7)
    params = PHDParams.of(birth_odds=odds, birth_spread=1.3, p_miss=0.07,
                          birth_intensity=0.02)
    lk = params.likelihood
    for _ in range(40):
        nz = int(rng.integers(1, 25))
        Z = np.c_[rng.uniform(0, 600, nz), rng.uniform(0, 400, nz),
                  rng.uniform(0.5, 90, nz), rng.uniform(0.5, 200, nz)]
        std, log_norm = detection_noise(Z, lk)
        log_std = np.log(std)                # (what the kernel takes: it sums each row)
        log_kappa = rng.normal(-14, 3, nz)
        m_near = rng.uniform(0, 1.2, nz)
        lw_base, mode, c2 = _birth_weight_terms(params, log_kappa)
        assert mode == (2 if odds > 0 else 1)
        c = c2[K.BIRTH_LW_C:]               # lw_c: log_birth_weight's constants of this mode
        np.testing.assert_array_equal(c, _weight_consts(odds, 0.07, 1.3, True) if odds > 0
                                      else _weight_consts(0.02, 0.0, 0.0, False))
        states, log_w = np.empty((nz * 50, 6)), np.empty(nz * 50)
        det = np.empty(nz * 50, np.int64)
        j, n = K.birth_alloc_fill(m_near, _birth_consts(50, True, 50_000, lk, 1.3, 0.0, 0.1,
                                                        1.0, c),
                                  lw_base, mode, log_std, np.zeros(0, np.bool_), 0.0, Z,
                                  R.stream(3), states, log_w, det)
        # the filter's own constants array: these settings, then lw_c
        np.testing.assert_array_equal(c2[:K.BIRTH_LW_C], [
            params.birth.j_max, 1.0, params.birth.max_births_per_frame, lk.sigma_obs,
            lk.sigma_obs_min, lk.sigma_obs_pos_ratio, params.birth.birth_spread,
            params.birth.birth_speed_mean, params.birth.birth_speed_std,
            params.motion.min_size])
        assert _birth_weight_terms(params, log_kappa)[2] is c2            # made once
        want = log_birth_weight(Z, params, log_kappa, log_norm)
        want = np.repeat(want - np.array([libm.log(float(max(v, 1))) for v in j]), j)
        assert n == j.sum()
        np.testing.assert_array_equal(log_w[:n].view(np.int64), want.view(np.int64))


@njit(cache=False)
def _log_norms(log_std):
    return K._log_norms(log_std)


def test_log_norms_is_numpys_row_sum():
    """The kernels' Σ log σ per row is numpy's ``log(std).sum(-1)`` bit for bit, over
    magnitudes where the order of the three adds shows (one row and many)."""
    rng = np.random.default_rng(8)
    for n in (1, 3, 17, 400):
        for _ in range(20):
            logs = np.log(rng.uniform(0.5, 50.0, (n, 4)) * rng.choice([1e-3, 1.0, 1e3], (n, 4)))
            np.testing.assert_array_equal(_log_norms(logs).view(np.int64),
                                          logs.sum(-1).view(np.int64))


def test_observation_noise_is_obs_std_and_as_observations_checks():
    """The detections' one-pass kernel: obs_std's stds bit for bit (sizes on both sides of the
    σ floor, ties with it) and as_observations' verdict (finite first, then sizes > 0), and
    observations_noise = as_observations + (obs_std, numpy's log of it), errors included,
    whose rows the kernels sum as detection_noise's Σ log σ (numpy's sum, bit for bit)."""
    rng = np.random.default_rng(5)
    lk = LikelihoodParams()
    for _ in range(200):
        nz = int(rng.integers(1, 20))
        Z = np.c_[rng.uniform(-50, 600, nz), rng.uniform(0, 400, nz),
                  rng.choice([0.5, 1 / 0.15, 20.0, 3.0], nz) * rng.uniform(0.9, 1.1, nz),
                  rng.choice([1 / 0.15, 70.0, 2.0], nz)]
        code, std = K.observation_noise(Z, lk.sigma_obs, lk.sigma_obs_min,
                                        lk.sigma_obs_pos_ratio)
        assert code == 0
        np.testing.assert_array_equal(std, obs_std(Z[:, 2:4], lk))
        z2, (s2, logs2) = observations_noise(Z, lk)
        s1, ln1 = detection_noise(as_observations(Z), lk)
        np.testing.assert_array_equal(s2, s1)
        np.testing.assert_array_equal(logs2.view(np.int64), np.log(s1).view(np.int64))
        np.testing.assert_array_equal(_log_norms(logs2).view(np.int64), ln1.view(np.int64))
        z3, (s3, logs3) = observations_noise(list(map(list, Z)), lk)    # the numpy route
        np.testing.assert_array_equal(s3, s1)
        np.testing.assert_array_equal(logs3.view(np.int64), logs2.view(np.int64))
        bad = Z.copy()
        if rng.random() < 0.5:            # a size <= 0 too: the non-finite value wins
            bad[int(rng.integers(nz)), 2 + int(rng.integers(2))] = 0.0
        bad[int(rng.integers(nz)), int(rng.integers(4))] = rng.choice([np.nan, np.inf, -np.inf])
        assert K.observation_noise(bad, 0.15, 1.0, 0.5)[0] == 1
        with pytest.raises(ValueError, match="non-finite"):
            observations_noise(bad, lk)
        with pytest.raises(ValueError, match="non-finite"):
            as_observations(bad)
        neg = Z.copy()
        neg[int(rng.integers(nz)), 2 + int(rng.integers(2))] = rng.choice([0.0, -3.0])
        assert K.observation_noise(neg, 0.15, 1.0, 0.5)[0] == 2
        with pytest.raises(ValueError, match="> 0"):
            observations_noise(neg, lk)
        with pytest.raises(ValueError, match="> 0"):
            as_observations(neg)


# ----------------------------------------------------------------------------- grid, M(z)

@pytest.mark.parametrize("n", [2000, 2003])
@pytest.mark.parametrize("cell", [0.01, 5.0, 40.0, 1e4, 3e4])
def test_grid_puts_every_point_in_its_cell_in_index_order(cell, n):
    """(cells of 1e4 and 3e4: few beside the points, the four-chunk sort; 2003 points: a rest
    after the four chunks; points on the cells' edges)"""
    rng = np.random.default_rng(2)
    x = _states(rng, n, far=20)
    if cell in (40.0, 3e4):
        x[:, :2] = np.round(x[:, :2] / cell) * cell             # points on the cells' edges
    ok, x0, y0, cx, cy, ni, nj, order, starts = K.grid_build(x[:, 0], x[:, 1], cell, cell)
    assert ok and ni * nj <= 4 * n + 64                         # cells grew when too many
    assert (4 * ni * nj <= n) == (cell >= 1e4)                  # (both sorts are tested)
    np.testing.assert_array_equal(np.sort(order), np.arange(n))
    key = (np.minimum(np.floor((x[:, 0] - x0) / cx), ni - 1) * nj
           + np.minimum(np.floor((x[:, 1] - y0) / cy), nj - 1)).astype(np.int64)
    np.testing.assert_array_equal(order, np.argsort(key, kind="stable"))
    np.testing.assert_array_equal(starts, np.searchsorted(key[order], np.arange(ni * nj + 1)))


@njit(cache=False)
def _grid_at(px, py, cx, cy, ext):
    return K.grid_build_at(px, py, cx, cy, ext)


@pytest.mark.parametrize("case", ["finite", "nan", "inf", "overflow", "one"])
def test_predicted_extent_gives_grid_builds_own_grid(case):
    """propagate_into's extent of the new positions (grid_shape's minima / maxima, in its
    order) lets grid_build_at skip grid_shape's pass: the very grid, order and starts of
    grid_build; a position not finite (or sums that overflow) marks the extent unknown, and
    grid_build_at takes grid_build's own pass (the same refusal, the same grid)."""
    rng = np.random.default_rng(5)
    n = 1 if case == "one" else 3001
    x = _states(rng, n, far=min(20, n))
    if case == "nan":
        x[n // 2, 0] = np.nan
    elif case == "inf":
        x[n - 1, 1] = np.inf
    elif case == "overflow":
        x[:, 1] = 1e308                              # finite, but their sum is not
    out = np.empty((n + 7, 6))
    lw_out = np.empty(n + 7)
    ext = np.full(5, np.nan)
    K.propagate_into(x, R.stream(9), 0.03, 0.1, 0.5, 1.0, out, np.zeros(n), -0.1, lw_out, ext)
    px, py = out[:n, 0], out[:n, 1]
    finite = case in ("finite", "one")
    assert ext[4] == (1.0 if finite else 0.0)
    if finite:
        np.testing.assert_array_equal(ext[:4], [px.min(), py.min(), px.max(), py.max()])
    for cell in (0.5, 7.0, 3e4):
        want = K.grid_build(px, py, cell, 2.0 * cell)
        got = _grid_at(px, py, cell, 2.0 * cell, ext)
        assert got[0] == want[0] == (case != "nan" and case != "inf")
        assert got[1:7] == want[1:7]
        np.testing.assert_array_equal(got[7], want[7])
        np.testing.assert_array_equal(got[8], want[8])
        # (no extent: grid_build itself)
        nothing = _grid_at(px, py, cell, 2.0 * cell, np.empty(0))
        assert nothing[:7] == want[:7] or not want[0]


def test_predict_leaves_its_positions_extent_for_the_scene_grid():
    """predict into the filter's buffers records the extent of exactly its set's positions
    (a set made otherwise has none: the scene model's grid makes its own)."""
    from pfscope.trackers.phd import filter as F
    rng = np.random.default_rng(3)
    ps = ParticleSet(_states(rng, 900), np.full(900, -2.0))
    buf = (np.empty((950, 6)), np.empty(950))
    pred = F.predict(ps, F.MotionParams(), np.random.default_rng(1), buf)
    ext = pred.extent()
    x = pred.states
    assert x.base is buf[0] and len(x) == 900
    np.testing.assert_array_equal(ext, [x[:, 0].min(), x[:, 1].min(), x[:, 0].max(),
                                        x[:, 1].max(), 1.0])
    assert F.predict(ps, F.MotionParams(), np.random.default_rng(1)).extent() is None


def test_grid_of_no_points_is_empty():
    ok, _, _, _, _, ni, nj, order, starts = K.grid_build(np.zeros(0), np.zeros(0), 1.0, 1.0)
    assert ok and ni == nj == 0 and len(order) == 0
    np.testing.assert_array_equal(starts, [0])


def test_grid_refuses_non_finite_points():
    x = np.array([0.0, np.nan, 3.0])
    assert not K.grid_build(x, np.zeros(3), 1.0, 1.0)[0]
    ps = ParticleSet(np.c_[x, np.zeros((3, 3)), np.full((3, 2), 20.0)], np.zeros(3))
    with pytest.raises(ValueError, match="non-finite"):
        mass_near(ps, np.array([[0.0, 0.0, 20.0, 20.0]]))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mass_near_kernel_equals_the_dense_gate_sum(seed):
    rng = np.random.default_rng(seed)
    x = _states(rng, 3000, far=30)
    Z = _dets_near(rng, x, 40)
    w = rng.uniform(0, 1e-3, 3000)
    std = obs_std(Z[:, 2:4])
    r2 = 13.28
    d2 = (((x[:, None, OBS] - Z[None]) / std[None]) ** 2).sum(-1)
    want = ((d2 <= r2) * w[:, None]).sum(0)
    for cell in (3.0, 50.0, 1e5):
        ok, got, _ = K.mass_near_kernel(x, w, Z, std, r2, cell, cell)
        assert ok
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-18)
    assert (want > 0).sum() >= 30


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mass_near_few_is_the_grid_kernel_bit_for_bit(seed):
    """κ_n's M'(z) of a few detections: the same sums, in the same order, as the kernel that
    buckets every particle (points on cell edges, cells that grow, detections off the grid)."""
    rng = np.random.default_rng(seed)
    for t in range(60):
        n = int(rng.integers(20, 2500))
        x = _states(rng, n, spread=float(rng.uniform(20, 400)), far=int(rng.integers(0, 5)))
        if t % 3 == 0:
            x[:, :2] = np.round(x[:, :2] / 7.0) * 7.0
        Z = _dets_near(rng, x, int(rng.integers(1, 12)))
        Z[0, :2] += 1e4 * (t % 4 == 1)
        w = rng.exponential(1e-3, n)
        std = obs_std(Z[:, 2:4])
        cell = float(rng.uniform(1.0, 80.0))
        ok, want, _ = K.mass_near_kernel(x, w, Z, std, 13.28, cell, 0.5 * cell)
        ok2, got = K.mass_near_few(x, w, Z, std, 13.28, cell, 0.5 * cell)
        assert ok and ok2
        assert np.array_equal(got, want), (t, got - want)
    x[0, 0] = np.nan
    assert not K.mass_near_few(x, w, Z, std, 13.28, 5.0, 5.0)[0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mass_near_two_is_both_kernels_bit_for_bit(seed):
    """The birth's M(z) and κ_n's M'(z) (stds doubled, some detections skipped) in one pass:
    the very floats and grid of mass_near_kernel and mass_near_skip -- on a grid that did not
    grow (M'(z)'s cells merge ours 2 x 2), one that grew (the same grid), points on cell
    edges, detections off the grid, cells of 1 (a median std of 0: mass_near_skip itself)."""
    rng = np.random.default_rng(seed)
    merged = grown = 0
    for t in range(80):
        n = int(rng.integers(1, 2500))
        x = _states(rng, n, spread=float(rng.uniform(5, 600)), far=int(rng.integers(0, 3)))
        if t % 3 == 0:
            x[:, :2] = np.round(x[:, :2] / 7.0) * 7.0
        Z = _dets_near(rng, x, int(rng.integers(1, min(n, 14) + 1)), clutter=int(t % 3))
        Z[0, :2] += 1e4 * (t % 5 == 1)
        w = rng.exponential(1e-3, n)
        std = obs_std(Z[:, 2:4])
        if t % 7 == 3:
            std[:, :2] = 0.0
        r2 = 13.28
        cell = _grid_cell(std, r2) * (rng.uniform(0.02, 0.5) if t % 4 == 2 else 1.0)
        skip = rng.random(len(Z)) < 0.4
        wide = std * 2.0
        ok, want, grid = K.mass_near_kernel(x, w, Z, std, r2, cell[0], cell[1])
        code, want_near = K.mass_near_skip(x, w, Z, wide, skip, r2)
        code2, got, grid2, near = K.mass_near_two(x, w, Z, std, r2, cell[0], cell[1], wide,
                                                  skip)
        assert ok and code and code2 == 1
        assert np.array_equal(got, want) and np.array_equal(near, want_near), t
        assert all(np.array_equal(a, b) for a, b in zip(grid, grid2))
        assert (near[skip] == 0).all()
        if t % 4 != 2 and t % 7 != 3:
            merged += grid[2] == cell[0]
            grown += grid[2] != cell[0]
    assert merged >= 10 and grown >= 3, (merged, grown)
    x[0, 0] = np.nan
    assert K.mass_near_two(x, w, Z, std, 13.28, 5.0, 5.0, 2.0 * std, skip)[0] == 0


def _quotient_sums(x, w, Z, std, r2, order):
    """Each detection's weight in its gate summed one by one in the grid's ``order``, the gate
    by _gate_d2's quotients (the position terms first): the reference of the fast gate."""
    out = np.zeros(len(Z))
    for j in range(len(Z)):
        q = (x[:, OBS] - Z[j]) / std[j]
        d2 = q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1]
        full = (d2 + q[:, 2] * q[:, 2]) + q[:, 3] * q[:, 3]
        inside = (d2 <= r2) & (full <= r2)
        s = 0.0
        for i in order[inside[order]]:
            s += float(w[i])
        out[j] = s
    return out


@pytest.mark.filterwarnings("ignore::RuntimeWarning")      # (the reference's odd stds)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fast_gate_decides_as_the_quotients_on_the_gates_edge(seed):
    """The gate sums test d² by products with the reciprocal stds and fall back to the
    quotients near r2: particles placed on the gate's edge (d² within a few roundings of r2,
    and at the fast band's own edges r2 (1 ± 1e-12)), stds of 0 / tiny / huge / NaN: the very
    sums of the quotients' decisions, also with the one weight (1,) of equal weights."""
    rng = np.random.default_rng(seed)
    r2 = 13.28
    hits = 0
    for t in range(12):
        nz = int(rng.integers(1, 8))
        Z = np.c_[rng.uniform(0, 500, (nz, 2)), rng.uniform(10, 80, (nz, 2))]
        std = obs_std(Z[:, 2:4])
        if t % 4 == 1:
            std[0] = [1e-160, 3.0, 1e160, 2.0]
        if t % 4 == 2:
            std[0, 2] = np.nan
        if t % 4 == 3:
            std[0, 1] = 0.0
        rows = []
        for j in range(nz):
            u = rng.normal(size=(400, 4))
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            k = rng.integers(-6, 7, 400)
            scale = np.where(rng.random(400) < 0.3, 1.0 + np.sign(k) * 1e-12 + k * 1e-17,
                             1.0 + k * 2.2e-16)
            rows.append(Z[j] + u * np.sqrt(r2 * scale)[:, None] * std[j])
        P = np.concatenate(rows)
        P = np.nan_to_num(P, nan=0.0, posinf=0.0, neginf=0.0)
        x = np.zeros((len(P), 6))
        x[:, OBS] = P
        n = len(x)
        w = rng.exponential(1e-3, n)
        for ww in (w, np.full(1, 1e-3)):
            wide_w = ww if len(ww) == n else np.full(n, ww[0])
            ok, got, grid = K.mass_near_kernel(x, ww, Z, std, r2, 7.0, 9.0)
            assert ok
            want = _quotient_sums(x, wide_w, Z, std, r2, grid[6])
            assert np.array_equal(got, want), (t, got - want)
            skip = np.zeros(nz, np.bool_)
            code, near = K.mass_near_skip(x, ww, Z, 2.0 * std, skip, r2)
            code2, got2, _, near2 = K.mass_near_two(x, ww, Z, std, r2, 7.0, 9.0, 2.0 * std, skip)
            assert code == code2 == 1 and np.array_equal(got2, got)
            cw = K.grid_cell(2.0 * std, r2)             # mass_near_skip's grid
            _, _, wgrid = K.mass_near_kernel(x, wide_w, Z, 2.0 * std, r2, cw[0], cw[1])
            want_near = _quotient_sums(x, wide_w, Z, 2.0 * std, r2, wgrid[6])
            assert np.array_equal(near, near2), t
            # (stds of 1e-160 beside 1e160: mass_near_skip's own grid keeps none of the
            # particles at the detection's very position, as before the fast gate)
            assert t % 4 == 1 or np.array_equal(near2, want_near), t
            few = K.mass_near_few(x, ww, Z, std, r2, 7.0, 9.0)[1]
            assert np.array_equal(few, got), t
        # the edge cases were there: particles on both sides of the edge in the band
        q = (x[:, OBS] - Z[0]) / std[0]
        d2 = (q * q).sum(1)
        hits += int(((d2 > r2) & (d2 < r2 * (1 + 1e-13))).sum() > 0
                    and ((d2 <= r2) & (d2 > r2 * (1 - 1e-13))).sum() > 0)
    assert hits >= 3          # (the frames whose first detection has ordinary stds)


def test_scene_model_hands_the_birth_its_mass_near():
    """The practical filter's κ_n computes the birth's M(z) in the same pass; the birth takes it
    (the very floats and grid of its own call) for the same particles, detections and stds
    only, once."""
    import pfscope.trackers.phd.filter as F
    from pfscope.trackers.phd.tracker import PHD_PRACTICAL

    p = PHD_PRACTICAL.filter
    f = F.PHDFilter(p, rng=np.random.default_rng(0))
    rng = np.random.default_rng(3)
    seen = []
    orig = F._mass_near

    def spy(predicted, Z, bp, lk, std_z, ahead=None):
        got = orig(predicted, Z, bp, lk, std_z, ahead)
        want = orig(predicted, Z, bp, lk, std_z)
        seen.append(ahead is not None and ahead[0] is predicted)
        assert np.array_equal(got[0], want[0])
        assert (got[1] is None and want[1] is None) or all(
            np.array_equal(a, b) for a, b in zip(got[1], want[1]))
        return got

    F._mass_near = spy
    try:
        for k in range(6):
            Z = np.column_stack([np.linspace(50, 550, 6) + 3 * k, np.full(6, 200.0),
                                 np.full(6, 30.0), np.full(6, 70.0)])
            Z = np.vstack([Z, rng.uniform(0, 600, (3, 4)) * [1, 1, 0.1, 0.1] + [0, 0, 20, 50]])
            f.step(Z)
            assert f.scene.take_birth_mass() is None          # taken once, by the birth
    finally:
        F._mass_near = orig
    assert not seen[0] and all(seen[1:]), seen
    # other detections (the same stds), other stds, other particles: computed again
    ps = f.particles
    Z = np.array([[68.0, 200.0, 30.0, 70.0], [268.0, 200.0, 30.0, 70.0]])   # on the walkers
    Z2 = Z + [6.0, 0.0, 0.0, 0.0]
    std = obs_std(Z[:, 2:4], p.likelihood)
    r2 = F.gate_threshold(p.birth.gate)
    want = F.mass_near_at(ps, Z2, std, r2, _grid_cell(std, r2))[0]
    assert not np.array_equal(want, F.mass_near_at(ps, Z, std, r2, _grid_cell(std, r2))[0])
    near, ahead = F.mass_near_two(ps, Z, std, r2, 2.0 * std, np.zeros(2, bool))
    assert np.array_equal(F._mass_near(ps, Z, p.birth, p.likelihood, std, ahead)[0], ahead[4])
    for other in ((ps, Z2, std), (ps, Z2, std.copy()), (ps.concat(ps), Z2, std)):
        got = F._mass_near(other[0], other[1], p.birth, p.likelihood, other[2], ahead)[0]
        assert np.array_equal(got, F.mass_near_at(other[0], Z2, std, r2,
                                                  _grid_cell(std, r2))[0])


# ----------------------------------------------------------------------------- update

def _dense_reference(ps, Z, lk, log_kappa, p_miss, r2):
    """Eq. (5) on the dense matrix with g = 0 outside the gate d² <= r2 (the brute force)."""
    states = ps.states
    log_g = log_likelihood(states, Z, lk)
    if lk.obs_std_source == "detection":
        std = obs_std(Z[:, 2:4], lk)[None]
    else:
        std = obs_std(states[:, None, 4:6], lk)
    d2 = (((states[:, None, OBS] - Z[None]) / std) ** 2).sum(-1)
    log_g = np.where(d2 <= r2, log_g, -np.inf)
    return update(ps, log_g, log_kappa, p_miss)


@pytest.mark.parametrize("source", ["detection", "particle"])
@pytest.mark.parametrize("p_miss", [0.0, 0.05, 1.0])
@pytest.mark.parametrize("kappa", ["gate", "zero", "mixed"])
@pytest.mark.parametrize("spread", [False, True])
def test_gauss_update_equals_the_dense_eq5_on_the_gate(source, p_miss, kappa, spread):
    rng = np.random.default_rng([len(source), int(p_miss * 100), len(kappa)])
    x = _states(rng, 1500, far=15)
    Z = _dets_near(rng, x, 25)
    lw = rng.normal(-7, 2, 1500)
    lw[:20] = -np.inf                                  # dead particles
    lw[300:900] = lw[300]                              # a run of equal weights (resampled)
    lw[900:1000] = np.repeat(lw[900:905], 20)          # (newborn: one weight per detection)
    if spread:                                         # weights e^-900 apart: the log route
        lw[20:200] -= 900.0
    ps = ParticleSet(x, lw)
    lk = LikelihoodParams(obs_std_source=source)
    log_kappa = rng.normal(-14, 1, 25)
    if kappa == "zero":
        log_kappa[:] = -np.inf
    elif kappa == "mixed":
        log_kappa[::3] = -np.inf
    r2 = tail_radius2(1e-12)
    got = update(ps, GatedGaussian(Z, lk, r2), log_kappa, p_miss)
    want = _dense_reference(ps, Z, lk, log_kappa, p_miss, r2)
    a, b = got.particles.log_weights, want.particles.log_weights
    np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b))
    f = np.isfinite(b)
    np.testing.assert_allclose(a[f], b[f], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(got.c_z, want.c_z, rtol=1e-10, atol=1e-300)
    np.testing.assert_allclose(got.per_det_mass, want.per_det_mass, rtol=1e-10, atol=1e-14)
    assert got.miss_mass == pytest.approx(want.miss_mass)
    # the mass the kernel summed is the log-sum-exp of its weights
    assert got.particles.log_mass == pytest.approx(want.particles.log_mass, rel=1e-12)
    if source == "detection" and not spread:           # the linear route: its weights recorded
        w, scale = got.particles.__dict__["_normalised"]
        np.testing.assert_allclose(w * scale, np.exp(b - want.particles.log_mass),
                                   rtol=1e-10, atol=1e-300)
    if p_miss < 1:
        assert np.count_nonzero(got.c_z > 0) >= 20     # the detections did win mass


@pytest.mark.parametrize("p_miss", [0.0, 0.05, 1.0])
def test_updated_log_weights_made_on_read_are_the_kernels(p_miss):
    """The update's log-weights are made from the linear kernel's bracket only when read
    (numpy, :func:`K.bracket_log_weights`): bit for bit those of the kernel route
    (:func:`K.gauss_update`, which makes them inside numba), and not made by a filter step."""
    rng = np.random.default_rng(int(p_miss * 100))
    x = _states(rng, 1500, far=15)
    Z = _dets_near(rng, x, 25)
    lw = rng.normal(-7, 2, 1500)
    lw[:20] = -np.inf
    lw[300:900] = lw[300]
    log_kappa = rng.normal(-14, 1, 25)
    log_kappa[::4] = -np.inf
    r2 = tail_radius2(1e-12)
    lk = LikelihoodParams()
    got = update(ParticleSet(x, lw), GatedGaussian(Z, lk, r2), log_kappa, p_miss)
    assert "_log_weights" not in got.particles.__dict__ and len(got.particles) == 1500
    std = obs_std(Z[:, 2:4], lk)
    log_pm = np.log(p_miss) if p_miss > 0 else -np.inf
    log_pd = np.log1p(-p_miss) if p_miss < 1 else -np.inf
    cell = 2 * np.sqrt(r2) * np.median(std[:, :2], axis=0)
    ok, want, *_ = K.gauss_update(x, lw, Z, std, np.log(std), True, log_kappa, log_pd,
                                  log_pm, r2, cell[0], cell[1])
    assert ok
    np.testing.assert_array_equal(got.particles.log_weights, want)
    if p_miss > 0:      # every kind of particle: dead, missed by every gate, reached
        assert np.isneginf(want).sum() == 20 and np.sum(want == lw + np.log(p_miss)) > 100
        assert np.sum(want > lw + np.log(p_miss)) > (100 if p_miss < 1 else -1)
    f = PHDFilter(rng=np.random.default_rng(0))
    for _ in range(3):
        r = f.step(Z)
    assert "_log_weights" not in r.updated.particles.__dict__       # a step reads none
    # ... nor C(z) and κ (made on their first read: numpy's exp of the logs)
    assert "c_z" not in r.updated.__dict__ and "kappa" not in r.updated.__dict__
    c_z, kappa = r.updated.c_z, r.updated.kappa
    assert r.updated.c_z is c_z and r.updated.kappa is kappa and len(kappa) == len(Z)
    assert np.all(c_z >= 0) and c_z.max() > 0 and np.all(kappa >= 0)
    ok = kappa + c_z > 0
    np.testing.assert_allclose(r.updated.per_det_mass[ok], (c_z / (kappa + c_z))[ok],
                               rtol=1e-12)
    np.testing.assert_array_equal(np.exp(r.updated.particles.log_weights),
                                  r.updated.particles.weights)


@pytest.mark.parametrize("seed", [0, 1])
def test_update_on_the_birth_grid_and_newborn_blocks_is_the_one_grid_update(seed):
    """The filter's route: the predicted particles through the grid M(z)'s kernel built (its
    own, finer cells) and the newborn as one block per detection, looked at by their bounding
    box -- the same gated pairs, hence the same weights (up to the order of C(z)'s sum), as
    one grid on every particle.  Blocks: on their detection, far from it, empty, one with a
    straggler that only a gate elsewhere reaches."""
    rng = np.random.default_rng(seed)
    n = 1500
    x = _states(rng, n, far=10)
    Z = _dets_near(rng, x, 12)
    std = obs_std(Z[:, 2:4])
    j = rng.integers(0, 60, len(Z))
    j[2] = 0                                           # an empty block
    born = np.concatenate([np.repeat(Z[z:z + 1], j[z], 0) for z in range(len(Z))])
    born = np.c_[born[:, :2], np.zeros((len(born), 2)), born[:, 2:]]
    born[:, [0, 1, 4, 5]] += rng.normal(0, 1, (len(born), 4)) * np.repeat(std, j, 0)
    s0 = int(j[:4].sum())                              # block 4 sits on detection 0 ...
    born[s0:s0 + j[4], [0, 1]] = Z[0, :2] + rng.normal(0, 1, (j[4], 2)) * std[0, :2]
    born[s0 + j[4] - 1, [0, 1]] = Z[5, :2]             # ... but one of them on detection 5
    born[s0 + j[4] - 1, [4, 5]] = Z[5, 2:]
    states = np.vstack([x, born])
    lw = np.r_[np.full(n, -7.0), np.repeat(rng.normal(-9, 1, len(Z)), j)]
    r2 = tail_radius2(1e-12)
    log_kappa = rng.normal(-14, 1, len(Z))
    lk = LikelihoodParams()
    cell = 2 * np.sqrt(13.28) * np.median(std[:, :2], axis=0)
    ok, _, grid = K.mass_near_kernel(x, np.exp(lw[:n]), Z, std, 13.28, cell[0], cell[1])
    assert ok
    ps = ParticleSet(states, lw)
    want = update(ps, GatedGaussian(Z, lk, r2), log_kappa, 0.05)
    got = update(ps, GatedGaussian(Z, lk, r2, persistent=(n, grid, j)), log_kappa, 0.05)
    a, b = got.particles.log_weights, want.particles.log_weights
    np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(got.c_z, want.c_z, rtol=1e-12, atol=1e-300)
    assert got.particles.log_mass == pytest.approx(want.particles.log_mass, rel=1e-13)
    assert (b[n:] != b[n:].min()).sum() > 100         # newborn did meet gates
    k = n + s0 + j[4] - 1                              # the straggler won at detection 5
    assert b[k] > lw[k] + np.log(0.05) + 1
    # told that the predicted weigh the same (they do): no pass bounds their weights, and
    # the very floats (C(z), the masses, the normalised weights the resampling walks)
    eq = update(ps, GatedGaussian(Z, lk, r2, persistent=(n, grid, j, True)), log_kappa, 0.05)
    np.testing.assert_array_equal(eq.particles.log_weights, a)
    np.testing.assert_array_equal(eq.c_z, got.c_z)
    np.testing.assert_array_equal(eq.per_det_mass, got.per_det_mass)
    assert eq.miss_mass == got.miss_mass and eq.particles.log_mass == got.particles.log_mass
    np.testing.assert_array_equal(eq.particles.weights, got.particles.weights)
    with pytest.raises(ValueError, match="non-finite"):   # the blocks must cover the rows
        update(ps, GatedGaussian(Z, lk, r2, persistent=(n, grid, j[:-1])), log_kappa, 0.05)


@pytest.mark.parametrize("p_miss", [0.05, 1.0])
def test_update_kernels_log_den_is_numpys_logaddexp(p_miss):
    """The linear update's share per detection is ``log C − log(κ + C)`` with log(κ + C)
    ``np.logaddexp(log κ, log C)`` and numpy's ``where(isfinite, ., 0)``, bit for bit: κ
    below, equal to and above C, C = 0 (a detection far from every particle, or p_D = 0),
    κ = 0 (log κ = -inf, alone and with C = 0), and an infinite κ."""
    rng = np.random.default_rng(4)
    x = _states(rng, 800, far=10)
    Z = _dets_near(rng, x, 12)
    Z[3, :2] += 1e5                                    # no particle in its gate: C = 0
    Z[4, :2] -= 1e5
    std, _ = detection_noise(Z, LikelihoodParams())
    lw = np.full(len(x), -7.0)
    log_pd = np.log1p(-p_miss) if p_miss < 1 else -np.inf
    log_pm = np.log(p_miss)
    args = (x, lw, Z, std, np.log(std))
    first = K.gauss_update_linear(*args, rng.normal(-14, 1, len(Z)), log_pd, log_pm,
                                  tail_radius2(1e-12), 30.0, 30.0, len(x), _NO_GRID,
                                  np.empty(0, np.int64), False)
    log_c = first[3]
    log_kappa = log_c + rng.choice([-3.0, 0.0, 2.0, -0.5], len(Z))
    log_kappa[6] = log_c[6]                            # κ = C exactly
    log_kappa[[7, 4]] = -np.inf                        # κ = 0, with C > 0 and with C = 0
    log_kappa[8] = np.inf
    log_kappa[3] = -13.5
    ok, done, *_, share = K.gauss_update_linear(*args, log_kappa, log_pd, log_pm,
                                                tail_radius2(1e-12), 30.0, 30.0, len(x),
                                                _NO_GRID, np.empty(0, np.int64), False)
    assert ok and done
    got_c = _[1]
    want = np.logaddexp(log_kappa, got_c)
    want = np.where(np.isfinite(want), want, 0.0)
    np.testing.assert_array_equal(share.view(np.int64), (got_c - want).view(np.int64))
    assert np.isfinite(got_c[[5, 6, 7, 9, 10, 11]]).all() == (p_miss < 1)
    assert got_c[3] == got_c[4] == -np.inf


def test_gauss_update_refuses_non_finite_positions():
    x = _states(np.random.default_rng(5), 10)
    x[3, 1] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        update(ParticleSet(x, np.zeros(10)),
               GatedGaussian(x[:2, OBS], LikelihoodParams(), 62.0), np.zeros(2), 0.05)


# ----------------------------------------------------------------------------- resample

@pytest.mark.parametrize("N,n", [(1, 4), (7, 3), (2000, 3000), (5000, 40)])
def test_systematic_index_is_searchsorted_on_the_cdf(N, n):
    rng = np.random.default_rng(N + n)
    lw = rng.normal(0, 3, N)
    lw[rng.random(N) < 0.3] = -np.inf
    lw[0] = 0.0
    lse = float(np.log(np.sum(np.exp(lw - lw.max()))) + lw.max())
    for u0 in (0.0, rng.random(), 1.0 - 1e-12):
        cdf = np.cumsum(np.exp(lw - lse))
        cdf[-1] = 1.0
        want = np.minimum(np.searchsorted(cdf, (u0 + np.arange(n)) / n, side="right"), N - 1)
        got = _systematic_index(lw, lse, u0, n)
        np.testing.assert_array_equal(got, want)
        assert not np.any(np.isneginf(lw[got]))        # zero-weight bins never picked


@pytest.mark.parametrize("N,n", [(1, 4), (2, 5), (7, 3), (2000, 3000), (5000, 40)])
@pytest.mark.parametrize("D", [6, 3, 0])
def test_systematic_take_copies_the_searchsorted_ancestors_rows(N, n, D):
    # both weight routes (log-weights; linear weights times a scale), the 6-column state rows
    # and any other width: the ancestors of searchsorted on the CDF and exactly their rows
    # (resample's walk copies the rows itself: _systematic_index covers no copy)
    rng = np.random.default_rng(N + n + D)
    states = rng.normal(0, 100, (N, D))
    w = rng.random(N) ** 3
    w[rng.random(N) < 0.3] = 0.0
    w[0] = 1.0
    scale = 1.0 / w.sum()
    with np.errstate(divide="ignore"):
        lw = np.log(w)
    lse = float(np.log(w.sum()))
    for u0 in (0.0, rng.random(), 1.0 - 1e-12):
        for args, terms in (((lw, lse, u0, n, np.empty(0), 0.0), np.exp(lw - lse)),
                            ((np.empty(0), 0.0, u0, n, w, scale), w * scale)):
            cdf = np.cumsum(terms)
            cdf[-1] = 1.0
            want = np.minimum(np.searchsorted(cdf, (u0 + np.arange(n)) / n, side="right"), N - 1)
            idx, rows, runs, pos = _systematic_take(states, *args, True)
            np.testing.assert_array_equal(idx, want)
            assert rows.shape == (n, D)
            np.testing.assert_array_equal(rows, states[want])
            # the position sums, added row by row in order (np.cumsum's sequential floats)
            want_pos = (np.array([np.cumsum(rows[:, 0])[-1], np.cumsum(rows[:, 1])[-1]])
                        if D >= 2 else np.zeros(2))
            assert pos.tobytes() == want_pos.tobytes()
            # the runs of copies of one ancestor, in order
            anc, first = np.unique(want, return_index=True)
            np.testing.assert_array_equal(runs, np.diff(np.append(first, n)))
            np.testing.assert_array_equal(np.repeat(anc, runs), want)
            no_idx, rows2, runs2, _ = _systematic_take(states, *args, False)   # the rows alone
            assert no_idx.shape == (0,)
            np.testing.assert_array_equal(rows2, rows)
            np.testing.assert_array_equal(runs2, runs)
            assert np.all(w[idx[idx < N - 1]] > 0)     # zero-weight bins never picked (but
            #                                            the last, its CDF forced to 1)


# ----------------------------------------------------------------------------- K-means

def _brute_d2(X, centers, lk):
    inv = 1.0 / obs_std(centers[:, 4:6], lk) ** 2
    C = centers[:, OBS]
    acc = (X[:, 0, None] - C[None, :, 0]) ** 2 * inv[None, :, 0]
    for d in range(1, 4):
        acc = acc + (X[:, d, None] - C[None, :, d]) ** 2 * inv[None, :, d]
    return acc


def _serial_scan(X, centers, inv):
    """The dense assignment's reference: every particle's d² to every centre in
    :func:`._kmeans_kernels._d2`'s order, and the serial scan's labels (centre 0, then each
    strictly less; ties to the lowest index).  Returns (labels, their d²)."""
    n, k = len(X), len(centers)
    with np.errstate(over="ignore", invalid="ignore"):
        a = X[:, None, :] - centers[:, OBS][None, :, :]             # (n, k, 4)
        d = (((a[..., 0] * a[..., 0]) * inv[:, 0] + (a[..., 1] * a[..., 1]) * inv[:, 1])
             + (a[..., 2] * a[..., 2]) * inv[:, 2]) + (a[..., 3] * a[..., 3]) * inv[:, 3]
    want = np.zeros(n, dtype=np.int64)
    for c in range(1, k):
        want[d[np.arange(n), c] < d[np.arange(n), want]] = c
    return want, d[np.arange(n), want]


def _centers(rng, k):
    c = np.zeros((k, 6))
    c[:, :2] = rng.uniform(-300, 300, (k, 2))
    c[:, 4] = rng.uniform(5, 60, k)
    c[:, 5] = c[:, 4] * rng.uniform(1.5, 3, k)
    if k >= 3:
        c[k // 2] = c[1]                               # exact ties
    return c


@pytest.mark.parametrize("k", [1, 5, 40, 150])
@pytest.mark.parametrize("guess", ["none", "random", "truth"])
def test_assign_is_the_argmin_lowest_index_on_ties(k, guess):
    rng = np.random.default_rng(k)
    lk = LikelihoodParams()
    centers = _centers(rng, k)
    src = rng.integers(0, k, 4000)
    X = centers[src][:, OBS] + rng.normal(0, 5, (4000, 4))
    X[:40, :2] += rng.uniform(-1e4, 1e4, (40, 2))      # far from every centre
    X[40:60] = centers[min(1, k - 1), OBS]             # on the tied centres
    want_d2 = _brute_d2(X, centers, lk)
    want = np.argmin(want_d2, axis=1)
    prev = {"none": np.full(4000, -1), "random": rng.integers(0, k, 4000), "truth": want}[guess]
    inv = KM._inv_var(centers, lk.sigma_obs, lk.sigma_obs_min, lk.sigma_obs_pos_ratio)
    for grid_min in (1, 10 ** 9):
        lab, d2 = np.empty(4000, dtype=np.int64), np.empty(4000)
        KM.assign(X, centers, inv, prev.astype(np.int64), lab, d2, grid_min)
        np.testing.assert_array_equal(lab, want)
        np.testing.assert_allclose(d2, want_d2[np.arange(4000), want], rtol=1e-12, atol=0)
    if k >= 3:
        assert not np.any(lab == k // 2)               # the tie went to centre 1


@pytest.mark.parametrize("k", [1, 2, 7, 25])
def test_dense_assign_is_the_serial_scan_bit_for_bit(k):
    """The dense assignment (previous particle's centre first, a centre passed over when its
    (y1, y2) part alone exceeds the best d²) against the serial scan of every centre
    (:func:`_nearest_dense`'s rule): the same labels and the same d² bytes, with the particles of a
    centre side by side (the guess usually right) and shuffled, exact ties, particles on a
    centre, a NaN particle (centre 0), a NaN or inf size among the centres."""
    rng = np.random.default_rng(11 + k)
    lk = LikelihoodParams()
    centers = _centers(rng, k)
    if k >= 7:
        centers[2, 4] = np.nan                         # a NaN d² after centre 0: never wins
        centers[4, :2] = np.inf
        # centres 1 (and its copy) and k − 1 mirrored about a point: a particle there ties
        # them, right after a particle of centre k − 1 (the guess: the tie goes to 1 anyway)
        centers[1] = centers[k // 2] = (5000.0, 5000.0, 0.0, 0.0, 20.0, 40.0)
        centers[k - 1] = (5040.0, 5000.0, 0.0, 0.0, 20.0, 40.0)
    n = 3000
    src = np.sort(rng.integers(0, k, n))
    X = centers[src][:, OBS] + rng.normal(0, 8, (n, 4))
    X[~np.isfinite(X)] = 1.0
    if k >= 7:
        X[300] = (5040.0, 5000.0, 20.0, 40.0)
        X[301] = (5020.0, 5000.0, 20.0, 40.0)
    X[100:130] = centers[min(1, k - 1), OBS]           # on the tied centres
    X[200, 0] = np.nan
    X[201, 2] = np.inf
    inv = KM._inv_var(centers, lk.sigma_obs, lk.sigma_obs_min, lk.sigma_obs_pos_ratio)
    for order in (np.arange(n), rng.permutation(n)):
        Xo = np.ascontiguousarray(X[order])
        lab, d2 = np.empty(n, dtype=np.int64), np.empty(n)
        KM._assign_dense(Xo, centers, inv, lab, d2)
        want, d_want = _serial_scan(Xo, centers, inv)
        np.testing.assert_array_equal(lab, want)
        assert d2.tobytes() == d_want.tobytes()


@pytest.mark.parametrize("k", [KM._BLOCKS_MIN, 4, 9, 19, 31])
def test_dense_assign_blocks_are_the_serial_scan_bit_for_bit(k):
    """Finite centres (from ``_BLOCKS_MIN`` on): the blocks of particles with their box's
    bounds (a centre whose d² lower bound over the box exceeds the previous centre's upper
    bound is not looked at) give the serial scan's labels and d² bytes -- particles of a
    centre side by side (a block usually has one candidate), shuffled (many), particles far
    from every centre, exact ties between two centres of the same size (the lower index),
    particles on a centre, and NaN, inf and huge coordinates (their block: the serial look)."""
    rng = np.random.default_rng(5 + k)
    lk = LikelihoodParams()
    centers = _centers(rng, k)                     # (centres 1 and k // 2 equal: ties)
    tie = k >= 4
    if tie:
        centers[2, :2] = (2000.0, 2000.0)
        centers[k - 1] = centers[2]
        centers[k - 1, 0] += 40.0                  # 2 and k - 1 mirrored about y1 + 20
    n = 5000
    src = np.sort(rng.integers(0, k, n))
    X = centers[src][:, OBS] + rng.normal(0, 6, (n, 4)) * rng.uniform(0.2, 3, (n, 1))
    if tie:
        X[400:440] = centers[2, OBS] + (20.0, 0.0, 0.0, 0.0)    # on the tie of 2 and k - 1
    X[500:530] = centers[1, OBS]                                # on the tied centres 1, k // 2
    X[600:640, :2] = rng.uniform(-5e3, 5e3, (40, 2))            # far from every centre
    X[700, 1] = np.nan
    X[740, 3] = np.inf
    X[780, 0] = -1e200
    inv = KM._inv_var(centers, lk.sigma_obs, lk.sigma_obs_min, lk.sigma_obs_pos_ratio)
    for order in (np.arange(n), rng.permutation(n)):
        Xo = np.ascontiguousarray(X[order])
        lab, d2 = np.empty(n, dtype=np.int64), np.empty(n)
        KM._assign_dense(Xo, centers, inv, lab, d2)
        want, d_want = _serial_scan(Xo, centers, inv)
        np.testing.assert_array_equal(lab, want)
        assert d2.tobytes() == d_want.tobytes()
        if order[0] == 0 and tie:
            assert np.all(want[np.arange(400, 440)] == 2)       # the ties were there
            assert np.all(want[np.arange(500, 530)] == 1)


@njit
def _moved_look(X, centers, inv, prev, dmin, moved):
    """``_assign_moved`` with the blocks' boxes (its callers' arguments)."""
    labels = np.empty(X.shape[0], np.int64)
    KM._assign_moved(X, centers, inv, prev, labels, dmin, moved, KM._boxes(X))
    return labels


@pytest.mark.parametrize("k", [KM._BLOCKS_MIN, 3, 6, 9, 19])
def test_late_dense_look_is_the_serial_scan_bit_for_bit(k):
    """A late Lloyd iteration (``_assign_moved``: a few centres moved since the labels and d²
    were taken) gives the serial scan's labels and d² bytes: the blocks whose particles'
    centres stayed look at the moved centres only, the runs of blocks with a particle of a
    moved centre (or a NaN, inf or huge coordinate) get the full look by the box bounds --
    particles side by side and shuffled, ties, far particles."""
    rng = np.random.default_rng(11 + k)
    lk = LikelihoodParams()
    centers = _centers(rng, k)
    n = 4000
    src = np.sort(rng.integers(0, k, n))
    X = centers[src][:, OBS] + rng.normal(0, 6, (n, 4)) * rng.uniform(0.2, 3, (n, 1))
    X[500:530] = centers[1, OBS]                                # on the tied centres 1, k // 2
    X[600:640, :2] = rng.uniform(-5e3, 5e3, (40, 2))            # far from every centre
    X[700, 1] = np.nan
    X[740, 3] = np.inf
    X[780, 0] = -1e200
    changed = 0
    for order in (np.arange(n), rng.permutation(n)):
        Xo = np.ascontiguousarray(X[order])
        inv0 = KM._inv_var(centers, lk.sigma_obs, lk.sigma_obs_min, lk.sigma_obs_pos_ratio)
        prev, d0 = np.empty(n, dtype=np.int64), np.empty(n)
        KM._assign_dense(Xo, centers, inv0, prev, d0)
        for picked in ([0], [min(2, k - 1), k - 1], [1]):
            moved = np.zeros(k, dtype=bool)
            moved[picked] = True
            c1 = centers.copy()
            c1[moved, :2] += rng.normal(0, 15, (moved.sum(), 2))   # moved (and resized)
            c1[moved, 4:] *= 1.1
            inv = KM._inv_var(c1, lk.sigma_obs, lk.sigma_obs_min, lk.sigma_obs_pos_ratio)
            dm = d0.copy()
            lab = _moved_look(Xo, c1, inv, prev, dm, moved)
            want, d_want = _serial_scan(Xo, c1, inv)
            np.testing.assert_array_equal(lab, want)
            assert dm.tobytes() == d_want.tobytes()
            changed += np.count_nonzero(want != prev)
    assert changed > 20                                 # the moved centres changed labels


@pytest.mark.parametrize("layout", ["many", "line", "same", "cluster+far"])
def test_assign_grid_of_centres_is_exact_for_any_layout(layout):
    """The grid over the centres (rings of cells around each particle) against argmin over
    every centre: thousands of centres, centres on a line (a degenerate grid), all on one
    point (ties everywhere), and one far-away centre that stretches the grid."""
    rng = np.random.default_rng(7)
    lk = LikelihoodParams()
    k = {"many": 1500, "line": 300, "same": 40, "cluster+far": 200}[layout]
    centers = _centers(rng, k)
    if layout == "many":
        centers[:, :2] = rng.uniform(-3000, 3000, (k, 2))
    elif layout == "line":
        centers[:, 1] = 17.0
    elif layout == "same":
        centers[:] = centers[0]
    else:
        centers[-1, :2] = (5e5, -5e5)
    n = 6000
    src = rng.integers(0, k, n)
    X = centers[src][:, OBS] + rng.normal(0, 20, (n, 4))
    X[:50, :2] = rng.uniform(-2e4, 2e4, (50, 2))       # far from the centres
    X[50:80] = centers[rng.integers(0, k, 30)][:, OBS]  # exactly on centres
    want_d2 = _brute_d2(X, centers, lk)
    want = np.argmin(want_d2, axis=1)
    inv = KM._inv_var(centers, lk.sigma_obs, lk.sigma_obs_min, lk.sigma_obs_pos_ratio)
    for prev in (np.full(n, -1), rng.integers(0, k, n), want):
        lab, d2 = np.empty(n, dtype=np.int64), np.empty(n)
        KM.assign(X, centers, inv, prev.astype(np.int64), lab, d2, 1)
        np.testing.assert_array_equal(lab, want)
        np.testing.assert_allclose(d2, want_d2[np.arange(n), want], rtol=1e-12, atol=0)


def test_lloyd_with_hundreds_of_centres_equals_the_brute_force_iteration():
    """Late Lloyd iterations skip the particles of centres with no moved centre in reach (a
    grid of the moved centres): the same labels and centres as the dense iteration."""
    rng = np.random.default_rng(3)
    lk = PHDParams().likelihood
    k = 400
    truth = _centers(rng, k)
    truth[:, :2] = rng.uniform(-2000, 2000, (k, 2))
    src = rng.integers(0, k, 20000)
    S = truth[src] + rng.normal(0, 6, (20000, 6))
    S[:, 4:6] = np.abs(S[:, 4:6]) + 2
    X = np.ascontiguousarray(S[:, OBS])
    w = rng.uniform(0.1, 1, 20000)
    init = truth + rng.normal(0, 10, truth.shape)
    init[:, 2:4] = 0
    c, lab, m, dmin, it = KM.lloyd(X, S, w, init, 50, 0.0, lk.sigma_obs, lk.sigma_obs_min,
                                   lk.sigma_obs_pos_ratio, 1)
    wc, wlab, wit = _brute_lloyd(X, S, w, init, lk, 50, 0.0)
    assert it == wit >= 3
    np.testing.assert_array_equal(lab, wlab)
    np.testing.assert_allclose(c, wc, rtol=1e-12, atol=1e-9)


def _brute_lloyd(X, S, w, centers, lk, max_iter, tol):
    """Plain weighted Lloyd on the dense distance matrix."""
    c = centers.copy()
    labels = None
    for it in range(1, max_iter + 1):
        d2 = _brute_d2(X, c, lk)
        new = np.argmin(d2, axis=1)
        if labels is not None and np.array_equal(new, labels):
            return c, new, it
        labels = new
        m = np.bincount(labels, weights=w, minlength=len(c))
        s = np.stack([np.bincount(labels, weights=S[:, d] * w, minlength=len(c))
                      for d in range(6)], axis=1)
        nz = m > 0
        new_c = c.copy()
        new_c[nz] = s[nz] / m[nz, None]
        step = np.max(np.abs(new_c[:, OBS] - c[:, OBS]))
        c = new_c
        if tol > 0 and step <= tol:
            return c, labels, it
    return c, np.argmin(_brute_d2(X, c, lk), axis=1), max_iter


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("k", [6, 60])
@pytest.mark.parametrize("tol", [0.0, 0.01])
def test_lloyd_equals_the_brute_force_iteration(seed, k, tol):
    rng = np.random.default_rng(seed)
    lk = PHDParams().likelihood
    truth = _centers(rng, k)
    src = rng.integers(0, k, 6000)
    S = truth[src] + rng.normal(0, 4, (6000, 6))
    S[:, 4:6] = np.abs(S[:, 4:6]) + 2
    X = np.ascontiguousarray(S[:, OBS])
    w = rng.uniform(0.1, 1, 6000)
    init = truth + rng.normal(0, 8, truth.shape)      # centres off the peaks: they must move
    init[:, 2:4] = 0
    for grid_min in (1, 10 ** 9, None):        # None: the dense specialisation
        c, lab, m, dmin, it = KM.lloyd(X, S, w, init, 50, tol, lk.sigma_obs, lk.sigma_obs_min,
                                      lk.sigma_obs_pos_ratio, grid_min)
        wc, wlab, wit = _brute_lloyd(X, S, w, init, lk, 50, tol)
        assert it == wit >= 2
        np.testing.assert_array_equal(lab, wlab)
        np.testing.assert_allclose(c, wc, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(m, np.bincount(wlab, weights=w, minlength=k), rtol=1e-12)
        if tol == 0:                                   # stopped on stable labels
            np.testing.assert_allclose(dmin, _brute_d2(X, c, lk)[np.arange(6000), lab],
                                       rtol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("k", [6, 24])
@pytest.mark.parametrize("tol", [0.0, 0.01])
def test_lloyd_on_resampled_copies_equals_the_brute_force_iteration(seed, k, tol):
    """After resampling, an ancestor's copies lie side by side (a target's particles too): a
    late dense iteration looks only at the centres that moved (for a particle of an unmoved
    centre), the grid search's first iteration starts from the particle before's answer --
    the same labels and centres as plain Lloyd, in that order and shuffled, and a copy's d²
    is its original's float."""
    rng = np.random.default_rng(seed)
    lk = PHDParams().likelihood
    truth = _centers(rng, k)
    src = np.sort(rng.integers(0, k, 2500))            # a target's particles side by side
    S = truth[src] + rng.normal(0, 4, (2500, 6))
    S[:, 4:6] = np.abs(S[:, 4:6]) + 2
    S = np.repeat(S, rng.integers(1, 4, 2500), axis=0)  # copies side by side
    S[rng.integers(0, len(S), 40), 0] *= -1.0           # a few rows differ in one coordinate
    S[rng.integers(0, len(S), 40), 5] += 0.5
    n = len(S)
    w = np.full(n, 0.25)
    init = truth + rng.normal(0, 8, truth.shape)        # centres off the peaks: they must move
    init[:, 2:4] = 0
    for order in (np.arange(n), rng.permutation(n)):
        So = np.ascontiguousarray(S[order])
        X = np.ascontiguousarray(So[:, OBS])
        wc, wlab, wit = _brute_lloyd(X, So, w, init, lk, 50, tol)
        copy = np.all(X[1:] == X[:-1], axis=1)
        for grid_min in (1, None):                      # None: the dense specialisation
            c, lab, m, dmin, it = KM.lloyd(X, So, w, init, 50, tol, lk.sigma_obs,
                                          lk.sigma_obs_min, lk.sigma_obs_pos_ratio, grid_min)
            assert it == wit >= 3
            np.testing.assert_array_equal(lab, wlab)
            np.testing.assert_allclose(c, wc, rtol=1e-12, atol=1e-9)
            if tol == 0:                               # stopped on stable labels
                np.testing.assert_allclose(dmin, _brute_d2(X, c, lk)[np.arange(n), lab],
                                           rtol=1e-12)
            assert np.array_equal(dmin[1:][copy], dmin[:-1][copy])


def test_dense_lloyd_compiles_none_of_the_grid_search(tmp_path):
    """A run whose frames never have INDEX_MIN_CENTERS centres compiles only the dense K-means
    (the first run after an install compiles less): numba prunes the grid branches of the
    ``grid_min=None`` specialisation.  A fresh process with an empty numba cache."""
    import os
    import subprocess
    import sys

    code = ("import numpy as np\n"
            "from pfscope.trackers.phd import _kmeans_kernels as KM\n"
            "rng = np.random.default_rng(0)\n"
            "S = rng.uniform(10, 60, (200, 6)); X = np.ascontiguousarray(S[:, [0, 1, 4, 5]])\n"
            "KM.lloyd(X, S, np.ones(200), S[:3].copy(), 10, 0.01, 0.15, 1.0, 0.5, None)\n"
            "print(len(KM._assign.signatures), len(KM._unstable_near_moved.signatures),\n"
            "      len(KM._assign_blocks.signatures))\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=600, check=True).stdout.split()
    assert out == ["0", "0", "1"]



def test_kmeans_and_association_compile_no_zeros_or_builtin_minmax_overloads(tmp_path):
    """The dense K-means and the association's kernels (``warmup._compile_main_share``, the
    warm-up's own share on a first run, and the IoU of gap filling) allocate with ``np.empty``
    and spell ``max``/``min`` out, so numba compiles none of ``np.zeros``' overloads (nor their
    zero fills) and no builtin max/min overload for them (~1 s of CPU of the first run).
    A fresh process with an empty numba cache, numba's compile events recorded."""
    import os
    import subprocess
    import sys

    code = ("from numba.core import event as ev\n"
            "with ev.install_recorder('numba:compile') as r:\n"
            "    from pfscope.trackers import warmup as W\n"
            "    W._compile_main_share()\n"
            "    W._compile_association(edges=False)\n"
            "names = {getattr(getattr(e.data['dispatcher'], 'py_func', None), '__qualname__',\n"
            "                 '?') for _, e in r.buffer if e.is_start}\n"
            "print('\\n'.join(sorted(names)))\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    names = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                           text=True, timeout=900, check=True).stdout.split()
    assert {"lloyd", "prepare", "farthest", "edge_scores", "iou"} <= set(names)
    unwanted = [n for n in names
                if n.split(".")[0] in ("ol_np_zeros", "ol_array_zero_fill", "ol_max", "ol_min")]
    assert unwanted == []

def test_farthest_member_is_numpys_per_cluster_argmax():
    """``farthest``: every cluster's member with the largest d² in one pass, as
    ``members[argmax(dmin[members])]`` (first of ties, first NaN), -1 for an empty cluster."""
    rng = np.random.default_rng(3)
    for trial in range(40):
        n, K = int(rng.integers(0, 60)), int(rng.integers(1, 8))
        labels = rng.integers(0, K, n).astype(np.int64)
        dmin = rng.integers(0, 4, n).astype(np.float64)       # many ties
        if trial % 3 == 0 and n:
            dmin[rng.integers(0, n, 2)] = np.nan
        got = KM.farthest(labels, dmin, K)
        for j in range(K):
            members = np.flatnonzero(labels == j)
            want = members[np.argmax(dmin[members])] if len(members) else -1
            assert got[j] == want


def test_prepare_copies_is_prepare_for_resampled_runs():
    """``prepare_copies`` (the runs of copies recorded by systematic resampling, equal
    weights) gives ``prepare``'s very floats and runs: the merged weights, the shift summed
    over every particle in order, the shifted rows -- also when two runs (two ancestors) have
    identical rows side by side (merged, as ``prepare`` does) and for a non-finite weight."""
    rng = np.random.default_rng(8)
    for trial in range(60):
        R = int(rng.integers(1, 400))
        rows = rng.normal(300.0, 80.0, (R, 6))
        if trial % 3 == 0 and R > 3:                 # two ancestors with identical rows
            for a in rng.integers(1, R, 3):
                rows[a] = rows[a - 1]
        copies = rng.integers(1, 5, R)
        states = np.repeat(rows, copies, axis=0)
        n = len(states)
        log_w = np.full(n, rng.normal(-5.0, 2.0))
        if trial == 7:
            log_w[:] = -np.inf
        want = KM.prepare(states, log_w)
        # the position sums taken here, or given (as resampling's walk records them: the
        # same additions in order, np.cumsum's sequential floats)
        pos = np.array([np.cumsum(states[:, 0])[-1], np.cumsum(states[:, 1])[-1]])
        for given in (np.empty(0), pos):
            got = KM.prepare_copies(states, log_w, copies.astype(np.int64), given)
            assert got[0] == want[0] or (np.isnan(got[0]) and np.isnan(want[0]))
            if not np.isfinite(want[0]):
                assert len(got[1]) == 0
                continue
            for a, b in zip(got[1:], want[1:]):
                assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
        if not np.isfinite(want[0]):
            continue
        if trial % 3 == 0 and R > 3:
            assert len(got[5]) < R


def test_prepare_is_numpys_spelling_with_runs_of_equal_weights():
    """``prepare`` (the K-means inputs in one pass) gives numpy's floats: the max, the relative
    weights ``exp(log_w − max)`` -- also for runs of equal log-weights (as resampling leaves
    them, where the kernel takes the exp once per run) and ``-inf`` -- the mean position of
    every particle and the shifted states; runs of consecutive identical rows (resampling's
    copies of an ancestor) become one row weighing their sum (added in particle order), with
    the run's length."""
    rng = np.random.default_rng(4)
    for trial in range(40):
        n = int(rng.integers(1, 300))
        states = rng.normal(300.0, 80.0, (n, 6))
        if trial % 2:                                # copies side by side, as resampled
            states = np.repeat(states, rng.integers(1, 5, n), axis=0)[:n]
            if trial % 3 == 0 and n > 2:             # equal rows that are not adjacent
                states[-1] = states[0]
        log_w = np.repeat(rng.normal(-5.0, 2.0, n), rng.integers(1, 6, n))[:n]
        if trial % 4 == 0:
            log_w[rng.integers(0, n, 3)] = -np.inf
        lmax, w, shift, S, X, runs = KM.prepare(states, log_w)
        assert lmax == np.max(log_w)
        new = np.ones(n, dtype=bool)
        new[1:] = np.any(states[1:] != states[:-1], axis=1)
        starts = np.flatnonzero(new)
        w_each = libm.exp(log_w - np.max(log_w))
        want_w = [sum(w_each[a:b].tolist(), 0.0) if b - a > 1 else w_each[a]
                  for a, b in zip(starts, list(starts[1:]) + [n])]
        assert runs.tolist() == np.diff(np.append(starts, n)).tolist()
        np.testing.assert_array_equal(w, want_w)
        want_shift = np.zeros(6)
        want_shift[:2] = states[:, :2].mean(axis=0)
        np.testing.assert_array_equal(shift, want_shift)
        np.testing.assert_array_equal(S, (states - want_shift)[starts])
        np.testing.assert_array_equal(X, (states - want_shift)[starts][:, [0, 1, 4, 5]])
        assert (trial % 2 == 0) == (len(w) == n)


_LIBC = __import__("platform").libc_ver()[0]


@pytest.mark.skipif(_LIBC != "glibc", reason="the C library's exp is glibc's here")
def test_inline_exp_is_the_c_librarys_in_the_gate():
    """The update's inline exp (:func:`_kernels._exp_gate`) gives libm's ``exp`` (what
    ``math.exp`` calls in a kernel) bit for bit on the gate's arguments -r2/2 <= x <= 0: a
    spread of them, both ends, zero, the tiny ones (1 + x) and the table's break points.
    (glibc >= 2.28 with FMA; a CPU without FMA runs the C library's other build, which this
    test would catch.)"""
    from numba import njit

    @njit(cache=False)
    def many(x, out):
        for i in range(x.shape[0]):
            out[i] = K._exp_gate(x[i])

    rng = np.random.default_rng(0)
    x = np.concatenate([-rng.random(400_000) * 40.0, -np.exp(rng.uniform(-50, 6, 100_000)),
                        -np.arange(0, 40 * 128) / 128.0, -np.arange(1, 40 * 128) / 128.0 + 1e-17,
                        [0.0, -0.0, -2.0 ** -54, -2.0 ** -55, -5e-324, -K.EXP_GATE_MAX + 1e-9, -500.0]])
    got = np.empty_like(x)
    many(x, got)
    want = libm.exp(x)
    bad = np.flatnonzero(got.view(np.int64) != want.view(np.int64))
    assert len(bad) == 0, (x[bad[:5]], got[bad[:5]], want[bad[:5]])
