"""The integral histograms of :mod:`.features` straight from per-pixel bin indices, in one numba
pass (no per-bin maps).

:func:`pfscope.trackers.dbn.features.bin_maps` spreads every pixel over one-hot maps (gradient
magnitude in its orientation bin, 1 in its colour bin: (H, W, O) and (H, W, Hb + G) float64),
which ``cv2.integral`` then sums.  For the handful of blob crops a frame describes, building,
copying and summing those maps (and the ~10 numpy calls around them, per crop) cost more than
the sums.  :func:`one_hot_integrals` reads the indices and magnitudes and writes the zero-padded
integrals directly, adding in ``cv2.integral``'s own order (per channel a running row sum ``s``,
``II[y + 1, x + 1] = II[y, x + 1] + s``; the zeros of the other bins leave ``s`` unchanged), so
the integrals are the same floats (tested against ``cv2.integral`` of :func:`bin_maps`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def one_hot_integrals(ob, mag, cb, n_o, n_c):
    """``(II_hog (H+1, W+1, n_o), II_colour (H+1, W+1, n_c))`` float64 of the (H, W) maps
    ``ob`` (orientation bin), ``mag`` (its gradient magnitude) and ``cb`` (colour bin)."""
    H, W = ob.shape
    ih = np.zeros((H + 1, W + 1, n_o))
    ic = np.zeros((H + 1, W + 1, n_c))
    sh = np.zeros(n_o)
    sc = np.zeros(n_c)
    for y in range(H):
        sh[:] = 0.0
        sc[:] = 0.0
        for x in range(W):
            sh[ob[y, x]] += np.float64(mag[y, x])
            sc[cb[y, x]] += 1.0
            for b in range(n_o):
                ih[y + 1, x + 1, b] = ih[y, x + 1, b] + sh[b]
            for b in range(n_c):
                ic[y + 1, x + 1, b] = ic[y, x + 1, b] + sc[b]
    return ih, ic


@njit(cache=True, nogil=True)
def region_cell_sums(ob, mag, cb, starts, heights, widths, region_of, yh, xh, yc, xc,
                     n_o, n_c):
    """Cell sums of boxes over the integral histograms of their regions, in one call.

    ``ob``, ``mag``, ``cb``: the bins of several regions, each raveled (row-major) and
    concatenated; region ``r`` is ``heights[r] x widths[r]`` pixels from ``starts[r]``.  Box
    ``i`` lies in region ``region_of[i]``; its cell edges ``yh (N, R+1)``, ``xh (N, C+1)``
    (HOG) and ``yc (N, Rc+1)``, ``xc (N, 2)`` (colour bands) are relative to that region.
    Returns ``hog (N, R, C, n_o)`` and ``col (N, Rc, 1, n_c)``: per cell
    ``II[y1, x1] − II[y0, x1] − II[y1, x0] + II[y0, x0]`` in that order, as
    :func:`pfscope.trackers.dbn.features._cell_sums` evaluates it (the same floats)."""
    N = yh.shape[0]
    R, C = yh.shape[1] - 1, xh.shape[1] - 1
    Rc, Cc = yc.shape[1] - 1, xc.shape[1] - 1
    hog = np.zeros((N, R, C, n_o))
    col = np.zeros((N, Rc, Cc, n_c))
    for r in range(len(starts)):
        H, W, s = heights[r], widths[r], starts[r]
        ih, ic = one_hot_integrals(ob[s:s + H * W].reshape(H, W),
                                   mag[s:s + H * W].reshape(H, W),
                                   cb[s:s + H * W].reshape(H, W), n_o, n_c)
        for i in range(N):
            if region_of[i] != r:
                continue
            for a in range(R):
                y0, y1 = yh[i, a], yh[i, a + 1]
                for k in range(C):
                    x0, x1 = xh[i, k], xh[i, k + 1]
                    for b in range(n_o):
                        hog[i, a, k, b] = (ih[y1, x1, b] - ih[y0, x1, b] - ih[y1, x0, b]
                                           + ih[y0, x0, b])
            for a in range(Rc):
                y0, y1 = yc[i, a], yc[i, a + 1]
                for k in range(Cc):
                    x0, x1 = xc[i, k], xc[i, k + 1]
                    for b in range(n_c):
                        col[i, a, k, b] = (ic[y1, x1, b] - ic[y0, x1, b] - ic[y1, x0, b]
                                           + ic[y0, x0, b])
    return hog, col
