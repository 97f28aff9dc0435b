"""Graph-matching data association (maggio2007 §3, Shafique & Shah 2005): trackers/phd/association.py."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from pfscope.trackers.phd.association import (
    AssocParams,
    GraphAssociator,
    boxes_xywh,
    max_weight_matching,
    propagate,
    score_edges,
    tail_velocity,
)

NAN = np.nan


def brute_force_best_matching(weights: np.ndarray) -> tuple[float, list[tuple[int, int]]]:
    """Best total weight over every matching of a small (T, M) graph; -inf marks a missing edge.

    Enumerates, for each row in turn, "unmatched" or every free column (exponential: tiny graphs
    only).  Returns (best total, one best list of (row, col))."""
    T, M = weights.shape
    best = [0.0, []]

    def rec(r, used, total, pairs):
        if r == T:
            if total > best[0] + 1e-12:
                best[0], best[1] = total, list(pairs)
            return
        rec(r + 1, used, total, pairs)
        for c in range(M):
            if not used[c] and np.isfinite(weights[r, c]):
                used[c] = True
                pairs.append((r, c))
                rec(r + 1, used, total + weights[r, c], pairs)
                pairs.pop()
                used[c] = False

    rec(0, [False] * M, 0.0, [])
    return best[0], best[1]


def state(y1, y2, w=40.0, h=80.0, v1=NAN, v2=NAN):
    return [y1, y2, v1, v2, w, h]


# --------------------------------------------------------------------------- optimality


def test_matching_equals_brute_force_on_random_small_graphs():
    rng = np.random.default_rng(0)
    n_nontrivial = 0
    for _ in range(300):
        T, M = rng.integers(0, 6, size=2)
        w = rng.normal(1.0, 2.0, size=(T, M))  # some negative: never worth taking
        allowed = rng.random((T, M)) < 0.6
        rows, cols = max_weight_matching(w, allowed)
        # a valid matching on allowed edges
        assert len(set(rows.tolist())) == len(rows) and len(set(cols.tolist())) == len(cols)
        assert np.all(allowed[rows, cols])
        bw = np.where(allowed, w, -np.inf)
        best, pairs = brute_force_best_matching(bw)
        assert w[rows, cols].sum() == pytest.approx(best, abs=1e-9)
        n_nontrivial += len(pairs) >= 2
    assert n_nontrivial > 50  # the comparison is not vacuous


def _contested_scene(rng, n_frames=40):
    """Up to 4 targets of size 40x80 crowded into a 60 px square, with missed detections and
    clutter: many tails compete for each new vertex."""
    pos = rng.uniform(0, 60, size=(4, 2))
    vel = rng.normal(0, 1.0, size=(4, 2))
    for k in range(1, n_frames + 1):
        pos = pos + vel
        seen = rng.random(4) < 0.7
        pts = pos[seen] + rng.normal(0, 2.0, size=(seen.sum(), 2))
        if rng.random() < 0.3:
            pts = np.vstack([pts, rng.uniform(0, 60, size=(1, 2))])
        rng.shuffle(pts)
        yield k, np.array([state(x, y) for x, y in pts]).reshape(-1, 6)


def test_each_step_is_the_best_extension_of_the_cover():
    rng = np.random.default_rng(1)
    assoc = GraphAssociator(AssocParams(depth=8))
    contested = 0
    for k, states in _contested_scene(rng):
        r = assoc.step(k, states)
        if len(r.edges_gain) == 0:
            continue
        src = np.unique(r.edges_src_id)
        W = np.full((len(src), len(states)), -np.inf)
        W[np.searchsorted(src, r.edges_src_id), r.edges_dst_index] = r.edges_weight
        assert np.all(r.edges_weight > 0)  # admissible edges all have positive weight
        best, _ = brute_force_best_matching(W)
        assert r.edges_weight[r.chosen].sum() == pytest.approx(best, rel=1e-12, abs=1e-9)
        # a chosen edge continues the source's track id; an unchosen target vertex gets a new id
        assert np.array_equal(r.ids[r.edges_dst_index[r.chosen]], r.edges_src_id[r.chosen])
        contested += (np.bincount(r.edges_dst_index) >= 2).any()
    assert contested >= 10


# --------------------------------------------------------------------------- the density


def _explicit_cov(tail, gap, p, P0):
    """Σ of the observable marginal: F^i P0 F^iᵀ + Σ_{j<i} F^j Q F^jᵀ + R (6-D matrices)."""
    F = np.eye(6)
    F[0, 2] = F[1, 3] = 1.0
    G = np.zeros((6, 4))
    c = p.accel_to_position  # y ← y + v + c·a: piecewise-constant acceleration
    G[0, 0], G[2, 0], G[1, 1], G[3, 1] = c, 1.0, c, 1.0
    G[4, 2] = G[5, 3] = 1.0
    w, h = tail[4], tail[5]
    Qa = np.diag([(p.sigma_v * w) ** 2, (p.sigma_v * h) ** 2, (p.sigma_size * w) ** 2, (p.sigma_size * h) ** 2])
    Q = G @ Qa @ G.T
    S = np.zeros((6, 6))
    Fj = np.eye(6)
    for _ in range(gap):
        S += Fj @ Q @ Fj.T
        Fj = F @ Fj
    Fi = np.linalg.matrix_power(F, gap)
    full = Fi @ P0 @ Fi.T + S
    idx = [0, 1, 4, 5]
    sw, sh = max(p.sigma_obs * w, p.sigma_obs_min), max(p.sigma_obs * h, p.sigma_obs_min)
    R = np.diag([(sw / 2) ** 2, (sh / 2) ** 2, sw ** 2, sh ** 2])
    return full[np.ix_(idx, idx)] + R, R


@pytest.mark.parametrize("c", [0.5, 0.0])
@pytest.mark.parametrize("mode", ["given", "prior", "two"])
@pytest.mark.parametrize("gap", [1, 7, 50])
def test_closed_form_propagation_equals_matrix_sum(mode, gap, c):
    p = AssocParams(accel_to_position=c)
    tail = np.array([100.0, 50.0, 1.5, -0.5, 30.0, 70.0])
    prev = np.array([97.0, 51.5, NAN, NAN, 20.0, 5.0])  # tiny h: σ^z hits its 1 px minimum
    d = 2
    if mode != "given":
        tail[2:4] = NAN
    T = tail[None]
    v, b, c = tail_velocity(T, prev[None], np.array([d if mode == "two" else 0]), p)
    mean, var = propagate(T, v, b, c, np.array([gap]), p)
    # explicit initial covariance of the tail-side error (y1, y2, v1, v2, w, h)
    _, R = _explicit_cov(tail, 1, p, np.zeros((6, 6)))
    Rt = np.diag([R[0, 0], R[1, 1], 0, 0, R[2, 2], R[3, 3]])
    P0 = Rt.copy()
    if mode == "prior":
        P0[2, 2], P0[3, 3] = (p.speed_prior * tail[4]) ** 2, (p.speed_prior * tail[5]) ** 2
        v_exp = np.zeros(2)
    elif mode == "two":
        _, Rp = _explicit_cov(prev, 1, p, np.zeros((6, 6)))
        for a in range(2):  # v̂ = (y_t − y_p)/Δ: cov(y_t, v̂) = σ_t²/Δ, var v̂ = (σ_t² + σ_p²)/Δ²
            P0[2 + a, 2 + a] = (R[a, a] + Rp[a, a]) / d ** 2
            P0[a, 2 + a] = P0[2 + a, a] = R[a, a] / d
        v_exp = (tail[:2] - prev[:2]) / d
    else:
        v_exp = tail[2:4]
    cov, _ = _explicit_cov(tail, gap, p, P0)
    assert np.allclose(np.diag(var[0]), cov, rtol=1e-12, atol=1e-9)  # diagonal: no cross terms
    assert np.allclose(mean[0], [*(tail[:2] + gap * v_exp), tail[4], tail[5]])
    # the gain is the log of that Gaussian density at the new vertex
    new = np.array([[tail[0] + 5, tail[1] - 3, NAN, NAN, 33.0, 66.0]])
    sc = score_edges(T, v, b, c, np.array([gap]), new, p)
    expect = multivariate_normal(mean[0], cov).logpdf(new[0, [0, 1, 4, 5]])
    assert sc.gain[0, 0] == pytest.approx(expect, rel=1e-10)
    # weight = gain − log-density at the gate of the gap-K edge of the same tail
    covK, _ = _explicit_cov(tail, p.depth, p, P0)
    floor = -0.5 * p.gate_d2 - 0.5 * np.linalg.slogdet(2 * np.pi * covK)[1]
    assert sc.weight[0, 0] == pytest.approx(expect - floor, rel=1e-10)


# --------------------------------------------------------------------------- gaps and ids


def _two_targets(n_frames, hidden, velocity_known, rng):
    """Target A moves right and is hidden on the frames in ``hidden``; target B is far away."""
    for k in range(1, n_frames + 1):
        rows = []
        a = np.array([50.0 + 1.0 * k, 100.0 + 0.5 * k])
        if k not in hidden:
            rows.append(state(*(a + rng.normal(0, 1.0, 2)), 40, 80,
                              *((1.0, 0.5) if velocity_known else (NAN, NAN))))
        b = np.array([600.0 - 0.8 * k, 400.0])
        rows.append(state(*(b + rng.normal(0, 1.0, 2)), 30, 60, *((-0.8, 0) if velocity_known else (NAN, NAN))))
        yield k, np.array(rows)


@pytest.mark.parametrize("velocity_known", [True, False], ids=["phd-centres", "mt-detections"])
@pytest.mark.parametrize("gap, recovered", [(31, True), (50, True), (51, False)])
def test_id_survives_a_gap_up_to_K_frames(velocity_known, gap, recovered):
    K = 50
    last_seen = 12
    hidden = set(range(last_seen + 1, last_seen + gap))  # reappears at last_seen + gap
    assoc = GraphAssociator(AssocParams(depth=K))
    rng = np.random.default_rng(3)
    ids_a, ended = {}, {}
    for k, states in _two_targets(last_seen + gap + 8, hidden, velocity_known, rng):
        r = assoc.step(k, states)
        if k not in hidden:
            ids_a[k] = int(r.ids[0])
        ended[k] = r.ended.tolist()
    before = ids_a[last_seen]
    after = ids_a[last_seen + gap]
    assert len({ids_a[k] for k in ids_a if k <= last_seen}) == 1
    assert len({ids_a[k] for k in ids_a if k >= last_seen + gap}) == 1
    if recovered:
        assert after == before
        assert all(before not in e for e in ended.values())
    else:
        assert after != before and after > before  # a new id, never a reused one
        assert ended[last_seen + K + 1] == [before]  # the tail fell out of the window


def test_a_dormant_tail_does_not_steal_an_active_track():
    """A stands still and is lost at frame 10; B walks through A's place. At frame 13 B's
    detection fits A's (gap-3) prediction *better* than B's own (gap-1) one in Mahalanobis terms,
    but the likelihood log f keeps B's identity (the log-determinant favours the short gap)."""
    p = AssocParams()
    assoc = GraphAssociator(p)
    rA = np.array([127.0, 100.0])
    for k in range(1, 11):
        xb = 100.0 + 2.0 * k
        r = assoc.step(k, np.array([state(*rA, 40, 80, 0, 0), state(xb, 100.0, 40, 80, 2.0, 0.0)]))
    id_a, id_b = r.ids
    for k in (11, 12):
        r = assoc.step(k, np.array([state(100.0 + 2.0 * k, 100.0, 40, 80, 2.0, 0.0)]))
        assert r.ids.tolist() == [id_b]
    det = np.array([state(127.5, 100.0, 40, 80, 2.0, 0.0)])  # B predicted at 126, A stands at 127
    tails = assoc.live_tracks()
    v, b, c = tail_velocity(tails.tail_states, tails.tail_states, np.zeros(len(tails.ids), int), p)
    sc = score_edges(tails.tail_states, v, b, c, 13 - tails.tail_frames, det, p)
    ia, ib = np.searchsorted(tails.ids, [id_a, id_b])
    assert sc.allowed[ia, 0] and sc.allowed[ib, 0]
    assert sc.d2[ia, 0] < sc.d2[ib, 0]  # the contest is real
    r = assoc.step(13, det)
    assert r.ids.tolist() == [id_b]


def test_short_tracks_are_not_reported():
    p = AssocParams(min_length=5)
    assoc = GraphAssociator(p)
    lags, zero_lag = [], []
    for k in range(1, 13):
        rows = []
        if k <= 4:  # A: 4 vertices only
            rows.append(state(100.0 + k, 100.0))
        if 3 <= k <= 7:  # B: exactly 5 vertices
            rows.append(state(400.0, 300.0 + k))
        r = assoc.step(k, np.array(rows).reshape(-1, 6))
        zero_lag += [(k, i) for i, cf in zip(r.ids, r.confirmed) if cf]
        lags += [(f.frame, int(i)) for f in r.finalised for i in f.ids]
        for f in r.finalised:
            assert f.frame == k - assoc.lag
            assert f.boxes.shape == (len(f.ids), 4)
    lags += [(f.frame, int(i)) for f in assoc.flush() for i in f.ids]
    assert zero_lag == [(7, 2)]  # only B, from its 5th vertex on
    assert lags == [(k, 2) for k in range(3, 8)]  # bounded lag: all of B, nothing of A
    assert assoc.n_buffered_frames == 0


def test_ids_start_at_one_increase_and_are_never_reused():
    assoc = GraphAssociator(AssocParams(depth=5))
    seen = []
    for k in range(1, 40):
        rows = [state(100.0, 100.0)] if (k <= 8 or k >= 20) else []  # same place, gap 12 > K
        if k % 3 == 0:
            rows.append(state(500.0 + 60 * k, 50.0))  # one-off vertices, each a new track
        r = assoc.step(k, np.array(rows).reshape(-1, 6))
        seen += [int(i) for i in r.ids if int(i) not in seen]
    assert seen[0] == 1
    assert seen == sorted(seen) and len(set(seen)) == len(seen)
    assert seen == list(range(1, len(seen) + 1))


def test_same_input_same_output():
    def run():
        assoc = GraphAssociator(AssocParams(depth=8))
        out = []
        for k, states in _contested_scene(np.random.default_rng(7), 30):
            # a duplicated vertex: an exact tie that must still be broken the same way
            states = np.vstack([states, states[:1]]) if len(states) else states
            r = assoc.step(k, states)
            out.append((r.ids.copy(), r.edges_src_id.copy(), r.edges_dst_index.copy(),
                        r.edges_weight.copy(), r.chosen.copy()))
        return out

    a, b = run(), run()
    for x, y in zip(a, b):
        for u, w in zip(x, y):
            assert np.array_equal(u, w)


def test_memory_stays_bounded_over_a_long_run():
    K, max_m = 20, 6
    assoc = GraphAssociator(AssocParams(depth=K))
    rng = np.random.default_rng(5)
    sizes = []
    for k in range(1, 401):
        n = min(rng.poisson(3), max_m)
        pts = rng.uniform([0, 0], [2000, 2000], size=(n, 2))  # clutter: mostly new tracks
        r = assoc.step(k, np.array([state(x, y, 20, 40) for x, y in pts]).reshape(-1, 6))
        tails = assoc.live_tracks()
        assert np.all(k - tails.tail_frames <= K)  # vertices older than K frames are forgotten
        assert assoc.n_buffered_frames <= assoc.lag
        sizes.append(assoc.n_live)
    assert max(sizes) <= K * max_m
    assert max(sizes[200:]) <= max(sizes[:200]) + max_m  # no growth with the length of the run
    assert r.ids.max(initial=0) > 5 * K * max_m / 4  # many tracks were created and ended


def test_edges_report_the_tails_before_the_update():
    assoc = GraphAssociator()
    s1 = np.array([state(100.0, 100.0), state(300.0, 100.0)])
    assoc.step(1, s1)
    s2 = s1 + [1.0, 0, 0, 0, 0, 0]
    r = assoc.step(3, s2)
    assert r.chosen.sum() == 2
    ch = r.chosen
    assert np.array_equal(r.edges_src[ch], s1[r.edges_dst_index[ch]], equal_nan=True)
    assert np.all(r.edges_gap == 2)
    assert np.allclose(boxes_xywh(s1), [[80, 60, 40, 80], [280, 60, 40, 80]])


@pytest.mark.parametrize("frame, states, msg", [
    (1, np.zeros((2, 4)), "shape"),
    (1, [state(1, 2, w=0.0)], "positive"),
    (1, [state(NAN, 2)], "non-finite"),
    (1, [state(1, 2), state(1, 2, h=np.inf)], "non-finite"),
    (1, [state(1, 2), state(1, 2, h=-5.0)], "positive"),
    (1, [state(1, 2, w=0.0), state(1, 2, w=NAN)], "non-finite"),   # the finite test first
])
@pytest.mark.parametrize("edges", [True, False])
def test_bad_input_is_rejected(frame, states, msg, edges):
    """... on both paths (edges=False: the fast path's kernel checks the values), before
    anything changes: the same frame then steps as on a fresh associator."""
    assoc = GraphAssociator()
    assoc.step(0, [state(1, 2)], edges=edges)
    with pytest.raises(ValueError, match=msg):
        assoc.step(frame, states, edges=edges)
    fresh = GraphAssociator()
    fresh.step(0, [state(1, 2)], edges=edges)
    a, b = (x.step(frame, [state(1, 2)], edges=edges) for x in (assoc, fresh))
    assert a.ids.tolist() == b.ids.tolist() == [1]
    assert a.lengths.tolist() == b.lengths.tolist() == [2]


def test_frames_must_increase():
    assoc = GraphAssociator()
    assoc.step(5, [state(1, 2)])
    with pytest.raises(ValueError, match="frame 5"):
        assoc.step(5, [state(1, 2)])


def test_lagged_rows_survive_a_frame_jump_that_ends_their_track():
    """Frames 1-5 then frame 100 (> K later): the track ends at that step, and its buffered rows
    (frames 2-5) are still finalised as confirmed."""
    assoc = GraphAssociator()
    rows = []
    for k in range(1, 6):
        rows += [(f.frame, i) for f in assoc.step(k, [state(100.0 + k, 100.0)]).finalised for i in f.ids]
    r = assoc.step(100, [state(500.0, 500.0)])
    assert r.ended.tolist() == [1]
    rows += [(f.frame, int(i)) for f in r.finalised for i in f.ids]
    assert rows == [(k, 1) for k in range(1, 6)]
    assert [f.frame for f in assoc.flush()] == [100]


# --------------------------------------------------------------------------- re-linking


from pfscope.trackers.phd.appearance import (DIM as APP_DIM, AppearanceModel, box_features,  # noqa: E402
                                             similarity)
from pfscope.trackers.phd.association import propagate_damped, score_relinks  # noqa: E402


def test_damped_propagation_is_the_cv_model_early_and_a_random_walk_late():
    p = AssocParams(relink_tau=20.0, sigma_obs=0.0, sigma_obs_min=1e-6)
    tail = np.array([state(100.0, 100.0, 40, 80, 2.0, 1.0)])
    z = np.zeros((1, 2))
    gaps = np.array([[2.0, 3.0, 400.0, 800.0]])
    m_cv, v_cv = propagate(tail, tail[:, 2:4], z, z, gaps, p)
    m_d, v_d = propagate_damped(tail, tail[:, 2:4], z, z, gaps, p)
    # i << tau: the same mean and (up to the discretisation of the acceleration) variance
    assert np.allclose(m_d[0, :2], m_cv[0, :2], rtol=1e-2)
    assert np.allclose(v_d[0, :2, :2], v_cv[0, :2, :2], rtol=0.1)  # i³/3 vs i(4i²−1)/12
    # i >> tau: the mean stops at y + v tau, the variance doubles with the gap (CV: x8)
    assert np.allclose(m_d[0, 3, :2], [100 + 2.0 * 20, 100 + 1.0 * 20], atol=1e-6)
    assert 1.9 < v_d[0, 3, 0] / v_d[0, 2, 0] < 2.1
    assert v_cv[0, 3, 0] / v_cv[0, 2, 0] > 7.5


def _hide_and_return(assoc, hidden, n_frames, jump=0.0, area=None):
    """Target A walks right (1.5 px/frame) and is hidden on ``hidden``; it comes back shifted
    by ``jump`` px; target B stays far away.  Returns A's id per frame (from the finalised
    rows and the flush, as the tracks file has them) and the re-link pairs."""
    assoc.area = area
    rows, pairs = {}, []
    for k in range(1, n_frames + 1):
        st = [state(900.0, 500.0, 30, 60, 0.0, 0.0)]
        if k not in hidden:
            x = 50.0 + 1.5 * k + (jump if k > max(hidden) else 0.0)
            st.insert(0, state(x, 100.0, 40, 80, 1.5, 0.0))
        r = assoc.step(k, np.array(st))
        pairs += r.relinked.tolist()
        for fr in r.finalised:
            rows[fr.frame] = fr
    for fr in assoc.flush():
        rows[fr.frame] = fr
    ids_a = {f: int(fr.ids[np.argmin(fr.states[:, 0])]) for f, fr in rows.items()
             if len(fr.ids) and fr.states[:, 0].min() < 600 and not fr.filled.all()}
    return ids_a, pairs


@pytest.mark.parametrize("relink_depth, jump, area, same", [
    (0, 0.0, None, False),        # off (paper): a gap longer than K gives a new id
    (60, 0.0, None, True),        # on: the new track takes the ended one's id
    (60, 0.0, 1280 * 720, True),  # scored against a new target anywhere in the image
    (60, 300.0, None, False),     # comes back far from the prediction: outside the gate
    (60, 200.0, None, True),      # in the gate (3.1 std): linked when only the gate counts
    (60, 200.0, 1280 * 720, False),  # ... but no likelier than a new target in the image
])
def test_a_track_ended_by_a_long_gap_is_relinked(relink_depth, jump, area, same):
    K, last_seen, gap = 10, 15, 25
    hidden = set(range(last_seen + 1, last_seen + gap))
    assoc = GraphAssociator(AssocParams(depth=K, min_length=3, relink_depth=relink_depth,
                                        relink_tau=30.0))
    ids_a, pairs = _hide_and_return(assoc, hidden, last_seen + gap + 10, jump, area)
    before = {ids_a[k] for k in ids_a if k <= last_seen}
    after = {ids_a[k] for k in ids_a if k >= last_seen + gap}
    assert len(before) == 1 and len(after) == 1  # every reported row of the new track renamed
    assert (before == after) == same
    if same:
        assert len(pairs) == 1 and pairs[0][1] == before.pop()
    else:
        assert pairs == []


def test_relinked_gap_is_filled_only_inside_the_buffer():
    K, last_seen, gap = 10, 15, 8  # gap <= K: an ordinary edge, for comparison below
    p = AssocParams(depth=K, min_length=3, relink_depth=40, relink_tau=30.0, fill_gaps=True)
    hidden = set(range(last_seen + 1, last_seen + 14))  # 13 missed frames > K: a re-link
    assoc = GraphAssociator(p)
    assoc.step  # noqa: B018
    rows = {}
    for k in range(1, 40):
        st = [] if k in hidden else [state(50.0 + 1.5 * k, 100.0, 40, 80, 1.5, 0.0)]
        r = assoc.step(k, np.array(st).reshape(-1, 6))
        for fr in r.finalised:
            rows[fr.frame] = fr
    for fr in assoc.flush():
        rows[fr.frame] = fr
    ids = {int(i) for fr in rows.values() for i in fr.ids}
    assert len(ids) == 1
    filled = sorted(f for f, fr in rows.items() if fr.filled.any())
    # filled frames lie strictly inside the gap, and each on the line between the two ends
    assert filled and all(last_seen < f < last_seen + 14 for f in filled)
    for f in filled:
        assert abs(rows[f].states[0, 0] - (50.0 + 1.5 * f)) < 1e-6


def test_two_targets_lost_while_crossing_get_their_own_ids_back():
    """A walks right, B left on a parallel line; both are missed for 20 frames around the
    crossing (K = 8).  Re-linking uses the velocity: each new track takes its own old id."""
    p = AssocParams(depth=8, min_length=3, relink_depth=40, relink_tau=60.0)
    assoc = GraphAssociator(p)
    assoc.area = 640.0 * 480.0
    hidden = set(range(21, 41))  # they pass each other at frame 35
    ids = {"A": {}, "B": {}}
    for k in range(1, 55):
        if k in hidden:
            st = np.zeros((0, 6))
        else:
            st = np.array([state(100.0 + 4 * k, 200.0, 30, 70, 4.0, 0.0),
                           state(380.0 - 4 * k, 215.0, 30, 70, -4.0, 0.0)])
        r = assoc.step(k, st)
        for i, x, ok in zip(r.ids.tolist(), r.states[:, 2].tolist(), r.confirmed.tolist()):
            if ok:  # as reported (the new tracks are renamed when confirmed)
                ids["A" if x > 0 else "B"][k] = i
    for name in "AB":
        assert len(set(ids[name].values())) == 1, ids[name]
        assert max(ids[name]) > 41  # seen again after the gap
    assert ids["A"][20] != ids["B"][20]


def test_relink_scores_prefer_the_fitting_track():
    p = AssocParams(relink_depth=50, relink_tau=20.0)
    lost = np.array([state(100.0, 100.0, 40, 80, 2.0, 0.0), state(300.0, 100.0, 40, 80, -2.0, 0.0)])
    z = np.zeros((2, 2))
    first = np.array([state(128.0, 100.0, 40, 80, 2.0, 0.0)])
    sc = score_relinks(lost, lost[:, 2:4], z, z, np.array([10, 10]), first, np.array([30]), p,
                       area=640 * 480)
    assert sc.allowed[0, 0] and sc.weight[0, 0] > 0
    assert not (sc.allowed[1, 0] and sc.weight[1, 0] > sc.weight[0, 0])
    # a new track that began before the ended one's last estimate cannot continue it
    sc = score_relinks(lost, lost[:, 2:4], z, z, np.array([10, 10]), first, np.array([10]), p)
    assert not sc.allowed.any()


@pytest.mark.parametrize("bad, msg", [({"relink_depth": -1}, "relink_depth"),
                                      ({"relink_depth": 2.5}, "relink_depth"),
                                      ({"relink_tau": 0.0}, "relink_tau"),
                                      ({"app_weight": -1.0}, "app_weight"),
                                      ({"app_alpha": 0.0}, "app_alpha")])
def test_bad_relink_and_appearance_params_are_rejected(bad, msg):
    with pytest.raises(ValueError, match=msg):
        AssocParams(**bad)


# --------------------------------------------------------------------------- appearance


def _image_with(boxes_colours, h=240, w=320):
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = (40, 160, 40)  # green background
    for (cx, cy, bw, bh), col in boxes_colours:
        img[int(cy - bh / 2):int(cy + bh / 2), int(cx - bw / 2):int(cx + bw / 2)] = col
    return img


def test_box_features_tell_colours_apart():
    red, blue = (20, 20, 220), (220, 30, 20)
    img = _image_with([((60, 100, 30, 70), red), ((200, 100, 30, 70), blue)])
    f = box_features(img, np.array([[60, 100, 30, 70], [200, 100, 30, 70], [62, 101, 28, 66],
                                    [-100, -100, 20, 20]], float))
    assert f.shape == (4, APP_DIM)
    rho = similarity(f, f)
    assert rho[0, 2] > 0.99 and rho[0, 1] < 0.05
    assert np.isnan(f[3]).all() and np.isnan(rho[3]).all()  # outside the image: unknown
    # the states layout (N, 6) is read the same way
    st = np.array([state(60.0, 100.0, 30, 70, 0.0, 0.0)])
    assert np.allclose(box_features(img, st), f[:1])


def test_appearance_model_learns_what_similarity_means():
    m = AppearanceModel()
    prior = m.llr(np.array([0.9, 0.5]))
    rng = np.random.default_rng(0)
    for _ in range(200):
        m.observe_same(rng.uniform(0.95, 1.0, 3))
        feats = np.eye(4).repeat(APP_DIM // 4, axis=1) / (APP_DIM // 4) * 2  # disjoint colours
        m.observe_different(feats)
    assert m.mu_same < 0.05 < 0.5 < m.mu_diff
    post = m.llr(np.array([0.98, 0.5, np.nan]))
    assert post[0] > 0 > post[1] and post[2] == 0.0
    assert post[1] < prior[1]  # the learnt model is more sure a poor match is another target
    assert m.llr(np.array([0.0])).item() == -AppearanceModel.LLR_CLIP
    # a model of few crops says less, either way
    few, many = m.llr(np.array([0.98, 0.5]), n=1.0), m.llr(np.array([0.98, 0.5]), n=100.0)
    assert np.all(np.abs(few) < np.abs(many)) and np.all(np.sign(few) == np.sign(many))


def test_appearance_keeps_identities_through_an_ambiguous_swap():
    """Red and blue stand side by side (16 px apart), are missed for 4 frames and come back
    swapped. By motion alone the ids follow the places; with the colours they follow the
    people."""
    red = np.zeros(APP_DIM)
    red[:APP_DIM // 2:7] = 1.0
    blue = np.zeros(APP_DIM)
    blue[3:APP_DIM // 2:7] = 1.0
    red[APP_DIM // 2:] = red[:APP_DIM // 2]
    blue[APP_DIM // 2:] = blue[:APP_DIM // 2]
    red /= red[:APP_DIM // 2].sum()
    blue /= blue[:APP_DIM // 2].sum()

    def run(app_weight):
        assoc = GraphAssociator(AssocParams(depth=10, min_length=2, app_weight=app_weight))
        out = []
        for k in range(1, 25):
            if 11 <= k <= 14:
                r = assoc.step(k, np.zeros((0, 6)), np.zeros((0, APP_DIM)))
                continue
            pos = (100.0, 116.0) if k <= 10 else (116.0, 100.0)  # red first, then swapped
            st = np.array([state(pos[0], 100.0, 40, 80, 0.0, 0.0),
                           state(pos[1], 100.0, 40, 80, 0.0, 0.0)])
            r = assoc.step(k, st, np.stack([red, blue]))
            out.append((k, r.ids.tolist()))
        return dict(out)

    off, on = run(0.0), run(3.0)
    assert off[10] == on[10]
    assert off[15] == off[10][::-1]  # motion: the places keep their ids (a swap of people)
    assert on[15] == on[10] and on[24] == on[10]  # colours: each person keeps its id


def test_a_duplicate_born_next_to_a_track_does_not_take_it_over(monkeypatch):
    """The PHD's peaks sometimes split one target in two for a frame.  The new track born on
    the duplicate has a colour model of one crop, as good a match to the next crop as the
    established track's; its evidence counts n / (n + MODEL_N0), so the established track keeps
    the target although the duplicate sits exactly where the next estimate comes."""
    red = np.zeros(APP_DIM)
    red[::5] = 1.0
    red[:APP_DIM // 2] /= red[:APP_DIM // 2].sum()
    red[APP_DIM // 2:] /= red[APP_DIM // 2:].sum()
    other = np.roll(red, 2)

    def run():
        assoc = GraphAssociator(AssocParams(depth=10, min_length=2, app_weight=2.0))
        for k in range(1, 21):  # one red target standing still, a differently dressed one far off
            r = assoc.step(k, np.array([state(100.0, 100.0, 40, 80, 0.0, 0.0),
                                        state(250.0, 100.0, 40, 80, 0.0, 0.0)]),
                           np.stack([red, other]))
        a = int(r.ids[0])
        r = assoc.step(21, np.array([state(100.0, 100.0, 40, 80, 0.0, 0.0),
                                     state(104.0, 100.0, 40, 80, 0.0, 0.0),
                                     state(250.0, 100.0, 40, 80, 0.0, 0.0)]),
                       np.stack([red, red, other]))
        dup = int(r.ids[1])
        assert dup != a
        r = assoc.step(22, np.array([state(104.0, 100.0, 40, 80, 0.0, 0.0),
                                     state(250.0, 100.0, 40, 80, 0.0, 0.0)]),
                       np.stack([red, other]))
        return a, dup, int(r.ids[0])

    a, dup, got = run()
    assert got == a
    monkeypatch.setattr(AppearanceModel, "MODEL_N0", 0.0)  # no shrinkage: the contest is real
    a, dup, got = run()
    assert got == dup


# --------------------------------------------------------------------------- storms: gated pairs

def test_gated_pairs_score_exactly_the_gated_edges():
    """score_edge_pairs (a k-d tree on the vertices, then the gate) lists the pairs that
    score_edges allows, with the same floats."""
    from pfscope.trackers.phd.association import score_edge_pairs

    rng = np.random.default_rng(3)
    p = AssocParams(depth=8)
    T, M = 300, 400
    tails = np.array([state(x, y, w, 2.5 * w, *(v if k % 3 else (NAN, NAN)))
                      for k, (x, y, w, v) in enumerate(zip(rng.uniform(0, 800, T),
                                                           rng.uniform(0, 600, T),
                                                           rng.uniform(10, 60, T),
                                                           rng.normal(0, 2, (T, 2))))])
    prev = tails + rng.normal(0, 3, tails.shape)
    v, b, c = tail_velocity(tails, prev, rng.integers(0, 3, T), p)
    gaps = rng.integers(1, 8, T)
    new = np.array([state(x, y, w, 2.5 * w) for x, y, w in
                    zip(rng.uniform(0, 800, M), rng.uniform(0, 600, M), rng.uniform(10, 60, M))])
    dense = score_edges(tails, v, b, c, gaps, new, p)
    pairs = score_edge_pairs(tails, v, b, c, gaps, new, p)
    er, ec = np.nonzero(dense.allowed)
    assert len(er) > 50                                  # the test has gated pairs to compare
    np.testing.assert_array_equal(pairs.rows, er)
    np.testing.assert_array_equal(pairs.cols, ec)
    np.testing.assert_array_equal(pairs.d2, dense.d2[er, ec])
    np.testing.assert_array_equal(pairs.gain, dense.gain[er, ec])
    np.testing.assert_array_equal(pairs.weight, dense.weight[er, ec])


def test_sparse_matching_finds_the_dense_optimum():
    from pfscope.trackers.phd.association import sparse_max_weight_matching

    rng = np.random.default_rng(5)
    for _ in range(200):
        T, M = rng.integers(1, 30, 2)
        w = rng.normal(0, 1, (T, M))
        allowed = rng.random((T, M)) < rng.uniform(0.05, 0.7)
        r1, c1 = max_weight_matching(w, allowed)
        er, ec = np.nonzero(allowed)
        r2, c2 = sparse_max_weight_matching(er, ec, w[er, ec])
        assert len(set(r2.tolist())) == len(r2) and len(set(c2.tolist())) == len(c2)
        assert np.all(allowed[r2, c2]) and np.all(w[r2, c2] > 0) and np.all(np.diff(r2) > 0)
        assert w[r2, c2].sum() == pytest.approx(w[r1, c1].sum(), abs=1e-9)


def test_the_sparse_association_of_a_storm_is_the_dense_one(monkeypatch):
    """Above DENSE_MAX_PAIRS pairs a frame is scored on its gated pairs and matched on that
    sparse graph: the same ids, edges and weights as the dense arrays (forced here on every
    frame of a contested scene)."""
    from pfscope.trackers.phd import association as A

    def run():
        assoc = GraphAssociator(AssocParams(depth=8))
        out = []
        for k, states in _contested_scene(np.random.default_rng(11), 40):
            r = assoc.step(k, states)
            out.append((r.ids.copy(), r.edges_src_id.copy(), r.edges_dst_index.copy(),
                        r.edges_weight.copy(), r.edges_gain.copy(), r.chosen.copy(),
                        r.edges_src.copy()))
        return out

    dense = run()
    monkeypatch.setattr(A, "DENSE_MAX_PAIRS", 0)
    sparse = run()
    assert sum(len(x[1]) for x in dense) > 100
    for x, y in zip(dense, sparse):
        for u, w in zip(x, y):
            np.testing.assert_array_equal(u, w)


def test_pair_similarities_are_the_matrix_entries():
    """The storm path's colour similarities (pairs only) equal the dense matrix's entries,
    unknown halves and unknown features included."""
    from pfscope.trackers.phd.appearance import similarity, similarity_pairs

    rng = np.random.default_rng(2)
    a, b = rng.random((12, APP_DIM)), rng.random((9, APP_DIM))
    a[3, : APP_DIM // 2] = np.nan                         # one half unknown
    b[5] = np.nan                                          # no colour at all
    rows, cols = np.nonzero(rng.random((12, 9)) < 0.5)
    dense = similarity(a, b)[rows, cols]
    pairs = similarity_pairs(a, b, rows, cols)
    assert np.isnan(pairs).sum() == np.isnan(dense).sum() > 0
    np.testing.assert_allclose(pairs, dense, rtol=1e-13, atol=0)


def _gap_rows(support: float, evidence: bool, free: int = 0) -> dict:
    """One target walking right, its estimates missing in frames 11-16 (a gap of 7, K = 10);
    with ``evidence`` the frames inside the gap have a detection on the target (the filter
    missed it), else only a false detection far away.  Returns frame → FinalRows."""
    p = AssocParams(depth=10, min_length=3, fill_gaps=True, extend_heads=True,
                    fill_support=support, fill_free=free)
    assoc = GraphAssociator(p)
    rows = {}
    for k in range(1, 30):
        x = 50.0 + 3.0 * k
        hidden = 11 <= k <= 16
        st = np.zeros((0, 6)) if hidden else np.array([state(x, 100.0, 40, 80, 3.0, 0.0)])
        dets = [[500.0, 400.0, 40.0, 80.0]]
        if evidence or not hidden:
            dets.append([x + 2.0, 101.0, 40.0, 80.0])
        r = assoc.step(k, st, detections=np.array(dets))
        for fr in r.finalised:
            rows[fr.frame] = fr
    for fr in assoc.flush():
        rows[fr.frame] = fr
    assert {int(i) for fr in rows.values() for i in fr.ids} == {1}  # one track across the gap
    return rows


def test_gap_is_filled_only_with_evidence_on_its_path():
    """fill_support: a gap whose interpolated path has detections on it is filled; the same
    gap across empty image is linked but not filled; fill_support = 0 fills both, and so does
    fill_free when the gap (6 missing frames) is no longer than it."""
    inside = set(range(11, 17))
    for support, evidence, free, filled in ((0.25, True, 0, True), (0.25, False, 0, False),
                                            (0.0, False, 0, True), (0.25, False, 5, False),
                                            (0.25, False, 6, True)):
        rows = _gap_rows(support, evidence, free)
        got = {f for f, fr in rows.items() if fr.filled.any()}
        assert got == (inside if filled else set()), (support, evidence, got)


def _head_rows(head_skip: int) -> set:
    """One target walking right, detected in frames 1-24 except 5 and 6 (two misses in a row),
    its estimates starting only at frame 10 (the frames PHD-MT's mass takes to reach T), and a
    false detection far away every frame.  Returns the frames the track has a row in."""
    p = AssocParams(depth=10, min_length=3, fill_gaps=True, extend_heads=True,
                    head_skip=head_skip)
    assoc = GraphAssociator(p)
    got = set()
    for k in range(1, 25):
        x = 50.0 + 3.0 * k
        st = np.array([state(x, 100.0, 40, 80, 3.0, 0.0)]) if k >= 10 else np.zeros((0, 6))
        dets = [[500.0, 400.0, 40.0, 80.0]]
        if k not in (5, 6):
            dets.append([x + 1.0, 101.0, 40.0, 80.0])
        r = assoc.step(k, st, detections=np.array(dets))
        got |= {fr.frame for fr in r.finalised if len(fr.ids)}
    got |= {fr.frame for fr in assoc.flush() if len(fr.ids)}
    return got


def test_track_heads_cross_as_many_missed_frames_as_head_skip():
    """extend_heads walks back from a track's first estimate through the detections; a frame
    without one stops it unless head_skip allows crossing it: two misses in a row stop the
    walk at head_skip 0 and 1, and head_skip 2 (practical's) crosses them and walks on as far
    as the held-back frames go (the report lag, depth = 10: frames 2-11 when the track is
    confirmed at frame 12)."""
    late = set(range(10, 25))
    assert _head_rows(0) == late | {7, 8, 9}
    assert _head_rows(1) == late | {7, 8, 9}
    assert _head_rows(2) == late | {2, 3, 4, 7, 8, 9}


def test_without_edge_arrays_the_tracks_are_the_same():
    """``step(..., edges=False)`` (a caller that does not show the edges) leaves the edge
    arrays empty and changes nothing else: the same ids, lengths and bounded-lag rows, gap
    filling with its evidence test included."""
    def run(edges):
        assoc = GraphAssociator(AssocParams(depth=8, fill_gaps=True, fill_support=0.25,
                                            fill_free=1))
        out, n_edges = [], 0
        for k, states in _contested_scene(np.random.default_rng(5), 60):
            r = assoc.step(k, states, edges=edges)
            n_edges += len(r.edges_src_id) + len(r.chosen) + len(r.edges_src)
            out.append((r.ids.copy(), r.lengths.copy(), r.confirmed.copy())
                       + tuple(x for f in r.finalised for x in (f.ids, f.states, f.filled)))
        out.append(tuple(x for f in assoc.flush() for x in (f.ids, f.states, f.filled)))
        return out, n_edges

    with_edges, n = run(True)
    without, n0 = run(False)
    assert n > 100 and n0 == 0
    assert any(f.any() for x in with_edges[:-1] for f in x[5::3])     # some gaps were filled
    for x, y in zip(with_edges, without, strict=True):
        for u, w in zip(x, y, strict=True):
            np.testing.assert_array_equal(u, w)


# --------------------------------------------------------------------------- one-pass kernels

def _random_tails(rng, T):
    """Tails with known, unknown (NaN) velocities, one- and two-vertex tracks."""
    tails = np.array([state(x, y, w, 2.5 * w, *(v if k % 3 else (NAN, NAN)))
                      for k, (x, y, w, v) in enumerate(zip(rng.uniform(0, 300, T),
                                                           rng.uniform(0, 200, T),
                                                           rng.uniform(3, 60, T),
                                                           rng.normal(0, 2, (T, 2))))])
    tails[1::5, 3] = NAN                       # one unknown component: unknown velocity
    prev = tails + rng.normal(0, 3, tails.shape)
    tail_frame = rng.integers(20, 40, T)
    prev_frame = np.where(rng.random(T) < 0.3, -1, tail_frame - rng.integers(1, 4, T))
    return tails, prev, tail_frame.astype(np.int64), prev_frame.astype(np.int64)


def test_frame_edges_kernel_is_the_numpy_spelling():
    """The step's one-pass kernel (tail velocity, edge scores, admissible weights) gives the
    same floats as tail_velocity + score_edges, and the same matching as
    max_weight_matching on them."""
    from pfscope.trackers.phd import _assoc_kernels as AK
    from pfscope.trackers.phd.association import OBS_INDEX, _match_admissible

    rng = np.random.default_rng(5)
    p = AssocParams(depth=30)
    for T, M in ((40, 30), (7, 9), (1, 1)):
        tails, prev, tf, pf = _random_tails(rng, T)
        frame = 41
        new = np.array([state(x, y, w, 2.5 * w) for x, y, w in
                        zip(rng.uniform(0, 300, M), rng.uniform(0, 200, M),
                            rng.uniform(3, 60, M))])
        v, b, c = tail_velocity(tails, prev, np.where(pf >= 0, tf - pf, 0), p)
        sc = score_edges(tails, v, b, c, frame - tf, new, p)
        gain, d2, weight, floor, w0, n_ok, one = AK.frame_edges(
            tails, prev, tf, pf, frame, np.ascontiguousarray(new[:, OBS_INDEX]),
            *p.kernel_args, float(p.speed_prior))
        for got, want in ((gain, sc.gain), (d2, sc.d2), (weight, sc.weight), (floor, sc.floor)):
            np.testing.assert_array_equal(got, want)
        ok = sc.allowed & np.isfinite(sc.weight) & (sc.weight > 0)
        np.testing.assert_array_equal(w0, np.where(ok, sc.weight, 0.0))
        assert n_ok == ok.sum()
        if T > 1:
            assert 0 < n_ok < T * M            # both kinds of pairs are compared
        for got, want in zip(_match_admissible(w0, n_ok, one),
                             max_weight_matching(sc.weight, sc.allowed)):
            np.testing.assert_array_equal(got, want)


def test_frame_edges_one_edge_each_matches_without_the_solver():
    """frame_edges' ``one`` (no tail, no vertex with two admissible edges) is exactly that,
    and the matching it allows (every admissible edge, in row order, no assignment solver)
    is max_weight_matching's, dtypes included -- on scenes of separated targets (one edge
    each, some tails and vertices without any) and of crowded ones (shared edges)."""
    from pfscope.trackers.phd import _assoc_kernels as AK
    from pfscope.trackers.phd.association import OBS_INDEX, _match_admissible

    rng = np.random.default_rng(8)
    p = AssocParams(depth=30)
    seen = set()
    for n in range(300):
        T = int(rng.integers(1, 8))
        spread = 60.0 if n % 2 else 1000.0        # crowded / separated
        tails = np.array([state(x, y, 20.0, 50.0, vx, vy) for x, y, vx, vy in
                          zip(*rng.uniform(0, spread, (2, T)), *rng.normal(0, 1, (2, T)))])
        prev = tails.copy()
        prev[:, :2] -= tails[:, 2:4]
        tf = np.full(T, 40, np.int64)
        pf = np.full(T, 39, np.int64)
        pick = rng.permutation(T)[:int(rng.integers(0, T + 1))]
        new = tails[pick].copy()
        new[:, :2] += tails[pick, 2:4] + rng.normal(0, 1.0, (len(pick), 2))
        clutter = [state(x, y, 20.0, 50.0) for x, y in
                   rng.uniform(0, spread, (int(rng.integers(0, 3)), 2))]
        new = np.concatenate([new.reshape(-1, 6), np.array(clutter).reshape(-1, 6)])
        if not len(new):
            continue
        gain, d2, weight, floor, w0, n_ok, one = AK.frame_edges(
            tails, prev, tf, pf, 41, np.ascontiguousarray(new[:, OBS_INDEX]),
            *p.kernel_args, float(p.speed_prior))
        ok = w0 > 0
        assert one == (ok.sum(axis=1).max() <= 1 and ok.sum(axis=0).max() <= 1)
        got = _match_admissible(w0, n_ok, one)
        want = max_weight_matching(weight, d2 <= p.gate_d2)
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)
            assert g.dtype == w.dtype == np.int64
        seen.add((bool(one), n_ok > 0, n_ok < T))
    assert {(True, True, True), (False, True, True)} <= seen, seen


def _returning_numpy(a: GraphAssociator, frame: int, Z: np.ndarray) -> np.ndarray:
    """GraphAssociator.returning spelt with numpy (tail_velocity + score_edges)."""
    p = a.params
    lost = ((a._length >= p.min_length) & (frame - a._tail_frame >= 2)
            & (frame - a._tail_frame <= p.depth))
    lost &= a._length >= p.revive_rate * (a._tail_frame - a._first_frame + 1)
    if not lost.any() or not len(Z):
        return np.zeros(len(Z), dtype=bool)
    prev_gap = np.where(a._prev_frame[lost] >= 0, a._tail_frame[lost] - a._prev_frame[lost], 0)
    v, b, c = tail_velocity(a._tail[lost], a._prev[lost], prev_gap, p)
    sc = score_edges(a._tail[lost], v, b, c, frame - a._tail_frame[lost],
                     np.concatenate([Z[:, :2], np.zeros((len(Z), 2)), Z[:, 2:]], axis=1), p)
    return sc.allowed.any(axis=0)


def test_returning_is_the_numpy_spelling():
    """returning (one kernel pass): the detections inside the gate of a confirmed tail unseen
    in the frame before, with estimates in at least revive_rate of its frames -- the same
    mask as tail_velocity + score_edges on the selected tails."""
    rng = np.random.default_rng(11)
    p = AssocParams(depth=30, min_length=3, revive_rate=0.8)
    a = GraphAssociator(p)
    T = 60
    tails, prev, tf, pf = _random_tails(rng, T)
    tails[:, :2] *= 10.0                                  # spread over the detections' image
    prev[:, :2] = tails[:, :2] + rng.normal(0, 3, (T, 2))
    a._ids = np.arange(1, T + 1)
    a._tail, a._prev, a._tail_frame, a._prev_frame = tails, prev, tf, pf
    a._length = rng.integers(1, 8, T)
    a._first_frame = tf - rng.integers(0, 9, T)
    frame = 42
    Z = np.column_stack([rng.uniform(0, 3000, 200), rng.uniform(0, 2000, 200),
                         rng.uniform(3, 60, 200)])
    Z = np.column_stack([Z, 2.5 * Z[:, 2]])
    got = a.returning(frame, Z)
    want = _returning_numpy(a, frame, Z)
    assert got.dtype == bool and 5 < want.sum() < len(Z)     # both kinds of detections
    np.testing.assert_array_equal(got, want)
    # each condition on the tail matters: with all tails short, none is lost
    a._length = np.full(T, p.min_length - 1)
    assert not a.returning(frame, Z).any()
    assert not a.returning(frame, Z[:0]).size


def test_returning_skip_after_a_step_is_exact():
    """After a step in which every track of min_length vertices got an estimate, returning
    answers without its kernel (advance's ``unseen``): along a run with missed estimates its
    mask is the numpy spelling's at every frame, both ways taken, hits included; a smaller
    min_length set between the steps (the frame rate learnt) is not answered from the flag."""
    rng = np.random.default_rng(12)
    p = AssocParams(depth=5, min_length=3, revive_rate=0.5)
    a = GraphAssociator(p)
    xs = np.array([50.0, 250.0, 450.0, 650.0])
    seen = set()
    for frame in range(1, 80):
        pos = xs + 2.0 * frame
        Z = np.column_stack([pos + rng.normal(0, 1, 4), np.full(4, 100.0),
                             np.full(4, 30.0), np.full(4, 75.0)])
        skipped = not a._unseen[0]
        got = a.returning(frame, Z)
        np.testing.assert_array_equal(got, _returning_numpy(a, frame, Z))
        seen.add(("skipped" if skipped else "kernel", bool(got.any())))
        # or_none (the tracker's): None exactly where the answer needs no kernel
        alt = a.returning(frame, Z, or_none=True)
        if alt is None:
            assert (skipped or not len(a._ids)) and not got.any()
        else:
            np.testing.assert_array_equal(alt, got)
        seen.add(("none", alt is None))
        hit = rng.random(4) < 0.8
        a.step(frame, np.array([state(x, 100.0, 30.0, 75.0) for x in pos[hit]]).reshape(-1, 6),
               edges=False)
    assert {("skipped", False), ("kernel", True), ("none", True), ("none", False)} <= seen, seen
    # a fifth target seen twice (below min_length), then missed while the four are seen:
    # the flag says no confirmed track is unseen ... which a shorter min_length undoes
    for frame in (80, 81, 82):
        pos = np.append(xs + 2.0 * frame, 900.0)[:4 if frame == 82 else 5]
        a.step(frame, np.array([state(x, 100.0, 30.0, 75.0) for x in pos]), edges=False)
    assert not a._unseen[0]
    a.params = dataclasses.replace(p, min_length=2)
    Z = np.array([[900.0, 100.0, 30.0, 75.0]])
    assert a.returning(83, Z).all()
    np.testing.assert_array_equal(a.returning(83, Z), _returning_numpy(a, 83, Z))


def test_buffer_frames_are_the_held_back_frames():
    """Gap filling reads the held-back frames as an array: an arange when the frame numbers
    are consecutive, the buffer's own numbers when some were skipped (a frame jump)."""
    for frames in (range(1, 30), [1, 2, 3, 5, 8, 9, 10, 14, 20, 21, 22, 23, 30, 31, 40, 41]):
        a = GraphAssociator(AssocParams(depth=5, fill_gaps=True))
        for k in frames:
            a.step(k, [state(10.0 + k, 20.0)])
            got = a._buffer_frames()
            assert got.dtype == np.int64
            np.testing.assert_array_equal(got, [b[0] for b in a._buffer])


def test_gap_rows_kernel_is_the_numpy_spelling():
    """Gap filling's rows (one kernel pass): every (buffered frame, edge) pair with the frame
    strictly inside the edge's gap, frame-major, the interpolated states and the fill_err
    test -- the same pairs and floats as the numpy spelling."""
    from pfscope.trackers.phd import _assoc_kernels as AK
    from pfscope.trackers.phd.association import OBS_INDEX, interpolation_std

    rng = np.random.default_rng(2)
    E = 9
    src = np.array([state(x, y, w, 2.5 * w, *v) for x, y, w, v in
                    zip(rng.uniform(0, 300, E), rng.uniform(0, 200, E), rng.uniform(3, 60, E),
                        rng.normal(0, 2, (E, 2)))])
    dst = src + rng.normal(0, 5, src.shape)
    src_frame = rng.integers(0, 30, E)
    frame = src_frame + rng.integers(1, 12, E)
    bf = np.arange(1, 60, 2)
    at, fi, ei, st, likely, run, n_far, n_unlikely = AK.gap_rows(bf, 0, 0, src, src_frame, dst,
                                                                 frame, 0.05, 0.1, 4.0)
    # the buffered frames given as a count from the first (consecutive), and one end frame
    # for every edge as one element: the same as the arrays spelt out
    for k0, B, fr in ((7, 20, frame), (3, 25, frame[:1]), (1, 1, np.array([40]))):
        a = AK.gap_rows(np.arange(k0, k0 + B), 0, 0, src, src_frame, dst,
                        np.broadcast_to(fr, frame.shape).copy(), 0.05, 0.1, 4.0)
        b = AK.gap_rows(bf[:0], k0, B, src, src_frame, dst, fr, 0.05, 0.1, 4.0)
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
        assert len(a[2])
    inside = (src_frame[None, :] < bf[:, None]) & (bf[:, None] < frame[None, :])
    np.testing.assert_array_equal(at, np.flatnonzero(inside.any(axis=1)))
    assert len(at) < len(bf)                               # frames without a pair left out
    fs = bf[at]
    want_fi, want_ei = np.nonzero(inside[at])
    np.testing.assert_array_equal(fi, want_fi)
    np.testing.assert_array_equal(ei, want_ei)
    np.testing.assert_array_equal(run, np.searchsorted(fi, np.arange(len(fs) + 1)))
    gap = frame - src_frame
    t = ((fs[fi] - src_frame[ei]) / gap[ei])[:, None]
    want = np.full((len(ei), 6), np.nan)
    want[:, OBS_INDEX] = (1.0 - t) * src[ei][:, OBS_INDEX] + t * dst[ei][:, OBS_INDEX]
    want[:, 2:4] = ((dst[:, [0, 1]] - src[:, [0, 1]]) / gap[:, None])[ei]
    np.testing.assert_array_equal(st, want)
    std = interpolation_std(0.05, fs[fi] - src_frame[ei], gap[ei])
    np.testing.assert_array_equal(likely, std <= 0.1)
    assert 0 < likely.sum() < len(likely)                  # both kinds of rows
    # the counts: edges missing more than fill_free frames (every edge), rows not likely
    assert n_far == np.count_nonzero(gap - 1 > 4.0) and 0 < n_far < E
    assert n_unlikely == np.count_nonzero(~likely)


def test_head_pick_kernel_is_the_numpy_spelling():
    """extend_heads' walk back, one frame (one kernel pass): the detection nearest the
    prediction, none another row of the frame covers, inside the gate -- np.argmin's pick
    on the numpy spelling of the distances and the overlap test."""
    from pfscope.trackers.phd import _assoc_kernels as AK
    from pfscope.trackers.phd.association import OBS_INDEX, _iou

    rng = np.random.default_rng(4)
    seen = set()
    for _ in range(300):
        N, B = rng.integers(0, 6), rng.integers(0, 4)
        d = np.column_stack([rng.uniform(0, 100, (N, 2)), rng.uniform(10, 30, (N, 2))])
        pred = np.array([50.0, 50.0, 20.0, 20.0]) + rng.normal(0, 5, 4)
        var = rng.uniform(20, 200, 4)
        rows = np.array([state(x, y, w, h) for x, y, w, h in
                         np.column_stack([rng.uniform(0, 100, (B, 2)),
                                          rng.uniform(10, 30, (B, 2))])]).reshape(-1, 6)
        d2 = np.sum((d - pred) ** 2 / var, axis=1)
        if B and N:
            d2[_iou(d, rows[:, OBS_INDEX]).max(axis=1) >= 0.3] = np.inf
        j = int(np.argmin(d2)) if N else -1
        want = j if j >= 0 and d2[j] <= 9.0 else -1
        got = AK.head_pick(d, pred, var, rows, 0.3, 9.0)
        assert got == want
        seen.add("none" if want < 0 else "pick")
        if B and N and np.isinf(d2).any() and want >= 0:
            seen.add("covered skipped")
    assert seen == {"none", "pick", "covered skipped"}


def _confirmed_numpy(all_ids, all_len, ids, min_length, extra_ids=None, extra_len=None):
    if extra_ids is not None and len(extra_ids):
        all_ids = np.concatenate([all_ids, extra_ids])
        all_len = np.concatenate([all_len, extra_len])
        order = np.argsort(all_ids, kind="stable")
        all_ids, all_len = all_ids[order], all_len[order]
    if len(ids) == 0 or len(all_ids) == 0:
        return np.zeros(len(ids), dtype=bool)
    pos = np.clip(np.searchsorted(all_ids, ids), 0, len(all_ids) - 1)
    return (all_ids[pos] == ids) & (all_len[pos] >= min_length)


def test_confirmed_rows_kernel_is_the_numpy_spelling():
    """The confirmed test of held-back rows (one kernel pass): live tracks first, then the
    tracks ended this frame (an id in both -- a re-linked track took a just-ended id -- is
    the live one), unknown ids not confirmed."""
    rng = np.random.default_rng(8)
    a = GraphAssociator(AssocParams(min_length=4))
    for _ in range(200):
        live = np.unique(rng.integers(1, 40, rng.integers(0, 12)))
        a._ids, a._length = live, rng.integers(1, 8, len(live))
        extra = rng.choice(np.arange(1, 50), rng.integers(0, 6), replace=False)
        elen = rng.integers(1, 8, len(extra))
        ids = rng.integers(0, 52, rng.integers(0, 15))
        for e, el in ((None, None), (extra, elen)):
            got = a._confirmed_ids(ids, e, el)
            want = _confirmed_numpy(live, a._length, ids, 4, e, el)
            np.testing.assert_array_equal(got, want)
    dup = GraphAssociator(AssocParams(min_length=4))
    dup._ids, dup._length = np.array([3, 7]), np.array([9, 1])
    assert dup._confirmed_ids(np.array([7, 3, 5]), np.array([7, 5]),
                              np.array([9, 9])).tolist() == [False, True, True]


def test_fill_rows_kernel_is_the_numpy_spelling():
    """Gap filling's rows of one buffered frame (one kernel pass): the frame's arrays with the
    kept gap rows that no estimate of the frame covers appended, flagged filled -- as the
    mask + uncovered + np.concatenate spelling, dtypes included; nothing added leaves them."""
    from pfscope.trackers.phd import _assoc_kernels as AK

    rng = np.random.default_rng(9)
    seen = set()
    for _ in range(300):
        R, B = int(rng.integers(1, 6)), int(rng.integers(0, 5))
        box = lambda n: np.column_stack([rng.uniform(0, 100, (n, 2)),
                                         rng.uniform(10, 30, (n, 2))])
        st = np.array([state(*b) for b in box(R)]).reshape(-1, 6)
        fid = rng.integers(1, 50, R).astype(np.int64)
        bst = np.array([state(*b) for b in box(B)]).reshape(-1, 6)
        bid = rng.integers(1, 50, B).astype(np.int64)
        bfill = rng.random(B) < 0.4
        lo = int(rng.integers(0, R))
        hi = int(rng.integers(lo + 1, R + 1))
        keep = rng.random(R) < 0.7 if rng.random() < 0.5 else np.zeros(0, dtype=bool)
        sel = np.arange(lo, hi)
        if len(keep):
            sel = sel[keep[lo:hi]]
        rows, rid = st[sel], fid[sel]
        free = AK.uncovered(rows, bst, bfill, 0.3)
        rows, rid = rows[free], rid[free]
        nbid, nbst, nbfill, n = AK.fill_rows(bid, bst, bfill, st, fid, lo, hi, keep, 0.3)
        assert n == len(rows)
        for got, want in ((nbid, np.concatenate([bid, rid])), (nbst, np.concatenate([bst, rows])),
                          (nbfill, np.concatenate([bfill, np.ones(len(rows), dtype=bool)]))):
            np.testing.assert_array_equal(got, want)
            assert got.dtype == want.dtype
        seen.add((n > 0, n < hi - lo, len(keep) > 0))
    assert {(True, True, True), (True, True, False), (False, True, True),
            (True, False, False)} <= seen, seen


def test_uncovered_kernel_is_the_numpy_spelling():
    """Gap filling's overlap test (one kernel pass): a gap row is kept unless an estimate of
    its frame (not a filled row) overlaps it by fill_overlap IoU or more."""
    from pfscope.trackers.phd import _assoc_kernels as AK
    from pfscope.trackers.phd.association import OBS_INDEX, _iou

    rng = np.random.default_rng(6)
    seen = set()
    for _ in range(200):
        R, B = rng.integers(1, 5), rng.integers(0, 5)
        box = lambda n: np.column_stack([rng.uniform(0, 100, (n, 2)),
                                         rng.uniform(10, 30, (n, 2))])
        rows = np.array([state(*b) for b in box(R)]).reshape(-1, 6)
        bst = np.array([state(*b) for b in box(B)]).reshape(-1, 6)
        bfill = rng.random(B) < 0.4
        est = bst[~bfill]
        want = (_iou(rows[:, OBS_INDEX], est[:, OBS_INDEX]).max(axis=1) < 0.3 if len(est)
                else np.ones(R, dtype=bool))
        got = AK.uncovered(rows, bst, bfill, 0.3)
        np.testing.assert_array_equal(got, want)
        seen.update(want.tolist())
        if len(est) and bfill.any():
            seen.add("filled rows ignored")
    assert seen == {True, False, "filled rows ignored"}


def _walker_frames(rng, n_frames, n_targets, spread):
    """Estimates (M, 6) per frame of walkers that cross (shared edges), vanish for a while
    (gaps, expiries, re-links) and come with clutter; velocities known on some frames."""
    pos = rng.uniform(0, spread, (n_targets, 2))
    vel = rng.normal(0, 2.0, (n_targets, 2))
    size = rng.uniform(15, 40, n_targets)
    away = np.zeros(n_targets, np.int64)
    out = []
    for k in range(n_frames):
        pos += vel
        away = np.where((away == 0) & (rng.random(n_targets) < 0.04),
                        rng.integers(1, 12, n_targets), np.maximum(away - 1, 0))
        seen = (away == 0) & (rng.random(n_targets) < 0.85)
        rows = [state(x + rng.normal(0, 1), y + rng.normal(0, 1), w, 2.5 * w,
                      *((vx, vy) if k % 3 else (NAN, NAN)))
                for (x, y), (vx, vy), w in zip(pos[seen], vel[seen], size[seen])]
        rows += [state(x, y, w, 2.5 * w) for x, y, w in
                 zip(*rng.uniform(0, spread, (2, int(rng.poisson(1.0)))),
                     rng.uniform(15, 40, 5))]
        out.append(np.array(rows).reshape(-1, 6))
    return out


def test_step_fast_path_is_the_general_one():
    """A step without colour features or edge arrays (one kernel pass: frame_step, the
    solver between two calls when the matching is not a set of stars) gives what the
    general path (the solver on every shared edge) gives
    (edges=True): the ids, lengths, confirmations, ended and re-linked tracks and finalised
    rows of every frame -- on scenes with crossings (the solver), gaps, expiries, re-links,
    gap filling and extended heads."""
    from pfscope.trackers.phd import _assoc_kernels as AK

    calls = []
    orig = AK.frame_step

    def spy(*a):
        out = orig(*a)
        calls.append(int(out[1][0]))      # (w0, [status, ...])
        return out

    rng = np.random.default_rng(11)
    stars = 0
    for depth, spread, settings in ((4, 120.0, {}),
                                    (6, 300.0, dict(fill_gaps=True, extend_heads=True,
                                                    head_skip=1, relink_depth=30,
                                                    fill_support=0.25, fill_err=0.2)),
                                    (3, 80.0, dict(fill_gaps=True, relink_depth=10))):
        p = AssocParams(depth=depth, min_length=3, **settings)
        fast, slow = GraphAssociator(p), GraphAssociator(p)
        fast.area = slow.area = 640.0 * 480.0
        AK.frame_step = spy
        try:
            for k, s in enumerate(_walker_frames(rng, 150, 6, spread), start=1):
                det = s[:, [0, 1, 4, 5]] + 0.5
                n0 = len(calls)
                a = fast.step(k, s, detections=det, edges=False)
                b = slow.step(k, s, detections=det, edges=True)
                ok = b.edges_weight > 0
                shared = (np.bincount(b.edges_src_id[ok]).max(initial=0) > 1
                          or np.bincount(b.edges_dst_index[ok]).max(initial=0) > 1)
                if shared and calls[n0:] == [0]:
                    stars += 1      # some tail or vertex with two edges: no solver
                for name in ("ids", "lengths", "confirmed", "ended", "relinked"):
                    np.testing.assert_array_equal(getattr(a, name), getattr(b, name), name)
                assert [r.frame for r in a.finalised] == [r.frame for r in b.finalised]
                for ra, rb in zip(a.finalised, b.finalised):
                    for name in ("ids", "states", "filled"):
                        np.testing.assert_array_equal(getattr(ra, name), getattr(rb, name))
                assert fast._unseen == slow._unseen
                np.testing.assert_array_equal(fast._ids, slow._ids)
                np.testing.assert_array_equal(fast._tail, slow._tail)
                np.testing.assert_array_equal(fast._lost_ids, slow._lost_ids)
        finally:
            AK.frame_step = orig
        for ra, rb in zip(fast.flush(), slow.flush()):
            np.testing.assert_array_equal(ra.ids, rb.ids)
            np.testing.assert_array_equal(ra.states, rb.states)
    # every way out of the kernel was taken: done (stars too), the solver, an expiring tail
    assert {0, 1, 2} <= set(calls) and stars > 10, (set(calls), stars)


def test_output_kernels_are_the_numpy_spelling():
    """The step's output kernels give numpy's floats: final_rows (the confirmed rows of a
    held-back frame, their top-left boxes and conf), track_boxes (the confirmed tracks' top-left boxes), row_boxes (a
    finalised frame's boxes and conf) and centre_boxes (xywh_to_cxcywh)."""
    from pfscope.trackers.phd import _assoc_kernels as AK
    from pfscope.trackers.types import xywh_to_cxcywh

    rng = np.random.default_rng(3)
    for n in (0, 1, 7):
        st = rng.uniform(1, 300, (n, 6))
        ids = rng.permutation(20)[:n].astype(np.int64)
        keep = rng.random(n) < 0.5
        live = np.sort(rng.permutation(20)[:10]).astype(np.int64)
        live_len = rng.integers(1, 6, 10).astype(np.int64)
        extra = np.setdiff1d(np.arange(20), live)[:4].astype(np.int64)
        extra_len = rng.integers(1, 6, len(extra)).astype(np.int64)
        ok = AK.confirmed(live, live_len, extra, extra_len, ids, 3)
        got = AK.final_rows(live, live_len, extra, extra_len, ids, st, keep, 3, 0.5, 1.0)
        assert len(got) == 5
        for g, w in zip(got, (ids[ok], st[ok], keep[ok], boxes_xywh(st[ok]).reshape(-1, 4),
                              np.where(keep[ok], 0.5, 1.0))):
            np.testing.assert_array_equal(g, w)
            assert g.dtype == w.dtype
        tid, tb = AK.track_boxes(ids, st, keep)
        np.testing.assert_array_equal(tid, ids[keep])
        np.testing.assert_array_equal(tb, boxes_xywh(st[keep]).reshape(-1, 4))
        rb, conf = AK.row_boxes(st, keep, 0.5, 1.0)
        np.testing.assert_array_equal(rb, boxes_xywh(st).reshape(-1, 4))
        np.testing.assert_array_equal(conf, np.where(keep, 0.5, 1.0))
        b = st[:, :4]
        np.testing.assert_array_equal(AK.centre_boxes(np.ascontiguousarray(b)),
                                      xywh_to_cxcywh(b))


def test_general_step_advances_with_one_kernel_specialisation(monkeypatch):
    """The general path hands the track advance C-contiguous matched pairs whatever layout the
    matching returns (a strided view would compile a second specialisation of
    ``_assoc_kernels.advance`` in the middle of a run: ~0.35 s on one frame of a DBN-PHD
    run): the kernel sees only 'C' arrays."""
    import pfscope.trackers.phd.association as A
    from pfscope.trackers.phd import _assoc_kernels as AK

    seen = []
    orig_match, orig_adv = A._match_admissible, AK.advance

    def strided(*a):
        r, c = orig_match(*a)
        return np.repeat(r, 2)[::2], np.repeat(c, 2)[::2]      # same values, stride 2

    def spy(*a):
        seen.append(all(x.flags.c_contiguous for x in a[7:9]))
        return orig_adv(*a)

    monkeypatch.setattr(A, "_match_admissible", strided)
    monkeypatch.setattr(AK, "advance", spy)
    rng = np.random.default_rng(5)
    g = GraphAssociator(AssocParams(depth=4, min_length=3))
    g.area = 640.0 * 480.0
    for k, s in enumerate(_walker_frames(rng, 20, 4, 120.0), start=1):
        g.step(k, s, detections=s[:, [0, 1, 4, 5]], edges=True)
    assert len(seen) == 20 and all(seen), seen


def test_group_pick_is_the_solvers_matching():
    """The fast path's matching of small groups that are not stars (_group_pick: every
    matching of each connected group enumerated) is the assignment solver's
    (_match_admissible) whenever it answers; ties and near-ties (within float rounding of
    the solver) are left to the solver, as are groups with too many matchings."""
    from pfscope.trackers.phd import _assoc_kernels as AK
    from pfscope.trackers.phd.association import _match_admissible

    rng = np.random.default_rng(5)
    answered = declined = 0
    for trial in range(3000):
        T, M = rng.integers(1, 7, 2)
        w0 = np.where(rng.random((T, M)) < rng.uniform(0.2, 0.7),
                      rng.uniform(0.01, 20.0, (T, M)), 0.0)
        kind = trial % 4
        nz = np.flatnonzero(w0)
        if kind == 1 and len(nz) > 1:      # an exact tie between two edges
            a, b = rng.choice(nz, 2, replace=False)
            w0.flat[b] = w0.flat[a]
        elif kind == 2 and len(nz) > 1:    # a near-tie (within rounding)
            a, b = rng.choice(nz, 2, replace=False)
            w0.flat[b] = w0.flat[a] * (1.0 + 1e-14)
        elif kind == 3 and T >= 2 and M >= 2:   # two sums equal: w00 + w11 == w01 + w10
            w0[:2, :2] = [[1.0, 2.0], [3.0, 4.0]]
        rdeg = np.count_nonzero(w0, axis=1).astype(np.int64)
        pick = AK._group_pick(w0, rdeg)
        if not len(pick):
            declined += 1
            continue
        answered += 1
        rows, cols = _match_admissible(w0, int(np.count_nonzero(w0)))
        want = np.full(T, -1)
        want[rows] = cols
        np.testing.assert_array_equal(pick, want, f"trial {trial}")
    assert answered > 1500 and declined > 100, (answered, declined)
    # a tie the solver decides: two matchings of equal weight
    w0 = np.array([[1.0, 2.0], [3.0, 4.0]])
    assert len(AK._group_pick(w0, np.array([2, 2]))) == 0
    # more matchings than GROUP_MAX_MATCHINGS: the solver
    w0 = np.ones((7, 7)) + np.arange(49).reshape(7, 7) * 1e-3
    assert len(AK._group_pick(w0, np.full(7, 7))) == 0


@pytest.mark.parametrize("seed", range(3))
def test_gap_fill_last_is_gap_rows_then_fill_rows(seed):
    """Gap filling's one-call frame (gap_fill_last): with every row in the last buffered frame,
    no edge longer than fill_free and every row likely, the last frame's rows are gap_rows'
    rows appended by fill_rows (ids[ei], no mask, the overlap test), array for array; with
    rows in another frame, a long edge or an unlikely row it hands back to the general path
    (status −1, the frame's arrays as given), with no row at all it says so (status 0)."""
    from pfscope.trackers.phd import _assoc_kernels as AK

    rng = np.random.default_rng(seed)
    seen = {0: 0, 1: 0, -1: 0}
    for _ in range(600):
        n_buf = int(rng.integers(1, 6))
        f0 = int(rng.integers(1, 50))
        frame = f0 + n_buf                       # the step's frame, after the buffered ones
        E = int(rng.integers(1, 5))
        src_frame = frame - rng.integers(1, 6, E)
        src = np.column_stack([rng.uniform(0, 300, (E, 2)), rng.normal(0, 2, (E, 2)),
                               rng.uniform(10, 60, (E, 2))])
        dst = src + rng.normal(0, 5, src.shape)
        ids = rng.permutation(100)[:E].astype(np.int64)
        B = int(rng.integers(0, 5))
        bid = rng.integers(100, 200, B).astype(np.int64)
        bst = np.column_stack([rng.uniform(0, 300, (B, 2)), rng.normal(0, 2, (B, 2)),
                               rng.uniform(10, 60, (B, 2))])
        if B and rng.random() < 0.5:
            bst[0] = src[0]                      # an estimate over a gap row: not filled
        bfill = rng.random(B) < 0.3
        fr = np.array([frame], dtype=np.int64)
        if rng.random() < 0.3:
            # per-edge end frames (a re-link's gaps), some inside the buffer: rows then in
            # earlier frames only
            fr = f0 + rng.integers(1, n_buf + 1, E)
            src_frame = fr - rng.integers(1, 4, E)
        sigma_v, fill_err = float(rng.choice([0.0, 0.05, 2.0])), 1 / 6
        fill_free, thr = float(rng.choice([1.0, 2.0, 8.0])), 0.5
        args = (np.zeros(0, dtype=np.int64), f0, n_buf, src, src_frame, dst, fr, sigma_v,
                fill_err, fill_free)
        status, nid, nst, nfill, added = AK.gap_fill_last(*args, ids, bid, bst, bfill, thr)
        at, fi, ei, st, likely, run, n_far, n_unlikely = AK.gap_rows(*args)
        seen[status] += 1
        if not len(ei):
            assert status == 0
        elif n_far or n_unlikely or len(at) != 1 or at[0] != n_buf - 1:
            assert status == -1 and nid is bid and nst is bst and nfill is bfill
        else:
            assert status == 1
            want = AK.fill_rows(bid, bst, bfill, st, ids[ei], 0, len(ei),
                                np.zeros(0, dtype=bool), thr)
            for got, w in zip((nid, nst, nfill, added), want):
                np.testing.assert_array_equal(got, w)
    assert min(seen.values()) >= 20, seen
