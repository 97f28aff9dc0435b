"""Fused numba kernels of the modified K-means of maggio2007 §3 (issue 12): weighted Lloyd
iterations with an exact nearest-centre search whose cost per particle does not grow with the
number of centres (a grid on the centres, :func:`assign`).  Split from :mod:`._kernels` (the
filter's kernels) so the two can change independently."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._kernels import grid_build, grid_span


# ----------------------------------------------------------------------------- K-means

@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _inv_var(centers, sigma_obs, sigma_min, pos_ratio):
    """(K, 4) inverse observation-noise variances at each centre's size (``1 / obs_std²``)."""
    K = centers.shape[0]
    inv = np.empty((K, 4), np.float64)
    for c in range(K):
        # (max(a, b) spelt out -- b if b > a else a, numba's own rule -- so the first run
        # compiles no builtin-max overload for the dense K-means)
        sw = sigma_obs * centers[c, 4]
        sw = sigma_min if sigma_min > sw else sw
        sh = sigma_obs * centers[c, 5]
        sh = sigma_min if sigma_min > sh else sh
        a = pos_ratio * sw
        b = pos_ratio * sh
        inv[c, 0] = 1.0 / (a * a)
        inv[c, 1] = 1.0 / (b * b)
        inv[c, 2] = 1.0 / (sw * sw)
        inv[c, 3] = 1.0 / (sh * sh)
    return inv


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _d2(X, i, centers, inv, c):
    """``Σ_d (x_d − c_d)² inv_d`` on (y1, y2, w, h), summed in coordinate order."""
    a = X[i, 0] - centers[c, 0]
    d = (a * a) * inv[c, 0]
    a = X[i, 1] - centers[c, 1]
    d += (a * a) * inv[c, 1]
    a = X[i, 2] - centers[c, 4]
    d += (a * a) * inv[c, 2]
    a = X[i, 3] - centers[c, 5]
    d += (a * a) * inv[c, 3]
    return d


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _nearest_dense(X, i, centers, inv):
    """Particle i's nearest centre and its d², looking at every centre (as ``argmin``: the
    first of equal d², and centre 0 when every d² is NaN)."""
    lab = np.int64(0)                # (not the literal 0: one _d2 specialisation, not two)
    best = _d2(X, i, centers, inv, lab)
    for c in range(1, centers.shape[0]):
        d = _d2(X, i, centers, inv, c)
        if d < best:
            best = d
            lab = c
    return lab, best


#: From this many centres on, the dense assignment takes the particles in blocks of
#: :data:`_BLOCK` and looks, for a block, only at the centres that could beat the previous
#: particle's centre somewhere in the block's box (:func:`_assign_dense`).  (The split
#: trials' local Lloyd runs have 2-5 centres: with the blocks a trial on the bench scene at
#: 16 targets costs ~50 us where the serial look took ~80.)
_BLOCKS_MIN = 2
#: Particles per block of :func:`_assign_dense`.
_BLOCK = 32
#: The blocks' coordinates (particles and centres) stay within this many pixels: their
#: differences' squares are then finite, so no d² is NaN (an inf square times a zero inverse
#: variance); a block with a particle beyond it gets the serial look.
_BLOCK_MAX_ABS = 1e150


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _dense_row(cc, x0, x1, x2, x3, g):
    """One particle's nearest centre and d² by the serial rule (centre 0, then ``g``, then the
    others, lowest index among equal d²; a NaN d² at centre 0 is the answer), ``cc`` (K, 8)
    the centres' (y1, y2, w, h) and inverse variances (:func:`_assign_dense`)."""
    K = cc.shape[0]
    a0 = x0 - cc[0, 0]
    a1 = x1 - cc[0, 1]
    a2 = x2 - cc[0, 2]
    a3 = x3 - cc[0, 3]
    best = (((a0 * a0) * cc[0, 4] + (a1 * a1) * cc[0, 5]) + (a2 * a2) * cc[0, 6]) \
        + (a3 * a3) * cc[0, 7]
    lab = 0
    if best != best:                               # NaN at centre 0: argmin's centre 0
        return lab, best
    if g != 0:
        a0 = x0 - cc[g, 0]
        a1 = x1 - cc[g, 1]
        a2 = x2 - cc[g, 2]
        a3 = x3 - cc[g, 3]
        d = (((a0 * a0) * cc[g, 4] + (a1 * a1) * cc[g, 5]) + (a2 * a2) * cc[g, 6]) \
            + (a3 * a3) * cc[g, 7]
        if d < best:
            best = d
            lab = g
    for c in range(1, K):
        a0 = x0 - cc[c, 0]
        a1 = x1 - cc[c, 1]
        p = (a0 * a0) * cc[c, 4] + (a1 * a1) * cc[c, 5]
        if p > best or c == g:                     # (a NaN part goes on: it never wins)
            continue
        a2 = x2 - cc[c, 2]
        a3 = x3 - cc[c, 3]
        d = (p + (a2 * a2) * cc[c, 6]) + (a3 * a3) * cc[c, 7]
        if d < best or (d == best and c < lab):
            best = d
            lab = c
    return lab, best


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _centre_rows(centers, inv, k_min):
    """(K, 8) the centres' (y1, y2, w, h) and inverse variances, one row per centre, and
    whether the blocks may be used: at least ``k_min`` centres, every value finite and within
    :data:`_BLOCK_MAX_ABS`."""
    K = centers.shape[0]
    cc = np.empty((K, 8), np.float64)
    for c in range(K):
        cc[c, 0] = centers[c, 0]
        cc[c, 1] = centers[c, 1]
        cc[c, 2] = centers[c, 4]
        cc[c, 3] = centers[c, 5]
        cc[c, 4] = inv[c, 0]
        cc[c, 5] = inv[c, 1]
        cc[c, 6] = inv[c, 2]
        cc[c, 7] = inv[c, 3]
    lim = _BLOCK_MAX_ABS
    blocks = K >= k_min
    for c in range(K):
        for d in range(8):
            v = cc[c, d]
            if not (v - v == 0.0 and -lim <= v <= lim):   # (not finite, or huge)
                blocks = False
    return cc, blocks


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _box(X, b0, b1, lim):
    """The box of particles ``b0:b1`` (each coordinate's range) and whether it lies within
    ``lim`` (a NaN coordinate but the first row's is passed over: its d² is NaN)."""
    l0 = X[b0, 0]
    l1 = X[b0, 1]
    l2 = X[b0, 2]
    l3 = X[b0, 3]
    h0 = l0
    h1 = l1
    h2 = l2
    h3 = l3
    for i in range(b0 + 1, b1):
        v = X[i, 0]
        l0 = v if v < l0 else l0
        h0 = v if v > h0 else h0
        v = X[i, 1]
        l1 = v if v < l1 else l1
        h1 = v if v > h1 else h1
        v = X[i, 2]
        l2 = v if v < l2 else l2
        h2 = v if v > h2 else h2
        v = X[i, 3]
        l3 = v if v < l3 else l3
        h3 = v if v > h3 else h3
    ok = (-lim <= l0 and h0 <= lim and -lim <= l1 and h1 <= lim and -lim <= l2
          and h2 <= lim and -lim <= l3 and h3 <= lim)
    return ok, l0, l1, l2, l3, h0, h1, h2, h3


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _lower(cc, c, l0, l1, l2, l3, h0, h1, h2, h3, ub):
    """A lower bound of the d² of every particle in the box ``(l, h)`` to centre c (each
    term at the box's near side), summed in :func:`_d2`'s order; stops early (with a value
    above ``ub``) once a partial sum exceeds ``ub``."""
    v = cc[c, 0]
    a = l0 - v if v < l0 else (h0 - v if v > h0 else 0.0)
    lb = (a * a) * cc[c, 4]
    if lb > ub:
        return lb
    v = cc[c, 1]
    a = l1 - v if v < l1 else (h1 - v if v > h1 else 0.0)
    lb = lb + (a * a) * cc[c, 5]
    if lb > ub:
        return lb
    v = cc[c, 2]
    a = l2 - v if v < l2 else (h2 - v if v > h2 else 0.0)
    lb = lb + (a * a) * cc[c, 6]
    v = cc[c, 3]
    a = l3 - v if v < l3 else (h3 - v if v > h3 else 0.0)
    return lb + (a * a) * cc[c, 7]

@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _box_cands(cc, idx, nm, boxes, b, ub, cand):
    """The centres ``idx[:nm]`` whose :func:`_lower` bound over block ``b``'s box is not above
    ``ub`` (those that could beat a d² of ``ub`` somewhere in it), written to ``cand`` in
    ``idx``'s order; returns their count."""
    l0 = boxes[b, 0]
    l1 = boxes[b, 1]
    l2 = boxes[b, 2]
    l3 = boxes[b, 3]
    h0 = boxes[b, 4]
    h1 = boxes[b, 5]
    h2 = boxes[b, 6]
    h3 = boxes[b, 7]
    nc = 0
    for k in range(nm):
        c = idx[k]
        if not _lower(cc, c, l0, l1, l2, l3, h0, h1, h2, h3, ub) > ub:
            cand[nc] = c
            nc += 1
    return nc


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _row_vs(X, i, cc, cand, nc, lab, best):
    """Particle ``i``'s label and d² after looking at the centres ``cand[:nc]`` from centre
    ``lab`` at d² ``best`` (:func:`_d2`'s sums; a tie goes to the lower index)."""
    x0 = X[i, 0]
    x1 = X[i, 1]
    x2 = X[i, 2]
    x3 = X[i, 3]
    for k in range(nc):
        c = cand[k]
        a0 = x0 - cc[c, 0]
        a1 = x1 - cc[c, 1]
        a2 = x2 - cc[c, 2]
        a3 = x3 - cc[c, 3]
        d = (((a0 * a0) * cc[c, 4] + (a1 * a1) * cc[c, 5]) + (a2 * a2) * cc[c, 6]) \
            + (a3 * a3) * cc[c, 7]
        if d < best or (d == best and c < lab):
            best = d
            lab = c
    return lab, best



@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _boxes(X):
    """(B, 9) the box of each block of :data:`_BLOCK` particles (:func:`_box`: the lows and
    highs of (y1, y2, w, h), then 1.0 if it lies within :data:`_BLOCK_MAX_ABS`, else 0.0):
    taken once for every assignment of a Lloyd run (the particles do not change)."""
    n = X.shape[0]
    nb = (n + _BLOCK - 1) // _BLOCK
    out = np.empty((nb, 9), np.float64)
    for b in range(nb):
        b0 = b * _BLOCK
        b1 = b0 + _BLOCK if b0 + _BLOCK < n else n
        ok, l0, l1, l2, l3, h0, h1, h2, h3 = _box(X, b0, b1, _BLOCK_MAX_ABS)
        out[b, 0] = l0
        out[b, 1] = l1
        out[b, 2] = l2
        out[b, 3] = l3
        out[b, 4] = h0
        out[b, 5] = h1
        out[b, 6] = h2
        out[b, 7] = h3
        out[b, 8] = 1.0 if ok else 0.0
    return out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _assign_dense(X, centers, inv, labels, dmin):
    """:func:`_nearest_dense` of every particle: the same labels and d² floats
    (:func:`_assign_blocks`, the blocks' boxes taken here)."""
    bx = _boxes(X) if centers.shape[0] >= _BLOCKS_MIN else np.empty((0, 9), np.float64)
    _assign_blocks(X, centers, inv, labels, dmin, bx, bx, dmin, dmin, bx, np.bool_(False))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _add_sums(S, w, labels, m, sums, b0, b1):
    """Particles ``b0:b1``'s weights and weighted states added to their clusters' ``m`` and
    ``sums``, in particle order (:func:`lloyd`'s sums): each run of particles of one cluster
    by :func:`_add_one` (6 state columns)."""
    D = S.shape[1]
    i = b0
    while i < b1:
        c = labels[i]
        j = i + 1
        while j < b1 and labels[j] == c:
            j += 1
        if D == 6:
            _add_one(S, w, m, sums, c, i, j)
        else:
            for k in range(i, j):
                wi = w[k]
                m[c] += wi
                for d in range(D):
                    sums[c, d] += S[k, d] * wi
        i = j


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _add_one(S, w, m, sums, c, b0, b1):
    """:func:`_add_sums` of particles ``b0:b1`` all of cluster c (6 state columns): the same
    additions, in particle order, with the running sums in registers."""
    mc = m[c]
    s0 = sums[c, 0]
    s1 = sums[c, 1]
    s2 = sums[c, 2]
    s3 = sums[c, 3]
    s4 = sums[c, 4]
    s5 = sums[c, 5]
    for i in range(b0, b1):
        wi = w[i]
        mc += wi
        s0 += S[i, 0] * wi
        s1 += S[i, 1] * wi
        s2 += S[i, 2] * wi
        s3 += S[i, 3] * wi
        s4 += S[i, 4] * wi
        s5 += S[i, 5] * wi
    m[c] = mc
    sums[c, 0] = s0
    sums[c, 1] = s1
    sums[c, 2] = s2
    sums[c, 3] = s3
    sums[c, 4] = s4
    sums[c, 5] = s5


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _assign_blocks(X, centers, inv, labels, dmin, boxes, S, w, m, sums, acc):
    """:func:`_nearest_dense` of every particle: the same labels and d² floats; ``boxes``
    those of the particles' blocks (:func:`_boxes`; empty: no blocks).  A particle
    starts from centre 0 (a NaN d² there is the answer, as argmin's rule above) and the
    previous particle's centre (resampling lays a target's particles side by side, so it is
    usually the nearest), then looks at the others taking the lowest index among equal d²;
    a centre whose (y1, y2) part of the sum alone exceeds the best d² is passed over without
    its size terms (the full sum adds non-negative terms to that part: it could only be
    larger).  Each d² is summed in :func:`_d2`'s order.  The centres and their inverse
    variances are one row per centre, hoisted.

    From :data:`_BLOCKS_MIN` centres on (all finite, within :data:`_BLOCK_MAX_ABS`), the
    particles go in blocks of :data:`_BLOCK` consecutive ones (a block reaching beyond it:
    the serial look): the block's box (the range of each coordinate) gives an upper bound ``ub`` of every particle's d² to the previous
    block's last centre g (each term at the box's far side) and a lower bound ``lb_c`` for
    each centre (each term at the near side; rounding is monotone and the terms are
    non-negative, so the bounds hold for the float d²).  A centre with ``lb_c > ub`` can
    neither beat nor tie g for any particle of the block and is not looked at; the others
    (g among them) are, in index order, the first of the smallest d² winning -- the serial
    rule's answer, as no d² is NaN there (a particle with a NaN coordinate makes its block
    take the serial look).  Resampling lays a target's particles side by side: on the bench
    scene ~94 % of the blocks have g alone, one d² a particle, and a run of such blocks with
    the same g is labelled in one loop with no branch (:func:`_run_rows`).

    ``acc``: each particle's weight ``w`` and weighted state ``S`` row are also added to
    its cluster's ``m`` (K,) and ``sums`` (K, D) as soon as its block is labelled (the
    block still in the cache; per cluster in particle order: :func:`lloyd`'s sums pass,
    the same floats); else ``S``, ``w``, ``m``, ``sums`` are not read (any arrays of
    their types)."""
    _assign_range(X, centers, inv, labels, dmin, boxes, S, w, m, sums, acc, np.int64(0),
                  X.shape[0], np.int64(0))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _assign_range(X, centers, inv, labels, dmin, boxes, S, w, m, sums, acc, r0, r1, g):
    """:func:`_assign_blocks` of the particles ``r0:r1`` (``r0`` a multiple of :data:`_BLOCK`,
    ``r1`` one or the particle count), ``g`` the centre the first block's upper bound is
    taken from (any centre: the answer is the same)."""
    K = centers.shape[0]
    if K == 0:
        return
    cc, blocks = _centre_rows(centers, inv, _BLOCKS_MIN)
    n = X.shape[0]
    B = _BLOCK
    if not blocks or boxes.shape[0] == 0:
        for i in range(r0, r1):
            lab, best = _dense_row(cc, X[i, 0], X[i, 1], X[i, 2], X[i, 3], g)
            labels[i] = lab
            dmin[i] = best
            g = lab
        if acc:
            _add_sums(S, w, labels, m, sums, r0, r1)
        return
    cand = np.empty(K, np.int64)
    run = np.int64(-1)              # a run of blocks whose one candidate is centre ``run``
    q0 = np.int64(0)                # (its first particle)
    for b in range(r0 // B, (r1 + B - 1) // B):
        b0 = b * B
        b1 = b0 + B if b0 + B < n else n
        # the centres whose lower bound of the d² over the block's box (each term at its
        # near side) is not above g's upper bound (each term at the far side); none looked
        # at (nc 0) when the box is beyond _BLOCK_MAX_ABS.  (Spelt out here: as a call per
        # block it costs twice as much.)
        nc = 0
        if boxes[b, 8] != 0.0:
            l0 = boxes[b, 0]
            l1 = boxes[b, 1]
            l2 = boxes[b, 2]
            l3 = boxes[b, 3]
            h0 = boxes[b, 4]
            h1 = boxes[b, 5]
            h2 = boxes[b, 6]
            h3 = boxes[b, 7]
            a = l0 - cc[g, 0]
            e = h0 - cc[g, 0]
            a = a * a
            e = e * e
            ub = (a if a > e else e) * cc[g, 4]
            a = l1 - cc[g, 1]
            e = h1 - cc[g, 1]
            a = a * a
            e = e * e
            ub = ub + (a if a > e else e) * cc[g, 5]
            a = l2 - cc[g, 2]
            e = h2 - cc[g, 2]
            a = a * a
            e = e * e
            ub = ub + (a if a > e else e) * cc[g, 6]
            a = l3 - cc[g, 3]
            e = h3 - cc[g, 3]
            a = a * a
            e = e * e
            ub = ub + (a if a > e else e) * cc[g, 7]
            for c in range(K):
                if not _lower(cc, c, l0, l1, l2, l3, h0, h1, h2, h3, ub) > ub:
                    cand[nc] = c
                    nc += 1
        if nc == 1 and cand[0] == run:
            continue                                   # the run goes on
        if run >= 0:
            _run_rows(X, cc, run, q0, b0, labels, dmin, S, w, m, sums, acc)
            run = -1
        if nc == 1:                                    # a run starts
            run = cand[0]
            q0 = b0
            g = run
            continue
        nan = nc == 0
        if nc > 1:
            for i in range(b0, b1):
                x0 = X[i, 0]
                x1 = X[i, 1]
                x2 = X[i, 2]
                x3 = X[i, 3]
                lab = cand[0]
                a0 = x0 - cc[lab, 0]
                a1 = x1 - cc[lab, 1]
                a2 = x2 - cc[lab, 2]
                a3 = x3 - cc[lab, 3]
                best = (((a0 * a0) * cc[lab, 4] + (a1 * a1) * cc[lab, 5])
                        + (a2 * a2) * cc[lab, 6]) + (a3 * a3) * cc[lab, 7]
                nan = nan or best != best
                for k in range(1, nc):
                    c = cand[k]
                    a0 = x0 - cc[c, 0]
                    a1 = x1 - cc[c, 1]
                    p = (a0 * a0) * cc[c, 4] + (a1 * a1) * cc[c, 5]
                    if p > best:
                        continue
                    a2 = x2 - cc[c, 2]
                    a3 = x3 - cc[c, 3]
                    d = (p + (a2 * a2) * cc[c, 6]) + (a3 * a3) * cc[c, 7]
                    if d < best:
                        best = d
                        lab = c
                labels[i] = lab
                dmin[i] = best
        if nan:                         # a box beyond _BLOCK_MAX_ABS, or a NaN d²
            for i in range(b0, b1):
                lab, best = _dense_row(cc, X[i, 0], X[i, 1], X[i, 2], X[i, 3], g)
                labels[i] = lab
                dmin[i] = best
                g = lab
        if acc:
            _add_sums(S, w, labels, m, sums, b0, b1)
        g = labels[b1 - 1]
    if run >= 0:
        _run_rows(X, cc, run, q0, r1, labels, dmin, S, w, m, sums, acc)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _run_rows(X, cc, c, r0, r1, labels, dmin, S, w, m, sums, acc):
    """Particles ``r0:r1`` of :func:`_assign_range`, blocks whose one candidate is centre c:
    its d² to each (one loop over the whole run, no branch in it), or, when one is NaN, the
    serial look; ``acc``: the sums (:func:`_add_one`)."""
    c0 = cc[c, 0]                   # (in locals: the stores below could alias ``cc``)
    c1 = cc[c, 1]
    c2 = cc[c, 2]
    c3 = cc[c, 3]
    i0 = cc[c, 4]
    i1 = cc[c, 5]
    i2 = cc[c, 6]
    i3 = cc[c, 7]
    nan = 0
    for i in range(r0, r1):
        a0 = X[i, 0] - c0
        a1 = X[i, 1] - c1
        a2 = X[i, 2] - c2
        a3 = X[i, 3] - c3
        d = (((a0 * a0) * i0 + (a1 * a1) * i1) + (a2 * a2) * i2) + (a3 * a3) * i3
        labels[i] = c
        dmin[i] = d
        nan |= d != d
    if nan != 0:
        g = c
        for i in range(r0, r1):
            lab, best = _dense_row(cc, X[i, 0], X[i, 1], X[i, 2], X[i, 3], g)
            labels[i] = lab
            dmin[i] = best
            g = lab
    if acc:
        if nan == 0 and S.shape[1] == 6:
            _add_one(S, w, m, sums, c, r0, r1)
        else:
            _add_sums(S, w, labels, m, sums, r0, r1)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _moved_list(moved):
    """The indices of the ``moved`` (K,) centres, ascending."""
    idx = np.empty(moved.shape[0], np.int64)
    nm = 0
    for c in range(moved.shape[0]):
        if moved[c]:
            idx[nm] = c
            nm += 1
    return idx[:nm]


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _moved_rows(X, b0, b1, centers, inv, prev, labels, dmin, moved, idx):
    """:func:`_assign_moved`'s answer for particles ``b0:b1``, each on its own: its previous
    centre and d² against the moved centres ``idx``, or every centre when its own moved (or
    its d² is NaN)."""
    for i in range(b0, b1):
        lab = prev[i]
        best = dmin[i]
        full = moved[lab] or best != best
        if not full:
            for k in range(idx.shape[0]):
                c = idx[k]
                d = _d2(X, i, centers, inv, c)
                if d < best or (d == best and c < lab):
                    best = d
                    lab = c
                elif d != d and c == 0:
                    full = True
                    break
        if full:
            lab, best = _nearest_dense(X, i, centers, inv)
        labels[i] = lab
        dmin[i] = best


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _assign_moved(X, centers, inv, prev, labels, dmin, moved, boxes):
    """:func:`_assign_dense`'s labels and d² when only the ``moved`` (K,) centres changed
    since ``prev`` (N,) -- each particle's nearest centre, the lowest index among equal d² --
    and ``dmin`` (its d², overwritten) were taken: a particle whose centre did not move looks
    at the moved centres only (an unmoved centre other than its own was no nearer then, nor
    of a lower index at the same d², and is the same now), the others at every centre.
    A NaN d² (argmin's centre 0 rule) gets the full look too.  When most centres moved, the
    vector loop over every centre.

    From :data:`_BLOCKS_MIN` centres on (finite, as :func:`_assign_blocks`'s blocks; ``boxes``
    from :func:`_boxes`, empty: none), in blocks of :data:`_BLOCK` particles: a block whose particles' centres all stayed put looks
    only at the moved centres whose lower bound over the block's box is not above the
    block's largest d² (the others can neither beat nor tie any particle's own centre), often
    none; a run of blocks with a particle whose centre moved gets the full look of
    :func:`_assign_blocks` (bounded by the boxes: about one d² a particle, where looking at
    every centre for each of the moved clusters' particles cost as much as a whole
    assignment in each late iteration)."""
    K = centers.shape[0]
    idx = _moved_list(moved)
    nm = idx.shape[0]
    if 2 * nm > K:
        _assign_blocks(X, centers, inv, labels, dmin, boxes, boxes, dmin, dmin, boxes,
                       np.bool_(False))
        return
    n = X.shape[0]
    cc, blocks = _centre_rows(centers, inv, _BLOCKS_MIN)
    if not blocks or boxes.shape[0] == 0:
        _moved_rows(X, 0, n, centers, inv, prev, labels, dmin, moved, idx)
        return
    cand = np.empty(K, np.int64)
    run = np.int64(-1)              # the first of a run of blocks that need the full look
    for b in range(boxes.shape[0]):
        b0 = b * _BLOCK
        b1 = b0 + _BLOCK if b0 + _BLOCK < n else n
        ok = boxes[b, 8] != 0.0
        ub = -np.inf
        if ok:
            for i in range(b0, b1):
                v = dmin[i]
                if moved[prev[i]] or not v - v == 0.0:     # (a moved centre; NaN or inf)
                    ok = False
                    break
                ub = v if v > ub else ub
        if not ok:
            # a particle whose centre moved (or with a NaN or inf d², or a box beyond
            # _BLOCK_MAX_ABS): the block gets the full look (every centre, by the box
            # bounds of :func:`_assign_blocks`), with the next such blocks in one call
            if run < 0:
                run = b
            continue
        if run >= 0:
            r0 = run * _BLOCK
            _assign_range(X, centers, inv, labels, dmin, boxes, boxes, dmin, dmin, boxes,
                          np.bool_(False), r0, b0, prev[r0])
            run = -1
        nc = _box_cands(cc, idx, nm, boxes, b, ub, cand)
        if nc == 0:
            for i in range(b0, b1):
                labels[i] = prev[i]
            continue
        for i in range(b0, b1):
            lab, best = _row_vs(X, i, cc, cand, nc, prev[i], dmin[i])
            labels[i] = lab
            dmin[i] = best
    if run >= 0:
        r0 = run * _BLOCK
        _assign_range(X, centers, inv, labels, dmin, boxes, boxes, dmin, dmin, boxes,
                      np.bool_(False), r0, n, prev[r0])


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _summaries(labels, dmin, bl, bub, b_lo, b_hi):
    """For the blocks ``b_lo:b_hi`` of :data:`_BLOCK` particles: ``bl`` the label all their
    particles share (-1 when they differ) and ``bub`` their largest d² (NaN when one is NaN
    or infinite)."""
    n = labels.shape[0]
    for b in range(b_lo, b_hi):
        b0 = b * _BLOCK
        b1 = b0 + _BLOCK if b0 + _BLOCK < n else n
        lab = labels[b0]
        mx = -np.inf
        fin = True
        for i in range(b0, b1):
            if labels[i] != lab:
                lab = -1
            v = dmin[i]
            fin = fin and v - v == 0.0
            mx = v if v > mx else mx
        bl[b] = lab
        bub[b] = mx if fin else np.nan


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _take_new(labels, new, touched, r0, r1):
    """``labels[r0:r1] = new[r0:r1]``, marking the clusters a particle left or joined in
    ``touched``; whether any label changed."""
    changed = False
    for i in range(r0, r1):
        if new[i] != labels[i]:
            changed = True
            touched[new[i]] = True
            touched[labels[i]] = True
            labels[i] = new[i]
    return changed


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _moved_inplace(X, centers, inv, labels, dmin, moved, boxes, bl, bub, new, touched, summ):
    """:func:`_assign_moved` with the labels and d² updated in place (``new`` (N,) scratch),
    the clusters a particle left or joined marked in ``touched`` (K,); ``bl``/``bub`` the
    blocks' :func:`_summaries` (``summ``: up to date, else taken here): a block of one
    unmoved centre whose moved centres' lower bounds all exceed its largest d² is not read
    at all (a late iteration where two centres creep costs about the blocks near them).
    Returns ``(changed, summ)``: whether a label changed, whether ``bl``/``bub`` are up to
    date (for :func:`lloyd`'s sums of the touched clusters)."""
    K = centers.shape[0]
    n = X.shape[0]
    nb = boxes.shape[0]
    idx = _moved_list(moved)
    nm = idx.shape[0]
    cc, blocks = _centre_rows(centers, inv, _BLOCKS_MIN)
    if 2 * nm > K or not blocks or nb == 0:
        _assign_moved(X, centers, inv, labels, new, dmin, moved, boxes)
        return _take_new(labels, new, touched, 0, n), False
    if not summ:
        _summaries(labels, dmin, bl, bub, 0, nb)
    cand = np.empty(K, np.int64)
    changed = False
    run = np.int64(-1)              # the first of a run of blocks that need the full look
    for b in range(nb + 1):
        b0 = b * _BLOCK if b < nb else n
        b1 = b0 + _BLOCK if b0 + _BLOCK < n else n
        if b < nb:
            ok = boxes[b, 8] != 0.0
            lab = bl[b]
            ub = bub[b]
            if ok and lab < 0:                             # a block of several centres
                ub = -np.inf
                for i in range(b0, b1):
                    v = dmin[i]
                    if moved[labels[i]] or not v - v == 0.0:
                        ok = False
                        break
                    ub = v if v > ub else ub
            elif ok:
                ok = not moved[lab] and ub - ub == 0.0
            if not ok:
                if run < 0:
                    run = b
                continue
        if run >= 0:                                       # the full look, by box bounds
            r0 = run * _BLOCK
            _assign_range(X, centers, inv, new, dmin, boxes, boxes, dmin, dmin, boxes,
                          np.bool_(False), r0, b0, labels[r0])
            changed = _take_new(labels, new, touched, r0, b0) or changed
            _summaries(labels, dmin, bl, bub, run, b)
            run = -1
        if b == nb:
            break
        nc = _box_cands(cc, idx, nm, boxes, b, ub, cand)
        if nc == 0:
            continue
        moved_here = False
        for i in range(b0, b1):
            lab, best = _row_vs(X, i, cc, cand, nc, labels[i], dmin[i])
            if lab != labels[i]:
                touched[lab] = True
                touched[labels[i]] = True
                labels[i] = lab
                moved_here = True
            dmin[i] = best
        if moved_here:
            changed = True
            _summaries(labels, dmin, bl, bub, b, b + 1)
    return changed, True


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _scaled(X, i, rm, cs, c):
    """Euclidean distance of particle i to centre c in the space scaled by ``rm`` (4,)."""
    a0 = X[i, 0] * rm[0] - cs[c, 0]
    a1 = X[i, 1] * rm[1] - cs[c, 1]
    a2 = X[i, 2] * rm[2] - cs[c, 2]
    a3 = X[i, 3] * rm[3] - cs[c, 3]
    return math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _min_inv(inv):
    m = np.empty(4, np.float64)
    for d in range(4):
        m[d] = np.inf
    for c in range(inv.shape[0]):
        for d in range(4):
            m[d] = min(m[d], inv[c, d])
    return m


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _metric(centers, m):
    """The scaled space of :func:`assign`: ``rm`` (4,) = sqrt(m), m (4,) at most the inverse
    variances of every centre, and ``cs`` (K, 4) the centres in it."""
    K = centers.shape[0]
    rm = np.sqrt(m)
    cs = np.empty((K, 4), np.float64)
    for c in range(K):
        cs[c, 0] = centers[c, 0] * rm[0]
        cs[c, 1] = centers[c, 1] * rm[1]
        cs[c, 2] = centers[c, 4] * rm[2]
        cs[c, 3] = centers[c, 5] * rm[3]
    return rm, cs


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _grid_of(u, v):
    """A grid of about ``len(u)`` square cells on the points ``(u, v)`` (:func:`grid_build`,
    which coarsens it to at most 4n + 64 cells)."""
    n = u.shape[0]
    u0 = np.inf
    u1 = -np.inf
    v0 = np.inf
    v1 = -np.inf
    for c in range(n):
        u0 = min(u0, u[c])
        u1 = max(u1, u[c])
        v0 = min(v0, v[c])
        v1 = max(v1, v[c])
    du = u1 - u0
    dv = v1 - v0
    g = 1e-6
    if n > 0 and du >= 0.0 and dv >= 0.0:          # False for NaN / inf extents
        g = max(math.sqrt(du * dv / n), max(du, dv) / n, 1e-6)
    return grid_build(u, v, g, g)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _slack(pu, pv, x0, y0, g, r):
    """Float slack of a ring bound: the cell edges and the point are O(|coordinates|)."""
    return 1e-9 * (1.0 + abs(pu) + abs(pv) + abs(x0) + abs(y0) + g * r)


#: A centre with more centres than this in its 3 × 3 block of cells gets no neighbour list
#: (its particles use the ring search), so the lists stay O(K) in memory however crowded.
_MAX_NEIGHBOURS = 64


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _neighbours(cs, x0, y0, g, ni, nj, order, starts):
    """Each centre's nearby centres by increasing scaled distance, as CSR arrays
    ``(first (K+1,), nb, nbd, cover (K,))``: every other centre within ``cover[c]`` of c is in
    c's list (those of its 3 × 3 block of cells closer than the block's edge, whose distance
    from c is ``cover[c]``; the centres beyond are at least that far).  A crowded block gives
    an empty list and ``cover`` 0."""
    K = cs.shape[0]
    cover = np.zeros(K, np.float64)
    count = np.zeros(K + 1, np.int64)
    for sweep in range(2):
        if sweep == 1:
            for c in range(K):
                count[c + 1] += count[c]
            nb = np.empty(count[K], np.int64)
            nbd = np.empty(count[K], np.float64)
        for c in range(K):
            pu = cs[c, 0]
            pv = cs[c, 1]
            ci = min(int((pu - x0) / g), ni - 1)
            cj = min(int((pv - y0) / g), nj - 1)
            if sweep == 0:
                cover[c] = min(pu - (x0 + (ci - 1) * g), x0 + (ci + 2) * g - pu,
                               pv - (y0 + (cj - 1) * g), y0 + (cj + 2) * g - pv)
                cover[c] = max(0.0, cover[c] - _slack(pu, pv, x0, y0, g, 2))
                crowd = 0
                for a in range(max(ci - 1, 0), min(ci + 1, ni - 1) + 1):
                    for b in range(max(cj - 1, 0), min(cj + 1, nj - 1) + 1):
                        crowd += starts[a * nj + b + 1] - starts[a * nj + b]
                if crowd > _MAX_NEIGHBOURS + 1:
                    cover[c] = 0.0
            q = count[c] if sweep == 1 else 0
            if cover[c] > 0.0:
                for a in range(max(ci - 1, 0), min(ci + 1, ni - 1) + 1):
                    for b in range(max(cj - 1, 0), min(cj + 1, nj - 1) + 1):
                        cell = a * nj + b
                        for k in range(starts[cell], starts[cell + 1]):
                            e = order[k]
                            if e == c:
                                continue
                            a0 = cs[c, 0] - cs[e, 0]
                            a1 = cs[c, 1] - cs[e, 1]
                            a2 = cs[c, 2] - cs[e, 2]
                            a3 = cs[c, 3] - cs[e, 3]
                            d = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3)
                            if d < cover[c]:
                                if sweep == 0:
                                    count[c + 1] += 1
                                else:
                                    nb[q] = e
                                    nbd[q] = d
                                    q += 1
            if sweep == 1 and count[c + 1] - count[c] > 1:
                # stable insertion sort of the (short: <= _MAX_NEIGHBOURS) list by distance:
                # the order of a stable argsort, without compiling numba's mergesort and its
                # fancy-index assignment (whose error message pulls in the string machinery:
                # half the first run's compile time, issue 22)
                lo = count[c]
                for a in range(lo + 1, count[c + 1]):
                    d = nbd[a]
                    e = nb[a]
                    b = a - 1
                    while b >= lo and nbd[b] > d:
                        nbd[b + 1] = nbd[b]
                        nb[b + 1] = nb[b]
                        b -= 1
                    nbd[b + 1] = d
                    nb[b + 1] = e
    return count, nb, nbd, cover


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _cell_guess(cs, x0, y0, g, ni, nj, order, starts):
    """(ni·nj,) a first-guess centre per cell, for particles with no previous label: the
    cell's centre nearest to its middle, or (empty cell) the better of its neighbours'
    guesses, spread by one forward and one backward sweep over the grid (O(cells + K)).
    Any guess gives the exact answer (:func:`_ring_search` starts from it); a near one
    lets the search stop after a ring or two."""
    rep = np.empty(ni * nj, np.int64)
    score = np.empty(ni * nj, np.float64)
    for q in range(ni * nj):
        rep[q] = -1
        score[q] = np.inf
    for a in range(ni):
        for b in range(nj):
            cell = a * nj + b
            mu = x0 + (a + 0.5) * g
            mv = y0 + (b + 0.5) * g
            for k in range(starts[cell], starts[cell + 1]):
                c = order[k]
                d = (cs[c, 0] - mu) ** 2 + (cs[c, 1] - mv) ** 2
                if d < score[cell]:
                    score[cell] = d
                    rep[cell] = c
    for sweep in range(2):
        step = 1 if sweep == 0 else -1
        for q in range(ni * nj):
            cell = q if sweep == 0 else ni * nj - 1 - q
            a = cell // nj
            b = cell - a * nj
            mu = x0 + (a + 0.5) * g
            mv = y0 + (b + 0.5) * g
            for t in range(2):
                na = a - step if t == 0 else a
                nb = b if t == 0 else b - step
                if na < 0 or na >= ni or nb < 0 or nb >= nj:
                    continue
                c = rep[na * nj + nb]
                if c < 0:
                    continue
                d = (cs[c, 0] - mu) ** 2 + (cs[c, 1] - mv) ** 2
                if d < score[cell]:
                    score[cell] = d
                    rep[cell] = c
    return rep


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _visit(X, i, centers, inv, order, starts, cell, lab, best):
    for k in range(starts[cell], starts[cell + 1]):
        c = order[k]
        d = _d2(X, i, centers, inv, c)
        if d < best or (d == best and c < lab):
            best = d
            lab = c
    return lab, best


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _ring_search(X, i, pu, pv, centers, inv, lab, best, x0, y0, g, ni, nj, order, starts):
    """The nearest centre (lowest index on ties) of particle i at scaled ``(pu, pv)``, from
    ``(lab, best)`` (a centre and its d², or ``(-1, inf)``): the grid's cells in rings of
    growing Chebyshev radius around the particle's cell, until the particle's distance to the
    edge of the rings looked at exceeds sqrt(best) — every centre beyond has ``d² >= e²``
    greater than it (a tie could not be missed: the test is strict, with float slack)."""
    fi = math.floor((pu - x0) / g)
    fj = math.floor((pv - y0) / g)
    if not (abs(fi) < 1e12 and abs(fj) < 1e12):   # absurd coordinates: look at every centre
        return _nearest_dense(X, i, centers, inv)
    ci = int(fi)
    cj = int(fj)
    r0 = max(0, -ci, ci - (ni - 1), -cj, cj - (nj - 1))     # the first ring that meets the grid
    r1 = max(ci, ni - 1 - ci, cj, nj - 1 - cj)              # the ring that covers it all
    for r in range(r0, r1 + 1):
        if r > 0:
            # every unvisited cell is outside the (2r - 1)² square of rings 0..r-1 around
            # (ci, cj), which holds the particle
            edge = min(pu - (x0 + (ci - r + 1) * g), x0 + (ci + r) * g - pu,
                       pv - (y0 + (cj - r + 1) * g), y0 + (cj + r) * g - pv)
            if edge - _slack(pu, pv, x0, y0, g, r) > math.sqrt(best) * (1.0 + 1e-9):
                break
        for a in range(max(ci - r, 0), min(ci + r, ni - 1) + 1):
            if a == ci - r or a == ci + r:
                for b in range(max(cj - r, 0), min(cj + r, nj - 1) + 1):
                    lab, best = _visit(X, i, centers, inv, order, starts, a * nj + b, lab, best)
            else:
                b = cj - r
                if 0 <= b < nj:
                    lab, best = _visit(X, i, centers, inv, order, starts, a * nj + b, lab, best)
                b = cj + r
                if 0 <= b < nj:
                    lab, best = _visit(X, i, centers, inv, order, starts, a * nj + b, lab, best)
    return lab, best


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _assign(X, centers, inv, prev, labels, dmin, grid_min, m, stable, reach):
    """:func:`assign` in the space scaled by sqrt(m) (m (4,) at most every centre's inverse
    variances), plus: a particle whose previous centre is ``stable`` (K,) keeps its
    label and d² (the caller knows they cannot have changed), and ``reach`` (N,) receives
    ``e + sqrt(d²)`` of each particle looked at (e its scaled distance to its centre; from
    ``grid_min`` centres on)."""
    n = X.shape[0]
    K = centers.shape[0]
    if K == 0:
        return
    if K < grid_min:
        _assign_dense(X, centers, inv, labels, dmin)
        return
    rm, cs = _metric(centers, m)
    ok, x0, y0, g, g2, ni, nj, order, starts = _grid_of(cs[:, 0].copy(), cs[:, 1].copy())
    if not ok:                                     # a non-finite centre: look at all of them
        _assign_dense(X, centers, inv, labels, dmin)
        for i in range(n):
            reach[i] = np.inf
        return
    first, nb, nbd, cover = _neighbours(cs, x0, y0, g, ni, nj, order, starts)
    rep = np.empty(0, np.int64)                    # first guesses, made on first need
    for i in range(n):
        lab = prev[i]
        pu = X[i, 0] * rm[0]
        pv = X[i, 1] * rm[1]
        if not (np.isfinite(pu) and np.isfinite(pv)):
            labels[i], dmin[i] = _nearest_dense(X, i, centers, inv)
            reach[i] = np.inf
            continue
        if lab >= 0 and lab < K and stable[lab]:
            labels[i] = lab
            continue
        if not (lab >= 0 and lab < K) and i > 0 and labels[i - 1] >= 0 and labels[i - 1] < K:
            # no previous label (the first iteration): start from particle i − 1's answer --
            # resampling keeps an ancestor's copies, and a target's particles, side by side
            lab = labels[i - 1]
        if not (lab >= 0 and lab < K):
            if rep.shape[0] == 0:
                rep = _cell_guess(cs, x0, y0, g, ni, nj, order, starts)
            fi = math.floor((pu - x0) / g)
            fj = math.floor((pv - y0) / g)
            a = 0 if not fi > 0.0 else (ni - 1 if fi > ni - 1.0 else int(fi))
            b = 0 if not fj > 0.0 else (nj - 1 if fj > nj - 1.0 else int(fj))
            lab = rep[a * nj + b]
        if lab >= 0:
            best = _d2(X, i, centers, inv, lab)
            e0 = _scaled(X, i, rm, cs, lab)
            # triangle inequality in the scaled space: a centre c at D(lab, c) from lab has
            # d(x, c) >= D(lab, c) − e0; c's list holds every centre nearer than cover[lab],
            # by increasing D, so the first listed one beyond sqrt(best) + e0 ends the look
            slack = 1e-9 * (1.0 + e0)
            c0 = lab
            done = False
            for q in range(first[c0], first[c0 + 1]):
                if nbd[q] - e0 > math.sqrt(best) * (1.0 + 1e-9) + slack:
                    done = True
                    break
                c = nb[q]
                d = _d2(X, i, centers, inv, c)
                if d < best or (d == best and c < lab):
                    best = d
                    lab = c
            if done or cover[c0] - e0 > math.sqrt(best) * (1.0 + 1e-9) + slack:
                labels[i] = lab                 # the usual case: no centre beyond the list
                dmin[i] = best
                reach[i] = (e0 if lab == c0 else _scaled(X, i, rm, cs, lab)) + math.sqrt(best)
                continue
        else:
            lab = -1
            best = np.inf
        lab, best = _ring_search(X, i, pu, pv, centers, inv, lab, best, x0, y0, g, ni, nj,
                                 order, starts)
        labels[i] = lab
        dmin[i] = best
        reach[i] = _scaled(X, i, rm, cs, lab) + math.sqrt(best)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def assign(X, centers, inv, prev, labels, dmin, grid_min):
    """Nearest centre of every particle (the lowest index among equal d², as ``argmin`` over
    all centres) into ``labels``/``dmin``; ``X`` (N, 4) the particles' (y1, y2, w, h),
    ``centers`` (K, 6), ``inv`` (K, 4) from :func:`_inv_var`; ``prev`` (N,) a previous label
    per particle (a first guess, -1 for none).

    Below ``grid_min`` centres every centre is looked at.  From ``grid_min`` on, exact too:
    every centre's inverse variances are at least ``m`` (their minimum over the centres,
    per coordinate), so in the (y1, y2, w, h) space scaled by ``sqrt(m)`` a centre at
    Euclidean distance e has ``d² >= e²``, and at least its (y1, y2) distance.

    A particle starts from its previous centre (else particle i − 1's answer, else a first
    guess per grid cell, :func:`_cell_guess`) at scaled distance e₀, and looks at that centre's neighbours
    (:func:`_neighbours`, by increasing distance D) until ``D − e₀ > sqrt(best d²)``; only when
    the list ends before that does it search the grid's rings (:func:`_ring_search`).  Time and
    memory are O(N + K) for K centres spread at about one per cell (no K × K table)."""
    _assign(X, centers, inv, prev, labels, dmin, grid_min, _min_inv(inv),
            np.zeros(centers.shape[0], np.bool_), np.empty(X.shape[0], np.float64))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _near(centers, rm, c, e, R):
    """Whether centre e is within scaled distance R of centre c (not strictly beyond it)."""
    a0 = (centers[c, 0] - centers[e, 0]) * rm[0]
    a1 = (centers[c, 1] - centers[e, 1]) * rm[1]
    a2 = (centers[c, 4] - centers[e, 4]) * rm[2]
    a3 = (centers[c, 5] - centers[e, 5]) * rm[3]
    return not math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3) > R


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _unstable_near_moved(centers, space, moved, stable, reach_c):
    """Clear ``stable[c]`` of every centre with a ``moved`` centre within its reach
    (``reach_c[c]``, with float slack) in the space scaled by sqrt(space).  The moved centres
    are put on a grid and each stable centre looks only at the cells its reach touches (or at
    the moved list, when that is shorter): O(K + moved) for reaches of a cell or so."""
    K = centers.shape[0]
    rm = np.sqrt(space)
    idx = _moved_list(moved)
    nm = idx.shape[0]
    if nm == 0:
        return
    mu = np.empty(nm, np.float64)
    mv = np.empty(nm, np.float64)
    for k in range(nm):
        mu[k] = centers[idx[k], 0] * rm[0]
        mv[k] = centers[idx[k], 1] * rm[1]
    ok, x0, y0, g, g2, ni, nj, order, starts = _grid_of(mu, mv)
    for c in range(K):
        if not stable[c]:
            continue
        R = reach_c[c] * (1.0 + 1e-9) + 1e-9
        cu = centers[c, 0] * rm[0]
        cv = centers[c, 1] * rm[1]
        pad = R + 1e-7 * (1.0 + abs(cu) + abs(cv) + abs(x0) + abs(y0))
        a0, a1 = grid_span(cu - pad, cu + pad, x0, g, ni)
        b0, b1 = grid_span(cv - pad, cv + pad, y0, g, nj)
        if ok and np.isfinite(pad) and (a1 - a0 + 1) * (b1 - b0 + 1) < nm:
            if a1 < a0 or b1 < b0:
                continue                            # no moved centre near
            for a in range(a0, a1 + 1):
                for b in range(b0, b1 + 1):
                    cell = a * nj + b
                    for k in range(starts[cell], starts[cell + 1]):
                        if _near(centers, rm, c, idx[order[k]], R):
                            stable[c] = False
                            break
                    if not stable[c]:
                        break
                if not stable[c]:
                    break
        else:
            for k in range(nm):
                if _near(centers, rm, c, idx[k], R):
                    stable[c] = False
                    break


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def farthest(labels, dmin, K):
    """(K,) each cluster's member with the largest ``dmin`` (its d² to the centre), -1 for an
    empty cluster: for cluster j the particle ``members[argmax(dmin[members])]`` with
    ``members = flatnonzero(labels == j)`` (the first of equal values; a NaN wins, as in
    ``np.argmax``), for every cluster in one pass instead of one O(N) pass per split
    candidate."""
    far = np.empty(K, np.int64)
    for c in range(K):
        far[c] = -1
    for i in range(labels.shape[0]):
        c = labels[i]
        f = far[c]
        if f < 0:
            far[c] = i
        elif dmin[f] != dmin[f]:                   # a NaN already: the first NaN stays
            continue
        elif dmin[i] > dmin[f] or dmin[i] != dmin[i]:
            far[c] = i
    return far


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def prepare(states, log_w):
    """The inputs of :func:`lloyd` from the particles, in two passes (numpy's spelling took
    five passes and as many temporaries), with each run of consecutive identical state rows
    merged into one row weighing their sum: ``lmax`` the largest log-weight (when it is not
    finite, nothing else is computed), ``w`` (M,) the weights relative to it
    ``exp(log_w − lmax)`` summed over each run, ``shift`` (6,) the mean position ``(y1, y2)``
    of every particle (zeros elsewhere), ``S`` (M, 6) the runs' states minus it, ``X`` (M, 4)
    their ``(y1, y2, w, h)`` and ``runs`` (M,) each run's length (``np.repeat(labels, runs)``
    gives every particle its row's label).  The same floats as ``np.max``, ``np.exp`` (taken
    once per run of equal log-weights), ``states[:, :2].mean(axis=0)`` (an axis-0 sum, row by
    row) and the subtraction.

    Why merge: systematic resampling lays the copies of an ancestor side by side as identical
    rows (about a third of the rows on the bench scene), and weighted K-means on the distinct
    rows with their summed weights has the same labels, and the same centres and masses up to
    summation round-off, for a third less work in every pass of the Lloyd iterations and the
    split trials.  Rows are compared with ``==`` (a NaN row is never merged)."""
    n = states.shape[0]
    lmax = -np.inf
    a0 = 0.0                                       # (the position sums in the same pass)
    a1 = 0.0
    for i in range(n):
        if log_w[i] > lmax:
            lmax = log_w[i]
        elif log_w[i] != log_w[i]:                 # NaN: np.max's answer
            lmax = np.nan
            break
        a0 += states[i, 0]
        a1 += states[i, 1]
    shift = np.empty(6, np.float64)
    for d in range(6):
        shift[d] = 0.0
    w = np.empty(n, np.float64)
    S = np.empty((n, 6), np.float64)
    X = np.empty((n, 4), np.float64)
    runs = np.empty(n, np.int64)
    if n == 0 or not lmax - lmax == 0.0:          # (not finite; no np.isfinite to compile)
        return lmax, w, shift, S, X, runs
    shift[0] = a0 / n
    shift[1] = a1 / n
    # a run of equal log-weights (after resampling every particle has the same one) takes
    # the exp once: the same float for the same argument
    lp = np.nan
    wp = 0.0
    m = 0
    for i in range(n):
        if log_w[i] != lp:
            lp = log_w[i]
            wp = math.exp(lp - lmax)
        if i > 0 and states[i, 0] == states[i - 1, 0] and states[i, 1] == states[i - 1, 1] \
                and states[i, 2] == states[i - 1, 2] and states[i, 3] == states[i - 1, 3] \
                and states[i, 4] == states[i - 1, 4] and states[i, 5] == states[i - 1, 5]:
            w[m - 1] += wp                         # a copy of the row before: merged
            runs[m - 1] += 1
            continue
        w[m] = wp
        runs[m] = 1
        for d in range(6):
            S[m, d] = states[i, d] - shift[d]
        X[m, 0] = S[m, 0]
        X[m, 1] = S[m, 1]
        X[m, 2] = S[m, 4]
        X[m, 3] = S[m, 5]
        m += 1
    return lmax, w[:m], shift, S[:m], X[:m], runs[:m]


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def prepare_copies(states, log_w, copies, pos):
    """:func:`prepare` for particles that are runs of consecutive copies of a row, ``copies``
    (R,) their lengths (systematic resampling's record, :meth:`~..smc.weights.ParticleSet.known_copies`),
    every log-weight equal: the same floats with no comparison of every row with the one
    before.  ``exp(log_w − lmax)`` is exp(0) = 1 for each particle, so a merged row weighs
    its particle count (a sum of ones, exact); the shift sums every particle's position in
    particle order (a run's row added once per copy, the very additions of :func:`prepare`);
    a run whose row equals the previous run's (two ancestors with identical rows) is merged
    into it, as :func:`prepare` would.  ``states`` (N, 6) with ``N = sum(copies)``.  ``pos``
    (2,): those position sums when the maker of the set took them (systematic resampling's
    walk, :meth:`~..smc.weights.ParticleSet.copy_sums`: the same additions in the same
    order), else empty."""
    n = states.shape[0]
    R = copies.shape[0]
    lmax = log_w[0] if n > 0 else -np.inf
    shift = np.empty(6, np.float64)
    for d in range(6):
        shift[d] = 0.0
    w = np.empty(R, np.float64)
    S = np.empty((R, 6), np.float64)
    X = np.empty((R, 4), np.float64)
    # the rows' run lengths are ``copies`` until two runs merge (rare: none on the bench
    # scene): no array of their own to write until then
    runs = copies
    merged = False
    if n == 0 or not lmax - lmax == 0.0:          # (not finite; no np.isfinite to compile)
        return lmax, w[:0], shift, S[:0], X[:0], runs[:0]
    a0 = 0.0
    a1 = 0.0
    if pos.shape[0] == 2:
        a0 = pos[0]
        a1 = pos[1]
    else:
        i = 0
        for r in range(R):
            v0 = states[i, 0]
            v1 = states[i, 1]
            for t in range(copies[r]):
                a0 += v0
                a1 += v1
            i += copies[r]
    shift[0] = a0 / n
    shift[1] = a1 / n
    m = 0
    i = 0
    for r in range(R):
        c = copies[r]
        if i > 0 and states[i, 0] == states[i - 1, 0] and states[i, 1] == states[i - 1, 1] \
                and states[i, 2] == states[i - 1, 2] and states[i, 3] == states[i - 1, 3] \
                and states[i, 4] == states[i - 1, 4] and states[i, 5] == states[i - 1, 5]:
            w[m - 1] += c                          # the previous run's row again: merged
            if not merged:
                runs = np.empty(R, np.int64)
                for q in range(m):
                    runs[q] = copies[q]
                merged = True
            runs[m - 1] += c
            i += c
            continue
        w[m] = c
        if merged:
            runs[m] = c
        for d in range(6):
            S[m, d] = states[i, d] - shift[d]
        X[m, 0] = S[m, 0]
        X[m, 1] = S[m, 1]
        X[m, 2] = S[m, 4]
        X[m, 3] = S[m, 5]
        m += 1
        i += c
    return lmax, w[:m], shift, S[:m], X[:m], runs[:m]


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def lloyd(X, S, w, centers, max_iter, tol, sigma_obs, sigma_min, pos_ratio, grid_min):
    """Weighted Lloyd iterations (maggio2007 §3) from ``centers`` (K, 6) until the labels are
    stable, no centre's (y1, y2, w, h) moved more than ``tol`` (> 0), or ``max_iter``
    iterations (then the labels are the nearest centres; ``grid_min``: :func:`assign`, or
    None: every centre is looked at, and numba compiles none of the grid search -- its dead
    branches are pruned for a None argument -- so a run that never has ``grid_min`` centres
    never pays for compiling it).
    ``X`` (N, 4) the particles' (y1, y2, w, h), ``S`` (N, 6) their states, ``w`` (N,)
    weights.  Returns ``(centers, labels, masses, dmin, iterations)``; an empty cluster keeps
    its centre.  Same floats as the numpy iteration (distances and sums in the same order).

    Late iterations cost little: only the clusters that lost or gained a particle have their
    sums redone (over their members, in particle order: the very floats of a full pass), and
    only those centres move; a particle whose centre did not move and has no moved centre
    within its reach (``e + sqrt(d²)`` of :func:`_assign`, in a scaled space kept across
    iterations) keeps its label without a look (no centre that could beat it has changed)."""
    centers = centers.copy()
    n = X.shape[0]
    K = centers.shape[0]
    D = S.shape[1]
    # (one spelling per dtype for every allocation of the kernels: each distinct np.zeros /
    # np.empty / np.full signature is one more numba compile on the first run; np.empty
    # filled by loops, no np.zeros: the dense K-means then compiles none of np.zeros'
    # overloads, nor their zero fills)
    labels = np.empty(n, np.int64)
    new = np.empty(n, np.int64)
    dmin = np.empty(n, np.float64)
    if grid_min is None:
        # the dense look writes every label and d² before they are read, and keeps no
        # reaches: no fill pass, no reach array (fewer fresh pages a call)
        reach = np.empty(0, np.float64)
    else:
        reach = np.empty(n, np.float64)
        for i in range(n):
            labels[i] = -1
            new[i] = -1
            dmin[i] = 0.0
            reach[i] = 0.0
    m = np.empty(K, np.float64)
    sums = np.empty((K, D), np.float64)
    stable = np.empty(K, np.bool_)
    moved = np.empty(K, np.bool_)
    touched = np.empty(K, np.bool_)
    reach_c = np.empty(K, np.float64)
    for c in range(K):
        m[c] = 0.0
        for d in range(D):
            sums[c, d] = 0.0
        stable[c] = False
        moved[c] = True
        touched[c] = True
        reach_c[c] = 0.0
    space = np.empty(4, np.float64)
    for d in range(4):
        space[d] = 0.0
    # the dense look's blocks of particles (their boxes, once for every assignment)
    boxes = _boxes(X) if grid_min is None and K >= _BLOCKS_MIN else np.empty((0, 9), np.float64)
    it = 0
    done = False
    # the blocks' summaries for the late dense iterations (:func:`_moved_inplace`)
    bl = np.empty(boxes.shape[0], np.int64)
    bub = np.empty(boxes.shape[0], np.float64)
    summ = False
    for it in range(1, max_iter + 1):
        inv = _inv_var(centers, sigma_obs, sigma_min, pos_ratio)
        summed = False
        late = False
        if grid_min is None:
            if it == 1:
                # the labels and the sums in one pass (their copy and the sums pass below
                # are not needed: every cluster is touched, the sums start at zero)
                _assign_blocks(X, centers, inv, labels, dmin, boxes, S, w, m, sums, np.bool_(True))
                summed = True
            elif D == 6 and boxes.shape[0] > 0:
                # in place, the comparison and the blocks' summaries with it
                for c in range(K):
                    touched[c] = False
                changed, summ = _moved_inplace(X, centers, inv, labels, dmin, moved, boxes,
                                               bl, bub, new, touched, summ)
                if not changed:
                    done = True
                    break
                late = True
            else:
                _assign_moved(X, centers, inv, labels, new, dmin, moved, boxes)
        else:
            if K >= grid_min:
                # the scaled space: a little below the smallest inverse variances, kept while
                # every centre stays above it (so the reaches of the last iteration stay valid)
                mm = _min_inv(inv)
                same_space = it > 1
                for d in range(4):
                    if mm[d] < space[d]:
                        same_space = False
                if not same_space:
                    for d in range(4):
                        space[d] = 0.9 * mm[d]
                # skip the particles of unmoved centres with no moved centre within their reach
                for c in range(K):
                    stable[c] = same_space and not moved[c]
                if same_space:
                    _unstable_near_moved(centers, space, moved, stable, reach_c)
            _assign(X, centers, inv, labels, new, dmin, grid_min, space, stable, reach)
        if late:
            pass                                # (compared and copied in place)
        elif it > 1:
            for c in range(K):
                touched[c] = False
            changed = False
            for i in range(n):                  # (the comparison and the copy in one pass)
                if new[i] != labels[i]:
                    changed = True
                    touched[new[i]] = True
                    touched[labels[i]] = True
                    labels[i] = new[i]
            if not changed:
                done = True
                break
        elif not summed:
            for i in range(n):
                labels[i] = new[i]
        if not summed:
            # sums of the touched clusters, over their members in particle order (and the
            # reaches, the grid search's only, in the same pass)
            for c in range(K):
                if touched[c]:
                    m[c] = 0.0
                    for d in range(D):
                        sums[c, d] = 0.0
                    reach_c[c] = 0.0
            if grid_min is None and D == 6 and summ:
                # the blocks of one touched cluster, the others' not read, the blocks of
                # several by runs (:func:`_add_one`: the same additions in the same order)
                nbk = boxes.shape[0]
                for b in range(nbk):
                    b0 = b * _BLOCK
                    b1 = b0 + _BLOCK if b0 + _BLOCK < n else n
                    c = bl[b]
                    if c >= 0:
                        if touched[c]:
                            _add_one(S, w, m, sums, c, b0, b1)
                        continue
                    i = b0
                    while i < b1:
                        c = labels[i]
                        j = i + 1
                        while j < b1 and labels[j] == c:
                            j += 1
                        if touched[c]:
                            _add_one(S, w, m, sums, c, i, j)
                        i = j
            elif grid_min is None and D == 6:
                # each run of particles of one touched cluster with its sums in registers
                # (:func:`_add_one`: the same additions in the same order)
                i = 0
                while i < n:
                    c = labels[i]
                    j = i + 1
                    while j < n and labels[j] == c:
                        j += 1
                    if touched[c]:
                        _add_one(S, w, m, sums, c, i, j)
                    i = j
            else:
                for i in range(n):
                    c = labels[i]
                    if touched[c]:
                        wi = w[i]
                        m[c] += wi
                        for d in range(D):
                            sums[c, d] += S[i, d] * wi
                    if grid_min is not None:
                        reach_c[c] = max(reach_c[c], reach[i])
        step = 0.0
        for c in range(K):
            moved[c] = False
            if touched[c] and m[c] > 0:
                for d in range(D):
                    val = sums[c, d] / m[c]
                    if d == 0 or d == 1 or d == 4 or d == 5:
                        a = abs(val - centers[c, d])
                        step = a if a > step else step          # max(step, a)
                        if val != centers[c, d]:
                            moved[c] = True
                    centers[c, d] = val
        if tol > 0 and step <= tol:
            done = True
            break
    if not done:
        inv = _inv_var(centers, sigma_obs, sigma_min, pos_ratio)
        if grid_min is None:
            if it == 0:
                _assign_blocks(X, centers, inv, new, dmin, boxes, boxes, dmin, dmin, boxes,
                               np.bool_(False))
            else:
                _assign_moved(X, centers, inv, labels, new, dmin, moved, boxes)
        else:
            for c in range(K):
                stable[c] = False
            _assign(X, centers, inv, labels, new, dmin, grid_min, _min_inv(inv), stable, reach)
        for i in range(n):
            labels[i] = new[i]
        masses = np.empty(K, np.float64)
        for c in range(K):
            masses[c] = 0.0
        for i in range(n):
            masses[labels[i]] += w[i]
        return centers, labels, masses, dmin, it
    # converged: the returned labels are those of the last sums, and each cluster's m is the
    # sum of its members' weights in particle order -- the very floats of a masses pass
    return centers, labels, m, dmin, it


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def split_neighbours(centers, K, j, reach2, n_max, sigma_obs, sigma_min, pos_ratio, out):
    """The clusters a split of cluster j is tried on, into ``out[:count]`` (ascending; returns
    count): j and its nearest clusters among the first K, at most ``n_max``, whose centres lie
    within twice j's reach (``reach2``: the d² of j's farthest member, under j's metric) -- by
    distance then index when more are in reach.  The distance is ``Σ_d (c_d − j_d)² inv_d``
    over (y1, y2, w, h) at j's size, summed in coordinate order (numpy's sum of 4 terms)."""
    sw = sigma_obs * centers[j, 4]          # (:func:`_inv_var` of centre j)
    sw = sigma_min if sigma_min > sw else sw
    sh = sigma_obs * centers[j, 5]
    sh = sigma_min if sigma_min > sh else sh
    a = pos_ratio * sw
    b = pos_ratio * sh
    i0 = 1.0 / (a * a)
    i1 = 1.0 / (b * b)
    i2 = 1.0 / (sw * sw)
    i3 = 1.0 / (sh * sh)
    lim = 4.0 * reach2
    dc = np.empty(K, np.float64)
    cnt = 0
    for c in range(K):
        a = centers[c, 0] - centers[j, 0]
        d = (a * a) * i0
        a = centers[c, 1] - centers[j, 1]
        d += (a * a) * i1
        a = centers[c, 4] - centers[j, 4]
        d += (a * a) * i2
        a = centers[c, 5] - centers[j, 5]
        d += (a * a) * i3
        dc[c] = d
        if d <= lim:
            cnt += 1
    if cnt <= n_max:
        k = 0
        for c in range(K):
            if dc[c] <= lim:
                out[k] = c
                k += 1
        return cnt
    # a crowd: the n_max nearest (distance, then index), then by index
    for k in range(n_max):
        best = -1
        for c in range(K):
            if dc[c] <= lim:
                dup = False
                for q in range(k):
                    if out[q] == c:
                        dup = True
                        break
                if not dup and (best < 0 or dc[c] < dc[best]):
                    best = c
        out[k] = best
    for k in range(1, n_max):               # then by index (insertion sort: a few entries)
        e = out[k]
        q = k
        while q > 0 and out[q - 1] > e:
            out[q] = out[q - 1]
            q -= 1
        out[q] = e
    return n_max


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def split_clusters(X, S, w, centers, masses, labels, dmin, scale, split_above, need,
                   min_split_mass, guarded, max_splits, n_near, max_iter, tol, sigma_obs,
                   sigma_min, pos_ratio):
    """The split loop of maggio2007 §3's modified K-means after the first Lloyd run
    (clustering module docstring: the guarded and literal rules, the local trials), in one
    pass: at most ``max_splits`` candidates -- clusters of mass above ``split_above`` not
    final yet, heaviest first (the lowest index among equal masses) -- are looked at, one at
    a time.  A candidate lighter than ``need`` (``guarded``: 2 ``min_split_mass``, else
    -inf) or with no member off its centre is final; else a new centre on its farthest
    member and :func:`lloyd` on its neighbourhood's particles (:func:`split_neighbours`: j
    and at most ``n_near`` - 1 more clusters); ``guarded``:
    kept only if j and the new cluster both reach ``min_split_mass``.

    ``X``, ``S``, ``w`` as for :func:`lloyd`; ``centers`` (K, 6), ``masses`` (K,) (times
    ``scale``), ``labels``, ``dmin`` from the first Lloyd run (not modified).  Returns
    ``(centers, masses, labels, dmin, n_splits, n_iter)`` (the new centres appended)."""
    n = X.shape[0]
    K = centers.shape[0]
    cap = K + (max_splits if max_splits > 0 else 0)
    C = np.empty((cap, 6), np.float64)
    M = np.empty(cap, np.float64)
    final = np.empty(cap, np.bool_)
    for c in range(K):
        for d in range(6):
            C[c, d] = centers[c, d]
        M[c] = masses[c]
        final[c] = False
    # (made on first need: most frames try no split -- no candidate, or each one lighter
    # than ``need`` -- and then copy, scan and allocate nothing per particle)
    lab = labels
    dm = dmin
    copied = False
    far_of = np.empty(0, np.int64)
    pick = np.empty(0, np.int64)
    near = np.empty(n_near, np.int64)
    is_local = np.empty(cap, np.bool_)
    n_splits = 0
    n_iter = 0
    budget = max_splits
    while budget > 0:
        j = np.int64(-1)                   # (not the literal: one split_neighbours compile)
        for c in range(K):
            if M[c] > split_above and not final[c] and (j < 0 or M[c] > M[j]):
                j = c
        if j < 0:
            break
        budget -= 1
        if M[j] < need:                    # guarded: j's own mass cannot give both halves
            final[j] = True                # min_split_mass (a single target, no trial)
            continue
        if far_of.shape[0] == 0:
            far_of = farthest(lab, dm, K)
            pick = np.empty(n, np.int64)
        far = far_of[j]
        if far < 0 or dm[far] <= 0.0:      # no member / all on the centre
            final[j] = True
            continue
        nn = split_neighbours(C, K, j, dm[far], n_near, sigma_obs, sigma_min, pos_ratio, near)
        for c in range(K):
            is_local[c] = False
        for q in range(nn):
            is_local[near[q]] = True
        m = 0                              # the neighbourhood's particles, in order
        for i in range(n):
            if is_local[lab[i]]:
                pick[m] = i
                m += 1
        sel = pick[:m]
        Xs = np.empty((m, 4), np.float64)
        Ss = np.empty((m, 6), np.float64)
        ws = np.empty(m, np.float64)
        for k in range(m):
            i = sel[k]
            for d in range(4):
                Xs[k, d] = X[i, d]
            for d in range(6):
                Ss[k, d] = S[i, d]
            ws[k] = w[i]
        init = np.empty((nn + 1, 6), np.float64)
        for q in range(nn):
            for d in range(6):
                init[q, d] = C[near[q], d]
        for d in range(6):
            init[nn, d] = S[far, d]
        t_c, t_lab, t_m, t_d, it = lloyd(Xs, Ss, ws, init, max_iter, tol, sigma_obs,
                                         sigma_min, pos_ratio, None)
        n_iter += it
        pos = 0                            # np.searchsorted(near, j)
        while pos < nn and near[pos] < j:
            pos += 1
        if guarded and not (t_m[pos] * scale >= min_split_mass
                            and t_m[nn] * scale >= min_split_mass):
            final[j] = True                # guarded rule: revert, this cluster is one target
            continue
        for q in range(nn):
            for d in range(6):
                C[near[q], d] = t_c[q, d]
            M[near[q]] = t_m[q] * scale
        for d in range(6):
            C[K, d] = t_c[nn, d]
        M[K] = t_m[nn] * scale
        if not copied:                     # (the caller's arrays stay as they were)
            lab = labels.copy()
            dm = dmin.copy()
            copied = True
        final[K] = False
        for q in range(m):
            t = t_lab[q]
            lab[sel[q]] = near[t] if t < nn else K
            dm[sel[q]] = t_d[q]
        K += 1
        n_splits += 1
        far_of = farthest(lab, dm, K)
    return C[:K].copy(), M[:K].copy(), lab, dm, n_splits, n_iter


#: ``Clusters.origin`` codes (re-exported by :mod:`.clustering`): a centre made by a split, a
#: centre not initialised on an observation (an extra centre, or the particles' mean).
ORIGIN_SPLIT = -1
ORIGIN_EXTRA = -2


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def peaks(states, log_w, copies, pos, Z, extra, scale, cfg, grid_min):
    """:func:`~.clustering.kmeans_peaks` after its argument checks, in one call (each numpy or
    Python operation of a frame costs 2-3 times more when the caches are cold, as between two
    frames of a real run): the observations' check, :func:`prepare`, the initial centres
    (§3: on the observations ``Z`` (N_z, 4) with zero velocity, then the ``extra`` (E, 6)
    ones; with neither, the particles' weighted mean), :func:`lloyd`, :func:`split_clusters`
    and the kept test ``mass >= T``.  ``scale`` is ``exp(max log_w)`` (numpy's exp, taken by
    the caller; the largest log-weight must be finite).  ``copies`` (R,): the particles are
    runs of copies of R rows, every log-weight equal (:func:`prepare_copies`, with ``pos``
    (2,) their position sums if known, else empty), or empty (:func:`prepare`).  ``cfg`` (12,) the settings ``T, split_above, need, min_split_mass,
    guarded (1.0 / 0.0), max_splits, n_near, max_iter, tol, sigma_obs, sigma_min, pos_ratio``
    (:func:`split_clusters`, :func:`lloyd`: integers as floats).

    Returns ``(bad, centers, masses, labels, runs, kept, origin, n_splits, n_iter,
    kept_centers)`` (``kept_centers`` = ``centers[kept]``):
    ``bad`` 1 for a non-finite observation, 2 for a width or height <= 0 (nothing else
    computed), else 0; ``labels`` (M,) of the merged rows, ``runs`` (M,) their lengths."""
    T = cfg[0]
    split_above = cfg[1]
    need = cfg[2]
    min_split_mass = cfg[3]
    guarded = cfg[4] != 0.0
    max_splits = int(cfg[5])
    n_near = int(cfg[6])
    max_iter = int(cfg[7])
    tol = cfg[8]
    sigma_obs = cfg[9]
    sigma_min = cfg[10]
    pos_ratio = cfg[11]
    nz = Z.shape[0]
    bad = 0
    for c in range(nz):
        for d in range(4):
            v = Z[c, d]
            if not v - v == 0.0:                   # (not finite)
                bad = 1
    if bad == 0:
        for c in range(nz):
            if not (Z[c, 2] > 0.0 and Z[c, 3] > 0.0):
                bad = 2
    ne = extra.shape[0]
    K0 = nz + ne
    k0 = K0 if K0 > 0 else 1
    if bad != 0:
        return (bad, np.empty((0, 6), np.float64), np.empty(0, np.float64),
                np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.bool_),
                np.empty(0, np.int64), 0, 0, np.empty((0, 6), np.float64))
    if copies.shape[0] > 0:
        lmax, w, shift, S, X, runs = prepare_copies(states, log_w, copies, pos)
    else:
        lmax, w, shift, S, X, runs = prepare(states, log_w)
    m = w.shape[0]
    # the centres in the shifted coordinates: the same floats as numpy's ``init - shift``
    init = np.empty((k0, 6), np.float64)
    for c in range(nz):
        init[c, 0] = Z[c, 0] - shift[0]
        init[c, 1] = Z[c, 1] - shift[1]
        init[c, 2] = 0.0 - shift[2]
        init[c, 3] = 0.0 - shift[3]
        init[c, 4] = Z[c, 2] - shift[4]
        init[c, 5] = Z[c, 3] - shift[5]
    for e in range(ne):
        for d in range(6):
            init[nz + e, d] = extra[e, d] - shift[d]
    if K0 == 0:                                    # the particles' weighted mean
        tw = 0.0
        for d in range(6):
            init[0, d] = 0.0
        for i in range(m):
            tw += w[i]
            for d in range(6):
                init[0, d] += w[i] * S[i, d]
        for d in range(6):
            init[0, d] = init[0, d] / tw
    centers, labels, masses, dmin, it = lloyd(X, S, w, init, max_iter, tol, sigma_obs,
                                              sigma_min, pos_ratio, grid_min)
    for c in range(k0):
        masses[c] = masses[c] * scale
    C, M, lab, dm, n_splits, it2 = split_clusters(
        X, S, w, centers, masses, labels, dmin, scale, split_above, need, min_split_mass,
        guarded, max_splits, n_near, max_iter, tol, sigma_obs, sigma_min, pos_ratio)
    K = C.shape[0]
    kept = np.empty(K, np.bool_)
    origin = np.empty(K, np.int64)
    nk = 0
    for c in range(K):
        for d in range(6):
            C[c, d] += shift[d]
        kept[c] = M[c] >= T
        nk += kept[c]
        origin[c] = c if c < nz else (ORIGIN_EXTRA if c < k0 else ORIGIN_SPLIT)
    kc = np.empty((nk, 6), np.float64)             # ``C[kept]``
    q = 0
    for c in range(K):
        if kept[c]:
            for d in range(6):
                kc[q, d] = C[c, d]
            q += 1
    return bad, C, M, lab, runs, kept, origin, n_splits, it + it2, kc
