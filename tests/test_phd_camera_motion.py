"""The camera's image motion estimated from the detections (``rate.camera_motion``,
:mod:`pfscope.trackers.phd.camera_motion`): on a panning and zooming camera PHD-MT keeps the
people as tracks only when the particles and the tracks follow the estimated motion; on a still
camera the estimate is the identity and the tracks are unchanged.

Scenes are built from boxes (no pixels), 10 fps, 1242x375, seeds 0-4: three people walking
(0.4 heights a second), each detected with probability 0.9 and 4 % box noise, plus Poisson
clutter.  The moving camera pans (the whole image shifts by up to 0.3 person heights a frame,
direction changing over 4 s) and zooms about the image centre (±25 % over 2.5 s).  Scored: the
share of frames (after the first second) where each person is covered by a track of the
tracks file (IoU >= 0.5)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from pfscope.trackers.api import make_tracker
from pfscope.trackers.eval.overlap import box_iou
from pfscope.trackers.phd import camera_motion as cm
from pfscope.trackers.phd.scene_motion import Chains
from pfscope.trackers.types import Detections, Frame, TrackSet, blank_image

SEEDS = range(5)
FPS, W, H = 10.0, 1242, 375
SECONDS = 8.0
PAN = 0.3             # pan speed amplitude, person heights per frame
ZOOM = 0.25           # zoom amplitude about the image centre
#: both arms with 0.1 clutter points around each detection, not the preset's 1 (the clutter
#: model is another setting's job; this test isolates the camera motion)
OPTIONS = {"clutter_rate": "0.1"}
#: a person's own speed prior of the practical preset at 10 fps: 1.5 sqrt(w h) a second
SPEED_VAR = (1.5 / FPS) ** 2 / 2


def _truth(seed: int, moving: bool) -> np.ndarray:
    """(frames, people, 4) true boxes (x, y, w, h)."""
    rng = np.random.default_rng(700 + seed)
    n = int(SECONDS * FPS)
    h0 = 0.22 * H
    x0 = np.array([0.3, 0.5, 0.7]) * W + rng.uniform(-20, 20, 3)
    walk = np.array([1.0, -1.0, 0.5]) * 0.4 * h0 / FPS          # px per frame, in the world
    phase = rng.uniform(0, 2 * np.pi)
    pan, out = 0.0, []
    for k in range(n):
        s = 1.0
        if moving:
            pan += PAN * h0 * np.sin(2 * np.pi * k / 40.0 + phase)
            s = 1.0 + ZOOM * np.sin(2 * np.pi * k / 25.0)
        cx = W / 2 + s * (x0 + walk * k - W / 2) + pan
        cy = np.full(3, H / 2 + s * (0.55 * H - H / 2))
        h = h0 * s
        w = 0.4 * h
        out.append(np.stack([cx - w / 2, cy - h / 2, np.full(3, w), np.full(3, h)], axis=1))
    return np.array(out)


def _detections(truth: np.ndarray, seed: int):
    rng = np.random.default_rng(900 + seed)
    for gt in truth:
        boxes, scores = [], []
        for g in gt:
            if rng.random() < 0.9:
                e = 0.04 * rng.standard_normal(4)
                w, h = g[2] * (1 + e[2]), g[3] * (1 + e[3])
                cx, cy = g[0] + g[2] / 2 + e[0] * g[2], g[1] + g[3] / 2 + e[1] * g[3]
                boxes.append([cx - w / 2, cy - h / 2, w, h])
                scores.append(rng.beta(8, 2))
        for _ in range(rng.poisson(1.0)):
            h = rng.uniform(0.15, 0.3) * H
            boxes.append([rng.uniform(0, W - 0.4 * h), rng.uniform(0, H - h), 0.4 * h, h])
            scores.append(rng.beta(2, 6))
        yield Detections(np.array(boxes).reshape(-1, 4), np.array(scores))


@cache
def _run(moving: bool, camera: bool) -> tuple[np.ndarray, tuple, tuple]:
    """Per seed: the share of (frame, person) covered by a track; the tracks file rows; the
    number of frames the camera was estimated to move."""
    out, rows_all, moved = [], [], []
    image = blank_image(H, W)
    empty = TrackSet(np.zeros(0, dtype=np.int64), np.zeros((0, 4)))
    for seed in SEEDS:
        truth = _truth(seed, moving)
        tracker = make_tracker("phd", seed, preset="practical",
                               **{"rate.camera_motion": str(camera).lower(), **OPTIONS})
        rows, n_moved = [], 0
        for k, det in enumerate(_detections(truth, seed)):
            rows.extend(tracker.step(Frame(k + 1, k / FPS, image), det).rows)
            n_moved += tracker.scene_motion.camera is not None
        rows.extend(tracker.finish())
        by_frame = dict(rows)
        hit = []
        for k in range(int(FPS), len(truth)):
            ts = by_frame.get(k + 1, empty)
            m = box_iou(truth[k], ts.boxes) if len(ts.boxes) else np.zeros((3, 0))
            hit.extend((m >= 0.5).any(axis=1) if m.shape[1] else [False] * 3)
        out.append(np.mean(hit))
        rows_all.append(tuple((f, ts.ids.tobytes(), ts.boxes.tobytes()) for f, ts in rows))
        moved.append(n_moved)
    return np.array(out), tuple(rows_all), tuple(moved)


def test_moving_camera_is_tracked_only_with_the_motion_compensated():
    """Pan and zoom: compensated, the people are covered in >= 50 % of the (frame, person)
    pairs on average over seeds 0-4 (>= 40 % in every seed) and >= 0.15 more than without
    (measured: 0.66, seeds 0.57-0.72, against 0.28, seeds 0.12-0.37).  The camera's motion is
    given in >= 70 % of the 80 frames of every seed (measured 62-78: the continuity of
    :class:`.camera_motion.CameraMotion` carries it through frames with fewer than two linked
    people; the per-frame fit alone gave 27-45)."""
    comp, _, moved = _run(True, True)
    raw, _, _ = _run(True, False)
    assert comp.mean() >= 0.5, (comp, raw)
    assert comp.min() >= 0.4, (comp, raw)
    assert comp.mean() - raw.mean() >= 0.15, (comp, raw)
    assert min(moved) >= 0.7 * SECONDS * FPS, moved     # the motion was seen (the pan
    # passes through a standstill twice in its 4 s period, and only links continuing a chain
    # count)


def test_still_camera_estimate_is_identity_and_tracks_unchanged():
    """Still camera (people walking, clutter): the camera is called still in >= 99 % of the
    frames of seeds 0-4 (the test's 99 % level; measured: none), and the tracks file
    is byte-identical with and without the compensation on every seed where it never moved
    (at least 3 of 5); where it did, the coverage moves by at most 0.05."""
    cov_on, rows_on, moved = _run(False, True)
    cov_off, rows_off, _ = _run(False, False)
    assert sum(moved) <= 0.01 * len(SEEDS) * SECONDS * FPS, moved
    still = [i for i, m in enumerate(moved) if m == 0]
    assert len(still) >= 3, moved
    for i in still:
        assert rows_on[i] == rows_off[i], i
    assert np.abs(cov_on - cov_off).max() <= 0.05, (cov_on, cov_off)


def _boxes(rng: np.random.Generator, n: int) -> np.ndarray:
    h = rng.uniform(60, 120, n)
    return np.stack([rng.uniform(100, W - 100, n), rng.uniform(120, H - 120, n), 0.4 * h, h],
                    axis=1)


@pytest.mark.parametrize("seed", range(5))
def test_fit_recovers_a_similarity(seed):
    """Six people under a known zoom 1.08 + shift (40, −10) px, 4 % box noise and their own
    steps at the speed prior (rms 0.08-0.16 box sizes), one link a mismatch: the fit puts the
    five true links' boxes within 0.12 box sizes rms of where the true motion puts them
    (measured 0.047-0.093; the identity: > 0.8), scale within 0.025 (measured 1.07-1.10)."""
    rng = np.random.default_rng(seed)
    q = _boxes(rng, 6)
    A = np.array([[1.08, 0.0, 40.0 - 0.08 * W / 2], [0.0, 1.08, -10.0 - 0.08 * H / 2]])
    z = cm.warp_boxes(q, A)
    step = np.sqrt(SPEED_VAR * q[:, 2] * q[:, 3])[:, None] * rng.standard_normal((6, 2))
    z[:, :2] += step + 0.04 * z[:, 2:4] * rng.standard_normal((6, 2))
    z[:, 2:4] *= 1 + 0.04 * rng.standard_normal((6, 2))
    z[5, :2] += z[5, 2:4] * 0.8                                    # a mismatched link
    got = cm.fit(q, z, np.arange(6), 0.075, 0.15, SPEED_VAR)
    assert got is not None
    want = cm.warp_boxes(q, A)
    err = (cm.warp_boxes(q, got) - want)[:5, :2] / want[:5, 2:4]
    assert np.sqrt(np.mean(err ** 2)) <= 0.12, err
    assert abs(cm.scale(got) - 1.08) <= 0.025


def test_fit_on_a_still_camera_is_none():
    """Still camera, 2-8 people each stepping at the speed prior with 4 % box noise, 500
    frames: the fit calls the camera still in >= 99 % of them (a group that happens to step
    the same way may pass the 99 % test now and then)."""
    rng = np.random.default_rng(0)
    moved = 0
    for _ in range(500):
        n = int(rng.integers(2, 9))
        q = _boxes(rng, n)
        z = q.copy()
        z[:, :2] += (np.sqrt(SPEED_VAR * q[:, 2] * q[:, 3])[:, None]
                     * rng.standard_normal((n, 2)))
        z[:, :2] += 0.04 * q[:, 2:4] * rng.standard_normal((n, 2))
        z[:, 2:4] *= 1 + 0.04 * rng.standard_normal((n, 2))
        moved += cm.fit(q, z, np.arange(n), 0.075, 0.15, SPEED_VAR) is not None
    assert moved <= 5, moved


def test_transform_helpers():
    """compose / invert / warp_states agree with applying the transforms one by one."""
    A = np.array([[1.1, -0.05, 12.0], [0.05, 1.1, -3.0]])
    B = np.array([[0.95, 0.0, -7.0], [0.0, 0.95, 4.0]])
    p = np.array([[10.0, 20.0], [300.0, -40.0]])
    assert np.allclose(cm.apply(cm.compose(B, A), p), cm.apply(B, cm.apply(A, p)))
    assert np.allclose(cm.apply(cm.invert(A), cm.apply(A, p)), p)
    s = np.array([[10.0, 20.0, 1.0, 2.0, 30.0, 60.0], [5.0, 5.0, np.nan, np.nan, 8.0, 16.0]])
    cm.warp_states(s, A)
    assert np.allclose(s[:, :2], cm.apply(A, np.array([[10.0, 20.0], [5.0, 5.0]])))
    assert np.allclose(s[0, 2:4], A[:, :2] @ [1.0, 2.0])
    assert np.isnan(s[1, 2:4]).all()
    assert np.allclose(s[:, 4:6], np.array([[30.0, 60.0], [8.0, 16.0]]) * cm.scale(A))
    # Chains links the people of the test's own panning scene (the estimator's input): at
    # least half of the 3 people's frame pairs
    ch, n = Chains(), 0
    for k, det in enumerate(_detections(_truth(0, True), 0)):
        b = det.boxes
        n += int((ch.observe(np.c_[b[:, :2] + b[:, 2:] / 2, b[:, 2:]], k) >= 0).sum())
    assert n >= 0.5 * 3 * (SECONDS * FPS - 1), n


def test_gap_rows_follow_the_camera():
    """A person standing still in the world while the camera pans 20 px a frame, missed in
    frame 3: the association (tails moved by ``follow_camera``) keeps one track, and the gap
    row of frame 3 sits where the person is in frame 3's image (x = 100 + 20·3), not where the
    interpolation in frame 4's coordinates puts it (20 px further)."""
    from pfscope.trackers.phd.association import AssocParams, GraphAssociator

    assoc = GraphAssociator(AssocParams(fill_gaps=True, min_length=2, depth=5))
    A = np.array([[1.0, 0.0, 20.0], [0.0, 1.0, 0.0]])
    rows = []
    for k in range(1, 9):
        if k > 1:
            assoc.follow_camera(k, A)
        st = np.zeros((0, 6)) if k == 3 else np.array([[100.0 + 20 * k, 200.0, np.nan,
                                                        np.nan, 40.0, 100.0]])
        rows.extend(assoc.step(k, st).finalised)
    rows.extend(assoc.flush())
    by = {r.frame: r for r in rows}
    assert len(np.unique(np.concatenate([r.ids for r in rows]))) == 1
    assert by[3].filled.all() and len(by[3].ids) == 1
    assert by[3].states[0, 0] == pytest.approx(160.0)



def _frame_pair(rng: np.random.Generator, A: np.ndarray, n: int) -> tuple:
    """Boxes of ``n`` people in frame k−1 and k under the camera motion ``A``, each person
    stepping at the speed prior, 4 % box noise in both frames."""
    q = _boxes(rng, n)
    z = cm.warp_boxes(q, A)
    z[:, :2] += np.sqrt(SPEED_VAR * q[:, 2] * q[:, 3])[:, None] * rng.standard_normal((n, 2))
    for b in (q, z):
        b[:, :2] += 0.04 * b[:, 2:4] * rng.standard_normal((n, 2))
        b[:, 2:4] *= 1 + 0.04 * rng.standard_normal((n, 2))
    return q, z


#: a car driving forward: everything grows 5 % a frame about the image centre
DRIVE = np.array([[1.05, 0.0, -0.05 * W / 2], [0.0, 1.05, -0.05 * H / 2]])


@pytest.mark.parametrize("seed", range(5))
def test_camera_continuity_fills_frames_with_few_links(seed):
    """A camera driving forward (5 % growth a frame), 40 frames at 10 fps; frames alternate
    between 3 linked people and a single one (the others missed).  The per-frame fit needs two
    inlier links, so it calls the single-link frames still; :class:`CameraMotion` (the level of
    the recent frames' motion) gives every frame after the first moving one a motion (measured:
    all of them, from the first frame), and on the single-link frames its scale is within 0.025
    of 1.05 (measured 0.005-0.014, seeds 0-4) -- without the continuity (the per-frame fit
    alone) none has one."""
    rng = np.random.default_rng(seed)
    est, per_frame = cm.CameraMotion(), 0
    single, errs = 0, []
    first = None
    for k in range(40):
        n = 3 if k % 2 == 0 else 1
        q, z = _frame_pair(rng, DRIVE, n)
        A = est.step(q, z, np.arange(n), 0.075, 0.15, SPEED_VAR, FPS * cm.MEMORY_S)
        per_frame += (n == 1) and cm.fit(q, z, np.arange(n), 0.075, 0.15, SPEED_VAR) is not None
        if A is not None and first is None:
            first = k
        if first is not None and n == 1:
            single += 1
            assert A is not None, k
            errs.append(abs(cm.scale(A) - 1.05))
    assert first is not None and first <= 10, first
    assert per_frame == 0
    assert single >= 14 and max(errs) <= 0.025, errs


def test_camera_continuity_on_a_still_camera_stays_still():
    """Still camera, 2-8 people stepping at the speed prior, 500 frames (every second frame a
    single link): :class:`CameraMotion` calls the camera moving in <= 3 % of the frames (the
    per-frame test's rare false alarms open the level for one second at most, and the level
    must itself differ from a still camera; measured: none, with 2-3 per-frame false alarms)."""
    rng = np.random.default_rng(0)
    est, moved = cm.CameraMotion(), 0
    for k in range(500):
        n = int(rng.integers(2, 9)) if k % 2 == 0 else 1
        q, z = _frame_pair(rng, cm.IDENTITY, n)
        moved += est.step(q, z, np.arange(n), 0.075, 0.15, SPEED_VAR,
                          FPS * cm.MEMORY_S) is not None
    assert moved <= 15, moved



def test_camera_continuity_does_not_call_a_walking_group_a_pan():
    """Still camera, 3-6 people all walking the same way at a third of the speed prior's std a
    frame (a group crossing the scene), 300 frames at 10 fps, seeds 0-2: the level, which takes
    the frames as independent, piles up their common velocity into a 'pan'; :class:`CameraMotion`
    opens it only within a second of a frame that passed the per-frame test, so the camera is
    called moving in <= 75 of the 900 frames (measured 50: 7, 33, 10; the per-frame test alone:
    24; without the opening condition: 110)."""
    moved = 0
    for seed in range(3):
        rng = np.random.default_rng(50 + seed)
        est = cm.CameraMotion()
        v = np.sqrt(SPEED_VAR) / 3.0
        for _ in range(300):
            n = int(rng.integers(3, 7))
            q, z = _frame_pair(rng, cm.IDENTITY, n)
            z[:, 0] += v * np.sqrt(z[:, 2] * z[:, 3])
            moved += est.step(q, z, np.arange(n), 0.075, 0.15, SPEED_VAR,
                              FPS * cm.MEMORY_S) is not None
    assert moved <= 75, moved


def _robust_fit_numpy(prev, cur, links, pos_std, size_std, speed_var):
    """The camera fit in its numpy array form (the definition the kernel must reproduce bit
    for bit): (s, t, H, significant) or None."""
    def scale_shift(src, dst, wt):
        w = np.broadcast_to(wt, src.shape)
        sw = w.sum(axis=(-3, -2))
        ps = (w * src).sum(axis=(-3, -2)) / sw
        qs = (w * dst).sum(axis=(-3, -2)) / sw
        dp, dq = src - ps[..., None, None, :], dst - qs[..., None, None, :]
        den = (w * dp * dp).sum(axis=(-3, -2, -1))
        s = np.where(den > 0, (w * dp * dq).sum(axis=(-3, -2, -1)) / np.where(den > 0, den, 1.0),
                     1.0)
        return s, qs - s[..., None] * ps

    def corners(b):
        half = b[:, 2:4] / 2.0
        return np.stack([b[:, :2] - half, b[:, :2] + half], axis=1)

    has = np.flatnonzero(links >= 0)
    if not len(has):
        return None
    q, z = prev[links[has]], cur[has]
    src, dst = corners(q), corners(z)
    size = z[:, None, 2:4]
    wh = z[:, 2] * z[:, 3]
    var = 2.0 * (pos_std ** 2 + size_std ** 2 / 4) + speed_var * wh[:, None, None] / size ** 2
    wt = 1.0 / (var * size ** 2)
    d2_id = np.sum((src - dst) ** 2 * wt, axis=(1, 2))

    def d2(s, t):
        s = np.asarray(s, dtype=np.float64)[..., None, None, None]
        return np.sum((s * src + np.asarray(t)[..., None, None, :] - dst) ** 2 * wt,
                      axis=(-2, -1))

    h = slice(0, cm.MAX_HYPOTHESES)
    sh = np.sqrt(wh[h] / (q[h, 2] * q[h, 3]))
    th = z[h, :2] - sh[:, None] * q[h, :2]
    if len(has) > 1:
        ii, jj = np.triu_indices(len(has), 1)
        k = np.stack([ii[:cm.MAX_HYPOTHESES], jj[:cm.MAX_HYPOTHESES]], axis=1)
        s_ab, t_ab = scale_shift(src[k], dst[k], wt[k])
        sh, th = np.concatenate([sh, s_ab]), np.concatenate([th, t_ab])
    cost = np.minimum(d2(sh, th), cm.INLIER_D2).sum(axis=1)
    best = int(np.argmin(cost))
    inl = d2(sh[best], th[best]) <= cm.INLIER_D2
    if not inl.any():
        return None
    s, t = scale_shift(src[inl], dst[inl], wt[inl])
    s = float(s)
    r = d2(s, t)
    gain = float(np.minimum(d2_id, cm.INLIER_D2).sum() - np.minimum(r, cm.INLIER_D2).sum())
    ok = int((r <= cm.INLIER_D2).sum()) >= cm.MIN_LINKS and gain > cm.LR_MARGIN
    w = np.broadcast_to(wt[inl], src[inl].shape)
    H = np.zeros((3, 3))
    H[0, 0] = float((w * src[inl] * src[inl]).sum())
    H[0, 1:] = H[1:, 0] = (w * src[inl]).sum(axis=(0, 1))
    H[1, 1], H[2, 2] = w.sum(axis=(0, 1))
    return s, np.asarray(t, dtype=np.float64), H, ok


@pytest.mark.parametrize("seed", range(4))
def test_robust_fit_kernel_is_the_numpy_form_bit_for_bit(seed):
    """The one-pass kernel of the camera fit gives the very floats of the array form (the same
    sums in numpy's order: 4-term sums in order, longer ones pairwise), on still and moving
    cameras, outlier links, unlinked detections, and frames of up to 60 links (pairwise sums
    past 128 terms, the hypothesis caps)."""
    rng = np.random.default_rng(seed)
    seen = {"none": 0, "significant": 0, "still": 0}
    for _ in range(300):
        n = int(rng.integers(0, rng.choice([5, 15, 61])))
        npv = int(rng.integers(max(n, 1), n + 5))
        prev = np.column_stack([rng.uniform(0, 800, npv), rng.uniform(0, 600, npv),
                                rng.uniform(10, 60, npv), rng.uniform(30, 150, npv)])
        links = rng.permutation(npv)[:n] if n else np.zeros(0, dtype=np.int64)
        links = np.where(rng.random(n) < rng.uniform(0, 0.5), -1, links)
        s = rng.choice([1.0, rng.uniform(0.9, 1.1)])
        cur = prev[np.maximum(links, 0)].copy()
        cur[:, :2] = (s * cur[:, :2] + rng.normal(0, 10, 2) * rng.integers(0, 2)
                      + rng.normal(0, rng.uniform(0.1, 5), (n, 2)))
        cur[:, 2:4] = s * cur[:, 2:4] * np.exp(rng.normal(0, 0.05, (n, 2)))
        out = rng.random(n) < 0.2
        cur[out, :2] += rng.normal(0, 80, (int(out.sum()), 2))
        args = (rng.uniform(0.02, 0.2), rng.uniform(0.05, 0.3),
                rng.choice([0.0, rng.uniform(0, 0.05)]))
        want = _robust_fit_numpy(prev, cur, links, *args)
        got = cm._robust_fit(prev, cur, links, *args)
        assert (got is None) == (want is None)
        if want is None:
            seen["none"] += 1
            continue
        seen["significant" if want[3] else "still"] += 1
        assert got.s == want[0] and isinstance(got.s, float)
        np.testing.assert_array_equal(got.t, want[1])
        np.testing.assert_array_equal(got.H, want[2])
        assert got.significant == want[3]
    assert min(seen.values()) > 0
