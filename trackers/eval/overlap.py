"""Box overlap and box centres shared by every metric.

The overlap of two boxes is the VACE "overlap ratio" |G ∩ D| / |G ∪ D| (intersection over
union), as used by the VACE scores that maggio2007 §4 (Table 1) reports and by CLEAR-MOT and
HOTA on MOTChallenge.  Boxes are MOT ``(x, y, w, h)`` top-left, continuous pixel coordinates
(no "+1" pixel convention, like TrackEval).
"""

from __future__ import annotations

import numpy as np

_EPS = np.finfo(float).eps


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,4) x (M,4) top-left boxes -> (N,M) intersection over union, in [0, 1].

    Degenerate boxes (zero area) overlap nothing.
    """
    a = np.asarray(a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 4)
    a0, a1 = a[:, None, :2], a[:, None, :2] + a[:, None, 2:]
    b0, b1 = b[None, :, :2], b[None, :, :2] + b[None, :, 2:]
    wh = np.maximum(np.minimum(a1, b1) - np.maximum(a0, b0), 0.0)
    inter = wh[..., 0] * wh[..., 1]
    area_a = a[:, 2] * a[:, 3]
    area_b = b[:, 2] * b[:, 3]
    union = area_a[:, None] + area_b[None, :] - inter
    valid = (area_a[:, None] > _EPS) & (area_b[None, :] > _EPS) & (union > _EPS)
    return np.where(valid, inter / np.where(valid, union, 1.0), 0.0)


def box_centers(boxes: np.ndarray) -> np.ndarray:
    """(N,4) top-left boxes -> (N,2) centres ``(x + w/2, y + h/2)``."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    return boxes[:, :2] + boxes[:, 2:] / 2.0
