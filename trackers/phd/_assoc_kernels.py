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
def _var4(tail, t, v, b, c, i, sv, ss, so, so_min, ratio, cc, cc2, out):
    """Variances of the four observable components of tail t's prediction ``i`` frames on
    (:func:`.association.propagate`) into ``out`` (4,)."""
    for k in range(2):
        s = so * tail[t, 4 + k]
        if not (s >= so_min or s != s):
            s = so_min
        r_y = (ratio * s) * (ratio * s)
        r_wh = s * s
        a = sv * tail[t, 4 + k]
        s2 = (i - 1.0) * i * (2.0 * i - 1.0) / 6.0 + cc * i * (i - 1.0) + cc2 * i
        out[k] = a * a * s2 + r_y + b[t, k] * i + c[t, k] * (i * i) + r_y
        g = ss * tail[t, 4 + k]
        out[2 + k] = g * g * i + 2.0 * r_wh


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
        _var4(tail, t, v, b, c, depth, sv, ss, so, so_min, ratio, cc, cc2, var)
        for k in range(4):
            lg[k] = math.log(two_pi * var[k])
        floor[t] = -0.5 * gate_d2 - 0.5 * (((lg[0] + lg[1]) + lg[2]) + lg[3])
        i = gaps[t]
        _var4(tail, t, v, b, c, i, sv, ss, so, so_min, ratio, cc, cc2, var)
        for k in range(4):
            lg[k] = math.log(two_pi * var[k])
        log_det = ((lg[0] + lg[1]) + lg[2]) + lg[3]
        m0 = tail[t, 0] + i * v[t, 0]
        m1 = tail[t, 1] + i * v[t, 1]
        m2 = tail[t, 4]
        m3 = tail[t, 5]
        for j in range(M):
            r0 = z[j, 0] - m0
            r1 = z[j, 1] - m1
            r2 = z[j, 2] - m2
            r3 = z[j, 3] - m3
            d = ((r0 * r0 / var[0] + r1 * r1 / var[1]) + r2 * r2 / var[2]) + r3 * r3 / var[3]
            d2[t, j] = d
            gn = -0.5 * d - 0.5 * log_det
            gain[t, j] = gn
            weight[t, j] = gn - floor[t]
    return gain, d2, weight, floor


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def iou(a, b):
    """(A, B) intersection over union of centre boxes ``a`` (A, 4), ``b`` (B, 4)
    ``(cx, cy, w, h)``: :func:`.association._iou`, the same floats as its numpy spelling."""
    A = a.shape[0]
    B = b.shape[0]
    out = np.empty((A, B), np.float64)
    for i in range(A):
        aw = a[i, 2] / 2
        ah = a[i, 3] / 2
        area_a = a[i, 2] * a[i, 3]
        for j in range(B):
            bw = b[j, 2] / 2
            bh = b[j, 3] / 2
            # max(x, y) and min(x, y) spelt out by numba's own rule (y if y > x else x; y if
            # y < x else x): the first run then compiles no builtin max / min overload for
            # the helper process's kernels (K-means, association, resampling walk)
            x = a[i, 0] - aw
            y = b[j, 0] - bw
            lo0 = y if y > x else x
            x = a[i, 1] - ah
            y = b[j, 1] - bh
            lo1 = y if y > x else x
            x = a[i, 0] + aw
            y = b[j, 0] + bw
            hi0 = y if y < x else x
            x = a[i, 1] + ah
            y = b[j, 1] + bh
            hi1 = y if y < x else x
            e0 = hi0 - lo0
            e1 = hi1 - lo1
            inter = (e0 if e0 > 0.0 else 0.0) * (e1 if e1 > 0.0 else 0.0)
            union = area_a + b[j, 2] * b[j, 3] - inter
            out[i, j] = inter / (union if union > 1e-12 else 1e-12)
    return out
