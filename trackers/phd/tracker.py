"""PHD-MT and MT — the two trackers of maggio2007 (§2–§4), wired stage by stage to an observer.

``PHDTracker`` (PHD-MT): detections → particle PHD filter (predict, birth, update eq. (5),
resample) → modified K-means peaks (§3) → graph-matching association (§3) → tracks.
``MTTracker`` (MT, the paper's baseline): the same association run directly on the detections.

Every stage is reported to the observer under ``phd/...`` and ``assoc/...`` paths, after
``obs.stage(name)`` so a recorder can place it on a ``stage`` timeline:

====================  ==========  =========================================================
stage                 level       what
====================  ==========  =========================================================
predict               particles   ``phd/particles/predicted`` (colour = weight)
birth                 particles   ``phd/particles/birth`` (colour = detection it came from)
birth                 clusters    ``phd/birth/detections`` boxes labelled J_z and M(z)
update                particles   ``phd/particles/updated`` (colour = weight)
update                clusters    ``phd/update/detections`` labelled C/(κ+C): how much mass
                                  each detection won (≈0 for isolated clutter)
resample              particles   ``phd/particles/resampled``
cluster               particles   ``phd/clusters/members`` (colour = cluster)
cluster               clusters    ``phd/clusters/kept`` / ``phd/clusters/dropped`` boxes with masses
associate             clusters    ``assoc/edges/candidates``, ``assoc/edges/chosen``,
                                  ``assoc/vertices`` (tentative and confirmed ids)
(all)                 tracks      scalars ``phd/mass``, ``phd/particles/count``,
                                  ``phd/birth/count``, ``assoc/tracks/live``; text events
====================  ==========  =========================================================

Output: :meth:`step` returns the confirmed tracks known at frame k (zero lag, what the live
view shows).  The tracks file uses the association's bounded-lag rows (:meth:`pop_final`,
:meth:`finish`), which also report the first ``min_length − 1`` frames of every track.
"""

from __future__ import annotations

from dataclasses import asdict, fields

import numpy as np

from ..observer import NullObserver, Observer
from ..types import Detections, Frame, TrackSet, xywh_to_cxcywh
from .association import AssocParams, AssocResult, FinalRows, GraphAssociator
from .clustering import kmeans_peaks
from .filter import PHDFilter, PHDParams

STAGE_NAMES = ("predict", "birth", "update", "resample", "cluster", "associate")


def _split_options(options: dict, *dataclasses) -> list[dict]:
    """Route ``name=value`` options to every dataclass that has the field (the motion noise
    ``sigma_v``/``sigma_size`` is shared by the filter and the association); unknown names fail."""
    out = [dict() for _ in dataclasses]
    for key, value in options.items():
        hit = False
        for i, dc in enumerate(dataclasses):
            if key in {f.name for f in fields(dc)}:
                out[i][key] = value
                hit = True
        if not hit:
            names = sorted({f.name for dc in dataclasses for f in fields(dc)})
            raise ValueError(f"unknown tracker option {key!r}; known: {', '.join(names)}")
    return out


def _rows_to_trackset(rows: FinalRows) -> TrackSet:
    return TrackSet(rows.ids, rows.boxes)


class _AssociatingTracker:
    """What PHD-MT and MT share: the associator, its instrumentation and the output."""

    name = "base"

    def __init__(self, assoc: AssocParams):
        self.associator = GraphAssociator(assoc)
        self._final: list[tuple[int, TrackSet]] = []
        self._announced: set[int] = set()

    def _associate(self, frame: Frame, states: np.ndarray, obs: Observer) -> TrackSet:
        obs.stage("associate")
        res = self.associator.step(frame.index, states)
        self._final.extend((r.frame, _rows_to_trackset(r)) for r in res.finalised)
        self._report_association(frame, res, obs)
        keep = res.confirmed
        return TrackSet(res.ids[keep], res.boxes[keep])

    def _report_association(self, frame: Frame, res: AssocResult, obs: Observer) -> None:
        obs.scalar("assoc/tracks/live", self.associator.n_live)
        for tid in res.ended.tolist():
            if tid in self._announced:
                obs.text("assoc", f"frame {frame.index}: track {tid} ended "
                                  f"(unseen for more than K={self.associator.params.depth} frames)")
                self._announced.discard(tid)
        new_confirmed = [int(t) for t, c in zip(res.ids, res.confirmed)
                         if c and int(t) not in self._announced]
        for tid in new_confirmed:
            self._announced.add(tid)
            obs.text("assoc", f"frame {frame.index}: track {tid} confirmed "
                              f"({self.associator.params.min_length} vertices)")
        if not obs.wants("clusters"):
            return
        dst = res.states[res.edges_dst_index, :2] if len(res.edges_dst_index) else np.zeros((0, 2))
        src = res.edges_src[:, :2]
        cand = ~res.chosen
        obs.segments("assoc/edges/candidates", src[cand], dst[cand], radii=0.5,
                     colors=(170, 170, 170, 140),
                     labels=[f"gap {g} w {w:.1f}" for g, w in zip(res.edges_gap[cand],
                                                                  res.edges_weight[cand])]
                     if cand.sum() <= 60 else None)
        ch = res.chosen
        obs.segments("assoc/edges/chosen", src[ch], dst[ch], class_ids=res.edges_src_id[ch],
                     radii=1.5, labels=[f"{i}: gap {g}, log f {lg:.1f}" for i, g, lg in zip(
                         res.edges_src_id[ch], res.edges_gap[ch], res.edges_gain[ch])])
        labels = [f"{i}{'' if c else '?'} (len {n})"
                  for i, c, n in zip(res.ids, res.confirmed, res.lengths)]
        obs.boxes("assoc/vertices", res.boxes, class_ids=res.ids, labels=labels)

    # -- output for the tracks file -------------------------------------------------------
    def pop_final(self) -> list[tuple[int, TrackSet]]:
        """Rows finalised since the last call (bounded lag of ``min_length − 1`` frames)."""
        out, self._final = self._final, []
        return out

    def finish(self) -> list[tuple[int, TrackSet]]:
        """End of sequence: everything not yet finalised."""
        out = self.pop_final()
        out.extend((r.frame, _rows_to_trackset(r)) for r in self.associator.flush())
        return out



class PHDTracker(_AssociatingTracker):
    """PHD-MT (maggio2007): particle PHD filter + modified K-means + graph matching.

    Options: any field of :class:`~trackers.phd.filter.PHDParams` (``rho``, ``p_miss`` ...) or
    :class:`~trackers.phd.association.AssocParams` (``depth``, ``min_length`` ...), plus
    ``T`` (cluster mass threshold, 0.6) and ``split_rule`` (see :func:`kmeans_peaks`)."""

    name = "phd"

    def __init__(self, rng: np.random.Generator, T: float = 0.6, split_rule: str = "guarded",
                 **options):
        phd_kw, assoc_kw = _split_options(options, PHDParams, AssocParams)
        self.params = PHDParams(**phd_kw)
        super().__init__(AssocParams(**assoc_kw))
        self.T = float(T)
        self.split_rule = split_rule
        self.filter = PHDFilter(self.params, rng)

    def config(self) -> dict:
        return {"tracker": self.name, "phd": asdict(self.params),
                "assoc": asdict(self.associator.params), "T": self.T,
                "split_rule": self.split_rule}

    def views(self):
        """Viewer layout hint: (2D views, plots) as engine paths (no Rerun here)."""
        return ([("Tracks", ["tracks/**"]),
                 ("Particles", ["phd/particles/updated", "tracks/**"]),
                 ("Birth & update", ["phd/particles/birth", "phd/birth/**", "phd/update/**"]),
                 ("Clusters", ["phd/clusters/**"]),
                 ("Association", ["assoc/**", "tracks/**"])],
                [("PHD mass", ["phd/mass", "phd/clusters/kept", "tracks/count",
                               "detections/count"]),
                 ("Particles", ["phd/particles/count", "phd/birth/count"])])

    def step(self, frame: Frame, detections: Detections, obs: Observer = NullObserver()) -> TrackSet:
        r = self.filter.step(detections)
        clusters = kmeans_peaks(r.resampled, r.observations, self.T, params=self.params,
                                split_rule=self.split_rule)
        self._report_filter(detections, r, clusters, obs)
        return self._associate(frame, clusters.kept_centers, obs)

    def _report_filter(self, detections: Detections, r, clusters, obs: Observer) -> None:
        """Log every stage of the frame, each after ``obs.stage`` (computed first, so the
        NullObserver path costs nothing but the scalars' function calls)."""
        want_p, want_c = obs.wants("particles"), obs.wants("clusters")
        obs.stage("predict")
        if want_p:
            obs.points("phd/particles/predicted", r.predicted.states[:, :2],
                       weights=r.predicted.weights)

        obs.stage("birth")
        born = r.birth
        obs.scalar("phd/birth/count", len(born.particles))
        if want_p:
            obs.points("phd/particles/birth", born.particles.states[:, :2],
                       class_ids=born.det_index)
        if want_c:
            obs.boxes("phd/birth/detections", detections.boxes, labels=[
                f"J={j} M={m:.2f}" for j, m in zip(born.j_per_det, born.mass_near)],
                colors=(255, 140, 0, 255))

        obs.stage("update")
        up = r.updated
        obs.scalar("phd/mass", up.particles.mass)
        if want_p:
            obs.points("phd/particles/updated", up.particles.states[:, :2],
                       weights=up.particles.weights)
        if want_c:
            obs.boxes("phd/update/detections", detections.boxes, labels=[
                f"won {m:.2f}" for m in up.per_det_mass], colors=(255, 90, 90, 255))

        obs.stage("resample")
        obs.scalar("phd/particles/count", len(r.resampled))
        if want_p:
            obs.points("phd/particles/resampled", r.resampled.states[:, :2],
                       weights=r.resampled.weights)

        obs.stage("cluster")
        obs.scalar("phd/clusters/kept", int(clusters.kept.sum()))
        if want_p and len(r.resampled):
            obs.points("phd/clusters/members", r.resampled.states[:, :2],
                       class_ids=clusters.labels)
        if want_c and len(clusters):
            boxes = clusters.boxes()
            k = clusters.kept
            obs.boxes("phd/clusters/kept", boxes[k], class_ids=np.flatnonzero(k),
                      labels=[f"m={m:.2f}" for m in clusters.masses[k]])
            obs.boxes("phd/clusters/dropped", boxes[~k], colors=(128, 128, 128, 200),
                      labels=[f"m={m:.2f} < T" for m in clusters.masses[~k]])


class MTTracker(_AssociatingTracker):
    """MT (maggio2007 §4 baseline): graph-matching association directly on the detections.

    Detections carry no velocity, so vertices get NaN velocity and the associator estimates a
    track's velocity from its last two vertices.  Options: fields of ``AssocParams``."""

    name = "mt"

    def __init__(self, rng: np.random.Generator | None = None, **options):
        (assoc_kw,) = _split_options(options, AssocParams)
        super().__init__(AssocParams(**assoc_kw))

    def config(self) -> dict:
        return {"tracker": self.name, "assoc": asdict(self.associator.params)}

    def views(self):
        return ([("Association", ["assoc/**", "tracks/**"]), ("Tracks", ["tracks/**"])],
                [("Counts", ["tracks/count", "detections/count", "assoc/**"])])

    def step(self, frame: Frame, detections: Detections, obs: Observer = NullObserver()) -> TrackSet:
        z = xywh_to_cxcywh(detections.boxes)
        states = np.full((len(z), 6), np.nan)
        states[:, [0, 1, 4, 5]] = z
        return self._associate(frame, states, obs)
