"""Per-frame metrics for the recording: OSPA, cardinality, TP/FP/FN, ID switches, and which boxes
are misses, false positives and switches.

:class:`OnlineEvaluator` is fed one frame at a time (as a tracker runs, or while replaying a
tracks file) and returns a :class:`FrameMetrics`; :func:`trackers.eval.evaluate` runs the same
evaluator over a whole sequence, so the time series and the sequence scores always agree.

Which true boxes are scored and which track boxes are left out follows the evaluation
convention (:mod:`.conventions`): ``"mot15"`` drops the ``conf = 0`` true boxes and keeps every
track box (one covering a dropped box is a false positive); ``"mot16"`` first removes the track
boxes matched to a distractor, then scores only the pedestrian ``conf != 0`` true boxes.  The
default (None) decides per frame from the gt: ``"mot16"`` when it carries MOT16 classes, else
``"mot15"``.  OSPA is computed on box centres (:mod:`.ospa`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..errors import InputError
from ..types import GroundTruth, TrackSet
from .clear import ClearMatcher, detection_match, mota
from .conventions import DISTRACTOR_IOU, check_convention, frame_convention, gt_masks
from .ospa import DEFAULT_ALPHA, DEFAULT_C, DEFAULT_P, ospa_gospa
from .overlap import box_centers, box_iou

_EPS = np.finfo(float).eps
_NO_INDEX = np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class FrameMetrics:
    """Metrics of one frame. Index arrays point into the ``gt`` / ``tracks`` given to
    :meth:`OnlineEvaluator.update`.

    frame: frame number; n_true / n_est: true targets scored / track boxes scored (those
    removed for covering a distractor excluded); tp, fp, fn, idsw: CLEAR-MOT counts of this frame;
    ospa, gospa: distances between true and estimated box centres (pixels).
    match_gt_idx, match_track_idx (k,): CLEAR matches; match_iou (k,): their overlap;
    match_dist (k,): their centre distance in pixels.
    fp_idx: unmatched tracks; fn_idx: missed true boxes; switch_idx: tracks whose match is an ID
    switch; ignored_gt_idx: true boxes not scored under the convention; ignored_track_idx: tracks
    removed because they cover a distractor (``"mot16"`` only); convention: the one applied.
    det_tp, det_iou_sum: VACE per-frame detection matches (identities ignored) and their summed IoU.
    """

    frame: int
    n_true: int
    n_est: int
    tp: int
    fp: int
    fn: int
    idsw: int
    ospa: float
    gospa: float
    match_gt_idx: np.ndarray = field(repr=False)
    match_track_idx: np.ndarray = field(repr=False)
    match_iou: np.ndarray = field(repr=False)
    match_dist: np.ndarray = field(repr=False)
    fp_idx: np.ndarray = field(repr=False)
    fn_idx: np.ndarray = field(repr=False)
    switch_idx: np.ndarray = field(repr=False)
    ignored_gt_idx: np.ndarray = field(repr=False)
    ignored_track_idx: np.ndarray = field(repr=False)
    det_tp: int = 0
    det_iou_sum: float = 0.0
    convention: str = "mot15"

    @property
    def motp(self) -> float:
        """Mean IoU of this frame's CLEAR matches (nan when there are none)."""
        return float(self.match_iou.mean()) if self.tp else float("nan")

    @property
    def modp(self) -> float:
        """VACE MODP(t): mean IoU of this frame's detection matches (nan when there are none)."""
        return self.det_iou_sum / self.det_tp if self.det_tp else float("nan")

    @property
    def moda(self) -> float:
        """VACE MODA(t) = 1 - (misses + false positives) / true targets (nan without targets)."""
        if self.n_true == 0:
            return float("nan")
        misses = self.n_true - self.det_tp
        false = self.n_est - self.det_tp
        return 1.0 - (misses + false) / self.n_true


@dataclass(frozen=True)
class _Scored:
    """One frame after the convention's preprocessing: the boxes that are scored and their IoU."""

    gt_idx: np.ndarray       # into GroundTruth
    track_idx: np.ndarray    # into TrackSet
    ignored_gt_idx: np.ndarray
    ignored_track_idx: np.ndarray
    gt_ids: np.ndarray
    track_ids: np.ndarray
    iou: np.ndarray          # (len(gt_idx), len(track_idx))
    convention: str = "mot15"


def _duplicates(ids: np.ndarray) -> np.ndarray:
    if len(set(ids.tolist())) == len(ids):  # the usual case, without np.unique's cost
        return ids[:0]
    u, n = np.unique(ids, return_counts=True)
    return u[n > 1]


def _without(n: int, idx: np.ndarray, drop: np.ndarray) -> np.ndarray:
    """``np.setdiff1d(idx, drop)`` for indices into a length-``n`` array (sorted, distinct),
    by a mask: a frame scores a few boxes, where setdiff1d's sort/isin cost was most of it."""
    keep = np.zeros(n, dtype=bool)
    keep[idx] = True
    keep[drop] = False
    return np.flatnonzero(keep)


def score_frame(frame: int, gt: GroundTruth, tracks: TrackSet, iou_threshold: float,
                convention: str | None = None, gt_name: str = "ground truth",
                tracks_name: str = "tracks") -> _Scored:
    """Apply the convention's preprocessing to one frame (``convention`` already checked; None
    decides from ``gt``) and compute the IoU of the boxes that are scored."""
    for ids, name in ((gt.ids, gt_name), (tracks.ids, tracks_name)):
        dup = _duplicates(ids)
        if len(dup):
            raise InputError(f"{name}: frame {frame}: id {int(dup[0])} appears "
                             f"{int(np.sum(ids == dup[0]))} times (ids must be unique per frame)")
    convention = frame_convention(convention, gt)
    iou_all = box_iou(gt.boxes, tracks.boxes)
    scored, distractor = gt_masks(gt, convention)
    dropped = _NO_INDEX
    if distractor.any() and len(tracks):
        # Match against every true box, distractors included (TrackEval's preprocessing).
        score = np.where(iou_all < DISTRACTOR_IOU - _EPS, 0.0, iou_all)
        rows, cols = linear_sum_assignment(-score)
        ok = score[rows, cols] > _EPS
        dropped = np.sort(cols[ok][distractor[rows[ok]]]).astype(np.int64)
    keep_gt = np.flatnonzero(scored)
    keep_tr = _without(len(tracks), np.arange(len(tracks)), dropped)
    return _Scored(gt_idx=keep_gt, track_idx=keep_tr, ignored_gt_idx=np.flatnonzero(~scored),
                   ignored_track_idx=dropped, gt_ids=gt.ids[keep_gt], track_ids=tracks.ids[keep_tr],
                   iou=iou_all[np.ix_(keep_gt, keep_tr)], convention=convention)


class OnlineEvaluator:
    """Scores a tracker frame by frame (frames must come in increasing order).

    Keeps only what CLEAR-MOT needs across frames (one entry per true target id) and running
    totals; :attr:`totals` gives the scores so far.  ``convention``: ``"mot15"``, ``"mot16"``, or
    None / ``"auto"`` to follow each frame's gt (:func:`.conventions.frame_convention`; for a
    whole table that is :func:`.conventions.detect_convention`, as :func:`.evaluate` uses).
    """

    def __init__(self, *, iou_threshold: float = 0.5, ospa_c: float = DEFAULT_C,
                 ospa_p: float = DEFAULT_P, gospa_alpha: float = DEFAULT_ALPHA,
                 convention: str | None = None):
        ospa_gospa(np.zeros((0, 2)), np.zeros((0, 2)), ospa_c, ospa_p, gospa_alpha)  # validates
        self.iou_threshold = float(iou_threshold)
        self.ospa_c, self.ospa_p = float(ospa_c), float(ospa_p)
        self.gospa_alpha = float(gospa_alpha)
        self.convention = check_convention(convention)
        self._clear = ClearMatcher(iou_threshold)
        self._last_frame: int | None = None
        self._sums = dict(frames=0, tp=0, fp=0, fn=0, idsw=0, iou=0.0, ospa=0.0, gospa=0.0)

    def update(self, frame: int, gt: GroundTruth, tracks: TrackSet) -> FrameMetrics:
        """Score one frame. Raises InputError on a frame number that does not increase or on an
        id repeated within the frame."""
        return self._update(frame, score_frame(frame, gt, tracks, self.iou_threshold,
                                               self.convention), gt, tracks)

    def _update(self, frame: int, s: _Scored, gt: GroundTruth, tracks: TrackSet) -> FrameMetrics:
        frame = int(frame)
        if self._last_frame is not None and frame <= self._last_frame:
            raise InputError(f"frame {frame} scored after frame {self._last_frame}: "
                             f"frames must increase")
        self._last_frame = frame
        step = self._clear.step(s.gt_ids, s.track_ids, s.iou)
        g_idx, t_idx = s.gt_idx[step.rows], s.track_idx[step.cols]
        gc, tc = box_centers(gt.boxes[s.gt_idx]), box_centers(tracks.boxes[s.track_idx])
        dist = np.linalg.norm(gc[step.rows] - tc[step.cols], axis=1)
        det_rows, det_cols = detection_match(s.iou, self.iou_threshold)
        n_true, n_est, tp = len(s.gt_idx), len(s.track_idx), len(step.rows)
        d_ospa, d_gospa = ospa_gospa(gc, tc, self.ospa_c, self.ospa_p, self.gospa_alpha)
        m = FrameMetrics(
            frame=frame, n_true=n_true, n_est=n_est, tp=tp, fp=n_est - tp, fn=n_true - tp,
            idsw=int(step.switch.sum()),
            ospa=d_ospa, gospa=d_gospa,
            match_gt_idx=g_idx, match_track_idx=t_idx, match_iou=s.iou[step.rows, step.cols],
            match_dist=dist,
            fp_idx=_without(len(tracks), s.track_idx, t_idx),
            fn_idx=_without(len(gt.ids), s.gt_idx, g_idx),
            switch_idx=t_idx[step.switch],
            ignored_gt_idx=s.ignored_gt_idx, ignored_track_idx=s.ignored_track_idx,
            det_tp=len(det_rows), det_iou_sum=float(s.iou[det_rows, det_cols].sum()),
            convention=s.convention)
        acc = self._sums
        acc["frames"] += 1
        for k in ("tp", "fp", "fn", "idsw"):
            acc[k] += getattr(m, k)
        acc["iou"] += float(m.match_iou.sum())
        acc["ospa"] += m.ospa
        acc["gospa"] += m.gospa
        return m

    @property
    def totals(self) -> dict[str, float]:
        """Running CLEAR-MOT scores and mean OSPA/GOSPA over the frames scored so far."""
        a = self._sums
        n = max(1, a["frames"])
        return {"MOTA": mota(a["tp"], a["fp"], a["fn"], a["idsw"]),
                "MOTP": a["iou"] / max(1, a["tp"]),
                "TP": a["tp"], "FP": a["fp"], "FN": a["fn"], "IDSW": a["idsw"],
                "GT": a["tp"] + a["fn"], "OSPA": a["ospa"] / n, "GOSPA": a["gospa"] / n,
                "num_frames": a["frames"]}

    def track_quality(self) -> dict[str, int]:
        """MT / PT / ML / Frag over the frames scored so far."""
        return self._clear.track_quality()
