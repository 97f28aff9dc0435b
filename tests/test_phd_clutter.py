"""Clutter learnt online (``clutter_model="learn"``, trackers/phd/clutter.py): the PHD mass
follows the true count on both kinds of clutter -- false detections spread at random and false
detections that repeat in place -- where each fixed model fails on one of them; and the parts
(the place memory and its β, the clutter share seen by the EM) behave as documented."""

from __future__ import annotations

import math

import _libm as libm
import numpy as np
import pytest

from pfscope.trackers.phd.clutter import BETA_FLOOR, PlaceClutter, clutter_share
from pfscope.trackers.phd.filter import ClutterParams, LikelihoodParams, log_clutter_density

SEEDS = (0, 1, 2)
DUP_SEEDS = (0, 1, 2, 3, 4, 5)
FRAMES = 120
WARMUP = 20


def _scene(kind: str, seed: int):
    """Detections-only synthetic scenes (blank frames: nothing rendered): 6 people walking,
    p_D 0.9; ``random``: 5 false boxes a frame anywhere; ``place``: 3 fixed spots firing in
    half of the frames (a real detector's false detections on a pole or a poster) + 0.5 at
    random."""
    from pfscope.trackers.data.sources import open_source
    from pfscope.trackers.data.synthetic import SceneConfig
    from pfscope.trackers.search import blank_image_source

    if kind == "random":
        cfg = SceneConfig(seed=seed, frames=FRAMES, clutter=5.0, persistent_clutter=0)
    else:
        cfg = SceneConfig(seed=seed, frames=FRAMES, clutter=0.5, persistent_clutter=3,
                          persistent_prob=0.5)
    src = open_source(None, synthetic_config=cfg)
    return blank_image_source(src) or src


def _mass_ratio(kind: str, model: str, seed: int) -> float:
    """Σ PHD mass / Σ true people over frames WARMUP+1..FRAMES (PHD-MT practical)."""
    from pfscope.trackers.api import make_tracker
    from pfscope.trackers.pipeline import BaseHook, run

    tr = make_tracker("phd", seed, preset="practical", clutter_model=model)
    mass, count = [], []

    class Hook(BaseHook):
        def on_frame(self, report):
            mass.append(tr.filter.mass)
            count.append(len(report.gt.ids))

    run(_scene(kind, seed), {"phd": tr}, frames=FRAMES, level=None, hooks=[Hook()],
        keep_rows=False, score=False)
    return float(np.sum(mass[WARMUP:]) / max(1, np.sum(count[WARMUP:])))


@pytest.fixture(scope="module")
def ratios():
    return {(kind, model): [_mass_ratio(kind, model, s) for s in SEEDS]
            for kind in ("random", "place") for model in ("learn", "gate", "scene")}


def test_mass_follows_the_count_on_random_and_on_repeated_clutter(ratios):
    """Over seeds 0-2 (measured: learn 0.88-0.91 on random clutter, 0.76-0.81 with spots that
    fire in place, 0.87-0.91 and 0.71-0.76 before the EM's priors; gate 0.73-0.84 and 0.56-0.66; scene 0.91-0.94 and 1.14-1.23)."""
    learn_r, learn_p = ratios[("random", "learn")], ratios[("place", "learn")]
    # stated tolerances, every seed: within 15 % of the count on random clutter; with spots
    # firing in place, within 30 % and never above the count (the spots do not become targets)
    assert all(0.85 <= r <= 1.15 for r in learn_r), learn_r
    assert all(0.70 <= r <= 1.0 for r in learn_p), learn_p
    # closer to the count than the paper's reading ('gate') on both kinds, seed by seed
    for kind in ("random", "place"):
        for a, b in zip(ratios[(kind, "learn")], ratios[(kind, "gate")]):
            assert abs(1 - a) < abs(1 - b), (kind, a, b)
    # a density over the image alone ('scene') turns the spots into targets
    assert all(r > 1.1 for r in ratios[("place", "scene")])


LK = LikelihoodParams()


def _place(**kw) -> PlaceClutter:
    return PlaceClutter(ClutterParams(clutter_model="learn", clutter_memory=100.0, **kw), LK)


def test_clutter_that_repeats_in_place_keeps_its_share_and_random_clutter_loses_it():
    spot = np.array([[100.0, 200.0, 40.0, 100.0]])
    rep = _place()
    for _ in range(60):                     # a spot firing on every frame, never explained
        log_r = rep.log_kappa(spot)
        rep.learn(spot, np.ones(1), np.ones(1) * (np.exp(log_r) > 0), 1 / 20)
    assert rep.beta > 0.5
    # the spot's own rate has reached the gate model's one clutter point around it
    gate = log_clutter_density(spot, ClutterParams(clutter_rate=1.0), LK)
    assert rep.place_rate(spot)[0] > 0.9
    assert rep.log_kappa(spot)[0] == pytest.approx(gate[0] + np.log(rep.place_rate(spot)[0]))

    rng = np.random.default_rng(0)
    rnd = _place()
    for _ in range(200):                    # 5 false boxes a frame anywhere in 640 x 480
        w = rng.uniform(24, 48, 5)
        Z = np.c_[rng.uniform(0, 640, 5), rng.uniform(0, 480, 5), w, w * rng.uniform(2, 3, 5)]
        log_r = rnd.log_kappa(Z)
        # the EM's share of each detection given to the place part: κ_r / (κ_u + κ_r) with
        # the uniform density's κ_u
        log_u = np.log(5 / (640 * 480)) + np.full(5, np.log(1 / (24 * 72)))
        rnd.learn(Z, np.ones(5), np.exp(log_r - np.logaddexp(log_u, log_r)), 1 / 20)
    assert rnd.beta < 0.1
    assert rnd.beta >= BETA_FLOOR
    assert len(rnd.mem_w) < 5 * 200             # faded entries are dropped


def test_clutter_share_reads_the_shadow_model_from_the_update():
    won = np.array([0.0, 0.3, 0.8, 1.0])
    log_k = np.log(np.array([1e-6, 2e-6, 5e-7, 1e-6]))
    # same κ in the update and in the shadow model: the clutter share is 1 - won
    assert clutter_share(won, log_k, log_k) == pytest.approx(1 - won)
    # a smaller shadow κ (the gate part taken out) gives the targets more of each detection
    less = clutter_share(won, log_k, log_k - np.log(4))
    assert np.all(less[1:3] < (1 - won)[1:3]) and less[0] == 1.0 and less[3] == 0.0
    c = won[1:3] / (1 - won[1:3]) * np.exp(log_k[1:3])          # C(z) of the update
    assert less[1:3] == pytest.approx(np.exp(log_k[1:3]) / 4 / (np.exp(log_k[1:3]) / 4 + c))


# ----------------------------------------------------------------------------- the EM's priors

def _near(**kw) -> "NearClutter":
    from pfscope.trackers.phd.clutter import NearClutter

    return NearClutter(ClutterParams(clutter_model="learn", clutter_memory=100.0, **kw), LK)


def test_near_rate_stays_at_its_prior_while_no_target_has_formed():
    """ν (false boxes per target per frame) divides the near shares by the predicted mass: with
    ~0 mass (no target formed yet, each detection of a person next to the little mass the last
    one left) its EM ran to the clip 1.  With the Gamma prior it stays near the prior unless
    the evidence outweighs it, and it still learns ν where targets exist."""
    from pfscope.trackers.phd.clutter import NEAR_PRIOR, PRIOR_FRAMES

    nc = _near()
    for t in range(300):                     # mass 0.001 a frame, near shares 0.01 a frame
        nc._exposure = 0.001
        nc.learn(np.array([0.01]), 1.0 / min(t + 5, 100))
    # the evidence alone reads 10 (→ the clip 1); prior and evidence together
    # (0.01 + n0 a ν0) / (0.001 + n0 a) with a = 1/100, n0 = 5: ~0.2
    assert nc.nu < 0.3, nc.nu
    a = 1 / 100
    assert nc.nu == pytest.approx((0.01 + PRIOR_FRAMES * a * NEAR_PRIOR)
                                  / (0.001 + PRIOR_FRAMES * a), rel=0.05)

    learnt = _near()
    rng = np.random.default_rng(0)
    for t in range(300):                     # 4 targets, 0.2 false boxes next to each a frame
        learnt._exposure = 4.0
        learnt.learn(np.full(rng.poisson(0.8), 1.0), 1.0 / min(t + 5, 100))
    assert 0.12 <= learnt.nu <= 0.3, learnt.nu

    empty = _near()
    for t in range(50):                      # nothing at all: the prior
        empty._exposure = 0.0
        empty.learn(np.zeros(0), 1.0 / min(t + 5, 100))
    assert empty.nu == pytest.approx(NEAR_PRIOR)


def test_place_rate_climbs_where_a_spot_keeps_firing_and_sinks_where_it_stops():
    """A place's own clutter rate (posterior mean under the prior β): a spot firing on every
    frame, never explained, reaches the ``gate`` model there (rate → 1); a place where clutter
    fell a few times sinks below β's prior share once quiet; no memory, no κ_r."""
    from pfscope.trackers.phd.clutter import PRIOR_FRAMES

    spot = np.array([[100.0, 200.0, 40.0, 100.0]])
    other = np.array([[400.0, 300.0, 40.0, 100.0]])
    rep = _place(repeat_prior=0.05)          # β small: most places do not fire again
    assert rep.place_rate(spot)[0] == 0.0
    rates = []
    for t in range(40):
        Z = np.vstack([spot, other]) if t < 3 else spot      # `other` fires 3 times, stops
        rep.learn(Z, np.ones(len(Z)), np.zeros(len(Z)), 1.0 / min(t + 5, 100))
        rates.append(rep.place_rate(spot)[0])
    # the evidence a place can hold is the memory's 1 / (1 - δ) frames (10 here): a spot that
    # fired on all of them is at (10 + n0 β) / (10 + n0) ~ 0.67, from (1 + n0 β) / (1 + n0)
    full = 1.0 / (1.0 - rep.fade)
    assert rates[0] < 0.3, rates
    assert rates[-1] == pytest.approx((full + PRIOR_FRAMES * rep.beta) / (full + PRIOR_FRAMES),
                                      rel=0.02), rates
    assert rates[-1] > 0.6
    assert np.all(np.diff(rates) > -1e-9)                    # climbs monotonically
    assert rep.place_rate(other)[0] < 0.25
    assert rep.log_kappa(spot)[0] == pytest.approx(
        log_clutter_density(spot, ClutterParams(clutter_rate=1.0), LK)[0]
        + np.log(rep.place_rate(spot)[0]))


def _learnt(kind: str, seed: int) -> dict:
    """PHD-MT practical (``clutter_model='learn'``) on the synthetic scene: per-frame averages
    after WARMUP of the learnt random rate λ_u and the structured counts (repeated in place,
    near people), and the largest ν of the first WARMUP frames (before tracks form)."""
    from pfscope.trackers.api import make_tracker
    from pfscope.trackers.pipeline import BaseHook, run

    tr = make_tracker("phd", seed, preset="practical", clutter_model="learn")
    rec = []

    class Hook(BaseHook):
        def on_frame(self, report):
            sc = tr.filter.scene
            rec.append((sc.rate, sc.place.count(), sc.people.count(), sc.people.nu))

    run(_scene(kind, seed), {"phd": tr}, frames=FRAMES, level=None, hooks=[Hook()],
        keep_rows=False, score=False)
    r = np.array(rec)
    late = r[WARMUP:].mean(0)
    return {"random": late[0], "place": late[1], "near": late[2],
            "total": late[0] + late[1] + late[2], "nu_early": r[:WARMUP, 3].max()}


@pytest.fixture(scope="module")
def learnt():
    return {kind: [_learnt(kind, s) for s in SEEDS] for kind in ("random", "place")}


def test_learnt_clutter_rate_follows_the_true_false_detection_rate(learnt):
    """The learnt clutter per frame (λ_u + repeated in place + near people) follows the true
    false-detection rate on both kinds, and the EM splits it the right way, seeds 0-2
    (measured: random, 5 a frame: total 4.8-5.1, λ_u 3.8-4.2; place, 1.5 a frame repeated at 3
    spots + 0.5 at random: total 1.9-2.1, λ_u 0.55-0.69, in place 1.15-1.36).  Before the
    priors, λ_u ran to ~0.02 a frame on PETS09-S2L1's 0.8 unchained false detections."""
    for r in learnt["random"]:
        assert 0.8 * 5.0 <= r["total"] <= 1.2 * 5.0, r
        assert r["random"] >= 0.7 * r["total"], r           # mostly read as random
    for r in learnt["place"]:
        assert 0.8 * 2.0 <= r["total"] <= 1.2 * 2.0, r
        assert 0.25 <= r["random"] <= 1.0, r                # the 0.5 a frame at random
        assert r["place"] >= 0.5 * r["total"], r            # the spots' 1.5 in place


def test_near_rate_does_not_collapse_to_its_clip_before_tracks_form(learnt):
    """In the first WARMUP frames (no target confirmed, little mass) ν stays at its prior
    (measured 0.010 on every seed; without the prior it started at, and was pinned to, 1)."""
    from pfscope.trackers.phd.clutter import NEAR_PRIOR

    for kind in ("random", "place"):
        for r in learnt[kind]:
            assert r["nu_early"] <= 5 * NEAR_PRIOR, (kind, r)


# ------------------------------------------------------------------ second boxes on one person

DUP_FRAMES = 100


def _duplicate_folder(root, seed: int):
    """A detections-only MOT folder (no frames): 4 people walking, p_D 0.9, no clutter but a
    second box on a detected person in half of the frames, as ACF puts on pedestrians: shifted
    by a quarter of the width and 10 % taller, a lower score."""
    from pfscope.trackers.data.synthetic import SceneConfig, SyntheticScene

    sc = SyntheticScene(SceneConfig(seed=seed, frames=DUP_FRAMES, targets=4, clutter=0.0,
                                    persistent_clutter=0))
    rng = np.random.default_rng(seed)
    folder = root / f"dup{seed}"
    for sub in ("det", "gt"):
        (folder / sub).mkdir(parents=True)
    cfg = sc.config
    (folder / "seqinfo.ini").write_text(
        f"[Sequence]\nname=dup{seed}\nimDir=img1\nframeRate={cfg.fps:g}\nseqLength={cfg.frames}\n"
        f"imWidth={cfg.width}\nimHeight={cfg.height}\nimExt=.jpg\n")
    rows = []
    for f, b, s in zip(np.asarray(sc.det.frame), np.asarray(sc.det.boxes),
                       np.asarray(sc.det.score)):
        rows.append((f, *b, s))
        if rng.random() < 0.5:
            x, y, w, h = b
            rows.append((f, x + rng.choice([-0.25, 0.25]) * w, y - 0.1 * h, w, 1.1 * h, 0.8 * s))
    (folder / "det" / "det.txt").write_text("".join(
        f"{int(f)},-1,{x:.3f},{y:.3f},{w:.3f},{h:.3f},{s:.4f},-1,-1,-1\n"
        for f, x, y, w, h, s in rows))
    (folder / "gt" / "gt.txt").write_text("".join(
        f"{int(f)},{int(i)},{x:.3f},{y:.3f},{w:.3f},{h:.3f},1,1,1\n"
        for f, i, (x, y, w, h) in zip(np.asarray(sc.gt.frame), np.asarray(sc.gt.id),
                                      np.asarray(sc.gt.boxes))))
    return folder


def _dup_scores(folder, seed: int, **options) -> dict:
    from pfscope.trackers.api import make_tracker
    from pfscope.trackers.data.sources import open_source
    from pfscope.trackers.pipeline import run

    # the duplicate term alone, as measured (the docstring's numbers): spot_places (on in
    # practical) also changes which boxes build a place memory; under it the term takes seed
    # 0's FP / GT from 0.32 to 0.22 and seeds 1-2 from 0.11 / 0.25 to 0.05 / 0.04
    tr = make_tracker("phd", seed, preset="practical", clutter_model="learn",
                      learn_update="model", spot_places=False, repeat_memory=0.1, **options)
    return run(open_source(folder), {"phd": tr}).scores["phd"]


def test_a_second_box_on_one_person_stays_one_track(tmp_path):
    """learn_update='model': a detector that boxes a detected person twice in half of the
    frames (no other clutter) gives about one track per person (DuplicateBoxes); with the
    duplicate term off (duplicate_prior 0) the second boxes become second tracks.  Six seeds
    (three were too few: one seed's share of the effect swings with the draws), measured
    FP / GT with the term / without: 0.19/0.30, 0.06/0.17, 0.08/0.28, 0.11/0.19, 0.08/0.22,
    0.03/0.08 (summed 0.45 of without; 0.34 with the generator before Box-Muller); IDF1
    0.65/0.54, 0.88/0.55, 0.76/0.61, 0.60/0.55, 0.78/0.76, 0.58/0.62 (mean gain 0.10)."""
    on, off = [], []
    for seed in DUP_SEEDS:
        folder = _duplicate_folder(tmp_path, seed)
        on.append(_dup_scores(folder, seed))
        off.append(_dup_scores(folder, seed, duplicate_prior=0.0))
    fp_on = [s["FP"] / s["GT"] for s in on]
    fp_off = [s["FP"] / s["GT"] for s in off]
    id_on, id_off = [s["IDF1"] for s in on], [s["IDF1"] for s in off]
    # stated tolerances: over the seeds at most 0.6 x the false positives without the term,
    # and at most 15 % of the ground truth on average; IDF1 higher on all seeds but one, by
    # >= 0.05 on average
    assert sum(fp_on) <= 0.6 * sum(fp_off), (fp_on, fp_off)
    assert np.mean(fp_on) <= 0.15, fp_on
    assert sum(a > b for a, b in zip(id_on, id_off)) >= len(DUP_SEEDS) - 1, (id_on, id_off)
    assert np.mean(id_on) >= np.mean(id_off) + 0.05, (id_on, id_off)


def test_duplicate_rate_learns_whether_a_pair_is_one_person():
    """DuplicateBoxes (unit): a pair of boxes gets κ_d = q · 1 / V on both, a box alone none;
    q climbs (towards 1, held back by its prior) when a tracked box's neighbour stays unexplained (won 1 next to won 0),
    and sinks to its floor when both are tracked (two people side by side)."""
    from pfscope.trackers.phd.clutter import DuplicateBoxes

    cl = ClutterParams(clutter_model="learn", learn_update="model")
    Z = np.array([[100.0, 200.0, 40.0, 100.0], [100.0, 205.0, 44.0, 105.0],
                  [400.0, 300.0, 40.0, 100.0]])
    one = log_clutter_density(Z, cl, LK)             # one clutter point around each box
    # the held prior (5 frames of evidence at 0.5 against 1 paired box a frame) keeps q at
    # (1 + 0.25 · 0.5) / 1.25 = 0.9 with every neighbour unexplained, 0.1 with none
    for won, goal in (([1.0, 0.0, 1.0], lambda q: q > 0.85), ([1.0, 1.0, 1.0],
                                                               lambda q: q < 0.15)):
        d = DuplicateBoxes(cl, LK)
        assert d.q == cl.duplicate_prior
        for _ in range(200):
            lk = d.log_kappa(Z)
            d.learn(np.array(won), 0.05)
        assert goal(d.q), (won, d.q)
        lk = d.log_kappa(Z)
        assert np.isneginf(lk[2])
        np.testing.assert_allclose(lk[:2], np.log(d.q) + one[:2])
    off = DuplicateBoxes(ClutterParams(clutter_model="learn", duplicate_prior=0.0), LK)
    assert np.isneginf(off.log_kappa(Z)).all()


def _scene_fp(seed: int, **options) -> dict:
    """PHD-MT practical under learn + model on the built-in scene (``pfscope record``'s default:
    two persistent clutter spots firing on and off besides random clutter)."""
    from pfscope.trackers.api import make_params, tracker_info
    from pfscope.trackers.data.sources import open_source as open_src
    from pfscope.trackers.data.synthetic import demo_config
    from pfscope.trackers.pipeline import run

    sets = {"clutter_model": "learn", "learn_update": "model", **options}
    src = open_src(None, synthetic_config=demo_config(seed=seed))
    trk = tracker_info("phd").cls(make_params("phd", None, sets), rng=np.random.default_rng(seed))
    return run(src, {"phd": trk}).scores["phd"]


def test_a_spot_that_fires_on_and_off_does_not_become_a_track():
    """``spot_places``: the place memory counts a chained detection by the probability that its
    chain is clutter and the newborn weigh against κ without it, so the scene's persistent
    spots stay clutter.  Seeds 0-2, learn + model, repeat_memory 0.3; measured FP on 43/24/4
    vs off 74/73/100, MOTA 0.815/0.839/0.895 vs 0.744/0.722/0.664 (the first version, which
    counted only unchained detections: FP 21/64/4, MOTA 0.867/0.743/0.895).  Asserts FP on <=
    off on every seed, summed FP on <= 0.6x off (measured 0.29) and mean MOTA + 0.05
    (measured +0.140)."""
    on = [_scene_fp(s, spot_places=True, repeat_memory=0.3) for s in (0, 1, 2)]
    off = [_scene_fp(s, spot_places=False, repeat_memory=0.3) for s in (0, 1, 2)]
    for a, b in zip(on, off):
        assert a["FP"] <= b["FP"], (a["FP"], b["FP"])
    assert sum(a["FP"] for a in on) <= 0.6 * sum(b["FP"] for b in off)
    assert np.mean([a["MOTA"] for a in on]) >= np.mean([b["MOTA"] for b in off]) + 0.05


def _random_parts(rng, n):
    """Random inputs of the learnt clutter's terms: -inf, 0, 1, ties and NaN among them."""
    log_v = rng.normal(8.0, 2.0, n)
    S = np.where(rng.random(n) < 0.4, 0.0, rng.exponential(0.5, n))
    E = rng.uniform(0.0, 30.0, n)
    m = np.where(rng.random(n) < 0.3, 0.0, rng.exponential(0.8, n))
    chained = rng.random(n) < 0.4
    cnt = rng.integers(0, 3, n)
    log_u = np.where(rng.random(n) < 0.1, -np.inf, rng.normal(-12.0, 2.0, n))
    won = np.clip(rng.uniform(-0.1, 1.1, n), -0.05, 1.05)
    won[rng.random(n) < 0.1] = 1.0
    won[rng.random(n) < 0.1] = 0.0
    return log_v, S, E, m, chained, cnt, log_u, won


@pytest.mark.parametrize("seed", range(3))
def test_kappa_terms_and_learn_shares_are_the_numpy_form_bit_for_bit(seed):
    """The learnt clutter's terms and the EM's split (one numba pass each) give the floats of
    their numpy form (kept here: the mixture before the kernels), NaN and -inf included; the
    place memory's update too, its S(z) kept along the memory equal to the grid pass's up to
    round-off."""
    from pfscope.trackers.phd.clutter import (PRIOR_FRAMES, _memory_step, kappa_terms,
                                              learn_shares)
    from pfscope.trackers.phd.gating import gate_sums

    rng = np.random.default_rng(seed)
    for _ in range(200):
        n = int(rng.integers(0, 25))
        log_v, S, E, m, chained, cnt, log_u, won = _random_parts(rng, n)
        beta, nu, q = rng.uniform(0.01, 1, 3)
        near = float(rng.choice([0.0, rng.uniform(0.01, 2)]))
        with np.errstate(all="ignore"):
            r = (S + PRIOR_FRAMES * beta) / (E + PRIOR_FRAMES)
            rep = libm.log(np.where(S > 0, np.minimum(r, 1.0), 0.0)) + -log_v
            nr = np.where(chained, -np.inf, libm.log(nu * np.minimum(m, 1.0)) + -log_v)
            dup = libm.log(q * cnt) + -log_v
            u = np.logaddexp(log_u, math.log(near) - log_v) if near > 0 else log_u
            shadow = np.logaddexp(np.logaddexp(np.logaddexp(u, rep), nr), dup)
            birth = np.logaddexp(np.logaddexp(u, nr), dup)
        out = kappa_terms(log_v, (S, E, beta), (m, nu, chained), (cnt, q), u)
        for a, b in zip(out, (rep, nr, dup, shadow, birth)):
            assert np.array_equal(a, b, equal_nan=True)
        # the EM's split of the clutter shares (SceneModel.learn's numpy form)
        link = rng.integers(-1, 6, n)
        prior = rng.uniform(0, 1, int(rng.integers(1, 6)))
        with np.errstate(all="ignore"):
            w = np.clip(won, 0.0, 1.0)
            sh = 1.0 / (1.0 + libm.exp(libm.log(w) - libm.log1p(-w) + shadow - shadow))
            sh = np.where(np.isfinite(sh), sh, np.where(w >= 1.0, 0.0, 1.0))
            fr = [libm.exp(x - shadow) for x in (rep, nr, dup)]
        fr = [np.where(np.isnan(x), 0.0, x) for x in fr]
        chain = np.ones(n)
        ok = (link >= 0) & (link < len(prior))
        chain[ok] = prior[link[ok]]
        sums = np.empty(3)
        got, random = learn_shares(won, shadow, shadow, (rep, nr, dup), link, prior, sums)
        want = (sh, sh * (1.0 - fr[1] - fr[2]) * chain, sh * fr[0] * chain, sh * fr[1],
                chain * (1.0 - won))
        for a, b in zip(got, want):
            assert np.array_equal(a, b, equal_nan=True)
        assert random == float(np.sum(sh * (1.0 - fr[0] - fr[1] - fr[2]))) == sums[0]
        # the repeated and near shares' sums (PlaceClutter / NearClutter.learn): np.sum's
        # floats, its 0.0 for -0.0s included
        for k, x in ((1, want[2]), (2, want[3])):
            assert np.float64(sums[k]).tobytes() == np.sum(x).tobytes(), (k, sums[k], x)
        neg = learn_shares(np.ones(12), np.zeros(12), np.zeros(12), (np.zeros(12),) * 3,
                           np.zeros(12, np.int64), -np.ones(3), sums)[0]
        assert np.signbit(neg[2]).all() and not np.signbit(sums[1])   # -0.0s: 0.0
        assert np.float64(sums[1]).tobytes() == np.sum(neg[2]).tobytes()
        # the place memory's update, its S(z) kept along (faded, minus the dropped, plus the
        # new) against the whole grid pass over the memory after it
        k = int(rng.integers(0, 40))
        mz, mw, me = rng.normal(size=(k, 4)), rng.exponential(0.01, k), rng.uniform(1, 9, k)
        ms = rng.uniform(0.3, 2, (k, 4))
        Z, Zs = rng.normal(size=(n, 4)), rng.uniform(0.3, 2, (n, 4))
        mS = gate_sums(mz, mz, 9.0, ms, mw)[0]
        z, sv, wv, e, S, exposure, ok = _memory_step(mz, ms, mw, me, mS, Z, Zs, sh, 0.97, 1e-3,
                                                     9.0, 1 << 20)
        w2 = np.concatenate([mw * 0.97, sh])
        keep = w2 >= 1e-3
        assert np.array_equal(wv, w2[keep]) and np.array_equal(z, np.vstack([mz, Z])[keep])
        assert np.array_equal(sv, np.vstack([ms, Zs])[keep])
        assert np.array_equal(e, np.concatenate([me * 0.97 + 1.0, np.ones(n)])[keep])
        want = gate_sums(z, z, 9.0, sv, wv)[0]
        assert ok and np.allclose(S, want, rtol=1e-12, atol=1e-15)
        assert exposure == pytest.approx(np.sum(wv / np.maximum(want, 1.0)), rel=1e-12)
        # over the budget: the caller's grid pass instead
        if (sh >= 1e-3).any():
            assert not _memory_step(mz, ms, mw, me, mS, Z, Zs, sh, 0.97, 1e-3, 9.0, 0)[6]


def test_neighbour_counts_at_two_widths_are_the_gate_sums_counts():
    """neighbour_counts (one pass for both widths below BRUTE_PAIRS pairs, two grid-indexed
    gate_sums above) counts what neighbours counts at scale 1 and NEAR_SCALE, people close
    together, apart and on one another."""
    from pfscope.trackers.phd.clutter import NEAR_SCALE, neighbour_counts, neighbours
    from pfscope.trackers.phd.filter import OBS_DIM, gate_threshold, obs_std

    cl, lk = ClutterParams(clutter_model="learn"), LikelihoodParams()
    rng = np.random.default_rng(0)
    wider = 0
    for n in (2, 3, 9, 40, 63, 64, 90):
        for _ in range(20):
            xy = rng.uniform(0, rng.choice([60.0, 300.0]), (n, 2))
            wh = rng.uniform(20, 40, (n, 1)) * [1.0, 2.5]
            Z = np.column_stack([xy, wh])
            Z[n // 2:] = Z[: n - n // 2] + rng.normal(0, 2, (n - n // 2, 4))  # second boxes
            std = obs_std(Z[:, 2:4], lk)
            a, b = neighbour_counts(Z, gate_threshold(cl.clutter_gate, OBS_DIM), std,
                                    std * NEAR_SCALE)
            assert np.array_equal(a, neighbours(Z, cl, lk))
            assert np.array_equal(b, neighbours(Z, cl, lk, NEAR_SCALE))
            assert b.sum() >= a.sum() > 0
            wider += b.sum() > a.sum()
    assert wider > 70             # of the 140 sets, most have more pairs at the wider gate


@pytest.mark.parametrize("seed", range(3))
def test_scene_density_and_score_sums_are_their_numpy_form(seed):
    """The scene density's one pass (extent, log-size moments, log κ_u with the 2 × 2 inverse
    and determinant in closed form, log V) and the score fit's sums give their numpy / LAPACK
    form's values (kept here) up to round-off."""
    from pfscope.trackers.phd.clutter import scene_density
    from pfscope.trackers.phd.filter import _score_sums, log_gate_volume, log_gate_volume0, obs_std

    rng = np.random.default_rng(seed)
    cl, lk = ClutterParams(clutter_model="learn"), LikelihoodParams()
    m1, m2 = np.zeros(2), np.zeros((2, 2))
    extent = np.array([np.inf, np.inf, -np.inf, -np.inf])
    o1, o2, ext = np.zeros(2), np.zeros((2, 2)), None
    sums = np.array([[2.0, 1.0, 3.0], [2.0, 0.5, 1.0]])
    psums = sums + 1.0
    for frame in range(60):
        n = int(rng.integers(0, 30))
        Z = np.column_stack([rng.uniform(-50, 700, (n, 2)),
                             rng.lognormal(3.5, 0.4, (n, 1)) * [1.0, 2.4]])
        std = obs_std(Z[:, 2:4], lk)
        a = 1.0 / min(frame + 1, 30)
        area = float(rng.choice([0.0, 640.0 * 480.0]))
        got_u, got_v = scene_density(Z, std, m1, m2, extent, a, n > 0, math.log(3.0), area,
                                     log_gate_volume0(cl), 0.05 ** 2)
        ls = np.log(Z[:, 2:4])
        if n:                                       # SceneModel._see_sizes before the kernel
            box = np.concatenate([(Z[:, :2] - Z[:, 2:4] / 2).min(0),
                                  (Z[:, :2] + Z[:, 2:4] / 2).max(0)])
            ext = box if ext is None else np.concatenate(
                [np.minimum(ext[:2], box[:2]), np.maximum(ext[2:], box[2:])])
            o1 = (1 - a) * o1 + a * ls.mean(0)
            o2 = (1 - a) * o2 + a * (ls.T @ ls) / n
        cov = o2 - np.outer(o1, o1)
        cov = 0.5 * (cov + cov.T) + 0.05 ** 2 * np.eye(2)
        d = ls - o1
        want = (-0.5 * np.einsum("ij,ij->i", d, np.linalg.solve(cov, d.T).T)
                - math.log(2 * math.pi) - 0.5 * math.log(np.linalg.det(cov)) - ls.sum(1))
        if area <= 0:
            area = 1.0 if ext is None else \
                max(ext[2] - ext[0], 1.0) * max(ext[3] - ext[1], 1.0)
        want = math.log(3.0) - math.log(area) + want
        assert np.allclose(m1, o1, rtol=1e-12) and np.allclose(m2, o2, rtol=1e-12)
        if ext is not None:
            assert np.array_equal(extent, ext)
        assert np.allclose(got_u, want, rtol=1e-9, atol=1e-9)
        assert np.allclose(got_v, log_gate_volume(Z, cl, lk, std), rtol=1e-13)
        # near_rate points spread as the 'gate' model join κ_u (np.logaddexp's floats)
        near = float(rng.uniform(0.01, 2))
        u2, v2 = scene_density(Z, std, m1, m2, extent, a, False, math.log(3.0), area,
                               log_gate_volume0(cl), 0.05 ** 2, near)
        assert np.array_equal(v2, got_v)
        assert np.array_equal(u2, np.logaddexp(got_u, math.log(near) - got_v))
        # the score sums: per class (won, 1 - won) and labelled by persistence
        s, won, persist = rng.normal(size=n), rng.uniform(0, 1, n), rng.random(n) < 0.5
        r, q = np.stack([won, 1 - won]), np.stack([persist, ~persist]).astype(float)
        want_s = 0.9 * sums + np.column_stack([r.sum(1), r @ s, r @ (s * s)])
        want_p = 0.9 * psums + np.column_stack([q.sum(1), q @ s, q @ (s * s)])
        _score_sums(won, s, persist, True, 0.9, sums, psums)
        assert np.allclose(sums, want_s, rtol=1e-12) and np.allclose(psums, want_p, rtol=1e-12)


def test_in_gate_early_out_is_the_full_test():
    """The place memory's pair test with its early out on the first coordinate
    (:func:`_in_gate_early`) answers as the full test (:func:`_in_gate`) on every pair: random
    ones, pairs within a few ulps of the gate's edge along the first axis (where the bound's
    margin must hold), and NaN, infinite and zero coordinates or stds."""
    from pfscope.trackers.phd.clutter import GATE_MARGIN, _in_gate, _in_gate_early

    rng = np.random.default_rng(7)
    r2 = 13.276704135987622
    R = math.sqrt(r2) * (1.0 + GATE_MARGIN)
    rows = [rng.normal(0, 4, 4) for _ in range(300)]
    for s in (0.3, 1.0, 7.5, 1e-3, 1e6):
        edge = s * math.sqrt(r2)
        for k in range(-6, 7):
            for x in (edge, np.nextafter(edge, 0.0), np.nextafter(edge, np.inf)):
                rows.append(np.array([x * (1 + k * 2.0 ** -52), 0.0, 0.0, 0.0]))
                rows.append(np.array([-x * (1 + k * 2.0 ** -52), 1e-9, 0.0, -1e-9]))
    rows += [np.array(v) for v in ([np.nan, 0, 0, 0], [0, np.nan, 0, 0], [np.inf, 0, 0, 0],
                                   [100.0, np.nan, 0, 0], [0, 0, 0, np.inf], [0, 0, 0, 0])]
    P = np.array(rows)
    stds = [np.full(4, s) for s in (0.3, 1.0, 7.5, 1e-3, 1e6)] + [
        rng.uniform(0.2, 3, 4), np.array([0.0, 1.0, 1.0, 1.0]), np.array([np.nan, 1, 1, 1]),
        np.array([np.inf, 1, 1, 1]), np.array([1.0, 0.0, 1.0, 1.0])]
    Z = np.zeros((1, 4))
    hits = 0
    for s in stds:
        std = s.reshape(1, 4)
        for q in range(len(P)):
            want = _in_gate(P, q, Z, 0, std, r2)
            assert _in_gate_early(P, q, Z, 0, std, r2, R) == want, (P[q], s)
            hits += want
    assert 0 < hits < len(P) * len(stds)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_duplicate_learn_brute_pass_is_the_grid_pass(seed, monkeypatch):
    """DuplicateBoxes.learn on few detections (one kernel call testing every pair) learns the
    very q / sums of the gate_sums pass it stands for (forced here by a zero brute bound):
    people side by side, second boxes, detections far apart, won on both sides of ½ and
    outside [0, 1]."""
    from pfscope.trackers.phd import clutter as C
    from pfscope.trackers.phd.filter import obs_std

    cl = ClutterParams(clutter_model="learn")
    runs = {}
    for brute in (True, False):
        if not brute:
            monkeypatch.setattr(C, "BRUTE_PAIRS", 0)
        r = np.random.default_rng(seed)
        d = C.DuplicateBoxes(cl, LK)
        qs = []
        for _ in range(30):
            n = int(r.integers(2, 20))
            base = r.uniform(0, 300, (n, 2))
            Z = np.c_[base, r.uniform(20, 40, (n, 1)), r.uniform(50, 90, (n, 1))]
            pairs = r.random(n) < 0.4
            Z[pairs, :2] = Z[np.roll(np.arange(n), 1)[pairs], :2] \
                + r.normal(0, 3, (int(pairs.sum()), 2))
            std = obs_std(Z[:, 2:4], LK) * C.NEAR_SCALE
            d.counts(Z, std)
            won = r.uniform(-0.1, 1.1, n)
            d.learn(won, 0.05)
            qs.append((d.q, d.num, d.den))
        runs[brute] = qs
    assert runs[True] == runs[False]
    assert len({q for q, _, _ in runs[True]}) > 10


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_scene_terms_is_the_three_calls_bit_for_bit(seed):
    """scene_terms (the scene density, the place memory's gate sums and kappa_terms in one
    call): the very floats and in-place updates of scene_density, gate_sums and kappa_terms
    -- with and without a memory, the near and duplicate parts, and where gate_sums' one-pass
    grid declines (a memory spread too sparsely: its GridIndex path)."""
    from pfscope.trackers.phd.clutter import kappa_terms, scene_density, scene_terms
    from pfscope.trackers.phd.filter import _no_extent
    from pfscope.trackers.phd.gating import gate_sums

    rng = np.random.default_rng(seed)
    for t in range(40):
        nz, k = int(rng.integers(0, 12)), int(rng.integers(0, 300)) * (t % 5 != 0)
        Z = np.column_stack([rng.uniform(0, 600, (nz, 2)), rng.uniform(10, 80, (nz, 2))])
        std = rng.uniform(1, 12, (nz, 4))
        mz = np.column_stack([rng.uniform(0, 600, (k, 2)), rng.uniform(10, 80, (k, 2))])
        if t % 4 == 3 and k:
            mz[0, :2] = 1e9                      # a sparse grid: gate_sums' GridIndex path
        mw, me = rng.exponential(0.05, k), rng.uniform(1, 20, k)
        m1 = rng.normal(3, 0.2, 2)
        m2 = np.outer(m1, m1) + [[0.04, 0.01], [0.01, 0.05]]
        ext = _no_extent() if t % 2 else np.array([0.0, 0.0, 500.0, 400.0])
        args = [Z, std, m1, m2, ext, 0.1, nz > 0, -1.5, 640.0 * 480 * (t % 3 == 0),
                -2.0, 0.0025, 0.3 * (t % 2)]
        near = (rng.uniform(0, 2, nz), 0.2, rng.random(nz) < 0.5) if t % 3 else None
        dup = (rng.integers(0, 3, nz), 0.7) if t % 2 else None
        want_args = [x.copy() if isinstance(x, np.ndarray) else x for x in args]
        log_u, log_v = scene_density(*want_args)
        S, E, _ = gate_sums(mz, Z, 13.28, std, mw, me)
        want = kappa_terms(log_v, place=(S, E, 0.4), near=near, dup=dup, log_u=log_u)
        got = scene_terms(tuple(args), mz, mw, me, 13.28, 0.4, near, dup)
        assert np.isfinite(log_u).all() and np.array_equal(got[0], log_u)
        assert np.array_equal(got[1], log_v)
        assert np.array_equal(got[2:], want, equal_nan=True), t
        for a, b in zip(args[2:5], want_args[2:5]):
            assert np.array_equal(a, b)


def _scene_state(f):
    """Everything the scene model carries from frame to frame (and the filter's particles)."""
    sc = f.scene
    pl, pe, du = sc.place, sc.people, sc.dups
    arrays = [f.particles.states, f.particles.log_weights, sc.size_m1, sc.size_m2, sc.extent,
              sc.score_sums, sc.persist_sums, sc._chain_clutter, pl.mem_z, pl.mem_s, pl.mem_w,
              pl.mem_e, sc._persist]
    if pl._sums is not None:
        arrays += [pl._sums[2], np.array([pl._sums[3]])]
    floats = [sc.rate, sc.near, sc.frames, sc.size_frames, sc.score_floor, pl.beta, pl.num,
              pl.den, pl._a, pl.frames, pe.nu, pe.num, pe.den, pe._a, pe._exposure, du.q,
              du.num, du.den]
    return [None if a is None else (np.asarray(a).dtype.str, np.asarray(a).shape,
                                    np.asarray(a).tobytes()) for a in arrays], floats


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fused_scene_model_is_the_calls_one_by_one(seed, monkeypatch):
    """The practical settings' SceneModel.log_kappa and learn in one kernel call each
    (``SceneModel.fused``: :func:`.clutter.scene_frame`, :func:`.filter.scene_learn`) give the
    very floats and state of the calls one by one (the reference), frame after frame: people
    walking, second boxes beside some, a spot firing on and off, random clutter, scores, a
    far box (the memory's one-pass grid declines after it: the caller finishes), unequal
    particle weights once (equal ones pass as their one value), a frame of
    one detection (no duplicate term) and an empty one (the reference path there); and the
    fused path was taken."""
    import pfscope.trackers.phd.filter as F
    from pfscope.trackers.phd.tracker import PHD_PRACTICAL
    from pfscope.trackers.smc.weights import ParticleSet
    from pfscope.trackers.types import Detections

    calls = {"frame": 0, "learn": 0}
    frame_k, learn_k = F.scene_frame, F.scene_learn

    def count_frame(*a):
        calls["frame"] += 1
        return frame_k(*a)

    def count_learn(*a):
        calls["learn"] += 1
        return learn_k(*a)

    monkeypatch.setattr(F, "scene_frame", count_frame)
    monkeypatch.setattr(F, "scene_learn", count_learn)
    declined = []
    sums_k = F.gate_sums

    def count_sums(*a, **kw):
        declined.append(1)
        return sums_k(*a, **kw)

    monkeypatch.setattr(F, "gate_sums", count_sums)
    weights = []
    weights_of = F._weights_exposure

    def spy_weights(ps, *buf):
        w, e = weights_of(ps, *buf)
        weights.append(len(w) == len(ps))
        assert (e is None) == (len(w) == len(ps))      # the exposure with the one value
        return w, e

    monkeypatch.setattr(F, "_weights_exposure", spy_weights)
    p = PHD_PRACTICAL.filter
    fused = F.PHDFilter(p, rng=np.random.default_rng(seed))
    ref = F.PHDFilter(p, rng=np.random.default_rng(seed))
    ref.scene.fused = False
    rng = np.random.default_rng(100 + seed)
    frames = 40
    for k in range(frames):
        x = np.linspace(60, 560, 6) + 4.0 * k
        boxes = np.column_stack([x, np.full(6, 150.0) + k, np.full(6, 30.0), np.full(6, 70.0)])
        boxes = boxes[rng.random(6) < 0.9]
        extra = [boxes[:2] + [9.0, 4.0, 3.0, -6.0]]                    # second boxes
        if k % 2:
            extra.append(np.array([[300.0, 400.0, 25.0, 60.0]]))        # a spot
        extra.append(rng.uniform(0, 600, (3, 4)) * [1, 1, 0.1, 0.1] + [0, 0, 20, 50])
        boxes = np.vstack([boxes] + extra)
        if k == 15:
            # unequal weights (the kernel reads the (N,) array, not the one equal value)
            for f in (fused, ref):
                ps = f.particles
                f.particles = ParticleSet(ps.states.copy(),
                                          ps.log_weights + np.linspace(-0.1, 0.1, len(ps)))
        if k == 10:
            # clutter remembered far away: the place memory's grid is then too sparse for
            # the one-pass kernel (the GridIndex path after it)
            for f in (fused, ref):
                pl = f.scene.place
                far = np.array([[3e7, 3e7, 30.0, 70.0]])
                pl.mem_z = np.vstack([pl.mem_z, far])
                pl.mem_s = np.vstack([pl.mem_s, F.obs_std(far[:, 2:4], p.likelihood)])
                pl.mem_w = np.append(pl.mem_w, 0.9)
                pl.mem_e = np.append(pl.mem_e, 1.0)
                pl._sums = None
        if k == 20:
            boxes = boxes[:1]
        elif k == 21:
            boxes = boxes[:0]
        det = Detections(boxes, rng.uniform(0.2, 1.0, len(boxes)))
        a, b = fused.step(det), ref.step(det)
        assert a.updated.per_det_mass.tobytes() == b.updated.per_det_mass.tobytes(), k
        assert _scene_state(fused) == _scene_state(ref), k
    # the fused path on every frame with particles and detections (not the first, nor frame
    # 21 (none)), never on the reference filter's
    assert calls["frame"] == calls["learn"] == frames - 2, calls
    assert 0 < len(declined) < calls["frame"], len(declined)
    assert any(weights) and not all(weights), weights       # the array, and the one value


def test_fused_path_follows_new_settings(monkeypatch):
    """The fused κ path keeps its settings checks and the settings' scalars per settings
    object: new settings (PHDFilter.set_params) are looked at again -- a duplicate term
    switched off leaves the fused path, a new score clip reaches scene_frame's scalars, a
    new memory scene_learn's."""
    from dataclasses import replace

    from pfscope.trackers.phd import clutter as CL
    from pfscope.trackers.phd import filter as F
    from pfscope.trackers.phd.tracker import PHD_PRACTICAL
    calls = []
    frame_k = F.scene_frame

    def count_frame(*a):
        calls.append(float(a[6][CL.P_CLIP]))
        return frame_k(*a)

    monkeypatch.setattr(F, "scene_frame", count_frame)
    p = PHD_PRACTICAL.filter
    f = F.PHDFilter(p, rng=np.random.default_rng(0))
    boxes = np.array([[100.0, 150.0, 30.0, 70.0], [300.0, 150.0, 30.0, 70.0]])

    def step(k):
        Z = F.as_observations(boxes + [2.0 * k, 0.0, 0.0, 0.0])
        f.scene.chains.observe(Z, k)
        f.step(Z)

    for k in range(3):
        step(k)
    assert len(calls) == 2 and calls[-1] == p.score.max_log_ratio   # (frame 0: no particles)
    f.set_params(replace(p, score=replace(p.score, max_log_ratio=1.25)))
    step(3)
    assert len(calls) == 3 and calls[-1] == 1.25
    f.set_params(replace(p, clutter=replace(p.clutter, duplicate_prior=0.0)))
    step(4)
    assert len(calls) == 3                                  # the calls one by one
    f.set_params(p)
    step(5)
    assert len(calls) == 4 and calls[-1] == p.score.max_log_ratio
    assert f.scene._lpar[F._L_D] == 1.0 - 1.0 / p.clutter.clutter_memory
    f.set_params(replace(p, clutter=replace(p.clutter, clutter_memory=7)))
    step(6)                                                 # (scene_learn's scalars too)
    assert len(calls) == 5 and f.scene._lpar[F._L_D] == 1.0 - 1.0 / 7
