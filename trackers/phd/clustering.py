"""Peak extraction from the particle PHD by modified K-means — maggio2007 §3.

§3: "N(k) clusters are first initialized on the N(k) observations with zero velocity. After
convergence of K-means, if M^(j) > 1 (i.e., the total mass of the samples in cluster j is
larger than 1) a new center is set on the cluster sample with largest distance from the
center. Next, K-means iterates until the condition M^(j) < 1 ∀j is satisfied. Finally,
clusters with M^(j) < T are discarded."  The particles are weighted by their PHD weight:
centres are weighted means, cluster masses are sums of weights.

Readings (each a parameter of :func:`kmeans_peaks`):

- **Distance** (``distance``): the squared Mahalanobis distance on ``(y1, y2, w, h)`` under the
  observation noise of maggio2007 §4 evaluated at the *centre's* size
  (``σ_w = max(0.15 w_c, 1)``, ``σ_y1 = σ_w / 2`` ...) — the same metric as the likelihood and
  the birth gate, so position and size are scaled by the object size and a distance of ~3.6
  is the 99% gate.  Velocity is not part of the distance (the detections carry none and the
  paper initialises centres with zero velocity); it is averaged into the centres, so the
  output centres carry the velocity estimate that §3 says the association benefits from.
- **Split rule** (``split_rule``): taken literally (``"literal"``), a single well-detected
  target whose mass exceeds 1 — e.g. 1/(1 − p_M e) ≈ 1.05 when clutter is negligible, or a
  target with a duplicate detection — is cut into two halves of ~0.5 < T and both are
  discarded: the target vanishes.  The default ``"guarded"`` keeps the paper's intent (split
  clusters that hold more than one target): a split is tried on a cluster with mass
  ``> split_above`` (1.0) and *kept only if both resulting clusters have mass
  >= min_split_mass* (default T); otherwise the state before the split is restored and that
  cluster is final.  Splits are tried one at a time, heaviest cluster first (deterministic).
- **Local split trials** (bounded cost, not in the paper): after a split §3 lets K-means
  iterate again over everything; here the trial Lloyd iterations run on the split cluster and
  its :data:`SPLIT_NEIGHBOURS` nearest clusters (centres within twice its reach) only, so a
  split costs O(its neighbourhood), not O(all particles) — a clutter storm with tens of split
  attempts stays bounded (the far clusters are unchanged by a split that could not reach them
  anyway).  A guarded split is not tried on a cluster whose own mass is below
  ``2 min_split_mass`` (its halves could both reach ``min_split_mass`` only by taking mass
  from the neighbouring clusters, i.e. from other peaks: a single target with a little
  clutter or a duplicate detection, mass ~1-1.2, is final at once; its neighbourhood, which
  holds it, then holds at least that much too).  (Before this
  pre-check every such trial ran its Lloyd iterations to the end and was rejected on the
  bench scene: ~5/6 of the trials' iterations at 16 targets; on the development set the
  tracks change a little, the accuracy does not -- docs/phd.md.)
- **Convergence** (``tol``, ``max_iter``): Lloyd stops when the labels are stable, when no centre's
  observed part moved more than ``tol`` pixels (centres are then the means of the returned
  labels), or after ``max_iter`` iterations (labels are then the nearest centres).
- **Subsample** (``subsample``, not in the paper; an option, default 1: every particle): after
  resampling every particle weighs the same, and systematic resampling lays the copies of an
  ancestor side by side, so every ``subsample``-th particle (each weighing ``n / n_sub`` times
  more) is a stratified half of the same PHD: K-means on it costs about half and finds the
  same peaks (bench scene, 4 and 16 targets: the same kept clusters on all 140 frames,
  centres ~0.05 px apart at the median).  ``labels`` of every particle are then its nearest
  final centre, taken when first read (particle-level stage data, per-measurement
  estimates).  Unequal weights: every particle.
- **No observations**: with no detection and no ``extra_centers`` the iteration starts from a
  single centre at the weighted mean of the particles (the split rule then separates peaks).
  ``extra_centers`` lets a caller add centres (e.g. the previous frame's peaks).

Cost (DESIGN.md, linear in the number of targets): systematic resampling lays the copies of
an ancestor side by side as identical rows (on the bench scene only ~2/3 of the resampled rows
are distinct), so each run of consecutive identical rows enters K-means as one row weighing
their sum (:func:`._kmeans_kernels.prepare`; for a set systematic resampling made, from the
runs it recorded, :meth:`~..smc.weights.ParticleSet.known_copies`, with no comparison of every row:
:func:`._kmeans_kernels.prepare_copies`): the same labels, the same centres and masses up
to summation round-off, a third fewer rows in every Lloyd pass and split trial; ``labels`` of
every particle (its row's) are taken when first read.  The split loop (candidates, pre-checks,
local trials) is one numba kernel (:func:`._kmeans_kernels.split_clusters`), the Lloyd
iterations another (:func:`._kmeans_kernels.lloyd`: assignment, then the weighted sums in
one pass, no (N × K) temporaries).  With fewer than :data:`INDEX_MIN_CENTERS` centres the
assignment has plain K-means' answer from a look at every centre -- by blocks of consecutive
particles, each looking only at the centres that could beat the previous block's centre
somewhere in its box (:func:`._kmeans_kernels._assign_blocks`; exact); with more, each particle looks only at the centres near it (a
grid of the centres, :func:`._kmeans_kernels.assign`), and the result is still *exact* — the same
labels, ties to the lowest index included, the same d² floats: every centre's inverse variances
are at least m (their minimum), so a centre at Euclidean distance e in the position plane scaled
by sqrt(m) has d² >= e², so a particle scans its previous centre's neighbours (the centres of
its 3 × 3 block of grid cells, by distance) until the triangle inequality rules out the rest,
and searches the grid's rings around itself only when that list ends too soon.  A late
iteration where most centres stay put costs about one distance per particle, and nothing is
O(K²) in time or memory (a 2,000-detection storm's K-means: 4.2 s → 0.33 s a frame).

**Per-measurement estimates** (:func:`measurement_estimates`, not in maggio2007; opt-in,
``clusters.estimate = measurement``): a K-means centre is the mean of every particle
assigned to the cluster, so it mixes the parts of the updated PHD that eq. (5) keeps apart --
the missed-detection part ``p_M ω`` (the whole predicted cloud, wide when the motion is fast)
and each detection's part ``t_z(x) ω`` with ``t_z = (1 − p_M) g(z|x) / (κ(z) + C(z))``.  The
state of the target that produced detection z is the mean of z's part alone -- the
per-measurement estimate of the SMC-PHD literature (Ristic, Clark & Vo 2010, "Improved SMC
implementation of the PHD filter"; Stone Soup's SMC-PHD reads its estimates that way) --
here restricted to the cluster's own particles, so that a neighbour's particles that z also
reaches (two people side by side) stay with the neighbour's cluster.  A kept cluster
initialised on a detection that won at least half a target (``won = C(z)/(κ(z)+C(z)) >= 0.5``:
more likely a target's than clutter) reports that mean's position and size, each particle
weighted by the share ``t_z / (p_M + Σ_z' t_z')`` of its updated weight that z explains; its
velocity stays the cluster's (z carries none: z's part is pulled to the newborn's prior speed)
and its mass is unchanged.  Other kept clusters (a split's, or on a detection that is more
likely clutter) keep the K-means centre.  Cost: one gated pass of the detections over those
clusters' particles (:func:`.filter.gated_log_g`), O(pairs).
Measured (development set, seeds 0-2): with ``clutter_model=learn learn_update=model``
PETS09-S2L1 IDF1 0.680 -> 0.708, KITTI-13 MOTA 0.121 -> 0.148, the others within 0.005; with the
``gate`` clutter model TUD-Stadtmitte loses 0.03 IDF1 (two people crossing swap identities on
two seeds: the centre's share of the predicted cloud carried their momentum through the
crossing), hence opt-in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Callable, Optional

import numpy as np

from ..smc.weights import ParticleSet
from ..types import cxcywh_to_xywh
from . import _kmeans_kernels
from .filter import OBS_COLS, OBS_DIM, STATE_DIM, PHDParams, as_observations, gated_log_g

#: ``Clusters.origin`` codes for centres not initialised on an observation.
ORIGIN_SPLIT = _kmeans_kernels.ORIGIN_SPLIT
ORIGIN_EXTRA = _kmeans_kernels.ORIGIN_EXTRA

#: From this many centres on, the assignment step looks only at the centres near each particle
#: (a grid of the centres, :func:`._kmeans_kernels.assign`; same labels as looking at all of them).
#: (Below it the dense look, which passes over far centres cheaply, is as fast or faster: 16
#: targets on the bench scene, ~20 centres, K-means 2-3 % faster than with 16 here.)
INDEX_MIN_CENTERS = 32
#: A split's trial Lloyd iterations run on the split cluster and at most this many of its
#: nearest neighbouring clusters (itself included).
SPLIT_NEIGHBOURS = 4


@dataclass(frozen=True, init=False)
class Clusters:
    """Result of :func:`kmeans_peaks`.

    centers (K, 6) states ``(y1, y2, v1, v2, w, h)``; masses (K,) PHD mass of each cluster;
    labels (N,) int64 cluster of each particle; kept (K,) bool ``mass >= T``;
    origin (K,) int64 the detection a centre was initialised on, or ``ORIGIN_SPLIT`` /
    ``ORIGIN_EXTRA``; n_splits accepted splits; n_iter total K-means iterations.
    """

    centers: np.ndarray
    masses: np.ndarray
    _labels: Optional[np.ndarray]       # (None: ``_labeller`` gives them when first read)
    kept: np.ndarray
    origin: np.ndarray
    n_splits: int = 0
    n_iter: int = 0
    _labeller: Optional[Callable[[], np.ndarray]] = field(default=None, repr=False,
                                                          compare=False)
    _kept_centers: Optional[np.ndarray] = field(default=None, repr=False, compare=False)

    def __init__(self, centers: np.ndarray, masses: np.ndarray, _labels: Optional[np.ndarray],
                 kept: np.ndarray, origin: np.ndarray, n_splits: int = 0, n_iter: int = 0,
                 _labeller: Optional[Callable[[], np.ndarray]] = None,
                 _kept_centers: Optional[np.ndarray] = None):
        # (the frozen dataclass's generated __init__ sets each field by object.__setattr__:
        # the instance dict directly costs a fraction; made every frame)
        d = self.__dict__
        d["centers"], d["masses"], d["_labels"], d["kept"] = centers, masses, _labels, kept
        d["origin"], d["n_splits"], d["n_iter"], d["_labeller"] = (origin, n_splits, n_iter,
                                                                   _labeller)
        d["_kept_centers"] = _kept_centers

    def __len__(self) -> int:
        return len(self.masses)

    @property
    def labels(self) -> np.ndarray:
        """(N,) int64 cluster of each particle (taken when first read, when K-means ran on a
        subsample or on merged runs of identical rows: only the particle-level stage data and
        the per-measurement estimates read them)."""
        if self._labels is None and self._labeller is not None:
            object.__setattr__(self, "_labels", self._labeller())
            object.__setattr__(self, "_labeller", None)
        return self._labels

    @property
    def kept_centers(self) -> np.ndarray:
        """(K_kept, 6) the estimated target states X̂_k passed to data association (a new
        array at each read: the first, :func:`kmeans_peaks`' kernel made it -- a boolean
        gather costs ~10-30 us when the caches are cold, as between two frames of a run)."""
        kc = self._kept_centers
        if kc is not None:
            self.__dict__["_kept_centers"] = None
            return kc
        return self.centers[self.kept]

    @property
    def kept_masses(self) -> np.ndarray:
        return self.masses[self.kept]

    def boxes(self) -> np.ndarray:
        """(K, 4) centre boxes as ``(x, y, w, h)`` top-left (for drawing)."""
        return cxcywh_to_xywh(self.centers[:, OBS_COLS])


def _lloyd(X, states, w_rel, centers, params: PHDParams, max_iter, tol=0.0):
    """Weighted Lloyd iterations from ``centers`` until the assignment is stable, no centre's
    observed part moves more than ``tol`` pixels, or ``max_iter`` iterations
    (:func:`._kmeans_kernels.lloyd`).  Returns centers, labels, relative masses, each particle's d²
    to its centre (at its last assignment), iterations.  Centres are the weighted means of the
    returned labels (an empty cluster keeps its centre), except after ``max_iter`` iterations,
    where the labels are the nearest centres."""
    lk = params.likelihood
    # below INDEX_MIN_CENTERS: the kernel's dense specialisation (grid_min None), which is all
    # a run of few detections per frame compiles (the grid search compiles on first need)
    grid_min = int(INDEX_MIN_CENTERS) if len(centers) >= INDEX_MIN_CENTERS else None
    c, lab, m, dmin, it = _kmeans_kernels.lloyd(
        X, states, w_rel, np.ascontiguousarray(centers, dtype=np.float64), int(max_iter),
        float(tol), lk.sigma_obs, lk.sigma_obs_min, lk.sigma_obs_pos_ratio, grid_min)
    return c, lab, m, dmin, int(it)


def kmeans_peaks(ps: ParticleSet, Z, T: float = 0.6, *, params: PHDParams | None = None,
                 split_rule: str = "guarded", split_above: float = 1.0,
                 min_split_mass: float | None = None, max_iter: int = 50, max_splits: int = 64,
                 extra_centers: np.ndarray | None = None, tol: float = 0.01,
                 subsample: int = 1) -> Clusters:
    """Modified K-means of maggio2007 §3 on the particle PHD ``ps``; ``Z`` (N_z, 4) the frame's
    observations (or a :class:`~trackers.types.Detections`) initialise the centres.

    T: discard threshold (0.6, §4).  params: supplies the observation-noise metric (default
    :class:`PHDParams`).  split_rule: ``"guarded"`` (default) or ``"literal"`` — see the
    module docstring; split_above: a cluster heavier than this is a split candidate (1.0, §3);
    min_split_mass: guarded rule, both halves must reach it (default ``T``).  max_iter: Lloyd
    iterations per run (the first run and each split trial); max_splits: split attempts at
    most; tol: convergence tolerance, pixels (largest move of a centre's (y1, y2, w, h)).
    So ``n_iter <= max_iter (1 + max_splits)``.  subsample: when every particle weighs the
    same (after resampling), K-means runs on every ``subsample``-th one (each weighing
    ``n / n_sub`` times more: the masses keep their total); ``labels`` are then each particle's
    nearest final centre, taken when first read.  Deterministic (no randomness).
    """
    if split_rule not in ("guarded", "literal"):
        raise ValueError(f"kmeans_peaks: split_rule must be 'guarded' or 'literal', got {split_rule!r}")
    guarded = split_rule == "guarded"
    params = params if params is not None else PHDParams()
    min_split_mass = T if min_split_mass is None else min_split_mass
    # (as_observations' checks: the shape here, the values in the kernel)
    if hasattr(Z, "observations"):
        Z = Z.observations()
    Z = np.ascontiguousarray(Z, dtype=np.float64)
    if not Z.flags.writeable:           # (the kernel's one specialisation: writable arrays)
        Z = Z.copy()
    if Z.size == 0:
        Z = _NO_OBS
    elif Z.ndim != 2 or Z.shape[1] != OBS_DIM:
        raise ValueError(f"observations: expected shape (N, 4) (y1, y2, w, h), got {Z.shape}")
    states = ps.states
    if states.shape[1] != STATE_DIM:
        raise ValueError(f"kmeans_peaks: expected (N, 6) particle states, got {states.shape}")
    n = len(states)
    extra = _NO_EXTRA
    if extra_centers is not None and len(extra_centers):
        extra = np.array(extra_centers, dtype=np.float64).reshape(-1, STATE_DIM)
    log_w = ps.log_weights
    full = None
    if subsample > 1 and n >= 2 * subsample and log_w[0] == log_w[-1] \
            and np.isfinite(log_w[0]) and np.all(log_w == log_w[0]):
        full = states
        states = states[::subsample]
        log_w = np.full(len(states), log_w[0] + math.log(n / len(states)))
    # (systematic resampling's equal weights: the max is any of them, no pass)
    equal = full is None and ps.is_known_equal()
    lmax = (log_w[0] if equal else log_w.max()) if n else -math.inf
    if not math.isfinite(lmax):         # no particle, or no finite weight: nothing to cluster
        Z = as_observations(Z)
        init, origin = _initial_centers(Z, extra)
        K = len(init)
        return Clusters(init, np.zeros(K), np.zeros(n, dtype=np.int64), np.zeros(K, dtype=bool),
                        origin)
    # Everything else in one kernel call (_kmeans_kernels.peaks): the weights relative to the
    # largest keep the means exact even when masses underflow; positions are centred (not
    # the sizes: they set the metric) so the expanded distance loses no precision on large
    # images; runs of identical rows (resampling's copies of an ancestor) are merged into one
    # row of their summed weight (_kmeans_kernels.prepare); the first Lloyd run, then the
    # split loop (guarded or literal rule, local trials: _kmeans_kernels.split_clusters).
    lk = params.likelihood
    K0 = len(Z) + len(extra)
    # systematic resampling's runs of copies (equal weights): each run's row taken once
    copies = ps.copies() if equal else None
    pos = _NO_POS
    if copies is None:
        copies = _NO_COPIES
    else:                               # (and their position sums, taken by the walk)
        pos = ps.copy_sums()
        if pos is None:
            pos = _NO_POS
    # the run's settings as one array (one kernel argument instead of twelve: each costs the
    # call ~2 us when the caches are cold), made once per distinct settings
    key = (T, split_above, min_split_mass, guarded, max_splits, max_iter, tol, lk.sigma_obs,
           lk.sigma_obs_min, lk.sigma_obs_pos_ratio)
    cfg = _CFG.get(key)
    if cfg is None:
        if len(_CFG) > 64:
            _CFG.clear()
        cfg = _CFG[key] = np.array(
            [T, split_above, 2.0 * min_split_mass if guarded else -np.inf, min_split_mass,
             1.0 if guarded else 0.0, int(max_splits), int(SPLIT_NEIGHBOURS), int(max_iter),
             tol, lk.sigma_obs, lk.sigma_obs_min, lk.sigma_obs_pos_ratio], dtype=np.float64)
    (bad, centers, masses, labels, runs, kept, origin, n_splits, n_iter,
     kc) = _kmeans_kernels.peaks(
        np.ascontiguousarray(states, dtype=np.float64),
        np.ascontiguousarray(log_w, dtype=np.float64), copies, pos, Z, extra, np.exp(lmax), cfg,
        int(INDEX_MIN_CENTERS) if K0 >= INDEX_MIN_CENTERS else None)
    if bad:
        as_observations(Z)              # (raises its message)
    if full is not None:
        return Clusters(centers, masses, None, kept, origin, n_splits, n_iter,
                        partial(_nearest_labels, full, ps.log_weights, centers, params), kc)
    if len(labels) != n:                # merged rows: every particle's label when first read
        return Clusters(centers, masses, None, kept, origin, n_splits, n_iter,
                        partial(np.repeat, labels, runs), kc)
    return Clusters(centers, masses, labels, kept, origin, n_splits, n_iter, None, kc)


_NO_OBS = np.zeros((0, OBS_DIM))
_CFG: dict = {}                         # kmeans_peaks' settings arrays (_kmeans_kernels.peaks)
_NO_COPIES = np.zeros(0, dtype=np.int64)
_NO_POS = np.zeros(0, dtype=np.float64)
_NO_EXTRA = np.zeros((0, STATE_DIM))


def _initial_centers(Z, extra):
    """§3's initial centres (observations with zero velocity, then ``extra``) and their
    origins, for the no-particle answer."""
    init = np.zeros((len(Z), STATE_DIM))
    init[:, OBS_COLS] = Z
    origin = np.arange(len(Z), dtype=np.int64)
    if len(extra):
        init = np.concatenate([init, extra])
        origin = np.concatenate([origin, np.full(len(extra), ORIGIN_EXTRA, dtype=np.int64)])
    return init, origin


def _nearest_labels(states, log_w, centers, params: PHDParams) -> np.ndarray:
    """(N,) each particle's nearest centre: :func:`._kmeans_kernels.prepare` (runs of
    identical rows merged), then :func:`._kmeans_kernels.lloyd` with no iteration (its final
    assignment only), looking at every centre (one dense pass is cheaper than the grid's
    first search from no labels), each run's label repeated over its particles."""
    _, w, shift, S, X, runs = _kmeans_kernels.prepare(
        np.ascontiguousarray(states, dtype=np.float64),
        np.ascontiguousarray(log_w, dtype=np.float64))
    lk = params.likelihood
    labels = _kmeans_kernels.lloyd(X, S, w, np.ascontiguousarray(centers - shift), 0, 0.0,
                                   lk.sigma_obs, lk.sigma_obs_min, lk.sigma_obs_pos_ratio,
                                   None)[1]
    return labels if len(labels) == len(states) else np.repeat(labels, runs)


#: :func:`measurement_estimates`: a detection must have won at least this share of a target
#: (``C(z)/(κ(z)+C(z))``: more likely a target's than clutter) for its cluster to report the
#: posterior given that detection.
MIN_WON = 0.5


def measurement_estimates(clusters: Clusters, ps: ParticleSet, Z, won: np.ndarray,
                          kappa: np.ndarray, c_z: np.ndarray, p_miss: float, likelihood,
                          params: PHDParams, frame=None, min_won: float = MIN_WON) -> Clusters:
    """``clusters`` (K-means of the particles ``ps``) with each kept cluster initialised on a
    detection z that won at least ``min_won`` reporting, for its position and size, the mean of
    the part of its particles' weight that z explains (module docstring, "Per-measurement
    estimates"); velocity, masses, labels unchanged.

    A particle's updated weight is ``ω⁻ (p_M + Σ_z' t_z'(x))`` with ``t_z = (1 − p_M) g(z|x) /
    (κ(z) + C(z))`` (eq. (5)), so the share z explains is ``t_z(x) / (p_M + Σ_z' t_z'(x))``;
    ``ps`` holds the updated PHD (after resampling), ``labels`` say which particles are the
    cluster's.  Z (N_z, 4) the frame's detections; won, kappa, c_z (N_z,) the update's
    ``per_det_mass``, κ(z), C(z); p_miss its p_M; ``likelihood``, ``params``: the filter's
    (the same gated g as the update, :func:`.filter.gated_log_g`).  A detection none of whose
    cluster's particles lies in its gate keeps the K-means centre."""
    Z = as_observations(Z)
    won, kappa, c_z = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (won, kappa, c_z))
    if not len(won) == len(kappa) == len(c_z) == len(Z):
        raise ValueError(f"measurement_estimates: {len(Z)} detections but {len(won)} won, "
                         f"{len(kappa)} κ and {len(c_z)} C values")
    labels = clusters.labels
    if len(labels) != len(ps):
        raise ValueError(f"measurement_estimates: {len(ps)} particles but {len(labels)} labels")
    k = np.flatnonzero(clusters.kept & (clusters.origin >= 0))
    if len(k) == 0 or len(ps) == 0:
        return clusters
    k = k[won[clusters.origin[k]] >= min_won]
    if len(k) == 0:
        return clusters
    cluster_of = np.full(len(Z), -1, dtype=np.int64)       # detection -> the cluster it reports
    cluster_of[clusters.origin[k]] = k
    # only the chosen clusters' particles matter: gate every detection against them (their
    # bracket p_M + Σ t needs each detection that reaches them)
    member = np.flatnonzero(np.isin(labels, k))
    if len(member) == 0:
        return clusters
    states = np.asarray(ps.states, dtype=np.float64)[member]
    rows, cols, vals = [], [], []
    for ch in gated_log_g(likelihood, states, Z, frame, params):
        rows.append(ch.rows)
        cols.append(ch.cols)
        vals.append(ch.values)
    if not rows:
        return clusters
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    log_pd = math.log1p(-p_miss) if p_miss < 1 else -np.inf
    t = np.exp(np.concatenate(vals) + log_pd - np.log(kappa + c_z)[cols])
    bracket = p_miss + np.bincount(rows, weights=t, minlength=len(member))
    own = cluster_of[cols] >= 0
    own[own] = labels[member[rows[own]]] == cluster_of[cols[own]]
    rows, cols, t = rows[own], cols[own], t[own]
    lw = np.asarray(ps.log_weights, dtype=np.float64)[member[rows]]
    ok = (bracket[rows] > 0) & np.isfinite(lw) & (t > 0)
    if not ok.any():
        return clusters
    rows, cols, t, lw = rows[ok], cols[ok], t[ok], lw[ok]
    w = np.exp(lw - lw.max()) * t / bracket[rows]
    total = np.bincount(cols, weights=w, minlength=len(Z))
    det = np.flatnonzero((total > 0) & (cluster_of >= 0))
    centers = clusters.centers.copy()
    for d in OBS_COLS:
        m = np.bincount(cols, weights=w * states[rows, d], minlength=len(Z))
        centers[cluster_of[det], d] = m[det] / total[det]
    return replace(clusters, centers=centers, _kept_centers=None)
