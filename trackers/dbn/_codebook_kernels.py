"""The codebook's detection step (Kim et al. 2005 §3, layered modelling) as one numba pass over
the pixels (:meth:`pfscope.trackers.dbn.codebook.Codebook.apply` after the training period).

The numpy version (kept as :meth:`Codebook._detect_numpy`, the reference the tests compare
with) walks the codeword slots with a fancy index per slot and then sweeps every (slot, pixel)
for the cache and deletion rules: about a dozen passes over the image per frame, ~10 ms on
PETS09 at half resolution.  Here each pixel is visited once: match its codewords (first match,
eq. (2) colour distortion and eq. (3) brightness), update the matched one or model the pixel in
its cache codebook, forget / promote cache codewords, delete stale background codewords.  The
arithmetic is float32 in the numpy code's order (tested: the same masks and codebooks as the
numpy reference, frame after frame).  Written out in one function on purpose: a helper taking
the codebook arrays costs a reference-count round trip per array per call, which made the
per-pixel update 15x slower.  ``error_model="numpy"``: its divisors are never zero (a
codeword's norm is floored at 1e-6, counts are >= 1), so Python's zero-division checks only
cost branches (~5 % of the pass; the same masks and codebooks).

Layout: the kernel takes the codebook's *pixel-major* storage (:class:`~.codebook._Book`:
(P, L[, 3]) arrays), so a pixel's codewords are adjacent in memory.  With slot-major (L, P)
rows every pixel touched ~20 separate memory streams (every slot's ``f`` and ``q`` for the
cache and deletion rules, the matched slot's colour and bounds, the cache's); pixel-major
measured ~0.7x the pass on PETS09 at half resolution, same masks and codebooks.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def detect(x, t, eps_detect2, eps_train2, alpha, beta, cache_add, cache_forget, stale_delete,
           bv, bvv, bimin, bimax, bf, blam, bp, bq,
           cv, cvv, cimin, cimax, cf, clam, cp, cq, fg):
    """One detection frame over every pixel (module docstring).  ``x`` (P, 3) pixels (uint8 or
    float32, read as float32);
    the book ``b*`` (P, L[, 3]) and the cache ``c*`` (P, Lc[, 3]) (pixel-major) are updated in place;
    ``fg`` (P,) bool receives the foreground."""
    L = bf.shape[1]
    Lc = cf.shape[1]
    P = x.shape[0]
    tiny = np.float32(1e-6)
    one = np.float32(1.0)
    for p in range(P):
        x0 = np.float32(x[p, 0])
        x1 = np.float32(x[p, 1])
        x2 = np.float32(x[p, 2])
        xx = x0 * x0 + x1 * x1 + x2 * x2
        inten = np.sqrt(xx)
        s = -1
        for j in range(L):
            if bf[p, j] <= 0:
                continue
            xv = x0 * bv[p, j, 0] + x1 * bv[p, j, 1] + x2 * bv[p, j, 2]
            den = bvv[p, j] if bvv[p, j] > tiny else tiny
            cd2 = xx - xv * xv / den
            hi = beta * bimax[p, j]
            lo2 = bimin[p, j] / alpha
            if lo2 < hi:
                hi = lo2
            if cd2 <= eps_detect2 and inten >= alpha * bimax[p, j] and inten <= hi:
                s = j
                break
        if s >= 0:
            fg[p] = False
            ff = np.float32(bf[p, s])
            va = (ff * bv[p, s, 0] + x0) / (ff + one)
            vb = (ff * bv[p, s, 1] + x1) / (ff + one)
            vc = (ff * bv[p, s, 2] + x2) / (ff + one)
            bv[p, s, 0] = va
            bv[p, s, 1] = vb
            bv[p, s, 2] = vc
            bvv[p, s] = va * va + vb * vb + vc * vc
            if inten < bimin[p, s]:
                bimin[p, s] = inten
            if inten > bimax[p, s]:
                bimax[p, s] = inten
            bf[p, s] += 1
            d = t - bq[p, s]
            if d > blam[p, s]:
                blam[p, s] = d
            bq[p, s] = t
        else:
            fg[p] = True
            cs = -1
            for j in range(Lc):
                if cf[p, j] <= 0:
                    continue
                xv = x0 * cv[p, j, 0] + x1 * cv[p, j, 1] + x2 * cv[p, j, 2]
                den = cvv[p, j] if cvv[p, j] > tiny else tiny
                cd2 = xx - xv * xv / den
                hi = beta * cimax[p, j]
                lo2 = cimin[p, j] / alpha
                if lo2 < hi:
                    hi = lo2
                if cd2 <= eps_train2 and inten >= alpha * cimax[p, j] and inten <= hi:
                    cs = j
                    break
            if cs >= 0:
                ff = np.float32(cf[p, cs])
                va = (ff * cv[p, cs, 0] + x0) / (ff + one)
                vb = (ff * cv[p, cs, 1] + x1) / (ff + one)
                vc = (ff * cv[p, cs, 2] + x2) / (ff + one)
                cv[p, cs, 0] = va
                cv[p, cs, 1] = vb
                cv[p, cs, 2] = vc
                cvv[p, cs] = va * va + vb * vb + vc * vc
                if inten < cimin[p, cs]:
                    cimin[p, cs] = inten
                if inten > cimax[p, cs]:
                    cimax[p, cs] = inten
                cf[p, cs] += 1
                d = t - cq[p, cs]
                if d > clam[p, cs]:
                    clam[p, cs] = d
                cq[p, cs] = t
            else:                       # a new cache codeword: first empty slot, else stalest
                k = -1
                best = -1
                for j in range(Lc):
                    if cf[p, j] == 0:
                        k = j
                        break
                    key = t - cq[p, j]
                    if key > best:
                        best = key
                        k = j
                cv[p, k, 0] = x0
                cv[p, k, 1] = x1
                cv[p, k, 2] = x2
                cvv[p, k] = xx
                cimin[p, k] = inten
                cimax[p, k] = inten
                cf[p, k] = 1
                clam[p, k] = t - 1
                cp[p, k] = t
                cq[p, k] = t
        # cache housekeeping: forget what vanished, then promote what stayed
        for j in range(Lc):
            if cf[p, j] > 0 and t - cq[p, j] > cache_forget:
                cf[p, j] = 0
                clam[p, j] = 0
        promo = False
        for j in range(Lc):
            if cf[p, j] > 0 and cf[p, j] > cache_add:
                promo = True
        if promo:
            # one book slot for the pixel, chosen before any promotion (as the numpy code does)
            k = -1
            best = -1
            for j in range(L):
                if bf[p, j] == 0:
                    k = j
                    break
                key = t - bq[p, j]
                if key > best:
                    best = key
                    k = j
            for j in range(Lc):
                if cf[p, j] > 0 and cf[p, j] > cache_add:
                    bv[p, k, 0] = cv[p, j, 0]
                    bv[p, k, 1] = cv[p, j, 1]
                    bv[p, k, 2] = cv[p, j, 2]
                    bvv[p, k] = cvv[p, j]
                    bimin[p, k] = cimin[p, j]
                    bimax[p, k] = cimax[p, j]
                    bf[p, k] = cf[p, j]
                    bp[p, k] = cp[p, j]
                    bq[p, k] = cq[p, j]
                    blam[p, k] = 0
                    cf[p, j] = 0
                    clam[p, j] = 0
        for j in range(L):
            if bf[p, j] > 0 and t - bq[p, j] > stale_delete:
                bf[p, j] = 0
                blam[p, j] = 0
