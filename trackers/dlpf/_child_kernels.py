"""Numba kernels of the children's histograms (eq. (12), :func:`.children.histograms`).

:func:`sample_pixels` gathers the ``grid`` samples of every box (the sample position rounded
half to even and clamped to the image, as ``np.clip(np.rint(...))`` did, the same float
operations in the same order) in one pass, where the numpy version built two (N, S) float
coordinate arrays and ``cv2.remap``-ed them.  The colour conversion and the bin table stay
OpenCV's (``cvtColor``, ``LUT``).  :func:`bin_counts` turns the table's bytes into bin indices
and counts them per box in one pass (the counts are whole numbers, then divided by the sample
count: the same floats as ``np.bincount(...) / S``).

Compile: ~1.1 CPU s (one signature each), then numba's cache.  The histograms are first needed
when a track is confirmed, which the install's short warm-up run may not reach, so
:class:`~.tracker.DLPFTracker` calls :func:`compile_kernels` when it is built (before any frame;
a load from the cache once compiled, so ``pip install -e .`` compiles them).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def sample_pixels(image, boxes, u, v):  # pragma: no cover - compiled
    """(1, N·S, 3) uint8: the pixels of ``image`` (H, W, 3) at the ``(u, v)`` (S,) grid of each
    box ``(x, y, w, h)`` of ``boxes`` (N, 4): ``x + w (u + 0.5)`` rounded half to even,
    clamped to ``0..W-1`` (rows alike); a non-finite coordinate reads column (row) 0."""
    H, W = image.shape[0], image.shape[1]
    n, S = boxes.shape[0], u.shape[0]
    out = np.empty((1, n * S, 3), dtype=np.uint8)
    for i in range(n):
        bx, by, bw, bh = boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 3]
        for k in range(S):
            x = np.rint(bx + bw * (u[k] + 0.5))
            y = np.rint(by + bh * (v[k] + 0.5))
            xi = 0
            if x > W - 1:
                xi = W - 1
            elif x > 0:
                xi = int(x)
            yi = 0
            if y > H - 1:
                yi = H - 1
            elif y > 0:
                yi = int(y)
            j = i * S + k
            out[0, j, 0] = image[yi, xi, 0]
            out[0, j, 1] = image[yi, xi, 1]
            out[0, j, 2] = image[yi, xi, 2]
    return out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def bin_counts(q, n, S, mh, ms, mv):  # pragma: no cover - compiled
    """(n, M) float64 normalised histograms from the bin table's bytes ``q`` (1, n·S, 3) of
    :func:`.children.hsv_bins` (``M = mh·ms + mv``; the small table when ``M <= 128``)."""
    M = mh * ms + mv
    small = M <= 128
    out = np.zeros((n, M))
    for i in range(n):
        for k in range(S):
            j = i * S + k
            a, b, c = np.int64(q[0, j, 0]), np.int64(q[0, j, 1]), np.int64(q[0, j, 2])
            if (b | c) >= 128:
                idx = c & 127 if small else (c & 127) + mh * ms
            else:
                idx = a + b if small else a * ms + (b & 127)
            out[i, idx] += 1.0
    s = float(S)
    for i in range(n):
        for m in range(M):
            out[i, m] = out[i, m] / s
    return out


def compile_kernels() -> None:
    """Compile (or load from numba's cache) both kernels with the signatures
    :func:`.children.histograms` calls them with (any image, boxes and grid give the same)."""
    from .children import histograms

    histograms(np.zeros((2, 2, 3), dtype=np.uint8), np.ones((1, 4)), (1, 1), 1, 1, 1, 0.5, 0.5)


__all__ = ["sample_pixels", "bin_counts", "compile_kernels"]
