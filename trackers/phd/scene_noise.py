"""The detector's box jitter, measured online, and the likelihood width it calls for (not in
maggio2007; off unless ``noise.learn_width`` > 0).

maggio2007 §4 fixes the observation noise at ``σ_{w,h} = 0.15 (w, h)``, ``σ_y = σ_{w,h} / 2``
(:func:`.filter.obs_std`).  That suits a steady detector: on PETS09 the size of a person's
detection changes by ~5 % from one frame to the next, a third of the model's width.  Another
detector on smaller people can jitter three times as much -- on KITTI-13 (a Faster R-CNN,
people ~30 px wide) the frame-to-frame size change is 11–15 % -- and then every detection falls
outside the prediction of the last one: each frame's newborn cloud misses the next detection,
the PHD mass never grows past a few percent and no track is ever confirmed (MOTA/IDF1 0/0),
while a likelihood twice as wide builds tracks there.  A fixed wider width doubles the false
positives on PETS09 instead, so the width is learnt from the scene:

- **Measure** (:class:`DetectorJitter`): detections of consecutive frames are paired when they
  are each other's best overlap with IoU >= ``pair_iou`` (a person seen twice; the candidate
  pairs come from a grid, :func:`.gating.gate_pairs`, so the cost is linear in the
  detections); the jitter of each size component is ``√π / 2 · mean |Δ log w|`` (the std of a
  Gaussian log-size noise, whose difference over two frames has std ``√2 σ`` and mean
  absolute value ``√(2/π) · √2 σ``), averaged exponentially over ``memory`` frames and started
  from a prior at the model's own width (``prior_pairs`` pseudo-pairs of jitter
  ``sigma_obs / learn_width``).  The mean absolute value rather than a median: a detector whose
  boxes come from a pyramid of fixed scales (ACF on PETS09) repeats the size exactly in most
  frames, a median of 0.
- **Use** (:func:`learnt_width`): ``sigma_obs = max(base, learn_width · jitter)`` with jitter
  the mean of the w and h estimates -- never narrower than the configured width, wider where
  the detector is unsteady.  The likelihood must cover the jitter of the new detection and the
  spread of the predicted cloud around the last one, hence a factor of a few: the paper's 0.15
  is about 3 × the PETS09 detector's jitter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..params import param
from .filter import _check
from .gating import gate_pairs

#: √π / 2: std of a Gaussian noise from the mean absolute difference of two draws.
_MAD_TO_STD = math.sqrt(math.pi) / 2.0


@dataclass(frozen=True)
class NoiseParams:
    """The likelihood width learnt from the detector's jitter (:mod:`.scene_noise`)."""

    learn_width: float = param(0.0, "0: the likelihood width filter.likelihood.sigma_obs as "
                                    "given; c > 0: sigma_obs = max(given, c × the detector's "
                                    "box-size jitter measured online between consecutive "
                                    "frames; not in paper; with rate.learn_motion on as well, the "
                                    "acceleration is read off the jitter while the width is "
                                    "still learnt: set rate.learn_motion=false with it)")
    pair_iou: float = param(0.3, "learn_width: detections of consecutive frames that are each "
                                 "other's best overlap with at least this IoU are one person "
                                 "seen twice")
    prior_pairs: float = param(50.0, "learn_width: pseudo-pairs of the prior (jitter "
                                     "sigma_obs / learn_width: the given width)")

    def __post_init__(self):
        _check(self, "learn_width", self.learn_width >= 0, ">= 0")
        _check(self, "pair_iou", 0.0 < self.pair_iou <= 1.0, "in (0, 1]")
        _check(self, "prior_pairs", self.prior_pairs > 0, "> 0")


def _pair_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of centre boxes ``(cx, cy, w, h)`` taken row by row (P, 4) x (P, 4) -> (P,)."""
    lo = np.maximum(a[:, :2] - a[:, 2:] / 2, b[:, :2] - b[:, 2:] / 2)
    hi = np.minimum(a[:, :2] + a[:, 2:] / 2, b[:, :2] + b[:, 2:] / 2)
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=1)
    union = np.prod(a[:, 2:], axis=1) + np.prod(b[:, 2:], axis=1) - inter
    return inter / np.maximum(union, 1e-12)


def consecutive_pairs(prev: np.ndarray, cur: np.ndarray, min_iou: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(i_prev, i_cur)`` of the detections ``prev`` (N, 4) and ``cur`` (M, 4)
    ``(cx, cy, w, h)`` that are each other's best overlap, with IoU >= ``min_iou``.  Only pairs
    whose centres are within two box sizes are looked at (an IoU >= 0.3 needs much less)."""
    empty = (np.zeros(0, np.intp), np.zeros(0, np.intp))
    if not len(prev) or not len(cur):
        return empty
    rows, cols = [], []
    # σ = the box size: a pair with IoU > 0 has |Δ centre| < the sum of half sizes
    for ch in gate_pairs(prev, cur, 4.0 * 4, std_z=np.concatenate([cur[:, 2:], cur[:, 2:]], 1)):
        rows.append(ch.rows)
        cols.append(ch.cols)
    if not rows:
        return empty
    r, c = np.concatenate(rows), np.concatenate(cols)
    ov = _pair_iou(prev[r], cur[c])
    keep = ov >= min_iou
    r, c, ov = r[keep], c[keep], ov[keep]
    if not len(r):
        return empty
    # mutual best: the best overlap of each row and of each column (ties: the first pair)
    order = np.lexsort((np.arange(len(ov)), -ov))
    _, first_r = np.unique(r[order], return_index=True)
    _, first_c = np.unique(c[order], return_index=True)
    pick = np.intersect1d(order[first_r], order[first_c])
    return r[pick], c[pick]


class DetectorJitter:
    """Online estimate of the detector's frame-to-frame size jitter (module docstring):
    :meth:`see` each frame's detections, :attr:`jitter` ``(σ_w, σ_h)`` relative std."""

    def __init__(self, params: NoiseParams, base_width: float):
        self.params = params
        prior = base_width / params.learn_width if params.learn_width > 0 else base_width
        n0 = params.prior_pairs
        self.n = n0
        self.abs_sum = np.full(2, n0 * prior / _MAD_TO_STD)
        self._prev: Optional[np.ndarray] = None
        self._prev_frame: Optional[int] = None

    @property
    def jitter(self) -> np.ndarray:
        return _MAD_TO_STD * self.abs_sum / self.n

    def see(self, frame: int, Z: np.ndarray, memory: float) -> None:
        """The detections ``Z`` (N, 4) ``(cx, cy, w, h)`` of ``frame``; pairs only with the
        frame just before (a gap breaks the chain); averages over about ``memory`` frames."""
        Z = np.asarray(Z, dtype=np.float64).reshape(-1, 4)
        if self._prev is not None and self._prev_frame == frame - 1:
            i, j = consecutive_pairs(self._prev, Z, self.params.pair_iou)
            d = 1.0 - 1.0 / max(memory, 1.0)
            dl = np.abs(np.log(Z[j, 2:4]) - np.log(self._prev[i, 2:4]))
            self.n = d * self.n + len(i)
            self.abs_sum = d * self.abs_sum + dl.sum(axis=0)
        self._prev, self._prev_frame = Z, frame


def learnt_width(base: float, jitter: np.ndarray, c: float) -> float:
    """``max(base, c · mean(jitter))`` (module docstring, "Use")."""
    return max(base, c * float(np.mean(jitter)))
