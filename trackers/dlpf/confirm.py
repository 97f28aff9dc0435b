"""Confirmation of parent detections (jung2013 §2.2, last paragraph): "some of false positive
detection can be solved by selecting the object, which is sequentially detected 4 times".

Parents are resampled every frame, so "the same parent" detecting four times has no meaning;
what persists is the *object*.  A candidate is a box seen by some parent's classifier hit; a hit
in the next frame overlapping it (IoU ≥ ``match_iou``, greedy by IoU) extends it.  A candidate
is confirmed when it has been detected ``count`` times (4 in the paper) with at most
``max_gap`` frames without a hit between two detections (0 = strictly consecutive frames, the
paper's "sequentially"); a candidate that misses more is dropped.  The parent of the
confirming hit becomes the track's parent.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..eval.overlap import box_iou


@dataclass
class Candidate:
    """An object seen by parents but not yet confirmed.  ``history``: (frame, person box) of
    each detection; ``parent``: index of the parent whose hit matched last."""

    cid: int
    box: np.ndarray
    count: int
    last: int
    parent: int
    score: float
    history: list = field(default_factory=list)


class Confirmer:
    """Counts sequential detections per candidate object (module docstring)."""

    def __init__(self, count: int = 4, max_gap: int = 0, match_iou: float = 0.3):
        if count < 1:
            raise ValueError(f"confirmation count must be >= 1, got {count}")
        self.count, self.max_gap, self.match_iou = int(count), int(max_gap), float(match_iou)
        self.candidates: list[Candidate] = []
        self._next = 1

    def step(self, frame: int, boxes: np.ndarray, scores: np.ndarray,
             parents: np.ndarray) -> list[Candidate]:
        """Feed frame ``frame``'s hits (person boxes (N, 4), scores, parent indices); return the
        candidates confirmed now (removed from the pending list)."""
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        # only candidates missed for at most max_gap frames may be extended
        cands = [c for c in self.candidates if frame - c.last - 1 <= self.max_gap]
        used_hit = np.zeros(len(boxes), dtype=bool)
        if cands and len(boxes):
            iou = box_iou(np.array([c.box for c in cands]), boxes)
            order = np.dstack(np.unravel_index(np.argsort(-iou, axis=None), iou.shape))[0]
            used_cand = np.zeros(len(cands), dtype=bool)
            for ci, hi in order:
                if iou[ci, hi] < self.match_iou:
                    break
                if used_cand[ci] or used_hit[hi]:
                    continue
                used_cand[ci] = used_hit[hi] = True
                c = cands[ci]
                c.box, c.count, c.last = boxes[hi].copy(), c.count + 1, frame
                c.parent, c.score = int(parents[hi]), float(scores[hi])
                c.history.append((frame, boxes[hi].copy()))
        # a candidate missed for more than max_gap frames is dropped
        self.candidates = [c for c in cands if frame - c.last <= self.max_gap]
        for hi in np.flatnonzero(~used_hit):
            self.candidates.append(Candidate(self._next, boxes[hi].copy(), 1, frame,
                                             int(parents[hi]), float(scores[hi]),
                                             [(frame, boxes[hi].copy())]))
            self._next += 1
        done = [c for c in self.candidates if c.count >= self.count and c.last == frame]
        self.candidates = [c for c in self.candidates if c not in done]
        return done

    def forget_inside(self, boxes: np.ndarray, iou: float) -> None:
        """Drop candidates overlapping ``boxes`` (already tracked objects) by IoU ≥ ``iou``."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        if not self.candidates or len(b) == 0:
            return
        ov = box_iou(np.array([c.box for c in self.candidates]), b).max(axis=1)
        self.candidates = [c for c, o in zip(self.candidates, ov) if o < iou]


__all__ = ["Candidate", "Confirmer"]
