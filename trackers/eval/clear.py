"""CLEAR-MOT matching (MOTA, MOTP, ID switches, MT/PT/ML, Frag) and VACE detection matching
(MODA, MODP).

maggio2007 §4 (Table 1) scores its trackers with the four VACE scores MODA, MODP, MOTA and MOTP
(Kasturi et al., "Framework for performance evaluation of face, text and vehicle detection and
tracking in video", PAMI 2009).  We compute:

- **CLEAR-MOT** (Bernardin & Stiefelhagen 2008) exactly as TrackEval's ``CLEAR`` metric does it:
  in every frame a true box and a track box may match only if their overlap (IoU) is at least
  the threshold (0.5, the MOT15 rule); among those, the Hungarian assignment first keeps the
  pairs matched in the previous frame (the MOTChallenge devkit's rule; py-motmetrics keeps a
  target's last match from any earlier frame instead), then maximises the summed overlap.  A
  match whose track id differs from the last track id matched to that true target (any number
  of frames before) is an ID switch.  MOTA = 1 - (FN + FP + IDSW) / GT; MOTP = summed overlap
  of the matches / TP (the VACE "overlap ratio averaged over matched pairs", higher is better).
- **VACE detection scores**: each frame on its own, a Hungarian assignment maximising the summed
  overlap of pairs with IoU >= threshold, ignoring identities.  MODA = 1 - (misses + false
  positives) / GT summed over frames (Kasturi et al. N-MODA, c_m = c_f = 1); MODP = per-frame
  mean overlap of the matched pairs, averaged over the frames that have at least one match.

Like TrackEval, the "previous frame" matches that MOTA prefers are only replaced in frames that
have both true and estimated boxes; ratios divide by max(1, count) so empty sequences give
finite numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

_EPS = np.finfo(float).eps
_CONTINUITY_BONUS = 1000.0  # larger than any summed IoU: keeping a match beats a better overlap


@dataclass(frozen=True)
class ClearStep:
    """CLEAR matches of one frame: ``rows`` index the true boxes, ``cols`` the track boxes
    given to :meth:`ClearMatcher.step`; ``switch`` (k,) bool marks matches that are ID switches."""

    rows: np.ndarray
    cols: np.ndarray
    switch: np.ndarray


def _threshold_match(score: np.ndarray, sim: np.ndarray, threshold: float):
    """Hungarian on ``score``, keeping only pairs with ``sim >= threshold`` (TrackEval's eps)."""
    score = np.where(sim < threshold - _EPS, 0.0, score)
    rows, cols = linear_sum_assignment(-score)
    ok = score[rows, cols] > _EPS
    return rows[ok], cols[ok]


def detection_match(iou: np.ndarray, threshold: float = 0.5):
    """VACE per-frame mapping: pairs with IoU >= threshold maximising the summed overlap,
    identities ignored. Returns ``(rows, cols)`` into the (G, T) ``iou`` matrix."""
    if iou.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    return _threshold_match(iou, iou, threshold)


class ClearMatcher:
    """Stateful CLEAR-MOT matcher: feed it the frames in order with :meth:`step`.

    Holds one entry per true target id ever seen (last matched track id, frame counts), nothing
    per frame.
    """

    def __init__(self, iou_threshold: float = 0.5):
        if not 0.0 < iou_threshold <= 1.0:
            raise ValueError(f"iou_threshold must be in (0, 1], got {iou_threshold!r}")
        self.iou_threshold = float(iou_threshold)
        self._last: dict[int, int] = {}        # gt id -> track id of its last match (for IDSW)
        self._prev_step: dict[int, int] = {}   # gt id -> track id matched in the previous step
        self._present: dict[int, int] = {}     # gt id -> frames present (MT/PT/ML)
        self._matched: dict[int, int] = {}     # gt id -> frames matched (MT/PT/ML)
        self._tracked_runs: dict[int, int] = {}  # gt id -> number of tracked runs (Frag)

    def step(self, gt_ids: np.ndarray, track_ids: np.ndarray, iou: np.ndarray) -> ClearStep:
        """Match one frame. ``iou`` is (len(gt_ids), len(track_ids))."""
        gt_ids = np.asarray(gt_ids, dtype=np.int64)
        track_ids = np.asarray(track_ids, dtype=np.int64)
        for g in gt_ids.tolist():
            self._present[g] = self._present.get(g, 0) + 1
        if len(gt_ids) == 0 or len(track_ids) == 0:
            # TrackEval skips such frames entirely: the previous-step matches stay in force.
            empty = np.zeros(0, dtype=np.int64)
            return ClearStep(empty, empty, np.zeros(0, dtype=bool))
        prev = np.array([self._prev_step.get(g, np.nan) for g in gt_ids.tolist()], dtype=float)
        kept = track_ids[None, :].astype(float) == prev[:, None]
        rows, cols = _threshold_match(_CONTINUITY_BONUS * kept + iou, iou, self.iou_threshold)
        m_gt = gt_ids[rows].tolist()
        m_tr = track_ids[cols].tolist()
        switch = np.array([g in self._last and self._last[g] != t for g, t in zip(m_gt, m_tr)],
                          dtype=bool)
        new_step = dict(zip(m_gt, m_tr))
        for g, t in new_step.items():
            self._last[g] = t
            self._matched[g] = self._matched.get(g, 0) + 1
            if g not in self._prev_step:  # a tracked run starts: Frag counts runs after the first
                self._tracked_runs[g] = self._tracked_runs.get(g, 0) + 1
        self._prev_step = new_step
        return ClearStep(rows, cols, switch)

    def track_quality(self) -> dict[str, int]:
        """MT / PT / ML (tracked > 80 %, 20-80 %, < 20 % of the frames where present) and Frag
        (times a tracked run restarted), over the true targets seen so far."""
        present = np.array(list(self._present.values()), dtype=float)
        matched = np.array([self._matched.get(g, 0) for g in self._present], dtype=float)
        ratio = matched / np.maximum(present, 1.0)
        mt = int(np.sum(ratio > 0.8))
        pt = int(np.sum(ratio >= 0.2)) - mt
        runs = np.array(list(self._tracked_runs.values()), dtype=np.int64)
        return {"MT": mt, "PT": pt, "ML": len(present) - mt - pt,
                "Frag": int(np.sum(np.maximum(runs - 1, 0)))}


def mota(tp: int, fp: int, fn: int, idsw: int) -> float:
    """CLEAR MOTA = 1 - (FN + FP + IDSW) / GT, GT = TP + FN (TrackEval divides by max(1, GT))."""
    return (tp - fp - idsw) / max(1.0, tp + fn)


def moda(tp: int, fp: int, fn: int) -> float:
    """VACE N-MODA = 1 - (misses + false positives) / GT with unit costs."""
    return (tp - fp) / max(1.0, tp + fn)
