"""trackers.phd.filter: the SMC-PHD recursion of maggio2007 §2 with the §4 settings."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

from pfscope.trackers.phd.clustering import kmeans_peaks
from pfscope.trackers.phd.filter import (GaussianLikelihood, PHDFilter, PHDParams, birth, log_clutter_density,
                                 log_likelihood, mass_near, n_resample, obs_std, predict,
                                 resample, update)
from pfscope.trackers.smc import ParticleSet
from pfscope.trackers.types import Detections

# Four targets moving with constant velocity, far apart (centre y, velocity, size).
TARGETS = np.array([
    [80.0, 90.0, 1.5, 0.5, 24.0, 60.0],
    [300.0, 120.0, -1.0, 1.0, 30.0, 70.0],
    [150.0, 300.0, 0.0, -2.0, 20.0, 50.0],
    [420.0, 320.0, 2.0, 0.0, 36.0, 80.0],
])


def truth_at(k):
    x = TARGETS.copy()
    x[:, 0:2] += k * x[:, 2:4]
    return x


def detections_at(k, rng, noise=1.0):
    """Observations (y1, y2, w, h) of every target with small noise, no clutter."""
    x = truth_at(k)
    z = x[:, [0, 1, 4, 5]].copy()
    z[:, 0:2] += rng.normal(0.0, noise, (len(z), 2))
    z[:, 2:4] *= 1.0 + rng.normal(0.0, 0.02, (len(z), 2))
    return z


def cloud(rng, center, mass, n=1500):
    """A PHD cloud of total weight ``mass`` around a state, spread like the observation noise."""
    c = np.asarray(center, dtype=np.float64)
    s = obs_std(c[4:6])
    std = np.array([s[0], s[1], 0.3, 0.3, s[2], s[3]])
    return ParticleSet(c + rng.standard_normal((n, 6)) * std, np.full(n, math.log(mass / n)))


# ----------------------------------------------------------------------------- whole recursion


def test_mass_counts_targets_on_a_clean_scene():
    # A clean scene: no clutter in the data and none in the model (κ = 0). Each detected
    # target then carries 1/(1 - p_M e) ≈ 1.05 at steady state.
    rng = np.random.default_rng(0)
    f = PHDFilter(PHDParams.of(clutter_rate=0.0), np.random.default_rng(1))
    for k in range(15):
        r = f.step(detections_at(k, rng))
    assert abs(r.mass - len(TARGETS)) <= 0.5, r.mass
    assert r.mass == pytest.approx(len(TARGETS) / (1 - 0.05 * 0.99), abs=0.15)


def test_paper_defaults_track_every_target():
    # With the paper's clutter (κ = 1 point per 99% gate) each target keeps ~0.8 of mass:
    # C(z) is only a few κ because the predicted cloud is as wide as the observation noise.
    rng = np.random.default_rng(0)
    f = PHDFilter(PHDParams(), np.random.default_rng(1))
    for k in range(15):
        Z = detections_at(k, rng)
        r = f.step(Z)
    n = len(TARGETS)
    assert 0.7 * n <= r.mass <= 1.06 * n, r.mass
    assert np.all(r.updated.per_det_mass > 0.6)
    c = kmeans_peaks(r.resampled, Z)
    assert c.kept.sum() == n
    truth = truth_at(14)
    err = np.abs(c.kept_centers[:, None, :] - truth[None, :, :])     # (K, n, 6)
    match = np.argmin(err[..., 0] + err[..., 1], axis=1)
    assert sorted(match) == list(range(n))
    e = err[np.arange(n), match]
    assert np.all(e[:, 0:2] < 3.0), e          # position within 3 px
    assert np.all(e[:, 2:4] < 1.0), e          # velocity within 1 px/frame
    assert np.all(e[:, 4:6] < 0.1 * truth[match, 4:6]), e


def test_isolated_clutter_is_filtered_but_a_persistent_target_is_not():
    # A real target appears at frame 0 and is detected every frame; a single false
    # detection flashes once at frame 3, far from it.
    p = PHDParams()
    f = PHDFilter(p, np.random.default_rng(4))
    target = np.array([200.0, 150.0, 30.0, 70.0])
    clutter = np.array([450.0, 60.0, 28.0, 64.0])
    kept_target, clutter_mass = [], []
    for k in range(8):
        Z = target[None] + [k * 1.0, 0.0, 0.0, 0.0]
        if k == 3:
            Z = np.vstack([Z, clutter])
        r = f.step(Z)
        c = kmeans_peaks(r.resampled, Z, T=0.6)
        near_t = np.hypot(*(c.centers[:, 0:2] - Z[0, 0:2]).T) < 10
        near_c = np.hypot(*(c.centers[:, 0:2] - clutter[0:2]).T) < 30
        kept_target.append(bool((c.kept & near_t).any()))
        clutter_mass.append(c.masses[near_c].sum() if near_c.any() else 0.0)
        assert not (c.kept & near_c).any(), f"clutter kept at frame {k}: {c.masses}"
    # §4: "multiple coherent and consecutive detections are necessary to increase the mass
    # to a level greater than T" — not at the first detection, but after a few.
    assert kept_target[0] is False
    assert all(kept_target[4:])
    assert 0.0 < clutter_mass[3] < 0.15          # "the mass starts growing around them"


def test_one_frame_detection_mass_is_small_and_grows_with_coherent_repeats():
    # The κ reading (1 clutter point per 99% gate volume) makes a first detection worth ~5%.
    f = PHDFilter(PHDParams(), np.random.default_rng(2))
    z = np.array([[100.0, 100.0, 30.0, 60.0]])
    masses = [f.step(z + [k, 0, 0, 0]).mass for k in range(6)]
    assert 0.02 < masses[0] < 0.1
    assert masses[1] < 0.6 and masses[2] < 0.6           # not yet a target
    assert np.all(np.diff(masses[:5]) > 0)
    assert masses[5] > 0.6


def test_step_is_seeded():
    rng = np.random.default_rng(0)
    Zs = [detections_at(k, rng) for k in range(4)]
    runs = []
    for seed in (7, 7, 8):
        f = PHDFilter(PHDParams(), np.random.default_rng(seed))
        for Z in Zs:
            r = f.step(Z)
        runs.append(r.resampled)
    np.testing.assert_array_equal(runs[0].states, runs[1].states)
    np.testing.assert_array_equal(runs[0].log_weights, runs[1].log_weights)
    assert not np.array_equal(runs[0].states, runs[2].states)


def test_step_accepts_detections_and_checks_input():
    f = PHDFilter(PHDParams(), np.random.default_rng(0))
    r = f.step(Detections(np.array([[10.0, 20.0, 30.0, 40.0]])))
    np.testing.assert_allclose(r.observations, [[25.0, 40.0, 30.0, 40.0]])
    assert len(r.updated.particles) == len(r.predicted) + len(r.born)
    with pytest.raises(ValueError, match="N, 4"):
        f.step(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="> 0"):
        f.step(np.array([[1.0, 1.0, 0.0, 5.0]]))
    with pytest.raises(ValueError):
        PHDFilter(PHDParams())                      # no generator
    with pytest.raises(ValueError, match="p_miss"):
        PHDParams.of(p_miss=1.5)
    with pytest.raises(ValueError, match="resampling"):
        PHDParams.of(resampling="bogus")


def test_step_takes_the_callers_observations_and_no_revive_flag():
    """What PHD-MT's tracker hands the step: the detections' observation vectors it made
    already (``observations``) and ``revive`` None on a frame with no returning track -- bit
    for bit the step that makes them from the Detections with an all-False revive array
    (while an all-True one changes the newborn: the flag is read)."""
    from pfscope.trackers.params import with_options
    from pfscope.trackers.phd.tracker import PHD_PRACTICAL

    # (the practical preset's filter with newborn odds: birth reads the revive flags)
    params = with_options(PHD_PRACTICAL.filter, {"birth_odds": 0.5, "revive_odds": 2.0})
    rng = np.random.default_rng(5)
    frames = []
    for k in range(8):
        z = detections_at(k, rng)
        z = np.concatenate([z, rng.uniform([0, 0, 20, 40], [400, 300, 40, 80], (2, 4))])
        xywh = z.copy()
        xywh[:, :2] -= xywh[:, 2:] / 2.0
        frames.append(Detections(xywh, rng.uniform(0.3, 1.0, len(z))))
    a, b, c = (PHDFilter(params, np.random.default_rng(9)) for _ in range(3))
    for d in frames:
        obs = d.observations()
        ra = a.step(d, revive=np.zeros(len(d), dtype=bool))
        rb = b.step(d, revive=None, observations=obs)
        rc = c.step(d, revive=np.ones(len(d), dtype=bool))
        assert rb.observations is obs
        np.testing.assert_array_equal(ra.observations, rb.observations)
        for x, y in ((ra.born, rb.born), (ra.resampled, rb.resampled)):
            np.testing.assert_array_equal(x.states, y.states)
            np.testing.assert_array_equal(x.log_weights, y.log_weights)
        np.testing.assert_array_equal(ra.updated.per_det_mass, rb.updated.per_det_mass)
    assert not np.array_equal(rc.born.log_weights, ra.born.log_weights)


def test_no_detections_decays_mass_by_survival_and_miss():
    f = PHDFilter(PHDParams(), np.random.default_rng(0))
    f.particles = cloud(np.random.default_rng(1), [100, 100, 0, 0, 30, 60], 1.0)
    r = f.step(np.zeros((0, 4)))
    assert r.mass == pytest.approx(0.99 * 0.05)
    assert len(r.born) == 0
    assert len(r.resampled) == round(1500 * 0.99 * 0.05)


# ----------------------------------------------------------------------------- stages


def test_predict_applies_survival_and_motion():
    p = PHDParams()
    ps = cloud(np.random.default_rng(0), [100, 100, 3, 0, 30, 60], 0.8)
    out = predict(ps, p.motion, np.random.default_rng(1))
    assert out.mass == pytest.approx(0.99 * 0.8)
    assert np.mean(out.states[:, 0] - ps.states[:, 0]) == pytest.approx(3.0, abs=0.2)


def test_birth_allocation_shrinks_where_mass_explains_a_detection():
    p = PHDParams()
    rng = np.random.default_rng(0)
    Z = np.array([[100.0, 100.0, 30.0, 60.0], [400.0, 100.0, 30.0, 60.0],
                  [250.0, 300.0, 30.0, 60.0]])
    predicted = cloud(rng, [100, 100, 0, 0, 30, 60], 0.8).concat(
        cloud(rng, [250, 300, 0, 0, 30, 60], 1.3))
    b = birth(predicted, Z, p, np.random.default_rng(1))
    # about 99% of a Gaussian cloud as wide as the noise lies in the 4-D 99% gate
    np.testing.assert_allclose(b.mass_near, [0.8 * 0.99, 0.0, 1.3 * 0.99], atol=0.03)
    np.testing.assert_array_equal(b.j_per_det, np.rint(1000 * np.maximum(0, 1 - b.mass_near)))
    assert b.j_per_det[1] == 1000 and b.j_per_det[2] == 0 and 150 < b.j_per_det[0] < 260
    assert len(b.particles) == b.j_per_det.sum()
    np.testing.assert_array_equal(np.bincount(b.det_index, minlength=3), b.j_per_det)
    # every detection that gets newborn gives them total weight birth_intensity
    w = b.particles.weights
    for j in (0, 1):
        assert w[b.det_index == j].sum() == pytest.approx(0.01)
    # newborn sit around their detection with the observation noise, velocity isotropic
    born1 = b.particles.states[b.det_index == 1]
    np.testing.assert_allclose(born1[:, [0, 1, 4, 5]].mean(0), Z[1], atol=0.5)
    np.testing.assert_allclose(born1[:, [0, 1, 4, 5]].std(0), obs_std(Z[1, 2:4]), rtol=0.1)
    assert abs(born1[:, 2].mean()) < 0.5 and abs(born1[:, 3].mean()) < 0.5
    # the "constant" reading allocates J_max everywhere
    bc = birth(predicted, Z, PHDParams.of(birth_allocation="constant"), np.random.default_rng(1))
    np.testing.assert_array_equal(bc.j_per_det, [1000, 1000, 1000])


def test_mass_near_counts_only_the_gate():
    p = PHDParams()
    z = np.array([[100.0, 100.0, 30.0, 60.0]])
    std = obs_std(z[0, 2:4])
    r = math.sqrt(chi2.ppf(0.99, 4))
    states = np.array([[100 + 0.9 * r * std[0], 100, 0, 0, 30, 60],
                       [100 + 1.1 * r * std[0], 100, 0, 0, 30, 60]])
    ps = ParticleSet(states, np.log([0.25, 0.5]))
    assert mass_near(ps, z, p.birth, p.likelihood)[0] == pytest.approx(0.25)


def test_update_matches_equation_5_in_linear_space():
    p = PHDParams()
    rng = np.random.default_rng(3)
    ps = cloud(rng, [100, 100, 0, 0, 30, 60], 0.7).concat(cloud(rng, [200, 90, 0, 0, 20, 50], 0.2, n=300))
    Z = np.array([[101.0, 99.0, 31.0, 58.0], [205.0, 92.0, 19.0, 52.0], [400, 300, 25, 25]])
    log_g = log_likelihood(ps.states, Z, p.likelihood)
    log_kappa = log_clutter_density(Z, p.clutter, p.likelihood)
    u = update(ps, log_g, log_kappa, p.likelihood.p_miss)
    # direct evaluation of eq. (5) with the same g and κ
    w = ps.weights
    psi = 0.95 * np.exp(log_g)
    C = psi.T @ w
    kappa = np.exp(log_kappa)
    expected = (0.05 + (psi / (kappa + C)).sum(1)) * w
    np.testing.assert_allclose(u.particles.weights, expected, rtol=1e-9)
    np.testing.assert_allclose(u.c_z, C, rtol=1e-9)
    np.testing.assert_allclose(u.per_det_mass, C / (kappa + C), rtol=1e-9)
    assert u.particles.mass == pytest.approx(u.miss_mass + u.per_det_mass.sum())
    assert u.per_det_mass[2] < 1e-6                      # nothing near the third detection


def test_clutter_density_is_rate_over_the_gate_volume():
    p = PHDParams()
    Z = np.array([[50.0, 50.0, 10.0, 20.0], [300.0, 200.0, 60.0, 150.0], [5, 5, 2.0, 3.0]])
    kappa = np.exp(log_clutter_density(Z, p.clutter, p.likelihood))
    # Monte-Carlo volume of the 99% ellipsoid around the second detection, times κ, is 1
    rng = np.random.default_rng(0)
    std = obs_std(Z[1, 2:4])
    r = math.sqrt(chi2.ppf(0.99, 4))
    u = rng.uniform(-r, r, (400000, 4))
    vol = (2 * r) ** 4 * np.mean((u ** 2).sum(1) <= r * r) * np.prod(std)
    assert kappa[1] * vol == pytest.approx(1.0, rel=0.02)
    # the ratio κ / max g is the same for every box size (8 / r^4)
    peak = np.exp(log_likelihood(np.c_[Z[:, :2], np.zeros((3, 2)), Z[:, 2:]], Z,
                                 p.likelihood).diagonal())
    np.testing.assert_allclose(kappa / peak, 8 / r ** 4, rtol=1e-9)
    assert np.all(np.exp(log_clutter_density(Z, PHDParams.of(clutter_rate=0.0).clutter)) == 0)


def test_likelihood_std_follows_the_paper():
    p = PHDParams()
    np.testing.assert_allclose(obs_std(np.array([40.0, 100.0]), p.likelihood), [3.0, 7.5, 6.0, 15.0])
    np.testing.assert_allclose(obs_std(np.array([4.0, 5.0]), p.likelihood), [0.5, 0.5, 1.0, 1.0])
    # the "particle" reading takes the std from the particle's own size
    z = np.array([[0.0, 0.0, 40.0, 100.0]])
    x = np.array([[3.0, 0, 0, 0, 40.0, 100.0], [3.0, 0, 0, 0, 80.0, 100.0]])
    lp = log_likelihood(x, z, PHDParams.of(obs_std_source="particle").likelihood)
    ld = log_likelihood(x, z, p.likelihood)
    assert lp[0, 0] == pytest.approx(ld[0, 0])
    assert lp[1, 0] != pytest.approx(ld[1, 0])


def test_resample_keeps_rho_particles_per_unit_mass():
    p = PHDParams()
    ps = cloud(np.random.default_rng(0), [100, 100, 0, 0, 30, 60], 2.345, n=5000)
    for scheme in ("systematic", "stratified", "residual", "multinomial"):
        out = resample(ps, PHDParams.of(resampling=scheme).resampling, np.random.default_rng(1))
        assert len(out) == round(1500 * 2.345)
        assert out.mass == pytest.approx(ps.mass, rel=1e-12)
    rp = p.resampling
    assert n_resample(0.0, rp) == 0
    assert n_resample(1e-6, rp) == 1                      # min_particles keeps the mass
    assert n_resample(1e6, rp) == rp.max_particles


# ----------------------------------------------------------------------------- pluggable likelihood


def test_update_takes_any_likelihood_and_the_filter_hands_it_the_frame():
    """The filter never knows which g it runs (maggio2007 eq. 5 = feng2015 eqs. 11-12): a
    likelihood that zeroes g on the left half of the image starves the target there."""
    from pfscope.trackers.types import Frame

    class RightHalfOnly:
        def __init__(self):
            self.frames = []
            self.gauss = GaussianLikelihood(PHDParams().likelihood)

        def log_g(self, states, Z, frame):
            self.frames.append(frame.index)
            lg = self.gauss.log_g(states, Z, frame)
            return np.where(states[:, [0]] < frame.width / 2, -np.inf, lg)

    Z = np.array([[100.0, 100.0, 30.0, 60.0], [500.0, 100.0, 30.0, 60.0]])
    image = np.zeros((240, 640, 3), np.uint8)
    lk = RightHalfOnly()
    f = PHDFilter(PHDParams(), np.random.default_rng(0), likelihood=lk)
    g = PHDFilter(PHDParams(), np.random.default_rng(0))
    for k in range(1, 8):
        r = f.step(Z, Frame(k, 0.0, image))
        q = g.step(Z)
    assert lk.frames == list(range(1, 8))
    left, right = r.resampled.states[:, 0] < 320, r.resampled.states[:, 0] >= 320
    w = r.resampled.weights
    assert w[left].sum() < 0.01 < 0.5 < w[right].sum()
    # with the Gaussian both targets carry mass
    wq, xq = q.resampled.weights, q.resampled.states[:, 0]
    assert wq[xq < 320].sum() > 0.5 and wq[xq >= 320].sum() > 0.5


def test_update_checks_the_likelihood_matrix_shape():
    ps = cloud(np.random.default_rng(0), [100, 100, 0, 0, 30, 60], 1.0, n=10)
    with pytest.raises(ValueError, match="log_g"):
        update(ps, np.zeros((9, 2)), np.zeros(2), 0.05)
