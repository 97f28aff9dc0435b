"""trackers.smc.random: the normals and uniforms drawn inside the kernels (SplitMix64 stream,
ziggurat), keyed by a word of the caller's Generator."""

import math

import numpy as np
from scipy import stats

from pfscope.trackers.smc import random as R


def _normals(key, n):
    out = np.empty(n)
    R.fill_normal(R.stream(key), out)
    return out


def test_normals_are_standard_normal():
    x = _normals(2024, 1_000_000)
    se = 1 / math.sqrt(len(x))
    assert abs(x.mean()) < 5 * se
    assert abs(x.var() - 1) < 5 * math.sqrt(2) * se
    assert abs(stats.skew(x)) < 5 * math.sqrt(6) * se
    assert abs(stats.kurtosis(x)) < 5 * math.sqrt(24) * se
    assert stats.kstest(x, "norm").pvalue > 1e-4
    # the base layer's tail beyond R (drawn by its own loop) at its normal frequency
    p = 2 * stats.norm.sf(R._ZIG_R)
    tail = np.mean(np.abs(x) > R._ZIG_R)
    assert abs(tail - p) < 5 * math.sqrt(p / len(x))
    # and the wedges: the density on a fine histogram (chi-square)
    edges = np.linspace(-4, 4, 81)
    counts, _ = np.histogram(x, edges)
    want = len(x) * np.diff(stats.norm.cdf(edges))
    chi2 = np.sum((counts - want) ** 2 / want)
    assert stats.chi2.sf(chi2, len(want) - 1) > 1e-4


def test_same_key_same_stream_other_key_independent():
    a, b, c = _normals(5, 10_000), _normals(5, 10_000), _normals(6, 10_000)
    np.testing.assert_array_equal(a, b)
    assert abs(np.corrcoef(a, c)[0, 1]) < 5 / math.sqrt(len(a))


def test_key_from_follows_the_generator():
    k1 = [R.key_from(np.random.default_rng(3)) for _ in range(2)]
    assert k1[0] == k1[1]
    g = np.random.default_rng(3)
    assert R.key_from(g) != R.key_from(g)
