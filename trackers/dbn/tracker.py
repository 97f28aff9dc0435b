"""DBN-PHD (feng2015) and its no-DBN baseline: a particle PHD filter on background-subtraction
blobs whose particle likelihood includes a deep belief network score.

One frame (stages, in order):

==========  ===================================================================================
background  codebook background subtraction (:mod:`.codebook`; MOG2/KNN by parameter) →
            Mask ``dbn/foreground`` (full resolution)
blobs       morphology + connected components → blobs = the measurements Z_k; each blob's box
            scored by the DBN; a blob bigger than the scene's person (:mod:`.scale`, learnt
            from the accepted blobs) is searched with person-sized windows the DBN scores,
            and the windows it keeps replace the blob (Scalar ``dbn/blobs/split``): Boxes
            ``dbn/blobs/accepted`` (role detection) and ``dbn/blobs/rejected`` (role
            dropped), values ``dbn`` = σ(a), ``fill``; an Event per rejected blob says why
            (its score against ``accept``)
predict     persistent particles moved by maggio2007's motion model, × survival (eqs. (1), (7))
            → Points ``dbn/particles/predicted`` (weights)
birth       newborn particles around the *accepted* blobs only (DBN new-born selection),
            J_z = J_max·max(0, 1 − M(z)), each weighing 1/J_k (eq. (10)) → Points
            ``dbn/particles/birth`` (ids = blob)
features    colour + HOG integral-histogram features and DBN score of every particle inside
            some blob's gate → Points ``dbn/particles/score`` (weights = σ(a), values
            ``score`` = a); Scalar ``dbn/particles/scored``
update      eqs. (11)–(12) with ``log g = log N(z; Hx, R) + s(x)`` (:mod:`.likelihood`),
            evaluated on gated pairs only → Points ``dbn/particles/before`` (prior weights) and
            ``dbn/particles/after`` (updated weights); Boxes ``dbn/update/blobs`` value ``won``
            = C/(κ + C); Scalar ``dbn/mass``
resample    Algorithm 3 (:func:`resample_alg3`) → Points ``dbn/particles/resampled``; Scalars
            ``dbn/n_hat`` (N̂_k = Σ w̃), ``dbn/particles/count``
cluster     maggio2007's modified K-means peaks (reused) → Boxes ``dbn/clusters/kept`` /
            ``dropped`` (value m)
associate   maggio2007's graph-matching association (reused, ``GraphAssociator``) → tracks
==========  ===================================================================================

The baseline ``phd-bgsub`` is this class with ``use_dbn = false``: every blob gives births and
g is the plain Gaussian (the ``features`` stage is empty).  ``--tracker dbn-phd --set
use_dbn=false`` is the same tracker.

Why the step calls the filter's stage functions instead of ``PHDFilter.step``: feng2015 changes
three of its parts — births only from DBN-accepted blobs with weight 1/J_k (eq. (10)), a fixed
particle budget N (Algorithm 3), and a likelihood evaluated only on gated pairs — so the
tracker keeps a :class:`~pfscope.trackers.phd.filter.PHDFilter` (its parameters, generator,
particles and likelihood) and runs :func:`predict`, :func:`birth` and :func:`update` of
``phd.filter`` itself.

Algorithm 3 versus the existing resampler (:mod:`pfscope.trackers.smc.resampling`): the draw is
the same systematic scheme (one offset μ₁ ~ U[0, 1/N], μ_j = μ₁ + (j − 1)/N, inverse CDF of
w̃/N̂_k) and both give every offspring weight N̂_k/N; the difference is the count — Algorithm 3
keeps a fixed N particles whatever N̂_k, maggio2007's resampler draws L_k = ρ·M̂_k.
:func:`resample_alg3` implements the pseudo-code (reading ``c_1 = 0`` as ``c_1 = w̃_1/N̂_k``: as
printed, the first particle could never be drawn); ``count = "per_target"`` gives the ρ·N̂
rule instead.

Where the score goes (parameter ``dbn.apply``).  feng2015 says the DBN score of eq. (9) is
"the weight for each particle" and feeds eq. (11), whose clutter term ``κ_{k,z}(z)`` is written
per measurement.  Two readings:

- ``"particle"`` (literal; preset ``paper``): ``ψ_{k,z}(x) = (1 − p_M) N(z; Hx, R) e^{s(x)}``
  (:mod:`.likelihood`).  Measured on PETS09-S2L1 this lowers the weight of *real* people's
  particles too (a DBN score < 1 for a good but not perfectly centred box), so in eq. (11)
  ``ψ/(κ + C)`` the clutter κ wins more of each person's blob, their clusters fall under the
  K-means threshold T and misses rise (README, "DBN-PHD (feng2015): Table I on our data").
- ``"blob"`` (default): the score classifies the *measurement* (person vs noise, which is
  what the paper trains it for, §II-B/D.2) and enters eq. (11) through ``κ_{k,z}(z)``.
  Treat the blob's features f as part of the measurement: a target generates (z, f) with
  ``g(z|x) p(f|person)``, clutter with ``κ(z) p(f|noise)``; dividing eq. (11)'s numerator and
  denominator by ``p(f|person)`` leaves ``ψ_{k,z}(x) / (κ(z)·p(f|noise)/p(f|person) + C_k(z))``
  with C_k(z) of eq. (12) unchanged.  The DBN's logit a(z) estimates
  ``log p(person|f)/p(noise|f)``, so ``κ_{k,z}(z) = κ(z) · exp(−c·a(z))`` (|c·a| clipped to
  ``kappa_clip``): an accepted blob (a > 0) competes with less clutter, so a person's mass
  stays near 1; a noise blob (a < 0) is mostly explained as clutter.  Particles keep the
  plain Gaussian g, so no good particle of a person is down-weighted, and only the blobs are
  scored (the ``features`` stage scores particles only for display at level ``particles``).
- ``"blob_particle"``: both, with the particle score normalised within each blob
  (``s(x) − max_{x' gated to z} s(x')``: the best particle of every blob keeps factor 1, so
  the score shapes the cloud inside a blob without moving the blob's total against κ).

The tracker reads its model's weights without torch (:mod:`.weights`); torch is loaded only
to train one (``pfscope train-dbn``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Optional

import cv2
import numpy as np

from ..api import StepResult, register
from ..params import param, part, to_dict
from ..phd.association import AssocParams
from ..phd.clustering import kmeans_peaks
from ..phd.gating import LogGPairs, gate_pairs
from ..phd.filter import (OBS_COLS, BirthParams, PHDFilter, PHDParams, birth, gate_threshold,
                          log_clutter_density, obs_std, predict, update)
from ..phd.tracker import ClusterParams, _AssociatingTracker
from ..report import Boxes, Mask, Points, StageLog
from ..smc.resampling import resample as smc_resample
from ..smc.weights import ParticleSet
from ..types import Detections, Frame, xywh_to_cxcywh
from .codebook import BackgroundParams, ForegroundModel, blobs_from_mask
from .likelihood import DBNLikelihood, DBNParams, gaussian_pairs, state_boxes
from .scale import (PersonScale, SplitParams, box_fill, needs_split, select_windows,
                    split_candidates)

COUNTS = ("fixed", "per_target")
BIRTH_WEIGHTS = ("eq10", "intensity")


@dataclass(frozen=True)
class ResampleParams:
    """Algorithm 3 of feng2015 (module docstring)."""

    n_particles: int = param(2000, "particle budget N kept after resampling (Algorithm 3; "
                                   "the paper gives no value)", paper="feng2015 Alg. 3")
    count: str = param("fixed", "'fixed': N particles (Algorithm 3); 'per_target': "
                                "ρ·N̂_k particles clipped to [1, 4N] (maggio2007's rule)")
    per_target_rho: float = param(500.0, "particles per target for count='per_target'")

    def __post_init__(self):
        if self.n_particles < 1:
            raise ValueError(f"ResampleParams.n_particles must be >= 1, got {self.n_particles}")
        if self.count not in COUNTS:
            raise ValueError(f"ResampleParams.count must be one of {', '.join(COUNTS)}, "
                             f"got {self.count!r}")
        if not self.per_target_rho > 0:
            raise ValueError(f"ResampleParams.per_target_rho must be > 0, "
                             f"got {self.per_target_rho}")


@dataclass(frozen=True)
class BirthSelection:
    """New-born targets from foreground blobs (feng2015 §II-D.3)."""

    birth_weight: str = param("eq10", "'eq10': every newborn weighs 1/J_k (feng2015 eq. (10)); "
                                      "'intensity': birth_intensity/J_z per blob (maggio2007)",
                              paper="feng2015 eq. (10)")
    select: str = param("accepted", "'accepted': only DBN-accepted blobs give births "
                                    "(feng2015 §II new-born selection); 'weighted': every blob "
                                    "does, its newborn weights times the DBN's P(person)")

    def __post_init__(self):
        if self.birth_weight not in BIRTH_WEIGHTS:
            raise ValueError(f"BirthSelection.birth_weight must be one of "
                             f"{', '.join(BIRTH_WEIGHTS)}, got {self.birth_weight!r}")


def _filter_defaults() -> PHDParams:
    # J_max 500 per blob (maggio2007 §4: 1000): with eq. (10) the newborn mass is 1 per frame
    # whatever J, and half the newborn halve the feature cost.
    return PHDParams(birth=BirthParams(j_max=500))


@dataclass(frozen=True)
class DBNPHDParams:
    """DBN-PHD: background model, DBN, the PHD filter's parts, births, Algorithm 3, peaks and
    association."""

    background: BackgroundParams = part(BackgroundParams, "background subtraction and blobs")
    dbn: DBNParams = part(DBNParams, "the DBN score in the likelihood")
    split: SplitParams = part(SplitParams, "scene-learnt person size and the split of "
                                           "multi-person blobs (DBN-PHD only)")
    filter: PHDParams = field(default_factory=_filter_defaults,
                              metadata={"doc": "particle PHD filter (motion, likelihood, "
                                               "clutter, birth)", "paper": None})
    births: BirthSelection = part(BirthSelection, "newborn weights")
    resample: ResampleParams = part(ResampleParams, "Algorithm 3 resampling")
    clusters: ClusterParams = part(ClusterParams, "modified K-means peaks (maggio2007 §3)")
    assoc: AssocParams = part(AssocParams, "graph-matching association (maggio2007 §3)")


def resample_alg3(ps: ParticleSet, n: int, rng: np.random.Generator) -> ParticleSet:
    """feng2015 Algorithm 3: ``n`` particles by systematic resampling of ``w̃ / N̂_k``, each
    weighing ``N̂_k / n`` with ``N̂_k = Σ w̃`` — exactly the shared systematic resampler
    (:func:`pfscope.trackers.smc.resample`) with a fixed ``n``."""
    return smc_resample(ps, n, rng, "systematic")


def _gated_pairs(states: np.ndarray, Z: np.ndarray, params: PHDParams, confidence: float):
    """Candidate pairs (rows, cols): particle inside the ``confidence`` gate of blob z under
    the observation noise R(z) — the PHD filter's grid-indexed gate (:mod:`..phd.gating`), so
    no (particles × blobs) array is formed."""
    chunks = list(gate_pairs(states[:, OBS_COLS], Z, gate_threshold(confidence),
                             std_z=obs_std(Z[:, 2:4], params.likelihood)))
    if not chunks:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return (np.concatenate([c.rows for c in chunks]).astype(np.int64),
            np.concatenate([c.cols for c in chunks]).astype(np.int64))


#: ``--preset paper``: feng2015 as published, differing from the default in exactly these fields
#: (tests/test_dbn.py checks it): the literal eq. (9) score on every particle, maggio2007's
#: J_max, the codebook trained online on the first frames (Kim 2005) instead of our
#: offline temporal-median start, and no search for people inside big blobs (:mod:`.scale`).
PAPER_CHANGES: dict[str, object] = {
    "dbn.score": "logit",                  # eq. (9): s = c · a(x)
    "dbn.apply": "particle",               # eq. (9) weighs every particle
    "filter.birth.j_max": PHDParams().birth.j_max,  # maggio2007 §4's J_max
    "background.initial": "online",        # Kim 2005 §2: train on the first N frames
    "split.enabled": False,                # feng2015 has no rule for multi-person blobs
}


@register(presets={"default": DBNPHDParams(), "paper": DBNPHDParams(
    filter=PHDParams(), dbn=DBNParams(score="logit", apply="particle"),
    background=BackgroundParams(initial="online"), split=SplitParams(enabled=False))})
class DBNPHDTracker(_AssociatingTracker):
    """DBN-PHD: codebook blobs → particle PHD with a DBN colour+HOG likelihood → K-means →
    graph association."""

    name = "dbn-phd"
    paper = "feng2015"
    stages = ("background", "blobs", "predict", "birth", "features", "update", "resample",
              "cluster", "associate")
    needs_detections = False
    needs_image = True
    Params = DBNPHDParams

    def __init__(self, params: Optional[DBNPHDParams] = None, *, rng: np.random.Generator,
                 model=None):
        self.params = params if params is not None else self.Params()
        super().__init__(self.params.assoc)
        self.background = ForegroundModel(self.params.background)
        dp = self.params.dbn
        self.dbn: Optional[DBNLikelihood] = None
        if dp.use_dbn:
            if model is None:
                # the weights in numpy, read without importing torch (~2.6 s of CPU)
                from .weights import default_weights, load_weights

                model = load_weights(dp.model) if dp.model else default_weights()
            self.dbn = DBNLikelihood(model, dp, self.params.filter.likelihood)
        # the filter's parts; its likelihood is the DBN one (or maggio2007's Gaussian)
        self.filter = PHDFilter(self.params.filter, rng, likelihood=self.dbn)
        self.person_scale = PersonScale(self.params.split)

    def prepare(self, source, first: int, last: int) -> None:
        """Offline start (the pipeline calls this for a recorded clip, not with ``--online``):
        the background starts from the temporal median of frames sampled evenly over
        ``first..last`` (``background.initial = 'median'``, :meth:`ForegroundModel.prime`)."""
        bp = self.params.background
        if bp.method != "codebook" or bp.initial != "median":
            return
        from ..data.sources import sample_frames

        self.background.prime(sample_frames(source, bp.median_frames, first, last))

    def upcoming(self, frame: Frame) -> None:
        """The pipeline's look-ahead on a recorded clip: ``frame`` is the one the next
        :meth:`step` gets.  Its background stage (resize, codebook, morphology: ~a quarter of
        the step) then runs on a helper thread, started as soon as this step's own mask is
        done, while this frame's blobs, filter and association, the recording and the scoring
        go on: the same masks in the same order (:meth:`ForegroundModel.upcoming`)."""
        self.background.upcoming(frame)

    def config(self) -> dict:
        cfg = {"tracker": self.name, "params": to_dict(self.params)}
        if self.dbn is not None:
            cfg["model"] = {"features": self.dbn.model.features.to_dict(),
                            "hidden": list(self.dbn.model.hidden),
                            "info": dict(self.dbn.model.info)}
        return cfg

    def _stage_log(self, level: Optional[str]) -> StageLog:
        """The frame's stage log (a benchmark overrides this to time the stages)."""
        return StageLog(self.stages, level)

    def _windows(self, boxes, mask):
        """``(big, windows, fg_ii)``: the blobs bigger than the scene's person (:mod:`.scale`),
        the person-sized windows searched inside each (blob index -> (K, 4)) and the mask's
        integral image (None when no blob is big)."""
        sp = self.params.split
        big = needs_split(boxes, self.person_scale, sp)
        if not big.any():
            return big, {}, None
        fg_ii = cv2.integral(mask)
        return big, {int(i): split_candidates(boxes[i], self.person_scale, sp, fg_ii,
                                              self.params.background.scale)
                     for i in np.flatnonzero(big)}, fg_ii

    def _split(self, boxes, fill, blob_a, windows, frame):
        """Blobs bigger than the scene's person searched for people (:mod:`.scale`; ``windows``
        from :meth:`_windows`): returns the measurements (split blobs replaced by the windows
        the DBN kept), their fill and DBN logits, and the number of blobs split.  The person
        size learns from the accepted blobs that were not split."""
        sp = self.params.split
        accept = self.params.dbn.accept
        scale = self.params.background.scale
        big, cands, fg_ii = windows
        out_b, out_f, out_a = [boxes[~big]], [fill[~big]], [blob_a[~big]]
        n_split = 0
        for i, cand in cands.items():
            if len(cand):
                a = self.dbn.logits_union(cand, frame)
                kept = select_windows(cand, 1.0 / (1.0 + np.exp(-a)), accept, sp.overlap)
                if len(kept):
                    out_b.append(cand[kept])
                    out_f.append(box_fill(fg_ii, cand[kept], scale))
                    out_a.append(a[kept])
                    n_split += 1
                    continue
            out_b.append(boxes[i:i + 1])
            out_f.append(fill[i:i + 1])
            out_a.append(blob_a[i:i + 1])
        self.person_scale.add(boxes[~big][blob_a[~big] >= _logit(accept)])
        return np.concatenate(out_b), np.concatenate(out_f), np.concatenate(out_a), n_split

    # ------------------------------------------------------------------------------- step

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult:
        p = self.params
        fp = p.filter
        rng = self.filter.rng
        log = self._stage_log(level)
        want_p, want_c = log.wants("particles"), log.wants("clusters")

        log.stage("background")
        mask = self.background.mask(frame)
        if self.dbn is not None and frame.image.ndim == 3:
            # the features' pyramid level at the background's scale is that same resize
            self.dbn.frame_features(frame, {p.background.scale: self.background.small})
        # the mask is 0/1: its mean is the count over the size (the same float, no float64 pass)
        log.scalar("dbn/foreground/fraction", np.count_nonzero(mask) / mask.size if mask.size
                   else 0.0)
        if want_c:
            H, W = frame.image.shape[:2]
            full = cv2.resize(mask, (W, H), interpolation=cv2.INTER_NEAREST)
            log.add(Mask("dbn/foreground", full, ("background", "foreground")))

        log.stage("blobs")
        bp = p.background
        boxes, fill = blobs_from_mask(mask, bp.scale, bp.min_area, bp.max_foreground)
        Z = xywh_to_cxcywh(boxes)
        n_split = 0
        if self.dbn is not None and len(boxes):
            windows = self._windows(boxes, mask) if p.split.enabled else None
            # every box the DBN scores in this stage, described together (the same features)
            self.dbn.describe_ahead(frame, [(boxes, False)] + [
                (c, True) for c in (windows[1].values() if windows else ()) if len(c)])
            blob_a = self.dbn.logits(boxes, frame)
            if windows is not None:
                boxes, fill, blob_a, n_split = self._split(boxes, fill, blob_a, windows, frame)
                Z = xywh_to_cxcywh(boxes)
            blob_prob = 1.0 / (1.0 + np.exp(-blob_a))
            accepted = blob_prob >= p.dbn.accept
        else:
            blob_a = np.zeros(len(boxes))
            blob_prob = np.full(len(boxes), np.nan)
            accepted = np.ones(len(boxes), dtype=bool)
        log.scalar("dbn/blobs/count", len(boxes))
        log.scalar("dbn/blobs/split", n_split)
        log.scalar("dbn/blobs/rejected", int((~accepted).sum()))
        for i in np.flatnonzero(~accepted):
            x, y, w, h = boxes[i]
            log.event("dbn/blobs", f"frame {frame.index}: blob at ({x:.0f}, {y:.0f}, {w:.0f}x"
                                   f"{h:.0f}) rejected as noise: DBN P(person) = "
                                   f"{blob_prob[i]:.2f} < accept {p.dbn.accept:g} (no births)",
                      "DEBUG")
        if want_c:
            log.add(Boxes("dbn/blobs/accepted", boxes[accepted], role="detection",
                          ids=np.flatnonzero(accepted), id_kind="detection",
                          values={"dbn": blob_prob[accepted], "fill": fill[accepted]}))
            log.add(Boxes("dbn/blobs/rejected", boxes[~accepted], role="dropped",
                          ids=np.flatnonzero(~accepted), id_kind="detection",
                          values={"dbn": blob_prob[~accepted], "fill": fill[~accepted]}))

        log.stage("predict")
        predicted = predict(self.filter.particles, fp.motion, rng)
        if want_p:
            log.add(Points("dbn/particles/predicted", predicted.states[:, :2],
                           weights=predicted.weights))

        log.stage("birth")
        weighted = p.births.select == "weighted" and self.dbn is not None
        acc_idx = np.arange(len(Z)) if weighted else np.flatnonzero(accepted)
        born = birth(predicted, Z[acc_idx], fp, rng)
        newborn = born.particles
        J = len(newborn)
        if J and p.births.birth_weight == "eq10":
            newborn = newborn.with_log_weights(np.full(J, -math.log(J)))   # eq. (10): 1/J_k
        if J and weighted:              # every blob gives births, weighted by P(person)
            lp = -np.logaddexp(0.0, -blob_a[acc_idx[born.det_index]])
            newborn = newborn.with_log_weights(newborn.log_weights + lp)
        log.scalar("dbn/birth/count", J)
        if want_p:
            log.add(Points("dbn/particles/birth", newborn.states[:, :2],
                           ids=acc_idx[born.det_index], id_kind="detection"))

        log.stage("features")
        cand = predicted.concat(newborn)
        rows, cols = _gated_pairs(cand.states, Z, fp, p.dbn.score_gate)
        log_g_pairs = gaussian_pairs(cand.states, Z, rows, cols, fp.likelihood)
        apply = p.dbn.apply
        on_particles = apply in ("particle", "blob_particle")
        # the gated particles (each once) only when they are scored: a sort of every pair
        score_them = self.dbn is not None and len(rows) > 0 and (on_particles or want_p)
        if not score_them:
            log.scalar("dbn/particles/scored", 0)
        else:
            uniq, inv = np.unique(rows, return_inverse=True)
            log.scalar("dbn/particles/scored", len(uniq))
            logits = self.dbn.logits(state_boxes(cand.states[uniq]), frame)
            if on_particles:
                s_pairs = self.dbn.log_score(logits)[inv]
                if apply == "blob_particle":        # best gated particle of each blob: 1
                    best = np.full(len(Z), -np.inf)
                    np.maximum.at(best, cols, s_pairs)
                    s_pairs = s_pairs - best[cols]
                log_g_pairs = log_g_pairs + s_pairs
            if want_p:
                log.add(Points("dbn/particles/score", cand.states[uniq, :2],
                               weights=1.0 / (1.0 + np.exp(-logits)), values={"score": logits}))

        log.stage("update")
        log_g = LogGPairs(rows, cols, log_g_pairs)  # sparse: the update never sees N × Z
        log_kappa = (log_clutter_density(Z, fp.clutter, fp.likelihood) if len(Z)
                     else np.zeros(0))
        if self.dbn is not None and len(Z) and apply in ("blob", "blob_particle"):
            # κ_{k,z}(z) = κ(z)·exp(−c·a(z)): the blob's noise odds (module docstring)
            clip = p.dbn.kappa_clip
            log_kappa = log_kappa - np.clip(p.dbn.c * blob_a, -clip, clip)
        up = update(cand, log_g, log_kappa, fp.likelihood.p_miss)
        updated = up.particles
        log.scalar("dbn/mass", updated.mass)
        if want_p:
            log.add(Points("dbn/particles/before", cand.states[:, :2], weights=cand.weights))
            log.add(Points("dbn/particles/after", updated.states[:, :2],
                           weights=updated.weights))
        if want_c:
            log.add(Boxes("dbn/update/blobs", boxes, role="detection",
                          values={"won": up.per_det_mass, "dbn": blob_prob}))

        log.stage("resample")
        n_hat = updated.mass
        rp = p.resample
        n = rp.n_particles
        if rp.count == "per_target":
            n = (int(np.clip(round(rp.per_target_rho * n_hat), 1, 4 * rp.n_particles))
                 if n_hat > 0 else 0)
        resampled = resample_alg3(updated, n, rng)
        self.filter.particles = resampled
        log.scalar("dbn/n_hat", n_hat)
        log.scalar("dbn/particles/count", len(resampled))
        if want_p:
            log.add(Points("dbn/particles/resampled", resampled.states[:, :2],
                           weights=resampled.weights))

        log.stage("cluster")
        cp = p.clusters
        clusters = kmeans_peaks(resampled, Z, cp.T, params=fp, split_rule=cp.split_rule)
        log.scalar("dbn/clusters/kept", int(clusters.kept.sum()))
        if want_p and len(resampled):
            log.add(Points("dbn/clusters/members", resampled.states[:, :2],
                           ids=clusters.labels, id_kind="cluster"))
        if want_c and len(clusters):
            cb = clusters.boxes()
            k = clusters.kept
            log.add(Boxes("dbn/clusters/kept", cb[k], ids=np.flatnonzero(k), id_kind="cluster",
                          values={"m": clusters.masses[k]}))
            log.add(Boxes("dbn/clusters/dropped", cb[~k], role="dropped",
                          values={"m": clusters.masses[~k]}))
        return self._associate(frame, clusters.kept_centers, log)


def _logit(p: float) -> float:
    p = min(max(p, 1e-12), 1 - 1e-12)
    return math.log(p / (1 - p))


def _baseline_params() -> DBNPHDParams:
    return DBNPHDParams(dbn=DBNParams(use_dbn=False))


@register(presets={"default": _baseline_params(),
                   "paper": replace(_baseline_params(), filter=PHDParams(),
                                    background=BackgroundParams(initial="online"))})
class PHDBgsubTracker(DBNPHDTracker):
    """PHD on background-subtraction blobs without the DBN (DBN-PHD's baseline, feng2015 "PHD")."""

    name = "phd-bgsub"
    paper = "feng2015 (baseline)"
