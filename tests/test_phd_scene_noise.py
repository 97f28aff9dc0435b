"""The likelihood width learnt from the detector's jitter (trackers.phd.scene_noise,
``noise.learn_width``).

The failure it addresses: a detector whose boxes jitter much more than maggio2007's 0.15-of-
the-size observation noise (KITTI-13: 11-15 % size change frame to frame, against ~5 % on
PETS09) leaves every newborn cloud outside the next detection, and PHD-MT confirms no track at
all.  The synthetic scene reproduces it with ``box_noise`` 0.15 (tolerances stated per test,
measured over seeds 0-2)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from pfscope.trackers.api import make_tracker
from pfscope.trackers.data.sources import open_source
from pfscope.trackers.data.synthetic import SceneConfig
from pfscope.trackers.phd.filter import PHDFilter, PHDParams
from pfscope.trackers.phd.scene_noise import (DetectorJitter, NoiseParams, consecutive_pairs,
                                              learnt_width)
from pfscope.trackers.pipeline import run

SEEDS = (0, 1, 2)
LEARN = 2.5          # the factor the tests run with (README/DESIGN: 2.5-3)


def _people(rng, n_frames: int, jitter: float, clutter: float):
    """Five people walking across a 640x480 image, log-normal size noise of std ``jitter``,
    plus Poisson clutter boxes; (cx, cy, w, h) per frame."""
    start = np.column_stack([rng.uniform(100, 540, 5), rng.uniform(150, 330, 5)])
    vel = rng.normal(0, 2.0, (5, 2))
    size = np.column_stack([rng.uniform(25, 50, 5), np.zeros(5)])
    size[:, 1] = 2.4 * size[:, 0]
    for k in range(n_frames):
        c = start + k * vel + rng.normal(0, jitter * size[:, :1] / 2, (5, 2))
        wh = size * np.exp(rng.normal(0, jitter, (5, 2)))
        n_c = rng.poisson(clutter)
        cl = np.column_stack([rng.uniform(0, 640, n_c), rng.uniform(0, 480, n_c),
                              rng.uniform(20, 60, n_c), rng.uniform(50, 140, n_c)])
        yield np.vstack([np.column_stack([c, wh]), cl])


@pytest.mark.parametrize("jitter", [0.04, 0.15])
def test_jitter_estimate_recovers_the_detectors_size_noise(jitter):
    """Over seeds 0-2, 100 frames, 3 clutter boxes a frame: the estimate is within 20 % of the
    true log-size std (the prior, 50 pseudo-pairs at 0.06, is forgotten over memory 30)."""
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        est = DetectorJitter(NoiseParams(learn_width=LEARN), base_width=0.15)
        for k, Z in enumerate(_people(rng, 100, jitter, 3.0)):
            est.see(k + 1, Z, memory=30.0)
        assert np.all(np.abs(est.jitter / jitter - 1) < 0.2), (seed, est.jitter)


def test_jitter_prior_is_the_given_width_and_a_gap_breaks_the_chain():
    est = DetectorJitter(NoiseParams(learn_width=2.0), base_width=0.15)
    np.testing.assert_allclose(est.jitter, 0.075)
    box = np.array([[100.0, 100.0, 40.0, 100.0]])
    est.see(1, box, memory=10.0)
    est.see(3, box * [1, 1, 1.5, 1.5], memory=10.0)     # frame 2 missing: not a pair
    np.testing.assert_allclose(est.jitter, 0.075)
    est.see(4, box * [1, 1, 1.5, 1.5], memory=10.0)     # same size again: pulls it down
    assert np.all(est.jitter < 0.075)


def test_consecutive_pairs_are_mutual_best_overlaps():
    prev = np.array([[100, 100, 40, 100], [300, 100, 40, 100], [500, 300, 30, 80]], float)
    cur = np.array([[104, 101, 42, 98], [110, 100, 40, 100], [300, 400, 40, 100]], float)
    i, j = consecutive_pairs(prev, cur, 0.3)
    # prev 0's best is cur 0 (closer), and cur 0's best is prev 0; cur 1 overlaps prev 0 too
    # but is not its best; prev 1, prev 2 and cur 2 overlap nothing
    assert (i.tolist(), j.tolist()) == ([0], [0])
    assert consecutive_pairs(prev, np.zeros((0, 4)), 0.3)[0].size == 0


def test_learnt_width_is_never_narrower_than_given():
    assert learnt_width(0.15, np.array([0.02, 0.02]), 3.0) == 0.15
    assert learnt_width(0.15, np.array([0.15, 0.10]), 2.0) == pytest.approx(0.25)


def test_filter_takes_a_new_gaussian_width_but_not_a_custom_likelihoods():
    rng = np.random.default_rng(0)
    f = PHDFilter(PHDParams(), rng)
    wide = PHDParams.of(sigma_obs=0.3)
    f.set_params(wide)
    assert f.likelihood.params.sigma_obs == 0.3 and f.scene.lk.sigma_obs == 0.3

    class Custom:
        def log_g(self, states, Z, frame=None):
            return np.zeros((len(states), len(Z)))

    g = PHDFilter(PHDParams(), rng, likelihood=Custom())
    with pytest.raises(ValueError, match="likelihood"):
        g.set_params(wide)


def _scene(box_noise: float, seed: int) -> SceneConfig:
    return SceneConfig(frames=150, targets=4, clutter=2.0, persistent_clutter=0, p_detect=0.9,
                       width=320, height=240, fps=10.0, seed=seed, box_noise=box_noise)


@cache
def _run(box_noise: float, learn: float, seed: int):
    # the width learning alone: with rate.learn_motion on as well, the acceleration is read
    # off the detector's jitter while the width is still being learnt (the two learners do
    # not compose yet; docs/trackers/phd.md)
    # ... and the paper's clutter model (gate), as measured: practical's learnt clutter
    # tracks this scene without the learnt width too (MOTA 0.65 on seed 0)
    t = make_tracker("phd", seed=seed, preset="practical",
                     **{"noise.learn_width": learn, "rate.learn_motion": False,
                        "clutter_model": "gate"})
    res = run(open_source("synthetic", synthetic_config=_scene(box_noise, seed)), [t])
    assert res.outcome.status == "completed", res.outcome
    return res.scores["phd"], t.filter.params.likelihood.sigma_obs


def test_jittery_detector_is_tracked_only_with_the_learnt_width():
    """Box noise 0.15 (KITTI-13's level): with the paper's width PHD-MT confirms no track
    (MOTA 0 on every seed); with the width learnt, MOTA >= 0.4 and IDF1 >= 0.4 on every seed
    (measured 0.50-0.60 / 0.45-0.62) and the width learnt is 0.3-0.45."""
    for seed in SEEDS:
        off, _ = _run(0.15, 0.0, seed)
        on, width = _run(0.15, LEARN, seed)
        assert off["MOTA"] == pytest.approx(0.0, abs=0.02) and off["IDF1"] < 0.05, (seed, off)
        assert on["MOTA"] >= 0.4 and on["IDF1"] >= 0.4, (seed, on)
        assert 0.3 <= width <= 0.45, (seed, width)


def test_steady_detector_keeps_the_given_width():
    """Box noise 0.03 (a PETS09-like detector): the width ends at the given 0.15 and learning
    it costs at most 0.03 of the paper width's scores on every seed.  The few early frames
    learnt wider than 0.15 can move seed 0 either way (measured: −0.021 MOTA before the
    persistence score bootstrap and gap-row test were in ``practical``, +0.049 with them;
    equal on seeds 1-2), so the bound is on the loss, the property a steady detector needs."""
    for seed in SEEDS:
        off, _ = _run(0.03, 0.0, seed)
        on, width = _run(0.03, LEARN, seed)
        assert width == 0.15, (seed, width)
        assert on["MOTA"] >= off["MOTA"] - 0.03 and on["IDF1"] >= off["IDF1"] - 0.03, \
            (seed, on, off)
