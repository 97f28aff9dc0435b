"""Evaluation conventions: which ground-truth boxes are scored, which track boxes are left out.

MOTChallenge changed its preprocessing between benchmarks and the scores move with it (on
PETS09-S2L1 a track on each of the 174 ``conf = 0`` boxes is 174 false positives under MOT15
rules and nothing at all under MOT16 ones), so every score states the convention it used:

- ``"mot15"`` (2D MOT 2015: py-motmetrics ``loadtxt(..., min_confidence=1)``, TrackEval with
  ``BENCHMARK='MOT15'``): gt rows with ``conf = 0`` are dropped; no track box is removed, so
  one covering a dropped gt box is a false positive.
- ``"mot16"`` (MOT16/MOT17: TrackEval's ``MotChallenge2DBox.get_preprocessed_seq_data``): in
  each frame the track boxes are first matched to all gt boxes (Hungarian on IoU, pairs with
  IoU >= 0.5 — TrackEval's fixed threshold, whatever the scoring threshold), and those matched
  to a *distractor* are removed; then only pedestrian gt rows with ``conf != 0`` are scored.  In a gt with MOT16 classes (see below) the distractors
  are the classes 2 person on vehicle, 7 static person, 8 distractor and 12 reflection and the
  pedestrians class 1 (a track on a car or an occluder stays a false positive, as in TrackEval);
  a gt without classes (MOT15 layout) has its ``conf = 0`` rows as the distractors.

Both conventions then match at IoU >= ``iou_threshold`` (0.5) with the same CLEAR matcher
(:mod:`.clear`): a target's match of the previous frame is kept first, as in the MOTChallenge
devkit and TrackEval.  py-motmetrics instead keeps a target's last match from any earlier frame
(its issue #132), which can move a few ID switches and with them MOTA and MOTP (in principle
also FP/FN, when a kept match blocks a better assignment); IDF1 does not depend on it.

Default (``convention=None`` or ``"auto"``): follow the ground truth's benchmark, told by its
layout (``seqinfo.ini`` has no benchmark field): ``"mot16"`` when the gt carries MOT16+
annotations — every row has an integer class id in 1..13 (column 8) and a visibility in [0, 1]
(column 9) — otherwise ``"mot15"`` (MOT15 gt rows have ``-1`` or world coordinates in columns
8-10; a converted MOT15 gt such as this project's PETS09-S2L1 has ``vis = -1``, unknown).
"""

from __future__ import annotations

import numpy as np

from ..types import GroundTruth

#: The conventions :func:`trackers.eval.evaluate` knows.
CONVENTIONS = ("mot15", "mot16")

#: MOT16+ class ids (TrackEval's numbering): the one that is scored, and the distractors whose
#: covering track boxes are removed under ``"mot16"``.
PEDESTRIAN = 1
DISTRACTOR_CLASSES = (2, 7, 8, 12)  # person on vehicle, static person, distractor, reflection

#: IoU at which ``"mot16"`` matches track boxes to distractors (fixed in TrackEval).
DISTRACTOR_IOU = 0.5

_SUMMARY = {"mot15": "gt conf=0 dropped, tracks kept",
            "mot16": "tracks on distractors removed, then conf=0/non-pedestrian gt dropped"}


def check_convention(convention: str | None) -> str | None:
    """``"mot15"`` / ``"mot16"`` (any case), or None for automatic (``None`` or ``"auto"``).
    Raises ValueError on anything else."""
    if convention is None:
        return None
    c = str(convention).strip().lower()
    if c == "auto":
        return None
    if c not in CONVENTIONS:
        raise ValueError(f"convention must be 'mot15', 'mot16' or 'auto', got {convention!r}")
    return c


def detect_convention(gt) -> str:
    """The default convention of a ground-truth :class:`~trackers.data.motio.MotTable`:
    ``"mot16"`` when it has MOT16 classes (:attr:`MotTable.has_classes`), else ``"mot15"``."""
    return "mot16" if gt.has_classes else "mot15"


def frame_convention(convention: str | None, gt: GroundTruth) -> str:
    """The convention for one frame: ``convention`` if given, else ``"mot16"`` when the frame's
    gt carries MOT16 classes (``gt.cls`` set, as :meth:`MotTable.ground_truth` does for such a
    gt), else ``"mot15"`` — the same rule as :func:`detect_convention`."""
    return convention or ("mot16" if gt.cls is not None else "mot15")


def gt_masks(gt: GroundTruth, convention: str) -> tuple[np.ndarray, np.ndarray]:
    """``(scored, distractor)`` boolean masks over the frame's gt boxes under ``convention``."""
    zero = np.asarray(gt.ignore, dtype=bool)
    if convention == "mot15":
        return ~zero, np.zeros(len(zero), dtype=bool)
    if gt.cls is None:  # no classes: conf = 0 marks the distractors
        return ~zero, zero
    cls = np.asarray(gt.cls)
    return ~zero & (cls == PEDESTRIAN), np.isin(cls, DISTRACTOR_CLASSES)


def describe_convention(convention: str, iou_threshold: float = 0.5) -> str:
    """One line for printed tables, e.g. ``MOT15 (gt conf=0 dropped, tracks kept; IoU 0.5)``."""
    c = check_convention(convention)
    if c is None:
        raise ValueError("describe_convention needs 'mot15' or 'mot16', not automatic")
    return f"{c.upper()} ({_SUMMARY[c]}; IoU {iou_threshold:g})"
