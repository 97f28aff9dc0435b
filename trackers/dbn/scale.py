"""The person size of a scene, learnt from the blobs the DBN accepts, and the split of blobs that
hold more than one person (DBN-PHD).

Why: background subtraction merges people who walk close together into one blob (PETS09-S3MF1:
about a third of the blobs that cover a person cover two to four; a 480×360 copy of PETS09-S2L1:
one in six).  Such a blob is not one person's shape, so the DBN turns it down (S3MF1: 80 % of
them get P(person) < 0.5) and, without a split, the people in it vanish from the filter (their
births are refused and their blob is explained as clutter): DBN-PHD's OSPA error was mostly
cardinality.  feng2015 gives no rule for merged blobs (its Fig. 2 shows one, "which may cause
miss detection"); the paper weights *particles* by the DBN, so a blob's part that looks like a
person must be able to hold a target.  Here the DBN looks inside the blob.

Person size (:class:`PersonScale`): every DBN-accepted blob whose width is not more than
``max_aspect`` of its height adds ``(foot y, height, width / height)``; the expected height at
a foot row is a line ``h = a + b·y`` (a camera looking down on a ground plane: people further
away stand higher in the image and look smaller) fitted by least squares, then refitted twice
without the points more than 2.5 robust standard deviations (1.4826 MAD) off; the width is the
median aspect ratio times the height.  Nothing about the camera or the resolution is assumed:
before ``min_samples`` blobs were accepted, no blob is split.

Split (:func:`split_candidates`, used by the tracker): a blob wider than ``split_at`` expected
widths or taller than ``split_at`` expected heights (at its foot row) is searched with windows of
the expected size (at each window's own foot row), steps of a third of the width and a quarter
of the height, each window with at least ``min_fill`` foreground.  The DBN scores every window
(the tracker) and :func:`select_windows` keeps, greedily by score, those with P(person) >=
``accept`` that overlap an already kept one by less than ``overlap`` (intersection over the
smaller box).  When it keeps at least one window, the windows replace the blob as measurements;
else the blob stays as it was (scored as a whole).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..params import param


@dataclass(frozen=True)
class SplitParams:
    """Scene-learnt person size and the split of multi-person blobs (:mod:`.scale`)."""

    enabled: bool = param(True, "search blobs bigger than one person (learnt from the blobs "
                                "the DBN accepts) with person-sized windows the DBN scores "
                                "(DBN-PHD only; no effect without the DBN)")
    min_samples: int = param(20, "accepted blobs needed before the person size is trusted")
    keep: int = param(400, "most recent accepted blobs the person size is fitted on")
    max_aspect: float = param(0.8, "accepted blobs wider than this times their height (two "
                                   "people side by side) do not teach the person size")
    split_at: float = param(1.5, "a blob wider or taller than this many expected persons is "
                                 "searched with person-sized windows")
    min_fill: float = param(0.3, "a window needs at least this foreground fraction")
    overlap: float = param(0.5, "a window overlapping a kept one by more than this fraction of "
                                "the smaller box is dropped (greedy, best DBN score first)")
    max_windows: int = param(64, "windows searched per blob at most (coarser steps beyond)")

    def __post_init__(self):
        def check(name, ok, rule):
            if not ok:
                raise ValueError(f"SplitParams.{name} must be {rule}, "
                                 f"got {getattr(self, name)!r}")
        check("min_samples", self.min_samples >= 3, ">= 3")
        check("keep", self.keep >= self.min_samples, ">= min_samples")
        check("max_aspect", self.max_aspect > 0, "> 0")
        check("split_at", self.split_at > 1, "> 1")
        check("min_fill", 0 <= self.min_fill <= 1, "in [0, 1]")
        check("overlap", 0 < self.overlap <= 1, "in (0, 1]")
        check("max_windows", self.max_windows >= 1, ">= 1")


class PersonScale:
    """Expected person height and width at a foot row, learnt online (module docstring)."""

    def __init__(self, params: SplitParams = SplitParams()):
        self.params = params
        self._foot = np.zeros(0)
        self._h = np.zeros(0)
        self._aspect = np.zeros(0)
        self._fit: Optional[tuple[float, float, float]] = None   # (a, b, aspect)

    @property
    def samples(self) -> int:
        return len(self._h)

    @property
    def ready(self) -> bool:
        return self.samples >= self.params.min_samples

    def add(self, boxes_xywh: np.ndarray) -> None:
        """Learn from accepted blobs ``(x, y, w, h)`` (the ones wider than ``max_aspect`` of
        their height are skipped)."""
        b = np.asarray(boxes_xywh, dtype=np.float64).reshape(-1, 4)
        b = b[(b[:, 3] > 0) & (b[:, 2] <= self.params.max_aspect * b[:, 3])]
        if not len(b):
            return
        k = self.params.keep
        self._foot = np.concatenate([self._foot, b[:, 1] + b[:, 3]])[-k:]
        self._h = np.concatenate([self._h, b[:, 3]])[-k:]
        self._aspect = np.concatenate([self._aspect, b[:, 2] / b[:, 3]])[-k:]
        self._fit = None

    def _line(self) -> tuple[float, float, float]:
        if self._fit is None:
            y, h = self._foot, self._h
            a, b = _robust_line(y, h)
            self._fit = (a, b, _median(self._aspect))
        return self._fit

    def size_at(self, foot_y) -> tuple[np.ndarray, np.ndarray]:
        """``(w, h)`` expected at foot rows ``foot_y`` (arrays; at least 4 px each)."""
        a, b, aspect = self._line()
        h = np.maximum(a + b * np.asarray(foot_y, dtype=np.float64), 4.0)
        # never beyond the heights seen (a line fitted on a narrow band of rows extrapolates)
        h = np.minimum(np.maximum(h, 0.5 * self._h.min()), 2.0 * self._h.max())
        return np.maximum(aspect * h, 4.0), h


def _median(x: np.ndarray) -> float:
    """``np.median`` of a 1-D float array without NaN: the same float (the middle element, or
    the mean of the middle two, of the same partition) without its generic machinery, which
    cost most of :func:`_robust_line` (run every frame)."""
    n = len(x)
    k = n // 2
    if n % 2:
        return float(np.partition(x, k)[k])
    part = np.partition(x, (k - 1, k))
    return float((part[k - 1] + part[k]) / 2)


def _robust_line(y: np.ndarray, h: np.ndarray) -> tuple[float, float]:
    """``h ≈ a + b·y``: least squares, then twice more without points off by > 2.5 robust σ.
    A flat line (the median) when the rows span too little to fit a slope."""
    def fit(m):
        yy, hh = y[m], h[m]
        my, mh = yy.mean(), hh.mean()
        dy = yy - my
        syy = float(dy @ dy)
        if len(yy) < 3 or syy < 1e-9 * max(1.0, my * my) * len(yy):
            return _median(hh), 0.0
        b = float(dy @ (hh - mh)) / syy                    # closed-form least squares
        return float(mh - b * my), b

    m = np.ones(len(y), bool)
    a, b = fit(m)
    for _ in range(2):
        r = h - (a + b * y)
        rm = r[m]
        med = _median(rm)
        s = 1.4826 * _median(np.abs(rm - med))
        if not s > 0:
            break
        keep = np.abs(r - med) <= 2.5 * s
        if keep.sum() < 3:
            break
        m = keep
        a, b = fit(m)
    return a, b


def needs_split(boxes_xywh: np.ndarray, scale: PersonScale, params: SplitParams) -> np.ndarray:
    """(N,) bool: blobs wider or taller than ``split_at`` expected persons at their foot row."""
    b = np.asarray(boxes_xywh, dtype=np.float64).reshape(-1, 4)
    if not len(b) or not scale.ready:
        return np.zeros(len(b), bool)
    w, h = scale.size_at(b[:, 1] + b[:, 3])
    return (b[:, 2] > params.split_at * w) | (b[:, 3] > params.split_at * h)


def split_candidates(blob: np.ndarray, scale: PersonScale, params: SplitParams,
                     fg_integral: np.ndarray, mask_scale: float) -> np.ndarray:
    """(K, 4) person-sized windows ``(x, y, w, h)`` inside ``blob`` (full-resolution px) with at
    least ``min_fill`` foreground; ``fg_integral`` is the zero-padded integral image of the
    foreground mask at ``mask_scale``."""
    x0, y0, bw, bh = (float(v) for v in blob)
    _, h_top = scale.size_at(y0 + bh)                  # the largest person (lowest foot row)
    hmax = float(min(h_top, bh))
    # foot rows: from the lowest a window of the expected height fits down to the blob's bottom
    n_rows = max(1, int(np.ceil(max(bh - 0.5 * hmax, 0.0) / (0.25 * hmax))) + 1)
    foot = np.linspace(y0 + min(hmax, bh), y0 + bh, n_rows)
    w_f, h_f = scale.size_at(foot)
    h_f = np.minimum(h_f, bh)
    w_f = np.minimum(w_f, bw)
    # per foot row, n_cols windows from x0 to the blob's right edge: every row's
    # np.linspace(x0, x0 + bw - w, n_cols) at once, in linspace's own float operations
    n_cols = np.maximum(np.ceil(np.maximum(bw - w_f, 0.0) / (w_f / 3.0)).astype(np.int64) + 1,
                        1)
    stop = x0 + bw - w_f
    div = (n_cols - 1).astype(np.float64)
    one = div == 0                                  # linspace(.., 1): start + 0 * delta
    delta = stop - x0
    step = delta / np.where(one, 1.0, div)
    row = np.repeat(np.arange(len(foot)), n_cols)
    j = (np.arange(len(row)) - np.repeat(np.cumsum(n_cols) - n_cols, n_cols)).astype(np.float64)
    xs = np.where(one[row], j * delta[row],
                  np.where(step[row] == 0, j / np.where(one, 1.0, div)[row] * delta[row],
                           j * step[row])) + x0
    last = np.cumsum(n_cols) - 1
    xs[last[~one]] = stop[~one]
    cand = np.stack([xs, (foot - h_f)[row], w_f[row], h_f[row]], axis=1)
    if len(cand) > params.max_windows:               # coarser: an even subset
        cand = cand[np.linspace(0, len(cand) - 1, params.max_windows).round().astype(int)]
    fill = box_fill(fg_integral, cand, mask_scale)
    return cand[fill >= params.min_fill]


def box_fill(fg_integral: np.ndarray, boxes_xywh: np.ndarray, mask_scale: float) -> np.ndarray:
    """(N,) foreground fraction of boxes (full-resolution px) from the mask's integral image."""
    b = np.asarray(boxes_xywh, dtype=np.float64).reshape(-1, 4) * mask_scale
    H, W = fg_integral.shape[0] - 1, fg_integral.shape[1] - 1
    # (np.minimum/np.maximum: np.clip's ints without its per-call overhead)
    lo = np.floor(b[:, :2]).astype(np.int64)
    hi = np.ceil(b[:, :2] + b[:, 2:]).astype(np.int64)
    lim = np.array([W, H])
    xa, ya = np.minimum(np.maximum(lo, 0), lim).T
    xb, yb = np.minimum(np.maximum(hi, 0), lim).T
    s = (fg_integral[yb, xb] - fg_integral[ya, xb] - fg_integral[yb, xa]
         + fg_integral[ya, xa]).astype(np.float64)
    area = np.maximum((xb - xa) * (yb - ya), 1)
    return s / area


def select_windows(windows: np.ndarray, prob: np.ndarray, accept: float,
                   overlap: float) -> np.ndarray:
    """Indices of the windows kept: P >= ``accept``, greedily best first, each overlapping
    every kept one by at most ``overlap`` (intersection over the smaller box)."""
    w = np.asarray(windows, dtype=np.float64).reshape(-1, 4)
    prob = np.asarray(prob)
    order = np.argsort(-prob, kind="stable")
    # a few dozen windows: Python floats (the same float64 arithmetic as numpy's) cost less
    # than a numpy call per pair
    box = w.tolist()
    kept: list[int] = []
    for i in order[prob[order] >= accept].tolist():
        xi, yi, wi, hi = box[i]
        for k in kept:
            xk, yk, wk, hk = box[k]
            ix = max(0.0, min(xi + wi, xk + wk) - max(xi, xk))
            iy = max(0.0, min(yi + hi, yk + hk) - max(yi, yk))
            if ix * iy > overlap * max(min(wi * hi, wk * hk), 1e-9):
                break
        else:
            kept.append(int(i))
    return np.asarray(kept, dtype=np.int64)


__all__ = ["SplitParams", "PersonScale", "needs_split", "split_candidates", "select_windows",
           "box_fill"]
