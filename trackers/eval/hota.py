"""HOTA (Luiten et al., "HOTA: A higher order metric for evaluating multi-object tracking",
IJCV 2021), computed as TrackEval's ``HOTA`` metric.

For each localisation threshold alpha in {0.05, 0.10, ..., 0.95}:
DetA = |TP| / (|TP| + |FN| + |FP|), AssA = mean over TP of A(c) with
A(c) = |TPA| / (|TPA| + |FNA| + |FPA|), HOTA_alpha = sqrt(DetA * AssA); the reported HOTA, DetA,
AssA, LocA ... are the means over the 19 alphas.  Per frame, the pairs are chosen by a
Hungarian assignment maximising IoU times the global alignment score of the two ids, then
kept for a given alpha when IoU >= alpha.

Input per frame: dense ids (0..n_gt-1, 0..n_tr-1) and the (G, T) IoU matrix.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

_EPS = np.finfo(float).eps

#: The 19 localisation thresholds over which HOTA is averaged (Luiten et al. 2021).
ALPHAS = np.arange(0.05, 0.99, 0.05)


def hota_scores(gt_ids: Sequence[np.ndarray], track_ids: Sequence[np.ndarray],
                ious: Sequence[np.ndarray], n_gt: int, n_tr: int,
                alphas: np.ndarray = ALPHAS) -> dict[str, float]:
    """HOTA, DetA, AssA, DetRe, DetPr, AssRe, AssPr, LocA (means over ``alphas``), and
    ``_hota_alpha``: the per-alpha TP, FN, FP and AssA lists that :func:`.combine.combine`
    sums over sequences."""
    alphas = np.asarray(alphas, dtype=float)
    na = len(alphas)
    gt_count = np.zeros((n_gt, 1))
    tr_count = np.zeros((1, n_tr))
    n_gt_dets = sum(len(g) for g in gt_ids)
    n_tr_dets = sum(len(t) for t in track_ids)
    if n_gt_dets == 0 or n_tr_dets == 0:
        tp, fn, fp = np.zeros(na), np.full(na, float(n_gt_dets)), np.full(na, float(n_tr_dets))
        ass_a = ass_re = ass_pr = np.zeros(na)
        loc_a = np.ones(na)
    else:
        # Pass 1: global alignment score between every true id and track id:
        # soft per-frame matches, each IoU normalised by the IoUs competing for its row/column.
        potential = np.zeros((n_gt, n_tr))
        for g, t, s in zip(gt_ids, track_ids, ious):
            denom = s.sum(0)[None, :] + s.sum(1)[:, None] - s
            soft = np.divide(s, denom, out=np.zeros_like(s), where=denom > _EPS)
            potential[g[:, None], t[None, :]] += soft
            gt_count[g] += 1
            tr_count[0, t] += 1
        align = potential / (gt_count + tr_count - potential)

        # Pass 2: per-frame matching maximising IoU x alignment, counted for every alpha at once.
        tp, fn, fp, loc = np.zeros(na), np.zeros(na), np.zeros(na), np.zeros(na)
        matches = np.zeros((na, n_gt, n_tr))
        for g, t, s in zip(gt_ids, track_ids, ious):
            if len(g) == 0 or len(t) == 0:
                fp += len(t)
                fn += len(g)
                continue
            rows, cols = linear_sum_assignment(-(align[g[:, None], t[None, :]] * s))
            sim = s[rows, cols]
            ok = sim[None, :] >= alphas[:, None] - _EPS                   # (na, k)
            n_ok = ok.sum(1)
            tp += n_ok
            fn += len(g) - n_ok
            fp += len(t) - n_ok
            loc += (ok * sim[None, :]).sum(1)
            a_idx, k_idx = np.nonzero(ok)
            np.add.at(matches, (a_idx, g[rows[k_idx]], t[cols[k_idx]]), 1.0)
        # Association accuracy A(c) of each TP pair, averaged over the TPs.
        sq = matches * matches
        n_tp = np.maximum(1.0, tp)
        ass_a = (sq / np.maximum(1.0, gt_count[None] + tr_count[None] - matches)).sum((1, 2)) / n_tp
        ass_re = (sq / np.maximum(1.0, gt_count[None])).sum((1, 2)) / n_tp
        ass_pr = (sq / np.maximum(1.0, tr_count[None])).sum((1, 2)) / n_tp
        loc_a = np.maximum(1e-10, loc) / np.maximum(1e-10, tp)
    det_re = tp / np.maximum(1.0, tp + fn)
    det_pr = tp / np.maximum(1.0, tp + fp)
    det_a = tp / np.maximum(1.0, tp + fn + fp)
    hota = np.sqrt(det_a * ass_a)
    return {"HOTA": float(hota.mean()), "DetA": float(det_a.mean()), "AssA": float(ass_a.mean()),
            "DetRe": float(det_re.mean()), "DetPr": float(det_pr.mean()),
            "AssRe": float(ass_re.mean()), "AssPr": float(ass_pr.mean()),
            "LocA": float(loc_a.mean()),
            # per-alpha counts, for combining sequences as TrackEval does (.combine)
            "_hota_alpha": {"TP": tp.tolist(), "FN": fn.tolist(), "FP": fp.tolist(),
                            "AssA": ass_a.tolist()}}
