"""trackers.smc: log-weights, the four resampling schemes, labels/extra columns; and
maggio2007's size-aware motion model (trackers.phd.motion)."""

import numpy as np
import pytest

from pfscope.trackers.phd.motion import propagate
from pfscope.trackers.smc import (SCHEMES, ParticleSet, ess, logsumexp, normalise, resample,
                                  resample_indices)
from pfscope.trackers.smc.weights import LazyParticleSet

# ----------------------------------------------------------------------------- weights


def test_logsumexp_matches_naive_and_survives_underflow():
    x = np.array([-1.0, 0.5, 2.0, -3.0])
    assert logsumexp(x) == pytest.approx(np.log(np.exp(x).sum()))
    # exp(-1000) underflows to 0 in linear space; the log-space sum must not.
    assert logsumexp(x - 1000.0) == pytest.approx(np.log(np.exp(x).sum()) - 1000.0)
    assert logsumexp(np.array([])) == -np.inf
    assert logsumexp(np.array([-np.inf, -np.inf])) == -np.inf
    assert logsumexp(np.array([-np.inf, 0.0])) == 0.0
    m = np.log(np.array([[1.0, 2.0], [3.0, 4.0]]))
    np.testing.assert_allclose(logsumexp(m, axis=0), np.log([4.0, 6.0]))
    np.testing.assert_allclose(logsumexp(m, axis=1), np.log([3.0, 7.0]))


def test_normalise_and_ess():
    lw = np.log(np.array([1.0, 1.0, 2.0]))
    nl, lse = normalise(lw)
    np.testing.assert_allclose(np.exp(nl), [0.25, 0.25, 0.5])
    assert lse == pytest.approx(np.log(4.0))
    assert ess(np.zeros(10)) == pytest.approx(10.0)
    assert ess(np.array([0.0, -np.inf, -np.inf])) == pytest.approx(1.0)
    assert ess(np.log([0.5, 0.25, 0.25])) == pytest.approx(1.0 / (0.25 + 2 * 0.0625))
    with pytest.raises(ValueError):
        normalise(np.array([-np.inf]))


def test_particle_set_checks_and_mass():
    ps = ParticleSet(np.zeros((3, 6)), np.log([0.2, 0.3, 0.5]) + np.log(2.0))
    assert ps.mass == pytest.approx(2.0)
    assert len(ps) == 3 and ps.dim == 6
    assert ps.concat(ps).mass == pytest.approx(4.0)
    assert ParticleSet.empty(6).mass == 0.0
    with pytest.raises(ValueError):
        ParticleSet(np.zeros((3, 6)), np.zeros(2))
    with pytest.raises(ValueError):
        ParticleSet(np.zeros(6), np.zeros(6))


# ----------------------------------------------------------------------------- resampling


@pytest.mark.parametrize("scheme", SCHEMES)
def test_resampling_preserves_mass(scheme):
    rng = np.random.default_rng(3)
    states = rng.normal(size=(400, 6))
    lw = rng.normal(size=400) * 3.0 - 900.0          # tiny weights: only log space survives
    ps = ParticleSet(states, lw)
    for n in (1, 7, 400, 1234):
        out = resample(ps, n, rng, scheme)
        assert len(out) == n
        assert out.log_mass == pytest.approx(ps.log_mass, abs=1e-9)
        np.testing.assert_allclose(out.log_weights, ps.log_mass - np.log(n))
        # every offspring is a copy of an input particle
        assert np.isin(out.states[:, 0], states[:, 0]).all()


@pytest.mark.parametrize("scheme", SCHEMES)
def test_resampling_counts_are_unbiased(scheme):
    rng = np.random.default_rng(11)
    w = np.array([0.02, 0.13, 0.3, 0.05, 0.0, 0.5])
    lw = np.log(np.where(w > 0, w, 1.0)) + np.where(w > 0, 0.0, -np.inf)
    n, runs = 10, 3000
    counts = np.zeros((runs, len(w)))
    for r in range(runs):
        counts[r] = np.bincount(resample_indices(lw, n, rng, scheme), minlength=len(w))
    mean = counts.mean(axis=0)
    # multinomial variance n w (1 - w) bounds the others; 5 standard errors
    se = np.sqrt(n * w * (1 - w) / runs)
    assert np.all(np.abs(mean - n * w) <= 5 * se + 1e-12), (mean, n * w)
    assert counts[:, 4].sum() == 0                    # zero weight is never drawn
    assert (counts.sum(axis=1) == n).all()


def test_low_variance_schemes_keep_their_guarantees():
    rng = np.random.default_rng(5)
    w = rng.dirichlet(np.ones(50))
    lw = np.log(w)
    for _ in range(50):
        c_sys = np.bincount(resample_indices(lw, 200, rng, "systematic"), minlength=50)
        assert np.all(np.abs(c_sys - 200 * w) < 1.0)     # systematic: within 1 of n w
        c_res = np.bincount(resample_indices(lw, 200, rng, "residual"), minlength=50)
        assert np.all(c_res >= np.floor(200 * w))        # residual: floor(n w) copies kept


def test_resampling_is_seeded_and_checks_its_scheme():
    lw = np.log(np.random.default_rng(0).dirichlet(np.ones(30)))
    for scheme in SCHEMES:
        a = resample_indices(lw, 100, np.random.default_rng(42), scheme)
        b = resample_indices(lw, 100, np.random.default_rng(42), scheme)
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="unknown resampling scheme"):
        resample_indices(lw, 10, np.random.default_rng(0), "bogus")
    assert len(resample(ParticleSet.empty(6), 10, np.random.default_rng(0))) == 0


# ----------------------------------------------------------------------------- motion


def _state(n, y=(100.0, 50.0), v=(2.0, -1.0), size=(20.0, 40.0)):
    return np.tile(np.r_[y, v, size], (n, 1))


def test_propagate_is_first_order_on_position_zero_order_on_size():
    x = _state(5)
    out = propagate(x, np.random.default_rng(0), sigma_v=0.0, sigma_size=0.0)
    np.testing.assert_allclose(out[:, 0:2], x[:, 0:2] + x[:, 2:4])
    np.testing.assert_allclose(out[:, 2:], x[:, 2:])


def test_propagate_noise_is_proportional_to_size():
    rng = np.random.default_rng(1)
    n = 20000
    for w, h in ((10.0, 30.0), (100.0, 300.0)):
        x = _state(n, size=(w, h))
        out = propagate(x, rng)
        dv = out[:, 2:4] - x[:, 2:4]
        np.testing.assert_allclose(dv.std(axis=0), [0.03 * w, 0.03 * h], rtol=0.03)
        np.testing.assert_allclose(out[:, 4:6].std(axis=0), [0.1 * w, 0.1 * h], rtol=0.03)
        # the acceleration enters the position with gain 1/2 (constant over the frame)
        dy = out[:, 0:2] - x[:, 0:2] - x[:, 2:4]
        np.testing.assert_allclose(dy, 0.5 * dv, atol=1e-9)
    tiny = propagate(_state(n, size=(1.0, 1.0)), rng)
    assert tiny[:, 4:6].min() >= 1.0


def test_propagate_is_seeded():
    x = np.random.default_rng(0).uniform(10, 50, size=(100, 6))
    a = propagate(x, np.random.default_rng(9))
    b = propagate(x, np.random.default_rng(9))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, propagate(x, np.random.default_rng(10)))


# ----------------------------------------------------------------------------- any dimension


@pytest.mark.parametrize("dim", [1, 4, 9])
def test_particle_sets_of_any_dimension_carry_labels_and_extra_through_resampling(dim):
    rng = np.random.default_rng(0)
    n = 500
    labels = np.repeat(np.arange(5), n // 5)
    extra = np.stack([labels * 10.0, -labels * 1.0], axis=1)   # columns tied to the label
    lw = np.log(np.where(labels == 3, 10.0, 1.0))               # label 3 is heavy
    ps = ParticleSet(rng.normal(size=(n, dim)), lw, labels, extra)
    out = resample(ps, 300, rng, "systematic")
    assert out.dim == dim and len(out) == 300
    assert out.mass == pytest.approx(ps.mass)
    # every offspring keeps its parent's label and extra row
    np.testing.assert_array_equal(out.extra[:, 0], out.labels * 10.0)
    np.testing.assert_array_equal(out.extra[:, 1], -out.labels * 1.0)
    # the heavy label gets ~10/14 of the offspring
    assert abs(np.mean(out.labels == 3) - 10 / 14) < 0.02
    both = ps.take(labels == 1).concat(ps.take(labels == 2))
    assert set(both.labels.tolist()) == {1, 2} and both.extra.shape == (200, 2)


def test_particle_set_rejects_mismatched_columns():
    with pytest.raises(ValueError, match="labels"):
        ParticleSet(np.zeros((3, 2)), np.zeros(3), labels=np.zeros(2))
    with pytest.raises(ValueError, match="extra"):
        ParticleSet(np.zeros((3, 2)), np.zeros(3), extra=np.zeros((4, 1)))
    with pytest.raises(ValueError, match="one side only"):
        ParticleSet(np.zeros((1, 2)), np.zeros(1), labels=[1]).concat(
            ParticleSet(np.zeros((1, 2)), np.zeros(1)))


def test_systematic_resampling_walks_the_known_normalised_weights():
    """A set whose maker recorded its normalised weights (the PHD update's kernel) is walked on
    them, not on exps of its log-weights: the same ancestors when they agree (up to round-off),
    the recorded ones when they differ."""
    rng = np.random.default_rng(4)
    lw = rng.normal(0, 2, 3000)
    ps = ParticleSet(rng.normal(size=(3000, 6)), lw)
    plain = resample(ps, 2500, np.random.default_rng(9))
    hinted = ParticleSet(ps.states, lw)
    w = np.exp(lw - lw.max())
    hinted.known_normalised(w, 1.0 / w.sum())
    got = resample(hinted, 2500, np.random.default_rng(9))
    np.testing.assert_array_equal(got.states, plain.states)
    assert got.log_mass == pytest.approx(plain.log_mass)
    skewed = ParticleSet(ps.states, lw)
    one = np.zeros(3000)
    one[17] = 5.0
    skewed.known_normalised(one, 0.2)                  # every ancestor is particle 17
    out = resample(skewed, 40, np.random.default_rng(9))
    np.testing.assert_array_equal(out.states, np.repeat(ps.states[17:18], 40, 0))


def test_lazy_particle_set_makes_its_log_weights_once_and_only_when_read():
    rng = np.random.default_rng(2)
    x, lw = rng.normal(size=(500, 6)), rng.normal(-5, 1, 500)
    calls = []

    def make():
        calls.append(1)
        return lw.copy()

    lazy = LazyParticleSet(x, make, labels=np.arange(500))
    assert len(lazy) == 500 and lazy.dim == 6 and not calls
    w = np.exp(lw - lw.max())
    lazy.known_normalised(w, 1.0 / w.sum())
    lazy.known_log_mass(float(logsumexp(lw)))
    out = resample(lazy, 400, np.random.default_rng(9))  # walks the recorded weights
    assert not calls
    plain = resample(ParticleSet(x, lw, np.arange(500)), 400, np.random.default_rng(9))
    np.testing.assert_array_equal(out.states, plain.states)
    np.testing.assert_array_equal(out.labels, plain.labels)
    np.testing.assert_array_equal(lazy.log_weights, lw)
    np.testing.assert_array_equal(lazy.weights, np.exp(lw))
    np.testing.assert_array_equal(lazy.take(np.arange(3)).log_weights, lw[:3])
    assert len(calls) == 1
    with pytest.raises(ValueError, match="labels"):
        LazyParticleSet(x, make, labels=np.arange(3))
    with pytest.raises(ValueError, match="log-weights"):
        _ = LazyParticleSet(x, lambda: lw[:7]).log_weights


def test_unchecked_sets_are_the_checked_ones():
    """ParticleSet.unchecked and LazyParticleSet.unchecked / its keywords (what a filter makes
    of its own arrays) hold what the constructor and the known_* records hold."""
    rng = np.random.default_rng(3)
    x, lw = rng.normal(size=(50, 6)), rng.normal(-5, 1, 50)
    a, b = ParticleSet(x, lw), ParticleSet.unchecked(x, lw)
    assert type(b) is ParticleSet and a.__dict__ == b.__dict__ and b.mass == a.mass
    w = np.exp(lw - lw.max())
    lm = float(logsumexp(lw))
    want = LazyParticleSet(x, lambda: lw)
    want.known_normalised(w, 1.0 / w.sum())
    want.known_log_mass(lm)
    for got in (LazyParticleSet.unchecked(x, lambda: lw, lm, (w, 1.0 / w.sum())),
                LazyParticleSet(x, lambda: lw, log_mass=lm, normalised=(w, 1.0 / w.sum()))):
        assert type(got) is LazyParticleSet and got.labels is None and got.extra is None
        assert got.log_mass == want.log_mass and got.normalised == want.normalised
        assert got.mass == want.mass and got.states is x
        np.testing.assert_array_equal(got.log_weights, lw)
    bare = LazyParticleSet.unchecked(x, lambda: lw, lm)
    assert bare.normalised is None and bare.log_mass == lm


def test_weights_of_equal_log_weights_are_numpys_exps():
    """The equal-weight shortcut of ParticleSet.weights (one exp) gives np.exp's floats;
    resampling and a PHD prediction of its output record the equality, a set with one weight
    off takes the full pass."""
    rng = np.random.default_rng(5)
    for t in range(2000):
        n = int(rng.integers(1, 5000))
        v = float(rng.choice([rng.normal(-9, 5), rng.uniform(-745, 700), -np.inf]))
        lw = np.full(n, v)
        if t % 3 == 0:
            lw[rng.integers(0, n)] = rng.choice([np.nextafter(v, np.inf), np.nan, v - 1])
        ps = ParticleSet(np.zeros((n, 2)), lw)
        w = ps.weights
        np.testing.assert_array_equal(w, np.exp(lw))
        assert not w.flags.writeable
        assert ps.__dict__["_equal"] == bool(np.all(lw == lw[0]))
    out = resample(ParticleSet(rng.normal(size=(300, 6)), rng.normal(size=300)), 200, rng)
    assert out.__dict__["_equal"]
    np.testing.assert_array_equal(out.weights, np.exp(out.log_weights))
    from pfscope.trackers.phd.filter import MotionParams, predict
    pred = predict(out, MotionParams(), rng)
    assert pred.__dict__["_equal"] and pred.log_weights.min() == pred.log_weights.max()
    np.testing.assert_array_equal(pred.weights, np.exp(pred.log_weights))
    assert not predict(ParticleSet(out.states, rng.normal(size=200)), MotionParams(),
                       rng).__dict__.get("_equal")


def test_log_mass_of_equal_weights_is_logsumexps_float():
    """The equal-weight shortcut of ParticleSet.log_mass (resampled sets and their prediction)
    gives logsumexp's very float; a set with one weight off, -inf or NaN takes the full pass."""
    rng = np.random.default_rng(3)
    for t in range(3000):
        n = int(rng.integers(1, 30000))
        v = float(rng.choice([rng.normal(0, 30), -rng.exponential(50), rng.uniform(-745, 700)]))
        lw = np.full(n, v)
        if t % 3 == 0:
            lw[rng.integers(0, n)] = rng.choice([np.nextafter(v, np.inf), -np.inf, np.nan, v - 1])
        got = ParticleSet(np.zeros((n, 2)), lw).log_mass
        want = float(logsumexp(lw))
        assert got == want or (np.isnan(got) and np.isnan(want)), (n, v, got, want)
    assert ParticleSet(np.zeros((4, 2)), np.full(4, -np.inf)).log_mass == -np.inf
    assert ParticleSet(np.zeros((0, 2)), np.zeros(0)).log_mass == -np.inf


def test_made_tells_which_cached_values_exist():
    """ParticleSet.made: False until the cached value is computed, True after (what the
    clutter model's shortcuts from known-equal weights ask before making their own floats)."""
    ps = ParticleSet(np.zeros((3, 6)), np.log(np.full(3, 0.5)))
    assert not ps.made("weights", "mass", "log_mass")
    ps.weights
    assert ps.made("weights") and not ps.made("mass")
    ps.mass
    assert ps.made("mass") and ps.made("log_mass")
