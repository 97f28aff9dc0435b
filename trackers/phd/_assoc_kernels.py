"""The association's edge scores as one numba kernel (:func:`edge_scores`): the dense
(tails × new vertices) gains of :func:`.association.score_edges`, which numpy spelt as some forty
small array operations a frame -- most of the association's time with a few targets.  Same
floats as the numpy spelling: the same operations in the same order (a sum over the four
observable components is numpy's, left to right)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _var4(tail, t, b0, b1, c0, c1, i, sv, ss, so, so_min, ratio, cc, cc2, out):
    """Variances of the four observable components of tail t's prediction ``i`` frames on
    (:func:`.association.propagate`) into ``out`` (4,); ``b0, b1, c0, c1`` its error growth
    (:func:`.association.tail_velocity`)."""
    for k in range(2):
        s = so * tail[t, 4 + k]
        if not (s >= so_min or s != s):
            s = so_min
        r_y = (ratio * s) * (ratio * s)
        r_wh = s * s
        a = sv * tail[t, 4 + k]
        s2 = (i - 1.0) * i * (2.0 * i - 1.0) / 6.0 + cc * i * (i - 1.0) + cc2 * i
        bk = b0 if k == 0 else b1
        ck = c0 if k == 0 else c1
        out[k] = a * a * s2 + r_y + bk * i + ck * (i * i) + r_y
        g = ss * tail[t, 4 + k]
        out[2 + k] = g * g * i + 2.0 * r_wh


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _tail_gauss(tail, t, v0, v1, b0, b1, c0, c1, i, depth, gate_d2, sv, ss, so, so_min, ratio,
                cc, cc2, two_pi, var, lg):
    """Tail t's predicted Gaussian ``i`` frames on: ``floor`` (the gain at the gate's edge
    ``depth`` frames on), ``log_det`` and the mean ``m0..m3``; ``var`` (4,) left holding the
    variances at ``i`` (``lg`` (4,): scratch).  Shared by :func:`_tail_row` and
    :func:`_tail_w0`."""
    _var4(tail, t, b0, b1, c0, c1, depth, sv, ss, so, so_min, ratio, cc, cc2, var)
    for k in range(4):
        lg[k] = math.log(two_pi * var[k])
    floor = -0.5 * gate_d2 - 0.5 * (((lg[0] + lg[1]) + lg[2]) + lg[3])
    _var4(tail, t, b0, b1, c0, c1, i, sv, ss, so, so_min, ratio, cc, cc2, var)
    for k in range(4):
        lg[k] = math.log(two_pi * var[k])
    log_det = ((lg[0] + lg[1]) + lg[2]) + lg[3]
    m0 = tail[t, 0] + i * v0
    m1 = tail[t, 1] + i * v1
    m2 = tail[t, 4]
    m3 = tail[t, 5]
    return floor, log_det, m0, m1, m2, m3


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True, inline="always")
def _d2_diag(a0, a1, a2, a3, m0, m1, m2, m3, var):
    """The squared Mahalanobis distance of ``(a0..a3)`` from ``(m0..m3)`` under the diagonal
    variances ``var`` (4,), summed in that order: the one spelling for every gate test and edge
    score of the association."""
    r0 = a0 - m0
    r1 = a1 - m1
    r2 = a2 - m2
    r3 = a3 - m3
    return ((r0 * r0 / var[0] + r1 * r1 / var[1]) + r2 * r2 / var[2]) + r3 * r3 / var[3]


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _tail_row(tail, t, v0, v1, b0, b1, c0, c1, i, z, depth, gate_d2, sv, ss, so, so_min,
              ratio, cc, cc2, two_pi, var, lg, gain, d2, weight):
    """Tail t's row of :func:`edge_scores` (velocity ``v0, v1``, error growth ``b0, b1, c0,
    c1``, gap ``i`` frames) into ``gain``, ``d2``, ``weight`` (T, M); returns its floor (the
    gain at the gate's edge ``depth`` frames on).  ``var``, ``lg`` (4,): scratch."""
    floor, log_det, m0, m1, m2, m3 = _tail_gauss(tail, t, v0, v1, b0, b1, c0, c1, i, depth,
                                                 gate_d2, sv, ss, so, so_min, ratio, cc, cc2,
                                                 two_pi, var, lg)
    for j in range(z.shape[0]):
        d = _d2_diag(z[j, 0], z[j, 1], z[j, 2], z[j, 3], m0, m1, m2, m3, var)
        d2[t, j] = d
        gn = -0.5 * d - 0.5 * log_det
        gain[t, j] = gn
        weight[t, j] = gn - floor
    return floor


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def edge_scores(tail, v, b, c, gaps, z, depth, gate_d2, sv, ss, so, so_min, ratio, cc, cc2,
                two_pi):
    """Every (tail, new vertex) edge: ``tail`` (T, 6), ``v``, ``b``, ``c`` (T, 2) from
    :func:`.association.tail_velocity`, ``gaps`` (T,) float, ``z`` (M, 4) the new vertices'
    ``(y1, y2, w, h)``, ``depth`` (float) the graph depth, ``two_pi`` ``2.0 * np.pi``.  Returns
    ``gain, d2, weight`` (T, M) and ``floor`` (T,), as :func:`.association.score_edges`
    (``allowed`` is ``d2 <= gate_d2``).  (Few allocation spellings and no bool array: each is
    one more compile on the first run.)"""
    T = tail.shape[0]
    M = z.shape[0]
    gain = np.empty((T, M), np.float64)
    d2 = np.empty((T, M), np.float64)
    weight = np.empty((T, M), np.float64)
    floor = np.empty(T, np.float64)
    var = np.empty(4, np.float64)
    lg = np.empty(4, np.float64)
    for t in range(T):
        floor[t] = _tail_row(tail, t, v[t, 0], v[t, 1], b[t, 0], b[t, 1], c[t, 0], c[t, 1],
                             gaps[t], z, depth, gate_d2, sv, ss, so, so_min, ratio, cc, cc2,
                             two_pi, var, lg, gain, d2, weight)
    return gain, d2, weight, floor


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _iou1(ax, ay, aw, ah, bx, by, bw, bh):
    """Intersection over union of two centre boxes (cx, cy, w, h)."""
    aw2 = aw / 2
    ah2 = ah / 2
    bw2 = bw / 2
    bh2 = bh / 2
    # max(x, y) and min(x, y) spelt out by numba's own rule (y if y > x else x; y if
    # y < x else x): the first run then compiles no builtin max / min overload for
    # the helper process's kernels (K-means, association, resampling walk)
    x = ax - aw2
    y = bx - bw2
    lo0 = y if y > x else x
    x = ay - ah2
    y = by - bh2
    lo1 = y if y > x else x
    x = ax + aw2
    y = bx + bw2
    hi0 = y if y < x else x
    x = ay + ah2
    y = by + bh2
    hi1 = y if y < x else x
    e0 = hi0 - lo0
    e1 = hi1 - lo1
    inter = (e0 if e0 > 0.0 else 0.0) * (e1 if e1 > 0.0 else 0.0)
    union = aw * ah + bw * bh - inter
    return inter / (union if union > 1e-12 else 1e-12)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def iou(a, b):
    """(A, B) intersection over union of centre boxes ``a`` (A, 4), ``b`` (B, 4)
    ``(cx, cy, w, h)``: :func:`.association._iou`, the same floats as its numpy spelling."""
    A = a.shape[0]
    B = b.shape[0]
    out = np.empty((A, B), np.float64)
    for i in range(A):
        for j in range(B):
            out[i, j] = _iou1(a[i, 0], a[i, 1], a[i, 2], a[i, 3],
                              b[j, 0], b[j, 1], b[j, 2], b[j, 3])
    return out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def check_states(s):
    """The association's input check of ``s`` (M, 6) states in one pass: 1 when a position or
    size ``(y1, y2, w, h)`` is not finite, 2 when a width or height is not positive (NaN is
    not), else 0 (:meth:`.association.GraphAssociator._check`)."""
    code = 0
    for j in range(s.shape[0]):
        for k in (0, 1, 4, 5):
            x = s[j, k]
            if not (x - x == 0.0):      # inf - inf and NaN - NaN are NaN
                return 1
        if s[j, 4] <= 0.0 or s[j, 5] <= 0.0:
            code = 2
    return code


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _vbc(tail, prev, t, d, so, so_min, ratio, speed_prior, vbc):
    """Tail t's velocity and error growth (:func:`.association.tail_velocity`, the same floats)
    into ``vbc`` (3, 2) = v, b, c; ``d`` the frames to its previous vertex (<= 0: none)."""
    for k in range(2):
        vbc[1, k] = 0.0
        vbc[2, k] = 0.0
    v0 = tail[t, 2]
    v1 = tail[t, 3]
    if (v0 - v0 == 0.0) and (v1 - v1 == 0.0):
        vbc[0, 0] = v0
        vbc[0, 1] = v1
        return
    if d > 0:
        fd = float(d)
        for k in range(2):
            st = so * tail[t, 4 + k]
            if not (st >= so_min or st != st):
                st = so_min
            sp = so * prev[t, 4 + k]
            if not (sp >= so_min or sp != sp):
                sp = so_min
            var_t = (ratio * st) * (ratio * st)
            var_p = (ratio * sp) * (ratio * sp)
            vbc[0, k] = (tail[t, k] - prev[t, k]) / fd
            vbc[1, k] = 2.0 * var_t / fd
            vbc[2, k] = (var_t + var_p) / (fd * fd)
    else:
        for k in range(2):
            vbc[0, k] = 0.0
            g = speed_prior * tail[t, 4 + k]
            vbc[2, k] = g * g


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def frame_edges(tail, prev, tail_frame, prev_frame, frame, z, depth, gate_d2, sv, ss, so,
                so_min, ratio, cc, cc2, two_pi, speed_prior):
    """:func:`edge_scores` of the live tails against ``z`` (M, 4) at ``frame`` with the tails'
    velocity terms (:func:`.association.tail_velocity`) and gaps (``frame − tail_frame``)
    taken in the same pass: ``tail``/``prev`` (T, 6), ``tail_frame``/``prev_frame`` (T,)
    int64 (``prev_frame`` −1: one vertex).  Returns ``gain, d2, weight`` (T, M), ``floor``
    (T,), ``w0`` (T, M): the weight where the edge is worth matching (inside the gate, finite
    and positive: :func:`.association.max_weight_matching`), else 0.0, how many are, and
    ``one``: no tail and no vertex has more than one such edge (then the maximum-weight
    matching takes every one of them: :func:`.association._match_admissible`)."""
    T = tail.shape[0]
    M = z.shape[0]
    gain = np.empty((T, M), np.float64)
    d2 = np.empty((T, M), np.float64)
    weight = np.empty((T, M), np.float64)
    w0 = np.empty((T, M), np.float64)
    floor = np.empty(T, np.float64)
    var = np.empty(4, np.float64)
    lg = np.empty(4, np.float64)
    vbc = np.empty((3, 2), np.float64)
    n_ok = 0
    one = True
    col = np.empty(M, np.bool_)     # the vertex has an admissible edge (np.empty + a fill)
    for j in range(M):
        col[j] = False
    for t in range(T):
        d = tail_frame[t] - prev_frame[t] if prev_frame[t] >= 0 else 0
        _vbc(tail, prev, t, d, so, so_min, ratio, speed_prior, vbc)
        f = _tail_row(tail, t, vbc[0, 0], vbc[0, 1], vbc[1, 0], vbc[1, 1], vbc[2, 0],
                      vbc[2, 1], float(frame - tail_frame[t]), z, depth, gate_d2, sv, ss, so,
                      so_min, ratio, cc, cc2, two_pi, var, lg, gain, d2, weight)
        floor[t] = f
        row = False
        for j in range(M):
            w = weight[t, j]
            if d2[t, j] <= gate_d2 and w - w == 0.0 and w > 0.0:
                w0[t, j] = w
                n_ok += 1
                if row or col[j]:
                    one = False
                row = True
                col[j] = True
            else:
                w0[t, j] = 0.0
    return gain, d2, weight, floor, w0, n_ok, one


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def revive_hits(tail, prev, tail_frame, prev_frame, first_frame, length, frame, z, min_length,
                revive_rate, kv):
    """:meth:`.association.GraphAssociator.returning` in one pass: ``hit`` (N,) bool, the
    detections ``z`` (N, 4) ``(cx, cy, w, h)`` inside the edge gate (:func:`edge_scores`'s
    d², the same floats) of a confirmed tail unseen in the frame before ``frame`` (within
    the graph depth) with estimates in at least ``revive_rate`` of its frames.  ``kv``:
    ``AssocParams.kernel_vec`` (one argument for eleven floats: fewer to type and unbox)."""
    depth = int(kv[0])
    gate_d2 = kv[1]
    sv = kv[2]
    ss = kv[3]
    so = kv[4]
    so_min = kv[5]
    ratio = kv[6]
    cc = kv[7]
    cc2 = kv[8]
    speed_prior = kv[10]
    N = z.shape[0]
    hit = np.empty(N, np.bool_)      # np.empty + a fill: no np.zeros overload to compile
    for j in range(N):
        hit[j] = False
    var = np.empty(4, np.float64)
    vbc = np.empty((3, 2), np.float64)
    for t in range(tail.shape[0]):
        gap = frame - tail_frame[t]
        if not (length[t] >= min_length and gap >= 2 and gap <= depth):
            continue
        if not length[t] >= revive_rate * (tail_frame[t] - first_frame[t] + 1):
            continue
        d = tail_frame[t] - prev_frame[t] if prev_frame[t] >= 0 else 0
        _vbc(tail, prev, t, d, so, so_min, ratio, speed_prior, vbc)
        i = float(gap)
        _var4(tail, t, vbc[1, 0], vbc[1, 1], vbc[2, 0], vbc[2, 1], i, sv, ss, so, so_min, ratio,
              cc, cc2, var)
        m0 = tail[t, 0] + i * vbc[0, 0]
        m1 = tail[t, 1] + i * vbc[0, 1]
        m2 = tail[t, 4]
        m3 = tail[t, 5]
        for j in range(N):
            dd = _d2_diag(z[j, 0], z[j, 1], z[j, 2], z[j, 3], m0, m1, m2, m3, var)
            if dd <= gate_d2:
                hit[j] = True
    return hit


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def advance(live_ids, tail, tail_frame, prev, prev_frame, length, new, rows, cols, frame,
            next_id, min_length):
    """The matching's outcome in place (:meth:`.association.GraphAssociator.step`, step 3):
    each matched tail ``rows[p]`` moves to ``prev``, takes the new vertex ``cols[p]`` at
    ``frame`` and one more vertex; returns ``ids`` (M,) -- the matched vertices their tail's
    track id, the others new ids from ``next_id`` in input order -- ``matched`` (M,), and
    ``unseen``: some tail of at least ``min_length`` vertices has none at ``frame`` (else no
    track can be a returning one at the next frame: :func:`revive_hits` would find none)."""
    M = new.shape[0]
    ids = np.empty(M, np.int64)
    matched = np.empty(M, np.bool_)
    for i in range(M):
        ids[i] = 0
        matched[i] = False
    for p in range(rows.shape[0]):
        r = rows[p]
        c = cols[p]
        ids[c] = live_ids[r]
        matched[c] = True
        for k in range(tail.shape[1]):
            prev[r, k] = tail[r, k]
            tail[r, k] = new[c, k]
        prev_frame[r] = tail_frame[r]
        tail_frame[r] = frame
        length[r] += 1
    n = next_id
    for j in range(M):
        if not matched[j]:
            ids[j] = n
            n += 1
    unseen = False
    for t in range(tail.shape[0]):
        if length[t] >= min_length and tail_frame[t] < frame:
            unseen = True
            break
    return ids, matched, unseen


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def gap_rows(bf, f0, n_buf, src, src_frame, dst, frame, sigma_v, fill_err, fill_free):
    """Gap filling's rows (:meth:`.association.GraphAssociator._fill_gaps`): every (buffered
    frame, edge) pair with the frame strictly inside the edge's gap
    (``src_frame[e] < f < frame[e]``; ``bf`` (B,) the buffered frames, in order, or, when
    empty, the ``n_buf`` consecutive frames from ``f0``; ``frame`` (E,) each edge's end
    frame, or (1,) the one of every edge).  Returns
    ``at`` (K,): the buffer positions of the frames with a pair; the pairs frame-major and
    in edge order within a frame -- ``fi`` (index into ``at``), ``ei`` (R,) -- frame k's rows
    ``run[k]:run[k + 1]`` (``run`` (K + 1,)); their states ``st`` (R, 6): the straight line
    between the edge's ends (``src``, ``dst`` (E, 6)) on (y1, y2, w, h), the mean velocity
    over the gap, NaN elsewhere; and ``likely`` (R,): the line's error std there
    (:func:`.association.interpolation_std` under ``sigma_v``) at most ``fill_err``.  The
    same floats as the numpy spelling.  Then two counts that spare the caller its masks on
    the usual frame: ``n_far`` the edges whose gap leaves more than ``fill_free`` frames
    missing (``gap − 1 > fill_free``, every edge), ``n_unlikely`` the rows not ``likely``."""
    given = bf.shape[0] > 0
    B = bf.shape[0] if given else n_buf
    E = src.shape[0]
    one = frame.shape[0] == 1
    n_far = 0
    for e in range(E):
        if frame[0 if one else e] - src_frame[e] - 1 > fill_free:
            n_far += 1
    R = 0
    K = 0
    for k in range(B):
        f = bf[k] if given else f0 + k
        n = 0
        for e in range(E):
            if src_frame[e] < f and f < frame[0 if one else e]:
                n += 1
        R += n
        if n:
            K += 1
    at = np.empty(K, np.int64)
    fi = np.empty(R, np.int64)
    ei = np.empty(R, np.int64)
    run = np.empty(K + 1, np.int64)
    st = np.full((R, 6), np.nan)
    likely = np.empty(R, np.bool_)
    n = 0
    kk = 0
    for k in range(B):
        f = bf[k] if given else f0 + k
        first = True
        for e in range(E):
            fe = frame[0 if one else e]
            if not (src_frame[e] < f and f < fe):
                continue
            if first:
                at[kk] = k
                run[kk] = n
                kk += 1
                first = False
            gap = fe - src_frame[e]
            ti = f - src_frame[e]
            t = ti / gap
            fi[n] = kk - 1
            ei[n] = e
            for c in (0, 1, 4, 5):
                st[n, c] = (1.0 - t) * src[e, c] + t * dst[e, c]
            st[n, 2] = (dst[e, 0] - src[e, 0]) / gap
            st[n, 3] = (dst[e, 1] - src[e, 1]) / gap
            g = float(gap)
            tf = float(ti)
            likely[n] = (sigma_v * tf * (g - tf) / math.sqrt(3.0 * (g if g > 1.0 else 1.0))
                         <= fill_err)
            n += 1
    run[K] = n
    n_unlikely = 0
    for i in range(R):
        if not likely[i]:
            n_unlikely += 1
    return at, fi, ei, st, likely, run, n_far, n_unlikely


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def gap_fill_last(bf, f0, n_buf, src, src_frame, dst, frame, sigma_v, fill_err, fill_free,
                  ids, bid, bst, bfill, fill_overlap):
    """Gap filling's usual frame in one call (:meth:`.association.GraphAssociator.
    _fill_gaps` on a still camera): :func:`gap_rows` (its first ten arguments), and when
    every row falls into the last buffered frame -- ``bid``, ``bst``, ``bfill`` (its rows, as
    :func:`fill_rows` takes them) -- with no edge longer than ``fill_free`` and every row
    likely, that frame's rows with the gap rows appended (:func:`fill_rows` on all of them,
    ids ``ids[ei]``, no mask).  Returns ``(status, bid, bst, bfill, added)``: status 0 no gap
    row (nothing to do), 1 done (the frame's rows as :func:`fill_rows` returns them), −1 the
    caller's general path (the given arrays back)."""
    at, fi, ei, st, likely, run, n_far, n_unlikely = gap_rows(
        bf, f0, n_buf, src, src_frame, dst, frame, sigma_v, fill_err, fill_free)
    R = ei.shape[0]
    if R == 0:
        return 0, bid, bst, bfill, 0
    B = bf.shape[0] if bf.shape[0] > 0 else n_buf
    if n_far or n_unlikely or at.shape[0] != 1 or at[0] != B - 1:
        return -1, bid, bst, bfill, 0
    fid = np.empty(R, np.int64)
    for i in range(R):
        fid[i] = ids[ei[i]]
    # (no mask: every row kept; the bounds as int64, not literals, and the mask a writable
    # array, as the caller's general path passes them: one specialisation of fill_rows)
    nbid, nbst, nbfill, n = fill_rows(bid, bst, bfill, st, fid, np.int64(0), np.int64(R),
                                      np.empty(0, np.bool_), fill_overlap)
    return 1, nbid, nbst, nbfill, n


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def head_pick(d, pred, var, rows, fill_overlap, gate_d2):
    """One frame of ``extend_heads``' walk back (:meth:`.association.GraphAssociator.
    _extend_heads`): the detection of ``d`` (N, 4) ``(cx, cy, w, h)`` nearest ``pred`` (4,)
    in squared Mahalanobis distance under ``var`` (4,) -- none that a row of ``rows`` (B, 6)
    overlaps by ``fill_overlap`` IoU or more, np.argmin's pick (first NaN, else first
    minimum) -- or −1 when it is outside the gate ``gate_d2`` (or there is none)."""
    best = -1
    bv = np.inf
    for i in range(d.shape[0]):
        dd = _d2_diag(d[i, 0], d[i, 1], d[i, 2], d[i, 3], pred[0], pred[1], pred[2], pred[3],
                      var)
        if rows.shape[0]:
            m = _iou1(d[i, 0], d[i, 1], d[i, 2], d[i, 3],
                      rows[0, 0], rows[0, 1], rows[0, 4], rows[0, 5])
            for b in range(1, rows.shape[0]):
                u = _iou1(d[i, 0], d[i, 1], d[i, 2], d[i, 3],
                          rows[b, 0], rows[b, 1], rows[b, 4], rows[b, 5])
                if u > m or u != u:      # np.max: NaN propagates
                    m = u
            if m >= fill_overlap:
                dd = np.inf
        if dd != dd:                     # np.argmin: the first NaN
            return -1
        if best < 0 or dd < bv:
            best = i
            bv = dd
    if best < 0 or not bv <= gate_d2:
        return -1
    return best


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def confirmed(live_ids, live_len, extra_ids, extra_len, ids, min_length):
    """(R,) bool: ``ids`` whose track has at least ``min_length`` vertices, looked up in the
    live tracks (``live_ids`` sorted ascending) first, then in ``extra_ids`` (tracks just
    ended) -- :meth:`.association.GraphAssociator._confirmed_ids`."""
    out = np.empty(ids.shape[0], np.bool_)
    for r in range(ids.shape[0]):
        out[r] = False
    L = live_ids.shape[0]
    for r in range(ids.shape[0]):
        x = ids[r]
        pos = np.searchsorted(live_ids, x)
        if pos < L and live_ids[pos] == x:
            out[r] = live_len[pos] >= min_length
            continue
        for e in range(extra_ids.shape[0]):
            if extra_ids[e] == x:
                out[r] = extra_len[e] >= min_length
                break
    return out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def uncovered(rows, bst, bfill, fill_overlap):
    """(R,) bool: the gap rows ``rows`` (R, 6) that no estimate of their frame (``bst`` (B, 6)
    where not ``bfill``) overlaps by ``fill_overlap`` IoU or more (np.max's NaN rule); all
    True when the frame has no estimate."""
    R = rows.shape[0]
    out = np.ones(R, np.bool_)
    for i in range(R):
        m = -np.inf
        seen = False
        nan = False
        for b in range(bst.shape[0]):
            if bfill[b]:
                continue
            seen = True
            u = _iou1(rows[i, 0], rows[i, 1], rows[i, 4], rows[i, 5],
                      bst[b, 0], bst[b, 1], bst[b, 4], bst[b, 5])
            if u != u:
                nan = True
            elif u > m:
                m = u
        out[i] = not seen or (not nan and m < fill_overlap)
    return out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def fill_rows(bid, bst, bfill, st, fid, lo, hi, keep, fill_overlap):
    """One buffered frame's rows -- ``bid`` (B,) int64 ids, ``bst`` (B, 6), ``bfill`` (B,) --
    with the gap rows ``st[lo:hi]`` (ids ``fid[lo:hi]``) appended that are kept (``keep[i]``;
    an empty ``keep``: all) and :func:`uncovered` (no estimate of the frame overlaps them by
    ``fill_overlap``), flagged filled: the three arrays (np.concatenate's values) and how
    many rows were added (0: the frame's rows stay as they are)."""
    free = uncovered(st[lo:hi], bst, bfill, fill_overlap)
    n = 0
    for i in range(lo, hi):
        if not (keep.shape[0] == 0 or keep[i]):
            free[i - lo] = False
        elif free[i - lo]:
            n += 1
    B = bid.shape[0]
    nbid = np.empty(B + n, np.int64)
    nbst = np.empty((B + n, bst.shape[1]), np.float64)
    nbfill = np.empty(B + n, np.bool_)
    for b in range(B):
        nbid[b] = bid[b]
        for c in range(bst.shape[1]):
            nbst[b, c] = bst[b, c]
        nbfill[b] = bfill[b]
    o = B
    for i in range(lo, hi):
        if free[i - lo]:
            nbid[o] = fid[i]
            for c in range(bst.shape[1]):
                nbst[o, c] = st[i, c]
            nbfill[o] = True
            o += 1
    return nbid, nbst, nbfill, n


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _tail_w0(tail, t, v0, v1, b0, b1, c0, c1, i, new, depth, gate_d2, sv, ss, so, so_min,
             ratio, cc, cc2, two_pi, var, lg, w0):
    """Tail t's row of :func:`frame_edges`' ``w0`` (the admissible weights, else 0.0) against
    the states ``new`` (M, 6) -- :func:`_tail_row`'s floats, without its gain and d² rows."""
    floor, log_det, m0, m1, m2, m3 = _tail_gauss(tail, t, v0, v1, b0, b1, c0, c1, i, depth,
                                                 gate_d2, sv, ss, so, so_min, ratio, cc, cc2,
                                                 two_pi, var, lg)
    for j in range(new.shape[0]):
        d = _d2_diag(new[j, 0], new[j, 1], new[j, 4], new[j, 5], m0, m1, m2, m3, var)
        w = (-0.5 * d - 0.5 * log_det) - floor
        if d <= gate_d2 and w - w == 0.0 and w > 0.0:
            w0[t, j] = w
        else:
            w0[t, j] = 0.0


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _star_pick(w0, rdeg, cdeg):
    """The maximum-weight matching of the admissible edges (``w0`` != 0, positive; ``rdeg``,
    ``cdeg`` their count per tail and per vertex) when it needs no assignment solver: every
    connected group of edges is a star -- one edge, a tail whose vertices have no other tail,
    or a vertex whose tails have no other vertex -- with a single heaviest edge (a tie: the
    solver decides).  A star's matching is its heaviest edge, so the maximum-weight matching
    is those and it is unique (the solver's, :func:`.association._match_admissible`).
    Returns ``pick`` (T,): each tail's vertex, −1 none; empty (T > 0): the solver is needed."""
    T = w0.shape[0]
    M = w0.shape[1]
    pick = np.empty(T, np.int64)
    none = np.empty(0, np.int64)
    for t in range(T):
        pick[t] = -1
    for t in range(T):
        if rdeg[t] == 0:
            continue
        if rdeg[t] == 1:
            for j in range(M):
                if w0[t, j] != 0.0:
                    break
            if cdeg[j] == 1:
                pick[t] = j
            continue
        best = -1
        tie = False
        for j in range(M):
            w = w0[t, j]
            if w != 0.0:
                if cdeg[j] != 1:
                    return none            # not a star: the solver
                if best < 0 or w > w0[t, best]:
                    best = j
                    tie = False
                elif w == w0[t, best]:
                    tie = True
        if tie:
            return none
        pick[t] = best
    for j in range(M):
        if cdeg[j] < 2:
            continue
        best = -1
        tie = False
        for t in range(T):
            w = w0[t, j]
            if w != 0.0:
                if rdeg[t] != 1:
                    return none
                if best < 0 or w > w0[best, j]:
                    best = t
                    tie = False
                elif w == w0[best, j]:
                    tie = True
        if tie:
            return none
        pick[best] = j
    return pick


#: :func:`_group_pick`: the most matchings a group of admissible edges may have (the product
#: of its tails' edge counts + 1) for the kernel to enumerate them; more: the solver decides
GROUP_MAX_MATCHINGS = 4096
#: :func:`_group_pick`: the heaviest matching of a group must beat every other by this much
#: (relative to 1 + its weight) -- far above the solver's float error (~1e-14 on these
#: sizes) -- else the solver decides (a tie, or so near one that float rounding could)
GROUP_MARGIN = 1e-9


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _group_pick(w0, rdeg):
    """:func:`_star_pick` for any shape of small groups: the admissible edges (``w0`` != 0,
    positive; ``rdeg`` their count per tail) split into connected groups, and each group's
    matchings are enumerated (every tail of the group takes one of its edges or none, no
    vertex twice).  When every group has at most :data:`GROUP_MAX_MATCHINGS` candidates and
    its heaviest matching beats all others by :data:`GROUP_MARGIN`, that maximum-weight
    matching is unique, so it is the assignment solver's (:func:`.association.
    _match_admissible` keeps its positive pairs: a maximum-weight matching).  Returns ``pick``
    (T,): each tail's vertex, −1 none; empty (T > 0): the solver is needed."""
    T = w0.shape[0]
    M = w0.shape[1]
    none = np.empty(0, np.int64)
    # groups: union-find over tails 0..T-1 and vertices T..T+M-1
    par = np.empty(T + M, np.int64)
    for a in range(T + M):
        par[a] = a
    for t in range(T):
        for j in range(M):
            if w0[t, j] != 0.0:
                a = t
                while par[a] != a:
                    a = par[a]
                b = T + j
                while par[b] != b:
                    b = par[b]
                if a < b:
                    par[b] = a
                elif b < a:
                    par[a] = b
    root = np.empty(T, np.int64)
    for t in range(T):
        a = t
        while par[a] != a:
            a = par[a]
        root[t] = a
    pick = np.empty(T, np.int64)
    for t in range(T):
        pick[t] = -1
    # (np.empty and loops: no np.zeros overload to compile, as the other kernels here)
    done = np.empty(T, np.bool_)
    for t in range(T):
        done[t] = False
    rows = np.empty(T, np.int64)
    choice = np.empty(T, np.int64)
    best_choice = np.empty(T, np.int64)
    cand = np.empty((T, M), np.int64)
    used = np.empty(M, np.bool_)
    for j in range(M):
        used[j] = False
    for t0 in range(T):
        if done[t0] or rdeg[t0] == 0:
            continue
        # the group's tails (in order) and their vertices
        k = 0
        n = 1
        for t in range(t0, T):
            if root[t] == root[t0] and rdeg[t] > 0:
                done[t] = True
                rows[k] = t
                d = 0
                for j in range(M):
                    if w0[t, j] != 0.0:
                        cand[k, d] = j
                        d += 1
                k += 1
                n *= rdeg[t] + 1
                if n > GROUP_MAX_MATCHINGS:
                    return none
        # every matching of the group: an odometer over each tail's choice (-1: none)
        for i in range(k):
            choice[i] = -1
        best = -1.0
        second = -1.0
        while True:
            ok = True
            total = 0.0
            for i in range(k):
                c = choice[i]
                if c >= 0:
                    j = cand[i, c]
                    if used[j]:
                        ok = False
                    used[j] = True
                    total += w0[rows[i], j]
            for i in range(k):
                if choice[i] >= 0:
                    used[cand[i, choice[i]]] = False
            if ok:
                if total > best:
                    second = best
                    best = total
                    for i in range(k):
                        best_choice[i] = choice[i]
                elif total > second:
                    second = total
            i = 0
            while i < k:
                choice[i] += 1
                if choice[i] < rdeg[rows[i]]:
                    break
                choice[i] = -1
                i += 1
            if i == k:
                break
        if not best - second > GROUP_MARGIN * (1.0 + best):
            return none
        for i in range(k):
            if best_choice[i] >= 0:
                pick[rows[i]] = cand[i, best_choice[i]]
    return pick


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def frame_step(live_ids, tail, tail_frame, prev, prev_frame, length, new, frame, kv, next_id,
               min_length, rows, cols, given):
    """:meth:`.association.GraphAssociator.step`'s steps 1-3 for a frame without colour
    features or edge arrays, in one pass: the input check of ``new`` first
    (:func:`check_states`; its code ``c`` > 0 gives ``status`` 2 + c, nothing done), no tail
    expires (else ``status`` 2, nothing done),
    :func:`frame_edges`' admissible weights of the live tails against ``new`` (M, 6) (``kv``:
    ``kernel_args`` then ``speed_prior``; the same floats), the matching when it needs no
    assignment solver (:func:`_star_pick`: every group of admissible edges a star, the
    usual frame), then :func:`advance` in place.  When the
    matching needs the assignment solver: ``status`` 1 and ``w0`` (T, M) (:func:`frame_edges`'
    admissible weights, else 0.0), nothing done; called again with the solver's ``rows``,
    ``cols`` and ``given`` true, it advances with them.  Returns ``w0`` (empty unless status
    1), one int64 array: ``status, flags, P``, then the vertices' track ``ids`` (M,),
    their tracks' ``lengths`` (M,) after the frame (a new track's 1) and the ``rows``,
    ``cols`` of the ``L`` matched pairs whose tail had a gap of more than one frame (gap
    filling's edges, in pair order; ``L`` = (len − 3 − 2 M) / 2), and (M,) bool
    ``lengths >= min_length`` (empty unless status 0: the step's ``confirmed``, without a
    numpy comparison in Python).  ``flags``: 1 some tail
    of ``min_length`` vertices unseen at ``frame`` (:func:`advance`), 2 some vertex's track
    has ``min_length`` vertices now, 4 some matched tail had a gap of more than one frame."""
    T = tail.shape[0]
    M = new.shape[0]
    w0 = np.empty((0, 0), np.float64)
    if not given:
        bad = check_states(new)
        if bad != 0:
            out = np.empty(3, np.int64)
            out[0] = 2 + bad
            out[1] = 0
            out[2] = 0
            return w0, out, np.empty(0, np.bool_)
        depth = kv[0]
        for t in range(T):
            if frame - tail_frame[t] > depth:
                out = np.empty(3, np.int64)
                out[0] = 2
                out[1] = 0
                out[2] = 0
                return w0, out, np.empty(0, np.bool_)
        w0 = np.empty((T, M), np.float64)
        var = np.empty(4, np.float64)
        lg = np.empty(4, np.float64)
        vbc = np.empty((3, 2), np.float64)
        n_ok = 0
        one = True
        for t in range(T):
            d = tail_frame[t] - prev_frame[t] if prev_frame[t] >= 0 else 0
            _vbc(tail, prev, t, d, kv[4], kv[5], kv[6], kv[10], vbc)
            _tail_w0(tail, t, vbc[0, 0], vbc[0, 1], vbc[1, 0], vbc[1, 1], vbc[2, 0],
                     vbc[2, 1], float(frame - tail_frame[t]), new, kv[0], kv[1], kv[2], kv[3],
                     kv[4], kv[5], kv[6], kv[7], kv[8], kv[9], var, lg, w0)
        rdeg = np.empty(T, np.int64)
        cdeg = np.empty(M, np.int64)
        for j in range(M):
            cdeg[j] = 0
        for t in range(T):
            rdeg[t] = 0
            for j in range(M):
                if w0[t, j] != 0.0:
                    rdeg[t] += 1
                    cdeg[j] += 1
        pick = _star_pick(w0, rdeg, cdeg)
        if pick.shape[0] == 0 and T > 0:
            # (not every group a star with a single heaviest edge: small groups enumerated)
            pick = _group_pick(w0, rdeg)
        if pick.shape[0] == 0 and T > 0:
            out = np.empty(3, np.int64)
            out[0] = 1
            out[1] = 0
            out[2] = 0
            return w0, out, np.empty(0, np.bool_)
        n = 0
        for t in range(T):
            if pick[t] >= 0:
                n += 1
        rows = np.empty(n, np.int64)
        cols = np.empty(n, np.int64)
        n = 0
        for t in range(T):
            if pick[t] >= 0:
                rows[n] = t
                cols[n] = pick[t]
                n += 1
    P = rows.shape[0]
    L = 0
    for p in range(P):
        if frame - tail_frame[rows[p]] > 1:
            L += 1
    out = np.empty(3 + 2 * M + 2 * L, np.int64)
    flags = 4 if L else 0
    q = 0
    for p in range(P):
        if frame - tail_frame[rows[p]] > 1:
            out[3 + 2 * M + q] = rows[p]
            out[3 + 2 * M + L + q] = cols[p]
            q += 1
    ids, matched, unseen = advance(live_ids, tail, tail_frame, prev, prev_frame, length, new,
                                   rows, cols, frame, next_id, min_length)
    if unseen:
        flags |= 1
    for j in range(M):
        out[3 + j] = ids[j]
        out[3 + M + j] = 1
    for p in range(P):
        out[3 + M + cols[p]] = length[rows[p]]
    ok = np.empty(M, np.bool_)
    for j in range(M):
        if out[3 + M + j] == min_length:
            flags |= 2
        ok[j] = out[3 + M + j] >= min_length
    out[0] = 0
    out[1] = flags
    out[2] = P
    return np.empty((0, 0), np.float64), out, ok


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True, inline="always")
def corner_box(states, j, out, o):
    """``out[o]`` = the top-left box ``(x − w / 2, y − h / 2, w, h)`` of state row
    ``states[j]`` (:func:`.association.boxes_xywh`'s floats): the one spelling of the
    conversion for every kernel that writes boxes."""
    w = states[j, 4]
    h = states[j, 5]
    out[o, 0] = states[j, 0] - w / 2.0
    out[o, 1] = states[j, 1] - h / 2.0
    out[o, 2] = w
    out[o, 3] = h


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True, inline="always")
def centre_box(boxes, j, out):
    """``out[j]`` = the centre box ``(x + w / 2, y + h / 2, w, h)`` of top-left box
    ``boxes[j]`` (:func:`pfscope.trackers.types.xywh_to_cxcywh`'s floats)."""
    w = boxes[j, 2]
    h = boxes[j, 3]
    out[j, 0] = boxes[j, 0] + w / 2.0
    out[j, 1] = boxes[j, 1] + h / 2.0
    out[j, 2] = w
    out[j, 3] = h


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def final_rows(live_ids, live_len, extra_ids, extra_len, bid, bst, bfill, min_length,
               gap_conf, est_conf):
    """A held-back frame's rows ``bid`` (R,), ``bst`` (R, 6), ``bfill`` (R,) of the tracks with
    at least ``min_length`` vertices (:func:`confirmed`), as ``a[mask]`` for each, and those
    rows' top-left boxes and tracks-file conf (:func:`row_boxes`' floats)."""
    ok = confirmed(live_ids, live_len, extra_ids, extra_len, bid, min_length)
    n = 0
    for r in range(ok.shape[0]):
        if ok[r]:
            n += 1
    oid = np.empty(n, np.int64)
    ost = np.empty((n, bst.shape[1]), np.float64)
    ofill = np.empty(n, np.bool_)
    box = np.empty((n, 4), np.float64)
    conf = np.empty(n, np.float64)
    o = 0
    for r in range(ok.shape[0]):
        if ok[r]:
            oid[o] = bid[r]
            for c in range(bst.shape[1]):
                ost[o, c] = bst[r, c]
            ofill[o] = bfill[r]
            corner_box(bst, r, box, o)
            conf[o] = gap_conf if bfill[r] else est_conf
            o += 1
    return oid, ost, ofill, box, conf


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def track_boxes(ids, states, keep):
    """The tracks a step reports: ``ids[keep]`` and the top-left boxes ``(x, y, w, h)`` of
    ``states[keep]`` (:func:`.association.boxes_xywh`: ``x − w / 2``, ``y − h / 2``, the same
    floats)."""
    n = 0
    for j in range(keep.shape[0]):
        if keep[j]:
            n += 1
    oid = np.empty(n, np.int64)
    out = np.empty((n, 4), np.float64)
    o = 0
    for j in range(keep.shape[0]):
        if keep[j]:
            oid[o] = ids[j]
            corner_box(states, j, out, o)
            o += 1
    return oid, out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def row_boxes(states, filled, gap_conf, est_conf):
    """A finalised frame's top-left boxes (:func:`.association.boxes_xywh`, the same floats)
    and tracks-file conf ``np.where(filled, gap_conf, est_conf)``."""
    R = states.shape[0]
    out = np.empty((R, 4), np.float64)
    conf = np.empty(R, np.float64)
    for j in range(R):
        corner_box(states, j, out, j)
        conf[j] = gap_conf if filled[j] else est_conf
    return out, conf


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def centre_boxes(boxes):
    """(N, 4) top-left boxes -> centre boxes ``(cx, cy, w, h)``
    (:func:`pfscope.trackers.types.xywh_to_cxcywh`, the same floats)."""
    N = boxes.shape[0]
    out = np.empty((N, 4), np.float64)
    for j in range(N):
        centre_box(boxes, j, out)
    return out
