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
- **No observations**: with no detection and no ``extra_centers`` the iteration starts from a
  single centre at the weighted mean of the particles (the split rule then separates peaks).
  ``extra_centers`` lets a caller add centres (e.g. the previous frame's peaks).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..smc.weights import ParticleSet
from ..types import cxcywh_to_xywh
from .filter import OBS_COLS, STATE_DIM, PHDParams, as_observations, obs_std

#: ``Clusters.origin`` codes for centres not initialised on an observation.
ORIGIN_SPLIT = -1
ORIGIN_EXTRA = -2


@dataclass(frozen=True)
class Clusters:
    """Result of :func:`kmeans_peaks`.

    centers (K, 6) states ``(y1, y2, v1, v2, w, h)``; masses (K,) PHD mass of each cluster;
    labels (N,) int64 cluster of each particle; kept (K,) bool ``mass >= T``;
    origin (K,) int64 the detection a centre was initialised on, or ``ORIGIN_SPLIT`` /
    ``ORIGIN_EXTRA``; n_splits accepted splits; n_iter total K-means iterations.
    """

    centers: np.ndarray
    masses: np.ndarray
    labels: np.ndarray
    kept: np.ndarray
    origin: np.ndarray
    n_splits: int = 0
    n_iter: int = 0

    def __len__(self) -> int:
        return len(self.masses)

    @property
    def kept_centers(self) -> np.ndarray:
        """(K_kept, 6) the estimated target states X̂_k passed to data association."""
        return self.centers[self.kept]

    @property
    def kept_masses(self) -> np.ndarray:
        return self.masses[self.kept]

    def boxes(self) -> np.ndarray:
        """(K, 4) centre boxes as ``(x, y, w, h)`` top-left (for drawing)."""
        return cxcywh_to_xywh(self.centers[:, OBS_COLS])


def _distances(X: np.ndarray, centers: np.ndarray, params: PHDParams) -> np.ndarray:
    """(N, K) squared Mahalanobis distances of the observed part ``X`` (N, 4) to the centres,
    each under the observation noise at its own size.  Expanded as matrix products
    (``Σ x²/σ² − 2 Σ x c/σ² + Σ c²/σ²``) so one iteration is two (N,4)@(4,K) products; ``X``
    is expected centred near 0 (see :func:`kmeans_peaks`) to keep cancellation negligible."""
    C = centers[:, OBS_COLS]
    inv = 1.0 / obs_std(centers[:, 4:6], params.likelihood) ** 2            # (K, 4)
    d2 = (X * X) @ inv.T - 2.0 * X @ (C * inv).T + np.sum(C * C * inv, axis=1)[None, :]
    return np.maximum(d2, 0.0)


def _lloyd(X, states, w_rel, centers, params, max_iter):
    """Weighted Lloyd iterations from ``centers`` until the assignment is stable.
    Returns centers, labels, relative masses, d2 matrix, iterations."""
    centers = centers.copy()
    K = len(centers)
    labels = None
    it = 0
    for it in range(1, max_iter + 1):
        d2 = _distances(X, centers, params)
        new = np.argmin(d2, axis=1)
        if labels is not None and np.array_equal(new, labels):
            break
        labels = new
        m = np.bincount(labels, weights=w_rel, minlength=K)
        nz = m > 0
        sums = np.stack([np.bincount(labels, weights=w_rel * states[:, d], minlength=K)
                         for d in range(STATE_DIM)], axis=1)
        # Weighted mean of every non-empty cluster; an empty cluster keeps its centre.
        centers[nz] = sums[nz] / m[nz, None]
    else:
        d2 = _distances(X, centers, params)
        labels = np.argmin(d2, axis=1)
    m = np.bincount(labels, weights=w_rel, minlength=K)
    return centers, labels, m, d2, it


def kmeans_peaks(ps: ParticleSet, Z, T: float = 0.6, *, params: PHDParams | None = None,
                 split_rule: str = "guarded", split_above: float = 1.0,
                 min_split_mass: float | None = None, max_iter: int = 50, max_splits: int = 64,
                 extra_centers: np.ndarray | None = None) -> Clusters:
    """Modified K-means of maggio2007 §3 on the particle PHD ``ps``; ``Z`` (N_z, 4) the frame's
    observations (or a :class:`~trackers.types.Detections`) initialise the centres.

    T: discard threshold (0.6, §4).  params: supplies the observation-noise metric (default
    :class:`PHDParams`).  split_rule: ``"guarded"`` (default) or ``"literal"`` — see the
    module docstring; split_above: a cluster heavier than this is a split candidate (1.0, §3);
    min_split_mass: guarded rule, both halves must reach it (default ``T``).  max_iter: Lloyd
    iterations per run; max_splits: split attempts at most.  Deterministic (no randomness).
    """
    if split_rule not in ("guarded", "literal"):
        raise ValueError(f"kmeans_peaks: split_rule must be 'guarded' or 'literal', got {split_rule!r}")
    params = params if params is not None else PHDParams()
    min_split_mass = T if min_split_mass is None else min_split_mass
    Z = as_observations(Z)
    states = ps.states
    if states.shape[1] != STATE_DIM:
        raise ValueError(f"kmeans_peaks: expected (N, 6) particle states, got {states.shape}")
    n = len(ps)

    # §3: centres on the observations with zero velocity.
    init = np.zeros((len(Z), STATE_DIM))
    init[:, OBS_COLS] = Z
    origin = np.arange(len(Z), dtype=np.int64)
    if extra_centers is not None and len(extra_centers):
        extra = np.asarray(extra_centers, dtype=np.float64).reshape(-1, STATE_DIM)
        init = np.concatenate([init, extra])
        origin = np.concatenate([origin, np.full(len(extra), ORIGIN_EXTRA, dtype=np.int64)])
    if n == 0:
        K = len(init)
        return Clusters(init, np.zeros(K), np.zeros(0, dtype=np.int64), np.zeros(K, dtype=bool),
                        origin)

    # Weights relative to the largest keep the means exact even when masses underflow.
    lw = ps.log_weights
    lmax = float(np.max(lw))
    if not np.isfinite(lmax):
        K = len(init)
        return Clusters(init, np.zeros(K), np.zeros(n, dtype=np.int64), np.zeros(K, dtype=bool),
                        origin)
    w_rel = np.exp(lw - lmax)
    scale = np.exp(lmax)
    if len(init) == 0:
        init = (w_rel @ states / w_rel.sum())[None, :]
        origin = np.array([ORIGIN_EXTRA], dtype=np.int64)

    # Centre the positions (not the sizes: they set the metric) so the expanded distance
    # loses no precision on large images.
    shift = np.zeros(len(OBS_COLS))
    shift[:2] = states[:, :2].mean(axis=0)
    S = states.copy()
    S[:, OBS_COLS] -= shift
    X = np.ascontiguousarray(S[:, OBS_COLS])

    def run(c):
        c = c.copy()
        c[:, OBS_COLS] -= shift
        c, lab, m, d2, it = _lloyd(X, S, w_rel, c, params, max_iter)
        c[:, OBS_COLS] += shift
        return c, lab, m * scale, d2, it

    centers, labels, masses, d2, n_iter = run(init)
    final = np.zeros(len(centers), dtype=bool)
    n_splits = 0
    for _ in range(max_splits):
        cand = (masses > split_above) & ~final
        if not cand.any():
            break
        j = int(np.argmax(np.where(cand, masses, -np.inf)))
        members = np.flatnonzero(labels == j)
        far = members[np.argmax(d2[members, j])]
        if d2[far, j] <= 0.0:          # every sample on the centre: nothing to split
            final[j] = True
            continue
        new_c = states[far].copy()
        t_centers, t_labels, t_masses, t_d2, it = run(np.concatenate([centers, new_c[None]]))
        n_iter += it
        if split_rule == "literal" or (t_masses[j] >= min_split_mass
                                       and t_masses[-1] >= min_split_mass):
            centers, labels, masses, d2 = t_centers, t_labels, t_masses, t_d2
            final = np.append(final, False)
            origin = np.append(origin, ORIGIN_SPLIT)
            n_splits += 1
        else:
            final[j] = True            # guarded rule: revert, this cluster is one target
    kept = masses >= T
    return Clusters(centers, masses, labels.astype(np.int64), kept, origin, n_splits, n_iter)

