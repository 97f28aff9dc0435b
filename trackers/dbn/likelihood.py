"""The DBN particle likelihood of feng2015 eqs. (8)–(12), as a PHD :class:`Likelihood`.

Reading of the paper: eq. (11) needs ``ψ_{k,z}(x) = (1 − p_M) g_k(z | x)``, a function of the
measurement z, while the DBN score of eq. (9) is a function of the particle alone ("the weight
for each particle x_k^i").  We combine them as

    log g(z | x) = log N(z; Hx, R(z))  +  s(x),

the maggio2007 Gaussian on the blob ``z = (y1, y2, w, h)`` (which blob the particle explains)
times the appearance score ``exp(s(x))`` of the particle's own box (whether it looks like a
person), with ``s`` one of (parameter ``score``):

- ``"logsigmoid"`` (default): ``s = c · log σ(a(x))``, the log-probability of "person" raised
  to ``c``; ≤ 0, so a confident person leaves g unchanged relative to the clutter κ(z) and a
  noise patch scales it down (its blob wins little mass in eq. (11)'s ``ψ / (κ + C)``);
- ``"logit"``: ``s = c · a(x)``, eq. (9) literally (``1 · W⁽³⁾`` read as the output unit's
  activation a); unbounded, so it also moves g against κ for people.

This is the ``apply = "particle"`` reading (the ``paper`` preset).  The tracker's default,
``apply = "blob"``, uses the DBN on the measurement instead (κ(z) scaled by the blob's noise
odds, see :mod:`.tracker`, "Where the score goes"); :class:`DBNLikelihood` is then used only
for the blobs' (and, for display, the particles') scores.

Cost: the Gaussian is cheap; the score needs the particle's features (integral-histogram
look-ups, :mod:`.features`) and a DBN forward pass.  :meth:`DBNLikelihood.log_g_pairs` scores
only the particles that appear in the candidate pairs (those inside some blob's gate), once
each; the dense :meth:`DBNLikelihood.log_g` (the filter's fallback) scores every particle.

The integral histograms of a frame are built once and reused for every call with that frame
(the blobs' scores and the particles' scores share them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from ..params import param
from ..phd.filter import OBS_COLS, OBS_DIM, LikelihoodParams, log_likelihood, obs_std
from ..types import Frame, cxcywh_to_xywh
from .features import FrameFeatures

SCORES = ("logsigmoid", "logit")
#: feature_height for a model that does not record its people's height (models trained before
#: train-dbn recorded it; the shipped model records 41.8: PETS09 people at half scale)
DEFAULT_BOX_HEIGHT = 48.0
APPLY = ("particle", "blob", "blob_particle")


@dataclass(frozen=True)
class DBNParams:
    """The DBN and how its score enters the PHD update (feng2015 §II-C, eq. (9))."""

    use_dbn: bool = param(True, "weight particles by the DBN score (false: the plain Gaussian "
                                "likelihood on blobs, the no-DBN baseline)")
    model: str = param("", "DBN model file (`pfscope train-dbn`); empty: the model shipped "
                           "in the package (trained on person / non-person crops of PETS09-S2L1 "
                           "and PETS09-S3MF1)")
    c: float = param(1.0, "the constant c of eq. (9) (the paper gives no value)",
                     paper="feng2015 eq. (9)")
    score: str = param("logsigmoid", "log-score s(x): 'logsigmoid' c·log σ(a) (default) or "
                                     "'logit' c·a (eq. (9) literally)")
    feature_scale: float = param(0.5, "image scale the colour/HOG histograms are taken at "
                                      "when feature_height is 0")
    feature_height: float = param(-1.0, "every box is described on the image-pyramid level "
                                         "(scales 1, 1/2, 1/4, ...) that brings its height "
                                         "nearest this many px, so the person scale comes "
                                         "from the box, not the video's resolution; -1: the "
                                         "people's height in the model's training set (its "
                                         "info 'box_height', 41.8 for the shipped one; 48 "
                                         "for a model without it); 0: one fixed "
                                         "feature_scale")
    accept: float = param(0.5, "a blob is accepted as a person when its DBN probability σ(a) "
                               ">= this; only accepted blobs give births (new-born target "
                               "selection, feng2015 §II)")
    apply: str = param("blob", "where the DBN score enters eq. (11) (tracker module docstring, "
                               "'Where the score goes'): 'particle' g(z|x)·exp(s(x)) (the "
                               "literal reading, preset 'paper'); 'blob' (default, measured "
                               "better) the blob's clutter intensity κ(z)·exp(−c·a(z)); "
                               "'blob_particle' both, the particle score normalised per blob "
                               "(best gated particle of each blob gets factor 1)")
    kappa_clip: float = param(5.0, "|c·a(z)| is clipped to this in the blob reading (κ(z) moves "
                                   "by at most a factor e^clip either way)")
    score_gate: float = param(0.99, "particles are scored only inside this confidence gate "
                                    "of some blob (elsewhere g is 0 for every blob)")

    def __post_init__(self):
        if self.score not in SCORES:
            raise ValueError(f"DBNParams.score must be one of {', '.join(SCORES)}, "
                             f"got {self.score!r}")
        if self.apply not in APPLY:
            raise ValueError(f"DBNParams.apply must be one of {', '.join(APPLY)}, "
                             f"got {self.apply!r}")
        if not self.kappa_clip > 0:
            raise ValueError(f"DBNParams.kappa_clip must be > 0, got {self.kappa_clip!r}")
        if not (self.feature_height >= 0 or self.feature_height == -1):
            raise ValueError(f"DBNParams.feature_height must be -1 or >= 0, "
                             f"got {self.feature_height!r}")
        if not 0 < self.feature_scale <= 1:
            raise ValueError(f"DBNParams.feature_scale must be in (0, 1], "
                             f"got {self.feature_scale!r}")
        if not 0 <= self.accept <= 1:
            raise ValueError(f"DBNParams.accept must be in [0, 1], got {self.accept!r}")
        if not 0 < self.score_gate < 1:
            raise ValueError(f"DBNParams.score_gate must be in (0, 1), got {self.score_gate!r}")


def state_boxes(states: np.ndarray) -> np.ndarray:
    """(N, 4) top-left boxes ``(x, y, w, h)`` of PHD states ``(y1, y2, v1, v2, w, h)``."""
    return cxcywh_to_xywh(np.asarray(states)[:, OBS_COLS])


def gaussian_pairs(states: np.ndarray, Z: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                   lk: LikelihoodParams) -> np.ndarray:
    """maggio2007's ``log g(z | x)`` for the pairs ``(rows[i], cols[i])`` only: (P,)."""
    x = states[rows][:, OBS_COLS]
    z = Z[cols]
    if lk.obs_std_source == "detection":
        std = obs_std(z[:, 2:4], lk)
    else:
        std = obs_std(x[:, 2:4], lk)
    q = (x - z) / std
    return (-0.5 * np.einsum("pk,pk->p", q, q) - np.log(std).sum(-1)
            - 0.5 * OBS_DIM * math.log(2 * math.pi))


class DBNLikelihood:
    """``g(z|x) = N(z; Hx, R) · exp(s(x))`` (module docstring): the PHD filter's Likelihood
    protocol, dense (``log_g``) and on candidate pairs (``log_g_pairs``)."""

    def __init__(self, model, params: DBNParams = DBNParams(),
                 lk: LikelihoodParams = LikelihoodParams()):
        self.model = model
        self.params = params
        self.lk = lk
        self._key: Optional[tuple] = None
        self._ff: Optional[FrameFeatures] = None
        #: :meth:`describe_ahead`'s features, by (union, boxes' bytes), for frame _ahead_key
        self._ahead: dict = {}
        self._ahead_key: Optional[tuple] = None

    @property
    def box_height(self) -> float:
        """The box height features are described at (``feature_height``; -1: the model's)."""
        fh = self.params.feature_height
        if fh < 0:
            return float((getattr(self.model, "info", None) or {}).get("box_height",
                                                                       DEFAULT_BOX_HEIGHT))
        return float(fh)

    def frame_features(self, frame: Frame, scaled: Optional[dict] = None) -> FrameFeatures:
        """The frame's integral histograms, built once per frame; ``scaled``: the frame's
        image already reduced by ``cv2.resize`` (INTER_AREA) at these scales
        (:class:`FrameFeatures`)."""
        key = (frame.index, id(frame.image))
        if self._key != key or self._ff is None:
            cfg = replace(self.model.features, box_height=self.box_height)
            self._ff = FrameFeatures(frame.image, cfg, self.params.feature_scale, scaled)
            self._key = key
        return self._ff

    def describe_ahead(self, frame: Frame, requests) -> None:
        """The features of the boxes about to be scored in this frame, computed together
        (``requests``: ``(boxes, union)`` pairs, :meth:`FrameFeatures.describe_many`: the same
        floats as one call each): the next :meth:`logits` (``union`` false) or
        :meth:`logits_union` (true) call on the same boxes of this frame reads them."""
        ff = self.frame_features(frame)
        feats = ff.describe_many(requests)
        self._ahead = {(bool(u), np.asarray(b, dtype=np.float64).tobytes()): f
                       for (b, u), f in zip(requests, feats)}
        self._ahead_key = self._key

    def _features(self, boxes_xywh: np.ndarray, frame: Frame, union: bool) -> np.ndarray:
        ff = self.frame_features(frame)
        if self._ahead and self._ahead_key == self._key:
            f = self._ahead.pop((union, np.asarray(boxes_xywh, dtype=np.float64).tobytes()),
                                None)
            if f is not None:
                return f
        return ff.describe_union(boxes_xywh) if union else ff.describe(boxes_xywh)

    def logits(self, boxes_xywh: np.ndarray, frame: Frame) -> np.ndarray:
        """DBN output activations ``a`` (N,) of boxes (top-left, full-resolution px)."""
        return self.model.logits(self._features(boxes_xywh, frame, False))

    def logits_union(self, boxes_xywh: np.ndarray, frame: Frame) -> np.ndarray:
        """:meth:`logits` of boxes close together (one crop over their union,
        :meth:`FrameFeatures.describe_union`)."""
        return self.model.logits(self._features(boxes_xywh, frame, True))

    def log_score(self, logits: np.ndarray) -> np.ndarray:
        """``s(x)`` from the DBN activations (module docstring)."""
        a = np.asarray(logits, dtype=np.float64)
        if self.params.score == "logit":
            return self.params.c * a
        return self.params.c * -np.logaddexp(0.0, -a)           # c · log σ(a)

    def particle_log_score(self, states: np.ndarray, frame: Frame) -> np.ndarray:
        return self.log_score(self.logits(state_boxes(states), frame))

    def log_g(self, states: np.ndarray, Z: np.ndarray, frame: Optional[Frame]) -> np.ndarray:
        """(N, N_z) ``log g(z|x)``, every particle scored (the dense route)."""
        g = log_likelihood(states, Z, self.lk)
        if frame is None or len(states) == 0 or len(Z) == 0:
            return g
        return g + self.particle_log_score(states, frame)[:, None]

    def log_g_pairs(self, states: np.ndarray, Z: np.ndarray, rows: np.ndarray,
                    cols: np.ndarray, frame: Optional[Frame]) -> np.ndarray:
        """(P,) ``log g(Z[cols[i]] | states[rows[i]])``: each particle in ``rows`` is scored
        once, whatever the number of its pairs."""
        rows = np.asarray(rows, dtype=np.int64)
        cols = np.asarray(cols, dtype=np.int64)
        g = gaussian_pairs(states, Z, rows, cols, self.lk)
        if frame is None or len(rows) == 0:
            return g
        uniq, inv = np.unique(rows, return_inverse=True)
        return g + self.particle_log_score(states[uniq], frame)[inv]


__all__ = ["DBNParams", "DBNLikelihood", "gaussian_pairs", "state_boxes", "SCORES", "APPLY"]
