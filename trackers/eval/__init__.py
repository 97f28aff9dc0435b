"""Tracking metrics: CLEAR-MOT and VACE (maggio2007 §4, Table 1), OSPA/GOSPA and mean error
(feng2015 §III, Table I), identity (IDF1) and HOTA.

- :func:`evaluate` scores a whole tracks table against a ground-truth table.
- :class:`OnlineEvaluator` scores frame by frame for the recording (OSPA, cardinality, FP, FN,
  ID switches, and the indices of the boxes that are misses, false positives and switches).
- :func:`combine` scores several sequences as one (the COMBINED row).
- :func:`format_table` prints the scores of several trackers side by side.

Everything is computed here with numpy/scipy (TrackEval cannot be a dependency: every release
requires ``opencv-python``, which would replace pfscope's ``opencv-python-headless``).  CLEAR,
identity and HOTA follow TrackEval's definitions to the letter and are checked against TrackEval
in the tests when it is installed; the MOT15 convention also against py-motmetrics.  A match
needs IoU >= 0.5; which gt rows are scored and which track boxes are left out follows the
convention (:mod:`.conventions`): ``"mot15"`` drops the ``conf = 0`` gt rows and keeps every
track box, ``"mot16"`` removes the track boxes on distractors first (TrackEval's MOT16+
preprocessing); by default the gt's layout decides (MOT16 classes and visibilities: mot16).
"""

from .combine import combine
from .clear import ClearMatcher, detection_match
from .conventions import CONVENTIONS, check_convention, describe_convention, detect_convention
from .hota import ALPHAS, hota_scores
from .identity import identity_scores
from .online import FrameMetrics, OnlineEvaluator
from .ospa import DEFAULT_ALPHA, DEFAULT_C, DEFAULT_P, gospa, ospa
from .overlap import box_centers, box_iou
from .sequence import evaluate
from .table import DEFAULT_COLUMNS, format_table

__all__ = [
    "evaluate", "combine", "format_table", "OnlineEvaluator", "FrameMetrics", "DEFAULT_COLUMNS",
    "ospa", "gospa", "DEFAULT_C", "DEFAULT_P", "DEFAULT_ALPHA", "box_iou", "box_centers",
    "ClearMatcher", "detection_match", "identity_scores", "hota_scores", "ALPHAS",
    "CONVENTIONS", "check_convention", "detect_convention", "describe_convention",
]
