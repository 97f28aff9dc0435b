"""trackers.smc.random: the normals drawn inside the kernels (counter-based SplitMix64 words,
Box–Muller with inline log / cos / sin), keyed by a word of the caller's Generator."""

import math

import numpy as np
import pytest
from numba import njit
from scipy import stats

from pfscope.trackers.smc import random as R


def _normals(key, n, first=0):
    out = np.empty(n)
    R.fill_normal(np.array([key, first], np.uint64), out)
    return out


@njit(cache=False)
def _subkey(key, j):
    return R.subkey(key, j)


@njit(cache=False)
def _pairs_into(key, p0, dp, n):
    a, b = np.empty(n), np.empty(n)
    R.normal_pairs_into(key, p0, dp, a, b, n)
    return a, b


def test_normals_are_standard_normal():
    x = _normals(2024, 1_000_000)
    se = 1 / math.sqrt(len(x))
    assert abs(x.mean()) < 5 * se
    assert abs(x.var() - 1) < 5 * math.sqrt(2) * se
    assert abs(stats.skew(x)) < 5 * math.sqrt(6) * se
    assert abs(stats.kurtosis(x)) < 5 * math.sqrt(24) * se
    assert stats.kstest(x, "norm").pvalue > 1e-4
    # the tails at their normal frequency (beyond 3 σ and 4 σ)
    for t in (3.0, 4.0):
        p = 2 * stats.norm.sf(t)
        assert abs(np.mean(np.abs(x) > t) - p) < 5 * math.sqrt(p / len(x))
    # and the density on a fine histogram (chi-square)
    edges = np.linspace(-4, 4, 81)
    counts, _ = np.histogram(x, edges)
    want = len(x) * np.diff(stats.norm.cdf(edges))
    chi2 = np.sum((counts - want) ** 2 / want)
    assert stats.chi2.sf(chi2, len(want) - 1) > 1e-4


def test_neighbouring_normals_are_independent():
    """The two normals of a pair, neighbouring pairs, and the pair's radius and angle: no
    correlation, and the pair (x, y) is isotropic (its angle uniform, its squared radius
    exponential with mean 2)."""
    x = _normals(77, 1_000_000)
    lim = 5 / math.sqrt(len(x) / 2)
    a, b = x[0::2], x[1::2]
    assert abs(np.corrcoef(a, b)[0, 1]) < lim                 # within a pair
    assert abs(np.corrcoef(b[:-1], a[1:])[0, 1]) < lim        # across pairs
    assert abs(np.corrcoef(a[:-1], a[1:])[0, 1]) < lim
    assert abs(np.corrcoef(a ** 2, b ** 2)[0, 1]) < lim       # not just uncorrelated
    theta = np.arctan2(b, a)
    assert stats.kstest((theta + np.pi) / (2 * np.pi), "uniform").pvalue > 1e-4
    assert stats.kstest(a * a + b * b, "expon", args=(0, 2)).pvalue > 1e-4
    # the quadrants' four branches: each a quarter, the signs of (x, y) independent
    q = (a > 0).astype(int) * 2 + (b > 0)
    counts = np.bincount(q, minlength=4)
    assert stats.chisquare(counts).pvalue > 1e-4


def test_normal_i_is_a_pure_function_of_key_and_i():
    """Same key, same normals (determinism); normal i does not depend on which others were
    drawn (a slice from an offset, the kernels' chunked loops with a stride); other keys and
    subkeys give independent normals."""
    a, b = _normals(5, 10_000), _normals(5, 10_000)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(_normals(5, 1001, first=600), a[600:1601])
    # pairs 2k (and 2k + 1) of k = 0 … n − 1, as propagate_into draws them in chunks
    e0, e1 = _pairs_into(np.uint64(5), np.uint64(0), np.uint64(2), 2000)
    e2, e3 = _pairs_into(np.uint64(5), np.uint64(1), np.uint64(2), 2000)
    np.testing.assert_array_equal(np.c_[e0, e1, e2, e3].ravel(), a[:8000])
    c = _normals(6, 10_000)
    assert abs(np.corrcoef(a, c)[0, 1]) < 5 / math.sqrt(len(a))
    k0, k1 = _subkey(np.uint64(5), 0), _subkey(np.uint64(5), 1)
    assert len({5, int(k0), int(k1)}) == 3
    for k in (k0, k1):
        s = _normals(int(k), 10_000)
        assert abs(np.corrcoef(a, s)[0, 1]) < 5 / math.sqrt(len(a))
        assert stats.kstest(s, "norm").pvalue > 1e-4


def test_key_from_follows_the_generator():
    k1 = [R.key_from(np.random.default_rng(3)) for _ in range(2)]
    assert k1[0] == k1[1]
    g = np.random.default_rng(3)
    assert R.key_from(g) != R.key_from(g)


def test_key_stream_is_stream_of_key_from():
    """key_stream(rng): the word stream(key_from(rng)) makes, as the same uint64 (1,) array,
    and it advances the generator as key_from does."""
    a, b = np.random.default_rng(3), np.random.default_rng(3)
    for _ in range(20):
        want, got = R.stream(R.key_from(a)), R.key_stream(b)
        assert got.dtype == want.dtype == np.uint64 and got.shape == want.shape == (1,)
        assert got[0] == want[0]
    assert a.random() == b.random()


def test_direction_is_uniform_on_the_circle():
    n = 400_000
    c, s = np.empty(n), np.empty(n)
    R.fill_direction(R.stream(9), c, s)
    assert np.abs(np.hypot(c, s) - 1).max() < 4e-16
    theta = np.arctan2(s, c)
    assert stats.kstest((theta + np.pi) / (2 * np.pi), "uniform").pvalue > 1e-4
    counts, _ = np.histogram(theta, np.linspace(-np.pi, np.pi, 65))   # every octant's half
    assert stats.chisquare(counts).pvalue > 1e-4
    assert abs(np.corrcoef(theta[:-1], theta[1:])[0, 1]) < 5 / math.sqrt(n)


def _ulps(got, want):
    return np.max(np.abs(got - want) / np.spacing(np.abs(want)))


def test_inline_log_cos_sin_are_the_c_librarys_within_one_ulp():
    """The generator's polynomial log (on [2⁻⁵³, 1]) and cos / sin (on [−π/4, π/4]) against
    the C library's (``math``): within one unit in the last place, exact on most arguments."""
    rng = np.random.default_rng(0)
    x = np.concatenate([1.0 - rng.random(200_000), 2.0 ** -rng.uniform(0, 53, 100_000),
                        np.ldexp(1.0, -np.arange(54)), 1 - np.arange(1, 2000) * 2.0 ** -53,
                        np.arange(1, 2000) * 2.0 ** -53, [math.sqrt(0.5), math.sqrt(2) / 2]])
    t = np.concatenate([(rng.random(200_000) - 0.5) * (math.pi / 2),
                        [-math.pi / 4, math.pi / 4, 0.0, 1e-300, -1e-20, 0.3, -0.3]])
    lx, ct, st = np.empty_like(x), np.empty_like(t), np.empty_like(t)
    R.log_cos_sin(x, t, lx, ct, st)
    log_ref = np.array([math.log(v) for v in x])
    nz = log_ref != 0
    assert np.all(lx[~nz] == 0.0)
    assert _ulps(lx[nz], log_ref[nz]) <= 1.0
    assert np.mean(lx == log_ref) > 0.9
    cos_ref = np.array([math.cos(v) for v in t])
    sin_ref = np.array([math.sin(v) for v in t])
    assert _ulps(ct, cos_ref) <= 1.0
    nz = sin_ref != 0
    assert _ulps(st[nz], sin_ref[nz]) <= 1.0 and np.all(st[~nz] == sin_ref[~nz])
    assert np.mean(ct == cos_ref) > 0.9 and np.mean(st == sin_ref) > 0.9


@pytest.mark.parametrize("key", [0, 2 ** 64 - 1])
def test_extreme_keys_and_words(key):
    """Any 64-bit key works (the counter wraps modulo 2⁶⁴); no NaN or infinity."""
    x = _normals(key, 100_001)
    assert np.isfinite(x).all()
    assert np.abs(x).max() < 8.6                   # sqrt(−2 log 2⁻⁵³) = 8.57
