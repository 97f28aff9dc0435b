"""Graph-matching data association of PHD-MT and MT (maggio2007 §3, after Shafique & Shah 2005).

maggio2007 §3 links the per-frame estimates ``x̂_k`` (PHD-MT: the K-means cluster centres; MT:
the raw detections) into tracks with a graph ``G``: the vertices of the last ``K`` frames
``{V_{k-i}}_{i=1..K}`` get edges to the vertices ``V_k`` of the new frame, the gain of an edge is
``log f(x̂_k | x̂_{k-i})`` -- the single-target transition density of §2 propagated over the ``i``
frames of the gap -- and the path cover of maximum gain is the set of tracks.  A vertex without a
backward edge starts a track, one without a forward edge ends it; a track therefore survives a
gap (a missed detection, an occlusion) of up to ``K`` frames and keeps its identity.  §4: ``K=50``,
tracks shorter than 5 frames are discarded.

Online, greedy extension (Shafique & Shah 2005, the non-iterative greedy algorithm).  The cover is
grown one frame at a time and edges once chosen are never revised, so a vertex that already has a
forward edge can never get another: the only candidate sources are the *tails* -- the last vertex
of each live track -- whose frame lies within ``K`` frames of the new one.  Per frame, the best
extension is a maximum-weight bipartite matching between tails and new vertices, solved exactly
with :func:`scipy.optimize.linear_sum_assignment`.  Only the tails are kept (bounded memory: at
most the number of vertices of the last ``K`` frames); a tail older than ``K`` frames is forgotten
and its track reported as ended.

Readings and choices (all constants are :class:`AssocParams` fields):

* **State** ``x = (y1, y2, v1, v2, w, h)``: centre, velocity (px/frame), size.  The observable part
  ``z = (y1, y2, w, h)`` is what an edge scores: the density is the marginal of ``f`` on the
  observable components (a detection has no velocity; a cluster centre's velocity is an estimate
  used to predict, not something to score).
* **Transition** (§2, parameters of §4): first-order (constant-velocity) Gaussian dynamics on the
  position, zero-order on the size, noise std proportional to the size at the *earlier* vertex:
  ``σ_v1 = 0.03 w``, ``σ_v2 = 0.03 h``, ``σ_w = 0.1 w``, ``σ_h = 0.1 h``.  The acceleration noise
  is read as a piecewise-constant acceleration over each frame, ``x ← F x + G a`` with
  ``F = [[1, 1], [0, 1]]``, ``G = [c, 1]ᵀ`` per axis, ``c = accel_to_position = ½`` (dt²/2; the
  same reading as :mod:`pfscope.trackers.phd.motion`), so that ``σ_v`` is the std of the per-frame
  velocity change.  Over a gap of ``i`` frames the mean is ``F^i x`` and the covariance
  ``Σ_{j<i} F^j Q F^jᵀ`` in closed form: position variance ``σ_v² Σ_{j<i} (j+c)²``
  ``= σ_v² [(i−1)i(2i−1)/6 + c i(i−1) + c² i]`` (``= σ_v² i(4i²−1)/12`` for ``c = ½``);
  size variance ``i σ_w²`` (random walk, std fixed at the earlier vertex's size).
* **Estimate noise.**  Both ends of an edge are noisy estimates, not true states.  We add the
  observation noise ``σ^z`` of §4 (``σ^z_w = max(0.15 w, 1)``, ``σ^z_h = max(0.15 h, 1)``,
  ``σ^z_y = σ^z_{w,h}/2``, at the earlier vertex's size) *twice* -- once for the tail, once for
  the new vertex -- to the covariance of the evaluated marginal: the residual ``z_k − F^i x̂`` of two
  noisy estimates has the variance of both errors.
* **Unknown velocity (MT).**  A vertex whose velocity is NaN has no velocity estimate.  For a track
  with at least two vertices the tail velocity is then the finite difference of its last two
  vertices, ``v̂ = (y_t − y_p)/Δ``; its error is carried exactly into the prediction ``y_t + i v̂``,
  whose tail-side variance is ``σ_t²(1 + i/Δ)² + σ_p² (i/Δ)²`` (``σ_t``, ``σ_p`` the estimate
  noise of the last two vertices).  A one-vertex track predicts zero velocity with a prior std
  ``speed_prior · (w, h)`` per frame (§2's birth intensity is Gaussian on the speed amplitude but
  §4 gives no number: 0.1 size/frame is ours), adding ``i² (speed_prior·w)²``.  A given (finite)
  velocity, like a cluster centre's, is used as the mean with no extra variance.
* **Edge weight.**  A log-density can be negative and the empty extension has weight 0, so the
  gain needs a floor.  An edge is admissible iff its Mahalanobis distance is inside the
  ``gate`` (99.9 %) chi-square quantile, 4 degrees of freedom.  Its weight is
  ``gain − floor(tail)`` where ``floor(tail)`` is the log-density at the gate of the *widest*
  edge that tail can have -- the one of gap ``K``:
  ``weight = ½(χ²_gate − d²) + ½ log(det Σ_K / det Σ_i)``.  Every admissible edge then has
  positive weight (a track can survive any gap up to ``K``), while the log-determinant of
  ``log f`` is kept, so at equal fit a recently seen track beats one unseen for several frames.
  (With a per-edge floor the determinant cancels, and a dormant tail with its wide gate steals
  the detections of a target walking past it -- the very occlusions §4 wants to bridge.)
* **Matching.**  Maximum-weight matching of the admissible edges, exact.  Tails are kept sorted by
  track id and new vertices in input order; among matchings of equal total weight the one
  :func:`scipy.optimize.linear_sum_assignment` returns on that canonical matrix is taken, so the
  result is a pure function of the input sequence.  A matched new vertex continues its tail's
  track; an unmatched one starts a new track; ids start at 1, increase and are never reused.
* **Track length** counts vertices (estimates supporting the track), not the frame span: a track
  is *confirmed* once it has ``min_length`` (5) vertices; unconfirmed tracks are not reported.
* **Reporting, two ways.**  (a) zero lag: :attr:`AssocResult.confirmed` marks the new vertices of
  confirmed tracks -- the first ``min_length − 1`` vertices of every track are then never
  reported; (b) bounded lag ``L = min_length − 1`` frames: :attr:`AssocResult.finalised` holds the
  rows of frame ``k − L`` whose track is confirmed by frame ``k`` (a track seen in consecutive
  frames is reported from its first frame), and :meth:`GraphAssociator.flush` returns the rest at
  the end of a sequence.  A track confirmed only after more than ``L`` frames (because of gaps)
  loses its rows older than ``L`` frames.
* **Gap filling** (``fill_gaps``, not in the paper; off in the ``paper`` preset).  An edge of gap
  ``i > 1`` links a track across ``i − 1`` frames where it had no estimate.  With ``fill_gaps``
  those frames get a row by linear interpolation of ``(y1, y2, w, h)`` between the two ends (the
  velocity of the row is the mean velocity over the gap), flagged in
  :attr:`FinalRows.filled`.  Only frames strictly inside a chosen edge are filled -- never before
  a track's first vertex, after its last, or across an edge that was not chosen; a gap box that
  another track's estimate of the frame covers (IoU >= ``fill_overlap``) is not filled -- and only
  frames still held back: the report lag becomes ``L = max(min_length − 1, depth)`` so that every
  gap the graph can bridge is still in the buffer when it is closed (rows stay in frame order).
* **Re-linking** (``relink_depth``, not in the paper; off in ``paper``).  An occlusion or a dip of
  the PHD mass longer than ``K`` frames ends a track, and the target comes back under a new id.
  A confirmed track that falls out of the window is kept (its last vertex, velocity terms and
  colour model) for ``relink_depth`` frames after its last vertex.  When a track is confirmed
  (it reaches ``min_length`` vertices), its *first* vertex is scored against every kept track
  that ended before it began, with a damped motion model over the gap
  (:func:`propagate_damped`: the same acceleration noise, the velocity pulled back to rest with
  time constant ``relink_tau``, so the prediction stops drifting and its variance grows
  linearly), and with the image area known, against a new target anywhere in the image
  (:func:`score_relinks`); an exact maximum-weight matching decides, and a matched new track
  takes the old id -- in the live tails, in the rows still held back and in this frame's ids
  (:attr:`AssocResult.relinked`).  With ``fill_gaps`` the held-back frames inside the re-linked
  gap are filled.  Cost: (kept tracks) × (tracks confirmed this frame).
* **Appearance** (``app_weight``, not in the paper; off in ``paper``).  When the tracker passes
  colour features of the estimates (:mod:`.appearance`: RGB histograms of the upper and lower
  half of the box), each track keeps an exponential average (rate ``app_alpha``), and every
  edge and re-link weight gets ``app_weight ×`` the log-likelihood ratio same/different target
  of the Bhattacharyya similarity, whose two distributions are learnt online from the matching
  itself (:class:`.appearance.AppearanceModel`: gap-1 edges are one target, two estimates of
  one frame are two), shrunk by ``n / (n + MODEL_N0)`` for a model of ``n`` crops.  A poor colour match can then veto an edge the motion allows (its weight
  drops to ≤ 0) or hand a contested vertex to the track that looks like it.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from ..params import param
from ..report import _made
from . import _assoc_kernels
from .appearance import DIM as APP_DIM, AppearanceModel, similarity, similarity_pairs
from .filter import STATE_DIM, obs_std
from .gating import GridIndex, expand_runs

#: Observable components of the state (y1, y2, w, h), maggio2007 §2 ``z = (y, w, h)``.
OBS_INDEX = np.array([0, 1, 4, 5])
#: no ids (an empty id / length array the kernels read)
_NO_IDS = np.zeros(0, dtype=np.int64)


def _any(a: np.ndarray) -> bool:
    """``a.any()``: the truth of a small mask without ndarray.any's Python-level wrapper
    (np.count_nonzero is one C call: ~1/4 of any's time on the few-element masks the step
    tests, ~6 a frame, more when gaps are filled)."""
    return np.count_nonzero(a) > 0


def _all(a: np.ndarray) -> bool:
    """``a.all()``, as :func:`_any` (true for an empty array, as ``all``)."""
    return np.count_nonzero(a) == a.size


def _empty(shape, dtype=np.float64) -> np.ndarray:
    a = np.zeros(shape, dtype=dtype)
    a.setflags(write=False)
    return a


#: one True (read-only), appended to a frame's filled flags
_TRUE1 = np.ones(1, dtype=bool)
#: no (new id, old id) pairs (read-only: the result of every frame that re-links nothing)
_NO_PAIRS = np.zeros((0, 2), dtype=np.int64)
#: an empty mask (fill_rows: keep every row)
_NO_BOOL = np.zeros(0, dtype=bool)
_TRUE1.setflags(write=False)
_NO_PAIRS.setflags(write=False)
#: a step's edge arrays when nobody asked for them (``edges=False``): empty, shared, read-only
_NO_EDGES = dict(edges_src=_empty((0, STATE_DIM)), edges_src_id=_empty(0, np.int64),
                 edges_dst_index=_empty(0, np.int64), edges_gain=_empty(0),
                 edges_weight=_empty(0), edges_gap=_empty(0, np.int64), chosen=_empty(0, bool))
#: Tracks-file ``conf`` of a row interpolated inside a linked gap (``fill_gaps``); rows of
#: estimates get :data:`EST_CONF`.
GAP_CONF = 0.5
EST_CONF = 1.0


@dataclass(frozen=True)
class AssocParams:
    """Parameters of the graph association (defaults: maggio2007 §4).

    depth: graph depth K in frames (a tail is a candidate while ``k − frame ≤ depth``).
    min_length: tracks with fewer vertices are not reported (§4: 5).
    gate: chi-square probability of the edge gate (4 observable dof).
    sigma_v: per-frame velocity noise std as a fraction of (w, h) of the earlier vertex (§4: 0.03).
    sigma_size: per-frame size noise std as a fraction of (w, h) (§4: 0.1).
    sigma_obs, sigma_obs_min: estimate noise ``σ^z_{w,h} = max(sigma_obs·size, sigma_obs_min)``,
        ``σ^z_y = sigma_obs_pos_ratio · σ^z_{w,h}`` (§4: 0.15, 1.0 px, 1/2); the same formula as the
        filter's likelihood (:func:`trackers.phd.filter.obs_std`).
    speed_prior: std of an unknown velocity per axis, fraction of (w, h) per frame (ours).
    accel_to_position: c in ``y ← y + v + c·a`` (½ = dt²/2; as :mod:`pfscope.trackers.phd.motion`).
    """

    depth: int = param(50, "graph depth K in frames (a track survives gaps up to K)",
                       paper="maggio2007 §4")
    min_length: int = param(5, "tracks with fewer vertices are not reported",
                            paper="maggio2007 §4")
    gate: float = param(0.999, "chi-square probability of the edge gate (4 dof)")
    sigma_v: float = param(0.03, "velocity noise std per frame, fraction of (w, h)",
                           paper="maggio2007 §4")
    sigma_size: float = param(0.1, "size noise std per frame, fraction of (w, h)",
                              paper="maggio2007 §4")
    sigma_obs: float = param(0.15, "estimate noise of w, h, fraction of the size",
                             paper="maggio2007 §4")
    sigma_obs_min: float = param(1.0, "floor of the estimate noise, pixels", paper="maggio2007 §4")
    sigma_obs_pos_ratio: float = param(0.5, "σ^z_y = ratio · σ^z_{w,h}", paper="maggio2007 §4")
    speed_prior: float = param(0.1, "std of an unknown velocity, fraction of (w, h) per frame "
                                    "(not in paper)")
    accel_to_position: float = param(0.5, "c in y ← y + v + c·a (dt²/2, as phd.motion)")
    fill_gaps: bool = param(False, "give the frames inside a linked gap a row interpolated "
                                   "between its ends, flagged (tracks file conf "
                                   "= GAP_CONF); the report lag becomes max(min_length − 1, "
                                   "depth) frames (not in paper)")
    fill_overlap: float = param(0.3, "fill_gaps: a gap box overlapping another track's "
                                     "estimate of that frame by this IoU or more is not "
                                     "filled")
    fill_support: float = param(0.0, "fill_gaps: a linked gap is filled only when at least "
                                     "this share of its inner frames has evidence on the "
                                     "interpolated path: a detection of the frame (kept with "
                                     "extend_heads) or another track's estimate (an "
                                     "occluder) overlapping the interpolated box by "
                                     "fill_overlap or more; a path across empty image is "
                                     "not filled (0: fill every gap)")
    fill_free: int = param(0, "fill_support: a gap of at most this many missing frames "
                              "is filled without evidence (missed detections in a row)")
    fill_err: float = param(0.0, "fill_gaps: a gap row no detection of its frame overlaps "
                                 "by fill_overlap (detections kept with extend_heads) is "
                                 "kept only where the straight line's error std "
                                 "there, under the scene's measured acceleration "
                                 "(GraphAssociator.scene_sigma_v; interpolation_std), is at "
                                 "most this fraction of the box size (0: off; not in paper)")
    relink_depth: int = param(0, "re-linking (not in paper; 0: off): a confirmed track unseen "
                                 "for more than depth frames stays re-linkable for this many "
                                 "frames; a new track, when confirmed, takes its id if its "
                                 "first estimate fits the ended track's damped prediction")
    app_weight: float = param(0.0, "appearance (not in paper; 0: off): weight of the colour "
                                   "log-likelihood ratio (phd.appearance, learnt online) added "
                                   "to the edge and re-link weights when the frame has pixels")
    app_alpha: float = param(0.1, "appearance: per-frame update rate of a track's colour model "
                                  "(exponential average)")
    relink_tau: float = param(20.0, "re-linking: time constant of the velocity damping, "
                                    "frames (the motion noise sigma_v with a pull of the "
                                    "velocity back to rest: an Ornstein-Uhlenbeck process)")
    extend_heads: bool = param(False, "when a track is confirmed, give the frames before its "
                                      "first estimate the detections that seeded it: walking "
                                      "back from the first estimate along the track's mean "
                                      "velocity, each held-back frame takes the detection "
                                      "inside the edge gate (one frame's estimate noise, "
                                      "twice), none another track's estimate covers; stops "
                                      "at the first frame without one (PHD-MT: the frames "
                                      "its mass took to reach T; flagged as filled; the "
                                      "report lag becomes max(min_length − 1, depth) as "
                                      "with fill_gaps; not in paper)")
    revive_rate: float = param(0.85, "PHD-MT's revive_odds go only to the detections near "
                                      "a confirmed track that had estimates in at least "
                                      "this share of its frames (clutter that fires now "
                                      "and then in one place does not qualify)")
    head_skip: int = param(0, "extend_heads: frames without a fitting detection the walk "
                              "back may cross in a row")

    def __post_init__(self):
        if int(self.depth) != self.depth or self.depth < 1:
            raise ValueError(f"AssocParams.depth must be an integer >= 1, got {self.depth}")
        if int(self.min_length) != self.min_length or self.min_length < 1:
            raise ValueError(f"AssocParams.min_length must be an integer >= 1, got {self.min_length}")
        if self.min_length - 1 > self.depth:
            raise ValueError("AssocParams: min_length - 1 (the report lag) must not exceed depth")
        if not 0.0 < self.gate < 1.0:
            raise ValueError(f"AssocParams.gate must be in (0, 1), got {self.gate}")
        for name in ("sigma_v", "sigma_size", "speed_prior", "accel_to_position"):
            if getattr(self, name) < 0:
                raise ValueError(f"AssocParams.{name} must be >= 0")
        if self.sigma_obs < 0 or self.sigma_obs_min <= 0:
            raise ValueError("AssocParams: sigma_obs must be >= 0 and sigma_obs_min > 0")
        if int(self.relink_depth) != self.relink_depth or self.relink_depth < 0:
            raise ValueError(f"AssocParams.relink_depth must be an integer >= 0, "
                             f"got {self.relink_depth}")
        if not self.app_weight >= 0:
            raise ValueError(f"AssocParams.app_weight must be >= 0, got {self.app_weight}")
        if not 0.0 < self.app_alpha <= 1.0:
            raise ValueError(f"AssocParams.app_alpha must be in (0, 1], got {self.app_alpha}")
        if not self.fill_err >= 0:
            raise ValueError(f"AssocParams.fill_err must be >= 0, got {self.fill_err}")
        if not self.relink_tau > 0:
            raise ValueError(f"AssocParams.relink_tau must be > 0, got {self.relink_tau}")

    @cached_property
    def gate_d2(self) -> float:
        """Squared Mahalanobis radius of the gate (chi-square quantile, 4 dof)."""
        from .filter import gate_threshold  # scipy.stats, imported on first use

        return gate_threshold(self.gate, len(OBS_INDEX))

    @cached_property
    def kernel_args(self) -> tuple:
        """The floats :mod:`._assoc_kernels`' edge passes read, in their order: depth, gate_d2,
        sigma_v, sigma_size, sigma_obs, sigma_obs_min, sigma_obs_pos_ratio, accel_to_position
        and its square, 2π (once per parameter set, not per frame)."""
        return (float(self.depth), float(self.gate_d2), float(self.sigma_v),
                float(self.sigma_size), float(self.sigma_obs), float(self.sigma_obs_min),
                float(self.sigma_obs_pos_ratio), float(self.accel_to_position),
                float(self.accel_to_position ** 2), 2.0 * np.pi)

    @cached_property
    def kernel_vec(self) -> np.ndarray:
        """:attr:`kernel_args` then ``speed_prior`` as one read-only float64 array (one
        argument of :func:`._assoc_kernels.frame_step` instead of eleven floats to type)."""
        a = np.array(self.kernel_args + (float(self.speed_prior),), dtype=np.float64)
        a.setflags(write=False)
        return a


# --------------------------------------------------------------------------- pure functions


def obs_noise_var(states: np.ndarray, params: AssocParams) -> np.ndarray:
    """(N, 4) variances of the estimate noise ``σ^z`` of (y1, y2, w, h) at each state's size (§4):
    the filter's observation model (:func:`trackers.phd.filter.obs_std`)."""
    return obs_std(states[:, 4:6], params) ** 2


def tail_velocity(tail_states: np.ndarray, prev_states: np.ndarray, prev_gap: np.ndarray,
                  params: AssocParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Velocity estimate of each tail and the growth of its prediction error.

    tail_states, prev_states: (T, 6) last and previous vertex of each track (prev rows unused where
    ``prev_gap <= 0``, i.e. the track has one vertex); prev_gap: (T,) frames between them.
    Returns ``v (T, 2)``, ``b (T, 2)``, ``c (T, 2)``: the tail-side position error variance at gap
    ``i`` is ``σ_t² + b i + c i²`` (see the module docstring, "Unknown velocity").
    """
    T = len(tail_states)
    v = tail_states[:, 2:4].copy()
    b = np.zeros((T, 2))
    c = np.zeros((T, 2))
    unknown = ~np.all(np.isfinite(v), axis=1)
    if not _any(unknown):
        return v, b, c
    var_t = obs_noise_var(tail_states, params)[:, :2]
    two = unknown & (prev_gap > 0)
    if _any(two):
        d = prev_gap[two, None].astype(np.float64)
        var_p = obs_noise_var(prev_states[two], params)[:, :2]
        v[two] = (tail_states[two, 0:2] - prev_states[two, 0:2]) / d
        # y_t + i v̂ = y_t + i (y_t − y_p)/Δ: error ε_t (1 + i/Δ) − ε_p i/Δ
        b[two] = 2.0 * var_t[two] / d
        c[two] = (var_t[two] + var_p) / d ** 2
    one = unknown & ~(prev_gap > 0)
    if _any(one):
        v[one] = 0.0
        c[one] = (params.speed_prior * tail_states[one, 4:6]) ** 2
    return v, b, c


def interpolation_std(sigma_v: float, t, gap) -> np.ndarray:
    """Error std (fraction of the box size) of the straight line between two estimates ``gap``
    frames apart, ``t`` frames after the first, when the target's velocity changes by white
    noise of std ``sigma_v`` per frame (the motion model of :func:`propagate`): the position
    given both ends (velocity unknown) is an integrated-Brownian bridge of variance
    ``σ_v² t² (gap − t)² / (3 gap)`` (0 at both ends, ``σ_v² gap³ / 48`` half-way)."""
    t = np.asarray(t, dtype=np.float64)
    gap = np.asarray(gap, dtype=np.float64)
    return sigma_v * t * (gap - t) / np.sqrt(3.0 * np.maximum(gap, 1.0))


def propagate(tail_states: np.ndarray, v: np.ndarray, b: np.ndarray, c: np.ndarray,
              gaps: np.ndarray, params: AssocParams) -> tuple[np.ndarray, np.ndarray]:
    """Mean and (diagonal) covariance of the observable new estimate, ``i = gaps`` frames later.

    tail_states (T, 6); v, b, c (T, 2) from :func:`tail_velocity`; gaps (T,) or (T, G) frames.
    Returns ``mean (T, [G,] 4)`` and ``var (T, [G,] 4)`` over (y1, y2, w, h): the marginal of
    ``F^i x`` and ``Σ_{j<i} F^j Q F^jᵀ`` plus the estimate noise of both ends (module docstring).
    The four components are independent, so the covariance is diagonal.
    """
    i = np.asarray(gaps, dtype=np.float64)
    extra = i.ndim - 1
    sh = (slice(None),) + (None,) * extra  # broadcast per-tail arrays over the gap axes
    i = i[..., None]
    size = tail_states[:, 4:6][sh]
    r = obs_noise_var(tail_states, params)[sh]
    r_y, r_wh = r[..., :2], r[..., 2:]
    # position: mean y + i v; process variance σ_v² Σ_{j<i}(j+c)²: the acceleration of step j
    # reaches the position through c now and through the velocity on the i−1−j later steps
    mean_y = tail_states[:, 0:2][sh] + i * v[sh]
    cc = params.accel_to_position
    s2 = (i - 1.0) * i * (2.0 * i - 1.0) / 6.0 + cc * i * (i - 1.0) + cc ** 2 * i
    var_y = ((params.sigma_v * size) ** 2 * s2
             + r_y + b[sh] * i + c[sh] * i ** 2  # tail-side estimate error (+ velocity error)
             + r_y)  # new-side estimate error
    # size: zero-order random walk, std proportional to the earlier vertex's size
    mean_wh = np.broadcast_to(size, var_y.shape)
    var_wh = (params.sigma_size * size) ** 2 * i + 2.0 * r_wh
    mean = np.concatenate([mean_y, mean_wh], axis=-1)
    var = np.concatenate([var_y, var_wh], axis=-1)
    return mean, var


@dataclass(frozen=True)
class EdgeScores:
    """All (tail, new vertex) pairs of one frame. Arrays are (T, M) unless noted.

    gain: ``log f(x̂_k | x̂_{k−i})`` on the observable components; d2: squared Mahalanobis
    distance; weight: ``gain − floor`` (floor (T,): log-density at the gate of the gap-K edge);
    allowed: inside the gate.
    """

    gain: np.ndarray
    d2: np.ndarray
    floor: np.ndarray
    weight: np.ndarray
    allowed: np.ndarray


def _edge_model(tail_states: np.ndarray, v: np.ndarray, b: np.ndarray, c: np.ndarray,
                gaps: np.ndarray, params: AssocParams):
    """Each tail's predicted new vertex at its gap: ``mean, var (T, 4)``, ``log_det (T,)``
    (of ``2π var``), and ``floor (T,)``, the log-density at the gate of the gap-K edge."""
    T = len(tail_states)
    gaps = np.asarray(gaps, dtype=np.float64)
    both = np.stack([gaps, np.full(T, float(params.depth))], axis=1)  # (T, 2): gap i, gap K
    mean, var = propagate(tail_states, v, b, c, both, params)
    log_det = np.sum(np.log(2.0 * np.pi * var), axis=-1)  # (T, 2)
    floor = -0.5 * params.gate_d2 - 0.5 * log_det[:, 1]
    return mean[:, 0, :], var[:, 0, :], log_det[:, 0], floor


def score_edges(tail_states: np.ndarray, v: np.ndarray, b: np.ndarray, c: np.ndarray,
                gaps: np.ndarray, new_states: np.ndarray, params: AssocParams) -> EdgeScores:
    """Gains and weights of every (tail, new vertex) edge: :func:`_edge_model` and the
    Mahalanobis distances of all pairs in one numba pass (:func:`._assoc_kernels.edge_scores`,
    the same floats as the numpy spelling)."""
    f64 = np.float64
    gain, d2, weight, floor = _assoc_kernels.edge_scores(
        np.ascontiguousarray(tail_states, dtype=f64), np.ascontiguousarray(v, dtype=f64),
        np.ascontiguousarray(b, dtype=f64), np.ascontiguousarray(c, dtype=f64),
        np.ascontiguousarray(np.broadcast_to(gaps, (len(tail_states),)), dtype=f64),
        np.ascontiguousarray(np.asarray(new_states, dtype=f64)[:, OBS_INDEX]),
        float(params.depth), float(params.gate_d2), float(params.sigma_v),
        float(params.sigma_size), float(params.sigma_obs), float(params.sigma_obs_min),
        float(params.sigma_obs_pos_ratio), float(params.accel_to_position),
        float(params.accel_to_position ** 2), 2.0 * np.pi)
    return EdgeScores(gain=gain, d2=d2, floor=floor, weight=weight, allowed=d2 <= params.gate_d2)


def propagate_damped(tail_states: np.ndarray, v: np.ndarray, b: np.ndarray, c: np.ndarray,
                     gaps: np.ndarray, params: AssocParams) -> tuple[np.ndarray, np.ndarray]:
    """Mean and diagonal covariance of the observable estimate ``gaps`` frames after an ended
    tail, under the re-linking model: the velocity is an Ornstein-Uhlenbeck process, the
    white-noise acceleration of :func:`propagate` (std ``σ_a = sigma_v · (w, h)`` per frame)
    with a pull back to rest of time constant ``τ = relink_tau`` (a person slows, stops,
    turns: ``dv = −v/τ dt + σ_a dW``), so over a long gap the position drifts
    ``v τ (1 − e^{−i/τ})`` and its variance grows linearly,
    ``σ_a² τ² [i − 2τ(1 − e^{−i/τ}) + τ(1 − e^{−2i/τ})/2]``, not as ``i³``; for ``i ≪ τ`` both
    give ``σ_a² i³/3``.  The tail's velocity error enters through
    ``k = τ(1 − e^{−i/τ})`` instead of ``i``; size and estimate noise as in :func:`propagate`.

    tail_states (T, 6); v, b, c (T, 2) from :func:`tail_velocity`; gaps (T,) or (T, G).
    Returns ``mean, var (T, [G,] 4)``.
    """
    i = np.asarray(gaps, dtype=np.float64)
    extra = i.ndim - 1
    sh = (slice(None),) + (None,) * extra
    i = i[..., None]
    tau = float(params.relink_tau)
    size = tail_states[:, 4:6][sh]
    r = obs_noise_var(tail_states, params)[sh]
    r_y, r_wh = r[..., :2], r[..., 2:]
    k = tau * -np.expm1(-i / tau)
    mean_y = tail_states[:, 0:2][sh] + k * v[sh]
    sa2 = (params.sigma_v * size) ** 2
    drift = sa2 * tau ** 2 * (i - 2.0 * k + 0.5 * tau * -np.expm1(-2.0 * i / tau))
    var_y = drift + 2.0 * r_y + b[sh] * k + c[sh] * k ** 2
    var_wh = (params.sigma_size * size) ** 2 * i + 2.0 * r_wh
    mean_wh = np.broadcast_to(size, var_y.shape)
    return (np.concatenate([mean_y, mean_wh], axis=-1),
            np.concatenate([var_y, var_wh], axis=-1))


def score_relinks(lost_states: np.ndarray, v: np.ndarray, b: np.ndarray, c: np.ndarray,
                  lost_frames: np.ndarray, first_states: np.ndarray, first_frames: np.ndarray,
                  params: AssocParams, area: float | None = None) -> EdgeScores:
    """Gains and weights of every (ended track, new track) pair: the new track's first estimate
    against the ended tail's damped prediction (:func:`propagate_damped`) over the gap between
    them.  (L, C) arrays; a pair is allowed when the new track began after the ended one's
    last estimate, within ``relink_depth`` frames, and inside the gate.

    Weight: with the image ``area`` (px²) known, the log-likelihood ratio of the two
    explanations of the new track's first position -- the ended target come back (the
    predicted density of the centre) against a new target anywhere in the image (``1/area``):
    ``log N(y; ŷ, Σ_y) + log area`` -- so a re-link must fit better than chance, which a long
    gap (wide prediction) or a small image makes harder.  Without the area, as in
    :func:`score_edges`: the gain above the floor of the widest re-link (gap
    ``relink_depth``)."""
    L = len(lost_states)
    gaps = first_frames[None, :].astype(np.float64) - lost_frames[:, None]  # (L, C)
    g = np.clip(gaps, 1.0, None)
    mean, var = propagate_damped(lost_states, v, b, c, g, params)  # (L, C, 4)
    res = first_states[None, :, OBS_INDEX] - mean
    d2 = np.sum(res ** 2 / var, axis=-1)
    gain = -0.5 * d2 - 0.5 * np.sum(np.log(2.0 * np.pi * var), axis=-1)
    allowed = (gaps >= 1) & (gaps <= params.relink_depth) & (d2 <= params.gate_d2)
    if area is not None and area > 0:
        pos = -0.5 * np.sum(res[..., :2] ** 2 / var[..., :2]
                            + np.log(2.0 * np.pi * var[..., :2]), axis=-1)
        floor = np.full(L, -math.log(area))
        return EdgeScores(gain=gain, d2=d2, floor=floor, weight=pos - floor[:, None],
                          allowed=allowed)
    widest = np.full((L, 1), float(max(params.relink_depth, 1)))
    _, var_r = propagate_damped(lost_states, v, b, c, widest, params)
    floor = -0.5 * params.gate_d2 - 0.5 * np.sum(np.log(2.0 * np.pi * var_r[:, 0]), axis=-1)
    return EdgeScores(gain=gain, d2=d2, floor=floor, weight=gain - floor[:, None],
                      allowed=allowed)


def max_weight_matching(weights: np.ndarray, allowed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact maximum-weight bipartite matching restricted to ``allowed`` edges.

    weights, allowed: (T, M).  Edges with weight ≤ 0 are never worth taking (leaving both ends
    unmatched scores 0) and are dropped.  With the others set to 0 the padded assignment problem
    has the same optimum as the matching problem, and zero-weight pairs of the assignment are
    discarded.  Returns ``rows (P,)``, ``cols (P,)`` sorted by row.
    """
    weights = np.asarray(weights, dtype=np.float64)
    ok = np.asarray(allowed, dtype=bool) & np.isfinite(weights) & (weights > 0)
    if not _any(ok):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    w = np.where(ok, weights, 0.0)
    rows, cols = _lsa()(w, maximize=True)
    keep = ok[rows, cols]
    return rows[keep].astype(np.int64), cols[keep].astype(np.int64)


def _match_admissible(w0: np.ndarray, n_ok: int,
                      one: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """:func:`max_weight_matching` of weights already zero outside the admissible edges (and
    positive on them: :func:`._assoc_kernels.frame_edges`' ``w0``, ``n_ok`` of them).
    ``one``: no row and no column holds more than one admissible edge (frame_edges' ``one``,
    the usual frame of separated targets): every matching may then take all of them and the
    maximum-weight one does (leaving one out loses its positive weight), so they are the
    answer, in row order as the assignment's -- without the assignment solver."""
    if not n_ok:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    if one:
        rows, cols = np.nonzero(w0)
        return rows.astype(np.int64, copy=False), cols.astype(np.int64, copy=False)
    rows, cols = _lsa()(w0, maximize=True)
    keep = w0[rows, cols] > 0.0
    if _all(keep):      # (every pair the assignment made is an edge: nothing to drop)
        return rows.astype(np.int64, copy=False), cols.astype(np.int64, copy=False)
    return rows[keep].astype(np.int64, copy=False), cols[keep].astype(np.int64, copy=False)


_LSA = None


def _lsa():
    """scipy's ``linear_sum_assignment``, imported on first use (slow to import; not needed
    for --help) and kept (an import statement in the matching costs a few us a frame)."""
    global _LSA
    if _LSA is None:
        from scipy.optimize import linear_sum_assignment
        _LSA = linear_sum_assignment
    return _LSA


#: Above this many (tail, new vertex) pairs a frame's edges are scored on the pairs inside the
#: gate only (:func:`score_edge_pairs`) and matched on that sparse graph
#: (:func:`sparse_max_weight_matching`): a clutter storm with thousands of estimates a frame
#: needs memory and time in the number of gated pairs, not tails × vertices (issue 12).  Below
#: it -- every scene of a few hundred targets -- the dense (T, M) arrays are cheaper.
DENSE_MAX_PAIRS = 250_000


@dataclass(frozen=True)
class EdgePairs:
    """The gated (tail, new vertex) edges of one frame as pairs: ``rows``/``cols`` (P,) and
    their ``gain``, ``d2`` and ``weight`` (P,); ``floor`` (T,) as in :class:`EdgeScores`."""

    rows: np.ndarray
    cols: np.ndarray
    gain: np.ndarray
    d2: np.ndarray
    floor: np.ndarray
    weight: np.ndarray


def score_edge_pairs(tail_states: np.ndarray, v: np.ndarray, b: np.ndarray, c: np.ndarray,
                     gaps: np.ndarray, new_states: np.ndarray,
                     params: AssocParams) -> EdgePairs:
    """:func:`score_edges` on the pairs inside the gate only, the same value for each pair.
    Candidates come from a grid on the new vertices' positions (:class:`.gating.GridIndex`,
    as the update's gate): a pair can pass the gate ``d2 <= gate_d2`` only if each position
    term does, i.e. inside the box ``|z − ŷ| <= sqrt(gate_d2 · var)`` around the tail's
    prediction.  Pairs are ordered by tail, then vertex (as ``np.nonzero`` of the dense gate)."""
    mean, var, log_det, floor = _edge_model(tail_states, v, b, c, gaps, params)
    g2 = params.gate_d2
    z = new_states[:, OBS_INDEX]
    half = np.sqrt(g2 * var[:, :2]) * (1.0 + 1e-9)            # (T, 2) gate box half-widths
    ti = np.flatnonzero(np.all(np.isfinite(mean[:, :2]) & np.isfinite(half), axis=1))
    zi = np.flatnonzero(np.all(np.isfinite(z[:, :2]), axis=1))
    rows = cols = np.zeros(0, dtype=np.int64)
    if len(ti) and len(zi):
        index = GridIndex(z[zi, :2], 2.0 * np.median(half[ti], axis=0) + 1e-9)
        owner, start, stop = index.runs(mean[ti, :2] - half[ti], mean[ti, :2] + half[ti])
        rows = ti[np.repeat(owner, stop - start)]
        cols = zi[index.order[expand_runs(start, stop)]]
        order = np.lexsort((cols, rows))
        rows, cols = rows[order].astype(np.int64), cols[order].astype(np.int64)
    res = z[cols] - mean[rows]
    d2 = np.sum(res ** 2 / var[rows], axis=-1)
    keep = d2 <= g2
    rows, cols, d2 = rows[keep], cols[keep], d2[keep]
    gain = -0.5 * d2 - 0.5 * log_det[rows]
    return EdgePairs(rows=rows, cols=cols, gain=gain, d2=d2, floor=floor,
                     weight=gain - floor[rows])


def sparse_max_weight_matching(rows: np.ndarray, cols: np.ndarray,
                               weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`max_weight_matching` on a sparse graph: edges ``(rows, cols)`` with ``weights``
    (P,).  Solved as a minimum-cost matching that covers every row (scipy's sparse LAPJVsp):
    each row also gets a private dummy column of cost C and each edge costs ``C − w``, so a
    matching costs ``C · rows − Σ w`` over its real edges and the cheapest is the heaviest.
    Time and memory grow with the edges, not rows × columns.  Returns ``rows, cols``
    sorted by row."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import min_weight_full_bipartite_matching

    ok = np.isfinite(weights) & (weights > 0)
    r, c, w = rows[ok].astype(np.int64), cols[ok].astype(np.int64), weights[ok]
    if not len(w):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    # only the rows and columns with an edge take part (the others stay unmatched)
    ur, r = np.unique(r, return_inverse=True)
    uc, c = np.unique(c, return_inverse=True)
    T, M = len(ur), len(uc)
    big = 1.0 + 2.0 * float(np.max(w))
    g = coo_matrix((np.concatenate([big - w, np.full(T, big)]),
                    (np.concatenate([r, np.arange(T)]), np.concatenate([c, M + np.arange(T)]))),
                   shape=(T, M + T)).tocsr()
    ri, ci = min_weight_full_bipartite_matching(g)
    real = ci < M
    order = np.argsort(ri[real], kind="stable")
    return (ur[ri[real][order]].astype(np.int64), uc[ci[real][order]].astype(np.int64))


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(A, B) intersection over union of centre boxes ``(cx, cy, w, h)``
    (:func:`._assoc_kernels.iou`)."""
    return _assoc_kernels.iou(np.ascontiguousarray(a, dtype=np.float64).reshape(-1, 4),
                              np.ascontiguousarray(b, dtype=np.float64).reshape(-1, 4))


def compile_step_kernels(params: AssocParams | None = None) -> None:
    """Call the kernels of :meth:`GraphAssociator.step` and :meth:`~GraphAssociator.returning`
    once with the argument types of a run (the warm-up, :mod:`pfscope.trackers.warmup`):
    the input check, the frame's edges, the matching's outcome, the revive test, the gap
    rows, the walk back of extend_heads and the confirmed test of the rows."""
    a = GraphAssociator(replace(params if params is not None else AssocParams(),
                                fill_gaps=True, extend_heads=True, min_length=3))
    s = np.array([[100.0, 100.0, 1.0, 0.0, 30.0, 70.0]])
    z = s[:, OBS_INDEX]
    a.step(1, s[:0], detections=z, edges=False)   # a detection before the track's first
    for k in (2, 3):
        a.step(k, s, detections=z, edges=False)
    a._unseen = (True, 0)     # (the revive kernel itself: the flag would skip it here)
    a.returning(4, z)
    a.step(4, s[:0], detections=z, edges=False)
    # a gap of one frame, filled; the track confirmed, its head extended back to frame 1
    a.step(5, s, detections=z, edges=False)
    a.step(6, s, detections=z, edges=True)        # the general path (edges, colour)
    # the tail expires (the general path) and the rows held back are final; then the fast
    # path's finalised rows
    a.step(7 + a.lag, s, detections=z, edges=False)
    a.step(8 + 2 * a.lag, s, detections=z, edges=False)
    a.step(9 + 2 * a.lag, s[:0], detections=z, edges=False)
    a.flush()                      # the confirmed test of the rows held back
    # the tracker's output: the confirmed tracks' and the final rows' boxes, its detections'
    # centres
    res = a.step(10 + 3 * a.lag, s, detections=z, edges=False)
    # gap filling's general path (a camera that moved, rows in several frames, long edges or
    # unlikely rows) with a run's argument types: the one-frame call above compiled its two
    # kernels inside it, for these very types (no second specialisation)
    st, fr = np.ascontiguousarray(s), np.array([3], dtype=np.int64)
    _, _, ei, rows, _, run, _, _ = _assoc_kernels.gap_rows(
        _NO_IDS, 1, 2, st, np.array([1], dtype=np.int64), st, fr, 0.1, 0.1, 2.0)
    lo, hi = run.tolist()
    _assoc_kernels.fill_rows(res.ids, st, np.zeros(1, dtype=bool), rows,
                             np.ones(1, dtype=np.int64)[ei], lo, hi, _NO_BOOL, 0.5)
    _assoc_kernels.track_boxes(res.ids, res.states, res.confirmed)
    _assoc_kernels.row_boxes(res.states, res.confirmed, GAP_CONF, EST_CONF)
    _assoc_kernels.centre_boxes(np.ascontiguousarray(z))


def boxes_xywh(states: np.ndarray) -> np.ndarray:
    """(N, 6) states -> (N, 4) top-left boxes ``(x, y, w, h)`` (MOT convention): the floats of
    ``cxcywh_to_xywh(states[:, OBS_INDEX])`` (``x − w / 2``, ``y − h / 2``, ``w``, ``h``),
    from slices of the states rather than a gathered copy converted in a second copy."""
    s = np.asarray(states, dtype=np.float64).reshape(-1, STATE_DIM)
    out = np.empty((len(s), 4))
    size = s[:, 4:6]
    out[:, 2:] = size
    np.subtract(s[:, :2], size / 2.0, out=out[:, :2])
    return out


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class FinalRows:
    """Finalised output of one past frame (bounded-lag reporting): confirmed tracks only.

    ids (R,) int64; states (R, 6); filled (R,) bool: the row is interpolated inside a linked gap
    (``AssocParams.fill_gaps``), not an estimate.  ``xywh`` (R, 4) the rows' top-left boxes
    ``(x, y, w, h)`` (also :attr:`boxes`) and ``conf`` (R,) their tracks-file confidence
    (``GAP_CONF`` where filled, else ``EST_CONF``), made from the states when not given (the
    association hands them over from its kernel pass).
    """

    frame: int
    ids: np.ndarray
    states: np.ndarray

    filled: np.ndarray | None = None
    xywh: np.ndarray | None = None
    conf: np.ndarray | None = None

    def __post_init__(self):
        if self.filled is None:
            object.__setattr__(self, "filled", np.zeros(len(self.ids), dtype=bool))
        if self.xywh is None or self.conf is None:
            box, conf = _assoc_kernels.row_boxes(
                np.ascontiguousarray(self.states, dtype=np.float64).reshape(-1, STATE_DIM),
                np.ascontiguousarray(self.filled, dtype=np.bool_), GAP_CONF, EST_CONF)
            object.__setattr__(self, "xywh", box)
            object.__setattr__(self, "conf", conf)

    @property
    def boxes(self) -> np.ndarray:
        return self.xywh


@dataclass(frozen=True)
class AssocResult:
    """Association of one frame.

    New vertices (M = number of estimates given): ``states (M, 6)``, ``ids (M,)`` their track ids,
    ``lengths (M,)`` track lengths in vertices after this frame, ``confirmed (M,)``
    ``lengths >= min_length``.
    Edges (E = admissible (tail, new vertex) pairs, gated-out pairs are not listed):
    ``edges_src (E, 6)`` tail states, ``edges_src_id (E,)`` tail track ids,
    ``edges_dst_index (E,)`` index into ``states``, ``edges_gain (E,)`` ``log f``,
    ``edges_weight (E,)`` matching weight, ``edges_gap (E,)`` frames, ``chosen (E,)`` in the cover.
    ``ended (P,)``: ids of tracks whose tail fell out of the K-frame window this frame.
    ``relinked (P, 2)``: ``(new id, old id)`` of tracks confirmed this frame that took the id of
    an ended track (``relink_depth``); ``ids`` already carry the old id.
    ``finalised``: bounded-lag rows of past frames (usually one, for frame ``k − L``).
    """

    frame: int
    states: np.ndarray
    ids: np.ndarray
    lengths: np.ndarray
    confirmed: np.ndarray
    edges_src: np.ndarray
    edges_src_id: np.ndarray
    edges_dst_index: np.ndarray
    edges_gain: np.ndarray
    edges_weight: np.ndarray
    edges_gap: np.ndarray
    chosen: np.ndarray
    ended: np.ndarray
    finalised: tuple[FinalRows, ...]
    relinked: np.ndarray | None = None

    def __post_init__(self):
        if self.relinked is None:
            object.__setattr__(self, "relinked", np.zeros((0, 2), dtype=np.int64))

    @property
    def boxes(self) -> np.ndarray:
        """(M, 4) ``(x, y, w, h)`` of the new vertices."""
        return boxes_xywh(self.states)


@dataclass(frozen=True)
class TrackTails:
    """Snapshot of the live tracks (copies): ids (T,), tail_frames (T,), tail_states (T, 6),
    lengths (T,), sorted by id."""

    ids: np.ndarray
    tail_frames: np.ndarray
    tail_states: np.ndarray
    lengths: np.ndarray


# --------------------------------------------------------------------------- the associator


class GraphAssociator:
    """Online max-weight path cover over a K-frame window (see the module docstring).

    ``step(frame, states)`` once per frame with the frame's estimates, frames strictly increasing
    (gaps between frame numbers count as missed frames).  Memory: the tails of the live tracks
    (at most the number of vertices of the last K frames) and ``min_length − 1`` frames of rows.
    """

    def __init__(self, params: AssocParams | None = None):
        self.params = params if params is not None else AssocParams()
        self._ids = np.zeros(0, dtype=np.int64)  # sorted ascending (new ids are appended)
        self._tail = np.zeros((0, STATE_DIM))
        self._tail_frame = np.zeros(0, dtype=np.int64)
        self._prev = np.zeros((0, STATE_DIM))
        self._prev_frame = np.zeros(0, dtype=np.int64)  # -1: the track has one vertex
        self._length = np.zeros(0, dtype=np.int64)
        self._first = np.zeros((0, STATE_DIM))           # first vertex of each live track
        self._first_frame = np.zeros(0, dtype=np.int64)
        self._app = np.zeros((0, APP_DIM))                # colour model of each live track
        self._app_n = np.zeros(0)                         # colour observations in it
        self._lost_app = np.zeros((0, APP_DIM))
        self._lost_app_n = np.zeros(0)
        self._app_model = AppearanceModel()
        #: image area in px² (set by the tracker from the frames): re-links are then scored
        #: against a new target anywhere in the image (:func:`score_relinks`)
        self.area: float | None = None
        # ended confirmed tracks still re-linkable (relink_depth): id, last vertex, its frame,
        # velocity terms (tail_velocity at the end), length
        self._lost_ids = np.zeros(0, dtype=np.int64)
        self._lost = np.zeros((0, STATE_DIM))
        self._lost_frame = np.zeros(0, dtype=np.int64)
        self._lost_vbc = np.zeros((0, 3, 2))
        self._lost_len = np.zeros(0, dtype=np.int64)
        self._next_id = 1
        self._last_frame: int | None = None
        self._buffer: deque[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = deque()
        #: detections (cx, cy, w, h) of the held-back frames, beside ``_buffer`` (extend_heads)
        self._dets: deque[tuple[int, np.ndarray]] = deque()
        #: acceleration std per frame (fraction of w, h) measured on the scene's detections
        #: beyond what their noise explains (set by the tracker from
        #: :class:`.scene_motion.SceneMotion`; ~0 on the still cameras measured): ``fill_err``
        self.scene_sigma_v = 0.0
        #: the camera's image motion (frame → 2×3 similarity from the frame before,
        #: :mod:`.camera_motion`) of the recent frames where the camera moved (follow_camera)
        self._cams: dict[int, np.ndarray] = {}
        #: after a step: (some track of at least min_length vertices had no estimate in it,
        #: that min_length); (False, n) with min_length still >= n: no track can be a
        #: returning one at the next frame, and returning looks no further
        self._unseen = (True, 0)
        #: a step's end frame of the gap filling's edges (:meth:`_fill_gaps`, gap_rows)
        self._frame1 = np.zeros(1, dtype=np.int64)

    # ---- introspection
    @property
    def lag(self) -> int:
        """Frames between a step and the frame its ``finalised`` rows belong to."""
        p = self.params
        return (max(p.min_length - 1, p.depth) if p.fill_gaps or p.extend_heads
                else p.min_length - 1)

    @property
    def n_live(self) -> int:
        """Number of tails kept (live tracks)."""
        return len(self._ids)

    @property
    def n_buffered_frames(self) -> int:
        return len(self._buffer)

    def live_tracks(self) -> TrackTails:
        return TrackTails(self._ids.copy(), self._tail_frame.copy(), self._tail.copy(),
                          self._length.copy())

    @property
    def n_lost(self) -> int:
        """Number of ended tracks still re-linkable (``relink_depth``)."""
        return len(self._lost_ids)

    def rescale_velocity(self, ratio: float) -> None:
        """Multiply the tails' velocities (px/frame) by ``ratio`` (the frame rate changed)."""
        if ratio != 1.0:
            self._tail[:, 2:4] *= ratio
            self._lost[:, 2:4] *= ratio
            # v (px/frame) and the error growth b i + c i² of an ended track, i in frames
            self._lost_vbc *= np.array([ratio, ratio, ratio ** 2])[None, :, None]

    def follow_camera(self, frame: int, A: np.ndarray) -> None:
        """The camera moved between the last frame and ``frame`` (about to be stepped) by the
        similarity ``A`` (2×3, :mod:`.camera_motion`): the live and ended tracks' states move
        into ``frame``'s image coordinates (so their predictions model the targets' own
        motion), and gap rows interpolated in them are mapped back into their own frames."""
        from .camera_motion import warp_states

        for a in (self._tail, self._prev, self._lost):
            warp_states(a, A)
        if len(self._lost_vbc):
            self._lost_vbc[:, 0, :] = self._lost_vbc[:, 0, :] @ A[:, :2].T
        self._cams[int(frame)] = A
        keep = int(frame) - (self.params.depth + self.params.relink_depth + 2)
        for f in [f for f in self._cams if f < keep]:
            del self._cams[f]

    def _to_frame(self, boxes: np.ndarray, f: int, frame: int) -> np.ndarray:
        """Boxes ``(cx, cy, w, h)`` in ``frame``'s image coordinates mapped back into frame
        ``f``'s (< frame) through the camera motions between them (themselves on a still
        camera)."""
        from .camera_motion import apply, compose, invert, scale

        C = None
        for g in range(int(f) + 1, int(frame) + 1):
            A = self._cams.get(g)
            if A is not None:
                C = A if C is None else compose(A, C)
        if C is None:
            return boxes
        Ci = invert(C)
        out = boxes.copy()
        out[:, :2] = apply(Ci, boxes[:, :2])
        out[:, 2:4] = boxes[:, 2:4] * scale(Ci)
        return out

    def _back(self, boxes: np.ndarray, f: int, frames: np.ndarray) -> np.ndarray:
        """:meth:`_to_frame` of each row of ``boxes`` from its ``frames`` into frame ``f``."""
        if not self._cams:
            return boxes
        out = boxes.copy()
        for g in np.unique(frames).tolist():
            m = frames == g
            out[m] = self._to_frame(boxes[m], f, g)
        return out

    # ---- input checking
    def _check(self, frame, states, values: bool = True) -> np.ndarray:
        """``states`` as a C-contiguous (M, 6) float64 array after the frame number's and the
        shape's checks; ``values``: also the positions' and sizes' (else the caller's, as
        :func:`._assoc_kernels.frame_step`'s status 3 and 4: :meth:`_bad_values`)."""
        if int(frame) != frame:
            raise ValueError(f"frame {frame!r}: frame numbers must be integers")
        if self._last_frame is not None and frame <= self._last_frame:
            raise ValueError(f"frame {frame}: frames must increase (previous was {self._last_frame})")
        s = np.asarray(states, dtype=np.float64)
        if s.size == 0:
            return np.zeros((0, STATE_DIM))
        if s.ndim != 2 or s.shape[1] != STATE_DIM:
            raise ValueError(f"frame {frame}: expected states of shape (M, 6), got {s.shape}")
        s = np.ascontiguousarray(s)
        if values:
            self._bad_values(frame, _assoc_kernels.check_states(s))  # (one pass)
        return s

    @staticmethod
    def _bad_values(frame, bad: int) -> None:
        """Raise for :func:`._assoc_kernels.check_states`' code ``bad`` (0: nothing)."""
        if bad == 1:
            raise ValueError(f"frame {frame}: non-finite position or size in the estimates")
        if bad == 2:
            raise ValueError(f"frame {frame}: estimates need positive width and height")

    def _check_features(self, features, M: int) -> np.ndarray:
        f = np.asarray(features, dtype=np.float64)
        if f.shape != (M, APP_DIM):
            raise ValueError(f"expected appearance features of shape ({M}, {APP_DIM}), "
                             f"got {f.shape}")
        return f

    # ---- one frame
    def _forget_lost(self, frame: int) -> None:
        """Drop the lost tracks older than ``relink_depth`` frames at ``frame``."""
        keep = frame - self._lost_frame <= self.params.relink_depth
        if not _all(keep):
            self._lost_ids, self._lost, self._lost_frame = (
                self._lost_ids[keep], self._lost[keep], self._lost_frame[keep])
            self._lost_vbc, self._lost_len = self._lost_vbc[keep], self._lost_len[keep]
            self._lost_app, self._lost_app_n = self._lost_app[keep], self._lost_app_n[keep]

    def _append_tracks(self, new_ids: np.ndarray, states: np.ndarray, frame: int) -> None:
        """New tracks ``new_ids`` (the largest ids yet: ``_ids`` stays sorted) on their first
        vertices ``states`` (n, 6) at ``frame``: length 1, no previous vertex (their colour
        models are the caller's)."""
        n = len(new_ids)
        self._ids = np.concatenate([self._ids, new_ids])
        self._tail = np.concatenate([self._tail, states])
        self._tail_frame = np.concatenate([self._tail_frame, np.full(n, frame, dtype=np.int64)])
        self._prev = np.concatenate([self._prev, np.full((n, STATE_DIM), np.nan)])
        self._prev_frame = np.concatenate([self._prev_frame, np.full(n, -1, dtype=np.int64)])
        self._length = np.concatenate([self._length, np.ones(n, dtype=np.int64)])
        self._first = np.concatenate([self._first, states])
        self._first_frame = np.concatenate([self._first_frame, np.full(n, frame, dtype=np.int64)])

    def step(self, frame: int, states, features=None, detections=None, *,
             edges: bool = True) -> AssocResult:
        """Extend the path cover with the estimates of ``frame``; ``states (M, 6)``, NaN velocity
        meaning unknown; ``features (M, D)``: their colour features
        (:func:`.appearance.box_features`, NaN rows unknown), used when ``app_weight > 0``;
        ``detections (N, 4)`` ``(cx, cy, w, h)``: the frame's detections, read by
        ``extend_heads`` (PHD-MT, whose estimates are not the detections).  ``edges=False``:
        the result's edge arrays are left empty (a caller that does not show them saves
        building them; the tracks are the same)."""
        p = self.params
        use_app = features is not None and p.app_weight > 0
        fast = not (use_app or edges)
        # (the fast path's kernel checks the values itself, before it changes anything)
        new = self._check(frame, states, values=not fast)
        M = len(new)
        if fast:
            if len(self._ids) * M <= DENSE_MAX_PAIRS:
                # no colour features and no edge arrays (the unrecorded run): steps 1-3 in one
                # kernel pass (the same floats and pairs) unless a tail expires
                res = self._step_fast(int(frame), new, detections)
                self._last_frame = int(frame)
                if res is not None:
                    return res
            else:
                self._bad_values(frame, _assoc_kernels.check_states(new))
        frame = int(frame)
        self._last_frame = frame

        # 1. forget tails older than K frames: their tracks end (bounded memory)
        gaps = frame - self._tail_frame
        expired = gaps > p.depth
        ended_ids = ended_len = _NO_IDS     # (most frames end no track: no indexing)
        if _any(expired):
            ended_ids, ended_len = self._ids[expired], self._length[expired]
            self._remember_lost(expired)
            keep = ~expired
            self._ids, self._tail, self._tail_frame = self._ids[keep], self._tail[keep], self._tail_frame[keep]
            self._prev, self._prev_frame = self._prev[keep], self._prev_frame[keep]
            self._length = self._length[keep]
            self._first, self._first_frame = self._first[keep], self._first_frame[keep]
            self._app, self._app_n = self._app[keep], self._app_n[keep]
            gaps = gaps[keep]
        if len(self._lost_ids):
            self._forget_lost(frame)
        use_app = features is not None and p.app_weight > 0
        feats = self._check_features(features, M) if use_app else None  # (None: all NaN)
        if use_app:
            self._app_model.observe_different(feats)

        # 2. score every (tail, new vertex) edge and match
        T = len(self._ids)
        sc = ep = None
        if T and M:
            if T * M <= DENSE_MAX_PAIRS:
                # tail_velocity, score_edges and the matching's admissible weights in one
                # kernel pass (the same floats)
                gain, d2, weight, floor, w0, n_ok, one = _assoc_kernels.frame_edges(
                    self._tail, self._prev, self._tail_frame, self._prev_frame, frame,
                    new.take(OBS_INDEX, axis=1), *p.kernel_args,   # (a C copy: ~1/3 of [:, idx])
                    float(p.speed_prior))
                if use_app or edges:
                    sc = EdgeScores(gain=gain, d2=d2, floor=floor, weight=weight,
                                    allowed=d2 <= p.gate_d2)
                if use_app:
                    llr = self._app_model.llr(similarity(self._app, feats),
                                              self._app_n[:, None])
                    sc = replace(sc, weight=sc.weight + p.app_weight * llr)
                    rows, cols = max_weight_matching(sc.weight, sc.allowed)
                else:
                    rows, cols = _match_admissible(w0, n_ok, one)
            else:   # a storm of estimates: the gated pairs only (DENSE_MAX_PAIRS)
                v, b, c = tail_velocity(
                    self._tail, self._prev,
                    np.where(self._prev_frame >= 0, self._tail_frame - self._prev_frame, 0), p)
                ep = score_edge_pairs(self._tail, v, b, c, gaps, new, p)
                if use_app:
                    llr = self._app_model.llr(similarity_pairs(self._app, feats, ep.rows,
                                                               ep.cols), self._app_n[ep.rows])
                    ep = replace(ep, weight=ep.weight + p.app_weight * llr)
                rows, cols = sparse_max_weight_matching(ep.rows, ep.cols, ep.weight)
        else:
            rows = cols = np.zeros(0, dtype=np.int64)

        # 3. matched vertices continue their track; the others start new tracks (input order)
        # (one kernel pass over the matched pairs, in place; rows and cols made C-contiguous: a
        # matching can return strided views, whose own specialisation would compile mid-run)
        ids, matched, unseen = _assoc_kernels.advance(
            self._ids, self._tail, self._tail_frame, self._prev, self._prev_frame, self._length,
            new, np.ascontiguousarray(rows), np.ascontiguousarray(cols), frame, self._next_id,
            int(p.min_length))
        self._unseen = (unseen, p.min_length)
        n_new = M - len(rows)
        self._next_id += n_new
        if n_new:   # (most frames of a steady scene start no track: nothing to append)
            unmatched = ~matched
            self._append_tracks(ids[unmatched], new[unmatched], frame)
        if use_app and len(rows):
            one = gaps[rows] == 1  # consecutive vertices of one track: the same target
            if _any(one):
                self._app_model.observe_same(
                    np.diagonal(similarity(self._app[rows[one]], feats[cols[one]])))
            old = self._app[rows]
            f = feats[cols]
            mix = (1.0 - p.app_alpha) * old + p.app_alpha * f
            self._app[rows] = np.where(np.isfinite(old), np.where(np.isfinite(f), mix, old), f)
            self._app_n[rows] += np.isfinite(f[:, 0])
        if n_new:
            if feats is None:   # no features: the new tracks' colour models are unknown
                self._app = np.concatenate([self._app, np.full((n_new, APP_DIM), np.nan)])
                self._app_n = np.concatenate([self._app_n, np.zeros(n_new)])
            else:
                self._app = np.concatenate([self._app, feats[unmatched]])
                self._app_n = np.concatenate([self._app_n,
                                              np.isfinite(feats[unmatched, 0]).astype(float)])

        # 4. edges for the observer: admissible pairs only
        if edges and (sc is not None or ep is not None):
            if sc is not None:
                er, ec = np.nonzero(sc.allowed)
                e_gain, e_weight = sc.gain[er, ec], sc.weight[er, ec]
                pick = np.zeros((T, M), dtype=bool)      # (dense: T × M is small here)
                pick[rows, cols] = True
                chosen = pick[er, ec]
            else:
                er, ec, e_gain, e_weight = ep.rows, ep.cols, ep.gain, ep.weight
                chosen = np.isin(er * M + ec, rows * M + cols)
            # each edge's source is the tail as it was before this frame: for a matched tail that
            # vertex has just moved to _prev
            matched_tail = np.zeros(T, dtype=bool)
            matched_tail[rows] = True
            edge_arrays = dict(edges_src=np.where(matched_tail[er][:, None], self._prev[er],
                                                  self._tail[er]),
                               edges_src_id=self._ids[er], edges_dst_index=ec.astype(np.int64),
                               edges_gain=e_gain, edges_weight=e_weight,
                               edges_gap=gaps[er].astype(np.int64), chosen=chosen)
        else:
            edge_arrays = _NO_EDGES

        # 5. gap filling: rows for the frames strictly inside each chosen edge of gap > 1
        if p.fill_gaps and len(rows):
            long = gaps[rows] > 1     # (the frame of the tail each matched vertex continued)
            if _any(long):
                r, c = rows[long], cols[long]
                self._fill_gaps(self._prev[r], self._prev_frame[r], new[c], frame, self._ids[r])
        lengths = self._length[self._ids.searchsorted(ids)]
        return self._finish(frame, new, ids, lengths, None, ended_ids, ended_len, detections,
                            edge_arrays)

    def _step_fast(self, frame: int, new: np.ndarray, detections) -> "AssocResult | None":
        """:meth:`step` without colour features or edge arrays: steps 1-3 in one kernel
        (:func:`._assoc_kernels.frame_step`; the assignment solver between two calls when
        the matching needs it); None (nothing done) when a tail expires this frame."""
        p = self.params
        kv = p.kernel_vec
        min_length = int(p.min_length)
        args = (self._ids, self._tail, self._tail_frame, self._prev, self._prev_frame,
                self._length, new, frame, kv, self._next_id, min_length)
        w0, out, confirmed = _assoc_kernels.frame_step(*args, _NO_IDS, _NO_IDS, False)
        status, flags, P = out[:3].tolist()
        if status >= 2:
            self._bad_values(frame, status - 2)     # (3, 4: the values' check; 2: none)
            return None
        if status == 1:
            # (the assignment solver on the admissible weights, then the advance)
            rows, cols = _match_admissible(w0, 1)
            w0, out, confirmed = _assoc_kernels.frame_step(*args, rows, cols, True)
            status, flags, P = out[:3].tolist()
        M = len(new)
        ids, lengths = out[3:3 + M], out[3 + M:3 + 2 * M]
        if len(self._lost_ids):
            self._forget_lost(frame)
        self._unseen = (bool(flags & 1), p.min_length)
        n_new = M - P
        if n_new:
            unmatched = ids >= self._next_id      # (new tracks' ids: from _next_id on)
            self._append_tracks(ids[unmatched], new[unmatched], frame)
            self._app = np.concatenate([self._app, np.full((n_new, APP_DIM), np.nan)])
            self._app_n = np.concatenate([self._app_n, np.zeros(n_new)])
            self._next_id += n_new
        if p.fill_gaps and flags & 4:
            # (the pairs whose tail had a gap of more than one frame, from the kernel; a
            # matched tail's previous vertex and frame are now in _prev, _prev_frame)
            L = (len(out) - 3 - 2 * M) // 2
            r, c = out[3 + 2 * M:3 + 2 * M + L], out[3 + 2 * M + L:]
            self._fill_gaps(self._prev[r], self._prev_frame[r], new[c], frame, self._ids[r])
        return self._finish(frame, new, ids, lengths, bool(flags & 2), _NO_IDS, _NO_IDS,
                            detections, _NO_EDGES, confirmed)

    def _finish(self, frame: int, new: np.ndarray, ids: np.ndarray, lengths: np.ndarray,
                at_min, ended_ids: np.ndarray, ended_len: np.ndarray, detections,
                edge_arrays: dict, confirmed: np.ndarray | None = None) -> "AssocResult":
        """:meth:`step`'s steps 5b-6 (``lengths``: of this frame's vertices' tracks;
        ``at_min``: some is ``min_length``, None: not known yet; ``confirmed``: ``lengths >=
        min_length`` when the caller has it, None: not known yet)."""
        p = self.params
        M = len(new)

        # 5b. re-linking: a track confirmed now may continue a recently ended one (renames it
        # in the live arrays, the buffer and ``ids``)
        # (only a track of this frame's vertices whose length is min_length now can be newly
        # confirmed -- _relink's candidates are exactly those: most frames have none, and its
        # tests are not run; a re-link renames and re-sorts, so the lengths are read again)
        relinked = _NO_PAIRS
        relink = p.relink_depth > 0 and len(self._lost_ids)
        # (a vertex whose track has min_length vertices now: a track confirmed at this frame)
        if not (relink or p.extend_heads):
            at_min = False
        elif at_min is None:
            at_min = _any(lengths == p.min_length)
        if relink and at_min:
            relinked = self._relink(frame, ids)
            if len(relinked):
                lengths = self._length[self._ids.searchsorted(ids)]
                at_min = _any(lengths == p.min_length)
                confirmed = None
        if confirmed is None:
            confirmed = lengths >= p.min_length

        # 6. bounded-lag output: rows of frames <= k − L, judged with the lengths known now
        self._buffer.append((frame, ids.copy(), new.copy(), np.zeros(M, dtype=bool)))
        if p.extend_heads:
            d = detections
            if d is None:
                d = np.zeros((0, 4))
            elif not (type(d) is np.ndarray and d.dtype == np.float64 and d.ndim == 2
                      and d.shape[1] == 4 and d.flags.c_contiguous):   # (the tracker's: as is)
                d = np.ascontiguousarray(np.asarray(d, dtype=np.float64).reshape(-1, 4))
            self._dets.append((frame, d))
            # (the tracks confirmed at this frame are those of its vertices whose length is
            # min_length now: most frames have none, and the walk back is not entered)
            if at_min:
                self._extend_heads(frame, relinked)
        finalised = []
        last = frame - self.lag
        while self._buffer and self._buffer[0][0] <= last:
            if self._dets and self._dets[0][0] == self._buffer[0][0]:
                self._dets.popleft()
            f, bid, bst, bfill = self._buffer.popleft()
            # (the confirmed test and the three masks in one kernel pass)
            # (and their top-left boxes and conf, the tracker's rows: row_boxes' floats)
            fid, fst, ffill, box, conf = _assoc_kernels.final_rows(
                self._ids, self._length, ended_ids, ended_len, bid, bst, bfill,
                int(p.min_length), GAP_CONF, EST_CONF)
            finalised.append(_made(FinalRows, frame=f, ids=fid, states=fst, filled=ffill,
                                   xywh=box, conf=conf))

        return _made(AssocResult, frame=frame, states=new, ids=ids, lengths=lengths,
                     confirmed=confirmed, ended=ended_ids, finalised=tuple(finalised),
                     relinked=relinked, **edge_arrays)

    def _remember_lost(self, expired: np.ndarray) -> None:
        """Keep the expiring confirmed tracks re-linkable (``relink_depth``)."""
        p = self.params
        sel = expired & (self._length >= p.min_length)
        if p.relink_depth <= 0 or not _any(sel):
            return
        prev_gap = np.where(self._prev_frame[sel] >= 0,
                            self._tail_frame[sel] - self._prev_frame[sel], 0)
        v, b, c = tail_velocity(self._tail[sel], self._prev[sel], prev_gap, p)
        self._lost_ids = np.concatenate([self._lost_ids, self._ids[sel]])
        self._lost = np.concatenate([self._lost, self._tail[sel]])
        self._lost_frame = np.concatenate([self._lost_frame, self._tail_frame[sel]])
        self._lost_vbc = np.concatenate([self._lost_vbc, np.stack([v, b, c], axis=1)])
        self._lost_len = np.concatenate([self._lost_len, self._length[sel]])
        self._lost_app = np.concatenate([self._lost_app, self._app[sel]])
        self._lost_app_n = np.concatenate([self._lost_app_n, self._app_n[sel]])

    def _relink(self, frame: int, ids: np.ndarray) -> np.ndarray:
        """Tracks confirmed at ``frame`` that began after a re-linkable ended track and whose
        first estimate fits its damped prediction (:func:`score_relinks`) take that track's id:
        an exact maximum-weight matching between the ended tracks and the newly confirmed
        ones.  Renames the track in the live arrays, in the buffered rows and in ``ids`` (this
        frame's vertices, in place); with ``fill_gaps`` the buffered frames inside the re-linked
        gap are filled.  Returns ``(P, 2)`` pairs ``(new id, old id)``."""
        p = self.params
        if not len(self._lost_ids):
            return np.zeros((0, 2), dtype=np.int64)
        cand = np.flatnonzero((self._length == p.min_length) & (self._tail_frame == frame))
        if not len(cand):
            return np.zeros((0, 2), dtype=np.int64)
        vbc = self._lost_vbc
        sc = score_relinks(self._lost, vbc[:, 0], vbc[:, 1], vbc[:, 2], self._lost_frame,
                           self._first[cand], self._first_frame[cand], p, self.area)
        weight = sc.weight
        if p.app_weight > 0:
            weight = weight + p.app_weight * self._app_model.llr(
                similarity(self._lost_app, self._app[cand]),
                np.minimum(self._lost_app_n[:, None], self._app_n[cand][None, :]))
        rows, cols = max_weight_matching(weight, sc.allowed)
        if not len(rows):
            return np.zeros((0, 2), dtype=np.int64)
        live = cand[cols]
        old_ids, new_ids = self._lost_ids[rows], self._ids[live]
        self._ids[live] = old_ids
        self._length[live] += self._lost_len[rows]
        src, src_frame = self._lost[rows], self._lost_frame[rows]
        dst, dst_frame = self._first[live], self._first_frame[live]
        keep = np.ones(len(self._lost_ids), dtype=bool)
        keep[rows] = False
        self._lost_ids, self._lost, self._lost_frame = (self._lost_ids[keep], self._lost[keep],
                                                        self._lost_frame[keep])
        self._lost_vbc, self._lost_len = self._lost_vbc[keep], self._lost_len[keep]
        self._lost_app, self._lost_app_n = self._lost_app[keep], self._lost_app_n[keep]
        order = np.argsort(self._ids, kind="stable")  # keep the tails sorted by id
        for name in ("_ids", "_tail", "_tail_frame", "_prev", "_prev_frame", "_length",
                     "_first", "_first_frame", "_app", "_app_n"):
            setattr(self, name, getattr(self, name)[order])
        rename = dict(zip(new_ids.tolist(), old_ids.tolist()))

        def renamed(a: np.ndarray) -> np.ndarray:
            if not len(a):
                return a
            hit = np.isin(a, new_ids)
            if not _any(hit):
                return a
            out = a.copy()
            out[hit] = [rename[x] for x in a[hit].tolist()]
            return out

        ids[:] = renamed(ids)
        for n, (f, bid, bst, bfill) in enumerate(self._buffer):
            self._buffer[n] = (f, renamed(bid), bst, bfill)
        if p.fill_gaps:
            self._fill_gaps(src, src_frame, dst, dst_frame, old_ids)
        return np.stack([new_ids, old_ids], axis=1).astype(np.int64)

    def returning(self, frame: int, Z: np.ndarray, *,
                  or_none: bool = False) -> np.ndarray | None:
        """(N_z,) bool: the detections ``Z`` (N_z, 4) ``(cx, cy, w, h)`` of ``frame`` (the
        frame about to be stepped) inside the edge gate of a confirmed live track that had no
        estimate in the previous frame (its prediction over the gap, :func:`propagate`) and
        had estimates in at least ``revive_rate`` of its frames so far (a person who was just
        missed, not clutter that fires now and then in one place).  ``or_none``: None instead
        of the all-False array when no live track can be such a track (most frames; the
        filter's birth takes None as "no flag": the tracker then makes no array)."""
        p = self.params
        if not (type(Z) is np.ndarray and Z.dtype == np.float64 and Z.ndim == 2
                and Z.shape[1] == 4 and Z.flags.c_contiguous):   # (the tracker's: as is)
            Z = np.ascontiguousarray(np.asarray(Z, dtype=np.float64).reshape(-1, 4))
        unseen, at_length = self._unseen
        if not len(self._ids) or not len(Z) or (not unseen and p.min_length >= at_length):
            return None if or_none else np.zeros(len(Z), dtype=bool)
        # the lost-track test, tail_velocity and score_edges' gate in one kernel pass (the
        # same floats): most frames have no such track, and numpy spent ~20 small calls
        return _assoc_kernels.revive_hits(
            self._tail, self._prev, self._tail_frame, self._prev_frame, self._first_frame,
            self._length, int(frame), Z, int(p.min_length), float(p.revive_rate),
            p.kernel_vec)

    def _extend_heads(self, frame: int, relinked: np.ndarray) -> None:
        """``extend_heads``: the tracks confirmed at ``frame`` (not re-linked) get rows in the
        held-back frames before their first estimate, from the detections there (module
        docstring of :class:`AssocParams`, ``extend_heads``).  A loop over those tracks and
        the frames walked back (at most the report lag), vectorised over the detections."""
        p = self.params
        cand = np.flatnonzero((self._length == p.min_length) & (self._tail_frame == frame))
        if len(relinked):
            cand = cand[~np.isin(self._ids[cand], relinked[:, 1])]
        if not len(cand) or not self._dets:
            return
        frames = {f: n for n, (f, _, _, _) in enumerate(self._buffer)}
        dets = {f: d for f, d in self._dets}
        for t in cand.tolist():
            first, f0 = self._first[t], int(self._first_frame[t])
            span = int(self._tail_frame[t]) - f0
            v = ((self._tail[t, :2] - first[:2]) / span) if span > 0 else np.zeros(2)
            x = first[OBS_INDEX].copy()
            var = 2.0 * obs_noise_var(first[None], p)[0]
            f, skip = f0 - 1, p.head_skip
            while f in frames and f in dets:
                d = dets[f]
                pred = x.copy()
                pred[:2] -= v
                n = frames[f]
                fr, bid, bst, bfill = self._buffer[n]
                # the nearest detection inside the gate that no row of the frame covers (a
                # detection another track's row covers is taken), one kernel pass
                j = _assoc_kernels.head_pick(d, pred, var, bst, float(p.fill_overlap),
                                             float(p.gate_d2))
                if j < 0:
                    if skip <= 0:   # no detection here (nor in the frames skipped): stop
                        break
                    skip -= 1
                    x = pred
                    f -= 1
                    continue
                skip = p.head_skip
                st = np.full((1, STATE_DIM), np.nan)
                st[0, OBS_INDEX] = d[j]
                st[0, 2:4] = v
                self._buffer[n] = (fr, np.concatenate([bid, self._ids[t:t + 1]]),
                                   np.concatenate([bst, st]), np.concatenate([bfill, _TRUE1]))
                x = d[j]
                f -= 1

    def _fill_gaps(self, src: np.ndarray, src_frame: np.ndarray, dst: np.ndarray, frame,
                   ids: np.ndarray) -> None:
        """Add interpolated rows to the buffered frames strictly between each chosen edge's ends
        (``src`` at ``src_frame`` → ``dst`` at ``frame``, one frame or one per edge).  The boxes
        of every (buffered frame, edge) pair in one kernel pass (:func:`._assoc_kernels.
        gap_rows`), shared by the gap support and the rows; the overlap test and the buffer's
        rows one call per frame that gets rows (at most ``depth`` frames)."""
        buf = self._buffer
        if not buf:
            return
        if type(frame) is int:      # (a step's: one end frame for every edge, one element)
            fr = self._frame1
            fr[0] = frame
        else:
            # a writable copy always: a broadcast view of one element stays read-only and
            # numba would compile gap_rows a second time for that array type (filled by
            # assignment, which broadcasts like np.broadcast_to(...).copy() at a fraction of
            # its Python cost)
            fr = np.empty(np.shape(src_frame), dtype=np.int64)
            fr[...] = frame
        obs = OBS_INDEX
        p = self.params
        # every (buffered frame, edge) pair with the frame strictly inside the edge's gap
        # (an edge of gap 1 has none), frame-major (each frame's rows in edge order): the
        # frames with rows are self._buffer[at[k]], their rows run[k]:run[k + 1]; the rows'
        # states and the fill_err test of the straight line in the same kernel pass, with the
        # count of edges longer than fill_free and of the unlikely rows (none of either, the
        # usual frame: no mask is made below)
        # (the buffered frames, consecutive unless frame numbers were skipped: then counted
        # by the kernel from the first, no array made)
        f0 = buf[0][0]
        bf = _NO_IDS if buf[-1][0] - f0 + 1 == len(buf) else self._buffer_frames()
        if not self._cams:
            # the usual frame (every row in the last buffered frame, no long edge, every row
            # likely): the rows and the frame's new rows in one call; else the steps below
            lf, lid, lst, lfill = buf[-1]
            status, lid, lst, lfill, added = _assoc_kernels.gap_fill_last(
                bf, f0, len(buf), np.ascontiguousarray(src), np.ascontiguousarray(src_frame),
                np.ascontiguousarray(dst), fr, float(self.scene_sigma_v), float(p.fill_err),
                float(p.fill_free), np.ascontiguousarray(ids, dtype=np.int64), lid, lst,
                lfill, float(p.fill_overlap))
            if status >= 0:
                if added:
                    buf[-1] = (lf, lid, lst, lfill)
                return
        at, fi, ei, st, likely, run, n_far, n_unlikely = _assoc_kernels.gap_rows(
            bf, f0, len(buf), np.ascontiguousarray(src), np.ascontiguousarray(src_frame),
            np.ascontiguousarray(dst), fr, float(self.scene_sigma_v), float(p.fill_err),
            float(p.fill_free))
        if not len(ei):
            return
        at, run = at.tolist(), run.tolist()
        fs = None
        if self._cams or n_far or n_unlikely:
            fs = self._buffer_frames()[at]
            # each edge's end frame
            frame = (fr if len(fr) == len(src_frame)
                     else np.full(len(src_frame), frame, dtype=np.int64))
        if self._cams:
            box = st[:, obs]
            for k in range(len(fs)):
                r = slice(run[k], run[k + 1])
                box[r] = self._back(box[r], int(fs[k]), frame[ei[r]])
            st[:, obs] = box
        if p.fill_support > 0 and n_far:
            # a gap of at most fill_free missing frames is filled anyway: the evidence is
            # looked up for the longer ones only (one edge's support is its own; with no
            # longer edge every row is selected)
            gap = frame - src_frame
            ok = gap - 1 <= self.params.fill_free
            look = ~ok
            if _any(look):
                hits = np.bincount(ei, weights=self._gap_hits(at, run, st[:, obs], look[ei]),
                                   minlength=len(gap))
                ok[look] = (hits / np.maximum(gap - 1, 1))[look] >= self.params.fill_support
            sel = ok[ei]
            if not _any(sel):
                return
            if not _all(sel):
                fi, ei, st, likely = fi[sel], ei[sel], st[sel], likely[sel]
                run = np.searchsorted(fi, np.arange(len(fs) + 1)).tolist()
        fid = ids[ei]
        if not n_unlikely:
            keep = _NO_BOOL     # (every row likely, hence kept: no mask)
        else:
            keep = self._likely_rows(fs, run, st, likely) if p.fill_err > 0 else None
            if keep is None or _all(keep):
                keep = _NO_BOOL     # (every row kept: no mask)
        thr = float(self.params.fill_overlap)
        for k, n in enumerate(at):
            lo, hi = run[k], run[k + 1]
            if lo == hi:
                continue
            f, bid, bst, bfill = self._buffer[n]
            # the kept rows that no other track's estimate already covers (the gap is then
            # the other track's frame: filling it would report one target twice), appended
            # in one kernel pass
            bid, bst, bfill, added = _assoc_kernels.fill_rows(bid, bst, bfill, st, fid, lo, hi,
                                                               keep, thr)
            if added:
                self._buffer[n] = (f, bid, bst, bfill)

    def _buffer_frames(self) -> np.ndarray:
        """(B,) int64 frames of the held-back rows (strictly increasing): an arange when they
        are consecutive (the usual case: no frame number skipped), else read off the buffer."""
        buf = self._buffer
        f0, f1 = buf[0][0], buf[-1][0]
        if f1 - f0 + 1 == len(buf):
            return np.arange(f0, f1 + 1, dtype=np.int64)
        return np.fromiter((b[0] for b in buf), np.int64, len(buf))

    def _likely_rows(self, fs: np.ndarray, run: list, st: np.ndarray,
                     likely: np.ndarray) -> np.ndarray:
        """``fill_err``: mask of the gap rows ``st`` (rows ``run[k]:run[k + 1]`` in frame
        ``fs[k]``) whose straight line is likely right -- ``likely``: its error std
        (:func:`interpolation_std` under ``scene_sigma_v``) at most ``fill_err``
        (:func:`._assoc_kernels.gap_rows`) -- or that a detection of its frame (kept with
        extend_heads) overlaps by ``fill_overlap``."""
        if _all(likely):
            return likely
        keep = likely.copy()
        for k in range(len(fs)):
            r = slice(run[k], run[k + 1])
            if _all(keep[r]):
                continue
            f = int(fs[k])
            d = next((d for g, d in self._dets if g == f), None)
            if d is not None and len(d):
                keep[r] |= _iou(st[r][:, OBS_INDEX], d).max(axis=1) >= self.params.fill_overlap
        return keep

    def _gap_hits(self, at: list, run: list, box: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """``fill_support``'s evidence: per gap row (``box`` (R, 4), rows ``run[k]:run[k + 1]``
        in the buffered frame ``self._buffer[at[k]]``), whether its interpolated box overlaps a
        detection of the frame or another track's estimate by ``fill_overlap`` or more; only
        the ``rows`` (mask) are looked at, the others are False.  One overlap call per frame."""
        obs = OBS_INDEX
        dets = {f: d for f, d in self._dets}
        hit = np.zeros(len(box), dtype=bool)
        for k, n in enumerate(at):
            m = rows[run[k]:run[k + 1]]
            if not _any(m):
                continue
            f, bid, bst, bfill = self._buffer[n]
            ev = bst[~bfill][:, obs]
            d = dets.get(f)
            if d is not None and len(d):
                ev = np.concatenate([ev, d])
            if len(ev):
                h = hit[run[k]:run[k + 1]]
                h[m] = _iou(box[run[k]:run[k + 1]][m], ev).max(axis=1) >= self.params.fill_overlap
        return hit

    def _confirmed_ids(self, ids: np.ndarray, extra_ids=None, extra_len=None) -> np.ndarray:
        """Mask of ``ids`` whose track has at least ``min_length`` vertices (live or just ended;
        one kernel pass)."""
        if extra_ids is None:
            extra_ids, extra_len = _NO_IDS, _NO_IDS
        return _assoc_kernels.confirmed(self._ids, self._length, extra_ids, extra_len, ids,
                                        int(self.params.min_length))

    def flush(self) -> tuple[FinalRows, ...]:
        """End of sequence: the buffered rows (the last ``L`` frames) of confirmed tracks."""
        out = []
        self._dets.clear()
        while self._buffer:
            f, bid, bst, bfill = self._buffer.popleft()
            ok = self._confirmed_ids(bid)
            out.append(FinalRows(f, bid[ok], bst[ok], bfill[ok]))
        return tuple(out)
