"""Gating: which (particle, detection) pairs the PHD filter looks at — DESIGN.md, "evaluate [the
likelihood] only where it matters (gating), so the cost stays linear in the number of targets".

maggio2007 eq. (5) sums ``ψ_z(x) = (1 − p_M) g(z|x)`` over every particle and every detection,
and §2 computes the birth allocation from the mass ``M(z)`` inside the 99% gate of each z.
Done densely both are (N particles × N_z detections): quadratic in the number of targets, and a
storm of clutter detections allocates gigabytes.  But the Gaussian g of §2/§4 is negligible
outside a few observation-noise standard deviations of z, so each detection only needs the
particles near it.

This module finds those pairs without ever forming the dense matrix:

- :class:`GridIndex` buckets particles on a uniform grid over the image position ``(y1, y2)``
  (one ``argsort`` of the cell keys).  A query box around each detection becomes a few
  contiguous *runs* of the sorted particles (one per grid row the box spans), found with
  ``searchsorted`` — no Python loop over particles or detections.
- :func:`gate_pairs` turns the runs into candidate pairs, keeps those whose squared
  Mahalanobis distance ``d² = Σ ((x_obs − z) / σ)²`` under the observation noise is ``<= r²``,
  and yields them in chunks of at most ``budget`` candidates (plus one detection's worth), each
  chunk holding *every* in-gate pair of a set of detections (columns are never split between
  chunks).  Memory is therefore bounded by the budget, whatever the number of detections.

The gate radius for the update is set by a tail probability (:func:`tail_radius2`):
``r² = χ²₄⁻¹(1 − tail)``.  Bound: a pair outside the gate has
``g(z|x) < e^{−r²/2} g_max(z)``, and eq. (5) with g set to 0 there changes

- each C(z) by less than ``(1 − p_M) e^{−r²/2} g_max(z) M̂`` (M̂ the total mass), and
- each particle's bracket ``p_M + Σ_z ψ_z/(κ + C)`` by less than
  ``(1 − p_M) e^{−r²/2} g_max(z) / κ(z)`` per detection, i.e. relatively by that over p_M.

With maggio2007's clutter reading ``κ(z) / g_max(z) = 8 / r₉₉⁴ ≈ 0.045`` (filter module
docstring), p_M = 0.05 and the default ``tail = 1e-12`` (``r² = 62.2``,
``e^{−r²/2} = 3.1e-14``), the worst case is a relative change below ``1.3e-11`` per dropped pair
in any particle's weight and below ``6.5e-13 M̂`` in C(z)/κ(z): float noise (measured on a
normal scene: ``<= 2e-12``).  With ``clutter_rate = 0`` κ is 0 and only the first bound holds;
with ``obs_std_source="particle"`` g_max is the particle's own peak.  The gate test runs in
float32 on positions relative to the grid origin, with the radius widened by the rounding it
can cause, so float32 only ever adds pairs at the edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Iterator, Optional

import numpy as np
from numba import njit

#: Default number of candidate pairs handled at once (~150 bytes each in flight).
DEFAULT_BUDGET = 1_000_000


@lru_cache(maxsize=32)
@lru_cache(maxsize=32)
def tail_radius2(tail: float, dof: int = 4) -> float:
    """Squared Mahalanobis radius ``r²`` with ``P(χ²_dof > r²) = tail`` (``isf``, accurate for
    tiny tails where ``ppf(1 − tail)`` would round)."""
    # scipy.stats.chi2.isf's own formula (the same float) without importing scipy.stats
    from scipy.special import chdtri

    return float(chdtri(dof, tail))


@dataclass(frozen=True)
class LogGPairs:
    """``log g(z|x)`` on a sparse set of (particle, detection) pairs; every pair not listed has
    ``g = 0`` (``log g = −inf``).

    rows (P,) intp particle index; cols (P,) intp detection index; values (P,) float64
    ``log g(z_cols | x_rows)``.  No pair may be listed twice."""

    rows: np.ndarray
    cols: np.ndarray
    values: np.ndarray

    def __post_init__(self):
        rows = np.asarray(self.rows, dtype=np.intp).reshape(-1)
        cols = np.asarray(self.cols, dtype=np.intp).reshape(-1)
        values = np.asarray(self.values, dtype=np.float64).reshape(-1)
        if not len(rows) == len(cols) == len(values):
            raise ValueError(f"LogGPairs: {len(rows)} rows, {len(cols)} cols and "
                             f"{len(values)} values")
        object.__setattr__(self, "rows", rows)
        object.__setattr__(self, "cols", cols)
        object.__setattr__(self, "values", values)

    def __len__(self) -> int:
        return len(self.values)


@dataclass(frozen=True)
class GatedPairs:
    """One chunk of :func:`gate_pairs`: rows (P,) intp particle index, cols (P,) intp detection
    index (non-decreasing), d2 (P,) squared Mahalanobis distance (``<= r²``); ``detections``
    (2,) the half-open range of detection indices whose pairs this chunk holds completely."""

    rows: np.ndarray
    cols: np.ndarray
    d2: np.ndarray
    detections: tuple[int, int]

    def __len__(self) -> int:
        return len(self.rows)


class GridIndex:
    """Points ``xy`` (N, 2) bucketed on a uniform grid of ``cell`` (2,) pixels.

    ``order`` (N,) the point indices sorted by cell key ``i · n_j + j`` (stable, so ties keep
    index order and the index is deterministic); ``keys`` (N,) the sorted keys."""

    def __init__(self, xy: np.ndarray, cell: np.ndarray):
        xy = np.asarray(xy, dtype=np.float64)
        cell = np.asarray(cell, dtype=np.float64).reshape(2)
        c0, c1 = float(cell[0]), float(cell[1])     # python tests: two numbers, ~7 us of ufuncs
        if not (c0 > 0 and c1 > 0 and math.isfinite(c0) and math.isfinite(c1)):
            raise ValueError(f"GridIndex: cell sizes must be finite and > 0, got {cell}")
        self.n = len(xy)
        if self.n == 0:
            self.origin = np.zeros(2)
            self.cell = cell
            self.shape = np.zeros(2, dtype=np.int64)
            self.order = np.zeros(0, dtype=np.intp)
            self.keys = np.zeros(0, dtype=np.int64)
            return
        # per column: numpy's axis-0 reduction of an (N, 2) array walks it ~4x slower than a
        # column's (the same minima and maxima, exact)
        x, y = xy[:, 0], xy[:, 1]
        lo = np.array([x.min(), y.min()])
        hi = np.array([x.max(), y.max()])
        # Far-flung points would make the key space overflow: grow the cells until it fits.
        extent = np.floor((hi - lo) / cell) + 1
        while extent[0] * extent[1] > 2.0 ** 60:
            cell = cell * 2.0
            extent = np.floor((hi - lo) / cell) + 1
        self.origin, self.cell = lo, cell
        self.shape = extent.astype(np.int64)
        # the cell of each point, a column at a time (the same floats as on the (N, 2) array)
        i = np.minimum(np.floor((x - lo[0]) / cell[0]).astype(np.int64), self.shape[0] - 1)
        j = np.minimum(np.floor((y - lo[1]) / cell[1]).astype(np.int64), self.shape[1] - 1)
        key = i * self.shape[1] + j
        self.order = np.argsort(key, kind="stable")
        self.keys = key[self.order]

    def _cells(self, v: np.ndarray, axis: int) -> np.ndarray:
        """Cell coordinate of values ``v`` along ``axis``, clipped to [-1, shape] before the
        integer cast (so huge or infinite values cannot overflow)."""
        c = np.floor((v - self.origin[axis]) / self.cell[axis])
        return np.clip(c, -1, self.shape[axis]).astype(np.int64)

    def runs(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Runs of ``order`` covering the cells that boxes ``[lo, hi]`` (M, 2) touch.

        Returns ``owner`` (R,) the box of each run (non-decreasing), ``start``/``stop`` (R,)
        positions in ``order``.  Every point inside a box is in one of its runs; a run may hold
        points outside the box (the rest of its cells), never a point twice for one box."""
        m = len(lo)
        empty = np.zeros(0, dtype=np.intp)
        if self.n == 0 or m == 0:
            return empty, empty, empty
        i0, i1 = self._cells(lo[:, 0], 0), self._cells(hi[:, 0], 0)
        j0, j1 = self._cells(lo[:, 1], 1), self._cells(hi[:, 1], 1)
        ni, nj = self.shape
        i0, j0 = np.maximum(i0, 0), np.maximum(j0, 0)
        i1, j1 = np.minimum(i1, ni - 1), np.minimum(j1, nj - 1)
        n_rows = np.where((i1 >= i0) & (j1 >= j0), i1 - i0 + 1, 0)
        owner = np.repeat(np.arange(m, dtype=np.intp), n_rows)
        first = np.cumsum(n_rows) - n_rows
        i = i0[owner] + (np.arange(len(owner)) - first[owner])
        # One grid row of a box is one contiguous key range [i nj + j0, i nj + j1].
        start = np.searchsorted(self.keys, i * nj + j0[owner], side="left")
        stop = np.searchsorted(self.keys, i * nj + j1[owner], side="right")
        keep = stop > start
        return owner[keep], start[keep].astype(np.intp), stop[keep].astype(np.intp)


def expand_runs(start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(start[r], stop[r])`` over runs r, vectorised."""
    lens = stop - start
    total = int(lens.sum())
    if total == 0:
        return np.zeros(0, dtype=np.intp)
    offset = np.cumsum(lens) - lens
    return np.repeat(start - offset, lens) + np.arange(total, dtype=np.intp)


def gate_pairs(obs: np.ndarray, Z: np.ndarray, r2: float, *, std_z: Optional[np.ndarray] = None,
               std_x: Optional[np.ndarray] = None, budget: int = DEFAULT_BUDGET,
               dtype=np.float64, index: Optional[GridIndex] = None) -> Iterator[GatedPairs]:
    """Every pair (particle i, detection j) with ``d²_ij = Σ_d ((obs_id − Z_jd) / σ_d)² <= r2``.

    obs (N, 4) the particles' observed part ``(y1, y2, w, h)``; Z (N_z, 4) the detections.
    The noise std σ is either per detection (``std_z`` (N_z, 4), maggio2007 §2 "proportional to
    the sizes w and h of each z") or per particle (``std_x`` (N, 4)); exactly one is given.
    ``dtype``: precision of the distance test (float32 halves the memory traffic; the pairs at
    the gate's edge it may flip carry ``g < e^{−r²/2} g_max``).  ``index``: a prebuilt
    :class:`GridIndex` on ``obs[:, :2]`` (built here when None).

    Yields :class:`GatedPairs` chunks over consecutive detection ranges, each holding every
    in-gate pair of its detections, with at most ``budget`` candidates per chunk unless a
    single detection has more.  Pairs are ordered by detection, then by grid cell."""
    if (std_z is None) == (std_x is None):
        raise ValueError("gate_pairs: give exactly one of std_z (per detection) or std_x "
                         "(per particle)")
    n, n_z = len(obs), len(Z)
    if n == 0 or n_z == 0:
        return
    r = math.sqrt(r2)
    obs = np.asarray(obs, dtype=np.float64)
    Z = np.asarray(Z, dtype=np.float64)
    # Query box: the gate ellipsoid's extent in (y1, y2), a hair wider for rounding.
    if std_z is not None:
        half = r * np.asarray(std_z, dtype=np.float64)[:, :2] * (1 + 1e-6) + 1e-9
    else:
        half = np.broadcast_to(r * np.max(std_x[:, :2], axis=0) * (1 + 1e-6) + 1e-9, (n_z, 2))
    if index is None:
        # Cells as wide as a typical gate: a typical box spans at most 2 x 2 cells, the largest
        # about (largest / median gate) + 1 grid rows, whatever the particles' extent.
        index = GridIndex(obs[:, :2], 2.0 * _median0(half))
    owner, start, stop = index.runs(Z[:, :2] - half, Z[:, :2] + half)
    if len(owner) == 0:
        return
    n_cand = np.bincount(owner, weights=stop - start, minlength=n_z)
    before = np.cumsum(n_cand) - n_cand
    # Detection j goes to chunk floor(candidates before j / budget): every chunk but the last
    # holds about `budget` candidates, a chunk never splits a detection.
    chunk_of = (before // max(int(budget), 1)).astype(np.int64)
    bounds = np.flatnonzero(np.diff(chunk_of)) + 1
    det_edges = np.concatenate([[0], bounds, [n_z]])
    run_edges = np.searchsorted(owner, det_edges, side="left")

    std = np.asarray(std_z if std_z is not None else std_x, dtype=np.float64)
    by_det = std_z is not None
    exact = np.dtype(dtype).itemsize >= 8
    if exact:
        # float64: the same operations as the dense distance (x − z) / σ, bit for bit.
        xo, zz, scl = np.asarray(obs, dtype=np.float64), np.asarray(Z, dtype=np.float64), std
        r2_test = r2
    else:
        # Positions relative to the grid origin, so the low precision is relative to the
        # scene's extent, not to the absolute coordinates; the test radius grows by the
        # rounding that can cause (pairs at the edge carry g < e^{-r²/2} g_max anyway).
        shift = np.zeros(4)
        shift[:2] = index.origin
        xo, zz = np.asarray(obs - shift, dtype=dtype), np.asarray(Z - shift, dtype=dtype)
        scl = np.asarray(1.0 / std, dtype=dtype)
        eps = float(np.finfo(dtype).eps)
        scale = max(float(np.max(np.abs(xo))), float(np.max(np.abs(zz))))
        r2_test = (r + 8.0 * eps * scale / float(np.min(std))) ** 2 * (1 + 8.0 * eps)
    for c in range(len(det_edges) - 1):
        r_lo, r_hi = run_edges[c], run_edges[c + 1]
        if r_hi == r_lo:
            continue
        o, s, e = owner[r_lo:r_hi], start[r_lo:r_hi], stop[r_lo:r_hi]
        rows = index.order[expand_runs(s, e)]
        cols = np.repeat(o, e - s)
        q = xo[rows]
        q -= zz[cols]
        sc = scl[cols] if by_det else scl[rows]
        if exact:
            q /= sc
        else:
            q *= sc
        d2 = np.einsum("ij,ij->i", q, q)
        keep = d2 <= r2_test
        yield GatedPairs(rows[keep], cols[keep], d2[keep],
                         (int(det_edges[c]), int(det_edges[c + 1])))


def _median0(a: np.ndarray) -> np.ndarray:
    """``np.median(a, axis=0)`` of a (n >= 1, k) array without its generic machinery (the same
    floats: the middle value, or the mean ``(a + b) / 2`` of the two middle ones)."""
    s = np.sort(a, axis=0)
    h = len(s) // 2
    return s[h] if len(s) % 2 else (s[h - 1] + s[h]) / 2.0


#: gate_sums in any order: below this many (point, detection) pairs every pair is tested (no
#: grid to build); above, the grid keeps the cost linear in the detections
BRUTE_PAIRS = 4096


def gate_sums(obs: np.ndarray, Z: np.ndarray, r2: float, std_z: np.ndarray, w: np.ndarray,
              e: Optional[np.ndarray] = None, ordered: bool = True
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per detection j, over the points i inside its gate (``d²_ij <= r2`` as in
    :func:`gate_pairs` with ``std_z``): ``S_j = Σ w_i``, ``E_j = max(0, max e_i)`` and the
    count ``C_j`` (N_z,) int64 -- what ``np.bincount`` / ``np.maximum.at`` over
    :func:`gate_pairs`' pairs give, without the pair arrays: one numba pass over the same grid
    (:class:`GridIndex`, the same cells), each detection's points visited in the same order
    (so ``S`` sums the same floats in the same order).  For the clutter model's memory and the
    detections' neighbours (:mod:`.clutter`), which ask this four times a frame of a few
    hundred points at most: the pairs' ~40 numpy calls were most of their cost.
    ``ordered=False``: the caller needs no particular summation order (counts, sums of 0s and
    1s), so small inputs (< :data:`BRUTE_PAIRS` pairs) test every pair without a grid."""
    n_z = len(Z)
    S, E, C = np.zeros(n_z), np.zeros(n_z), np.zeros(n_z, dtype=np.int64)
    if len(obs) == 0 or n_z == 0:
        return S, E, C
    obs = np.ascontiguousarray(obs, dtype=np.float64)
    Z = np.ascontiguousarray(Z, dtype=np.float64)
    std = np.ascontiguousarray(std_z, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    e = w if e is None else np.ascontiguousarray(e, dtype=np.float64)
    if not ordered and len(obs) * n_z < BRUTE_PAIRS:
        _gate_sums(obs, w, e, Z, std, float(r2), _NO_GRID, _NO_GRID, 0.0, 0.0, 1.0, 1.0, 0, 0,
                   S, E, C)
        return S, E, C
    if _gate_sums_cells(obs, w, e, Z, std, float(r2), S, E, C):
        return S, E, C
    # a grid the one-pass build does not take (non-finite values, a sparse key space):
    # GridIndex, then the same pass
    half = math.sqrt(r2) * std[:, :2] * (1 + 1e-6) + 1e-9      # gate_pairs' query boxes
    cell = 2.0 * _median0(half)
    index = GridIndex(obs[:, :2], cell)
    _gate_sums(obs, w, e, Z, std, float(r2), index.order.astype(np.int64, copy=False),
               index.keys, float(index.origin[0]), float(index.origin[1]),
               float(index.cell[0]), float(index.cell[1]), int(index.shape[0]),
               int(index.shape[1]), S, E, C)
    return S, E, C


_NO_GRID = np.zeros(0, dtype=np.int64)
#: the one-pass grid of :func:`_gate_sums_grid` sorts its points by counting when the grid has
#: at most this many cells per point (plus a constant); sparser grids go through GridIndex
COUNT_SORT_CELLS = 8


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _gate_sums_cells(obs, w, e, Z, std, r2, S, E, C):
    """:func:`_gate_sums_grid` on :func:`gate_sums`' cells (:func:`gate_cells_of`).  False
    (nothing written) on a non-finite std or where the grid kernel declines."""
    cell = np.empty(2)
    if not gate_cells_of(std, r2, cell):
        return False
    return _gate_sums_grid(obs, w, e, Z, std, r2, cell[0], cell[1], S, E, C)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def gate_cells_of(std, r2, cell):
    """``cell`` (2,) = ``2 median(r σ (1 + 1e-6) + 1e-9)`` per axis over the rows of ``std``
    (N >= 1, 4): gate_sums' grid cells, ``2 ×`` :func:`_median0` of gate_pairs' query boxes,
    the middle values found by selection and then mapped (the map is monotone: the same
    floats).  False on a non-finite std (the caller's numpy form decides)."""
    n = std.shape[0]
    r = math.sqrt(r2)
    tmp = np.empty(n)
    h = n // 2
    for c in range(2):
        for j in range(n):
            if not math.isfinite(std[j, c]):
                return False
            tmp[j] = std[j, c]
        hi = r * kth(tmp, h) * (1 + 1e-6) + 1e-9
        if n % 2:
            med = hi
        else:
            lo = tmp[0]                         # kth left a[:h] <= a[h]: the next is their max
            for j in range(1, h):
                lo = tmp[j] if tmp[j] > lo else lo
            med = ((r * lo * (1 + 1e-6) + 1e-9) + hi) / 2.0
        cell[c] = 2.0 * med
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def kth(a, k):
    """The ``k``-th smallest of ``a`` (no NaN; Hoare's selection, middle pivot: the value
    np.sort / np.partition put at ``k``), ``a`` reordered so that ``a[:k] <= a[k] <= a[k + 1:]``."""
    lo, hi = np.int64(0), np.int64(a.shape[0] - 1)
    while lo < hi:
        p = a[(lo + hi) >> 1]
        i, j = lo, hi
        while i <= j:
            while a[i] < p:
                i += 1
            while a[j] > p:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return a[k]


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _gate_sums_grid(obs, w, e, Z, std, r2, cx, cy, S, E, C):
    """:func:`gate_sums`' grid path in one pass: the :class:`GridIndex` of ``obs[:, :2]`` on
    cells ``(cx, cy)`` (the same origin, grown cells, shape, keys and stable order: grown until
    the key space fits, each point's cell clipped to the grid, points sorted by key and by
    index within a key -- here by counting), then :func:`_gate_sums`.  False (nothing
    written) where GridIndex must decide: a non-finite cell or point, or more than
    ``COUNT_SORT_CELLS`` cells per point."""
    n = obs.shape[0]
    if not (cx > 0 and cy > 0 and math.isfinite(cx) and math.isfinite(cy)):
        return False
    x0, y0, x1, y1 = obs[0, 0], obs[0, 1], obs[0, 0], obs[0, 1]
    for i in range(n):
        x, y = obs[i, 0], obs[i, 1]
        if not (math.isfinite(x) and math.isfinite(y)):
            return False
        x0 = x if x < x0 else x0
        y0 = y if y < y0 else y0
        x1 = x if x > x1 else x1
        y1 = y if y > y1 else y1
    # GridIndex's float extent (np.floor: a float, as there; math.floor would be an integer)
    ex = np.floor((x1 - x0) / cx) + 1.0
    ey = np.floor((y1 - y0) / cy) + 1.0
    while ex * ey > 2.0 ** 60:
        cx, cy = cx * 2.0, cy * 2.0
        ex = np.floor((x1 - x0) / cx) + 1.0
        ey = np.floor((y1 - y0) / cy) + 1.0
    if ex * ey > COUNT_SORT_CELLS * n + 4096:
        return False
    ni, nj = np.int64(ex), np.int64(ey)
    key = np.empty(n, dtype=np.int64)
    count = np.zeros(ni * nj + 1, dtype=np.int64)
    for p in range(n):
        i = min(np.int64(math.floor((obs[p, 0] - x0) / cx)), ni - 1)
        j = min(np.int64(math.floor((obs[p, 1] - y0) / cy)), nj - 1)
        key[p] = i * nj + j
        count[key[p] + 1] += 1
    for k in range(ni * nj):
        count[k + 1] += count[k]
    order = np.empty(n, dtype=np.int64)
    keys = np.empty(n, dtype=np.int64)
    for p in range(n):
        at = count[key[p]]
        order[at] = p
        keys[at] = key[p]
        count[key[p]] = at + 1
    _gate_sums(obs, w, e, Z, std, r2, order, keys, x0, y0, cx, cy, ni, nj, S, E, C)
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _gate_sums(obs, w, e, Z, std, r2, order, keys, ox, oy, cx, cy, ni, nj, S, E, C):
    """:func:`gate_sums`' pass, into ``S``, ``E``, ``C`` (zeros): :meth:`GridIndex.runs` and
    :func:`gate_pairs`' test per detection, its runs' points in order (``ni`` = 0: no grid,
    every point in index order)."""
    r = math.sqrt(r2)
    n = obs.shape[0]
    for j in range(Z.shape[0]):
        # ni = 0: no grid (ordered=False, few pairs): one run of every point, in index order
        i0 = i1 = j0 = j1 = 0
        if ni > 0:
            hx = r * std[j, 0] * (1 + 1e-6) + 1e-9
            hy = r * std[j, 1] * (1 + 1e-6) + 1e-9
            # GridIndex._cells (floor, clipped to [-1, shape]), then runs' clip to the grid
            a = (Z[j, 0] - hx - ox) / cx
            b = (Z[j, 0] + hx - ox) / cx
            c = (Z[j, 1] - hy - oy) / cy
            d = (Z[j, 1] + hy - oy) / cy
            i0 = math.floor(-1.0 if a < -1.0 else (ni if a > ni else a))
            i1 = math.floor(-1.0 if b < -1.0 else (ni if b > ni else b))
            j0 = math.floor(-1.0 if c < -1.0 else (nj if c > nj else c))
            j1 = math.floor(-1.0 if d < -1.0 else (nj if d > nj else d))
            i0 = 0 if i0 < 0 else i0
            j0 = 0 if j0 < 0 else j0
            i1 = ni - 1 if i1 > ni - 1 else i1
            j1 = nj - 1 if j1 > nj - 1 else j1
            if i1 < i0 or j1 < j0:
                continue
        s = 0.0
        m = 0.0
        k = 0
        for i in range(i0, i1 + 1):
            start, lo = 0, n
            if ni > 0:
                # searchsorted(keys, i nj + j0, "left") .. searchsorted(keys, i nj + j1, "right")
                key = i * nj + j0
                lo, hi = 0, n
                while lo < hi:
                    mid = (lo + hi) >> 1
                    if keys[mid] < key:
                        lo = mid + 1
                    else:
                        hi = mid
                start = lo
                key = i * nj + j1
                hi = n
                while lo < hi:
                    mid = (lo + hi) >> 1
                    if keys[mid] <= key:
                        lo = mid + 1
                    else:
                        hi = mid
            for p in range(start, lo):
                q = order[p] if ni > 0 else p
                d0 = (obs[q, 0] - Z[j, 0]) / std[j, 0]
                d1 = (obs[q, 1] - Z[j, 1]) / std[j, 1]
                d2 = (obs[q, 2] - Z[j, 2]) / std[j, 2]
                d3 = (obs[q, 3] - Z[j, 3]) / std[j, 3]
                if d0 * d0 + d1 * d1 + d2 * d2 + d3 * d3 <= r2:
                    s += w[q]
                    k += 1
                    m = e[q] if e[q] > m else m
        S[j] = s
        E[j] = m
        C[j] = k
