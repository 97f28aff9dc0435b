"""Fused numba kernels of the particle PHD filter and its K-means (issue 12, "reach for numba
where a profile shows numpy cannot").

The numpy versions were already gated and vectorised; what was left was numpy's call overhead
and its temporaries (one (pairs,) or (N, K) array per arithmetic step).  Each kernel here is one
or two passes over the particles with no temporary larger than O(N + N_z + grid):

- :func:`propagate_into` — the size-aware motion model on pre-drawn normals (predict).
- :func:`grid_build` / :func:`grid_span` — a uniform grid on the particles' positions (counting
  sort by cell), so a detection visits only the particles in the cells its gate box touches.
- :func:`mass_near_kernel` — M(z) of the birth allocation, the predicted mass in z's gate.
- :func:`birth_fill` — the newborn states from pre-drawn random numbers.
- :func:`gauss_update` — eq. (5) with the Gaussian g(z|x) evaluated on the fly inside each
  detection's gate: C(z) by an online log-sum-exp per detection, then each particle's bracket
  ``p_M + Σ_z ψ/(κ + C)`` by an online log-sum-exp per particle; no pair arrays.
- (systematic resampling, one walk over the CDF: ``trackers.smc.resampling._systematic_index``)
- :func:`lloyd` — weighted Lloyd iterations of the modified K-means (§3), with an exact
  nearest-centre search (:func:`assign`: triangle inequality in a scaled space).

Every random number is still drawn by the caller from its ``numpy.random.Generator``, in the
same order and shapes as before, so a seed keeps its meaning.  The kernels do their arithmetic
in the same order as the numpy code they replace where that is cheap (propagate, birth, the
K-means distances and weighted sums: bit for bit the same floats); the update's sums run in a
different order (float reordering only).  No kernel uses ``fastmath``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_HALF_LOG_2PI_4 = 2.0 * math.log(2.0 * math.pi)     # 0.5 · OBS_DIM · log(2π), OBS_DIM = 4


# ----------------------------------------------------------------------------- predict

@njit(cache=True, nogil=True)
def propagate_into(x, eps, sigma_v, sigma_size, accel_to_position, min_size, out):
    """``out`` (N, 6) = f(x) with the normals ``eps`` (N, 4): ``a = σ_v (w, h) ε₀₁``,
    ``y += v + c a``, ``v += a``, ``(w, h) = max((w, h) + σ_s (w, h) ε₂₃, min_size)``
    (:func:`~.motion.propagate`, same operation order)."""
    for i in range(x.shape[0]):
        w = x[i, 4]
        h = x[i, 5]
        a0 = sigma_v * w * eps[i, 0]
        a1 = sigma_v * h * eps[i, 1]
        out[i, 0] = x[i, 0] + (x[i, 2] + accel_to_position * a0)
        out[i, 1] = x[i, 1] + (x[i, 3] + accel_to_position * a1)
        out[i, 2] = x[i, 2] + a0
        out[i, 3] = x[i, 3] + a1
        nw = w + sigma_size * w * eps[i, 2]
        nh = h + sigma_size * h * eps[i, 3]
        out[i, 4] = nw if not nw < min_size else min_size
        out[i, 5] = nh if not nh < min_size else min_size


# ----------------------------------------------------------------------------- grid index

@njit(cache=True, nogil=True)
def grid_build(px, py, cell_x, cell_y):
    """Bucket the points ``(px, py)`` (N,) on a uniform grid of ``cell_x × cell_y``.

    Returns ``(ok, x0, y0, cell_x, cell_y, ni, nj, order, starts)``: ``order`` (N,) the point
    indices sorted by cell key ``i·nj + j`` (stable), ``starts`` (ni·nj + 1,) the first position
    in ``order`` of each cell.  The cells grow (×2) until there are at most ``4 N + 64`` of them,
    so memory stays O(N) however far apart the points are.  ``ok`` is False when a coordinate
    is not finite (nothing else is valid then)."""
    n = px.shape[0]
    x0 = np.inf
    y0 = np.inf
    x1 = -np.inf
    y1 = -np.inf
    for i in range(n):
        a = px[i]
        b = py[i]
        if not (np.isfinite(a) and np.isfinite(b)):
            return (False, 0.0, 0.0, cell_x, cell_y, 0, 0, np.zeros(0, np.int64),
                    np.zeros(1, np.int64))
        x0 = min(x0, a)
        x1 = max(x1, a)
        y0 = min(y0, b)
        y1 = max(y1, b)
    if n == 0:
        return (True, 0.0, 0.0, cell_x, cell_y, 0, 0, np.zeros(0, np.int64),
                np.zeros(1, np.int64))
    max_cells = 4.0 * n + 64.0
    while True:
        fi = math.floor((x1 - x0) / cell_x) + 1.0
        fj = math.floor((y1 - y0) / cell_y) + 1.0
        if fi * fj <= max_cells:
            break
        cell_x *= 2.0
        cell_y *= 2.0
    ni = int(fi)
    nj = int(fj)
    starts = np.zeros(ni * nj + 1, np.int64)
    keys = np.empty(n, np.int64)
    for i in range(n):
        ci = min(int((px[i] - x0) / cell_x), ni - 1)
        cj = min(int((py[i] - y0) / cell_y), nj - 1)
        k = ci * nj + cj
        keys[i] = k
        starts[k + 1] += 1
    for k in range(ni * nj):
        starts[k + 1] += starts[k]
    fill = starts[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        k = keys[i]
        order[fill[k]] = i
        fill[k] += 1
    return True, x0, y0, cell_x, cell_y, ni, nj, order, starts


@njit(cache=True, nogil=True)
def grid_span(lo, hi, origin, cell, n_cells):
    """Cells ``[c0, c1]`` along one axis that the interval ``[lo, hi]`` touches, clipped to the
    grid; ``c1 < c0`` when it misses the grid."""
    a = math.floor((lo - origin) / cell)
    b = math.floor((hi - origin) / cell)
    if not b >= 0.0 or not a <= n_cells - 1.0:      # also catches NaN
        return 0, -1
    c0 = 0 if a < 0.0 else int(a)
    c1 = n_cells - 1 if b > n_cells - 1.0 else int(b)
    return c0, c1


# ----------------------------------------------------------------------------- birth

@njit(cache=True, nogil=True)
def mass_near_kernel(states, w, Z, std_z, r2, cell_x, cell_y):
    """M(z) (N_z,): ``Σ w_i`` over the particles with ``Σ_d ((x_id − z_d)/σ_zd)² <= r2``
    on the observed columns (0, 1, 4, 5) of ``states`` (N, 6), ``std_z`` (N_z, 4) per detection.
    Returns ``(ok, out)``; ``ok`` False on non-finite positions."""
    nz = Z.shape[0]
    out = np.zeros(nz)
    if states.shape[0] == 0 or nz == 0:
        return True, out
    ok, x0, y0, cx, cy, ni, nj, order, starts = grid_build(states[:, 0], states[:, 1],
                                                           cell_x, cell_y)
    if not ok:
        return False, out
    r = math.sqrt(r2)
    for j in range(nz):
        hx = r * std_z[j, 0] * (1.0 + 1e-6) + 1e-9
        hy = r * std_z[j, 1] * (1.0 + 1e-6) + 1e-9
        i0, i1 = grid_span(Z[j, 0] - hx, Z[j, 0] + hx, x0, cx, ni)
        j0, j1 = grid_span(Z[j, 1] - hy, Z[j, 1] + hy, y0, cy, nj)
        s = 0.0
        for ci in range(i0, i1 + 1):
            for p in range(starts[ci * nj + j0], starts[ci * nj + j1 + 1]):
                i = order[p]
                q0 = (states[i, 0] - Z[j, 0]) / std_z[j, 0]
                q1 = (states[i, 1] - Z[j, 1]) / std_z[j, 1]
                q2 = (states[i, 4] - Z[j, 2]) / std_z[j, 2]
                q3 = (states[i, 5] - Z[j, 3]) / std_z[j, 3]
                if q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3 <= r2:
                    s += w[i]
        out[j] = s
    return True, out


@njit(cache=True, nogil=True)
def birth_fill(Z, j, lw_det, eps, cos_t, sin_t, speed_n, sigma_obs, sigma_min, pos_ratio,
               spread, speed_mean, speed_std, min_size):
    """The J = Σ j newborn: detection z's ``j[z]`` rows get ``(y, w, h) = z + spread σ(z) ε``,
    velocity ``(mean + std n) sqrt(w_z h_z) (cos θ, sin θ)``, sizes clipped to ``min_size``,
    log-weight ``lw_det[z]``.  ``eps`` (J, 4), ``cos_t``/``sin_t``/``speed_n`` (J,) the caller's
    draws.  Returns ``(states (J, 6), log_w (J,), det (J,))`` (the numpy birth's operations,
    same order)."""
    n = eps.shape[0]
    states = np.empty((n, 6))
    log_w = np.empty(n)
    det = np.empty(n, np.int64)
    k = 0
    for z in range(Z.shape[0]):
        sw = max(sigma_obs * Z[z, 2], sigma_min)
        sh = max(sigma_obs * Z[z, 3], sigma_min)
        s0 = spread * (pos_ratio * sw)
        s1 = spread * (pos_ratio * sh)
        s2 = spread * sw
        s3 = spread * sh
        scale = math.sqrt(Z[z, 2] * Z[z, 3])
        for _ in range(j[z]):
            states[k, 0] = Z[z, 0] + s0 * eps[k, 0]
            states[k, 1] = Z[z, 1] + s1 * eps[k, 1]
            ww = Z[z, 2] + s2 * eps[k, 2]
            hh = Z[z, 3] + s3 * eps[k, 3]
            states[k, 4] = ww if not ww < min_size else min_size
            states[k, 5] = hh if not hh < min_size else min_size
            speed = (speed_mean + speed_std * speed_n[k]) * scale
            states[k, 2] = speed * cos_t[k]
            states[k, 3] = speed * sin_t[k]
            log_w[k] = lw_det[z]
            det[k] = z
            k += 1
    return states, log_w, det


# ----------------------------------------------------------------------------- update

@njit(cache=True, nogil=True)
def _lse_add(m, s, a):
    """Online log-sum-exp: the pair (shift m, sum s) with log Σ = m + log s, plus term a."""
    if s == 0.0:
        return a, 1.0
    if a <= m:
        return m, s + math.exp(a - m)
    return a, s * math.exp(m - a) + 1.0


@njit(cache=True, nogil=True)
def gauss_update(states, lw, Z, std, log_norm, by_det, log_kappa, log_pd, log_pm, r2,
                 cell_x, cell_y):
    """Eq. (5) of maggio2007 with the Gaussian g(z|x) of §2/§4 on the pairs inside the gate
    ``d² <= r2`` (``d² = Σ_d ((x_d − z_d)/σ_d)²`` on the observed columns (0, 1, 4, 5)).

    ``std`` (N_z, 4) and ``log_norm`` (N_z,) = ``Σ log σ`` per detection (``by_det``) or
    (N, 4) / (N,) per particle.  ``log g = −d²/2 − log_norm − 2 log 2π``.  Returns
    ``(ok, new_lw (N,), log_c (N_z,))`` with ``log C(z) = log Σ_i (1 − p_M) g(z|x_i) ω_i`` and
    ``new_lw = lw + log[p_M + Σ_z ψ_z/(κ_z + C_z)]`` (κ = C = 0: the term is 0)."""
    n = states.shape[0]
    nz = Z.shape[0]
    log_c = np.full(nz, -np.inf)
    new_lw = lw.copy()
    ok, x0, y0, cx, cy, ni, nj, order, starts = grid_build(states[:, 0], states[:, 1],
                                                           cell_x, cell_y)
    if not ok:
        return False, new_lw, log_c
    r = math.sqrt(r2)
    hx_all = 0.0
    hy_all = 0.0
    if not by_det:
        for i in range(n):
            hx_all = max(hx_all, std[i, 0])
            hy_all = max(hy_all, std[i, 1])
    log_den = np.zeros(nz)
    sh = np.zeros(n)
    sm = np.zeros(n)
    if log_pm > -np.inf:
        for i in range(n):
            sh[i] = log_pm
            sm[i] = 1.0
    for rnd in range(2):
        for j in range(nz):
            if rnd == 1 and log_c[j] == -np.inf:
                continue                  # C = 0: ψ = 0 on every pair of z
            if by_det:
                hx = r * std[j, 0] * (1.0 + 1e-6) + 1e-9
                hy = r * std[j, 1] * (1.0 + 1e-6) + 1e-9
            else:
                hx = r * hx_all * (1.0 + 1e-6) + 1e-9
                hy = r * hy_all * (1.0 + 1e-6) + 1e-9
            i0, i1 = grid_span(Z[j, 0] - hx, Z[j, 0] + hx, x0, cx, ni)
            j0, j1 = grid_span(Z[j, 1] - hy, Z[j, 1] + hy, y0, cy, nj)
            m = -np.inf
            s = 0.0
            for ci in range(i0, i1 + 1):
                for p in range(starts[ci * nj + j0], starts[ci * nj + j1 + 1]):
                    i = order[p]
                    k = j if by_det else i
                    q0 = (states[i, 0] - Z[j, 0]) / std[k, 0]
                    q1 = (states[i, 1] - Z[j, 1]) / std[k, 1]
                    q2 = (states[i, 4] - Z[j, 2]) / std[k, 2]
                    q3 = (states[i, 5] - Z[j, 3]) / std[k, 3]
                    d2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
                    if not d2 <= r2:
                        continue
                    log_psi = log_pd + (-0.5 * d2 - log_norm[k] - _HALF_LOG_2PI_4)
                    if rnd == 0:
                        a = log_psi + lw[i]
                        if a > -np.inf:
                            m, s = _lse_add(m, s, a)
                    else:
                        t = log_psi - log_den[j]
                        if t > -np.inf:
                            sh[i], sm[i] = _lse_add(sh[i], sm[i], t)
            if rnd == 0:
                if s > 0.0:
                    log_c[j] = m + math.log(s)
                lk = log_kappa[j]
                lc = log_c[j]
                hi = max(lk, lc)
                if hi == -np.inf:
                    log_den[j] = 0.0          # κ = C = 0: the term is 0
                else:
                    log_den[j] = hi + math.log1p(math.exp(min(lk, lc) - hi))
    for i in range(n):
        if sm[i] > 0.0:
            new_lw[i] = lw[i] + (sh[i] + math.log(sm[i]))
        else:
            new_lw[i] = -np.inf
    return True, new_lw, log_c


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
