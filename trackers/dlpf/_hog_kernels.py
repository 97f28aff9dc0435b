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

:func:`warp_region` resamples a pyramid region from the frame with OpenCV's own fixed-point
``warpAffine`` arithmetic (the same bytes, ~0.7x OpenCV's CPU on these separable maps);
:func:`window_margins` (the linear SVM's margins summed from the blocks, no descriptor array)
and :func:`region_layout` (the pyramid's regions and distinct blocks, integer work) are the
classifier's bookkeeping.

Compile: ~4.5 CPU s for :func:`region_blocks` on the first call after an install (one
signature; numba's cache after that: loading it ~0.2 s), ~1.7–2 s for :func:`region_layout`,
~0.8 s for :func:`warp_region`, ~0.7 s for :func:`window_margins` (each ~0.01 s from the cache once numba is loaded);
:func:`compile_kernels` makes those calls (``pip install -e .`` runs a DLPF frame loop, which
compiles them too).
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
    """Compile (or load from numba's cache) the kernels with the signatures the classifier
    calls them with."""
    img = np.zeros((CELL * 3 + 2, CELL * 3 + 2), dtype=np.uint8)
    region_blocks(img, 2, 2, 1, 1, np.zeros((1, 2), dtype=np.int64), block_weights(), 0.2,
                  np.zeros((1, 4 * NBINS), dtype=np.float32))
    warp_region(img, 1.0, 0.0, 0.0, np.empty_like(img))
    one = np.zeros(1, dtype=np.int64)
    region_layout(one, one, one, 8, 16)
    window_margins(np.zeros((1, 4 * NBINS), dtype=np.float32), np.zeros((1, 105), np.int64),
                   np.zeros(105 * 4 * NBINS, dtype=np.float32), np.zeros(1, dtype=np.float32))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _round_even(v):
    """``cvRound`` of a double: nearest integer, halves to even (as ``np.rint``)."""
    r = math.floor(v)
    d = v - r                                   # exact below 2**52
    if d > 0.5 or (d == 0.5 and r - 2.0 * math.floor(r * 0.5) != 0.0):
        r += 1.0
    return np.int64(r)


@njit(cache=True, nogil=True, error_model="numpy")
def warp_region(grey, a, tx, ty, img):
    """``cv2.warpAffine(grey, [[a, 0, tx], [0, a, ty]], img's size, INTER_LINEAR |
    WARP_INVERSE_MAP, BORDER_REPLICATE)`` into ``img``, with OpenCV's own fixed-point
    arithmetic (source coordinates rounded to 1/32 px from 1/1024 steps, the 4 neighbours
    weighted by (32 − f)·f products, +2^14 >> 15, each neighbour's coordinate clamped to the
    image): the same bytes.  The map is separable (no rotation), so each source row's
    horizontal blend serves every output row that reads it."""
    Hs, Ws = grey.shape
    H, W = img.shape
    ix0 = np.empty(W, dtype=np.int64)
    ix1 = np.empty(W, dtype=np.int64)
    fx = np.empty(W, dtype=np.int32)
    X0 = _round_even(tx * 1024.0) + 16
    for x in range(W):
        X = (X0 + _round_even(a * x * 1024.0)) >> 5
        i0 = X >> 5
        fx[x] = np.int32(X & 31)
        i1 = i0 + 1
        ix0[x] = 0 if i0 < 0 else (Ws - 1 if i0 > Ws - 1 else i0)
        ix1[x] = 0 if i1 < 0 else (Ws - 1 if i1 > Ws - 1 else i1)
    h0 = np.empty(W, dtype=np.int32)      # the horizontal blends of source rows s0, s0 + 1
    h1 = np.empty(W, dtype=np.int32)
    have0 = -1
    have1 = -1
    for y in range(H):
        Y = (_round_even((a * y + ty) * 1024.0) + 16) >> 5
        j0 = Y >> 5
        fy = np.int32(Y & 31)
        gy = np.int32(32) - fy
        j1 = j0 + 1
        j0 = 0 if j0 < 0 else (Hs - 1 if j0 > Hs - 1 else j0)
        j1 = 0 if j1 < 0 else (Hs - 1 if j1 > Hs - 1 else j1)
        if j0 != have0:
            if j0 == have1:
                for x in range(W):
                    h0[x] = h1[x]
            else:
                r = grey[j0]
                for x in range(W):
                    h0[x] = np.int32(r[ix0[x]]) * (np.int32(32) - fx[x]) + np.int32(r[ix1[x]]) * fx[x]
            have0 = j0
        if j1 != have1:
            r = grey[j1]
            for x in range(W):
                h1[x] = np.int32(r[ix0[x]]) * (np.int32(32) - fx[x]) + np.int32(r[ix1[x]]) * fx[x]
            have1 = j1
        out = img[y]
        for x in range(W):
            out[x] = np.uint8(((h0[x] * gy + h1[x] * fy) * np.int32(32) + np.int32(16384))
                              >> np.int32(15))


@njit(cache=True, nogil=True, error_model="numpy")
def window_margins(blocks, binv, w, out):
    """``out[i] = Σ_j d_i[j] · w[j]`` (float32) for the descriptors ``d_i`` = ``blocks[binv[i]]``
    laid end to end (36 floats per block, ``binv`` (N, 105)), without building the (N, 3780)
    descriptor array.  The sums are taken in the order of numpy's ``einsum("ij,j->i")`` on
    float32 (its SIMD inner loop: 4 lanes, 16 products a step added last-vector first, a
    4-lane tail, the lanes summed pairwise ``(l0 + l1) + (l2 + l3)``; no fused multiply-add),
    so the margins are the same floats as that einsum's (tests/test_dlpf.py)."""
    n, nbk = binv.shape
    L = blocks.shape[1]
    D = nbk * L
    desc = np.empty(D, dtype=np.float32)
    acc = np.empty(4, dtype=np.float32)
    for i in range(n):
        for q in range(nbk):
            b = binv[i, q]
            for t in range(L):
                desc[q * L + t] = blocks[b, t]
        for lane in range(4):
            acc[lane] = np.float32(0.0)
        c = 0
        while c + 16 <= D:
            for lane in range(4):
                a = acc[lane]
                a = desc[c + 12 + lane] * w[c + 12 + lane] + a
                a = desc[c + 8 + lane] * w[c + 8 + lane] + a
                a = desc[c + 4 + lane] * w[c + 4 + lane] + a
                a = desc[c + lane] * w[c + lane] + a
                acc[lane] = a
            c += 16
        while c < D:
            for lane in range(4):
                if c + lane < D:
                    acc[lane] = desc[c + lane] * w[c + lane] + acc[lane]
            c += 4
        out[i] = (acc[0] + acc[1]) + (acc[2] + acc[3])


@njit(cache=True, nogil=True, error_model="numpy")
def region_layout(k, cu, cv, wx, wy):
    """The pyramid's bookkeeping for the distinct windows ``(k, cu, cv)`` (level, top-left
    cell; ``wx`` × ``wy`` cells each).  Regions: the 4-connected components of each level's
    union of window cells (two windows of one level touch when their cell rectangles overlap
    or share an edge), labelled 0.. in order of each region's first window.  Returns ``(reg``
    (label per window), ``x0, y0, x1, y1`` (each region's cell rectangle), ``rlev`` (its level),
    ``binv`` (N, (wx-1)(wy-1)): each window's blocks in OpenCV's order (x outer) as rows of the
    distinct blocks, ``local``: each distinct block's place on its region's ``(x1-x0-1)``-wide
    block grid, ``cuts``: the distinct blocks of region ``r`` are rows ``cuts[r]:cuts[r+1]``)``.
    Integer work only: the same as the numpy version it replaces."""
    n = k.shape[0]
    parent = np.empty(n, dtype=np.int64)
    for i in range(n):
        parent[i] = i
    for i in range(n):          # union by smallest index: a root is its component's first
        for j in range(i + 1, n):
            if k[i] != k[j]:
                continue
            du = cu[i] - cu[j]
            du = -du if du < 0 else du
            dv = cv[i] - cv[j]
            dv = -dv if dv < 0 else dv
            if du <= wx and dv <= wy and not (du == wx and dv == wy):
                a = i
                while parent[a] != a:
                    a = parent[a]
                b = j
                while parent[b] != b:
                    b = parent[b]
                if a < b:
                    parent[b] = a
                elif b < a:
                    parent[a] = b
    label = np.empty(n, dtype=np.int64)
    nreg = 0
    for i in range(n):
        a = i
        while parent[a] != a:
            a = parent[a]
        parent[i] = a
        if a == i:
            label[i] = nreg
            nreg += 1
    reg = np.empty(n, dtype=np.int64)
    x0 = np.empty(nreg, dtype=np.int64)
    y0 = np.empty(nreg, dtype=np.int64)
    x1 = np.empty(nreg, dtype=np.int64)
    y1 = np.empty(nreg, dtype=np.int64)
    rlev = np.empty(nreg, dtype=np.int64)
    for i in range(n):
        r = label[parent[i]]
        reg[i] = r
        if parent[i] == i:      # the region's first window
            x0[r] = cu[i]
            y0[r] = cv[i]
            x1[r] = cu[i] + wx
            y1[r] = cv[i] + wy
            rlev[r] = k[i]
        else:
            if cu[i] < x0[r]:
                x0[r] = cu[i]
            if cv[i] < y0[r]:
                y0[r] = cv[i]
            if cu[i] + wx > x1[r]:
                x1[r] = cu[i] + wx
            if cv[i] + wy > y1[r]:
                y1[r] = cv[i] + wy
    off = np.empty(nreg + 1, dtype=np.int64)
    off[0] = 0
    for r in range(nreg):
        off[r + 1] = off[r] + (x1[r] - x0[r] - 1) * (y1[r] - y0[r] - 1)
    # every block of every window as its place on its region's block grid (regions one after
    # the other): a block two windows share has one place, so marking the places used gives
    # the distinct blocks, grouped by region, without sorting
    bx, by = wx - 1, wy - 1
    index = np.empty(off[nreg], dtype=np.int64)
    for p in range(off[nreg]):
        index[p] = -1
    binv = np.empty((n, bx * by), dtype=np.int64)
    # each window's first block's place and its region's grid width (used twice below)
    base = np.empty(n, dtype=np.int64)
    gws = np.empty(n, dtype=np.int64)
    for i in range(n):
        r = reg[i]
        gws[i] = x1[r] - x0[r] - 1
        base[i] = off[r] + (cv[i] - y0[r]) * gws[i] + (cu[i] - x0[r])
        for a in range(bx):
            for b in range(by):
                index[base[i] + b * gws[i] + a] = 0
    m = 0
    for p in range(off[nreg]):
        if index[p] == 0:
            index[p] = m
            m += 1
    local = np.empty(m, dtype=np.int64)
    cuts = np.empty(nreg + 1, dtype=np.int64)
    m = 0
    for r in range(nreg):
        cuts[r] = m
        for p in range(off[r], off[r + 1]):
            if index[p] >= 0:
                local[m] = p - off[r]
                m += 1
    cuts[nreg] = m
    for i in range(n):
        for a in range(bx):
            for b in range(by):
                binv[i, a * by + b] = index[base[i] + b * gws[i] + a]
    return reg, x0, y0, x1, y1, rlev, binv, local, cuts
