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

Output: :attr:`StepResult.tracks` are the confirmed tracks known at frame k (zero lag, what the
live view shows).  :attr:`StepResult.rows` are the association's bounded-lag rows for the
tracks file, which also report the first ``min_length − 1`` frames of every track;
:meth:`finish` returns the rest at the end of a sequence.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..api import Rows, StepResult, register
from ..params import param, part, to_dict
from ..report import Boxes, Points, Segments, StageLog
from ..types import Detections, Frame, TrackSet, xywh_to_cxcywh
from .association import AssocParams, AssocResult, FinalRows, GraphAssociator
from .clustering import Clusters, kmeans_peaks
from .filter import STATE_DIM, PHDFilter, PHDParams, PHDStepResult


@dataclass(frozen=True)
class ClusterParams:
    """Peak extraction (maggio2007 §3)."""

    T: float = param(0.6, "cluster mass threshold: lighter clusters are dropped",
                     paper="maggio2007 §4")
    split_rule: str = param("guarded", "'guarded' (a split must leave both halves >= T) or "
                                       "'literal' (§3 as written); see phd.clustering")

    def __post_init__(self):
        if not self.T >= 0:
            raise ValueError(f"ClusterParams.T must be >= 0, got {self.T}")
        if self.split_rule not in ("guarded", "literal"):
            raise ValueError(f"ClusterParams.split_rule must be 'guarded' or 'literal', "
                             f"got {self.split_rule!r}")


@dataclass(frozen=True)
class PHDTrackerParams:
    """PHD-MT: the filter's parts, the peak extraction and the association."""

    filter: PHDParams = part(PHDParams, "particle PHD filter")
    clusters: ClusterParams = part(ClusterParams, "modified K-means peaks")
    assoc: AssocParams = part(AssocParams, "graph-matching association")


@dataclass(frozen=True)
class MTParams:
    """MT: the association alone."""

    assoc: AssocParams = part(AssocParams, "graph-matching association")


def _rows(finalised: tuple[FinalRows, ...]) -> Rows:
    return [(r.frame, TrackSet(r.ids, r.boxes)) for r in finalised]


class _AssociatingTracker:
    """What PHD-MT and MT share: the associator, its stage data and the output."""

    name: str
    needs_detections = True
    needs_image = False

    def __init__(self, assoc: AssocParams):
        self.associator = GraphAssociator(assoc)
        self._announced: set[int] = set()

    def _associate(self, frame: Frame, states: np.ndarray, log: StageLog) -> StepResult:
        log.stage("associate")
        res = self.associator.step(frame.index, states)
        self._report_association(frame, res, log)
        keep = res.confirmed
        return StepResult(TrackSet(res.ids[keep], res.boxes[keep]), _rows(res.finalised),
                          log.result())

    def _report_association(self, frame: Frame, res: AssocResult, log: StageLog) -> None:
        log.scalar("assoc/tracks/live", self.associator.n_live)
        for tid in res.ended.tolist():
            if tid in self._announced:
                log.event("assoc", f"frame {frame.index}: track {tid} ended "
                                   f"(unseen for more than K={self.associator.params.depth} frames)")
                self._announced.discard(tid)
        for tid, confirmed in zip(res.ids.tolist(), res.confirmed.tolist()):
            if confirmed and tid not in self._announced:
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
        return _rows(self.associator.flush())


@register(presets={"paper": PHDTrackerParams()})
class PHDTracker(_AssociatingTracker):
    """PHD-MT: particle PHD filter + modified K-means peaks + graph-matching association."""

    name = "phd"
    paper = "maggio2007"
    stages = ("predict", "birth", "update", "resample", "cluster", "associate")
    Params = PHDTrackerParams

    def __init__(self, params: Optional[PHDTrackerParams] = None, *,
                 rng: np.random.Generator, likelihood=None):
        self.params = params if params is not None else PHDTrackerParams()
        super().__init__(self.params.assoc)
        self.filter = PHDFilter(self.params.filter, rng, likelihood=likelihood)

    def config(self) -> dict:
        return {"tracker": self.name, "params": to_dict(self.params)}

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult:
        dets = detections if detections is not None else Detections.empty()
        log = StageLog(self.stages, level)
        r = self.filter.step(dets, frame)
        cp = self.params.clusters
        clusters = kmeans_peaks(r.resampled, r.observations, cp.T, params=self.params.filter,
                                split_rule=cp.split_rule)
        self._report_filter(dets, r, clusters, log)
        return self._associate(frame, clusters.kept_centers, log)

    def _report_filter(self, detections: Detections, r: PHDStepResult, clusters: Clusters,
                       log: StageLog) -> None:
        """The filter's and K-means' stage data (arrays the step computed anyway)."""
        want_p, want_c = log.wants("particles"), log.wants("clusters")
        log.stage("predict")
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
        log.scalar("phd/clusters/kept", int(clusters.kept.sum()))
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


@register(presets={"paper": MTParams()})
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
        z = xywh_to_cxcywh(dets.boxes)
        states = np.full((len(z), STATE_DIM), np.nan)
        states[:, [0, 1, 4, 5]] = z
        return self._associate(frame, states, StageLog(self.stages, level))
