"""Colour appearance of a box, for the association's edge gain (not in maggio2007).

A box's feature is two colour histograms -- the upper and the lower half of its central part
(``x`` within ``±inner_w/2 · w`` of the centre, ``y`` within ``±inner_h/2 · h``), where a
person's torso and legs are and the background least -- over RGB quantised to ``levels³`` bins,
each half normalised to sum 1.  Two features are compared with the Bhattacharyya coefficient
``ρ = Σ √(p q)`` averaged over the halves (1: same colours, 0: disjoint).

Cost: one small crop per box (a loop over the boxes, vectorised over the pixels of each);
nothing is done per pixel of the whole frame.
"""

from __future__ import annotations

import numpy as np

#: Quantisation levels per colour channel (levels³ bins per half).
LEVELS = 4
INNER_W = 0.6
INNER_H = 0.8
N_HALVES = 2
DIM = N_HALVES * LEVELS ** 3


def box_features(image: np.ndarray, centres: np.ndarray, levels: int = LEVELS) -> np.ndarray:
    """(N, 2·levels³) features of the boxes ``centres (N, ≥4)`` = ``(cx, cy, w, h)`` (or the
    (N, 6) states, whose columns 0, 1, 4, 5 are taken) in ``image (H, W, 3) uint8``.  A box
    with no pixel inside the image gets NaN (unknown appearance)."""
    c = np.asarray(centres, dtype=np.float64)
    if c.ndim == 2 and c.shape[1] == 6:
        c = c[:, [0, 1, 4, 5]]
    n_bins = levels ** 3
    out = np.full((len(c), N_HALVES * n_bins), np.nan)
    if image is None or image.ndim != 3 or not len(c):
        return out
    H, W = image.shape[:2]
    shift = 8 - int(np.log2(levels))
    x0 = np.clip(np.floor(c[:, 0] - INNER_W / 2 * c[:, 2]), 0, W).astype(np.int64)
    x1 = np.clip(np.ceil(c[:, 0] + INNER_W / 2 * c[:, 2]), 0, W).astype(np.int64)
    y0 = np.clip(np.floor(c[:, 1] - INNER_H / 2 * c[:, 3]), 0, H).astype(np.int64)
    ym = np.clip(np.round(c[:, 1]), 0, H).astype(np.int64)
    y1 = np.clip(np.ceil(c[:, 1] + INNER_H / 2 * c[:, 3]), 0, H).astype(np.int64)
    for n in range(len(c)):  # one crop per box
        for h, (a, b) in enumerate(((y0[n], ym[n]), (ym[n], y1[n]))):
            if b <= a or x1[n] <= x0[n]:
                continue
            q = image[a:b, x0[n]:x1[n]].reshape(-1, 3) >> shift
            idx = (q[:, 0].astype(np.int64) * levels + q[:, 1]) * levels + q[:, 2]
            hist = np.bincount(idx, minlength=n_bins).astype(np.float64)
            out[n, h * n_bins:(h + 1) * n_bins] = hist / hist.sum()
    return out


def _root_halves(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sqrt of features ``x (n, D)`` per half, ``(n, halves, D/halves)`` with NaN as 0, and
    which halves are known ``(n, halves)``."""
    x = np.asarray(x, dtype=np.float64)
    s = np.sqrt(x).reshape(len(x), N_HALVES, x.shape[1] // N_HALVES)
    return np.nan_to_num(s), np.isfinite(s[:, :, 0])


def _mean_over_halves(rho: np.ndarray, ok: np.ndarray) -> np.ndarray:
    n = ok.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sum(np.where(ok, rho, 0.0), axis=-1) / n, np.nan)


def similarity(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(A, B) Bhattacharyya coefficients between features ``a (A, D)`` and ``b (B, D)``,
    averaged over the halves both have; NaN where either side has no half."""
    sa, oka = _root_halves(a)
    sb, okb = _root_halves(b)
    return _mean_over_halves(np.einsum("ahd,bhd->abh", sa, sb), oka[:, None, :] & okb[None, :, :])


def similarity_pairs(a: np.ndarray, b: np.ndarray, rows: np.ndarray,
                     cols: np.ndarray) -> np.ndarray:
    """(P,) :func:`similarity` of the pairs ``(a[rows], b[cols])`` only (no (A, B) arrays)."""
    sa, oka = _root_halves(np.asarray(a, dtype=np.float64)[rows])
    sb, okb = _root_halves(np.asarray(b, dtype=np.float64)[cols])
    return _mean_over_halves(np.einsum("phd,phd->ph", sa, sb), oka & okb)


class AppearanceModel:
    """How much a colour similarity says about identity, learnt online from the association.

    The distance ``d = 1 − ρ`` is modelled as exponential, of mean ``μ_same`` between the
    consecutive vertices of one track (the edges of gap 1 the matching chose) and ``μ_diff``
    between two estimates of one frame (distinct targets by construction).  Each mean starts at
    a weak prior (``PRIOR_*``, worth ``PRIOR_N`` samples) and is a running mean of at most
    ``MEMORY`` samples.  The evidence of a pair is the log-likelihood ratio
    ``log p(d | same) / p(d | different) = log(μ_diff/μ_same) − d (1/μ_same − 1/μ_diff)``,
    clipped to ``[−LLR_CLIP, LLR_CLIP]``; 0 when either side's colours are unknown or the
    two means do not separate (μ_diff ≤ μ_same)."""

    PRIOR_SAME = 0.1
    PRIOR_DIFF = 0.2
    PRIOR_N = 20.0
    MEMORY = 2000.0
    LLR_CLIP = 5.0
    MAX_PAIRS = 400  # per frame, for μ_diff
    MODEL_N0 = 2.0   # llr shrinkage: a track's model of n crops counts n / (n + MODEL_N0)

    def __init__(self):
        self.mu_same, self.n_same = self.PRIOR_SAME, self.PRIOR_N
        self.mu_diff, self.n_diff = self.PRIOR_DIFF, self.PRIOR_N

    @staticmethod
    def _update(mu: float, n: float, d: np.ndarray, memory: float) -> tuple[float, float]:
        d = d[np.isfinite(d)]
        if not len(d):
            return mu, n
        n_new = min(n + len(d), memory)
        rate = len(d) / (n + len(d))
        return (1.0 - rate) * mu + rate * float(np.mean(d)), n_new

    def observe_same(self, rho: np.ndarray) -> None:
        """Similarities of pairs known to be one target."""
        d = np.clip(1.0 - np.asarray(rho, dtype=np.float64).ravel(), 1e-3, 1.0)
        self.mu_same, self.n_same = self._update(self.mu_same, self.n_same, d, self.MEMORY)

    def observe_different(self, feats: np.ndarray) -> None:
        """The features of one frame's estimates: every pair is two distinct targets (the
        first ``MAX_PAIRS`` pairs in input order)."""
        if len(feats) < 2:
            return
        iu = np.triu_indices(len(feats), 1)
        rho = similarity(feats, feats)[iu][:self.MAX_PAIRS]
        d = np.clip(1.0 - rho, 1e-3, 1.0)
        self.mu_diff, self.n_diff = self._update(self.mu_diff, self.n_diff, d, self.MEMORY)

    def llr(self, rho: np.ndarray, n=None) -> np.ndarray:
        """Log-likelihood ratio same/different of similarities ``rho`` (any shape); NaN → 0.
        ``n`` (broadcast to ``rho``): colour observations behind the track's model; the ratio
        is shrunk by ``n / (n + MODEL_N0)``, so a model of one crop (a track just born, often
        a duplicate estimate of a target already tracked) does not outvote an established one
        for matching its own pixels."""
        rho = np.asarray(rho, dtype=np.float64)
        if not self.mu_diff > self.mu_same:
            return np.zeros(rho.shape)
        d = np.clip(1.0 - rho, 1e-3, 1.0)
        out = (np.log(self.mu_diff / self.mu_same)
               - d * (1.0 / self.mu_same - 1.0 / self.mu_diff))
        out = np.where(np.isfinite(out), np.clip(out, -self.LLR_CLIP, self.LLR_CLIP), 0.0)
        if n is not None:
            n = np.asarray(n, dtype=np.float64)
            out = out * (n / (n + self.MODEL_N0))
        return out
