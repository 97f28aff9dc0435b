"""The parents' pedestrian classifier: HOG + linear SVM evaluated one window at a time
(jung2013 §2.1; Dalal & Triggs 2005 features).

jung2013 trains an intersection-kernel SVM (Maji et al. 2008): :mod:`.iksvm`
(``pfscope train-classifier``, ``--set model=FILE``).  The default here needs no training:
OpenCV's pre-trained Dalal–Triggs people SVM (``cv2.HOGDescriptor_getDefaultPeopleDetector``:
3780 weights + bias over the 64×128 HOG window), applied to *single windows* instead of a
sliding-window scan.

One parent = one window.  A parent at ``(x, y)`` with person height ``h`` (its randomly drawn
scale) looks at the window centred on ``(x, y)`` whose person part is ``h`` tall: Dalal & Triggs
train the 64×128 window with a 16-px context border, so the person fills the central 96 rows and
32 columns; the window is ``h·128/96`` tall and half as wide.  The window is cut from the frame
(replicated at the borders) and **resampled to 64×128 whatever its size**: people smaller than
the HOG window (PETS09: ~80 px tall at 768×576, half that at 480×360) are enlarged, not skipped.

Cost (``mode``):

- ``"pyramid"`` (default).  The parents' windows are snapped to a pyramid: a window whose height
  ``h_win`` gives the scale ``128 / h_win`` goes to the nearest level ``k`` (scale
  ``scale_step**k``, default 1.1: within ±5 %) and its top-left corner to the nearest node of
  that level's 8-px grid (within ±4 level px) — the grid and the window HOG's block stride, so
  windows on one level share their 16×16 blocks.  Resampled parents are often exact copies
  (about half the windows of a PETS09 frame are duplicates) and overlapping windows share most
  blocks: per frame, each distinct window is scored once and each block it uses is computed
  once.  Per level, the windows' union is split into connected regions (windows whose cell
  rectangles overlap or share an edge, one pairwise test over the frame's distinct windows: the
  4-connected components of the union of their cells, without rasterising it); each region is
  resampled once from the frame
  (``cv2.warpAffine``'s bytes, computed by :func:`._hog_kernels.warp_region` with OpenCV's
  fixed-point arithmetic; level px ``u`` samples frame px ``(u + 0.5)/s − 0.5`` like
  ``cv2.resize``; replicated border; 1 px more on each side so that border gradients see their
  real neighbours) and its needed blocks are computed by one kernel call
  (:func:`._hog_kernels.region_blocks`: OpenCV's HOG blocks — gradient, 9 unsigned bins,
  Gaussian block weight, bilinear cell split, L2-Hys, gamma — from sums shared by the
  overlapping blocks: the block weights are separable, so each region row's horizontal sums
  serve every block of its block column); a window's descriptor is its 7×15 blocks in
  OpenCV's order (x outer), and the linear SVM's margin is summed straight from the blocks
  (:func:`._hog_kernels.window_margins`, in numpy's einsum order: the same floats as the
  gathered descriptors' ``D·w``) — no (N, 3780) array.  The regions, their rectangles and the
  distinct blocks come from one integer kernel (:func:`._hog_kernels.region_layout`).  At integer level offsets this equals OpenCV's
  descriptor of the window on the level image up to float rounding (~1e-6); elsewhere up to
  warpAffine's 1/32-px coordinate rounding (tests/test_dlpf.py).  ``opencv_blocks=True``
  computes the blocks with OpenCV's ``HOGDescriptor.compute`` (``locations``, one block at a
  time: each pixel's gradient visited by the four blocks over it; ~1.8x the kernel's CPU).
  PETS09 frames 1–120: ~8.3 k blocks/frame instead of 310 × 105 = 32.5 k,
  over ~630 k level px.  With ``threads`` > 1
  the regions are split into shares of equal area computed by that many threads (the kernel
  and OpenCV release the GIL; each block is computed by one thread, so the margins do not
  depend on it).
- ``"window"``: one ``cv2.resize`` + the kernel's 105 blocks per window (a loop over a
  few hundred windows, ~0.1 ms per window, split over ``threads``), no snapping.

Both stack descriptors into (N, 3780) and score them with one matrix product ``D·w + b`` (or
the intersection-kernel SVM's lookup tables, :mod:`.iksvm`).  The tracker scores its tracks'
few verification windows with the exact per-window path (``score(..., exact=True)``): their
boxes localise the tracks.

:func:`sliding_window_count` counts the windows OpenCV's exhaustive ``detectMultiScale`` scores
on a frame, for the efficiency comparison.
"""

from __future__ import annotations

import math
import threading
from contextlib import contextmanager
from typing import Iterator, Optional

import cv2
import numpy as np

from . import _hog_kernels as hk

WIN_W, WIN_H = 64, 128
CELL = 8            # HOG cell and block stride (px)
BLOCK_LEN = 36      # 2x2 cells x 9 bins
_WEIGHTS = hk.block_weights(4.0)     # the block's Gaussian (winSigma (16 + 16)/8) x cell split
_L2HYS = 0.2
# a 64x128 window's 7 x 15 blocks: (row of the descriptor's blocks (x outer, OpenCV's order),
# place on the window's block grid (y outer))
_WINDOW_SEL = np.array([(bu * 15 + bv, bv * 7 + bu) for bu in range(7) for bv in range(15)],
                       dtype=np.int64)
#: Fraction of the window the person occupies (Dalal & Triggs' 16-px context border).
PERSON_W, PERSON_H = 0.5, 0.75


def window_boxes(centres: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """HOG windows (N, 4) ``(x, y, w, h)`` centred on ``centres`` (N, 2) holding a person
    ``heights`` (N,) tall."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    wh = np.asarray(heights, dtype=np.float64).reshape(-1) / PERSON_H
    ww = wh * WIN_W / WIN_H
    return np.stack([c[:, 0] - ww / 2, c[:, 1] - wh / 2, ww, wh], axis=1)


def person_boxes(windows: np.ndarray) -> np.ndarray:
    """The person box inside each window (the window without its context border)."""
    w = np.asarray(windows, dtype=np.float64).reshape(-1, 4)
    pw, ph = w[:, 2] * PERSON_W, w[:, 3] * PERSON_H
    return np.stack([w[:, 0] + (w[:, 2] - pw) / 2, w[:, 1] + (w[:, 3] - ph) / 2, pw, ph], axis=1)


class HOGWindowClassifier:
    """Linear SVM on HOG descriptors of single windows.  ``weights`` (3780,) and ``bias``
    default to OpenCV's people detector; the score is the signed margin ``w·x + b``.

    ``mode`` chooses how descriptors are computed (module docstring):

    - ``"pyramid"`` (default): windows snapped to the 8-px grid of pyramid levels
      ``scale_step`` apart, duplicates scored once, and every 16×16 HOG block computed once per
      frame for all the windows that share it (:meth:`snap`, :meth:`descriptors`);
    - ``"window"``: each window cut, resampled to 64×128 and described on its own (no snapping).
    """

    MODES = ("pyramid", "window")

    def __init__(self, weights: np.ndarray | None = None, bias: float | None = None, *,
                 mode: str = "pyramid", scale_step: float = 1.1, threads: int = 1,
                 opencv_blocks: bool = False):
        if mode not in self.MODES:
            raise ValueError(f"classifier mode must be one of {', '.join(self.MODES)}, "
                             f"got {mode!r}")
        if not scale_step > 1.0:
            raise ValueError(f"classifier scale_step must be > 1, got {scale_step}")
        self.mode, self.scale_step = mode, float(scale_step)
        if int(threads) < 1:
            raise ValueError(f"classifier threads must be >= 1, got {threads}")
        self.threads = int(threads)
        #: blocks by OpenCV's ``HOGDescriptor.compute`` (one block at a time) instead of the
        #: shared-sums kernel (:mod:`._hog_kernels`; same features up to float rounding)
        self.opencv_blocks = bool(opencv_blocks)
        self._pool = None
        self.hog = cv2.HOGDescriptor()
        self.block_hog = _block_hog()
        if weights is None:
            det = np.asarray(cv2.HOGDescriptor_getDefaultPeopleDetector(),
                             dtype=np.float32).reshape(-1)
            weights, bias = det[:-1], float(det[-1])
        self.weights = np.asarray(weights, dtype=np.float32).reshape(-1)
        self.bias = float(bias or 0.0)
        size = self.hog.getDescriptorSize()
        if len(self.weights) != size:
            raise ValueError(f"classifier: {len(self.weights)} SVM weights for a HOG descriptor "
                             f"of {size}")

    # ------------------------------------------------------------------ snapping
    def _levels(self, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pyramid level ``k`` (scale ``step**k``: a window ``128/step**k`` tall becomes 128) and
        the window's top-left cell ``(cu, cv)`` on that level's 8-px grid."""
        w = np.asarray(windows, dtype=np.float64).reshape(-1, 4)
        k = np.round(np.log(WIN_H / np.maximum(w[:, 3], 1e-6)) / math.log(self.scale_step))
        k = k.astype(np.int64)
        s = self.scale_step ** k
        cu = np.round(w[:, 0] * s / CELL).astype(np.int64)
        cv = np.round(w[:, 1] * s / CELL).astype(np.int64)
        return k, cu, cv

    def snap(self, windows: np.ndarray, rng: Optional[np.random.Generator] = None
             ) -> np.ndarray:
        """The windows (N, 4) the classifier actually scores: in ``"pyramid"`` mode each window
        moved to the nearest pyramid level and 8-px grid node of that level (a shift of at most
        4 level px and a scale change of at most ``±sqrt(scale_step)``); unchanged in
        ``"window"`` mode.  With ``rng``, windows that land on the node of an earlier one are
        moved to a random neighbouring node (:meth:`_spread`)."""
        w = np.asarray(windows, dtype=np.float64).reshape(-1, 4)
        if self.mode == "window" or len(w) == 0:
            return w.copy()
        k, cu, cv = self._levels(w)
        if rng is not None:
            k, cu, cv = self._spread(k, cu, cv, rng)
        s = self.scale_step ** k
        return np.stack([cu * CELL / s, cv * CELL / s, WIN_W / s, WIN_H / s], axis=1)

    #: moves of a duplicate window: the 8 grid neighbours on its level, one level up or down
    _MOVES = np.array([(0, -1, -1), (0, 0, -1), (0, 1, -1), (0, -1, 0), (0, 1, 0), (0, -1, 1),
                       (0, 0, 1), (0, 1, 1), (-1, 0, 0), (1, 0, 0)], dtype=np.int64)

    def _spread(self, k, cu, cv, rng: np.random.Generator, rounds: int = 3):
        """Move windows that snapped onto an earlier window's node to a random neighbouring
        node (``rounds`` tries): copies of one resampled parent (same position, jittered scale)
        would otherwise collapse into one window, and the search would look at half as many
        places; a neighbour shares most of its HOG blocks, so it costs little."""
        k, cu, cv = k.copy(), cu.copy(), cv.copy()
        for _ in range(rounds):
            _, first = np.unique(_pack(k, cu, cv), return_index=True)
            dup = np.ones(len(k), dtype=bool)
            dup[first] = False
            if not dup.any():
                break
            mv = self._MOVES[rng.integers(0, len(self._MOVES), int(dup.sum()))]
            d = np.flatnonzero(dup)
            s0 = self.scale_step ** k[d]
            cx, cy = (cu[d] * CELL + WIN_W / 2) / s0, (cv[d] * CELL + WIN_H / 2) / s0
            k[d] += mv[:, 0]
            s1 = self.scale_step ** k[d]            # a level move keeps the window's centre
            cu[d] = np.round((cx * s1 - WIN_W / 2) / CELL).astype(np.int64) + mv[:, 1]
            cv[d] = np.round((cy * s1 - WIN_H / 2) / CELL).astype(np.int64) + mv[:, 2]
        return k, cu, cv

    # ------------------------------------------------------------------ descriptors
    def descriptors(self, grey: np.ndarray, windows: np.ndarray) -> np.ndarray:
        """(N, 3780) float32 HOG descriptors of ``windows`` (snapped first in ``"pyramid"``
        mode, see :meth:`snap`), in OpenCV's 64×128 descriptor layout."""
        d, inv = self._descriptors(grey, windows)
        return d if inv is None else d[inv]

    def _descriptors(self, grey: np.ndarray, windows: np.ndarray, exact: bool = False
                     ) -> tuple[np.ndarray, Optional[np.ndarray]]:
        """Descriptors of the distinct windows and the index of each window among them (None:
        one row per window).  ``exact``: per window, unsnapped, whatever the mode."""
        w = np.asarray(windows, dtype=np.float64).reshape(-1, 4)
        if self.mode == "window" or exact:
            return self._window_descriptors(grey, w), None
        return self._pyramid_descriptors(grey, w)

    def _pyramid_descriptors(self, grey: np.ndarray, w: np.ndarray,
                             drain: Optional["_Drain"] = None) -> tuple[np.ndarray, np.ndarray]:
        blocks, binv, inv = self._pyramid_blocks(grey, w, drain)
        return blocks[binv].reshape(len(binv), -1), inv

    def _pyramid_margins(self, grey: np.ndarray, w: np.ndarray,
                         drain: Optional["_Drain"] = None) -> tuple[np.ndarray, np.ndarray]:
        """SVM margins of the distinct snapped windows and each window's index among them.
        The linear SVM's margins come from the blocks directly (:func:`._hog_kernels.
        window_margins`: the same floats as :meth:`decision` of the gathered descriptors);
        another ``decision`` (the IKSVM's) gets the descriptors."""
        blocks, binv, inv = self._pyramid_blocks(grey, w, drain)
        if type(self).decision is not HOGWindowClassifier.decision:
            return self.decision(blocks[binv].reshape(len(binv), -1)), inv
        m = np.empty(len(binv), dtype=np.float32)
        if len(binv):
            hk.window_margins(blocks, binv, self.weights, m)
        return m.astype(np.float64) + self.bias, inv

    def _pyramid_blocks(self, grey: np.ndarray, w: np.ndarray,
                        drain: Optional["_Drain"] = None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The distinct HOG blocks (M, 36) of the snapped windows, each distinct window's 105
        blocks as rows of them (n, 105) in OpenCV's descriptor order, and each window's index
        among the distinct windows."""
        wx, wy = WIN_W // CELL, WIN_H // CELL            # window: 8 x 16 cells, 7 x 15 blocks
        nb = (wx - 1) * (wy - 1)
        if len(w) == 0:
            return (np.empty((0, BLOCK_LEN), np.float32), np.zeros((0, nb), np.int64),
                    np.zeros(0, np.int64))
        grey = np.ascontiguousarray(grey)
        k, cu, cv = self._levels(w)
        _, first, inv = np.unique(_pack(k, cu, cv), return_index=True,
                                  return_inverse=True)          # duplicates scored once
        k, cu, cv = k[first], cu[first], cv[first]
        inv = inv.reshape(-1)
        # each connected group of touching windows of one level is one region of the level
        # image, resampled once; each block of it that some window uses is computed once
        # (hk.region_layout: the regions, their cell rectangles, the distinct blocks grouped
        # by region and each window's blocks among them)
        _, x0, y0, x1, y1, rlev, binv, local, cuts = hk.region_layout(k, cu, cv, wx, wy)
        nreg = len(x0)
        gw, gh = x1 - x0 - 1, y1 - y0 - 1
        blocks = np.empty((len(local), BLOCK_LEN), dtype=np.float32)
        # each block's top-left px in its region (1 px more on each side of a region so that
        # its border gradients see their real neighbours)
        if self.opencv_blocks:
            bgw = np.repeat(gw, np.diff(cuts))
            locs = np.empty((len(local), 2), dtype=np.int32)
            locs[:, 0] = 1 + CELL * (local % bgw)
            locs[:, 1] = 1 + CELL * (local // bgw)
        else:   # the kernel's (row of blocks, place on the region's block grid)
            locs = np.stack([np.arange(len(local)), local], axis=1)
        # level px (a, b) samples frame px ((a + 0.5)/s - 0.5, ...)
        inv_s = self.scale_step ** -rlev.astype(np.float64)
        tx = ((x0 * CELL - 1) + 0.5) * inv_s - 0.5
        ty = ((y0 * CELL - 1) + 0.5) * inv_s - 0.5
        sizes = np.stack([(x1 - x0) * CELL + 2, (y1 - y0) * CELL + 2], axis=1).tolist()
        jobs = [(slice(cuts[r], cuts[r + 1]),
                 np.array([[inv_s[r], 0.0, tx[r]], [0.0, inv_s[r], ty[r]]]),
                 tuple(sizes[r]), locs[cuts[r]:cuts[r + 1]], int(gw[r]), int(gh[r]))
                for r in range(nreg)]
        if drain is None:
            self._run_regions(grey, jobs, blocks)
        else:   # shared with a worker that is already running (score_with_exact)
            drain.start(grey, jobs, blocks)
            drain.run(self._block_hog(0))
            drain.wait()
        return blocks, binv, inv

    def _run_regions(self, grey: np.ndarray, jobs: list, blocks: np.ndarray) -> None:
        """Resample each region and compute its blocks into ``blocks[sel]``; with ``threads``
        > 1 the regions are split into that many shares of about equal area, one per thread
        (OpenCV releases the GIL; each block is computed once, by one thread, so the result
        does not depend on the split)."""
        if self.threads <= 1 or len(jobs) < 2:
            _regions_blocks(grey, jobs, blocks, self._block_hog(0))
            return
        size = np.array([j[2][0] * j[2][1] for j in jobs], dtype=np.float64)
        mid = np.cumsum(size) - size / 2                 # each region's middle, by area so far
        share = np.minimum(mid * self.threads // size.sum(), self.threads - 1)
        parts = [[j for j, p in zip(jobs, share) if p == t] for t in range(self.threads)]
        pool, hogs, _ = self._workers()
        futures = [pool.submit(_regions_blocks, grey, part, blocks, self._block_hog(t))
                   for t, part in enumerate(parts) if t and part]
        _regions_blocks(grey, parts[0], blocks, self._block_hog(0))
        for f in futures:
            f.result()

    def _block_hog(self, thread: int) -> Optional[cv2.HOGDescriptor]:
        """The block HOG of worker ``thread`` (0: the calling thread), None for the kernel."""
        if not self.opencv_blocks:
            return None
        return self.block_hog if thread == 0 else self._workers()[1][thread]

    def _workers(self):
        """The worker threads (created on first use), one block HOG and one window HOG per
        thread (the calling thread's first)."""
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            extra = self.threads - 1
            self._pool = ThreadPoolExecutor(extra, thread_name_prefix="pfscope-hog")
            self._hogs = ([self.block_hog] + [_block_hog() for _ in range(extra)],
                          [self.hog] + [cv2.HOGDescriptor() for _ in range(extra)])
        return (self._pool, *self._hogs)

    def _window_descriptors(self, grey: np.ndarray, w: np.ndarray,
                            hog: Optional[cv2.HOGDescriptor] = None) -> np.ndarray:
        """Per-window descriptors; ``hog`` given: all of them on the calling thread with it."""
        n = len(w)
        out = np.empty((n, self.hog.getDescriptorSize()), dtype=np.float32)
        if n == 0:
            return out
        H, W = grey.shape[:2]
        # one replicated border for every window that sticks out of the frame
        out_by = max(0.0, float(-w[:, 0].min()), float(-w[:, 1].min()),
                     float((w[:, 0] + w[:, 2]).max() - W), float((w[:, 1] + w[:, 3]).max() - H))
        pad = int(math.ceil(out_by)) + 1
        padded = cv2.copyMakeBorder(grey, pad, pad, pad, pad, cv2.BORDER_REPLICATE) \
            if pad > 1 else grey
        off = pad if pad > 1 else 0
        x0 = np.floor(w[:, 0] + off).astype(np.int64)
        y0 = np.floor(w[:, 1] + off).astype(np.int64)
        x1 = np.maximum(x0 + 1, np.round(w[:, 0] + w[:, 2] + off).astype(np.int64))
        y1 = np.maximum(y0 + 1, np.round(w[:, 1] + w[:, 3] + off).astype(np.int64))
        x0, y0 = np.maximum(x0, 0), np.maximum(y0, 0)
        x1 = np.minimum(x1, padded.shape[1])
        y1 = np.minimum(y1, padded.shape[0])

        def part(idx: range, hog: cv2.HOGDescriptor) -> None:
            buf = np.empty((WIN_H, WIN_W), dtype=np.uint8)
            for i in idx:  # a few hundred windows: resize + HOG each (module docstring)
                cv2.resize(padded[y0[i]:y1[i], x0[i]:x1[i]], (WIN_W, WIN_H), dst=buf,
                           interpolation=cv2.INTER_LINEAR)
                if self.opencv_blocks:
                    out[i] = hog.compute(buf).reshape(-1)
                else:   # all 7 x 15 blocks of the window, in OpenCV's order
                    hk.region_blocks(buf, WIN_W // CELL - 1, WIN_H // CELL - 1, 0, 0,
                                     _WINDOW_SEL, _WEIGHTS, _L2HYS, out[i].reshape(-1, BLOCK_LEN))

        if hog is not None or self.threads <= 1 or n < 2 * self.threads:
            part(range(n), hog or self.hog)
            return out
        pool, _, hogs = self._workers()     # each window by one thread: same result
        cuts = np.linspace(0, n, self.threads + 1).astype(int)
        futures = [pool.submit(part, range(cuts[t], cuts[t + 1]), hogs[t])
                   for t in range(1, self.threads)]
        part(range(cuts[0], cuts[1]), hogs[0])
        for f in futures:
            f.result()
        return out

    def decision(self, d: np.ndarray) -> np.ndarray:
        """SVM margins (N,) float64 of descriptors ``d`` (N, 3780)."""
        if len(d) == 0:
            return np.zeros(0)
        # einsum, not ``@``: a BLAS gemv this small gains nothing from threads, and OpenBLAS's
        # spinning worker threads then slowed the OpenCV calls after it ~3x on a 2-core machine
        return np.einsum("ij,j->i", d, self.weights).astype(np.float64) + self.bias

    def score(self, grey: np.ndarray, windows: np.ndarray, *, exact: bool = False) -> np.ndarray:
        """SVM margins (N,) float64 of ``windows`` (N, 4) on the grey frame (the windows of
        :meth:`snap` in ``"pyramid"`` mode; ``exact``: the windows as given, each resampled to
        64×128 on its own, whatever the mode)."""
        w = np.asarray(windows, dtype=np.float64).reshape(-1, 4)
        if self.mode == "pyramid" and not exact:
            m, inv = self._pyramid_margins(grey, w)
            return m[inv]
        return self.decision(self._window_descriptors(grey, w))

    def score_with_exact(self, grey: np.ndarray, windows: np.ndarray,
                         exact_windows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(score(grey, windows), score(grey, exact_windows, exact=True))``, the same margins.
        With ``threads`` > 1 in ``"pyramid"`` mode a worker describes the exact windows while
        this thread prepares the pyramid's regions, then both threads take regions from one
        queue until none is left (each region by one thread: the result does not depend on
        who took which)."""
        w = np.asarray(windows, dtype=np.float64).reshape(-1, 4)
        ew = np.asarray(exact_windows, dtype=np.float64).reshape(-1, 4)
        if self.threads <= 1 or self.mode != "pyramid" or not len(w) or not len(ew):
            return self.score(grey, w), self.score(grey, ew, exact=True)
        pool, _, whogs = self._workers()
        drain = _Drain()

        def worker():
            try:
                vd = self._window_descriptors(grey, ew, hog=whogs[1])
                drain.ready.wait()
                drain.run(self._block_hog(1))
                return vd
            except BaseException as e:       # re-raised on the calling thread
                drain.error = e
                raise
            finally:
                drain.finished.set()

        head = pool.submit(worker)
        try:
            m, inv = self._pyramid_margins(grey, w, drain)
        finally:
            drain.ready.set()                   # never leave the worker waiting
        vd = head.result()
        return m[inv], self.decision(vd)

    def describe(self) -> str:
        return "opencv-default-people-svm"


def load_classifier(path: str = "", *, mode: str = "pyramid", scale_step: float = 1.1,
                    threads: int = 1):
    """The DLPF classifier: OpenCV's people SVM (``path`` empty) or a model file written by
    ``pfscope train-classifier`` (:mod:`.iksvm`).  A missing, unreadable or mismatched file
    raises ``ValueError`` with one line naming it."""
    if not path:
        return HOGWindowClassifier(mode=mode, scale_step=scale_step, threads=threads)
    from .iksvm import IKSVMClassifier
    clf = IKSVMClassifier.load(path, mode=mode, scale_step=scale_step)
    clf.threads = int(threads)
    return clf


@contextmanager
def opencv_threads(n: int) -> Iterator[None]:
    """OpenCV's own worker threads set to ``n`` (``cv2.setNumThreads``: process-wide) inside the
    block, restored after it.  For code that already splits its work over its own threads:
    OpenCV's pool would split each call again over the same cores.  OpenCV's results do not
    depend on its thread count (each output row or point is computed the same way)."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def _pack(k: np.ndarray, cu: np.ndarray, cv: np.ndarray) -> np.ndarray:
    """One int64 key per (level, cell column, cell row) (each well inside ±2^20)."""
    return ((k + (1 << 20)) << 42) | ((cu + (1 << 20)) << 21) | (cv + (1 << 20))


class _Drain:
    """The pyramid's regions handed out one at a time to the threads that compute them."""

    def __init__(self):
        self.ready = threading.Event()      # the regions are known
        self.finished = threading.Event()   # the worker is done
        self.lock = threading.Lock()
        self.jobs: list = []
        self.next = 0
        self.error: Optional[BaseException] = None

    def start(self, grey: np.ndarray, jobs: list, blocks: np.ndarray) -> None:
        # largest first, so that the last region taken is a small one
        self.grey, self.blocks = grey, blocks
        self.jobs = sorted(jobs, key=lambda j: -j[2][0] * j[2][1])
        self.ready.set()

    def run(self, hog: cv2.HOGDescriptor) -> None:
        while True:
            with self.lock:
                i = self.next
                self.next += 1
            if i >= len(self.jobs):
                return
            _regions_blocks(self.grey, [self.jobs[i]], self.blocks, hog)

    def wait(self) -> None:
        """Until the worker has finished its last region (its error re-raised here)."""
        self.finished.wait()
        if self.error is not None:
            raise RuntimeError(f"classifier worker failed: {self.error}") from self.error


def _block_hog() -> cv2.HOGDescriptor:
    """One 16x16 block as a "window": same cells, bins, Gaussian block weighting (winSigma =
    (16+16)/8), L2-Hys and gamma correction as the 64x128 descriptor's blocks."""
    return cv2.HOGDescriptor((16, 16), (16, 16), (8, 8), (8, 8), 9, 1, -1.0,
                             cv2.HOGDescriptor_L2Hys, 0.2, True)


def _regions_blocks(grey: np.ndarray, jobs: list, blocks: np.ndarray,
                    hog: Optional[cv2.HOGDescriptor]) -> None:
    """For each job ``(sel, M, size, locs, gw, gh)``: the level region ``warpAffine(grey, M,
    size)`` (inverse map, bilinear, replicated border) and its blocks into ``blocks[sel]``:
    with ``hog`` OpenCV's blocks at px ``locs``; without, the kernel's
    (:func:`._hog_kernels.warp_region`: warpAffine's bytes by numba, then
    :func:`._hog_kernels.region_blocks`; ``locs`` = (row of ``blocks``, place on the region's
    ``gw`` x ``gh`` block grid))."""
    for sel, M, size, locs, gw, gh in jobs:
        if hog is None:     # numba resamples the region (OpenCV's bytes, no OpenCV call)
            region = np.empty((size[1], size[0]), dtype=np.uint8)
            hk.warp_region(grey, M[0, 0], M[0, 2], M[1, 2], region)
            hk.region_blocks(region, gw, gh, 1, 1, locs, _WEIGHTS, _L2HYS, blocks)
            continue
        region = cv2.warpAffine(grey, M, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_REPLICATE)
        blocks[sel] = hog.compute(region, (CELL, CELL), (0, 0), locs).reshape(-1, BLOCK_LEN)


def _regions(k: np.ndarray, cu: np.ndarray, cv: np.ndarray, wx: int, wy: int
             ) -> tuple[int, np.ndarray]:
    """Connected groups of windows (``wx`` x ``wy`` cells at ``(cu, cv)`` on level ``k``): two
    windows of one level are in a group when their cell rectangles overlap or share an edge
    (the 4-connected components of the union of their cells).  Returns (groups, label per
    window, 0..groups-1 in order of each group's first window); from
    :func:`._hog_kernels.region_layout` (a pairwise test over the few hundred distinct windows
    of a frame, union-find)."""
    if len(k) == 0:
        return 0, np.zeros(0, dtype=np.int64)
    reg, x0 = hk.region_layout(*(np.asarray(a, dtype=np.int64) for a in (k, cu, cv)),
                               wx, wy)[:2]
    return len(x0), reg


def sliding_window_count(width: int, height: int, *, win_stride=(8, 8), padding=(8, 8),
                         scale: float = 1.05, upscale: float = 1.0,
                         resize_to: int | None = None, nlevels: int = 64) -> int:
    """Windows OpenCV's ``HOGDescriptor.detectMultiScale`` scores on a ``width``×``height`` frame
    with these settings (the pyramid and the window grid of ``HOGDescriptor::detect``), after
    :class:`~pfscope.trackers.detect.hog.HOGPeopleDetector`'s ``upscale``/``resize_to``."""
    s = upscale
    if resize_to is not None and width * s > resize_to:
        s = resize_to / width
    W, H = int(round(width * s)), int(round(height * s))
    total, level_scale = 0, 1.0
    for _ in range(nlevels):
        sw, sh = int(round(W / level_scale)), int(round(H / level_scale))
        if sw < WIN_W or sh < WIN_H:
            break
        pw, ph = sw + 2 * padding[0], sh + 2 * padding[1]
        total += ((pw - WIN_W) // win_stride[0] + 1) * ((ph - WIN_H) // win_stride[1] + 1)
        level_scale *= scale
    return total


__all__ = ["HOGWindowClassifier", "load_classifier", "opencv_threads", "window_boxes", "person_boxes", "sliding_window_count",
           "WIN_W", "WIN_H"]
