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
  anyway).  A guarded split whose neighbourhood holds less than ``2 min_split_mass`` is not
  tried (both halves could not reach it).
- **Convergence** (``tol``, ``max_iter``): Lloyd stops when the labels are stable, when no centre's
  observed part moved more than ``tol`` pixels (centres are then the means of the returned
  labels), or after ``max_iter`` iterations (labels are then the nearest centres).
- **No observations**: with no detection and no ``extra_centers`` the iteration starts from a
  single centre at the weighted mean of the particles (the split rule then separates peaks).
  ``extra_centers`` lets a caller add centres (e.g. the previous frame's peaks).

Cost (DESIGN.md, linear in the number of targets): with fewer than :data:`INDEX_MIN_CENTERS`
centres the assignment step computes the dense (N particles × K centres) distances, as plain
K-means does; with more, each particle looks only at its nearest centres (a KD-tree on the
centres, :class:`_Assigner`), and the result is still *exact* — the same labels, ties to the
lowest index included (its distances are the direct ``Σ (x − c)² / σ²``, equal to the dense
expansion up to round-off): every centre's inverse variances are at least m (their minimum), so a
centre at Euclidean distance e in the space scaled by sqrt(m) has d² >= e², and once the best
of a particle's k nearest centres beats e_k² no other centre can win (the few particles it does
not settle look at more centres, then at all).  Across Lloyd iterations a particle keeps its
candidates and that bound, so an iteration where most centres stay put costs about one pass over
the particles.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..smc.weights import ParticleSet
from ..types import cxcywh_to_xywh
from .filter import OBS_COLS, STATE_DIM, PHDParams, as_observations, obs_std

#: ``Clusters.origin`` codes for centres not initialised on an observation.
ORIGIN_SPLIT = -1
ORIGIN_EXTRA = -2

#: From this many centres on, the assignment step uses a KD-tree on the centres instead of the
#: dense (N × K) distance matrix (below, the dense products are as fast and bit-identical to
#: the plain K-means).
INDEX_MIN_CENTERS = 32
#: Nearest centres (in the scaled (y1, y2, w, h) space) a particle looks at first, then on a
#: second try.
_NEIGHBOURS = (4, 32)
#: Particles per block of the indexed assignment (bounds its memory).
_BLOCK = 1 << 16
#: A split's trial Lloyd iterations run on the split cluster and at most this many of its
#: nearest neighbouring clusters (itself included).
SPLIT_NEIGHBOURS = 4


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
    each under the observation noise at its own size: ``Σ_d (x_d − c_d)² / σ_d²``, summed in
    the order of :func:`_pair_distances` (so both give the very same floats), in place."""
    C = centers[:, OBS_COLS]
    inv = 1.0 / obs_std(centers[:, 4:6], params.likelihood) ** 2            # (K, 4)
    acc = np.empty((len(X), len(C)))
    q = np.empty_like(acc)
    for d in range(4):
        out = acc if d == 0 else q
        np.subtract(X[:, d, None], C[None, :, d], out=out)
        out *= out
        out *= inv[None, :, d]
        if d:
            acc += q
    return acc


def _pair_distances(X: np.ndarray, CT: np.ndarray, invT: np.ndarray,
                    idx: np.ndarray) -> np.ndarray:
    """(n, k) squared Mahalanobis distances of ``X`` (n, 4) to the centres ``idx`` (n, k);
    ``CT``/``invT`` (4, K) the centres' observed part and inverse variances, transposed (one
    small gather per coordinate is much faster than gathering (n, k, 4) blocks)."""
    acc = None
    for d in range(CT.shape[0]):
        q = np.subtract(X[:, d, None], np.take(CT[d], idx))
        q *= q
        q *= np.take(invT[d], idx)
        acc = q if acc is None else np.add(acc, q, out=acc)
    return acc


def _nearest_of(d2: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row-wise minimum of ``d2`` (n, k) over the centres ``idx`` (n, k): (label, d²), the
    lowest centre index among equal minima (as ``np.argmin`` over all centres)."""
    rows = np.arange(len(d2))
    a = np.argmin(d2, axis=1)
    best = d2[rows, a]
    lab = idx[rows, a]
    tie = np.count_nonzero(d2 == best[:, None], axis=1) > 1    # e.g. duplicate detections
    if tie.any():
        t = np.flatnonzero(tie)
        lab[t] = np.where(d2[t] == best[t, None], idx[t], np.iinfo(idx.dtype).max).min(axis=1)
    return lab, best


@dataclass
class _Tier:
    """Particles settled by their k nearest centres (in the tree space) at their last query:
    ``members`` (n,) particle indices, ``cand`` (n, k) those centres, ``lab``/``best`` (n,)
    the nearest of them and its d², ``bound`` (n,) a lower bound on the tree-space distance
    to every other centre."""

    members: np.ndarray
    cand: np.ndarray
    lab: np.ndarray
    best: np.ndarray
    bound: np.ndarray

    @classmethod
    def empty(cls, k: int) -> "_Tier":
        return cls(np.zeros(0, dtype=np.intp), np.zeros((0, k), dtype=np.intp),
                   np.zeros(0, dtype=np.intp), np.zeros(0), np.zeros(0))

    def take(self, keep: np.ndarray) -> "_Tier":
        return _Tier(self.members[keep], self.cand[keep], self.lab[keep], self.best[keep],
                     self.bound[keep])

    def extend(self, parts: list["_Tier"]) -> "_Tier":
        return _Tier(*(np.concatenate([getattr(self, f)] + [getattr(p, f) for p in parts])
                       for f in ("members", "cand", "lab", "best", "bound")))


class _Assigner:
    """Nearest centre of every particle (lowest index on ties, as ``np.argmin``) and its d²,
    across the Lloyd iterations of one :func:`kmeans_peaks` call.

    Below :data:`INDEX_MIN_CENTERS` centres: the dense (N × K) matrix.  Above, exact, looking
    only at nearby centres.  Each centre's metric is diagonal with inverse variances
    ``inv_c >= m`` (m (4,) a little below their minimum over the centres), so in the space
    scaled by ``sqrt(m)`` every centre at Euclidean distance e from a particle has
    ``d²_c >= e²``.  A KD-tree on the scaled centres gives a particle its k nearest centres
    (k = 4, then 32 when that does not settle it, then all): the best of them is the answer
    once ``best < e_k²``.  The particle remembers them (a :class:`_Tier` per k) and between
    calls its bound drops by the largest (scaled) move of any centre and is capped by the
    distance to centres added since (a split), while ``best`` is recomputed only when one of
    its candidates changed — so the late Lloyd iterations, where most centres no longer move,
    cost about one pass over the particles."""

    def __init__(self, X: np.ndarray, params: PHDParams):
        self.X = X
        self.params = params
        self.C: Optional[np.ndarray] = None      # (K, 4) centres at the last call
        self.m = np.zeros(4)                     # metric lower bound of the tree space
        self.Xs = np.zeros((0, 4))               # particles in the tree space
        self.tiers: list[_Tier] = []

    def __call__(self, centers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        X, K, n = self.X, len(centers), len(self.X)
        if K < INDEX_MIN_CENTERS:
            self.C = None
            return _dense_assign(X, centers, self.params)
        from scipy.spatial import cKDTree  # scipy on first use (keeps `pfscope --help` fast)

        C = np.ascontiguousarray(centers[:, OBS_COLS])
        inv = 1.0 / obs_std(centers[:, 4:6], self.params.likelihood) ** 2     # (K, 4)
        CT, invT = np.ascontiguousarray(C.T), np.ascontiguousarray(inv.T)
        labels = np.empty(n, dtype=np.int64)
        dmin = np.empty(n)
        ks = [min(k, K) for k in _NEIGHBOURS]
        prev = self.C
        if prev is None or len(prev) > K or np.any(inv < self.m) \
                or [t.cand.shape[1] for t in self.tiers] != ks:
            # (Re)build the tree space a little below the smallest inverse variances, so
            # centres may grow somewhat before it has to be rebuilt.
            self.m = 0.9 * inv.min(axis=0)
            self.Xs = X * np.sqrt(self.m)
            self.tiers = [_Tier.empty(k) for k in ks]
            todo = np.arange(n)
        else:
            root_m = np.sqrt(self.m)
            kp = len(prev)
            changed = np.ones(K, dtype=bool)
            changed[:kp] = np.any(C[:kp] != prev, axis=1)
            moved = float(np.sqrt(np.max(np.sum(((C[:kp] - prev) * root_m) ** 2, axis=1))))
            left = []
            for i, t in enumerate(self.tiers):
                if len(t.members) == 0:
                    continue
                t.bound -= moved
                if K > kp:                           # centres added since (splits)
                    xs = self.Xs[t.members]
                    for c in range(kp, K):
                        q = xs - C[c] * root_m
                        np.minimum(t.bound, np.sqrt(np.einsum("ij,ij->i", q, q)), out=t.bound)
                stale = np.flatnonzero(changed[t.cand].any(axis=1))
                if len(stale):
                    cand = t.cand[stale]
                    t.lab[stale], t.best[stale] = _nearest_of(
                        _pair_distances(X[t.members[stale]], CT, invT, cand), cand)
                if t.cand.shape[1] < K:
                    bd = np.maximum(t.bound, 0.0)
                    sure = t.best < (bd * bd) * (1.0 - 1e-9)
                else:
                    sure = np.ones(len(t.members), dtype=bool)
                if sure.all():
                    labels[t.members] = t.lab
                    dmin[t.members] = t.best
                    continue
                labels[t.members[sure]] = t.lab[sure]
                dmin[t.members[sure]] = t.best[sure]
                left.append(t.members[~sure])
                self.tiers[i] = t.take(sure)
            todo = np.concatenate(left) if left else np.zeros(0, dtype=np.intp)
        self.C = C
        if len(todo):
            self._query(cKDTree(C * np.sqrt(self.m)), CT, invT, todo, labels, dmin)
        return labels, dmin

    def _query(self, tree, CT, invT, todo, labels, dmin) -> None:
        X, K = self.X, CT.shape[1]
        for i, t in enumerate(self.tiers):
            k = t.cand.shape[1]
            left, settled = [], []
            for b in range(0, len(todo), _BLOCK):
                part = todo[b:b + _BLOCK]
                e, idx = tree.query(self.Xs[part], k=k)
                e, idx = e.reshape(len(part), k), idx.reshape(len(part), k)
                lab, best = _nearest_of(_pair_distances(X[part], CT, invT, idx), idx)
                sure = (best < (e[:, -1] ** 2) * (1.0 - 1e-9) if k < K
                        else np.ones(len(part), dtype=bool))
                last = i == len(self.tiers) - 1
                # remember the candidates (the last tier keeps even the unsettled ones)
                keep = np.ones(len(part), dtype=bool) if last else sure
                settled.append(_Tier(part[keep], idx[keep], lab[keep], best[keep],
                                     e[keep, -1]))
                labels[part[sure]] = lab[sure]
                dmin[part[sure]] = best[sure]
                left.append(part[~sure])
            if any(len(p.members) for p in settled):
                self.tiers[i] = t.extend(settled)
            todo = np.concatenate(left)
            if len(todo) == 0:
                return
        # Not settled by the nearest centres: all of them, a block at a time.
        step = max(1, _BLOCK * 4 // K)
        every = np.arange(K)
        for b in range(0, len(todo), step):
            part = todo[b:b + step]
            d2 = _pair_distances(X[part], CT, invT, np.broadcast_to(every, (len(part), K)))
            lab = np.argmin(d2, axis=1)
            labels[part] = lab
            dmin[part] = d2[np.arange(len(part)), lab]


def _dense_assign(X: np.ndarray, centers: np.ndarray,
                  params: PHDParams) -> tuple[np.ndarray, np.ndarray]:
    """Nearest centre of every particle (first on ties) and its d², from the dense matrix."""
    d2 = _distances(X, centers, params)
    labels = np.argmin(d2, axis=1)
    return labels, d2[np.arange(len(X)), labels]


def _lloyd(X, states, w_rel, centers, assign, max_iter, tol=0.0):
    """Weighted Lloyd iterations from ``centers`` until the assignment (``assign``, an
    :class:`_Assigner` or any ``centers -> (labels, d²)``) is stable, no centre's observed part
    moves more than ``tol`` pixels, or ``max_iter`` iterations.  Returns centers, labels,
    relative masses, each particle's d² to its centre (at its last assignment), iterations.
    Centres are the weighted means of the returned labels (an empty cluster keeps its
    centre), except after ``max_iter`` iterations, where the labels are the nearest centres."""
    centers = centers.copy()
    K = len(centers)
    labels = None
    m = np.zeros(K)
    sums = np.zeros((K, STATE_DIM))
    it = 0
    for it in range(1, max_iter + 1):
        new, dmin = assign(centers)
        if labels is None:
            sel = np.arange(len(new))
            touched = np.ones(K, dtype=bool)
        elif np.array_equal(new, labels):
            break
        else:
            # Only clusters that lost or gained a particle change their sums; summing just
            # their members (in particle order) gives the very same floats as summing all.
            moved = new != labels
            touched = np.zeros(K, dtype=bool)
            touched[new[moved]] = True
            touched[labels[moved]] = True
            sel = np.flatnonzero(touched[new])
        labels = new
        lab, w = labels[sel], w_rel[sel]
        m[touched] = np.bincount(lab, weights=w, minlength=K)[touched]
        # the six weighted sums in one bincount over (cluster, coordinate) bins, each summed
        # in particle order (the same floats as one bincount per coordinate)
        bins = (lab * STATE_DIM)[:, None] + np.arange(STATE_DIM)
        ws = states[sel] if len(sel) < len(labels) else states
        sums[touched] = np.bincount(bins.ravel(), weights=(ws * w[:, None]).ravel(),
                                    minlength=K * STATE_DIM).reshape(K, STATE_DIM)[touched]
        nz = m > 0
        # Weighted mean of every non-empty cluster; an empty cluster keeps its centre.
        upd = nz & touched
        if tol > 0:
            step = np.max(np.abs(sums[upd][:, OBS_COLS] / m[upd, None]
                                 - centers[upd][:, OBS_COLS]), initial=0.0)
        centers[upd] = sums[upd] / m[upd, None]
        if tol > 0 and step <= tol:
            break                      # converged: centres are the means of `labels`
    else:
        labels, dmin = assign(centers)
    m = np.bincount(labels, weights=w_rel, minlength=K)
    return centers, labels, m, dmin, it


def kmeans_peaks(ps: ParticleSet, Z, T: float = 0.6, *, params: PHDParams | None = None,
                 split_rule: str = "guarded", split_above: float = 1.0,
                 min_split_mass: float | None = None, max_iter: int = 50, max_splits: int = 64,
                 extra_centers: np.ndarray | None = None, tol: float = 0.01) -> Clusters:
    """Modified K-means of maggio2007 §3 on the particle PHD ``ps``; ``Z`` (N_z, 4) the frame's
    observations (or a :class:`~trackers.types.Detections`) initialise the centres.

    T: discard threshold (0.6, §4).  params: supplies the observation-noise metric (default
    :class:`PHDParams`).  split_rule: ``"guarded"`` (default) or ``"literal"`` — see the
    module docstring; split_above: a cluster heavier than this is a split candidate (1.0, §3);
    min_split_mass: guarded rule, both halves must reach it (default ``T``).  max_iter: Lloyd
    iterations per run (the first run and each split trial); max_splits: split attempts at
    most; tol: convergence tolerance, pixels (largest move of a centre's (y1, y2, w, h)).
    So ``n_iter <= max_iter (1 + max_splits)``.  Deterministic (no randomness).
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
    # loses no precision on large images.  Centres stay in these coordinates until the end.
    shift = np.zeros(STATE_DIM)
    shift[:2] = states[:, :2].mean(axis=0)
    S = states - shift
    X = np.ascontiguousarray(S[:, OBS_COLS])
    assign = _Assigner(X, params)

    def run(c):
        c, lab, m, dmin, it = _lloyd(X, S, w_rel, c, assign, max_iter, tol)
        return c, lab, m * scale, dmin, it

    centers, labels, masses, dmin, n_iter = run(init - shift)
    final = np.zeros(len(centers), dtype=bool)
    n_splits = 0
    for _ in range(max_splits):
        cand = (masses > split_above) & ~final
        if not cand.any():
            break
        j = int(np.argmax(np.where(cand, masses, -np.inf)))
        members = np.flatnonzero(labels == j)
        far = members[np.argmax(dmin[members])]      # members of j: dmin is d² to centre j
        if dmin[far] <= 0.0:           # every sample on the centre: nothing to split
            final[j] = True
            continue
        # The trial runs on cluster j and its neighbours only: the clusters whose centres lie
        # within twice j's reach (the d² of its farthest member, under j's metric).
        inv_j = 1.0 / obs_std(centers[j, 4:6], params.likelihood) ** 2
        dc = np.sum((centers[:, OBS_COLS] - centers[j, OBS_COLS]) ** 2 * inv_j, axis=1)
        near = np.flatnonzero(dc <= 4.0 * dmin[far])
        near = np.sort(near[np.argsort(dc[near], kind="stable")][:SPLIT_NEIGHBOURS])
        if split_rule == "guarded" and masses[near].sum() < 2.0 * min_split_mass:
            final[j] = True            # the trial cannot give two halves >= min_split_mass
            continue
        is_local = np.zeros(len(centers), dtype=bool)
        is_local[near] = True
        sel = np.flatnonzero(is_local[labels])
        Xl = X[sel]
        t_c, t_lab, t_m, t_d, it = _lloyd(Xl, S[sel], w_rel[sel],
                                          np.concatenate([centers[near], S[far][None]]),
                                          lambda c, Xl=Xl: _dense_assign(Xl, c, params),
                                          max_iter, tol)
        n_iter += it
        t_m = t_m * scale
        pos = int(np.searchsorted(near, j))
        if split_rule == "guarded" and not (t_m[pos] >= min_split_mass
                                            and t_m[-1] >= min_split_mass):
            final[j] = True            # guarded rule: revert, this cluster is one target
            continue
        k = len(centers)
        centers = np.concatenate([centers, t_c[-1:]])
        centers[near] = t_c[:-1]
        masses = np.append(masses, t_m[-1])
        masses[near] = t_m[:-1]
        labels[sel] = np.append(near, k)[t_lab]
        dmin[sel] = t_d
        final = np.append(final, False)
        origin = np.append(origin, ORIGIN_SPLIT)
        n_splits += 1
    kept = masses >= T
    return Clusters(centers + shift, masses, labels.astype(np.int64), kept, origin, n_splits,
                    n_iter)

