"""Fused numba kernels of the modified K-means of maggio2007 §3 (issue 12): weighted Lloyd
iterations with an exact nearest-centre search whose cost per particle does not grow with the
number of centres (a grid on the centres, :func:`assign`).  Split from :mod:`._kernels` (the
filter's kernels) so the two can change independently."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._kernels import grid_build


# ----------------------------------------------------------------------------- K-means

@njit(cache=True, nogil=True)
def _inv_var(centers, sigma_obs, sigma_min, pos_ratio):
    """(K, 4) inverse observation-noise variances at each centre's size (``1 / obs_std²``)."""
    K = centers.shape[0]
    inv = np.empty((K, 4))
    for c in range(K):
        sw = max(sigma_obs * centers[c, 4], sigma_min)
        sh = max(sigma_obs * centers[c, 5], sigma_min)
        a = pos_ratio * sw
        b = pos_ratio * sh
        inv[c, 0] = 1.0 / (a * a)
        inv[c, 1] = 1.0 / (b * b)
        inv[c, 2] = 1.0 / (sw * sw)
        inv[c, 3] = 1.0 / (sh * sh)
    return inv


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def _assign_dense(X, centers, inv, labels, dmin):
    for i in range(X.shape[0]):
        best = _d2(X, i, centers, inv, 0)
        lab = 0
        for c in range(1, centers.shape[0]):
            d = _d2(X, i, centers, inv, c)
            if d < best:
                best = d
                lab = c
        labels[i] = lab
        dmin[i] = best


@njit(cache=True, nogil=True)
def _scaled(X, i, rm, cs, c):
    """Euclidean distance of particle i to centre c in the space scaled by ``rm`` (4,)."""
    a0 = X[i, 0] * rm[0] - cs[c, 0]
    a1 = X[i, 1] * rm[1] - cs[c, 1]
    a2 = X[i, 2] * rm[2] - cs[c, 2]
    a3 = X[i, 3] * rm[3] - cs[c, 3]
    return math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3)


@njit(cache=True, nogil=True)
def _min_inv(inv):
    m = np.full(4, np.inf)
    for c in range(inv.shape[0]):
        for d in range(4):
            m[d] = min(m[d], inv[c, d])
    return m


@njit(cache=True, nogil=True)
def _metric(centers, m):
    """The scaled space of :func:`assign`: ``rm`` (4,) = sqrt(m), m (4,) at most the inverse
    variances of every centre, ``cs`` (K, 4) the centres in it, ``dcc`` (K, K) their
    distances and ``gap`` (K,) each centre's distance to its nearest other centre."""
    K = centers.shape[0]
    rm = np.sqrt(m)
    cs = np.empty((K, 4))
    for c in range(K):
        cs[c, 0] = centers[c, 0] * rm[0]
        cs[c, 1] = centers[c, 1] * rm[1]
        cs[c, 2] = centers[c, 4] * rm[2]
        cs[c, 3] = centers[c, 5] * rm[3]
    dcc = np.empty((K, K))
    for c in range(K):
        for e in range(K):
            a0 = cs[c, 0] - cs[e, 0]
            a1 = cs[c, 1] - cs[e, 1]
            a2 = cs[c, 2] - cs[e, 2]
            a3 = cs[c, 3] - cs[e, 3]
            dcc[c, e] = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3)
    gap = np.full(K, np.inf)
    for c in range(K):
        for e in range(K):
            if e != c and dcc[c, e] < gap[c]:
                gap[c] = dcc[c, e]
    return rm, cs, dcc, gap


@njit(cache=True, nogil=True)
def _first_guess(cs):
    """A cheap first centre for particles without a previous label: a grid of about K cells
    on the centres' scaled (y1, y2), each cell's centre nearest to its middle.  Returns
    ``(u0, v0, g, ni, nj, rep)``; any guess is fine (the search from it is exact), a near one
    is fast."""
    K = cs.shape[0]
    u0 = np.inf
    u1 = -np.inf
    v0 = np.inf
    v1 = -np.inf
    for c in range(K):
        u0 = min(u0, cs[c, 0])
        u1 = max(u1, cs[c, 0])
        v0 = min(v0, cs[c, 1])
        v1 = max(v1, cs[c, 1])
    if not (np.isfinite(u0) and np.isfinite(u1) and np.isfinite(v0) and np.isfinite(v1)):
        return 0.0, 0.0, 1.0, 1, 1, np.zeros(1, np.int64)
    g = max(2.0, math.sqrt(max(u1 - u0, 1.0) * max(v1 - v0, 1.0) / K))
    while (math.floor((u1 - u0) / g) + 1.0) * (math.floor((v1 - v0) / g) + 1.0) > 4.0 * K + 64:
        g *= 2.0
    ni = math.floor((u1 - u0) / g) + 1
    nj = math.floor((v1 - v0) / g) + 1
    rep = np.empty(ni * nj, np.int64)
    for a in range(ni):
        mu = u0 + (a + 0.5) * g
        for b in range(nj):
            mv = v0 + (b + 0.5) * g
            best = np.inf
            r = 0
            for c in range(K):
                d = (cs[c, 0] - mu) ** 2 + (cs[c, 1] - mv) ** 2
                if d < best:
                    best = d
                    r = c
            rep[a * nj + b] = r
    return u0, v0, g, ni, nj, rep


@njit(cache=True, nogil=True)
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
    rm, cs, dcc, gap = _metric(centers, m)
    # each centre's others by increasing distance, sorted on first use
    near = np.empty((K, K), np.int64)
    sorted_row = np.zeros(K, np.bool_)
    u0, v0, g, ni, nj, rep = _first_guess(cs)
    for i in range(n):
        lab = prev[i]
        if lab >= 0 and lab < K:
            if stable[lab]:
                labels[i] = lab
                continue
        else:
            fi = math.floor((X[i, 0] * rm[0] - u0) / g)
            fj = math.floor((X[i, 1] * rm[1] - v0) / g)
            ci = 0 if not fi > 0.0 else (ni - 1 if fi > ni - 1.0 else int(fi))
            cj = 0 if not fj > 0.0 else (nj - 1 if fj > nj - 1.0 else int(fj))
            lab = rep[ci * nj + cj]
        best = _d2(X, i, centers, inv, lab)
        c0 = lab
        e0 = _scaled(X, i, rm, cs, c0)
        # triangle inequality in the scaled space: d²(x, c) >= (D(c0, c) − e0)² > best
        # once D(c0, c) − e0 > sqrt(best), for c and every centre after it
        if gap[c0] - e0 > math.sqrt(best) * (1.0 + 1e-9) + 1e-9 * (1.0 + e0):
            labels[i] = lab                 # no other centre is near enough: the usual case
            dmin[i] = best
            reach[i] = e0 + math.sqrt(best)
            continue
        if not sorted_row[c0]:
            near[c0] = np.argsort(dcc[c0])
            sorted_row[c0] = True
        for q in range(K):
            c = near[c0, q]
            if c == c0:
                continue
            if dcc[c0, c] - e0 > math.sqrt(best) * (1.0 + 1e-9) + 1e-9 * (1.0 + e0):
                break
            d = _d2(X, i, centers, inv, c)
            if d < best or (d == best and c < lab):
                best = d
                lab = c
        labels[i] = lab
        dmin[i] = best
        reach[i] = _scaled(X, i, rm, cs, lab) + math.sqrt(best)


@njit(cache=True, nogil=True)
def assign(X, centers, inv, prev, labels, dmin, grid_min):
    """Nearest centre of every particle (the lowest index among equal d², as ``argmin`` over
    all centres) into ``labels``/``dmin``; ``X`` (N, 4) the particles' (y1, y2, w, h),
    ``centers`` (K, 6), ``inv`` (K, 4) from :func:`_inv_var`; ``prev`` (N,) a previous label
    per particle (a first guess, -1 for none).

    Below ``grid_min`` centres every centre is looked at.  From ``grid_min`` on, exact too:
    every centre's inverse variances are at least ``m`` (their minimum over the centres,
    per coordinate), so in the (y1, y2, w, h) space scaled by ``sqrt(m)`` a centre at
    Euclidean distance e has ``d² >= e²``.

    From a first centre c (the previous label, else the centre nearest to the middle of the
    particle's cell in a coarse grid, :func:`_first_guess`), the particle at scaled distance
    e₀ from c looks at the other centres c' in increasing scaled distance ``D(c, c')`` and
    stops once ``D(c, c') − e₀ > sqrt(best d²)`` (triangle inequality: every centre after
    that has ``d² >= e² > best``) — after one or two looks for a particle near its centre."""
    _assign(X, centers, inv, prev, labels, dmin, grid_min, _min_inv(inv),
            np.zeros(centers.shape[0], np.bool_), np.empty(X.shape[0]))


@njit(cache=True, nogil=True)
def lloyd(X, S, w, centers, max_iter, tol, sigma_obs, sigma_min, pos_ratio, grid_min):
    """Weighted Lloyd iterations (maggio2007 §3) from ``centers`` (K, 6) until the labels are
    stable, no centre's (y1, y2, w, h) moved more than ``tol`` (> 0), or ``max_iter``
    iterations (then the labels are the nearest centres; ``grid_min``: :func:`assign`).
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
    labels = np.full(n, -1, np.int64)
    new = np.full(n, -1, np.int64)
    dmin = np.zeros(n)
    reach = np.zeros(n)
    m = np.zeros(K)
    sums = np.zeros((K, D))
    stable = np.zeros(K, np.bool_)
    moved = np.ones(K, np.bool_)
    touched = np.ones(K, np.bool_)
    reach_c = np.zeros(K)
    space = np.zeros(4)
    it = 0
    done = False
    for it in range(1, max_iter + 1):
        inv = _inv_var(centers, sigma_obs, sigma_min, pos_ratio)
        if K >= grid_min:
            # the scaled space: a little below the smallest inverse variances, kept while every
            # centre stays above it (so the reaches of the last iteration stay valid)
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
                rm = np.sqrt(space)
                for c in range(K):
                    if not stable[c]:
                        continue
                    for e in range(K):
                        if moved[e]:
                            a0 = (centers[c, 0] - centers[e, 0]) * rm[0]
                            a1 = (centers[c, 1] - centers[e, 1]) * rm[1]
                            a2 = (centers[c, 4] - centers[e, 4]) * rm[2]
                            a3 = (centers[c, 5] - centers[e, 5]) * rm[3]
                            dce = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3)
                            if not dce > reach_c[c] * (1.0 + 1e-9) + 1e-9:
                                stable[c] = False
                                break
        _assign(X, centers, inv, labels, new, dmin, grid_min, space, stable, reach)
        if it > 1:
            for c in range(K):
                touched[c] = False
            changed = False
            for i in range(n):
                if new[i] != labels[i]:
                    changed = True
                    touched[new[i]] = True
                    touched[labels[i]] = True
            if not changed:
                done = True
                break
        for i in range(n):
            labels[i] = new[i]
        # sums of the touched clusters, over their members in particle order
        for c in range(K):
            if touched[c]:
                m[c] = 0.0
                for d in range(D):
                    sums[c, d] = 0.0
                reach_c[c] = 0.0
        for i in range(n):
            c = labels[i]
            if touched[c]:
                wi = w[i]
                m[c] += wi
                for d in range(D):
                    sums[c, d] += S[i, d] * wi
        for i in range(n):
            c = labels[i]
            reach_c[c] = max(reach_c[c], reach[i])
        step = 0.0
        for c in range(K):
            moved[c] = False
            if touched[c] and m[c] > 0:
                for d in range(D):
                    val = sums[c, d] / m[c]
                    if d == 0 or d == 1 or d == 4 or d == 5:
                        step = max(step, abs(val - centers[c, d]))
                        if val != centers[c, d]:
                            moved[c] = True
                    centers[c, d] = val
        if tol > 0 and step <= tol:
            done = True
            break
    if not done:
        inv = _inv_var(centers, sigma_obs, sigma_min, pos_ratio)
        for c in range(K):
            stable[c] = False
        _assign(X, centers, inv, labels, new, dmin, grid_min, _min_inv(inv), stable, reach)
        for i in range(n):
            labels[i] = new[i]
    masses = np.zeros(K)
    for i in range(n):
        masses[labels[i]] += w[i]
    return centers, labels, masses, dmin, it
