"""DLPF — the dual-layer particle filter of jung2013 (§2): detect and track in one loop, with
no detector scanning the frame.

One frame (stages in order):

``motion``    free parents are predicted (eqs. (2)–(5)); Lucas–Kanade motion is measured at
              them (eq. (1), :mod:`.motion`), capped (eq. (6)), zeroed inside tracked regions,
              scored (eq. (7)).  On a recorded clip the prediction and the LK call are begun
              at the end of the previous step, LK on a helper thread
              (:meth:`DLPFTracker.upcoming`: the same draws and flow).
``parents``   free parents are resampled on those weights (eq. (8)), a fraction ``explore`` is
              re-drawn uniformly (ours: without it a person who starts walking where no parent
              is would never be found; a re-drawn parent only probes the motion in the frame
              it is drawn and classifies from the next one on, but a fraction
              ``explore_classify`` of them), each
              draws a random scale (§2.1), log-uniform over
              ``scale_min..scale_max`` of the image height (0.06-0.9: any person) until the
              online perspective prior (:mod:`.scale`: person height linear in the image row,
              or a constant height while its samples sit at one depth, fitted to the
              classifier-verified boxes of confirmed tracks, nothing scene-specific) is ready;
              then a fraction ``prior_mix`` draw from it and the rest from the learnt heights
              widened ×/÷ ``prior_margin`` (ours).
``classify``  each free parent (but the re-drawn ones that only probe the motion) evaluates
              the HOG+SVM classifier on its one window
              (:mod:`.classifier`; windows snapped to a pyramid grid so that duplicates and
              shared HOG blocks are computed once per frame; the SVM is OpenCV's people SVM or
              the paper's intersection-kernel SVM, ``classifier.model``); hits above
              ``hit_threshold`` are merged by NMS; hits on an already tracked person are
              ignored.
``confirm``   hits extend candidate objects; 4 sequential detections confirm one (§2.2,
              :mod:`.confirm`); its parent leaves the search, spawns children and takes the HSV
              reference histogram (eq. (12)).
``children``  every track's children: moved by the track's Lucas-Kanade flow into this frame
              (``children.flow``, ours: the current frame's observation; the paper preset's
              AR(2) prediction from earlier estimates trails a walker by about a frame),
              histograms, Bhattacharyya distance
              (eq. (13)), weights (eq. (14)), MAP estimate (eq. (15)), resampling
              (:mod:`.children`).  A track whose MAP likelihood ``exp(−λB²)`` stays below
              ``lost_likelihood`` for ``lost_frames`` frames ends and its parent is reset (§2.2).
``tracks``    the frame's tracks.

**Overlapping tracks** (two colour trackers collapse onto the more distinctive person when
people cross): tracks are processed from the strongest (lowest MAP distance) to the weakest; the
children of a weaker track whose box overlaps a stronger track's MAP box by IoU ≥
``overlap_iou`` get zero weight (unless that would remove them all), so it cannot take the MAP
there; a track that nevertheless overlaps a stronger one for ``merge_frames`` frames is a
duplicate and ends (its parent is reset).

Stage data (paths under ``dlpf/``):

=========  ==========  ==================================================================
stage      level       items
=========  ==========  ==================================================================
motion     particles   Field ``dlpf/motion/magnitude`` (capped LK magnitude on a grid, masked),
                       Points ``dlpf/parents/predicted`` (weights: eq. (8), values ``m``)
parents    particles   Points ``dlpf/parents/free`` (values ``scale``: person height px),
                       Points ``dlpf/parents/owned`` (ids = track)
classify   particles   Boxes ``dlpf/classify/windows`` (values ``score``)
classify   clusters    Boxes ``dlpf/classify/hits`` (role detection, values ``score``)
confirm    clusters    Boxes ``dlpf/confirm/candidates`` (values ``count``)
children   particles   Points ``dlpf/children`` (ids = track, values ``weight``)
children   clusters    Boxes ``dlpf/children/map`` (ids = track, values ``B``)
(all)      tracks      Scalars ``dlpf/classify/windows``, ``dlpf/classify/hits``,
                       ``dlpf/parents/free``, ``dlpf/children/count``, ``dlpf/tracks``,
                       ``dlpf/confirm/candidates``, ``dlpf/motion/mean``,
                       ``dlpf/bhattacharyya/<id>``, ``dlpf/scale/prior_{25,50,75}``
                       (the scale prior's person height at 25/50/75 % of the image height,
                       once it is ready); Events ``dlpf`` (confirmed, ended)
=========  ==========  ==================================================================

Output: the tracks at each frame (zero lag); with ``backfill`` a newly confirmed track also
reports the boxes of its 3 earlier detections as rows of their frames.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np

from ..api import Rows, StepResult, register
from ..detect._common import check_image, to_bgr, to_gray
from ..eval.overlap import box_iou
from ..params import param, part, to_dict
from ..report import Boxes, Field, Points, StageLog
from ..smc import ParticleSet, logsumexp, resample_indices
from ..types import Detections, Frame, TrackSet
from . import children as ch
from ._child_kernels import compile_kernels as compile_child_kernels
from . import motion as mo
from . import parents as pa
from .classifier import (HOGWindowClassifier, load_classifier, opencv_threads, person_boxes,
                         window_boxes)
from .confirm import Confirmer
from .scale import ScalePrior


@dataclass(frozen=True)
class MotionParams:
    """LK motion measurement and its likelihood (jung2013 §2.1)."""

    y0: float = param(5.0, "target motion magnitude y0 (px/frame) of eq. (7)", paper="jung2013 §2.1")
    cap: float = param(5.0, "maximum of the motion magnitude M(x, y), eq. (6)", paper="jung2013 §2.1")
    R: float = param(1.0, "standard deviation R of the motion noise in eq. (7) (only its "
                          "constant term; cancels in the 'exp' reading)")
    likelihood: str = param("exp", "reading of eqs. (7)-(8): 'exp' (weights exp(L)), 'shift' "
                                   "(L - min L), 'literal' (L / sum L); see dlpf.motion")
    lk_window: int = param(15, "Lucas-Kanade window side (px), the region Omega of eq. (1)")
    lk_levels: int = param(3, "pyramid levels of the LK solver (for motions beyond the window)")
    mask_margin: float = param(0.1, "tracked regions grown by this fraction of their size per "
                                    "side before their motion is zeroed (§2.2)")
    field_step: int = param(16, "grid spacing (px) of the motion-magnitude image in recordings")

    def __post_init__(self):
        if self.likelihood not in mo.READINGS:
            raise ValueError(f"likelihood must be one of {', '.join(mo.READINGS)}, "
                             f"got {self.likelihood!r}")
        if not (self.cap > 0 and self.R > 0 and self.lk_window >= 3 and self.field_step >= 2):
            raise ValueError("need cap > 0, R > 0, lk_window >= 3, field_step >= 2")


@dataclass(frozen=True)
class ParentParams:
    """The first layer (jung2013 §2.1)."""

    n: int = param(300, "number of parent particles (the paper gives no number; 300 keeps the "
                        "classifier cost near 300 windows/frame, ~10% of an exhaustive scan)")
    q_pos: float = param(6.0, "std of the position process noise Q_pos (px), eq. (5)")
    q_vel: float = param(1.0, "std of the velocity process noise Q_vel (px/frame), eq. (5)")
    velocity_from_flow: bool = param(True, "set a parent's velocity to the LK flow it measured "
                                           "(ours: the paper does not say how v is updated)")
    explore: float = param(0.2, "fraction of free parents re-drawn uniformly each frame (ours)")
    explore_classify: float = param(0.5, "fraction of the re-drawn parents that also classify "
                                         "their window in the frame they are drawn (ours; the "
                                         "others only probe the motion there and classify from "
                                         "the next frame on, if resampling keeps them: a lone "
                                         "random window costs ~100 HOG blocks that no other "
                                         "window shares, all of them two thirds of the HOG at "
                                         "explore 0.2; 1 = every free parent classifies)")
    foreground: float = param(0.05, "a free parent classifies its window only if at least this "
                                    "fraction of the window's person box is foreground "
                                    "(dlpf.motion.Foreground: MOG2 on the frame shrunk 4x); "
                                    "the others carry the frame's median margin like the "
                                    "parents that only probe the motion (ours: windows on the "
                                    "learnt background cost HOG blocks and find nobody; "
                                    "0 = every window classifies, no background model)")
    foreground_probe: float = param(0.1, "the share of the windows parents.foreground gates out "
                                         "that classify anyway, drawn at random each frame (ours: "
                                         "a person who has stood still since the first frame is "
                                         "background to the model, and only these windows can "
                                         "still find them; 0 = none)")
    scheme: str = param("multinomial", "resampling scheme of eq. (8) (i.i.d. uniforms u_i = "
                                       "multinomial)", paper="jung2013 §2.1")
    score_weight: float = param(1.0, "beta: a parent's resampling log-weight also gets beta x its "
                                     "last SVM margin (clipped to [-3, 3]) so that descendants of "
                                     "near-misses search around them (ours; 0 = the paper: motion "
                                     "only)")
    scale_jitter: float = param(0.1, "std of the log-scale random walk of a resampled parent "
                                     "(ours; 0 = the paper: a fresh random scale every frame)")
    scale_min: float = param(0.06, "smallest person height a parent looks for before the scale "
                                   "prior has learnt the scene's range, fraction of the image "
                                   "height (768x576: 35 px)")
    scale_max: float = param(0.9, "largest person height searched before the scale prior has "
                                  "learnt the scene's range, fraction of the image height")
    prior_mix: float = param(0.7, "fraction of free parents whose scale is drawn from the online "
                                  "perspective prior (height vs image row, fitted to verified "
                                  "track boxes; dlpf.scale) once it is ready (ours; 0 = the "
                                  "paper's flat random scale)")
    prior_forget: float = param(0.995, "forgetting factor per sample of the scale prior's fit")
    prior_min_samples: int = param(8, "verified boxes the scale prior needs before it is used")
    prior_margin: float = param(2.0, "once the prior is ready, the flat draw spans its learnt "
                                     "heights (top to bottom row) divided / multiplied by this")

    def __post_init__(self):
        if self.n < 1 or not 0 <= self.explore <= 1 or not 0 < self.scale_min <= self.scale_max:
            raise ValueError("need n >= 1, 0 <= explore <= 1, 0 < scale_min <= scale_max")
        if not 0 <= self.explore_classify <= 1:
            raise ValueError("need 0 <= explore_classify <= 1")
        if not 0 <= self.prior_mix <= 1:
            raise ValueError("need 0 <= prior_mix <= 1")
        if not 0 <= self.foreground <= 1:
            raise ValueError("need 0 <= foreground <= 1")
        if not 0 <= self.foreground_probe <= 1:
            raise ValueError("need 0 <= foreground_probe <= 1")


@dataclass(frozen=True)
class ClassifierParams:
    """HOG + linear SVM on each parent's window (jung2013 §2.1; OpenCV's Dalal-Triggs SVM)."""

    hit_threshold: float = param(-0.3, "SVM margin above which a window is a detection (OpenCV's "
                                       "detectMultiScale uses 0; chosen on PETS09 frames 1-400: "
                                       "confirmation and re-verification filter the extra hits)")
    nms_iou: float = param(0.3, "hits overlapping a stronger hit by this IoU are merged into it")
    verify_windows: int = param(5, "windows each track's own parent classifies around the "
                                   "track per frame; the best hit supports it and re-seeds part "
                                   "of its children (ours; 0 = the paper: colour only)")
    tracked_iou: float = param(0.3, "hits overlapping a live track by this IoU are ignored "
                                    "(the person is already tracked)")
    mode: str = param("pyramid", "how window descriptors are computed: 'pyramid' (windows "
                                 "snapped to the 8-px grid of pyramid levels scale_step apart; "
                                 "duplicates and shared HOG blocks computed once per frame) or "
                                 "'window' (each window resampled to 64x128 on its own); see "
                                 "dlpf.classifier")
    scale_step: float = param(1.1, "scale ratio between pyramid levels in 'pyramid' mode (the "
                                    "window scale is rounded to a level: within +-5%)")
    spread: bool = param(True, "in 'pyramid' mode, parents' windows that snap onto the same "
                               "node are moved to neighbouring nodes (copies of a resampled "
                               "parent would otherwise be one window)")
    exact_verify: bool = param(True, "tracks' verification windows are scored unsnapped, each "
                                     "resampled on its own (a few per track), in 'pyramid' "
                                     "mode too")
    threads: int = param(2, "threads that compute the pyramid's HOG blocks ('pyramid' mode; "
                            "each region's blocks by one thread, so the scores and the tracks "
                            "are the same for any value; 1 = none; more than 1: OpenCV's own "
                            "threads are off during the step)")
    model: str = param("", "classifier file from 'pfscope train-classifier' (an intersection-"
                           "kernel SVM, jung2013 §2.1); empty: OpenCV's pre-trained people SVM.  "
                           "Its margins are on another scale: use it with hit_threshold=0 "
                           "(PETS09: chosen from {0, 0.5} on frames 321-400, held out of a "
                           "model trained on 1-320)")

    def __post_init__(self):
        if self.mode not in HOGWindowClassifier.MODES:
            raise ValueError(f"classifier.mode must be one of "
                             f"{', '.join(HOGWindowClassifier.MODES)}, got {self.mode!r}")
        if not self.scale_step > 1.0:
            raise ValueError(f"classifier.scale_step must be > 1, got {self.scale_step}")
        if self.threads < 1:
            raise ValueError(f"classifier.threads must be >= 1, got {self.threads}")


@dataclass(frozen=True)
class ConfirmParams:
    """Confirmation (jung2013 §2.2)."""

    count: int = param(4, "sequential detections that confirm an object", paper="jung2013 §2.2")
    max_gap: int = param(1, "frames without a hit allowed between two detections of a candidate "
                            "(0: strictly consecutive; ours: 1, since a random parent may miss)")
    match_iou: float = param(0.3, "IoU for a hit to extend a candidate")
    backfill: bool = param(True, "a confirmed track also reports its earlier detections")


@dataclass(frozen=True)
class ChildParams:
    """The second layer: colour particle filter per track (jung2013 §2.2; Pérez et al. 2002)."""

    n: int = param(100, "child particles per track")
    Mh: int = param(10, "hue bins (M = Mh*Ms + Mv, eq. (12))", paper="Pérez et al. 2002")
    Ms: int = param(10, "saturation bins", paper="Pérez et al. 2002")
    Mv: int = param(10, "value-only bins", paper="Pérez et al. 2002")
    s_min: float = param(0.1, "pixels with saturation below this go to the value bins")
    v_min: float = param(0.2, "pixels with value below this go to the value bins")
    grid_x: int = param(8, "sample columns of the object region R(x), eq. (12)")
    grid_y: int = param(16, "sample rows of the object region R(x)")
    lam: float = param(20.0, "lambda of eq. (14), w ~ exp(-lambda B^2)", paper="Pérez et al. 2002")
    damping: float = param(0.7, "AR(2) velocity factor d: x_k = x_k-1 + d (x_k-1 - x_k-2) + w")
    pos_sigma: float = param(0.04, "position noise std, fraction of the box height")
    scale_sigma: float = param(0.02, "log-height noise std")
    estimate: str = param("mean", "state estimate: 'map' (eq. (15), the paper) or 'mean' "
                                  "(weighted mean; ours: MAP of 100 colour particles jitters, "
                                  "a third of its boxes were below IoU 0.5 on PETS09 1-400)")
    inject: float = param(0.2, "fraction of a track's children re-seeded at its parent's best "
                               "classifier hit (ours; see classifier.verify_windows)")
    support_sigma: float = param(0.15, "children also weighted by N(centre; parent's best hit, "
                                       "(sigma h)^2) when the track's parent has a hit (ours; 0: "
                                       "colour only, the paper)")
    unsupported_frames: int = param(8, "a track whose parent finds no hit for this many frames "
                                       "ends (ours; 0: never, the paper)")
    ref_update: float = param(0.1, "alpha: a track whose parent has a classifier hit blends the "
                                   "hit box's histogram into its reference, q* <- (1 - alpha) q* + "
                                   "alpha q (ours; 0 = the paper: q* fixed at confirmation)")
    snap: float = param(0.5, "a track whose parent has a classifier hit reports (1 - snap) x its "
                             "estimate + snap x the hit box (ours; 0 = the paper's eq. (15))")
    lost_likelihood: float = param(0.15, "a frame is 'low' when exp(-lambda B_MAP^2) < this")
    lost_frames: int = param(5, "consecutive low frames that end a track (its parent is reset)")
    overlap_iou: float = param(0.4, "children of a weaker track overlapping a stronger track's "
                                    "box by this IoU get zero weight")
    merge_frames: int = param(3, "frames a weaker track may overlap a stronger one before it ends")
    flow: bool = param(True, "children move by the track's Lucas-Kanade flow measured from the "
                             "last frame to this one (median over a grid inside its box), the "
                             "current frame's observation, instead of the AR(2) velocity of the "
                             "earlier estimates, which trails a walking person by about a frame "
                             "(ours; false = the AR(2) prediction)")

    def __post_init__(self):
        if self.estimate not in ("map", "mean"):
            raise ValueError(f"estimate must be 'map' or 'mean', got {self.estimate!r}")
        if min(self.n, self.Mh, self.Ms, self.Mv, self.grid_x, self.grid_y, self.lost_frames) < 1:
            raise ValueError("child counts, bins, grid and lost_frames must be >= 1")
        if max(self.Mh, self.Ms, self.Mv) > 127:
            raise ValueError("at most 127 bins per HSV channel (Mh, Ms, Mv)")


@dataclass(frozen=True)
class DLPFParams:
    """DLPF: motion, parents, classifier, confirmation, children."""

    motion: MotionParams = part(MotionParams, "LK motion measurement (§2.1)")
    parents: ParentParams = part(ParentParams, "parent particles (§2.1)")
    classifier: ClassifierParams = part(ClassifierParams, "HOG + SVM per window (§2.1)")
    confirm: ConfirmParams = part(ConfirmParams, "confirmation (§2.2)")
    children: ChildParams = part(ChildParams, "child particles (§2.2)")


#: where a track's flow is measured, relative to its box: 4 x 8 points over the central half of
#: its width (the person, not the background beside them) and 80 % of its height
_FLOW_GRID = np.stack([g.ravel() for g in np.meshgrid(np.linspace(0.3, 0.7, 4),
                                                      np.linspace(0.1, 0.9, 8))], axis=1)


@dataclass
class _Track:
    tid: int
    parent: int                  # index of its parent particle
    ref: np.ndarray              # reference histogram q* (M,), taken at confirmation
    aspect: float                # box width / height, from the confirmed box
    kids: ParticleSet            # states (cx, cy, h, cx', cy', h'), labels = tid
    box: np.ndarray              # current estimate (x, y, w, h)
    velocity: np.ndarray         # (2,) px/frame of the estimate
    B: float = 0.0               # Bhattacharyya distance of the estimate
    low: int = 0                 # consecutive low-likelihood frames
    unsupported: int = 0         # consecutive frames without a parent hit
    support: Optional[np.ndarray] = None  # this frame's best classifier hit of its parent
    overlap: int = 0             # consecutive frames overlapping a stronger track
    shift: Optional[np.ndarray] = None  # this frame's measured LK motion of its box (children.flow)


#: The settings DLPF landed with (before the scale prior etc.): ``--preset landed`` reproduces
#: the first measurement (PETS09 401-795: MOTA 0.21, IDF1 0.22).
LANDED = DLPFParams(parents=ParentParams(prior_mix=0.0, foreground=0.0),
                    classifier=ClassifierParams(hit_threshold=0.0),
                    children=ChildParams(estimate="map", ref_update=0.0, snap=0.0))


#: ``--preset paper``: jung2013 as published.  Each field below is one of our additions turned
#: off (its value in the paper's reading) — and these are the *only* fields in which the paper
#: preset differs from the default (tests/test_dlpf.py checks that).  The classifier stays
#: OpenCV's linear people SVM unless ``classifier.model`` names an IKSVM from
#: ``pfscope train-classifier`` (the paper's classifier needs training data we do not ship).
PAPER_CHANGES: dict[str, object] = {
    "parents.velocity_from_flow": False,   # eq. (4): constant velocity, v moved by noise only
    "parents.explore": 0.0,                # eq. (8): resampled on motion only, no re-draws
    "parents.score_weight": 0.0,           # eq. (8): motion weights only
    "parents.scale_jitter": 0.0,           # §2.1: a fresh random scale every frame
    "parents.prior_mix": 0.0,              # §2.1: no scale prior (flat random scale)
    "parents.foreground": 0.0,             # §2.1: every free parent classifies its window
    "parents.foreground_probe": 0.0,       # (no gate: nothing to probe)
    "classifier.hit_threshold": 0.0,       # the SVM's sign
    "classifier.verify_windows": 0,        # §2.2: a confirmed object is tracked by colour only
    "confirm.max_gap": 0,                  # §2.2: 4 *sequential* detections
    "confirm.backfill": False,             # tracks start at confirmation
    "children.estimate": "map",            # eq. (15): MAP child
    "children.flow": False,                # children's AR(2) prediction, no measured flow
    "children.inject": 0.0,                # no re-seeding at classifier hits
    "children.support_sigma": 0.0,         # eq. (14): colour weights only
    "children.unsupported_frames": 0,      # a track ends only when its colour is lost
    "children.ref_update": 0.0,            # §2.2: q* taken at k0 and kept
    "children.snap": 0.0,                  # eq. (15) reported as is
    "children.merge_frames": 1_000_000,    # no duplicate-track removal (ours)
    "children.overlap_iou": 1.01,          # no overlap suppression between tracks (ours)
}


def _with_changes(base, changes: dict):
    from dataclasses import replace

    parts: dict[str, dict] = {}
    for key, value in changes.items():
        part, name = key.split(".")
        parts.setdefault(part, {})[name] = value
    return replace(base, **{k: replace(getattr(base, k), **v) for k, v in parts.items()})


PAPER = _with_changes(DLPFParams(), PAPER_CHANGES)


_HELPER: list[ThreadPoolExecutor] = []


def _helper() -> ThreadPoolExecutor:
    """The one thread :meth:`DLPFTracker.upcoming` measures the next frame's motion on."""
    if not _HELPER:
        _HELPER.append(ThreadPoolExecutor(1, thread_name_prefix="pfscope-dlpf-motion"))
    return _HELPER[0]


@dataclass
class _Ahead:
    """The next frame's motion stage begun at the end of a step (:meth:`DLPFTracker.upcoming`):
    its free parents and their prediction (drawn then: the rng's next draws either way) and
    the helper's ``(image, grey, (flow, ok) or None)`` of that frame."""

    frame: Frame
    free: np.ndarray
    pred: np.ndarray
    images: Future


@register(presets={"default": DLPFParams(), "paper": PAPER, "landed": LANDED})
class DLPFTracker:
    """DLPF (jung2013): parents on LK motion classify one HOG window each; confirmed people are
    tracked by HSV child particles."""

    name = "dlpf"
    paper = "jung2013"
    stages = ("motion", "parents", "classify", "confirm", "children", "tracks")
    needs_detections = False
    needs_image = True
    Params = DLPFParams
    #: the background model of ``parents.foreground`` (built at the first frame)
    _foreground: Optional[mo.Foreground] = None

    def __init__(self, params: Optional[DLPFParams] = None, *,
                 rng: Optional[np.random.Generator] = None,
                 classifier: Optional[HOGWindowClassifier] = None):
        self.params = params or DLPFParams()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        cp = self.params.classifier
        self.classifier = classifier or load_classifier(cp.model, mode=cp.mode,
                                                        scale_step=cp.scale_step,
                                                        threads=cp.threads)
        compile_child_kernels()     # the children's histograms: before any frame, not at the
        c = self.params.confirm       # first confirmation (a load from numba's cache once built)
        self.confirmer = Confirmer(c.count, c.max_gap, c.match_iou)
        self.parents: Optional[ParticleSet] = None
        self.tracks: list[_Track] = []
        self._prev_grey: Optional[np.ndarray] = None
        self._size: Optional[tuple[int, int]] = None
        self._next: Optional[Frame] = None       # upcoming(): the frame the next step gets
        self._ahead: Optional[_Ahead] = None     # its motion, begun on the helper thread
        self._next_id = 1
        self.scale_prior: Optional[ScalePrior] = None   # built at the first frame (needs H)
        self.windows_evaluated = 0   # running total, for efficiency figures
        self.frames_seen = 0

    # ------------------------------------------------------------------ helpers
    def _heights(self, H: int) -> tuple[float, float]:
        p = self.params.parents
        return p.scale_min * H, p.scale_max * H

    def predicted_track_boxes(self) -> np.ndarray:
        """Live tracks' boxes moved one frame along their velocity (the regions whose motion is
        masked and whose hits are ignored this frame)."""
        if not self.tracks:
            return np.zeros((0, 4))
        b = np.array([t.box for t in self.tracks])
        b[:, :2] += self._shifts()
        return b

    def _shifts(self) -> np.ndarray:
        """(T, 2) each live track's motion into this frame: its measured flow (children.flow)
        when it has one, else its velocity."""
        return np.array([t.shift if t.shift is not None else t.velocity
                         for t in self.tracks]).reshape(-1, 2)

    def _track_flow_points(self) -> np.ndarray:
        """(T·32, 2) the points whose Lucas-Kanade flow, last frame → this one, gives each
        track's ``shift``: a 4 × 8 grid over the central half of its box's width (the person,
        not the background beside them); none when ``children.flow`` is off."""
        if not self.tracks or self._prev_grey is None or not self.params.children.flow:
            return np.zeros((0, 2))
        b = np.array([t.box for t in self.tracks])
        return (b[:, None, :2] + _FLOW_GRID[None] * b[:, None, 2:]).reshape(-1, 2)

    def _set_track_flow(self, flow: np.ndarray, ok: np.ndarray) -> None:
        """``t.shift`` of every track: the median flow of its grid points (None when fewer than
        4 of them were tracked, or without flow points)."""
        for t in self.tracks:
            t.shift = None
        if not len(flow):
            return
        flow, ok = flow.reshape(len(self.tracks), -1, 2), ok.reshape(len(self.tracks), -1)
        for k, t in enumerate(self.tracks):
            if ok[k].sum() >= 4:
                t.shift = np.median(flow[k][ok[k]], axis=0)

    def _end(self, track: _Track, why: str, frame: int, log: StageLog) -> None:
        assert self.parents is not None and self._size is not None
        W, H = self._size
        lo, hi = self._heights(H)
        self.parents = pa.reset(self.parents, np.array([track.parent]), W, H, lo, hi, self.rng)
        log.event("dlpf", f"frame {frame}: track {track.tid} ended ({why}); parent "
                          f"{track.parent} reset")

    # ------------------------------------------------------------------ the step
    def upcoming(self, frame: Frame) -> None:
        """The pipeline's look-ahead on a recorded clip (:func:`pfscope.trackers.pipeline.run`):
        ``frame`` is the one the next :meth:`step` gets.  At the end of this step the free
        parents' prediction into it is drawn (the rng's next draws either way) and its grey
        image and the Lucas-Kanade call of its motion stage (~a fifth of the step; OpenCV
        releases the GIL) run on a helper thread while the recording and the scoring of this
        frame go on: the same flow, the same draws in the same order, the same tracks."""
        self._next = frame

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult:
        nxt, self._next = self._next, None
        log = StageLog(self.stages, level)
        # the motion stage starts here: its Lucas-Kanade call, begun on the helper at the end
        # of the last step (upcoming), is what the step waits for first (about half of the LK's
        # wall: the rest overlaps the recording of the last frame); clocked outside any stage,
        # that wait was the profile's "other"
        log.stage("motion")
        # the helper's work for this frame is collected first: OpenCV's thread setting below
        # is process-wide, and is never changed while the helper's LK runs
        if self._ahead is not None:
            self._ahead.images.exception()         # wait (an error: redone inline, below)
        # with classifier.threads > 1 the step spreads its work over its own threads; OpenCV's
        # internal ones (warpAffine, LK, colour conversions split over row bands) then only
        # contend with them for the same cores: off for the step, restored after it (results
        # do not depend on it; tests/test_dlpf.py)
        if self.params.classifier.threads <= 1:
            res = self._step(frame, log)
        else:
            with opencv_threads(1):
                res = self._step(frame, log)
        if nxt is not None and nxt is not frame:
            self._look_ahead(nxt)
        return res

    def _look_ahead(self, nxt: Frame) -> None:
        """Begin ``nxt``'s motion stage: the free parents' prediction (rng) now, its grey image
        and the one Lucas-Kanade call on the helper thread."""
        P = self.params
        if self.parents is None or self._size is None or self._prev_grey is None:
            return
        assert self.parents.labels is not None
        W, H = self._size
        free = np.flatnonzero(self.parents.labels == 0)
        pred = pa.predict(self.parents.states[free], P.parents.q_pos, P.parents.q_vel, self.rng,
                          W, H)
        pts = np.concatenate([self._track_flow_points(), pred[:, :2]])
        self._ahead = _Ahead(nxt, free, pred,
                             _helper().submit(_motion_images, nxt, self._prev_grey, pts,
                                              P.motion.lk_window, P.motion.lk_levels))

    def _step(self, frame: Frame, log: StageLog) -> StepResult:
        """The step's stages; ``log`` is in its motion stage (begun by :meth:`step`)."""
        P = self.params
        ahead, self._ahead = self._ahead, None
        lk = None     # the helper's flow and status of this frame's motion points
        if ahead is not None and ahead.frame is frame and ahead.images.exception() is None:
            img, grey, lk = ahead.images.result()
        else:         # no look-ahead, or it failed: the same error is raised here
            img = to_bgr(check_image(frame, "dlpf"))
            grey = to_gray(img)
        H, W = grey.shape
        if self._size is not None and self._size != (W, H):
            raise ValueError(f"frame {frame.index}: dlpf: frame size changed from "
                             f"{self._size[0]}x{self._size[1]} to {W}x{H}")
        self._size = (W, H)
        lo, hi = self._heights(H)
        rng = self.rng
        if self.parents is None:
            self.parents = pa.init_parents(P.parents.n, W, H, lo, hi, rng)
        if self.scale_prior is None:
            self.scale_prior = ScalePrior(H, forget=P.parents.prior_forget,
                                          min_samples=P.parents.prior_min_samples)
        prior = self.scale_prior
        rows: Rows = []
        # ---------------------------------------------------------------- motion (eqs. 1-7)
        # (begun in step(): the stage clock covers the prediction and the Lucas-Kanade call,
        # its largest cost, ~400 points/frame, or the wait for the helper's)
        labels = self.parents.labels
        assert labels is not None
        if ahead is not None:   # drawn at the end of the last step (upcoming)
            free, pred = ahead.free, ahead.pred
        else:
            free = np.flatnonzero(labels == 0)
            pred = pa.predict(self.parents.states[free], P.parents.q_pos, P.parents.q_vel, rng,
                              W, H)
        # one Lucas-Kanade call for the tracks' flow grids and the free parents (eq. (1))
        tpts = self._track_flow_points()
        if lk is not None:      # measured on the helper thread (upcoming)
            flow, ok = lk
        elif self._prev_grey is not None and len(free) + len(tpts):
            # the step's own threads are idle here: OpenCV may split the points over them
            # (each point's flow is computed the same way whatever the thread count)
            with opencv_threads(max(cv2.getNumThreads(), P.classifier.threads)):
                flow, ok = mo.lk_flow(self._prev_grey, grey,
                                      np.concatenate([tpts, pred[:, :2]]),
                                      win=P.motion.lk_window, levels=P.motion.lk_levels)
        else:
            flow, ok = np.zeros((len(tpts) + len(free), 2)), np.zeros(len(tpts) + len(free), bool)
        if P.parents.foreground > 0:    # learn this frame's background (classify's gate)
            if self._foreground is None:
                self._foreground = mo.Foreground()
            self._foreground.update(grey)
        self._set_track_flow(flow[:len(tpts)], ok[:len(tpts)])
        flow, ok = flow[len(tpts):], ok[len(tpts):]
        tboxes = self.predicted_track_boxes()
        tracked = mo.inside_boxes(pred[:, :2], tboxes, P.motion.mask_margin)
        m = mo.magnitude(flow, P.motion.cap)
        m[tracked] = 0.0                                          # §2.2: masked motion
        L = mo.log_likelihood(m, P.motion.y0, P.motion.R)         # eq. (7)
        lw = mo.resampling_log_weights(L, P.motion.likelihood)    # eq. (8) normalisation
        assert self.parents.extra is not None
        if P.parents.score_weight:
            lw = lw + P.parents.score_weight * np.clip(self.parents.extra[free, 1], -3.0, 3.0)
            lw = lw - logsumexp(lw)
        if P.parents.velocity_from_flow:
            use = ok & ~tracked
            pred[use, 2:] = flow[use]
            pred[tracked, 2:] = 0.0
        log.scalar("dlpf/motion/mean", float(m.mean()) if len(m) else 0.0)
        if log.wants("particles"):
            log.add(Field("dlpf/motion/magnitude", mo.motion_field(
                self._prev_grey, grey, P.motion.field_step, P.motion.cap,
                win=P.motion.lk_window, levels=P.motion.lk_levels, track_boxes=tboxes,
                margin=P.motion.mask_margin), unit="px/frame", vmin=0.0, vmax=P.motion.cap))
            log.add(Points("dlpf/parents/predicted", pred[:, :2], weights=np.exp(lw),
                           values={"m": m}))

        # ---------------------------------------------------------------- parents (eq. 8)
        log.stage("parents")
        anc = resample_indices(lw, len(free), rng, P.parents.scheme) if len(free) else \
            np.zeros(0, dtype=np.int64)
        new = pred[anc]
        n_explore = int(round(P.parents.explore * len(free)))
        classify = np.ones(len(free), dtype=bool)      # the free parents that classify
        if n_explore:
            pick = rng.choice(len(free), n_explore, replace=False)
            new[pick] = pa.uniform_states(n_explore, W, H, rng)
            # pick is a random subset in random order: its first part classifies
            classify[pick[int(round(P.parents.explore_classify * n_explore)):]] = False
        if P.parents.prior_mix > 0:  # the learnt range narrows the flat draw too (ours)
            lo, hi = prior.bounds(lo, hi, P.parents.prior_margin)
        heights = pa.draw_heights(len(free), lo, hi, rng)
        if P.parents.scale_jitter > 0:  # inherited scale, random walk (ours; §2.1 redraws)
            inherited = self.parents.extra[free[anc], 0] * np.exp(
                rng.normal(0.0, P.parents.scale_jitter, len(free)))
            fresh = np.zeros(len(free), dtype=bool)
            if n_explore:
                fresh[pick] = True
            heights = np.where(fresh, heights, np.clip(inherited, lo, hi))
        if P.parents.prior_mix > 0 and prior.ready():  # perspective prior (ours)
            redraw = rng.random(len(free)) < P.parents.prior_mix
            heights = np.where(redraw, prior.draw(new[:, 1], lo, hi, 1.0, rng),
                               heights)
        states = self.parents.states.copy()
        extra = self.parents.extra.copy()
        states[free] = new
        extra[free, 0] = heights
        self.parents = ParticleSet(states, np.full(len(states), -np.log(len(states))),
                                   labels.copy(), extra)
        log.scalar("dlpf/parents/free", len(free))
        if prior.ready():  # the learnt perspective: expected person height at 3 image rows
            for frac in (0.25, 0.5, 0.75):
                log.scalar(f"dlpf/scale/prior_{int(frac * 100)}",
                           float(prior.mean_height(np.array([frac * H]))[0]))
        if log.wants("particles"):
            log.add(Points("dlpf/parents/free", new[:, :2], values={"scale": heights}))
            owned = np.flatnonzero(labels != 0)
            log.add(Points("dlpf/parents/owned", states[owned, :2], ids=labels[owned],
                           id_kind="track"))

        # ---------------------------------------------------------------- classify (one window each)
        log.stage("classify")
        # the windows the classifier scores ('pyramid' mode: snapped to its level grid); the
        # parents just re-drawn only probe the motion this frame (parents.explore_classify)
        cls = np.flatnonzero(classify)
        wins = window_boxes(new[cls, :2], heights[cls])
        if self._foreground is not None and P.parents.foreground > 0:
            # no window on the learnt background: nobody there to find (parents.foreground)
            keep = self._foreground.fraction(person_boxes(wins)) >= P.parents.foreground
            if P.parents.foreground_probe > 0 and not keep.all():
                # a few gated windows still look: a person standing still since frame 1 is
                # background to the model, and only these can find them
                keep |= rng.random(len(keep)) < P.parents.foreground_probe
            cls, wins = cls[keep], wins[keep]
        windows = self.classifier.snap(wins, rng if P.classifier.spread else None)
        vwin, vtrack = self._verify_windows()
        # a track's few verification windows localise it: scored exactly (unsnapped), since
        # the hit box pulls the track's box (children.snap) and feeds the scale prior
        both = getattr(self.classifier, "score_with_exact", None)
        if P.classifier.exact_verify and both is not None:   # the two overlap on two threads
            scores, vscores = both(grey, windows, vwin)
        else:
            scores = self.classifier.score(grey, windows)
            vscores = self.classifier.score(grey, vwin, exact=P.classifier.exact_verify)
        all_scores = np.concatenate([scores, vscores])
        # a parent that did not classify gets the frame's median margin: its resampling weight
        # (parents.score_weight) neither favours nor penalises it against a typical window
        margins = np.full(len(free), float(np.median(scores)) if len(scores) else 0.0)
        margins[cls] = scores
        self.parents.extra[free, 1] = margins
        self._support(vwin, vscores, vtrack)
        sup = [t for t in self.tracks if t.support is not None]
        if sup:  # (only tracks that moved teach it: dlpf.scale)
            prior.add(np.array([t.support for t in sup]), [t.tid for t in sup])
        self.windows_evaluated += len(all_scores)
        self.frames_seen += 1
        hit = np.flatnonzero(scores > P.classifier.hit_threshold)
        hboxes = person_boxes(windows[hit])
        hscores = scores[hit]
        hparents = free[cls[hit]]
        if len(hit) > 1 and P.classifier.nms_iou < 1.0:
            shifted = hscores - hscores.min() + 1.0
            keep = np.asarray(cv2.dnn.NMSBoxes(hboxes.tolist(), shifted.tolist(), 0.0,
                                               P.classifier.nms_iou), dtype=np.int64).reshape(-1)
            hboxes, hscores, hparents = hboxes[keep], hscores[keep], hparents[keep]
        if len(hboxes) and len(tboxes):
            fresh = box_iou(hboxes, tboxes).max(axis=1) < P.classifier.tracked_iou
            hboxes, hscores, hparents = hboxes[fresh], hscores[fresh], hparents[fresh]
        log.scalar("dlpf/classify/windows", len(all_scores))
        log.scalar("dlpf/classify/hits", len(hboxes))
        if log.wants("particles"):
            log.add(Boxes("dlpf/classify/windows", windows, values={"score": scores}))
            log.add(Boxes("dlpf/classify/verify", vwin, ids=vtrack, id_kind="track",
                          values={"score": vscores}))
        if log.wants("clusters"):
            log.add(Boxes("dlpf/classify/hits", hboxes, role="detection",
                          values={"score": hscores}))

        # ---------------------------------------------------------------- confirm (§2.2)
        log.stage("confirm")
        self.confirmer.forget_inside(tboxes, P.classifier.tracked_iou)
        born = []
        for cand in self.confirmer.step(frame.index, hboxes, hscores, hparents):
            tr = self._spawn(img, cand.box, cand.parent)
            prior.add(np.array([b for _, b in cand.history]), [tr.tid] * len(cand.history))
            born.append(tr)
            log.event("dlpf", f"frame {frame.index}: track {tr.tid} confirmed after "
                              f"{cand.count} detections (parent {cand.parent})")
            if P.confirm.backfill:
                rows.extend((f, TrackSet([tr.tid], [b])) for f, b in cand.history[:-1])
        log.scalar("dlpf/confirm/candidates", len(self.confirmer.candidates))
        if log.wants("clusters"):
            cs = self.confirmer.candidates
            log.add(Boxes("dlpf/confirm/candidates", np.array([c.box for c in cs]).reshape(-1, 4),
                          values={"count": [c.count for c in cs]}))

        # ---------------------------------------------------------------- children (eqs. 12-15)
        log.stage("children")
        self._update_children(img, frame.index, log)
        self.tracks.extend(born)
        # an owned parent follows its track (it "generates" the children, §2.2)
        if self.tracks:
            st = self.parents.states.copy()
            for t in self.tracks:
                st[t.parent, :2] = t.box[:2] + t.box[2:] / 2
                st[t.parent, 2:] = t.velocity
            self.parents = ParticleSet(st, self.parents.log_weights, self.parents.labels,
                                       self.parents.extra)
        n_kids = sum(len(t.kids) for t in self.tracks)
        log.scalar("dlpf/children/count", n_kids)
        for t in self.tracks:
            log.scalar(f"dlpf/bhattacharyya/{t.tid}", t.B)
        if self.tracks and log.wants("particles"):
            kid_states = np.concatenate([t.kids.states for t in self.tracks])
            kid_ids = np.concatenate([t.kids.labels for t in self.tracks])
            kid_w = np.concatenate([np.exp(t.kids.log_weights) for t in self.tracks])
            log.add(Points("dlpf/children", kid_states[:, :2], ids=kid_ids, id_kind="track",
                           values={"weight": kid_w}))
        if log.wants("clusters"):
            log.add(Boxes("dlpf/children/map", np.array([t.box for t in self.tracks]).reshape(-1, 4),
                          ids=[t.tid for t in self.tracks], id_kind="track",
                          values={"B": [t.B for t in self.tracks]}))

        # ---------------------------------------------------------------- tracks
        log.stage("tracks")
        ts = TrackSet([t.tid for t in self.tracks],
                      np.array([t.box for t in self.tracks]).reshape(-1, 4))
        log.scalar("dlpf/tracks", len(ts))
        rows.append((frame.index, ts))
        self._prev_grey = grey
        return StepResult(ts, rows, log.result())

    def _verify_windows(self) -> tuple[np.ndarray, np.ndarray]:
        """Windows each track's parent classifies around its predicted box: the box itself and
        ``verify_windows − 1`` jittered copies (position 10% of the height, scale 10%)."""
        k = self.params.classifier.verify_windows
        tboxes = np.array([t.box for t in self.tracks]).reshape(-1, 4)
        tboxes[:, :2] += self._shifts()
        if k <= 0 or len(tboxes) == 0:
            return np.zeros((0, 4)), np.zeros(0, dtype=np.int64)
        n = len(tboxes)
        c = np.repeat(tboxes[:, :2] + tboxes[:, 2:] / 2, k, axis=0)
        h = np.repeat(tboxes[:, 3], k)
        jit = np.ones((n, k), dtype=bool)
        jit[:, 0] = False
        jit = jit.ravel()
        m = int(jit.sum())
        c[jit] += self.rng.normal(0.0, 0.1, (m, 2)) * h[jit, None]
        h[jit] *= np.exp(self.rng.normal(0.0, 0.1, m))
        ids = np.repeat([t.tid for t in self.tracks], k)
        return window_boxes(c, h), ids

    def _support(self, windows: np.ndarray, scores: np.ndarray, ids: np.ndarray) -> None:
        """Each track's best verification hit (person box) or None."""
        thr = self.params.classifier.hit_threshold
        for t in self.tracks:
            t.support = None
            sel = np.flatnonzero(ids == t.tid)
            if len(sel):
                j = sel[int(np.argmax(scores[sel]))]
                if scores[j] > thr:
                    t.support = person_boxes(windows[j:j + 1])[0]

    def _spawn(self, img: np.ndarray, box: np.ndarray, parent: int) -> _Track:
        C = self.params.children
        tid = self._next_id
        self._next_id += 1
        assert self.parents is not None and self.parents.labels is not None
        labels = self.parents.labels.copy()
        labels[parent] = tid
        self.parents = ParticleSet(self.parents.states, self.parents.log_weights, labels,
                                   self.parents.extra)
        ref = ch.histograms(img, box[None], (C.grid_x, C.grid_y), C.Mh, C.Ms, C.Mv,
                            C.s_min, C.v_min)[0]
        kids = ParticleSet(ch.spawn(box, C.n, C.pos_sigma, self.rng),
                           np.full(C.n, -np.log(C.n)), np.full(C.n, tid, dtype=np.int64))
        return _Track(tid, parent, ref, float(box[2] / box[3]), kids, np.array(box, float),
                      np.zeros(2))

    def _update_children(self, img: np.ndarray, frame: int, log: StageLog) -> None:
        """Eqs. (12)-(15) for every live track, overlap suppression, track ends (§2.2)."""
        C = self.params.children
        if not self.tracks:
            return
        rng = self.rng
        H, W = img.shape[:2]
        preds = ch.predict_tracks([t.kids.states for t in self.tracks],
                                  [t.shift for t in self.tracks], C.damping, C.pos_sigma,
                                  C.scale_sigma, rng)
        for t, p in zip(self.tracks, preds):  # re-seed part of the children at the parent's hit
            k = int(round(C.inject * len(p)))
            if t.support is not None and k:
                pick = rng.choice(len(p), k, replace=False)
                seeds = ch.spawn(t.support, k, C.pos_sigma, rng)
                seeds[:, 2] = t.support[3]
                seeds[:, 3:5] = seeds[:, :2] - t.velocity
                p[pick] = seeds
        # slow reference refresh (ours): the tracks whose parent has a hit
        refresh = [t for t in self.tracks if t.support is not None] if C.ref_update > 0 else []
        sizes = [len(p) for p in preds]
        starts = np.cumsum([0] + sizes)
        # all tracks' children at once (the same values as track by track)
        allb = ch.boxes_of(np.concatenate(preds), np.repeat([t.aspect for t in self.tracks], sizes))
        # every child's box and every refreshed track's hit box: one gather, one bincount
        hist = ch.histograms(img, np.concatenate([allb, *(t.support[None] for t in refresh)]),
                             (C.grid_x, C.grid_y), C.Mh, C.Ms, C.Mv, C.s_min, C.v_min)
        for t, q in zip(refresh, hist[len(allb):]):
            t.ref = (1.0 - C.ref_update) * t.ref + C.ref_update * q
        B_all = ch.bhattacharyya(np.repeat([t.ref for t in self.tracks], sizes, axis=0),
                                 hist[:len(allb)])                # eq. (13)
        lw_all = ch.log_weights(B_all, C.lam)                     # eq. (14)
        Bs, lws, boxes = [], [], []
        for k, t in enumerate(self.tracks):
            sl = slice(starts[k], starts[k + 1])
            Bs.append(B_all[sl])
            lw = lw_all[sl]
            if t.support is not None and C.support_sigma > 0:
                sc = t.support[:2] + t.support[2:] / 2
                d2 = ((preds[k][:, :2] - sc) ** 2).sum(1)
                lw = lw - d2 / (2.0 * (C.support_sigma * t.support[3]) ** 2)
            lws.append(lw)
            boxes.append(allb[sl])
        # strongest first: the weaker track may not take its MAP inside a stronger one's box
        order = sorted(range(len(self.tracks)), key=lambda k: float(Bs[k].min()))
        grid = (C.grid_x, C.grid_y)

        def estimate(k: int, accepted: list) -> tuple:
            """Track k's log-weights (children inside an accepted box zeroed), whether all its
            children are inside one, its MAP index and its box."""
            t, lw, bx = self.tracks[k], lws[k], boxes[k]
            overlapping, j = False, -1
            if accepted:
                ov = box_iou(bx, np.array(accepted)).max(axis=1) >= C.overlap_iou
                if ov.all():
                    overlapping = True
                else:
                    lw = np.where(ov, -np.inf, lw)
            if C.estimate == "map":
                j = ch.map_index(lw)                              # eq. (15)
                est = preds[k][j, :3]
            else:
                w = np.exp(lw - lw.max())
                est = (w[:, None] * preds[k][:, :3]).sum(0) / w.sum()
            box = ch.boxes_of(est, t.aspect)[0]
            if t.support is not None and C.snap > 0:  # pull the estimate onto the hit (ours)
                c = t.support[:2] + t.support[2:] / 2
                sup = ch.boxes_of((c[0], c[1], t.support[3]), t.aspect)[0]
                box = (1.0 - C.snap) * box + C.snap * sup
            return lw, overlapping, j, box

        def why_end(t: _Track, box: np.ndarray, low: int, overlap: int,
                    unsupported: int) -> Optional[str]:
            cx, cy = box[0] + box[2] / 2, box[1] + box[3] / 2
            if low >= C.lost_frames:
                return f"likelihood below {C.lost_likelihood} for {low} frames"
            if C.unsupported_frames and unsupported >= C.unsupported_frames:
                return f"no classifier hit for {unsupported} frames"
            if overlap >= C.merge_frames:
                return f"inside a stronger track for {overlap} frames"
            if not (0 <= cx < W and 0 <= cy < H):
                return "left the image"
            return None

        # the estimates in that order as far as whether each track is kept is known without its
        # distance B (unknown only for a track without a hit one low frame from its end): their
        # boxes' B in one histogram call, the same values as one call per track
        plan: list[tuple] = []
        kept: list[np.ndarray] = []
        for k in order:
            t = self.tracks[k]
            plan.append(estimate(k, kept))
            if t.support is None and t.low + 1 >= C.lost_frames:
                break
            if why_end(t, plan[-1][3], 0, t.overlap + 1 if plan[-1][1] else 0,
                       0 if t.support is not None else t.unsupported + 1) is None:
                kept.append(plan[-1][3])
        if C.estimate == "mean":
            planned = ch.bhattacharyya(np.array([self.tracks[k].ref for k in order[:len(plan)]]),
                                       ch.histograms(img, np.array([e[3] for e in plan]), grid,
                                                     C.Mh, C.Ms, C.Mv, C.s_min, C.v_min))
        accepted: list[np.ndarray] = []
        ended: list[tuple[_Track, str]] = []
        for i, k in enumerate(order):
            t, B = self.tracks[k], Bs[k]
            lw, overlapping, j, box = plan[i] if i < len(plan) else estimate(k, accepted)
            if C.estimate == "map":
                Best = float(B[j])
            elif i < len(plan):
                Best = float(planned[i])
            else:
                Best = float(ch.bhattacharyya(t.ref, ch.histograms(
                    img, box[None], grid, C.Mh, C.Ms, C.Mv, C.s_min, C.v_min))[0])
            t.velocity = box[:2] + box[2:] / 2 - (t.box[:2] + t.box[2:] / 2)
            t.box, t.B = box, Best
            idx = resample_indices(lw, C.n, rng, "systematic")
            t.kids = ParticleSet(preds[k][idx], np.full(C.n, -np.log(C.n)),
                                 np.full(C.n, t.tid, dtype=np.int64))
            low = np.exp(-C.lam * Best ** 2) < C.lost_likelihood and t.support is None
            t.low = t.low + 1 if low else 0
            t.overlap = t.overlap + 1 if overlapping else 0
            t.unsupported = 0 if t.support is not None else t.unsupported + 1
            why = why_end(t, box, t.low, t.overlap, t.unsupported)
            if why is not None:
                ended.append((t, why))
            else:
                accepted.append(box)
        for t, why in ended:
            self.tracks.remove(t)
            self._end(t, why, frame, log)

    def finish(self) -> Rows:
        return []

    def config(self) -> dict:
        return {"tracker": self.name, "paper": self.paper, "params": to_dict(self.params),
                "classifier": self.classifier.describe(),
                "classifier_info": dict(getattr(self.classifier, "info", {}))}


def _motion_images(frame: Frame, prev_grey: np.ndarray, points: np.ndarray, win: int,
                   levels: int) -> tuple[np.ndarray, np.ndarray, Optional[tuple]]:
    """The look-ahead's helper-thread work for ``frame``: its BGR and grey images and the
    Lucas-Kanade ``(flow, ok)`` of ``points`` from ``prev_grey`` (None when the size changed:
    the step reports that)."""
    img = to_bgr(check_image(frame, "dlpf"))
    grey = to_gray(img)
    if grey.shape != prev_grey.shape:
        return img, grey, None
    return img, grey, mo.lk_flow(prev_grey, grey, points, win=win, levels=levels)


__all__ = ["DLPFTracker", "DLPFParams", "MotionParams", "ParentParams", "ClassifierParams",
           "ConfirmParams", "ChildParams"]
