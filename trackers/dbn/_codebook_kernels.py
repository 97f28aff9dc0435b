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
    the book ``b*`` (L, P[, 3]) and the cache ``c*`` (Lc, P[, 3]) are updated in place;
    ``fg`` (P,) bool receives the foreground."""
    L = bf.shape[0]
    Lc = cf.shape[0]
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
            if bf[j, p] <= 0:
                continue
            xv = x0 * bv[j, p, 0] + x1 * bv[j, p, 1] + x2 * bv[j, p, 2]
            den = bvv[j, p] if bvv[j, p] > tiny else tiny
            cd2 = xx - xv * xv / den
            hi = beta * bimax[j, p]
            lo2 = bimin[j, p] / alpha
            if lo2 < hi:
                hi = lo2
            if cd2 <= eps_detect2 and inten >= alpha * bimax[j, p] and inten <= hi:
                s = j
                break
        if s >= 0:
            fg[p] = False
            ff = np.float32(bf[s, p])
            va = (ff * bv[s, p, 0] + x0) / (ff + one)
            vb = (ff * bv[s, p, 1] + x1) / (ff + one)
            vc = (ff * bv[s, p, 2] + x2) / (ff + one)
            bv[s, p, 0] = va
            bv[s, p, 1] = vb
            bv[s, p, 2] = vc
            bvv[s, p] = va * va + vb * vb + vc * vc
            if inten < bimin[s, p]:
                bimin[s, p] = inten
            if inten > bimax[s, p]:
                bimax[s, p] = inten
            bf[s, p] += 1
            d = t - bq[s, p]
            if d > blam[s, p]:
                blam[s, p] = d
            bq[s, p] = t
        else:
            fg[p] = True
            cs = -1
            for j in range(Lc):
                if cf[j, p] <= 0:
                    continue
                xv = x0 * cv[j, p, 0] + x1 * cv[j, p, 1] + x2 * cv[j, p, 2]
                den = cvv[j, p] if cvv[j, p] > tiny else tiny
                cd2 = xx - xv * xv / den
                hi = beta * cimax[j, p]
                lo2 = cimin[j, p] / alpha
                if lo2 < hi:
                    hi = lo2
                if cd2 <= eps_train2 and inten >= alpha * cimax[j, p] and inten <= hi:
                    cs = j
                    break
            if cs >= 0:
                ff = np.float32(cf[cs, p])
                va = (ff * cv[cs, p, 0] + x0) / (ff + one)
                vb = (ff * cv[cs, p, 1] + x1) / (ff + one)
                vc = (ff * cv[cs, p, 2] + x2) / (ff + one)
                cv[cs, p, 0] = va
                cv[cs, p, 1] = vb
                cv[cs, p, 2] = vc
                cvv[cs, p] = va * va + vb * vb + vc * vc
                if inten < cimin[cs, p]:
                    cimin[cs, p] = inten
                if inten > cimax[cs, p]:
                    cimax[cs, p] = inten
                cf[cs, p] += 1
                d = t - cq[cs, p]
                if d > clam[cs, p]:
                    clam[cs, p] = d
                cq[cs, p] = t
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
