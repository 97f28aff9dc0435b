"""Scores of several sequences as one: the COMBINED row of a benchmark.

As TrackEval and MOTChallenge combine sequences: the CLEAR-MOT and identity *counts* are summed
over the sequences and the ratios computed from the sums (so a long sequence weighs more than a
short one, and MOTA of the whole is not the mean of the MOTAs); MOTP is weighted by TP; HOTA is
combined per localisation threshold (TP, FN, FP summed, AssA weighted by TP, then
``sqrt(DetA · AssA)`` averaged over the thresholds); OSPA/GOSPA (means over frames) and ME
(a mean over targets) are weighted by frames and by ground-truth ids.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

#: Counts summed over sequences.
SUMMED = ("TP", "FP", "FN", "IDSW", "GT", "IDTP", "IDFP", "IDFN", "MT", "PT", "ML", "Frag",
          "num_frames", "num_gt_ids", "num_track_ids", "ignored_gt", "ignored_tracks",
          "track_rows_outside")


def combine(per_sequence: Sequence[Mapping]) -> dict:
    """One scores dict (the keys of :func:`.sequence.evaluate` that combine) for all of
    ``per_sequence`` (each an ``evaluate()`` dict).  Raises ValueError on an empty list or on
    sequences scored under different conventions."""
    seqs = list(per_sequence)
    if not seqs:
        raise ValueError("combine: no sequence to combine")
    convs = {s.get("convention") for s in seqs}
    if len(convs) > 1:
        raise ValueError(f"combine: sequences scored under different conventions: {sorted(map(str, convs))}")
    out: dict = {k: int(sum(s[k] for s in seqs)) for k in SUMMED if all(k in s for s in seqs)}
    tp, fp, fn, sw, gt = (out[k] for k in ("TP", "FP", "FN", "IDSW", "GT"))
    out["MOTA"] = 1.0 - (fn + fp + sw) / max(1, gt)
    out["MOTP"] = (sum(s["MOTP"] * s["TP"] for s in seqs) / tp) if tp else 0.0
    out["Recall"] = tp / max(1, gt)
    out["Precision"] = tp / max(1, tp + fp)
    idtp, idfp, idfn = out["IDTP"], out["IDFP"], out["IDFN"]
    out["IDF1"] = 2 * idtp / max(1, 2 * idtp + idfp + idfn)
    out["IDP"] = idtp / max(1, idtp + idfp)
    out["IDR"] = idtp / max(1, idtp + idfn)
    if all("_hota_alpha" in s for s in seqs):
        a = [s["_hota_alpha"] for s in seqs]
        htp = np.sum([x["TP"] for x in a], axis=0)
        hfn = np.sum([x["FN"] for x in a], axis=0)
        hfp = np.sum([x["FP"] for x in a], axis=0)
        ass = np.sum([np.asarray(x["AssA"]) * np.asarray(x["TP"]) for x in a], axis=0)
        ass_a = ass / np.maximum(1.0, htp)
        det_a = htp / np.maximum(1.0, htp + hfn + hfp)
        out["HOTA"] = float(np.sqrt(det_a * ass_a).mean())
        out["DetA"] = float(det_a.mean())
        out["AssA"] = float(ass_a.mean())
    frames = np.array([s.get("num_frames", 0) for s in seqs], float)
    for k in ("OSPA", "GOSPA"):
        if all(k in s for s in seqs) and frames.sum() > 0:
            out[k] = float(np.dot([s[k] for s in seqs], frames) / frames.sum())
    me = [(s["ME"], s.get("num_gt_ids", 1)) for s in seqs
          if "ME" in s and np.isfinite(s["ME"])]
    if me:
        out["ME"] = float(sum(v * n for v, n in me) / max(1, sum(n for _, n in me)))
    out["num_sequences"] = len(seqs)
    if convs != {None}:
        out["convention"] = convs.pop()
    iou = {s.get("iou_threshold") for s in seqs}
    if len(iou) == 1 and None not in iou:
        out["iou_threshold"] = iou.pop()
    return out


__all__ = ["combine", "SUMMED"]
