"""Numba kernel of the classifier's HOG blocks, sharing the work of overlapping blocks.

OpenCV's ``HOGDescriptor.compute`` (with ``locations``) builds each 16×16 block's 2×2×9
histogram on its own: every pixel of the block adds its two orientation-bin weights (from
``computeGradient``: magnitude split between the two nearest of 9 bins) to up to 4 cells, each
time weighted by ``gauss(i, j) · wy_c(i) · wx_c(j)`` — the block's Gaussian (σ = 4 px) and
the bilinear split between the cells.  Neighbouring blocks (8-px stride) overlap by half, so
every pixel is visited by up to 4 blocks.

Both weights are products of a row factor and a column factor, so a block's histogram is a
separable sum: ``hist[cx, cy, b] = Σ_i hy[cy, i] · Σ_j hx[cx, j] · A_b(y0 + i, x0 + j)``.
:func:`region_blocks` computes, row by row, OpenCV's gradient of the row (square-root gamma,
centred differences, ``fastAtan2``'s polynomial, reflected border: the same bins, magnitudes
within ~2e-6 relative), the horizontal sums of the row once per block column (each pixel read
once), and adds them to the one or two block rows holding the row; then OpenCV's L2-Hys
normalisation of each wanted block.  Same features as OpenCV's blocks up to float rounding
(another summation order, the Gaussian factored as ``exp(-a s)·exp(-b s)``: descriptors within
~1e-6, tests/test_dlpf.py) at ~0.55x OpenCV's CPU on the pyramid's regions of PETS09-S2L1
(gradient included).  No ``fastmath``.

Compile: ~4.5 CPU s on the first call after an install (one signature; numba's cache after
that: loading it ~0.2 s); :func:`compile_kernels` makes that call.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

CELL = 8
BLOCK = 16
NBINS = 9


def block_weights(sigma: float = 4.0) -> np.ndarray:
    """(2, 16) float32: ``w[c, t]`` = weight of block offset ``t`` (row or column) in cell
    ``c`` of the block: the Gaussian's factor times the bilinear split (OpenCV's HOGCache)."""
    w = np.zeros((2, BLOCK), dtype=np.float64)
    for t in range(BLOCK):
        g = math.exp(-((t - BLOCK / 2) ** 2) / (2.0 * sigma * sigma))
        c = (t + 0.5) / CELL - 0.5
        c0 = math.floor(c)
        f = c - c0
        if c0 >= 0:
            w[c0, t] += g * (1.0 - f)
        if c0 + 1 <= 1:
            w[c0 + 1, t] += g * f
    return w.astype(np.float32)


_P1 = np.float32(0.9997878412794807 * 180 / math.pi)
_P3 = np.float32(-0.3258083974640975 * 180 / math.pi)
_P5 = np.float32(0.1555786518463281 * 180 / math.pi)
_P7 = np.float32(-0.04432655554792128 * 180 / math.pi)
_EPS = np.float32(np.finfo(np.float64).eps)
_DEG2RAD = np.float32(math.pi / 180)
_RAD2BIN = np.float32(NBINS / math.pi)  # unsigned orientation: pi radians over the 9 bins
_LUT = np.sqrt(np.arange(256, dtype=np.float32))       # gamma correction (square root)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _gradient_row(img, y, x0, n, lut, dx, dy, g0, g1, q0):
    """OpenCV's ``HOGDescriptor.computeGradient`` of image row ``y``, pixels ``x0 ..
    x0 + n - 1`` (border by reflection, as OpenCV's BORDER_REFLECT_101): each pixel's
    magnitude split between its two nearest of 9 unsigned orientation bins, ``g0`` to bin
    ``q0`` and ``g1`` to ``q0 + 1`` (mod 9).  The angle is OpenCV's ``fastAtan2`` polynomial
    (``cartToPolar``)."""
    H, W = img.shape
    ym = y - 1 if y > 0 else 1
    yp = y + 1 if y < H - 1 else H - 2
    rm = img[ym]
    r0 = img[y]
    rp = img[yp]
    lo = 1 if x0 == 0 else 0                    # the border pixels by reflection
    hi = n - 1 if x0 + n == W else n
    for i in range(lo, hi):
        x = x0 + i
        dx[i] = lut[r0[x + 1]] - lut[r0[x - 1]]
        dy[i] = lut[rp[x]] - lut[rm[x]]
    if lo == 1:
        dx[0] = lut[r0[1]] - lut[r0[1]]
        dy[0] = lut[rp[x0]] - lut[rm[x0]]
    if hi == n - 1:
        x = x0 + n - 1
        dx[n - 1] = lut[r0[W - 2]] - lut[r0[W - 2]]
        dy[n - 1] = lut[rp[x]] - lut[rm[x]]
    for i in range(n):          # branch-free (vectorised) magnitude, angle, bins
        gx = dx[i]
        gy = dy[i]
        mag = np.sqrt(gx * gx + gy * gy)
        ax = abs(gx)
        ay = abs(gy)
        big = ax >= ay
        c = (ay if big else ax) / ((ax if big else ay) + _EPS)
        c2 = c * c
        p = (((_P7 * c2 + _P5) * c2 + _P3) * c2 + _P1) * c
        a = p if big else np.float32(90.0) - p
        a = np.float32(180.0) - a if gx < 0 else a
        a = np.float32(360.0) - a if gy < 0 else a
        f = (a * _DEG2RAD) * _RAD2BIN + np.float32(0.5)      # >= 0.5: truncation = floor
        hb = np.int32(f)
        f -= np.float32(hb)
        g0[i] = mag * (np.float32(1.0) - f)
        g1[i] = mag * f
        hb -= 1
        hb = hb + NBINS if hb < 0 else hb
        q0[i] = hb - NBINS if hb >= NBINS else hb


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _axpy(dst, a, src):
    for q in range(dst.shape[0]):
        dst[q] += a * src[q]


@njit(cache=True, nogil=True, error_model="numpy")
def region_blocks(img, gw, gh, ox, oy, sel, w, l2hys, out):
    """HOG blocks of the uint8 image ``img`` into ``out[k]`` (36 floats) for each ``(k,
    place)`` row of ``sel``: place ``bv * gw + bu`` on a ``gw`` × ``gh`` grid of blocks, block
    ``(bu, bv)`` at px ``(ox + 8 bu, oy + 8 bv)`` (the grid must lie inside ``img``; gradients
    at ``img``'s own border reflect, as OpenCV's).  ``w`` is :func:`block_weights`, ``l2hys``
    the L2-Hys clip (0.2); the layout of a block is OpenCV's (cell x outer, cell y, 9 bins)."""
    rows = CELL * gh + CELL
    cols = CELL * gw + CELL
    L = gw * 2 * NBINS
    Rr = np.empty(L, dtype=np.float32)          # one row's horizontal sums [bu, cx, b]
    G0 = np.empty(cols, dtype=np.float32)
    G1 = np.empty(cols, dtype=np.float32)
    Q0 = np.empty(cols, dtype=np.int32)
    DX = np.empty(cols, dtype=np.float32)
    DY = np.empty(cols, dtype=np.float32)
    lut = _LUT
    V = np.zeros((gh, 2, L), dtype=np.float32)  # the blocks' sums [bv, cy, (bu, cx, b)]
    for r in range(rows):
        y = oy + r
        Rr[:] = 0.0
        _gradient_row(img, y, ox, cols, lut, DX, DY, G0, G1, Q0)
        # horizontal: each pixel of the row read once, added to the (one or two) block
        # columns holding it, each with its cell columns' weights
        for x in range(cols):
            a0 = G0[x]
            a1 = G1[x]
            b0 = Q0[x]
            b1 = b0 + 1 if b0 < NBINS - 1 else 0
            u = x >> 3
            t = x & 7
            if u < gw:                  # offset t in block column u
                o = u * 2 * NBINS
                w0 = w[0, t]
                Rr[o + b0] += a0 * w0
                Rr[o + b1] += a1 * w0
                if t >= 4:
                    w1 = w[1, t]
                    Rr[o + NBINS + b0] += a0 * w1
                    Rr[o + NBINS + b1] += a1 * w1
            if u >= 1:                  # offset t + 8 in block column u - 1
                o = (u - 1) * 2 * NBINS
                w1 = w[1, t + 8]
                Rr[o + NBINS + b0] += a0 * w1
                Rr[o + NBINS + b1] += a1 * w1
                if t < 4:
                    w0 = w[0, t + 8]
                    Rr[o + b0] += a0 * w0
                    Rr[o + b1] += a1 * w0
        # vertical: the row adds to the (one or two) block rows holding it, contiguous
        bv = r >> 3
        t = r & 7
        if bv < gh:
            _axpy(V[bv, 0], w[0, t], Rr)
            if t >= 4:
                _axpy(V[bv, 1], w[1, t], Rr)
        if bv >= 1:
            _axpy(V[bv - 1, 1], w[1, t + 8], Rr)
            if t < 4:
                _axpy(V[bv - 1, 0], w[0, t + 8], Rr)
    h = np.empty((2, 2 * NBINS), dtype=np.float32)      # [cy, cx*9 + b]
    thresh = np.float32(l2hys)
    for s in range(sel.shape[0]):
        k = sel[s, 0]
        place = sel[s, 1]
        bu = place % gw
        bv = place // gw
        for cy in range(2):
            for q in range(2 * NBINS):
                h[cy, q] = V[bv, cy, bu * 2 * NBINS + q]
        # L2-Hys (OpenCV's normalizeBlockHistogram)
        sq = np.float32(0.0)
        for cy in range(2):
            for q in range(2 * NBINS):
                sq += h[cy, q] * h[cy, q]
        sc = np.float32(1.0) / (np.float32(math.sqrt(sq)) + np.float32(4 * NBINS * 0.1))
        sq = np.float32(0.0)
        for cy in range(2):
            for q in range(2 * NBINS):
                v = min(h[cy, q] * sc, thresh)
                h[cy, q] = v
                sq += v * v
        sc = np.float32(1.0) / (np.float32(math.sqrt(sq)) + np.float32(1e-3))
        for cx in range(2):             # OpenCV's layout: cell x outer, cell y, bin
            for cy in range(2):
                o = (cx * 2 + cy) * NBINS
                for b in range(NBINS):
                    out[k, o + b] = h[cy, cx * NBINS + b] * sc


def compile_kernels() -> None:
    """Compile (or load from numba's cache) :func:`region_blocks` with the signature the
    classifier calls it with."""
    img = np.zeros((CELL * 3 + 2, CELL * 3 + 2), dtype=np.uint8)
    region_blocks(img, 2, 2, 1, 1, np.zeros((1, 2), dtype=np.int64), block_weights(), 0.2,
                  np.zeros((1, 4 * NBINS), dtype=np.float32))
