"""Resampling schemes for particle filters: systematic, stratified, residual, multinomial.

maggio2007 §2 resamples the PHD particles after each update ("L_k particles are resampled
from {ω̃_k/M̂_{k|k}, x̃_k}") without naming a scheme; these are the four standard unbiased
schemes (Douc, Cappé & Moulines 2005; Arulampalam et al. 2002 = maggio2007 ref. [1]).
Every scheme draws ``n`` ancestor indices such that ``E[count_i] = n * w_i`` for normalised
weights ``w``.  All randomness comes from an explicit ``numpy.random.Generator``.

:func:`resample` applies a scheme to a :class:`ParticleSet` and *preserves its mass*: the
``n`` offspring share the total weight equally (maggio2007 §2: "the weights ... are
normalized to preserve the total mass").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .weights import ParticleSet, logsumexp, normalised_weights

SCHEMES = ("systematic", "stratified", "residual", "multinomial")


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _systematic_index(lw, log_mass, u0, n):
    """Ancestors (n,) of systematic resampling: ``u_k = (u0 + k) / n`` against the CDF of
    ``exp(lw − log_mass)`` (its last bin forced to 1, summed in order as ``np.cumsum``), the
    first bin whose CDF exceeds ``u_k`` (``searchsorted(side="right")``: zero-weight bins are
    never picked). The walk of :func:`_systematic_take` with no columns to copy."""
    return _systematic_take(np.empty((lw.shape[0], 0), np.float64), lw, log_mass, u0, n,
                            np.empty(0, np.float64), 0.0, True)[0]


_NO_WEIGHTS = np.empty(0, np.float64)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _systematic_take(states, lw, log_mass, u0, n, w, scale, want_idx):
    """:func:`_systematic_index` and the ancestors' rows of ``states`` (N, D) in the same walk:
    returns ``(idx (n,), states[idx] (n, D), runs (M,), pos (2,))`` with no exp or gather pass
    of its own (``idx`` empty unless ``want_idx``: a set without labels or extra needs only the
    rows); ``runs`` the lengths of the runs of consecutive copies of one ancestor (the walk lays
    an ancestor's copies side by side: ``np.repeat(np.unique(idx), runs)`` is ``idx``); ``pos``
    the sums of the copied rows' first two columns, added row by row in order (zeros when
    ``D < 2``): K-means' centring shift (:func:`~..phd._kmeans_kernels.prepare_copies`), taken
    here where the walk's other work hides the chain of additions.  With
    ``w`` (N,) given (else empty), the normalised weights are ``w · scale`` instead of
    ``exp(lw − log_mass)`` (:meth:`~.weights.ParticleSet.known_normalised`): no exp at all,
    and ``lw`` is not read (may be empty)."""
    N = states.shape[0]
    D = states.shape[1]
    idx = np.empty(n if want_idx else 0, np.int64)
    out = np.empty((n, D), np.float64)
    runs = np.empty(n, np.int64)
    lin = w.shape[0] == N
    j = 0
    c = (w[0] * scale if lin else math.exp(lw[0] - log_mass)) if N > 1 else 1.0
    m = -1
    jp = -1
    cnt = 0
    a0 = 0.0
    a1 = 0.0
    two = D >= 2
    for k in range(n):
        u = (u0 + k) / n
        while j < N - 1 and c <= u:
            j += 1
            c = c + (w[j] * scale if lin else math.exp(lw[j] - log_mass)) if j < N - 1 else 1.0
        if want_idx:
            idx[k] = j
        new = np.int64(j != jp)            # (arithmetic, no branch: copies come 1 or 2 at
        m += new                           # random, a branch would be mispredicted often)
        cnt = cnt * (1 - new) + 1
        runs[m] = cnt
        jp = j
        for d in range(D):
            out[k, d] = states[j, d]
        if two:
            a0 += states[j, 0]
            a1 += states[j, 1]
    pos = np.empty(2, np.float64)
    pos[0] = a0
    pos[1] = a1
    return idx, out, runs[:m + 1], pos


def _cdf(w: np.ndarray) -> np.ndarray:
    c = np.cumsum(w)
    c[-1] = 1.0  # guard against round-off leaving the last bin short of 1
    return c


def _invert(cdf: np.ndarray, u: np.ndarray) -> np.ndarray:
    # side="right": u exactly on a boundary belongs to the next bin, so zero-weight bins
    # (flat cdf) are never selected.
    idx = np.searchsorted(cdf, u, side="right")
    return np.minimum(idx, len(cdf) - 1).astype(np.int64)


def systematic(log_weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """One uniform offset, ``n`` evenly spaced points: ``u_j = (U + j) / n``.  Lowest variance
    in practice; counts differ from ``n w_i`` by less than 1.  One walk over the CDF (numba,
    :func:`_systematic_index`), no (N,) or (n,) temporaries."""
    lw = np.asarray(log_weights, dtype=np.float64).reshape(-1)
    lse = logsumexp(lw)
    if not np.isfinite(lse):
        raise ValueError("cannot normalise weights with zero (or non-finite) total mass")
    return _systematic_index(lw, float(lse), float(rng.random()), int(n))


def stratified(log_weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """One uniform per stratum: ``u_j = (U_j + j) / n``."""
    w = normalised_weights(log_weights)
    u = (rng.random(n) + np.arange(n)) / n
    return _invert(_cdf(w), u)


def multinomial(log_weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` i.i.d. draws from the categorical distribution ``w`` (sorted, so the output order
    matches the other schemes: ancestors in increasing index order)."""
    w = normalised_weights(log_weights)
    u = np.sort(rng.random(n))
    return _invert(_cdf(w), u)


def residual(log_weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``floor(n w_i)`` deterministic copies, the remaining ``n - sum floor`` drawn
    multinomially from the residual weights ``n w_i - floor(n w_i)``."""
    w = normalised_weights(log_weights)
    nw = n * w
    copies = np.floor(nw).astype(np.int64)
    rest = n - int(copies.sum())
    idx = np.repeat(np.arange(len(w), dtype=np.int64), copies)
    if rest > 0:
        r = nw - copies
        r_sum = r.sum()
        r = r / r_sum if r_sum > 0 else np.full(len(w), 1.0 / len(w))
        extra = _invert(_cdf(r), np.sort(rng.random(rest)))
        idx = np.sort(np.concatenate([idx, extra]))
    return idx


_FUNCS = {"systematic": systematic, "stratified": stratified,
          "residual": residual, "multinomial": multinomial}


def resample_indices(log_weights: np.ndarray, n: int, rng: np.random.Generator,
                     scheme: str = "systematic") -> np.ndarray:
    """Ancestor indices ``(n,) int64`` drawn with ``scheme`` (one of :data:`SCHEMES`)."""
    try:
        fn = _FUNCS[scheme]
    except KeyError:
        raise ValueError(f"unknown resampling scheme {scheme!r}; choose one of "
                         f"{', '.join(SCHEMES)}") from None
    n = int(n)
    if n < 0:
        raise ValueError(f"resample: n must be >= 0, got {n}")
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    return fn(log_weights, n, rng)


def resample(ps: ParticleSet, n: int, rng: np.random.Generator,
             scheme: str = "systematic") -> ParticleSet:
    """Draw ``n`` particles from ``ps`` and give each weight ``ps.mass / n`` (mass preserved).

    An empty or zero-mass input, or ``n == 0``, gives an empty set.  ``"systematic"`` records
    the lengths of the runs of copies of one ancestor in the new set
    (:meth:`ParticleSet.known_copies`)."""
    n = int(n)
    if len(ps) == 0 or n == 0 or not math.isfinite(ps.log_mass):
        return ps.take(np.zeros(0, dtype=np.int64))
    lw = np.empty(n)                 # np.full's values (np.full is empty + copyto in Python)
    lw.fill(ps.log_mass - np.log(n))
    if scheme == "systematic":      # the log-mass is known: one walk that also copies the rows
        known = ps.normalised        # the walk reads these or the log-weights, not both
        w, scale = known or (_NO_WEIGHTS, 0.0)
        idx, states, runs, pos = _systematic_take(ps.states, _NO_WEIGHTS if known else ps.log_weights,
                                             ps.log_mass, float(rng.random()), n, w, scale,
                                             ps.labels is not None or ps.extra is not None)
        out = ParticleSet(states, lw, None if ps.labels is None else ps.labels[idx],
                          None if ps.extra is None else ps.extra[idx])
        out.known_equal()                                   # (np.full)
        out.known_copies(runs, pos)
        return out
    idx = resample_indices(ps.log_weights, n, rng, scheme)
    return ps.take(idx).with_log_weights(lw)
