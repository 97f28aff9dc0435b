"""The codebook's detection step (Kim et al. 2005 §3, layered modelling) as one numba pass over
the pixels (:meth:`pfscope.trackers.dbn.codebook.Codebook.apply` after the training period).

The numpy version (kept as :meth:`Codebook._detect_numpy`, the reference the tests compare
with) walks the codeword slots with a fancy index per slot and then sweeps every (slot, pixel)
for the cache and deletion rules: about a dozen passes over the image per frame, ~10 ms on
PETS09 at half resolution.  Here each pixel is visited once: match its codewords (first match,
eq. (2) colour distortion and eq. (3) brightness), update the matched one or model the pixel in
its cache codebook, forget / promote cache codewords, delete stale background codewords.  The
arithmetic is float32 in the numpy code's order (a pixel's decision can differ only where
float32 rounding decides a comparison: tested to agree on all but a few pixels).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def _match(x0, x1, x2, xx, inten, v, vv, imin, imax, f, p, L, e2, alpha, beta, tiny):
    for s in range(L):
        if f[s, p] <= 0:
            continue
        xv = x0 * v[s, p, 0] + x1 * v[s, p, 1] + x2 * v[s, p, 2]
        den = vv[s, p] if vv[s, p] > tiny else tiny
        cd2 = xx - xv * xv / den
        hi = beta * imax[s, p]
        lo2 = imin[s, p] / alpha
        if lo2 < hi:
            hi = lo2
        if cd2 <= e2 and inten >= alpha * imax[s, p] and inten <= hi:
            return s
    return -1


@njit(cache=True, nogil=True, inline="always")
def _update(x0, x1, x2, inten, v, vv, imin, imax, f, lam, q, s, p, t):
    ff = np.float32(f[s, p])
    one = np.float32(1.0)
    a = (ff * v[s, p, 0] + x0) / (ff + one)
    b = (ff * v[s, p, 1] + x1) / (ff + one)
    c = (ff * v[s, p, 2] + x2) / (ff + one)
    v[s, p, 0] = a
    v[s, p, 1] = b
    v[s, p, 2] = c
    vv[s, p] = a * a + b * b + c * c
    if inten < imin[s, p]:
        imin[s, p] = inten
    if inten > imax[s, p]:
        imax[s, p] = inten
    f[s, p] += 1
    d = t - q[s, p]
    if d > lam[s, p]:
        lam[s, p] = d
    q[s, p] = t


@njit(cache=True, nogil=True)
def detect(x, t, eps_detect2, eps_train2, alpha, beta, cache_add, cache_forget, stale_delete,
           bv, bvv, bimin, bimax, bf, blam, bp, bq,
           cv, cvv, cimin, cimax, cf, clam, cp, cq, fg):
    """One detection frame over every pixel (module docstring).  ``x`` (P, 3) float32 pixels;
    the book ``b*`` (L, P[, 3]) and the cache ``c*`` (Lc, P[, 3]) are updated in place;
    ``fg`` (P,) bool receives the foreground."""
    L = bf.shape[0]
    Lc = cf.shape[0]
    P = x.shape[0]
    tiny = np.float32(1e-6)
    for p in range(P):
        x0 = x[p, 0]
        x1 = x[p, 1]
        x2 = x[p, 2]
        xx = x0 * x0 + x1 * x1 + x2 * x2
        inten = np.sqrt(xx)
        s = _match(x0, x1, x2, xx, inten, bv, bvv, bimin, bimax, bf, p, L, eps_detect2,
                   alpha, beta, tiny)
        if s >= 0:
            fg[p] = False
            _update(x0, x1, x2, inten, bv, bvv, bimin, bimax, bf, blam, bq, s, p, t)
        else:
            fg[p] = True
            cs = _match(x0, x1, x2, xx, inten, cv, cvv, cimin, cimax, cf, p, Lc, eps_train2,
                        alpha, beta, tiny)
            if cs >= 0:
                _update(x0, x1, x2, inten, cv, cvv, cimin, cimax, cf, clam, cq, cs, p, t)
            else:                       # a new cache codeword: first empty slot, else stalest
                k = -1
                best = -1
                for j in range(Lc):
                    if cf[j, p] == 0:
                        k = j
                        break
                    key = t - cq[j, p]
                    if key > best:
                        best = key
                        k = j
                cv[k, p, 0] = x0
                cv[k, p, 1] = x1
                cv[k, p, 2] = x2
                cvv[k, p] = xx
                cimin[k, p] = inten
                cimax[k, p] = inten
                cf[k, p] = 1
                clam[k, p] = t - 1
                cp[k, p] = t
                cq[k, p] = t
        # cache housekeeping: forget what vanished, then promote what stayed
        for j in range(Lc):
            if cf[j, p] > 0 and t - cq[j, p] > cache_forget:
                cf[j, p] = 0
                clam[j, p] = 0
        promo = False
        for j in range(Lc):
            if cf[j, p] > 0 and cf[j, p] > cache_add:
                promo = True
        if promo:
            # one book slot for the pixel, chosen before any promotion (as the numpy code does)
            k = -1
            best = -1
            for j in range(L):
                if bf[j, p] == 0:
                    k = j
                    break
                key = t - bq[j, p]
                if key > best:
                    best = key
                    k = j
            for j in range(Lc):
                if cf[j, p] > 0 and cf[j, p] > cache_add:
                    bv[k, p, 0] = cv[j, p, 0]
                    bv[k, p, 1] = cv[j, p, 1]
                    bv[k, p, 2] = cv[j, p, 2]
                    bvv[k, p] = cvv[j, p]
                    bimin[k, p] = cimin[j, p]
                    bimax[k, p] = cimax[j, p]
                    bf[k, p] = cf[j, p]
                    bp[k, p] = cp[j, p]
                    bq[k, p] = cq[j, p]
                    blam[k, p] = 0
                    cf[j, p] = 0
                    clam[j, p] = 0
        for j in range(L):
            if bf[j, p] > 0 and t - bq[j, p] > stale_delete:
                bf[j, p] = 0
                blam[j, p] = 0
