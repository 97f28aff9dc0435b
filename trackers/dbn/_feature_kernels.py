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
