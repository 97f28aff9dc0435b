"""Scores of a whole sequence: a tracks file against a ground-truth file.

Runs :class:`~trackers.eval.online.OnlineEvaluator` over the frames (CLEAR-MOT, VACE, OSPA,
GOSPA, ME), then the two metrics that need the whole sequence at once: identity (IDF1) and HOTA.
The metric definitions live in the modules named in each key's comment below.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from ..data.motio import MotTable
from ..errors import InputError
from .clear import moda
from .conventions import check_convention, detect_convention
from .hota import hota_scores
from .identity import identity_scores
from .online import OnlineEvaluator, score_frame
from .ospa import DEFAULT_ALPHA, DEFAULT_C, DEFAULT_P


def _name(table: MotTable, default: str) -> str:
    return table.path or default


def _frames(gt: MotTable, tracks: MotTable, frames: Iterable[int] | None) -> list[int]:
    if frames is None:
        last = gt.last_frame
        if last == 0:
            raise InputError(f"{_name(gt, 'ground truth')}: no ground-truth rows, nothing to "
                             f"evaluate (pass frames= to score a sequence without targets)")
        beyond = tracks.frame > last
        if beyond.any():
            raise InputError(
                f"{_name(tracks, 'tracks')}: {int(beyond.sum())} rows in frames "
                f"{int(tracks.frame[beyond].min())}..{int(tracks.frame[beyond].max())} beyond the "
                f"last ground-truth frame {last} (wrong sequence? pass frames= to score "
                f"a longer sequence)")
        return list(range(1, last + 1))
    out = [int(f) for f in frames]
    if not out:
        raise InputError("frames: empty range, nothing to evaluate")
    if min(out) < 1:
        raise InputError(f"frames: frame numbers start at 1, got {min(out)}")
    if any(b <= a for a, b in zip(out, out[1:])):
        raise InputError("frames: frame numbers must increase")
    return out


def _dense(ids_per_frame: list[np.ndarray]) -> tuple[list[np.ndarray], int]:
    """Relabel ids to 0..n-1 across the sequence (identity and HOTA index arrays by id)."""
    if not ids_per_frame:
        return [], 0
    flat = np.concatenate(ids_per_frame)
    uniq, inv = np.unique(flat, return_inverse=True)
    cuts = np.cumsum([len(a) for a in ids_per_frame])[:-1]
    return np.split(inv.astype(np.int64), cuts), len(uniq)


def evaluate(gt: MotTable, tracks: MotTable, *, iou_threshold: float = 0.5,
             ospa_c: float = DEFAULT_C, ospa_p: float = DEFAULT_P,
             gospa_alpha: float = DEFAULT_ALPHA, frames: Iterable[int] | None = None,
             convention: str | None = None) -> dict[str, float | str]:
    """Score ``tracks`` against ``gt`` over ``frames``.

    frames: the frames to score, increasing (e.g. ``range(1, seqLength + 1)``); rows of either
    table outside them are not scored (their count is ``track_rows_outside``). ``None`` scores
    1..last gt frame and raises InputError if the tracks go beyond it, or if gt is empty.
    An empty tracks table is valid (everything missed). Ids repeated within a frame raise
    InputError.

    convention (:mod:`.conventions`): which gt rows are scored and which track boxes are left out.

    - ``"mot15"``: gt rows with conf = 0 are dropped; every track box is scored (one covering a
      dropped gt box is a false positive). As py-motmetrics (``min_confidence=1``) and
      TrackEval's MOT15 mode.
    - ``"mot16"``: TrackEval's MOT16/17 preprocessing: track boxes matched (IoU >= 0.5) to a
      distractor are removed, then only pedestrian gt rows with conf != 0 are scored.
      Distractors: classes 2, 7, 8, 12 in a gt with MOT16 classes; the conf = 0 rows in a gt
      without classes (MOT15 layout).
    - ``None`` or ``"auto"`` (default): follow the gt's benchmark, told by its layout:
      ``"mot16"`` when every gt row has an integer class id in 1..13 and a visibility in [0, 1]
      (MOT16/17/20 gt), else ``"mot15"`` (MOT15 gt: -1 or world coordinates in columns 8-10, or
      ``vis = -1``; PETS09-S2L1 here is one).

    Any other value raises ValueError. Matches need IoU >= ``iou_threshold`` either way.

    Keys (ratios in [0, 1] except MOTA/MODA, which can be negative; OSPA/GOSPA/ME in pixels):

    - MOTA, MOTP, IDSW, TP, FP, FN, GT, MT, PT, ML, Frag, Recall, Precision: CLEAR-MOT
      (:mod:`.clear`)
    - MODA, MODP: VACE (:mod:`.clear`)
    - IDF1, IDP, IDR, IDTP, IDFP, IDFN: identity (:mod:`.identity`)
    - HOTA, DetA, AssA, DetRe, DetPr, AssRe, AssPr, LocA: HOTA (:mod:`.hota`)
    - OSPA, GOSPA: mean over the frames of the per-frame distances on box centres (:mod:`.ospa`)
    - ME: feng2015's mean error: each true target's mean centre distance to its CLEAR match,
      averaged over the targets matched at least once (nan if none)
    - num_frames, num_gt_ids, num_track_ids, track_rows_outside; ignored_gt: gt boxes not
      scored; ignored_tracks: track boxes removed for covering a distractor (``"mot16"``)
    - convention: ``"mot15"`` or ``"mot16"``, the one applied; iou_threshold: the one used
    """
    convention = check_convention(convention) or detect_convention(gt)
    frame_list = _frames(gt, tracks, frames)
    ev = OnlineEvaluator(iou_threshold=iou_threshold, ospa_c=ospa_c, ospa_p=ospa_p,
                         gospa_alpha=gospa_alpha, convention=convention)
    gt_name, tr_name = _name(gt, "ground truth"), _name(tracks, "tracks")
    gt_ids, tr_ids, ious, me_ids, me_dist = [], [], [], [], []
    det_tp = det_fp = n_modp = 0
    modp_sum = 0.0
    ignored_gt = ignored_tr = 0
    for f in frame_list:
        g, t = gt.ground_truth(f), tracks.tracks(f)
        s = score_frame(f, g, t, iou_threshold, convention, gt_name, tr_name)
        m = ev._update(f, s, g, t)
        gt_ids.append(s.gt_ids)
        tr_ids.append(s.track_ids)
        ious.append(s.iou)
        me_ids.append(g.ids[m.match_gt_idx])
        me_dist.append(m.match_dist)
        det_tp += m.det_tp
        det_fp += m.n_est - m.det_tp
        if m.det_tp:
            modp_sum += m.modp
            n_modp += 1
        ignored_gt += len(m.ignored_gt_idx)
        ignored_tr += len(m.ignored_track_idx)

    tot = ev.totals
    res: dict[str, float | str] = {k: tot[k]
                                   for k in ("MOTA", "MOTP", "IDSW", "TP", "FP", "FN", "GT")}
    res.update(ev.track_quality())
    res["Recall"] = tot["TP"] / max(1, tot["GT"])
    res["Precision"] = tot["TP"] / max(1, tot["TP"] + tot["FP"])
    res["MODA"] = moda(det_tp, det_fp, tot["GT"] - det_tp)
    res["MODP"] = modp_sum / n_modp if n_modp else 0.0

    g_dense, n_gt = _dense(gt_ids)
    t_dense, n_tr = _dense(tr_ids)
    res.update(identity_scores(g_dense, t_dense, ious, n_gt, n_tr, iou_threshold))
    res.update(hota_scores(g_dense, t_dense, ious, n_gt, n_tr))

    res["OSPA"], res["GOSPA"] = tot["OSPA"], tot["GOSPA"]
    ids, dist = np.concatenate(me_ids), np.concatenate(me_dist)
    if len(ids):
        uniq, inv = np.unique(ids, return_inverse=True)
        per_target = np.bincount(inv, weights=dist) / np.bincount(inv)
        res["ME"] = float(per_target.mean())
    else:
        res["ME"] = float("nan")

    in_range = np.isin(tracks.frame, np.asarray(frame_list)) if len(tracks) else np.zeros(0, bool)
    res.update(num_frames=len(frame_list), num_gt_ids=n_gt, num_track_ids=n_tr,
               ignored_gt=ignored_gt, ignored_tracks=ignored_tr,
               track_rows_outside=int(len(tracks) - in_range.sum()),
               convention=convention, iou_threshold=float(iou_threshold))
    return res
