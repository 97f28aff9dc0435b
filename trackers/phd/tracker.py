"""PHD-MT and MT — the two trackers of maggio2007 (§2–§4), with every stage in the result.

``PHDTracker`` (PHD-MT): detections → particle PHD filter (predict, birth, update eq. (5),
resample) → modified K-means peaks (§3) → graph-matching association (§3) → tracks.
``MTTracker`` (MT, the paper's baseline): the same association run directly on the detections.

Each step returns its stage data (:mod:`pfscope.trackers.report`), paths under ``phd/`` and
``assoc/``:

====================  ==========  =========================================================
stage                 level       items
====================  ==========  =========================================================
predict               particles   Points ``phd/particles/predicted`` (weights)
predict               tracks      Scalars ``phd/camera/scale``, ``phd/camera/shift`` (px):
                                  the camera motion followed (``rate.camera_motion``; 1, 0
                                  on a still camera)
birth                 particles   Points ``phd/particles/birth`` (ids = detection)
birth                 clusters    Boxes ``phd/birth/detections`` values ``J`` (J_z), ``M``
                                  (mass near z)
update                particles   Points ``phd/particles/updated`` (weights)
update                clusters    Boxes ``phd/update/detections`` value ``won``: C/(κ+C),
                                  how much mass each detection won (≈0 for isolated clutter)
resample              particles   Points ``phd/particles/resampled`` (weights)
cluster               particles   Points ``phd/clusters/members`` (ids = cluster)
cluster               clusters    Boxes ``phd/clusters/kept`` / ``phd/clusters/dropped``,
                                  value ``m`` (mass)
associate             clusters    Segments ``assoc/edges/candidates`` / ``assoc/edges/chosen``
                                  (values gap, weight, log f), Boxes ``assoc/vertices``
                                  (ids = track, values length, confirmed)
(all)                 tracks      Scalars ``phd/mass``, ``phd/particles/count``,
                                  ``phd/birth/count``, ``phd/clusters/kept``,
                                  ``assoc/tracks/live``; Events ``assoc`` (confirmed, ended)
====================  ==========  =========================================================

Presets (``pfscope trackers``): ``practical`` (the default) is the same algorithm with settings
per second (:class:`RateParams`, converted with the frame rate read from the frames'
timestamps), scene clutter with online estimates and birth odds (:mod:`.filter`, "Scene
clutter"), detection scores, re-linking of tracks ended by a long gap and, for PHD-MT, gap
filling and a colour appearance cue (:mod:`.association`, :mod:`.appearance`); ``paper`` is
maggio2007 §4 unchanged (the dataclass defaults).

Output: :attr:`StepResult.tracks` are the confirmed tracks known at frame k (zero lag, what the
live view shows).  :attr:`StepResult.rows` are the association's bounded-lag rows for the
tracks file, which also report the first ``min_length − 1`` frames of every track;
:meth:`finish` returns the rest at the end of a sequence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from ..api import Rows, StepResult, register
from ..params import param, part, to_dict, with_options
from ..report import Boxes, Points, Segments, StageLog
from ..types import Detections, Frame, TrackSet, xywh_to_cxcywh
from .association import AssocParams, AssocResult, FinalRows, GraphAssociator
from . import _assoc_kernels
from .appearance import box_features
from .camera_motion import MEMORY_S as CAMERA_MEMORY_S, scale as camera_scale, warp_states
from .clustering import Clusters, kmeans_peaks, measurement_estimates
from .filter import STATE_DIM, PHDFilter, PHDParams, PHDStepResult, _check
from .scene_motion import SceneMotion
from .scene_noise import DetectorJitter, NoiseParams, learnt_width


@dataclass(frozen=True)
class ClusterParams:
    """Peak extraction (maggio2007 §3)."""

    T: float = param(0.6, "cluster mass threshold: lighter clusters are dropped",
                     paper="maggio2007 §4")
    split_rule: str = param("guarded", "'guarded' (a split must leave both halves >= T) or "
                                       "'literal' (§3 as written); see phd.clustering")
    estimate: str = param("centre", "what a kept cluster reports: 'centre' (the K-means mean, "
                                    "§3) or 'measurement' (on a detection that won >= 0.5: "
                                    "the mean of the part of the cluster that detection "
                                    "explains; phd.clustering)")
    subsample: int = param(1, "K-means runs on every n-th of the resampled (equal-weight) "
                              "particles, 1: on all of them (PHD-MT; 2 halves "
                              "K-means' cost; phd.clustering)")

    def __post_init__(self):
        if not self.T >= 0:
            raise ValueError(f"ClusterParams.T must be >= 0, got {self.T}")
        if self.split_rule not in ("guarded", "literal"):
            raise ValueError(f"ClusterParams.split_rule must be 'guarded' or 'literal', "
                             f"got {self.split_rule!r}")
        if self.estimate not in ("centre", "measurement"):
            raise ValueError(f"ClusterParams.estimate must be 'centre' or 'measurement', "
                             f"got {self.estimate!r}")
        if not (isinstance(self.subsample, int) and self.subsample >= 1):
            raise ValueError(f"ClusterParams.subsample must be an integer >= 1, "
                             f"got {self.subsample!r}")


@dataclass(frozen=True)
class RateParams:
    """Settings per second (the ``practical`` preset), converted to the per-frame fields with
    the source's frame rate, read from the frames' timestamps (``fps = (index − 1) /
    timestamp``; until a frame gives it -- frame 1 has timestamp 0 -- ``fallback_fps``, and the
    particles' and tracks' velocities are rescaled when the true rate is learnt).  With
    ``per_second`` false (``paper``) every per-frame field is used as given.

    Noise follows continuous-time models: white-noise acceleration (velocity change std per
    frame ``accel_per_s · dt^1.5`` in px/frame, fraction of (w, h)), a size random walk
    (``size_per_s · √dt``); speeds scale with dt, probabilities per second with ``^dt``,
    durations with the frame rate.  When ``per_second`` is true these fields overwrite:
    filter.motion.{sigma_v, sigma_size, p_survival}, filter.birth.{birth_speed_std,
    birth_odds}, filter.clutter.clutter_memory, assoc.{sigma_v, sigma_size, speed_prior,
    depth, min_length, relink_depth, relink_tau, app_alpha}."""

    per_second: bool = param(False, "convert the per-second settings below with the frame "
                                    "rate (false: the per-frame fields as given, paper)")
    fallback_fps: float = param(10.0, "frame rate assumed until the timestamps give one")
    accel_per_s: float = param(1.0, "acceleration noise, fraction of (w, h) per s^1.5 "
                                    "(→ sigma_v = accel_per_s · dt^1.5)")
    size_per_s: float = param(0.1, "size random-walk std, fraction per √s "
                                   "(→ sigma_size = size_per_s · √dt)")
    birth_speed_per_s: float = param(1.5, "newborn speed std, sqrt(w h) per second "
                                          "(→ birth_speed_std, speed_prior)")
    survival_per_s: float = param(0.95, "probability that a target stays one more second "
                                        "(→ p_survival = survival_per_s^dt)")
    birth_odds_per_s: float = param(0.15, "odds per second that a detection no target "
                                          "explains is a new target rather than clutter "
                                          "(→ birth_odds = birth_odds_per_s · dt)")
    gap_s: float = param(2.0, "longest gap the association bridges, seconds "
                              "(→ depth = ceil(gap_s · fps))")
    min_track_s: float = param(0.5, "shortest track reported, seconds of estimates "
                                    "(→ min_length = max(2, round(min_track_s · fps)))")
    memory_s: float = param(20.0, "averaging time of the online clutter and score estimates "
                                  "(→ clutter_memory)")
    relink_s: float = param(5.0, "a confirmed track unseen for longer than gap_s stays "
                                 "re-linkable until this many seconds after its last "
                                 "estimate; 0: off (→ relink_depth = ceil(relink_s · fps))")
    relink_tau_s: float = param(3.0, "re-linking: time constant of the velocity damping, "
                                     "seconds (→ relink_tau = relink_tau_s · fps)")
    app_memory_s: float = param(2.0, "averaging time of a track's colour model, seconds "
                                     "(→ app_alpha = 1 − exp(−dt / app_memory_s))")
    learn_motion: bool = param(False, "PHD-MT: raise the filter's acceleration and size noise "
                                      "above accel_per_s, size_per_s by what the scene's "
                                      "detections show the motion model misses (learnt "
                                      "online, phd.scene_motion; never below the preset)")

    camera_motion: bool = param(False, "PHD-MT (with learn_motion): estimate the camera's "
                                       "image motion each frame from the linked detections "
                                       "(a similarity, used only when significantly better "
                                       "than a still camera; phd.camera_motion) and move the "
                                       "particles and the tracks' predictions with it")

    def __post_init__(self):
        for name in ("fallback_fps", "gap_s", "memory_s", "relink_tau_s", "app_memory_s"):
            _check(self, name, getattr(self, name) > 0, "> 0")
        for name in ("accel_per_s", "size_per_s", "birth_speed_per_s", "birth_odds_per_s",
                     "min_track_s", "relink_s"):
            _check(self, name, getattr(self, name) >= 0, ">= 0")
        _check(self, "survival_per_s", 0.0 <= self.survival_per_s <= 1.0, "in [0, 1]")


#: Per-frame field → the per-second field it is derived from when ``rate.per_second`` is true
#: (what :func:`filter_per_frame` and :func:`assoc_per_frame` overwrite).  ``--set`` on one
#: of these is then refused naming the ``rate.*`` field (trackers.params.derived_from).
RATE_DERIVED = {
    "filter.motion.sigma_v": "rate.accel_per_s", "filter.motion.sigma_size": "rate.size_per_s",
    "filter.motion.p_survival": "rate.survival_per_s",
    "filter.birth.birth_speed_std": "rate.birth_speed_per_s",
    "filter.birth.birth_odds": "rate.birth_odds_per_s",
    "filter.clutter.clutter_memory": "rate.memory_s",
    "assoc.sigma_v": "rate.accel_per_s", "assoc.sigma_size": "rate.size_per_s",
    "assoc.speed_prior": "rate.birth_speed_per_s", "assoc.depth": "rate.gap_s",
    "assoc.min_length": "rate.min_track_s", "assoc.relink_depth": "rate.relink_s",
    "assoc.relink_tau": "rate.relink_tau_s", "assoc.app_alpha": "rate.app_memory_s",
}


def rate_derived(params) -> dict:
    """``{field: why}`` of the fields of ``params`` (with a ``rate`` part) that a ``--set``
    cannot change as things stand: under ``rate.per_second`` the per-frame fields derived from
    ``rate.*``; without it the ``rate.*`` fields (nothing reads them)."""
    from ..params import leaves

    names = {n for n, _, _ in leaves(params)}
    if params.rate.per_second:
        return {n: f"derived each frame from {src} (rate.per_second = true); set {src} "
                   f"instead, or rate.per_second=false to give per-frame values"
                for n, src in RATE_DERIVED.items() if n in names}
    return {n: "read only when rate.per_second = true (preset practical); set "
               "rate.per_second=true too, or the per-frame field it converts to"
            for n in names if n.startswith("rate.") and n != "rate.per_second"}


def assoc_per_frame(a: AssocParams, r: RateParams, fps: float) -> AssocParams:
    """The association's per-frame fields from the per-second ones at ``fps``."""
    dt = 1.0 / fps
    depth = max(1, math.ceil(r.gap_s * fps - 1e-9))
    min_length = min(max(2, round(r.min_track_s * fps)), depth + 1)
    relink_depth = math.ceil(r.relink_s * fps - 1e-9) if r.relink_s > 0 else 0
    return replace(a, sigma_v=r.accel_per_s * dt ** 1.5, sigma_size=r.size_per_s * dt ** 0.5,
                   speed_prior=r.birth_speed_per_s * dt, depth=depth, min_length=min_length,
                   relink_depth=relink_depth, relink_tau=r.relink_tau_s * fps,
                   app_alpha=-math.expm1(-dt / r.app_memory_s))


def filter_per_frame(f: PHDParams, r: RateParams, fps: float) -> PHDParams:
    """The filter's per-frame fields from the per-second ones at ``fps``."""
    dt = 1.0 / fps
    return replace(
        f,
        motion=replace(f.motion, sigma_v=r.accel_per_s * dt ** 1.5,
                       sigma_size=r.size_per_s * dt ** 0.5, p_survival=r.survival_per_s ** dt),
        birth=replace(f.birth, birth_speed_std=r.birth_speed_per_s * dt,
                      birth_odds=r.birth_odds_per_s * dt),
        clutter=replace(f.clutter, clutter_memory=max(1.0, r.memory_s * fps)))


@dataclass(frozen=True)
class PHDTrackerParams:
    """PHD-MT: the filter's parts, the peak extraction and the association."""

    filter: PHDParams = part(PHDParams, "particle PHD filter")
    clusters: ClusterParams = part(ClusterParams, "modified K-means peaks")
    assoc: AssocParams = part(AssocParams, "graph-matching association")
    rate: RateParams = part(RateParams, "settings per second (practical preset)")
    noise: NoiseParams = part(NoiseParams, "likelihood width learnt from the detector's "
                                           "jitter (not in paper)")

    def derived_from(self) -> dict:
        return rate_derived(self)

    def at_fps(self, fps: float) -> "PHDTrackerParams":
        """The per-frame settings at ``fps`` (itself when ``rate.per_second`` is false)."""
        if not self.rate.per_second:
            return self
        return replace(self, filter=filter_per_frame(self.filter, self.rate, fps),
                       assoc=assoc_per_frame(self.assoc, self.rate, fps))


@dataclass(frozen=True)
class MTParams:
    """MT: the association alone."""

    assoc: AssocParams = part(AssocParams, "graph-matching association")
    rate: RateParams = part(RateParams, "settings per second (practical preset)")

    def derived_from(self) -> dict:
        return rate_derived(self)

    def at_fps(self, fps: float) -> "MTParams":
        if not self.rate.per_second:
            return self
        return replace(self, assoc=assoc_per_frame(self.assoc, self.rate, fps))


def frame_rate(frame: Frame) -> Optional[float]:
    """Frames per second from a frame's index and timestamp (None when they cannot tell)."""
    if frame.index > 1 and frame.timestamp > 0 and math.isfinite(frame.timestamp):
        return (frame.index - 1) / frame.timestamp
    return None


#: the association's and the step's kernels are loaded in this process (:func:`_load_kernels`)
_kernels_loaded = False


def _load_kernels() -> None:
    """The association's kernels and the step's own (input centres, output boxes), called
    once with a run's argument types on made-up data (the warm-up's
    :func:`~..warmup._compile_association`: the edge scores,
    :func:`.association.compile_step_kernels` and the gap filling's IoU), in a tracker's first
    frame.  numba loads a cached kernel on
    its first call (~3-5 ms each, ~35 ms for these): without this, each loads in the first
    frame that reaches it -- a returning track, a track's first final rows, a walk back, an
    expiry -- a hiccup of a few ms in the middle of a run.  (The app's warm-up calls them
    already; this covers a tracker stepped without it, e.g. ``pipeline.run``.)  On a first
    run after an install, with an empty cache, this is where they compile."""
    global _kernels_loaded
    from ..warmup import _compile_association

    _compile_association()
    _kernels_loaded = True


def _rows(finalised: tuple[FinalRows, ...], flagged: bool) -> Rows:
    # (the association's arrays are in TrackSet's final form already: int64 ids, float64 boxes
    # and conf, made with the rows: FinalRows.xywh / conf)
    out = []
    for r in finalised:
        out.append((r.frame, TrackSet.of(r.ids, r.xywh, r.conf if flagged else None)))
    return out


class _AssociatingTracker:
    """What PHD-MT and MT share: the associator, its stage data and the output."""

    name: str
    needs_detections = True
    needs_image = False

    params: "PHDTrackerParams | MTParams"

    def __init__(self, assoc: AssocParams):
        self.associator = GraphAssociator(assoc)
        self._announced: set[int] = set()
        self.fps: Optional[float] = None        # the frame rate the settings are converted at
        self._fps_known = False
        self.active = self.params               # per-frame settings in use

    def _retime(self, frame: Frame) -> None:
        """Per-second settings: convert at the first frame, again (once) when the timestamps
        first give the frame rate; velocities in px/frame are rescaled to the new rate."""
        if not self.params.rate.per_second or self._fps_known:
            return
        fps = frame_rate(frame)
        self._fps_known = fps is not None
        fps = fps if fps is not None else self.params.rate.fallback_fps
        if self.fps is not None and fps == self.fps:
            return
        ratio = 1.0 if self.fps is None else self.fps / fps
        self.fps = fps
        self.active = self.params.at_fps(fps)
        self.associator.params = self.active.assoc
        self.associator.rescale_velocity(ratio)
        self._retime_filter(ratio)

    def _retime_filter(self, ratio: float) -> None:
        pass

    @property
    def _flagged(self) -> bool:
        """Rows carry the filled flag (tracks-file conf) when some are not estimates."""
        p = self.associator.params
        return p.fill_gaps or p.extend_heads

    def _associate(self, frame: Frame, states: np.ndarray, log: StageLog,
                   detections: Optional[np.ndarray] = None) -> StepResult:
        log.stage("associate")
        feats = None
        image = frame.image
        ndim = getattr(image, "ndim", 0) if image is not None else 0
        if ndim >= 2:
            shape = image.shape    # (frame.width × frame.height)
            self.associator.area = float(int(shape[1]) * int(shape[0]))
        if self.associator.params.app_weight > 0 and frame.has_pixels:
            feats = box_features(image, states)
        res = self.associator.step(frame.index, states, feats, detections,
                                   edges=log.wants("clusters"))
        # (ids[confirmed] and their top-left boxes in one kernel pass: boxes_xywh's floats)
        ids, boxes = _assoc_kernels.track_boxes(res.ids, res.states, res.confirmed)
        self._report_association(frame, res, log, ids)
        return StepResult(TrackSet.of(ids, boxes), _rows(res.finalised, self._flagged),
                          log.result())

    def _report_association(self, frame: Frame, res: AssocResult, log: StageLog,
                            confirmed_ids: np.ndarray) -> None:
        """The association's stage data; ``confirmed_ids``: ``res.ids[res.confirmed]`` (in
        order: the tracks' ids the step reports)."""
        log.scalar("assoc/tracks/live", self.associator.n_live)
        for new_id, old_id in res.relinked.tolist():
            log.event("assoc", f"frame {frame.index}: new track {new_id} re-linked to ended "
                               f"track {old_id}")
            self._announced.add(old_id)
        for tid in res.ended.tolist():
            if tid in self._announced:
                log.event("assoc", f"frame {frame.index}: track {tid} ended "
                                   f"(unseen for more than K={self.associator.params.depth} frames)")
                self._announced.discard(tid)
        tids = confirmed_ids.tolist()
        # (most frames confirm no track: one set test instead of a loop over the vertices)
        if not self._announced.issuperset(tids):
            for tid in tids:
                if tid not in self._announced:
                    self._announced.add(tid)
                    log.event("assoc", f"frame {frame.index}: track {tid} confirmed "
                                       f"({self.associator.params.min_length} vertices)")
        if not log.wants("clusters"):
            return
        dst = res.states[res.edges_dst_index, :2] if len(res.edges_dst_index) else np.zeros((0, 2))
        src = res.edges_src[:, :2]
        cand, ch = ~res.chosen, res.chosen
        log.add(Segments("assoc/edges/candidates", src[cand], dst[cand], role="candidate",
                         ids=res.edges_src_id[cand], id_kind="track",
                         values={"gap": res.edges_gap[cand], "weight": res.edges_weight[cand]}))
        log.add(Segments("assoc/edges/chosen", src[ch], dst[ch], ids=res.edges_src_id[ch],
                         id_kind="track", values={"gap": res.edges_gap[ch],
                                                  "log f": res.edges_gain[ch]}))
        log.add(Boxes("assoc/vertices", res.boxes, ids=res.ids, id_kind="track",
                      values={"length": res.lengths, "confirmed": res.confirmed}))

    def finish(self) -> Rows:
        """End of sequence: every row not yet finalised."""
        return _rows(self.associator.flush(), self._flagged)


#: The practical default of PHD-MT (README, "Presets"): maggio2007's algorithm with settings
#: per second, detection scores, gap filling, re-linking of tracks ended by a long gap
#: (``rate.relink_s``) and a colour appearance cue in the edge weights (``assoc.app_weight``,
#: when the frames have pixels; chosen on PETS09-S2L1 frames 1-400 among 0.5, 1, 2, 3);
#: track heads walk back across up to two frames without a fitting detection (``head_skip``:
#: a newborn missed once or twice, p_D 0.9, still gets its first frames; random-clutter OSPA
#: at 16 targets 16.1 -> 14.7, dev set unchanged); clutter learnt online (``learn``: random
#: clutter, places where it repeats, boxes beside and second boxes on people, .clutter) and
#: used in the update as that mixture (``learn_update`` 'model'), with ``spot_places`` (a
#: place's memory counts a chained detection by the probability that its chain is clutter;
#: newborns weigh against κ without the place memory) and a place memory of
#: ``repeat_memory`` 0.3.  On the development set (seeds 0-2) it takes COMBINED MOTA/IDF1 from
#: 0.710 / 0.687 (the paper's ``gate`` clutter, the default before) to 0.735 / 0.751 and
#: KITTI-13 (moving camera, 10 fps) from no track to 0.233 / 0.485, keeps the built-in scene
#: at MOTA 0.815 / 0.839 / 0.895, and costs TUD-Stadtmitte MOTA 0.753 -> 0.719 (docs/trackers/
#: phd.md); ``--set clutter_model=gate`` is the paper's.  The ``scene`` preset is the same
#: with clutter as a density over the image learnt online, the better model when clutter
#: falls at random (the synthetic
#: scene: mass within 10 % of the true count, where ``gate`` under-counts by ~20 %).  The score
#: model also fits its classes on persistence (``persist_frames`` 3: chains of mutually nearest
#: detections over 3 earlier frames) and uses that fit while it separates the classes better
#: than the mass does (before any track; dev set unchanged within the seeds' spread).
PHD_PRACTICAL = PHDTrackerParams(
    filter=PHDParams.of(clutter_model="learn", learn_update="model", spot_places=True,
                        repeat_memory=0.3, near_learn=True, score_model="gaussian",
                        persist_frames=3, p_miss=0.1, revive_odds=1.0),
    assoc=AssocParams(fill_gaps=True, fill_support=0.25, fill_free=2, app_weight=2.0, extend_heads=True,
                      head_skip=2, fill_err=1 / 6),
    rate=RateParams(per_second=True, learn_motion=True, camera_motion=True))
PHD_SCENE = with_options(PHD_PRACTICAL, {"filter.clutter.clutter_model": "scene"})
#: The practical default of MT: the same association settings per second (re-linking
#: included).  No gap filling: MT links clutter into tracks across gaps, and filling them
#: multiplies its false positives.  No appearance: MT's vertices are raw detections, clutter
#: included.
MT_PRACTICAL = MTParams(rate=RateParams(per_second=True))


@register(presets={"practical": PHD_PRACTICAL, "paper": PHDTrackerParams(), "scene": PHD_SCENE})
class PHDTracker(_AssociatingTracker):
    """PHD-MT: particle PHD filter + modified K-means peaks + graph-matching association."""

    name = "phd"
    paper = "maggio2007"
    stages = ("predict", "birth", "update", "resample", "cluster", "associate")
    #: the practical preset's appearance cue reads the pixels of the estimates' boxes (when a
    #: frame has none -- a blank stand-in -- the association runs on motion alone)
    needs_image = True
    #: ... but it runs on blank frames too (a detections-only sequence): the cue switches off
    image_optional = True
    Params = PHDTrackerParams

    def __init__(self, params: Optional[PHDTrackerParams] = None, *,
                 rng: np.random.Generator, likelihood=None):
        self.params = params if params is not None else PHDTrackerParams()
        super().__init__(self.params.assoc)
        self.filter = PHDFilter(self.params.filter, rng, likelihood=likelihood)
        np_ = self.params.noise
        self.jitter = (DetectorJitter(np_, self.params.filter.likelihood.sigma_obs)
                       if np_.learn_width > 0 and likelihood is None else None)
        lk = self.params.filter.likelihood
        self.scene_motion = (SceneMotion(lk.sigma_obs * lk.sigma_obs_pos_ratio,
                                         camera=self.params.rate.camera_motion)
                             if self.params.rate.per_second and self.params.rate.learn_motion
                             else None)
        if self.scene_motion is not None:
            # the score model's persistence labels link the same detections each frame: one
            # Chains for both (observed first in _learn_scene, keyed by the frame index)
            self.filter.scene.chains = self.scene_motion.chains
        #: the camera's motion into the last frame (rate.camera_motion; None: still)
        self._camera: Optional[np.ndarray] = None
        #: (preset settings, learnt values, filter settings) of the last _learn_scene
        self._scene_last: Optional[tuple] = None

    def _learn_scene(self, frame: Frame, xywh: np.ndarray) -> np.ndarray:
        """What the scene's detections teach the filter, on top of the preset at this frame
        rate: the likelihood width the detector's jitter calls for (``noise.learn_width``,
        :mod:`.scene_noise`) and the motion noise raised to what the scene measures
        (``rate.learn_motion``, :mod:`.scene_motion`).  ``xywh``: the frame's detections'
        top-left boxes; returns their centre boxes ``(cx, cy, w, h)`` (without the jitter's
        model, from the scene motion's kernel pass: :meth:`.SceneMotion.observe_boxes`)."""
        fp = self.active.filter
        want = fp
        boxes = None
        if self.jitter is not None:
            boxes = _assoc_kernels.centre_boxes(xywh)
            self.jitter.see(frame.index, boxes, fp.clutter.clutter_memory)
            width = learnt_width(fp.likelihood.sigma_obs, self.jitter.jitter,
                                 self.params.noise.learn_width)
            want = replace(want, likelihood=replace(fp.likelihood, sigma_obs=width))
        if self.scene_motion is not None:
            sm = self.scene_motion
            # a person's own displacement a frame: the newborn speed prior (per axis)
            bp = fp.birth
            sm.speed_var = (bp.birth_speed_std ** 2 + bp.birth_speed_mean ** 2) / 2.0
            sm.size_std = want.likelihood.sigma_obs
            sm.camera_memory = CAMERA_MEMORY_S * (self.fps or self.params.rate.fallback_fps)
            if boxes is None:
                boxes = sm.observe_boxes(xywh, frame.index)
            else:
                sm.observe(boxes, frame.index)
            # the residuals the likelihood explains: the learnt width's when there is one
            sm.pos_std = want.likelihood.sigma_obs * want.likelihood.sigma_obs_pos_ratio
            sv, ss = sm.sigmas()
            self.associator.scene_sigma_v = sv or 0.0
            sv, ss = max(fp.motion.sigma_v, sv or 0.0), max(fp.motion.sigma_size, ss or 0.0)
            # the same settings as the last frame's: nothing to build or compare (two
            # dataclass replaces and a deep comparison, ~0.1 ms a frame)
            key = (want.likelihood.sigma_obs, sv, ss)
            last = self._scene_last
            if last is not None and last[0] is fp and last[1] == key \
                    and last[2] is self.filter.params:
                return boxes
            want = replace(want, motion=replace(fp.motion, sigma_v=sv, sigma_size=ss))
        else:
            key = (want.likelihood.sigma_obs,)
        if want != self.filter.params:
            self.filter.set_params(want)
        self._scene_last = (fp, key, self.filter.params)
        return boxes

    def _follow_camera(self, index: int, cam: np.ndarray) -> None:
        """The camera moved (``rate.camera_motion``; ``cam`` the similarity frame k−1 → k,
        :mod:`.camera_motion`): the particles and the association's track states move into
        frame k's image coordinates before the prediction, which then models the people's own
        motion only."""
        ps = self.filter.particles
        if len(ps):
            states = ps.states.copy()
            warp_states(states, cam)
            self.filter.particles = type(ps)(states, ps.log_weights, ps.labels, ps.extra)
        self.associator.follow_camera(index, cam)

    def _retime_filter(self, ratio: float) -> None:
        self.filter.set_params(self.active.filter)
        if ratio != 1.0 and len(self.filter.particles):
            ps = self.filter.particles
            states = ps.states.copy()
            states[:, 2:4] *= ratio
            self.filter.particles = type(ps)(states, ps.log_weights, ps.labels, ps.extra)

    def config(self) -> dict:
        return {"tracker": self.name, "params": to_dict(self.params)}

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult:
        dets = detections if detections is not None else Detections.empty()
        if not _kernels_loaded:
            _load_kernels()
        if not self._fps_known:         # (known: nothing to convert again)
            self._retime(frame)
        # the detections' centre boxes, read-only below: one conversion a frame
        # (xywh_to_cxcywh's floats, in a kernel pass: the scene motion's when it learns)
        xywh = np.ascontiguousarray(dets.boxes)
        cam = None
        if self.jitter is not None or self.scene_motion is not None:
            z = self._learn_scene(frame, xywh)
            cam = self.scene_motion.camera if self.scene_motion is not None else None
            if cam is not None:
                self._follow_camera(frame.index, cam)
        else:
            z = _assoc_kernels.centre_boxes(xywh)
        log = StageLog(self.stages, level)
        self._camera = cam
        revive = None
        if self.active.filter.birth.revive_odds > 0 and len(dets):
            revive = self.associator.returning(frame.index, z, or_none=True)
        r = self.filter.step(dets, frame, revive, z)
        cp = self.params.clusters
        clusters = kmeans_peaks(r.resampled, r.observations, cp.T, params=self.filter.params,
                                split_rule=cp.split_rule, subsample=cp.subsample)
        if cp.estimate == "measurement":
            up = r.updated
            clusters = measurement_estimates(
                clusters, r.resampled, r.observations, up.per_det_mass, up.kappa, up.c_z,
                self.filter.params.likelihood.p_miss, self.filter.likelihood,
                self.filter.params, frame)
        kept = clusters.kept_centers
        self._report_filter(dets, r, clusters, log, len(kept))
        return self._associate(frame, kept, log, r.observations)

    def _report_filter(self, detections: Detections, r: PHDStepResult, clusters: Clusters,
                       log: StageLog, n_kept: int) -> None:
        """The filter's and K-means' stage data (arrays the step computed anyway; ``n_kept``:
        the kept clusters, the estimates' count -- a count of the mask would be one more
        numpy call, ~7 us a frame on a cold cache)."""
        want_p = want_c = False
        if log.recorded:                # (level None: scalars only)
            want_p, want_c = log.wants("particles"), log.wants("clusters")
        log.stage("predict")
        if self.params.rate.camera_motion and self.scene_motion is not None:
            cam = self._camera
            log.scalar("phd/camera/scale", 1.0 if cam is None else camera_scale(cam))
            log.scalar("phd/camera/shift", 0.0 if cam is None else float(np.hypot(*cam[:, 2])))
        if want_p:
            log.add(Points("phd/particles/predicted", r.predicted.states[:, :2],
                           weights=r.predicted.weights))

        log.stage("birth")
        born = r.birth
        log.scalar("phd/birth/count", len(born.particles))
        if want_p:
            log.add(Points("phd/particles/birth", born.particles.states[:, :2],
                           ids=born.det_index, id_kind="detection"))
        if want_c:
            log.add(Boxes("phd/birth/detections", detections.boxes, role="detection",
                          values={"J": born.j_per_det, "M": born.mass_near}))

        log.stage("update")
        up = r.updated
        log.scalar("phd/mass", up.particles.mass)
        if want_p:
            log.add(Points("phd/particles/updated", up.particles.states[:, :2],
                           weights=up.particles.weights))
        if want_c:
            log.add(Boxes("phd/update/detections", detections.boxes, role="detection",
                          values={"won": up.per_det_mass}))

        log.stage("resample")
        log.scalar("phd/particles/count", len(r.resampled))
        if want_p:
            log.add(Points("phd/particles/resampled", r.resampled.states[:, :2],
                           weights=r.resampled.weights))

        log.stage("cluster")
        log.scalar("phd/clusters/kept", n_kept)
        if want_p:
            log.add(Points("phd/clusters/members", r.resampled.states[:, :2],
                           ids=clusters.labels, id_kind="cluster"))
        if want_c:
            boxes = clusters.boxes().reshape(-1, 4)
            k = clusters.kept
            log.add(Boxes("phd/clusters/kept", boxes[k], ids=np.flatnonzero(k),
                          id_kind="cluster", values={"m": clusters.masses[k]}))
            log.add(Boxes("phd/clusters/dropped", boxes[~k], role="dropped",
                          values={"m": clusters.masses[~k]}))


@register(presets={"practical": MT_PRACTICAL, "paper": MTParams()})
class MTTracker(_AssociatingTracker):
    """MT: the graph-matching association run directly on the detections (PHD-MT's baseline).

    Detections carry no velocity, so vertices get NaN velocity and the associator estimates a
    track's velocity from its last two vertices."""

    name = "mt"
    paper = "maggio2007 (baseline)"
    stages = ("associate",)
    Params = MTParams

    def __init__(self, params: Optional[MTParams] = None, *,
                 rng: Optional[np.random.Generator] = None):
        self.params = params if params is not None else MTParams()
        super().__init__(self.params.assoc)

    def config(self) -> dict:
        return {"tracker": self.name, "params": to_dict(self.params)}

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult:
        dets = detections if detections is not None else Detections.empty()
        self._retime(frame)
        z = xywh_to_cxcywh(dets.boxes)
        states = np.full((len(z), STATE_DIM), np.nan)
        states[:, [0, 1, 4, 5]] = z
        return self._associate(frame, states, StageLog(self.stages, level))
