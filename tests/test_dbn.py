"""DBN-PHD (feng2015): codebook background, integral-histogram features, the torch RBM/DBN,
the likelihood's two routes, Algorithm 3, and the tracker through the one pipeline."""

from __future__ import annotations

import functools
import os
import pickle
import subprocess
import sys
import zipfile

import cv2
import numpy as np
import pytest

from pfscope.trackers.api import make_tracker, registry
from pfscope.trackers.data.sources import open_source
from pfscope.trackers.data.synthetic import SceneConfig
from pfscope.trackers.dbn.codebook import BackgroundParams, Codebook, blobs_from_mask
from pfscope.trackers.dbn.features import FeatureConfig, FrameFeatures, describe_brute_force
from pfscope.trackers.dbn import weights as dbn_weights
from pfscope.trackers.dbn.tracker import resample_alg3
from pfscope.trackers.errors import InputError
from pfscope.trackers.pipeline import run
from pfscope.trackers.report import Boxes, Mask, Points, Scalar, find
from pfscope.trackers.smc.resampling import resample
from pfscope.trackers.smc.weights import ParticleSet

torch = pytest.importorskip("torch")
from pfscope.trackers.dbn import model as dbn_model  # noqa: E402  (needs torch)


def _image(seed=0, h=120, w=160):
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    img[40:90, 50:80] = (30, 160, 220)          # a saturated patch
    return img


BOXES = np.array([[10, 10, 30, 60],             # inside
                  [-15, 20, 30, 60],            # crosses the left border
                  [140, 100, 40, 50],           # crosses right and bottom
                  [60.3, 44.7, 1.0, 1.0],       # tiny
                  [0, 0, 0.2, 0.4],             # sub-pixel at the corner
                  [55, 45, 20, 40]])            # inside the uniform patch


# ----------------------------------------------------------------------------- features

def test_integral_histogram_features_equal_brute_force():
    img = _image()
    cfg = FeatureConfig()
    for scale in (1.0, 0.5):
        fast = FrameFeatures(img, cfg, scale).describe(BOXES)
        slow = describe_brute_force(img, BOXES, cfg, scale)
        np.testing.assert_allclose(fast, slow, rtol=1e-9, atol=1e-9)


def test_histograms_are_normalised_and_invariant_including_at_the_border():
    img = _image()
    cfg = FeatureConfig()
    f = FrameFeatures(img, cfg).describe(BOXES)
    assert f.shape == (len(BOXES), cfg.dim) and np.all((f >= 0) & (f <= 1))
    hog = f[:, :cfg.hog_dim]
    np.testing.assert_allclose(np.linalg.norm(hog[[0, 1, 2]], axis=1), 1.0, atol=1e-6)
    assert np.all(hog[5] == 0)                    # a flat patch has no gradient: HOG 0, not NaN
    bands = f[:, cfg.hog_dim:].reshape(len(BOXES), cfg.colour_rows, cfg.colour_bins)
    sq = (bands ** 2).sum(axis=2)                 # Hellinger map: unit norm per band
    # every band with a pixel in the image has unit norm, even for tiny boxes; box 2's lower
    # band (rows 125-150) lies wholly below the 120-row image: empty, all zeros
    expect = np.ones_like(sq)
    expect[2, 1] = 0.0
    np.testing.assert_allclose(sq, expect, atol=1e-9)
    # a box entirely outside the image has empty (all-zero) features, not NaN
    out = FrameFeatures(img, cfg).describe(np.array([[500.0, 500.0, 20.0, 40.0]]))
    assert np.all(out == 0)
    # colour is translation-invariant inside a uniform region
    a = FrameFeatures(img, cfg).describe(np.array([[52, 42, 20, 40], [56, 46, 20, 40]]))
    np.testing.assert_allclose(a[0, cfg.hog_dim:], a[1, cfg.hog_dim:])
    # HOG is invariant to a contrast gain (block normalisation)
    dark = np.repeat(img[:, :, :1] // 2, 3, axis=2)   # grey, so grey(2x) == 2 grey(x) exactly
    gain = dark * 2
    h1 = FrameFeatures(dark, cfg).describe(BOXES[:3])[:, :cfg.hog_dim]
    h2 = FrameFeatures(gain, cfg).describe(BOXES[:3])[:, :cfg.hog_dim]
    np.testing.assert_allclose(h1, h2, atol=1e-6)


def test_feature_cost_does_not_depend_on_box_area():
    ff = FrameFeatures(_image(h=240, w=320), FeatureConfig())
    small = ff.describe(np.tile([[10, 10, 4, 8]], (2000, 1)))
    big = ff.describe(np.tile([[0, 0, 320, 240]], (2000, 1)))
    assert small.shape == big.shape
    # the integral-image gather gives every copy of a box the same features as the box alone,
    # and different boxes different features
    one_small = ff.describe(np.array([[10, 10, 4, 8]]))
    np.testing.assert_allclose(small, np.repeat(one_small, 2000, axis=0), atol=1e-9)
    img = _image(h=240, w=320)
    ref = describe_brute_force(img, np.array([[10, 10, 4, 8], [0, 0, 320, 240]]),
                               FeatureConfig())   # pixel-by-pixel sums: the reference
    np.testing.assert_allclose(small[0], ref[0], atol=1e-6)
    np.testing.assert_allclose(big[0], ref[1], atol=1e-6)
    assert not np.allclose(small[0], big[0])


# ----------------------------------------------------------------------------- background

def test_codebook_finds_a_moving_object_and_tolerates_a_brightness_change():
    rng = np.random.default_rng(0)
    bg = rng.integers(60, 200, (60, 80, 3)).astype(np.float64)
    cb = Codebook(BackgroundParams(train_frames=10, scale=1.0))
    for t in range(10):                              # train on the background only
        cb.apply(np.clip(bg + rng.normal(0, 2, bg.shape), 0, 255).astype(np.uint8))
    frame = bg.copy()
    frame[20:40, 30:45] = (255, 0, 0)
    fg = cb.apply(frame.astype(np.uint8))
    assert fg[20:40, 30:45].mean() > 0.95 and fg.mean() < 0.1
    brighter = cb.apply(np.clip(bg * 1.1, 0, 255).astype(np.uint8))
    assert brighter.mean() < 0.02                    # within [α, β]: still background
    boxes, fill = blobs_from_mask(fg.astype(np.uint8), 1.0, 20)
    assert len(boxes) == 1 and np.allclose(boxes[0], [30, 20, 15, 20])


# ----------------------------------------------------------------------------- the DBN

def _toy(seed=0, n=400, d=20):
    rng = np.random.default_rng(seed)
    protos = rng.random((3, d)) < 0.5
    x = protos[rng.integers(0, 3, n)]
    flip = rng.random((n, d)) < 0.05
    return torch.from_numpy((x ^ flip).astype(np.float64))


def test_cd1_lowers_the_reconstruction_error_on_a_toy_set():
    V = _toy()
    gen = torch.Generator().manual_seed(0)
    rbm = dbn_model.RBM(V.shape[1], 8, gen)
    before = rbm.reconstruction_error(V)
    with dbn_model.single_thread():
        errs = dbn_model.pretrain_rbm(rbm, V, epochs=20, lr=0.1, batch=20, gen=gen)
    assert errs[-1] < 0.5 * before and errs[-1] < errs[0]


def _toy_features(seed=0, n=300):
    rng = np.random.default_rng(seed)
    d = FeatureConfig().dim
    y = (rng.random(n) < 0.4).astype(np.float64)
    X = np.clip(rng.random((n, d)) * 0.5 + 0.4 * y[:, None] * (np.arange(d) % 3 == 0), 0, 1)
    return X, y


def _small_model(seed):
    X, y = _toy_features()
    return dbn_model.train_dbn(X, y, seed=seed, pre_epochs=2, fine_epochs=5)


def test_same_seed_same_model_and_a_useful_classifier():
    a, b, c = _small_model(3), _small_model(3), _small_model(4)
    for k, v in a.net.state_dict().items():
        assert torch.equal(v, b.net.state_dict()[k])
    assert any(not torch.equal(v, c.net.state_dict()[k]) for k, v in a.net.state_dict().items())
    assert a.info["holdout_auc"] > 0.9 and a.info["holdout_accuracy"] > 0.75


def test_model_save_load_round_trip(tmp_path):
    m = _small_model(0)
    path = m.save(tmp_path / "m.pt")
    assert path.stat().st_size < 2_000_000
    X, _ = _toy_features(1, 50)
    # torch's loader and the tracker's torch-free one (weights.load_weights) read the same net
    for back in (dbn_model.load_model(path), dbn_weights.load_weights(path)):
        np.testing.assert_array_equal(m.logits(X), back.logits(X))
        assert back.features == m.features and back.hidden == m.hidden
        assert back.info == dbn_model.load_model(path).info and back.info["seed"] == 0


def test_the_tracker_reads_its_model_without_torch():
    # the shipped model's weights equal torch's reading of it, and a DBN-PHD tracker is built
    # (model read) in a process that never imports torch
    X = np.random.default_rng(0).random((40, dbn_model.default_model().features.dim))
    np.testing.assert_array_equal(dbn_weights.default_weights().logits(X),
                                  dbn_model.default_model().logits(X))
    from conftest import imported_in_fresh_process

    code = ("from pfscope.trackers.api import make_tracker; "
            "t = make_tracker('dbn-phd', seed=0); assert t.dbn is not None")
    assert not imported_in_fresh_process(code, "torch")


def test_a_model_file_runs_no_code(tmp_path):
    # a pickle naming any global but the tensor rebuild and storages is refused, not run
    class Evil:
        def __reduce__(self):
            return (os.makedirs, (str(tmp_path / "ran"),))

    evil = tmp_path / "evil.pt"
    with zipfile.ZipFile(evil, "w") as z:
        z.writestr("evil/data.pkl", pickle.dumps({"format": "pfscope-dbn", "x": Evil()}))
    with pytest.raises(InputError, match="not a pfscope DBN model"):
        dbn_weights.load_weights(evil)
    assert not (tmp_path / "ran").exists()


def test_a_bad_model_file_gives_one_clear_line(tmp_path):
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a model at all")
    wrong = tmp_path / "wrong.pt"
    torch.save({"format": "something-else"}, wrong)
    old = tmp_path / "old.pt"
    st = _small_model(0).state()
    st["version"] = 999
    torch.save(st, old)
    broken = tmp_path / "broken.pt"
    st = _small_model(0).state()
    st["hidden"] = [7, 5]
    torch.save(st, broken)
    for path, words in ((junk, "not a pfscope DBN model"), (wrong, "format tag"),
                        (old, "version 999"), (broken, "does not match"),
                        (tmp_path / "missing.pt", "no such")):
        for load in (dbn_model.load_model, dbn_weights.load_weights):
            with pytest.raises(InputError) as e:
                load(path)
            msg = str(e.value)
            assert str(path) in msg and words in msg and "\n" not in msg, (load, msg)
    with pytest.raises(InputError, match="no such DBN model"):
        make_tracker("dbn-phd", model=str(tmp_path / "missing.pt"))


def test_roc_auc():
    assert dbn_model.roc_auc(np.array([0.1, 0.4, 0.35, 0.8]), np.array([0, 0, 1, 1])) == 0.75


# ----------------------------------------------------------------------------- likelihood, Alg. 3

def test_dense_and_pair_likelihoods_agree():
    from pfscope.trackers.dbn.likelihood import DBNLikelihood, DBNParams
    from pfscope.trackers.types import Frame

    frame = Frame(1, 0.0, _image(h=240, w=320))
    lik = DBNLikelihood(dbn_model.default_model(), DBNParams())
    rng = np.random.default_rng(0)
    states = np.column_stack([rng.uniform(0, 320, 50), rng.uniform(0, 240, 50),
                              np.zeros((50, 2)), rng.uniform(10, 40, 50), rng.uniform(30, 90, 50)])
    Z = np.array([[100.0, 120.0, 30.0, 70.0], [200.0, 100.0, 25.0, 60.0]])
    dense = lik.log_g(states, Z, frame)
    rows = np.repeat(np.arange(50), 2)
    cols = np.tile([0, 1], 50)
    np.testing.assert_allclose(lik.log_g_pairs(states, Z, rows, cols, frame),
                               dense[rows, cols], rtol=1e-12)


def test_algorithm3_is_systematic_resampling_to_n_with_weights_n_hat_over_n():
    rng = np.random.default_rng(0)
    ps = ParticleSet(rng.normal(size=(300, 6)), np.log(rng.random(300) * 0.02))
    a = resample_alg3(ps, 1000, np.random.default_rng(5))
    assert len(a) == 1000 and np.isclose(a.mass, ps.mass)
    np.testing.assert_allclose(a.weights, ps.mass / 1000)
    # independent reference, feng2015 Algorithm 3 written out: the CDF of w / N_hat, one
    # uniform u1 in [0, 1/n), u_j = u1 + (j - 1)/n, particle i for the u_j in its CDF step
    w = np.exp(ps.log_weights - ps.log_weights.max())
    cdf = np.cumsum(w / w.sum())
    u1 = np.random.default_rng(5).random() / 1000
    ref = np.minimum(np.searchsorted(cdf, u1 + np.arange(1000) / 1000), len(cdf) - 1)
    match = np.all(a.states == ps.states[ref], axis=1)
    assert match.mean() > 0.99, match.mean()            # float ties at a step's edge aside
    # and counts per particle: floor or ceil of n * w / N_hat, as systematic resampling gives
    counts = np.bincount(ref, minlength=len(cdf))
    expect = 1000 * w / w.sum()
    assert np.all(np.abs(counts - expect) <= 1 + 1e-9)


# ----------------------------------------------------------------------------- the tracker

def _scene(frames=30, seed=2):
    return open_source("synthetic", synthetic_config=SceneConfig(
        frames=frames, targets=4, width=320, height=240, seed=seed))


def test_registry_has_dbn_phd_and_its_baseline_without_importing_torch():
    reg = registry()
    assert reg["dbn-phd"].paper == "feng2015" and "paper" in reg["dbn-phd"].presets
    assert reg["phd-bgsub"].params.dbn.use_dbn is False
    code = ("import sys; from pfscope.trackers.api import registry; registry(); "
            "import pfscope.viewer_app.cli as c; c.build_parser(); print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "False", out.stderr


def test_the_tracker_runs_through_the_pipeline_and_reports_every_stage():
    tr = make_tracker("dbn-phd", seed=0)
    seen = {}

    class Keep:
        def begin(self, info): pass
        def on_rows(self, lane, rows): pass
        def end(self, outcome): pass

        def on_frame(self, report):
            seen[report.frame.index] = report.results["dbn-phd"].stages

    res = run(_scene(), [tr], level="particles", hooks=[Keep()])
    assert res.outcome.status == "completed" and res.frames == 30
    last = seen[30]
    assert [s.name for s in last] == list(tr.stages)
    assert find(last, "dbn/foreground", Mask)[0].mask.shape == (240, 320)
    acc = find(last, "dbn/blobs/accepted", Boxes)[0]
    assert "dbn" in acc.values and len(acc) >= 1
    score = find(last, "dbn/particles/score", Points)[0]
    assert len(score) and np.all((score.weights >= 0) & (score.weights <= 1))
    # N_hat, the PHD's mass, counts the people the DBN accepted: frames 11-30, mean
    # |N_hat - accepted blobs| measured 0.13-0.18 over scene seeds 0-2 x tracker seeds 0-2
    n_hat = np.array([find(seen[f], "dbn/n_hat", Scalar)[0].value for f in range(11, 31)])
    blobs = np.array([len(find(seen[f], "dbn/blobs/accepted", Boxes)[0])
                      for f in range(11, 31)])
    assert blobs.mean() >= 1 and np.abs(n_hat - blobs).mean() < 0.4, (n_hat, blobs)
    # its tracks are on people: precision (IoU >= 0.5 with a ground-truth box, by hand)
    # measured 0.68-0.93, recall 0.11-0.38 (the shipped DBN, trained on PETS09, accepts about
    # half of this small synthetic scene's people)
    prec, rec = _precision_recall(res.rows["dbn-phd"], _scene().gt)
    assert prec >= 0.6 and rec >= 0.08, (prec, rec)


def test_same_seed_same_tracks():
    def rows(seed):
        res = run(_scene(frames=20), [make_tracker("dbn-phd", seed=seed)])
        return [(f, ts.ids.tolist(), ts.boxes.tolist()) for f, ts in res.rows["dbn-phd"]]
    assert rows(1) == rows(1)


def _precision_recall(rows, gt, iou=0.5):
    """Share of track boxes that overlap a ground-truth box of their frame by ``iou``, and share
    of ground-truth boxes that one overlaps."""
    from pfscope.trackers.eval import box_iou

    tp = n_tr = hit = 0
    for f, ts in rows:
        g = gt.boxes[gt.frame == f]
        n_tr += len(ts)
        if len(ts) and len(g):
            m = box_iou(ts.boxes, g) >= iou
            tp += int(m.any(axis=1).sum())
            hit += int(m.any(axis=0).sum())
    return tp / max(n_tr, 1), hit / max(len(gt.frame), 1)


def test_baseline_runs_without_the_dbn(monkeypatch):
    # no DBN at all: loading one fails, the baseline never asks
    def no_dbn(*a, **k):
        raise AssertionError("phd-bgsub loaded a DBN")

    monkeypatch.setattr(dbn_model, "default_model", no_dbn)
    monkeypatch.setattr(dbn_model, "load_model", no_dbn)
    monkeypatch.setattr(dbn_weights, "default_weights", no_dbn)
    monkeypatch.setattr(dbn_weights, "load_weights", no_dbn)
    res = run(_scene(), [make_tracker("phd-bgsub", seed=0)], level="particles")
    assert res.outcome.status == "completed" and res.frames == 30
    # every foreground blob is a person to it: precision measured 0.76-0.79, recall
    # 0.48-0.62 over scene seeds 0-2 x tracker seeds 0-2
    prec, rec = _precision_recall(res.rows["phd-bgsub"], _scene().gt)
    assert prec >= 0.65 and rec >= 0.4, (prec, rec)



def test_synth_bg_noise_is_off_by_default_and_changes_pixels_only():
    base = SceneConfig(frames=5, targets=2, width=160, height=120, seed=4)
    noisy = SceneConfig(frames=5, targets=2, width=160, height=120, seed=4, bg_noise=3.0,
                        flicker=0.05)
    from pfscope.trackers.data.synthetic import SyntheticScene
    a, b = SyntheticScene(base), SyntheticScene(noisy)
    assert len(a.noise_patches) == 0 and len(b.noise_patches) > 0
    np.testing.assert_array_equal(a.gt.boxes, b.gt.boxes)
    np.testing.assert_array_equal(a.det.boxes, b.det.boxes)
    assert not np.array_equal(a.render(3), b.render(3))
    np.testing.assert_array_equal(SyntheticScene(noisy).render(3), b.render(3))  # seeded


def test_dbn_cuts_false_positives_and_raises_mota_on_a_noisy_synthetic_scene():
    """Issue 8 asks for "DBN-PHD beats its no-DBN baseline on OSPA" on a noisy synthetic
    scene.  With the person-blob training set, over seeds 1–5 (100 frames, 6 people) the mean
    OSPA is better (44.6 vs 47.9 px) and 4 of 5 seeds are, but seed 5 is 18 px worse, and on
    this test's 40-frame scenes 3 of 6 seeds go each way: not reliable enough to assert.
    What holds on every seed is what the DBN is for — fewer noise tracks and a better MOTA —
    and that is what this checks, over 3 seeds with a tolerance, with a DBN that knows the
    scene's drawn figures (the shipped model knows PETS people: on these figures it learns a
    wrong person size from accepted noise blobs and its MOTA gain is +0.03, issue 20 notes)."""
    from pfscope.trackers.dbn.tracker import DBNPHDTracker

    model = _synthetic_scene_model()
    fp = {"dbn-phd": [], "phd-bgsub": []}
    mota = {"dbn-phd": [], "phd-bgsub": []}
    for seed in (1, 2, 3):
        cfg = SceneConfig(frames=40, targets=4, width=320, height=240, seed=seed,
                          bg_noise=0.6, flicker=0.04)
        dbn = DBNPHDTracker(make_tracker("dbn-phd", seed=seed).params,
                            rng=np.random.default_rng(seed), model=model)
        res = run(open_source("synthetic", synthetic_config=cfg),
                  [dbn, make_tracker("phd-bgsub", seed=seed)])
        for name, fps in fp.items():
            fps.append(res.scores[name]["FP"])
            mota[name].append(res.scores[name]["MOTA"])
    assert np.mean(fp["dbn-phd"]) < 0.8 * np.mean(fp["phd-bgsub"]), fp
    assert np.mean(mota["dbn-phd"]) > np.mean(mota["phd-bgsub"]) + 0.05, mota
    assert np.all(np.array(mota["dbn-phd"]) > np.array(mota["phd-bgsub"]) - 0.05), mota


@functools.lru_cache(maxsize=1)
def _synthetic_scene_model():
    """A DBN trained on the synthetic scene's figures (scene seed 1000, never scored here):
    the model pfscope used by default before it shipped one trained on real people."""
    src = open_source("synthetic", synthetic_config=SceneConfig(
        frames=60, targets=8, seed=1000, name="dbn-training"))
    stats: dict = {}
    X, y = dbn_model.collect_samples(src, range(6, 61), seed=0, stride=2,
                                     background=BackgroundParams(initial="online"), stats=stats)
    return dbn_model.train_dbn(X, y, seed=0, hue_shifts=(), box_height=stats["box_height"])


@pytest.mark.slow
def test_dbn_beats_its_baseline_on_ospa_over_seeds_on_a_noisy_synthetic_scene():
    """Issue 8's test: on the README's noisy scene (100 frames, 6 people, 320x240, noise
    patches 0.6/frame, flicker 0.04), over seeds 1-5, DBN-PHD's mean OSPA is lower than the
    same filter's without the DBN (README: 44.6 vs 47.9 px; seed 5 alone goes the other way,
    hence the mean over seeds).  The DBN is one trained on the synthetic scene's figures: the
    shipped model knows PETS people, not these drawn figures, and with it the mean OSPA is
    71 vs 46 px (it rejects the figures; issue 20 notes).  The features are taken at the fixed
    half scale (``feature_height=0``): the drawn figures have no optical blur, and described at
    full resolution (the pyramid level their 54 px asks for) they differ from the half-scale
    figures the model learnt from — with the pyramid the mean OSPA is 50.9 vs 46.1 (issue 20
    notes; on real video the pyramid is what wins, PETS09 at 480x360: 28.1 -> 21.5)."""
    from pfscope.trackers.dbn.tracker import DBNPHDTracker

    model = _synthetic_scene_model()
    ospa = {"dbn-phd": [], "phd-bgsub": []}
    for seed in range(1, 6):
        cfg = SceneConfig(frames=100, targets=6, width=320, height=240, seed=seed,
                          bg_noise=0.6, flicker=0.04)
        dbn = DBNPHDTracker(make_tracker("dbn-phd", seed=seed, feature_height=0).params,
                            rng=np.random.default_rng(seed), model=model)
        res = run(open_source("synthetic", synthetic_config=cfg),
                  [dbn, make_tracker("phd-bgsub", seed=seed)])
        for name, values in ospa.items():
            values.append(res.scores[name]["OSPA"])
    assert np.mean(ospa["dbn-phd"]) < np.mean(ospa["phd-bgsub"]), ospa


# ----------------------------------------------------------------------------- speed paths

def test_per_box_crop_route_equals_the_whole_frame_integral_route():
    """A few boxes (the blobs) are described from their own crops; many (the particles) from
    the frame's integral histograms.  Both give the same features, at the border too."""
    img = _image(3, h=121, w=163)
    cfg = FeatureConfig()
    for scale in (1.0, 0.5):
        crop = FrameFeatures(img, cfg, scale)
        assert crop.describe(BOXES).shape == (len(BOXES), cfg.dim) and crop._ii is None
        whole = FrameFeatures(img, cfg, scale)
        whole._integrals()                                   # forces the integral route
        np.testing.assert_allclose(crop.describe(BOXES), whole.describe(BOXES),
                                   rtol=1e-9, atol=1e-9)


def test_codebook_first_match_equals_the_dense_first_match():
    """The slot-by-slot matching gives, per pixel, whether any codeword matches (Kim eqs. (2),
    (3)) and the first one that does — as the dense (L, P) evaluation."""
    from pfscope.trackers.dbn.codebook import _Book

    rng = np.random.default_rng(0)
    P, L = 3000, 4
    b = _Book(P, L)
    b.v[:] = rng.uniform(0, 255, (L, P, 3))
    b.vv[:] = np.einsum("lpc,lpc->lp", b.v, b.v)
    inten = np.sqrt(b.vv)
    b.imin[:] = inten * rng.uniform(0.8, 1.0, (L, P))
    b.imax[:] = inten * rng.uniform(1.0, 1.2, (L, P))
    b.f[:] = rng.integers(0, 3, (L, P))
    x = (b.v[rng.integers(0, L, P), np.arange(P)] + rng.normal(0, 8, (P, 3))).astype(np.float32)
    xx = np.einsum("pc,pc->p", x, x)
    xi = np.sqrt(xx)
    usable = rng.random((L, P)) < 0.7
    for use in (None, usable):
        eps, alpha, beta = 12.0, 0.6, 1.25
        xv = np.einsum("pc,lpc->lp", x, b.v)
        cd2 = xx[None] - xv * xv / np.maximum(b.vv, 1e-6)
        dense = ((b.f > 0) & (cd2 <= eps * eps) & (xi[None] >= alpha * b.imax)
                 & (xi[None] <= np.minimum(beta * b.imax, b.imin / alpha)))
        if use is not None:
            dense &= use
        hit, slot = b.first_match(x, xx, xi, eps, alpha, beta, use)
        assert 0.2 < hit.mean() < 0.95                      # both cases occur
        np.testing.assert_array_equal(hit, dense.any(axis=0))
        np.testing.assert_array_equal(slot[hit], np.argmax(dense, axis=0)[hit])


def test_row_wise_codebook_update_equals_the_indexed_update():
    from pfscope.trackers.dbn.codebook import _Book

    rng = np.random.default_rng(1)
    P, L = 2000, 3
    a, b = _Book(P, L), _Book(P, L)
    for book in (a, b):
        book.v[:] = np.arange(L * P * 3, dtype=np.float32).reshape(L, P, 3) % 251
        book.vv[:] = np.einsum("lpc,lpc->lp", book.v, book.v)
        book.imin[:], book.imax[:] = 50, 200
        book.f[:], book.q[:], book.lam[:] = 3, 5, 2
    x = rng.uniform(0, 255, (P, 3)).astype(np.float32)
    xi = np.sqrt(np.einsum("pc,pc->p", x, x))
    hit = rng.random(P) < 0.9
    slot = np.where(rng.random(P) < 0.8, 0, rng.integers(1, L, P))  # slot 0: the row route
    a.update_hits(hit, slot, x, xi, 9)
    pix = np.flatnonzero(hit)
    b.update(pix, slot[pix], x, xi, 9)
    for arr in ("v", "vv", "imin", "imax", "f", "lam", "p", "q"):
        np.testing.assert_allclose(getattr(a, arr), getattr(b, arr), rtol=1e-6, err_msg=arr)


# ----------------------------------------------------------------------------- training set

def test_person_blobs_are_positives_and_partial_blobs_are_left_out():
    gt = np.array([[100.0, 50.0, 40.0, 100.0]])
    blobs = np.array([[102.0, 52.0, 40.0, 96.0],      # the person's blob: IoU ~0.9
                      [100.0, 50.0, 40.0, 40.0],      # the head and torso only: IoU 0.4
                      [300.0, 200.0, 30.0, 30.0]])    # noise far away
    boxes, labels = dbn_model.sample_boxes((480, 640, 3), gt, blobs, np.random.default_rng(0),
                                           n_random=0, n_near=0, n_jitter=0)
    got = {tuple(b): lab for b, lab in zip(boxes.tolist(), labels.tolist())}
    assert got[tuple(blobs[0])] == 1.0 and got[tuple(gt[0])] == 1.0
    assert got[tuple(blobs[2])] == 0.0
    assert tuple(blobs[1]) not in got


def test_bin_integrals_equal_cv2_integral_of_the_bin_maps_float_for_float():
    """The one-pass kernel (no one-hot maps) adds in cv2.integral's order: the same floats."""
    from pfscope.trackers.dbn.features import bin_integrals, bin_maps, integral

    cfg = FeatureConfig()
    rng = np.random.default_rng(7)
    img = _image(5)
    noisy = np.clip(img + rng.normal(0, 20, img.shape), 0, 255).astype(np.uint8)
    for im in (img, noisy, noisy[3:70, 5:60]):
        hm, cm = bin_maps(im, cfg)
        ih, ic = bin_integrals(im, cfg)
        assert ih.shape == (im.shape[0] + 1, im.shape[1] + 1, cfg.orientations)
        assert ic[-1, -1].sum() == im.shape[0] * im.shape[1]      # every pixel in one bin
        np.testing.assert_array_equal(ih, integral(hm))
        np.testing.assert_array_equal(ic, integral(cm))


def test_crop_route_equals_per_box_crops_float_for_float():
    """The blobs' route (every box's bins computed together, integrals and cell sums in one
    numba call) gives exactly what describing each box from its own crop (one-pixel margin,
    cv2.integral of its bin maps, 4 look-ups per cell) gives — and describe_union exactly
    what one crop over the boxes' union gives."""
    from pfscope.trackers.dbn.features import _cell_sums, _normalise, bin_maps, integral

    cfg = FeatureConfig()
    rng = np.random.default_rng(3)
    img = np.clip(_image(6) + rng.normal(0, 15, (120, 160, 3)), 0, 255).astype(np.uint8)
    ff = FrameFeatures(img, cfg)
    H, W = img.shape[:2]

    def by_crop(boxes, union):
        yh, xh = ff.edges(boxes, cfg.hog_rows, cfg.hog_cols)
        yc, xc = ff.edges(boxes, cfg.colour_rows, 1)
        lo_y, hi_y = np.minimum(yh[:, 0], yc[:, 0]), np.maximum(yh[:, -1], yc[:, -1])
        lo_x, hi_x = np.minimum(xh[:, 0], xc[:, 0]), np.maximum(xh[:, -1], xc[:, -1])
        if union:
            lo_y[:], hi_y[:], lo_x[:], hi_x[:] = lo_y.min(), hi_y.max(), lo_x.min(), hi_x.max()
        out = np.zeros((len(boxes), cfg.dim))
        for i in range(len(boxes)):
            y0, y1, x0, x1 = lo_y[i], hi_y[i], lo_x[i], hi_x[i]
            if y1 <= y0 or x1 <= x0:
                out[i] = _normalise(np.zeros((1, cfg.hog_dim)),
                                    np.zeros((1, cfg.colour_rows, cfg.colour_bins)), cfg)
                continue
            cy0, cx0 = max(y0 - 1, 0), max(x0 - 1, 0)
            hm, cm = bin_maps(img[cy0:min(y1 + 1, H), cx0:min(x1 + 1, W)], cfg)
            reg = (slice(y0 - cy0, y1 - cy0), slice(x0 - cx0, x1 - cx0))
            hog = _cell_sums(integral(np.ascontiguousarray(hm[reg])), yh[i:i + 1] - y0,
                             xh[i:i + 1] - x0)
            col = _cell_sums(integral(np.ascontiguousarray(cm[reg])), yc[i:i + 1] - y0,
                             xc[i:i + 1] - x0)
            out[i] = _normalise(hog.reshape(1, -1), col[:, :, 0, :], cfg)[0]
        return out

    np.testing.assert_array_equal(ff.describe(BOXES), by_crop(BOXES, False))
    assert ff._ii is None                                   # the crop route was taken
    near = np.array([[40, 30, 20, 50], [48, 34, 22, 48], [55, 28, 18, 55.5]])
    np.testing.assert_array_equal(ff.describe_union(near), by_crop(near, True))


def test_blobs_from_the_foregrounds_box_are_the_whole_masks():
    """blobs_from_mask labels only the box around the foreground: the same boxes and fills in
    the same order as labelling the whole mask (OpenCV), also with blobs of equal area, whose
    order is OpenCV's label order over the whole image (its parallel stripes)."""
    def whole(mask, scale, min_area):
        n, _l, stats, _c = cv2.connectedComponentsWithStats(mask, connectivity=8,
                                                             ltype=cv2.CV_32S)
        st = stats[1:n].astype(np.float64)
        area = st[:, cv2.CC_STAT_AREA]
        keep = area >= min_area * scale * scale
        boxes = st[keep][:, :4]
        order = np.argsort(-area[keep], kind="stable")
        return boxes[order] / scale, (area[keep] / (boxes[:, 2] * boxes[:, 3]))[order]

    rng = np.random.default_rng(0)
    masks = [np.zeros((288, 384), np.uint8), np.ones((60, 80), np.uint8)]
    for k in range(40):
        m = np.zeros((288, 384), np.uint8)
        for _ in range(rng.integers(1, 12)):               # equal squares and random boxes
            y, x = rng.integers(0, 270), rng.integers(0, 360)
            if rng.random() < 0.5:
                m[y:y + 12, x:x + 12] = 1
            else:
                m[y:y + rng.integers(1, 40), x:x + rng.integers(1, 30)] = 1
        m |= (rng.random(m.shape) < 0.002).astype(np.uint8)     # specks
        masks.append(m)
    for m in masks:
        for min_area in (150, 4):
            got, want = blobs_from_mask(m, 0.5, min_area), whole(m, 0.5, min_area)
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])


def test_split_windows_are_each_foot_rows_linspace_float_for_float():
    """split_candidates builds every foot row's windows at once: the same windows, in the same
    order, as np.linspace per row (blobs narrower than a person included: one window a row)."""
    from pfscope.trackers.dbn.scale import PersonScale, SplitParams, split_candidates

    def per_row(blob, scale, params, ii, mask_scale):
        x0, y0, bw, bh = (float(v) for v in blob)
        _, h_top = scale.size_at(y0 + bh)
        hmax = float(min(h_top, bh))
        n_rows = max(1, int(np.ceil(max(bh - 0.5 * hmax, 0.0) / (0.25 * hmax))) + 1)
        foot = np.linspace(y0 + min(hmax, bh), y0 + bh, n_rows)
        w_f, h_f = scale.size_at(foot)
        h_f, w_f = np.minimum(h_f, bh), np.minimum(w_f, bw)
        out = []
        for fy, ww, hh in zip(foot, w_f, h_f):
            n_cols = max(1, int(np.ceil(max(bw - ww, 0.0) / (ww / 3.0))) + 1)
            xs = np.linspace(x0, x0 + bw - ww, n_cols)
            out.append(np.stack([xs, np.full(n_cols, fy - hh), np.full(n_cols, ww),
                                 np.full(n_cols, hh)], axis=1))
        cand = np.concatenate(out)
        if len(cand) > params.max_windows:
            cand = cand[np.linspace(0, len(cand) - 1, params.max_windows).round().astype(int)]
        return cand

    rng = np.random.default_rng(0)
    sp = SplitParams(min_samples=5, min_fill=0.0, max_windows=10_000)
    ps = PersonScale(sp)
    hs = rng.uniform(30, 150, 30)
    ps.add(np.c_[rng.uniform(0, 700, 30), rng.uniform(0, 400, 30),
                 hs * rng.uniform(0.3, 0.6, 30), hs])
    ii = cv2.integral(np.ones((288, 384), np.uint8))
    narrow = 0
    for t in range(300):
        blob = np.array([rng.uniform(-20, 700), rng.uniform(-20, 500), rng.uniform(1, 400),
                         rng.uniform(1, 300)])
        if t % 3 == 0:
            blob = np.round(blob)
        got, want = split_candidates(blob, ps, sp, ii, 0.5), per_row(blob, ps, sp, ii, 0.5)
        np.testing.assert_array_equal(got, want)
        narrow += blob[2] < ps.size_at(blob[1] + blob[3])[0]
    assert narrow > 10                                  # one-window rows were exercised


def test_describe_many_gives_each_requests_own_floats_in_its_own_route():
    """describe_many (a frame's blobs and the windows of the blobs it splits, described
    together) gives exactly what one describe / describe_union call per request, in order,
    gives: on a pyramid (boxes on several levels), with empty requests, and when a request of
    many boxes builds a level's whole-frame integrals, which a later union request then uses
    (as it would alone)."""
    rng = np.random.default_rng(5)
    img = np.clip(_image(6) + rng.normal(0, 15, (120, 160, 3)), 0, 255).astype(np.uint8)
    near = np.array([[40, 30, 20, 50], [48, 34, 22, 48], [55, 28, 18, 55.5]])
    many = np.c_[rng.uniform(0, 140, (40, 2)), rng.uniform(8, 30, (40, 1)),
                 rng.uniform(20, 60, (40, 1))]
    for cfg, scale in ((FeatureConfig(), 1.0), (FeatureConfig(), 0.5),
                       (FeatureConfig(box_height=25.0), 1.0)):
        for reqs in ([(BOXES, False), (near, True), (near + 30, True), (np.zeros((0, 4)), True)],
                     [(near, True), (many, False), (near, True), (BOXES[:3], False)]):
            one = FrameFeatures(img, cfg, scale)
            want = [one.describe_union(b) if u else one.describe(b) for b, u in reqs]
            got = FrameFeatures(img, cfg, scale).describe_many(reqs)
            assert len(got) == len(want)
            for g, w in zip(got, want):
                np.testing.assert_array_equal(g, w)


def test_dbn_reads_the_features_described_ahead_once():
    """DBNLikelihood.describe_ahead: the blobs and split windows of a frame are described in
    one describe_many call; the logits / logits_union calls on those boxes read them (the
    same logits as without), other boxes or another frame are described as before."""
    from pfscope.trackers.dbn.likelihood import DBNLikelihood
    from pfscope.trackers.types import Frame

    img = _image(6)
    calls = []
    orig = FrameFeatures.describe_many

    def counted(self, requests):
        calls.append(len(requests))
        return orig(self, requests)

    near = np.array([[40, 30, 20, 50], [48, 34, 22, 48]])
    model = dbn_weights.default_weights()
    plain = DBNLikelihood(model)
    frame = Frame(1, 0.0, img)
    ref_b, ref_w = plain.logits(BOXES, frame), plain.logits_union(near, frame)
    lk = DBNLikelihood(model)
    FrameFeatures.describe_many = counted
    try:
        lk.describe_ahead(frame, [(BOXES, False), (near, True)])
        assert calls == [2]
        np.testing.assert_array_equal(lk.logits(BOXES, frame), ref_b)
        np.testing.assert_array_equal(lk.logits_union(near, frame), ref_w)
        assert calls == [2]                                 # read, not described again
        lk.logits(near, frame)                              # not announced as a plain request
        lk.describe_ahead(frame, [(BOXES, False)])
        lk.logits(BOXES, Frame(2, 0.1, img))                # another frame
        assert calls == [2, 1, 1, 1]
    finally:
        FrameFeatures.describe_many = orig


def test_features_use_a_given_resize_instead_of_resizing_again():
    """A pyramid level whose scale is in ``scaled`` (the background model's copy of the frame)
    is described on that image: the same features as resizing again when it is the same
    resize, and a different image would show (it is really used)."""
    import cv2

    cfg = FeatureConfig(box_height=25.0)           # BOXES heights 40-60 px -> level 1 (0.5)
    img = _image(8)
    half = cv2.resize(img, (80, 60), interpolation=cv2.INTER_AREA)
    ref = FrameFeatures(img, cfg).describe(BOXES[:3])
    np.testing.assert_array_equal(FrameFeatures(img, cfg, scaled={0.5: half}).describe(BOXES[:3]),
                                  ref)
    other = FrameFeatures(img, cfg, scaled={0.5: 255 - half}).describe(BOXES[:3])
    assert not np.array_equal(other, ref)
    wrong_size = FrameFeatures(img, cfg, scaled={0.5: half[:-1]}).describe(BOXES[:3])
    np.testing.assert_array_equal(wrong_size, ref)   # not that resize: resized again


def test_hue_rotation_augmentation_rolls_hue_bins_only():
    cfg = FeatureConfig()
    img = _image(4)
    X = FrameFeatures(img, cfg).describe(BOXES[:3])
    r = dbn_model.rotate_hue(X, cfg, 2)
    np.testing.assert_array_equal(r[:, :cfg.hog_dim], X[:, :cfg.hog_dim])
    np.testing.assert_array_equal(dbn_model.rotate_hue(r, cfg, cfg.hue_bins - 2), X)
    # exact for whole bins: turn the image's hue by 2 bins (45 OpenCV units), same features
    import cv2
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    turned = hsv.copy()
    turned[..., 0] = (hsv[..., 0].astype(int) + 180 * 2 // cfg.hue_bins) % 180
    from pfscope.trackers.dbn.features import bin_maps
    _, c0 = bin_maps(img, cfg)
    hb = np.argmax(c0, axis=2)
    chrom = hb < cfg.hue_bins
    h = hsv[..., 0].astype(int)
    np.testing.assert_array_equal(hb[chrom], h[chrom] * cfg.hue_bins // 180)
    hb2 = turned[..., 0].astype(int) * cfg.hue_bins // 180
    np.testing.assert_array_equal(hb2[chrom], (hb[chrom] + 2) % cfg.hue_bins)


def test_bench_dbn_times_every_stage_of_both_lanes_and_writes_json(tmp_path):
    import json
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = tmp_path / "b.json"
    r = subprocess.run([sys.executable, str(root / "benchmarks" / "bench_dbn.py"), "--source",
                        "synthetic", "--frames", "12", "--json", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    data = json.loads(out.read_text())
    (run_,) = data["runs"]
    assert run_["frames"] == 12
    for lane in ("dbn-phd", "phd-bgsub"):
        d = run_["lanes"][lane]
        assert list(d["stage_ms"]) == ["background", "blobs", "predict", "birth", "features",
                                       "update", "resample", "cluster", "associate"]
        assert all(v >= 0 for v in d["stage_ms"].values())
        # the stages are the step: their sum is the step time, up to the report's overhead
        assert sum(d["stage_ms"].values()) <= d["ms_per_frame"] * 1.01 + 0.5
        assert d["fps"] > 0 and d["OSPA"] is not None and d["MOTA"] is not None
    assert "per-stage ms/frame" in r.stdout


# ----------------------------------------------------------------------------- issue 20

def test_dbn_paper_preset_differs_from_the_default_in_exactly_the_documented_fields():
    from conftest import flat_params

    from pfscope.trackers.api import make_params
    from pfscope.trackers.dbn.tracker import PAPER_CHANGES
    from pfscope.trackers.params import to_dict

    default = flat_params(to_dict(make_params("dbn-phd", None, {})))
    paper = flat_params(to_dict(make_params("dbn-phd", "paper", {})))
    differ = {k: paper[k] for k in default if paper[k] != default[k]}
    assert differ == PAPER_CHANGES
    # the literal reading runs: the DBN score sits on the particles (the features stage has
    # the particles' scores), not on the blobs
    tr = make_tracker("dbn-phd", preset="paper")
    assert tr.dbn is not None and tr.params.dbn.apply == "particle"


def test_shipped_model_loads_and_knows_people_of_two_dev_sequences():
    """The packaged model (no training at start-up) against person crops (gt boxes) and
    non-person crops (random person-sized windows and windows shifted 0.6-1.2 box sizes off a
    person) of PETS09-S2L1 and PETS09-S3MF1.  It was trained on both sequences (held-out
    scores per fold are in the issue 20 notes), so this checks that the file shipped, loads
    with weights_only and is a person classifier that accepts people: per sequence ROC AUC
    >= 0.99 and >= 90 % of the people at P(person) >= 0.5 (measured: 1.000 / 0.999, 98.0 % /
    94.2 %).  The old default (trained at start-up
    on the synthetic scene) scored AUC 0.966 / 0.985 and accepted 87.8 % / 86.5 %."""
    from conftest import sequence

    from pfscope.trackers.eval.overlap import box_iou

    assert dbn_model.SHIPPED.is_file() and dbn_model.SHIPPED.stat().st_size < 3_000_000
    model = dbn_model.default_model()
    assert model.info.get("trained_on", "").count("PETS09") == 2
    for name in ("PETS09-S2L1", "PETS09-S3MF1"):
        src = open_source(sequence(name))
        rng = np.random.default_rng(0)
        X, y = [], []
        for frame in src.frames(60):
            if frame.index % 6:
                continue
            g = src.gt.ground_truth(frame.index)
            people = g.boxes[~g.ignore]
            H, W = frame.image.shape[:2]
            h = rng.uniform(0.7, 1.3, 20) * np.median(people[:, 3])
            neg = np.c_[rng.uniform(0, W - 40, 20), rng.uniform(0, H - 100, 20), 0.4 * h, h]
            near = people.copy()
            ang, d = rng.uniform(0, 2 * np.pi, len(near)), rng.uniform(0.6, 1.2, len(near))
            near[:, 0] += np.cos(ang) * d * near[:, 2]
            near[:, 1] += np.sin(ang) * d * near[:, 3]
            neg = np.concatenate([neg, near])
            neg = neg[box_iou(neg, g.boxes).max(axis=1) < 0.2]
            ff = FrameFeatures(frame.image, model.features, 0.5)
            X += [ff.describe(people), ff.describe(neg)]
            y += [np.ones(len(people)), np.zeros(len(neg))]
        a, y = model.logits(np.concatenate(X)), np.concatenate(y) > 0
        auc, accepted = dbn_model.roc_auc(a, y), float(np.mean(a[y] >= 0))
        assert auc >= 0.99 and accepted >= 0.90, (name, auc, accepted)


def _walkers_clip(n=30, h=96, w=128, seed=0):
    """An empty textured scene and ``n`` frames of it with three walking blocks (each pixel
    covered in well under half of the frames)."""
    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur(rng.integers(0, 255, (h, w, 3)).astype(np.uint8), (5, 5), 0)
    frames, boxes = [], []
    for t in range(n):
        img = bg.copy()
        bs = []
        for k, (y0, speed, colour) in enumerate(((10, 4, (0, 0, 255)), (40, -3, (0, 255, 0)),
                                                 (60, 5, (255, 0, 0)))):
            x = int((t * speed + 30 * k) % (w - 12))
            img[y0:y0 + 30, x:x + 12] = colour
            bs.append((x, y0, 12, 30))
        frames.append(img)
        boxes.append(bs)
    return bg, frames, boxes


def test_temporal_median_background_recovers_the_empty_scene(tmp_path):
    from pfscope.trackers.data.sources import sample_frames
    from pfscope.trackers.dbn.codebook import ForegroundModel
    from pfscope.trackers.types import Frame

    bg, frames, boxes = _walkers_clip()
    for k, img in enumerate(frames, 1):
        cv2.imwrite(str(tmp_path / f"{k:04d}.png"), img)
    src = open_source(tmp_path)
    imgs = sample_frames(src, 30)
    assert len(imgs) == 30
    p = BackgroundParams(scale=1.0, morph_kernel=0, min_area=20)
    fm = ForegroundModel(p)
    med = fm.prime(imgs)
    err = np.abs(med.astype(int) - bg.astype(int))
    assert err.mean() < 1.0 and np.percentile(err, 99) <= 3            # the empty scene
    # the first frame is already segmented: the walkers are foreground, the rest is not
    mask = fm.mask(Frame(1, 0.0, frames[0])).astype(bool)
    truth = np.zeros(mask.shape, bool)
    for x, y, w, h in boxes[0]:
        truth[y:y + h, x:x + w] = True
    assert (mask & truth).sum() / truth.sum() > 0.9 and (mask & ~truth).sum() < 0.01 * mask.size
    # the online start (a stream) has learnt nothing yet at frame 1: no walker is found
    online = ForegroundModel(BackgroundParams(scale=1.0, morph_kernel=0, min_area=20,
                                              initial="online"))
    assert online.prime(imgs) is None
    assert (online.mask(Frame(1, 0.0, frames[0])).astype(bool) & truth).sum() == 0


def test_dbn_phd_prepares_its_background_offline_unless_online():
    from pfscope.trackers.api import StepResult
    from pfscope.trackers.types import TrackSet

    src = open_source("synthetic", synthetic_config=SceneConfig(frames=12, targets=3, width=160,
                                                                height=120, seed=5))
    calls = []
    tr = make_tracker("phd-bgsub", seed=0)
    orig = tr.background.prime
    tr.background.prime = lambda imgs: calls.append(len(imgs)) or orig(imgs)  # type: ignore
    tr.prepare(src, 1, 12)
    assert calls == [12]                       # all 12 frames of the clip (fewer than 30)
    assert tr.background._model.t == tr.params.background.train_frames   # training is over
    paper = make_tracker("phd-bgsub", preset="paper")
    paper.background.prime = lambda imgs: calls.append(-1)  # type: ignore
    paper.prepare(src, 1, 12)                  # background.initial = online: nothing to do
    assert calls == [12]

    class Probe:                               # the pipeline's side: prepare() unless online
        name, needs_detections = "probe", False

        def __init__(self):
            self.prepared = []

        def prepare(self, source, first, last):
            self.prepared.append((first, last))

        def step(self, frame, detections, level=None):
            return StepResult(TrackSet([], np.zeros((0, 4))), [], [])

        def finish(self):
            return []

    a, b = Probe(), Probe()
    run(src, [a], frames=5, start=3, score=False)
    run(src, [b], frames=5, offline=False, score=False)
    assert a.prepared == [(3, 7)] and b.prepared == []


# ----------------------------------------------------------------------------- issue 20/22

def test_codebook_kernel_equals_the_numpy_reference_frame_after_frame():
    """The numba detection step (one pass over the pixels) gives the same masks and the same
    codebooks as the numpy reference, through cache promotion and stale deletion (short
    cache_add / stale_delete so both happen within the clip)."""
    rng = np.random.default_rng(3)
    h, w = 48, 64
    bg = rng.integers(40, 200, (h, w, 3)).astype(np.float32)
    bp = BackgroundParams(cache_add=5, cache_forget=3, stale_delete=6, train_frames=4)
    a, b = Codebook(bp), Codebook(bp, kernel=False)
    a.prime(np.stack([bg] * 5))
    b.prime(np.stack([bg] * 5))
    promoted = False
    for t in range(30):
        img = np.clip(bg + rng.normal(0, 3, bg.shape), 0, 255)
        img[10:30, 5 + t:15 + t] = (250, 20, 20)                    # a mover
        if t >= 8:
            img[30:40, 40:50] = (20, 250, 20)                        # something parked
        img = img.astype(np.uint8)
        ma, mb = a.apply(img), b.apply(img)
        np.testing.assert_array_equal(ma, mb)
        for arr in ("v", "vv", "imin", "imax", "f", "lam", "p", "q"):
            np.testing.assert_array_equal(getattr(a.book, arr), getattr(b.book, arr), arr)
            np.testing.assert_array_equal(getattr(a.cache, arr), getattr(b.cache, arr), arr)
        promoted |= t > 20 and not ma[30:40, 40:50].any()
    assert promoted                                    # the parked patch joined the background
    assert ma[10:30, 41:44].all()                      # the mover's leading edge is foreground


def test_codebook_storage_is_pixel_major_and_the_slot_views_share_it():
    """The kernel walks pixels: a pixel's codewords are adjacent in the storage it gets, and
    the (L, P) attributes the numpy code writes are views of that same memory."""
    from pfscope.trackers.dbn.codebook import _Book

    P, L = 50, 4
    b = _Book(P, L)
    store = dict(zip(_Book.FIELDS, b.pixel_major()))
    for name, arr in store.items():
        assert arr.flags.c_contiguous and arr.shape[:2] == (P, L), name
        assert getattr(b, name).shape[:2] == (L, P), name
    b.f[2, 7] = 9                                   # a numpy-side write reaches the kernel's
    b.v[1, 3] = (1.0, 2.0, 3.0)
    assert store["f"][7, 2] == 9 and store["v"][3, 1].tolist() == [1.0, 2.0, 3.0]
    b.update(np.array([5]), np.array([3]), np.full((P, 3), 10, np.float32),
             np.full(P, 17.0, np.float32), 4)
    assert store["f"][5, 3] == 1 and store["q"][5, 3] == 4


def test_person_scale_learns_the_height_line_of_the_scene_and_ignores_merged_blobs():
    """Heights on a perspective line (people further up the image look smaller), 3x the
    size anything in the defaults assumes, plus wide two-person blobs and a few too-tall ones:
    the learnt line and aspect are the people's."""
    from pfscope.trackers.dbn.scale import PersonScale, SplitParams

    rng = np.random.default_rng(0)
    foot = rng.uniform(200, 900, 60)
    hgt = 60 + 0.4 * foot + rng.normal(0, 4, 60)          # 140..420 px tall
    people = np.stack([rng.uniform(0, 500, 60), foot - hgt, 0.4 * hgt, hgt], 1)
    merged = people[:15].copy()
    merged[:, 2] *= 2.6                                   # two or three side by side
    tall = people[15:20].copy()
    tall[:, 1] -= tall[:, 3]
    tall[:, 3] *= 2.0                                     # one behind the other
    ps = PersonScale(SplitParams(min_samples=20))
    ps.add(people[:10])
    assert not ps.ready
    ps.add(np.concatenate([people[10:], merged, tall]))
    assert ps.ready
    w, h = ps.size_at(np.array([300.0, 800.0]))
    np.testing.assert_allclose(h, [180.0, 380.0], rtol=0.05)
    np.testing.assert_allclose(w / h, 0.4, rtol=0.05)


def test_split_windows_are_person_sized_inside_the_blob_and_do_not_overlap():
    from pfscope.trackers.dbn.scale import (PersonScale, SplitParams, needs_split,
                                            select_windows, split_candidates)

    sp = SplitParams(min_samples=3)
    ps = PersonScale(sp)
    ps.add(np.array([[0, 100, 20, 50], [50, 100, 20, 50], [90, 100, 20, 50.0]]))
    mask = np.zeros((200, 200), np.uint8)
    mask[100:150, 40:100] = 1                              # three people merged, 60 x 50
    blobs = np.array([[40, 100, 60, 50], [0, 100, 22, 50.0]])
    np.testing.assert_array_equal(needs_split(blobs, ps, sp), [True, False])
    cand = split_candidates(blobs[0], ps, sp, cv2.integral(mask), 1.0)
    assert len(cand) >= 3
    assert np.all(cand[:, 0] >= 40 - 1e-9) and np.all(cand[:, 0] + cand[:, 2] <= 100 + 1e-9)
    np.testing.assert_allclose(cand[:, 2:], [[20, 50]] * len(cand))
    # a DBN that likes windows centred on the three people (x = 50, 70, 90)
    cx = cand[:, 0] + cand[:, 2] / 2
    prob = np.exp(-np.min(np.abs(cx[:, None] - [50, 70, 90]), axis=1) / 2.0)
    kept = select_windows(cand, prob, 0.5, sp.overlap)
    np.testing.assert_allclose(np.sort(cx[kept]), [50, 70, 90], atol=4)
    assert np.all(prob[kept] >= 0.5)


def test_dbn_phd_splits_a_blob_of_people_its_dbn_rejects_as_a_whole():
    """End to end through the tracker: once the person size is learnt, a merged blob the DBN
    turns down as a whole becomes one measurement per person (a stub DBN that accepts
    person-shaped boxes only); without the split it stays one rejected blob."""
    from pfscope.trackers.dbn.tracker import DBNPHDTracker
    from pfscope.trackers.types import Frame

    def person_like(boxes, frame):
        """+4 for a person-shaped box of one colour (one person), else -4."""
        out = []
        for x, y, w, h in np.round(np.asarray(boxes, float).reshape(-1, 4)).astype(int):
            crop = frame.image[y:y + h, x:x + w, 1:].reshape(-1, 2)
            one = len(crop) and crop.std(axis=0).max() < 10
            out.append(4.0 if one and abs(w / h - 0.4) < 0.1 else -4.0)
        return np.array(out)

    counts = {}
    for enabled in (True, False):
        tr = make_tracker("dbn-phd", seed=0, **{"split.enabled": enabled,
                                                 "split.min_samples": 5})
        assert isinstance(tr, DBNPHDTracker)
        tr.dbn.logits = person_like
        tr.dbn.logits_union = person_like
        tr.background.mask = lambda frame: frame.image[::2, ::2, 0] // 255    # at scale 0.5
        img = np.zeros((240, 320, 3), np.uint8)
        for k in range(3):                          # 3 single people, 20 x 50 each
            img[100:150, 20 + 60 * k:40 + 60 * k] = 255
        for t in range(1, 8):
            tr.step(Frame(t, t / 7, img), None)
        img2 = img.copy()
        for k, g in enumerate((40, 120, 200)):      # then three side by side: one blob 60 x 50
            img2[160:210, 200 + 20 * k:220 + 20 * k] = (255, g, 255 - g)
        res = tr.step(Frame(8, 8 / 7, img2), None)
        counts[enabled] = find(res.stages, "dbn/blobs/count", Scalar)[0].value
    assert counts[False] == 4 and counts[True] == 6, counts


def test_pyramid_features_describe_a_person_alike_at_two_resolutions():
    """feature_height: a box is described on the pyramid level nearest 48 px tall, so the same
    scene at full and at half resolution gives nearly the same features (fixed-scale features
    differ more), and the level follows the box height, not the image size."""
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.integers(0, 256, (400, 400, 3), dtype=np.uint8), (0, 0), 3)
    img[100:292, 150:230] = (40, 90, 200)
    img[150:200, 170:210] = (220, 220, 220)
    half = cv2.resize(img, (200, 200), interpolation=cv2.INTER_AREA)
    box = np.array([[140.0, 90.0, 100.0, 212.0]])
    pyr = FeatureConfig(box_height=48.0)
    fixed = FeatureConfig()
    f_full = FrameFeatures(img, pyr).describe(box)
    f_half = FrameFeatures(half, pyr).describe(box / 2)
    g_full = FrameFeatures(img, fixed, 0.5).describe(box)
    g_half = FrameFeatures(half, fixed, 0.5).describe(box / 2)
    d_pyr = np.linalg.norm(f_full - f_half)
    d_fixed = np.linalg.norm(g_full - g_half)
    assert d_pyr < 0.5 * d_fixed, (d_pyr, d_fixed)
    ff = FrameFeatures(img, pyr)
    np.testing.assert_array_equal(ff.levels(np.array([[0, 0, 10, 48], [0, 0, 10, 96],
                                                      [0, 0, 10, 212], [0, 0, 5, 20]])),
                                  [0, 1, 2, 0])
    # the per-blob union crop gives the whole-frame numbers
    boxes = np.array([[150.0, 100, 40, 96], [170, 110, 40, 96], [160, 120, 44, 100]])
    union = FrameFeatures(img, fixed, 0.5).describe_union(boxes)
    whole = FrameFeatures(img, fixed, 0.5)
    whole._integrals()
    np.testing.assert_allclose(union, whole.describe(boxes), rtol=1e-9, atol=1e-9)


def test_numpy_forward_pass_equals_the_torch_network():
    """DBNModel.logits runs the trained network in numpy (speed); it is the torch network's
    output to float rounding, on the shipped model and on extreme inputs."""
    model = dbn_model.default_model()
    rng = np.random.default_rng(0)
    X = np.concatenate([rng.random((50, model.features.dim)),
                        np.zeros((1, model.features.dim)), np.ones((1, model.features.dim))])
    np.testing.assert_allclose(model.logits(X), model.torch_logits(X), rtol=1e-9, atol=1e-9)
    assert np.ptp(model.logits(X)) > 1.0                     # not a constant


def test_weighted_births_let_a_rejected_blob_give_light_newborn():
    """births.select='weighted': every blob gives births, weighted by the DBN's P(person); a
    rejected blob's newborn weigh about P(person) of an accepted one's. The default
    ('accepted', feng2015's new-born selection) gives a rejected blob none."""
    from pfscope.trackers.types import Frame

    def half_people(boxes, frame):                  # the left blob a person, the right not
        b = np.asarray(boxes, float).reshape(-1, 4)
        return np.where(b[:, 0] < 100, 3.0, -3.0)

    img = np.zeros((240, 320, 3), np.uint8)
    img[100:150, 40:60] = 255
    img[100:150, 200:220] = 255
    births = {}
    for select in ("accepted", "weighted"):
        tr = make_tracker("dbn-phd", seed=0, **{"births.select": select})
        tr.dbn.logits = half_people
        tr.dbn.logits_union = half_people
        tr.background.mask = lambda frame: frame.image[::2, ::2, 0] // 255
        res = tr.step(Frame(1, 0.0, img), None, "particles")
        births[select] = find(res.stages, "dbn/particles/before", Points)[0]  # newborn only
    acc = births["accepted"]
    assert len(acc.xy) and np.all(acc.xy[:, 0] < 100)
    w = births["weighted"]
    right = w.xy[:, 0] > 100
    assert right.any() and (~right).any()
    ratio = w.weights[right].mean() / w.weights[~right].mean()
    p_right, p_left = 1 / (1 + np.exp(3.0)), 1 / (1 + np.exp(-3.0))
    assert ratio == pytest.approx(p_right / p_left, rel=0.1)


def test_person_scale_median_is_numpys_float_for_float():
    """The robust line's median (run every frame) is np.median's float: odd and even counts,
    ties, one and two elements."""
    from pfscope.trackers.dbn.scale import _median

    rng = np.random.default_rng(5)
    for n in (1, 2, 3, 4, 21, 400, 401):
        for x in (rng.normal(0.0, 3.0, n), rng.integers(0, 4, n).astype(float),
                  rng.uniform(0.1, 0.9, n)):
            assert _median(x) == np.median(x), n


def test_background_start_median_is_numpys_bit_for_bit():
    """The offline background's temporal median (one sort) is np.median(axis=0)'s array, bit
    for bit: odd and even counts, ties (uint8 frames as float32), float64, a NaN."""
    from pfscope.trackers.dbn.codebook import _median0

    rng = np.random.default_rng(6)
    for k in (1, 2, 3, 30, 31):
        for x in (rng.integers(0, 256, (k, 5, 7, 3)).astype(np.float32),
                  rng.normal(0.0, 50.0, (k, 5, 7, 3))):
            m = _median0(x)
            assert m.dtype == x.dtype and m.tobytes() == np.median(x, axis=0).tobytes(), k
    x = rng.normal(0.0, 1.0, (6, 4, 4, 3)).astype(np.float32)
    x[2, 1, 1, 0] = np.nan
    assert np.array_equal(_median0(x), np.median(x, axis=0), equal_nan=True)


def _moving_square_clip(n=12, h=60, w=80):
    rng = np.random.default_rng(4)
    bg = rng.integers(60, 160, (h, w, 3)).astype(np.uint8)
    out = []
    for k in range(n):
        img = np.clip(bg.astype(np.int16) + rng.integers(-3, 4, bg.shape), 0, 255).astype(np.uint8)
        img[20:44, 4 + 5 * k:16 + 5 * k] = (30, 30, 220)
        out.append(img)
    return out


def test_background_look_ahead_gives_the_same_masks_on_the_helper_thread():
    """ForegroundModel.upcoming: the next frame's stage runs on the helper thread once this
    frame's mask is done, and every mask (and the codebook) is what computing it in mask() gives;
    a frame other than the announced one is refused."""
    import threading

    from pfscope.trackers.dbn.codebook import ForegroundModel
    from pfscope.trackers.types import Frame

    imgs = _moving_square_clip()
    frames = [Frame(k + 1, k / 10.0, im) for k, im in enumerate(imgs)]
    bp = BackgroundParams(scale=0.5, morph_kernel=3, min_area=10)
    plain, ahead = ForegroundModel(bp), ForegroundModel(bp)
    plain.prime(imgs[:5])
    ahead.prime(imgs[:5])
    where = []
    stage = ahead._stage
    ahead._stage = lambda f: where.append((f.index, threading.current_thread().name)) or stage(f)
    for k, fr in enumerate(frames):
        if k + 1 < len(frames):
            ahead.upcoming(frames[k + 1])
        np.testing.assert_array_equal(ahead.mask(fr), plain.mask(fr))
        np.testing.assert_array_equal(ahead.small, plain.small)
    for name in ("v", "vv", "imin", "imax", "f", "lam", "p", "q"):
        np.testing.assert_array_equal(getattr(ahead._model.book, name),
                                      getattr(plain._model.book, name))
    assert where[0] == (1, threading.current_thread().name)        # nothing announced it
    assert [i for i, _ in where] == list(range(1, len(frames) + 1))  # each frame once, in order
    assert all(t.startswith("pfscope-background") for _, t in where[1:])
    other = ForegroundModel(bp)
    other.prime(imgs[:5])
    other.mask(frames[0])
    other.upcoming(frames[1])
    other.mask(frames[1])                     # computes frames[1]... and starts nothing more
    other.upcoming(frames[3])
    other.mask(frames[2])                     # starts frames[3] on the helper
    with pytest.raises(RuntimeError, match="announced"):
        other.mask(frames[4])


def test_pipeline_announces_the_next_frame_of_a_recorded_clip(tmp_path):
    """run(): a tracker with upcoming() hears of frame k+1 before step(k) on a recorded clip
    (never after the last frame); phd-bgsub's tracks are the same with and without it."""
    from pfscope.trackers.data.sources import ImageFolderSource
    from pfscope.trackers.dbn.tracker import PHDBgsubTracker
    from pfscope.trackers.pipeline import BaseHook

    for k, im in enumerate(_moving_square_clip(16), 1):
        cv2.imwrite(str(tmp_path / f"{k:06d}.png"), im)
    src = ImageFolderSource(tmp_path)
    calls = []

    class Spy(PHDBgsubTracker):
        name = "phd-bgsub"

        def upcoming(self, frame):
            calls.append(("next", frame.index))
            super().upcoming(frame)

        def step(self, frame, detections, level=None):
            calls.append(("step", frame.index))
            return super().step(frame, detections, level)

    class NoAhead(PHDBgsubTracker):
        upcoming = None

    class Rows(BaseHook):
        def __init__(self):
            self.rows = []

        def on_frame(self, r):
            res = next(iter(r.results.values()))
            self.rows.append((r.frame.index, res.tracks.ids.tolist(), res.tracks.boxes.tolist(),
                              [(it.path, it.value) for st in res.stages for it in st.items
                               if isinstance(it, Scalar)]))

    a, b = Rows(), Rows()
    params = registry()["phd-bgsub"].params
    run(src, [Spy(params, rng=np.random.default_rng(0))], frames=10, start=3, hooks=[a],
        score=False)
    run(src, [NoAhead(params, rng=np.random.default_rng(0))], frames=10, start=3, hooks=[b],
        score=False)
    assert calls == [c for k in range(3, 13)
                     for c in ((("next", k + 1), ("step", k)) if k < 12 else (("step", k),))]
    assert a.rows == b.rows
    blobs = [dict(sc)["dbn/blobs/count"] for *_, sc in a.rows]
    assert min(blobs) >= 1                    # the square is a blob in every frame


def test_with_next_pairs_each_frame_with_the_next_and_defers_a_read_error():
    from pfscope.trackers.pipeline import with_next

    assert list(with_next(iter([1, 2, 3]))) == [(1, 2), (2, 3), (3, None)]
    assert list(with_next(iter([]))) == []

    def broken():
        yield 1
        yield 2
        raise InputError("frame 3: unreadable")

    got = []
    with pytest.raises(InputError, match="frame 3"):
        for pair in with_next(broken()):
            got.append(pair)
    assert got == [(1, 2), (2, None)]          # frame 2 is handed out before the error
