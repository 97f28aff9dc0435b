"""Identity metrics IDF1, IDP, IDR (Ristani et al., "Performance measures and a data set for
multi-target, multi-camera tracking", ECCV workshops 2016), computed as TrackEval's ``Identity``.

A true trajectory and a track may be paired once for the whole sequence; the pairing minimises
IDFN + IDFP, where a pair's frames count as identity true positives only when the boxes overlap
with IoU >= threshold.  IDF1 = 2 IDTP / (2 IDTP + IDFP + IDFN) (ratio of correctly identified
detections over the mean of true and computed detections), IDP = IDTP / (IDTP + IDFP),
IDR = IDTP / (IDTP + IDFN).

Input per frame: dense ids (0..n_gt-1, 0..n_tr-1) and the (G, T) IoU matrix.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

_BIG = 1e10  # forbids pairing a true id with another id's "unmatched" slot


def identity_scores(gt_ids: Sequence[np.ndarray], track_ids: Sequence[np.ndarray],
                    ious: Sequence[np.ndarray], n_gt: int, n_tr: int,
                    threshold: float = 0.5) -> dict[str, float]:
    """IDTP, IDFP, IDFN, IDF1, IDP, IDR over a sequence (lists indexed by frame)."""
    gt_count = np.zeros(n_gt)
    tr_count = np.zeros(n_tr)
    pairs = np.zeros((n_gt, n_tr))
    for g, t, s in zip(gt_ids, track_ids, ious):
        gt_count[g] += 1
        tr_count[t] += 1
        r, c = np.nonzero(s >= threshold)
        np.add.at(pairs, (g[r], t[c]), 1.0)
    n_gt_dets, n_tr_dets = int(gt_count.sum()), int(tr_count.sum())
    if n_gt_dets == 0 or n_tr_dets == 0:
        idtp, idfn, idfp = 0, n_gt_dets, n_tr_dets
    else:
        # Square (n_gt + n_tr) assignment: a true id is paired with a track or left alone
        # (its own "unmatched" column), a track likewise; TrackEval's fn_mat + fp_mat.
        size = n_gt + n_tr
        fn = np.zeros((size, size))
        fp = np.zeros((size, size))
        fn[:n_gt, n_tr:] = _BIG
        fp[n_gt:, :n_tr] = _BIG
        fn[:n_gt, :n_tr] = gt_count[:, None] - pairs
        fn[np.arange(n_gt), n_tr + np.arange(n_gt)] = gt_count
        fp[:n_gt, :n_tr] = tr_count[None, :] - pairs
        fp[n_gt + np.arange(n_tr), np.arange(n_tr)] = tr_count
        rows, cols = linear_sum_assignment(fn + fp)
        idfn = int(round(fn[rows, cols].sum()))
        idfp = int(round(fp[rows, cols].sum()))
        idtp = n_gt_dets - idfn
    return {
        "IDTP": idtp, "IDFP": idfp, "IDFN": idfn,
        "IDF1": idtp / max(1.0, idtp + 0.5 * idfp + 0.5 * idfn),
        "IDP": idtp / max(1.0, idtp + idfp),
        "IDR": idtp / max(1.0, idtp + idfn),
    }
