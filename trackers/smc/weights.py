"""Log-weight utilities and the weighted particle set shared by every particle filter.

Weights are kept as natural-log weights so that products of many small likelihoods never
underflow (maggio2007 §2, eq. (5) multiplies Gaussian likelihoods of 4-D observations; the
PHD weights of a large cloud are ~1/ρ each).  A :class:`ParticleSet` is *unnormalised*: its
total weight ``mass`` is meaningful (for the PHD filter it is the expected number of
targets, maggio2007 §2 "M̂_{k|k} is the total mass"); single-target filters simply keep
mass 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable, Optional

import numpy as np


def logsumexp(log_w: np.ndarray, axis=None) -> np.ndarray | float:
    """``log(sum(exp(log_w)))`` without overflow/underflow; ``-inf`` for an empty or all ``-inf``
    input (an empty sum is 0)."""
    a = np.asarray(log_w, dtype=np.float64)
    if a.size == 0:
        if axis is None:
            return -np.inf
        return np.full(np.delete(a.shape, axis), -np.inf)
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)  # all -inf slices: exp(-inf - 0) = 0 -> log 0 = -inf
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(a - m), axis=axis, keepdims=True)) + m
    if axis is None:
        return float(out.reshape(()))
    return np.squeeze(out, axis=axis)


def normalise(log_w: np.ndarray) -> tuple[np.ndarray, float]:
    """Return ``(log_w - logsumexp(log_w), logsumexp(log_w))``: normalised log-weights (summing
    to 1 in linear space) and the log of the total mass that was divided out.

    An empty or zero-mass input raises ``ValueError`` (there is nothing to normalise)."""
    lse = logsumexp(log_w)
    if not np.isfinite(lse):
        raise ValueError("cannot normalise weights with zero (or non-finite) total mass")
    return np.asarray(log_w, dtype=np.float64) - lse, lse


def normalised_weights(log_w: np.ndarray) -> np.ndarray:
    """Linear weights summing to 1 (float64, (N,))."""
    lw, _ = normalise(log_w)
    return np.exp(lw)


def ess(log_w: np.ndarray) -> float:
    """Effective sample size ``1 / sum(w_i^2)`` of the normalised weights, in ``[1, N]``
    (Arulampalam et al. 2002, cited as [1] in maggio2007).  0 for an empty set."""
    if np.size(log_w) == 0:
        return 0.0
    lw, _ = normalise(log_w)
    # 1/sum(w^2) = exp(-logsumexp(2 lw)), computed in log space for tiny weights.
    return float(np.exp(-logsumexp(2.0 * lw)))


@dataclass(frozen=True, init=False)
class ParticleSet:
    """Weighted particles, structure-of-arrays, of any state dimension D.

    states: (N, D) float64 — for PHD-MT ``D = 6``, ``x = (y1, y2, v1, v2, w, h)`` (maggio2007
    §2); for a DLPF parent ``D = 4``, ``(x, y, vx, vy)`` (jung2013 §2).
    log_weights: (N,) float64 natural-log weights, unnormalised (their sum is the mass).
    labels: optional (N,) int64 — which object a particle belongs to (a DLPF child cloud's
    track id, the detection a newborn came from ...).
    extra: optional (N, E) float64 — per-particle values that are not state (a parent's
    classifier scale, a score ...).

    Every operation (``take``, ``concat``, resampling) carries ``labels`` and ``extra`` along.
    """

    states: np.ndarray
    log_weights: np.ndarray
    labels: Optional[np.ndarray] = None
    extra: Optional[np.ndarray] = None

    def __init__(self, states: np.ndarray, log_weights: np.ndarray,
                 labels: Optional[np.ndarray] = None, extra: Optional[np.ndarray] = None):
        # the dataclass's frozen __init__ (object.__setattr__ a field) written into the
        # instance dict directly: a filter makes several sets a frame, and the generated
        # one cost ~5x a plain class's
        d = self.__dict__
        d["states"], d["log_weights"], d["labels"], d["extra"] = (states, log_weights, labels,
                                                                  extra)
        self.__post_init__()

    def __post_init__(self):
        s, lw = self.states, self.log_weights
        if not (type(s) is np.ndarray and s.dtype == np.float64 and s.ndim == 2
                and type(lw) is np.ndarray and lw.dtype == np.float64 and lw.ndim == 1):
            # (the filters hand float64 arrays of the right rank: nothing to convert)
            s = np.asarray(s, dtype=np.float64)
            lw = np.asarray(lw, dtype=np.float64).reshape(-1)
            if s.ndim != 2:
                raise ValueError(f"ParticleSet.states: expected shape (N, D), got {s.shape}")
            object.__setattr__(self, "states", s)
            object.__setattr__(self, "log_weights", lw)
        if len(lw) != len(s):
            raise ValueError(f"ParticleSet: {len(s)} states but {len(lw)} log-weights")
        if self.labels is not None:
            lab = np.asarray(self.labels, dtype=np.int64).reshape(-1)
            if len(lab) != len(s):
                raise ValueError(f"ParticleSet: {len(s)} states but {len(lab)} labels")
            object.__setattr__(self, "labels", lab)
        if self.extra is not None:
            ex = np.asarray(self.extra, dtype=np.float64)
            if ex.ndim != 2 or len(ex) != len(s):
                raise ValueError(f"ParticleSet.extra: expected shape ({len(s)}, E), got {ex.shape}")
            object.__setattr__(self, "extra", ex)

    @classmethod
    def unchecked(cls, states: np.ndarray, log_weights: np.ndarray) -> "ParticleSet":
        """A set of arrays its maker knows valid -- float64 ``states`` (N, D) and
        ``log_weights`` (N,), no labels or extra (a filter's own buffers) -- made without
        :meth:`__post_init__`'s checks (the same set)."""
        ps = object.__new__(cls)
        d = ps.__dict__
        d["states"], d["log_weights"], d["labels"], d["extra"] = (states, log_weights, None,
                                                                  None)
        return ps

    @classmethod
    def empty(cls, dim: int, *, labels: bool = False, n_extra: int = 0) -> "ParticleSet":
        """No particles, of state dimension ``dim`` (with empty labels / ``n_extra`` columns)."""
        return cls(np.zeros((0, dim)), np.zeros(0),
                   np.zeros(0, dtype=np.int64) if labels else None,
                   np.zeros((0, n_extra)) if n_extra else None)

    def __len__(self) -> int:
        return self.states.shape[0]          # as many log-weights (checked when made)

    @property
    def dim(self) -> int:
        return int(self.states.shape[1])

    @cached_property
    def log_mass(self) -> float:
        """``logsumexp(log_weights)``, computed once (a set's arrays are never changed in
        place: every operation returns a new set).  Equal weights (every set systematic
        resampling made, and its prediction) take a shortcut with logsumexp's very floats:
        ``exp(a − max) = 1`` each, their sum ``n`` exactly, so the value is ``log n + a``."""
        lw = self.log_weights
        if self._equal and np.isfinite(lw[0]):
            return float((np.log(np.array([float(len(lw))])) + lw[:1])[0])
        return float(logsumexp(lw))

    @cached_property
    def _equal(self) -> bool:
        """Every log-weight the same (not NaN), and at least one."""
        lw = self.log_weights
        return bool(len(lw) and lw[0] == lw[-1] and lw.min() == lw.max())

    def known_equal(self) -> None:
        """Record that every log-weight is the same finite-or-inf value, when the maker
        knows it (systematic resampling's ``np.full``, and a prediction of such a set):
        :attr:`weights` and :attr:`log_mass` then skip their min / max pass."""
        self.__dict__["_equal"] = bool(len(self))

    def known_copies(self, runs: np.ndarray, pos_sums: Optional[np.ndarray] = None) -> None:
        """Record that this set's rows are runs of consecutive copies of one ancestor,
        ``runs`` (M,) their lengths, when the maker knows it (systematic resampling lays the
        copies side by side): K-means (:func:`~..phd.clustering.kmeans_peaks`) then takes each
        run's row once without comparing every row with the one before.  ``pos_sums`` (2,),
        if given: the sums of the states' first two columns, added row by row in order
        (:meth:`copy_sums`).  (A set's arrays are never changed in place; a set made from this
        one's arrays has no record.)"""
        self.__dict__["_copies"] = runs
        if pos_sums is not None:
            self.__dict__["_copy_sums"] = pos_sums

    def copies(self) -> Optional[np.ndarray]:
        """The run lengths :meth:`known_copies` recorded, else None."""
        return self.__dict__.get("_copies")

    def copy_sums(self) -> Optional[np.ndarray]:
        """The position sums :meth:`known_copies` recorded (K-means' centring shift without a
        pass of its own), else None."""
        return self.__dict__.get("_copy_sums")

    def known_extent(self, ext: np.ndarray) -> None:
        """Record ``ext`` = ``(x0, y0, x1, y1, finite)``, the extent of the states' first two
        columns (min then max; ``finite`` 0.0 when one of them is not), when the maker computed
        it in its own pass (the PHD prediction's kernel): the scene model's grid then skips a
        pass of its own (:meth:`extent`)."""
        self.__dict__["_extent"] = ext

    def extent(self) -> Optional[np.ndarray]:
        """The extent :meth:`known_extent` recorded, else None."""
        return self.__dict__.get("_extent")

    def is_known_equal(self) -> bool:
        """True when :meth:`known_equal` was recorded, or the equal-weights test already ran
        and found them equal (no pass over the weights here)."""
        return bool(self.__dict__.get("_equal"))

    def made(self, *names: str) -> bool:
        """True when any of the cached values ``names`` (``"weights"``, ``"log_mass"``,
        ``"mass"``) has been computed already: a caller that could make it more cheaply from
        the known-equal weights does so only while it has not (the cached floats win)."""
        d = self.__dict__
        for name in names:
            if ("_mass" if name == "mass" else name) in d:
                return True
        return False

    def known_log_mass(self, log_mass: float) -> None:
        """Record ``log_mass`` when the code that made the weights already summed them (the
        PHD update's kernel): :attr:`log_mass` then needs no pass of its own."""
        d = self.__dict__
        d["log_mass"] = float(log_mass)
        d.pop("_mass", None)

    def known_normalised(self, w: np.ndarray, scale: float) -> None:
        """Record ``w · scale`` (N,), the normalised weights ``exp(log_weights − log_mass)``
        as the code that made the weights summed them (the PHD update's kernel: linear
        weights and their total): systematic resampling then walks them with no exp a
        particle (:func:`.resampling.resample`).  Equal to the exps up to round-off."""
        self.__dict__["_normalised"] = (w, float(scale))   # (a frozen dataclass)

    @property
    def normalised(self) -> "tuple[np.ndarray, float] | None":
        """``(w, scale)`` recorded by :meth:`known_normalised`, else None."""
        return self.__dict__.get("_normalised")

    @property
    def mass(self) -> float:
        """Total weight ``exp(logsumexp(log_weights))`` (0 for an empty set), computed once
        (the PHD filter's resampling, its step result and the tracker read the updated
        set's)."""
        m = self.__dict__.get("_mass")
        if m is None:
            m = self.__dict__["_mass"] = float(np.exp(self.log_mass))
        return m

    @cached_property
    def weights(self) -> np.ndarray:
        """Linear (unnormalised) weights, (N,), computed once (read-only: callers share it;
        the PHD filter's M(z) and its clutter model both read the predicted set's).  Equal
        log-weights (a resampled set and its prediction) take one exp: numpy's exp gives an
        element the same float alone or in an array."""
        lw = self.log_weights
        if self._equal:
            w = np.full(len(lw), np.exp(lw[:1])[0])
            w.setflags(write=False)
            return w
        w = np.exp(lw)
        w.setflags(write=False)
        return w

    def ess(self) -> float:
        return ess(self.log_weights)

    def with_log_weights(self, log_weights: np.ndarray) -> "ParticleSet":
        """The same particles with new log-weights."""
        return ParticleSet(self.states, log_weights, self.labels, self.extra)

    def concat(self, other: "ParticleSet") -> "ParticleSet":
        """This set followed by ``other`` (same dimension; labels/extra on both or neither)."""
        if other.dim != self.dim:
            raise ValueError(f"ParticleSet.concat: dimension {self.dim} vs {other.dim}")

        def cat(a, b, what):
            if a is None and b is None:
                return None
            if a is None or b is None:
                # an empty side without the column adopts the other's
                if a is None and len(self) == 0:
                    return b
                if b is None and len(other) == 0:
                    return a
                raise ValueError(f"ParticleSet.concat: {what} on one side only")
            return np.concatenate([a, b])

        return ParticleSet(np.concatenate([self.states, other.states]),
                           np.concatenate([self.log_weights, other.log_weights]),
                           cat(self.labels, other.labels, "labels"),
                           cat(self.extra, other.extra, "extra"))

    def take(self, index: np.ndarray) -> "ParticleSet":
        """Subset / reordering by an index array or boolean mask (weights unchanged)."""
        return ParticleSet(self.states[index], self.log_weights[index],
                           None if self.labels is None else self.labels[index],
                           None if self.extra is None else self.extra[index])


class LazyParticleSet(ParticleSet):
    """A :class:`ParticleSet` whose log-weights are made by ``make()`` on their first read.

    The PHD update's kernel sums the new weights in linear space (their mass and normalised
    weights: :meth:`~ParticleSet.known_log_mass`, :meth:`~ParticleSet.known_normalised`), and
    in a run nothing else reads the updated set's log-weights (particle-level stage data
    does): a log a particle saved.  Otherwise a :class:`ParticleSet` (``make`` must give the
    (N,) float64 log-weights of ``states``' N rows, the same every call)."""

    def __init__(self, states: np.ndarray, make: Callable[[], np.ndarray],
                 labels: Optional[np.ndarray] = None, extra: Optional[np.ndarray] = None,
                 *, log_mass: Optional[float] = None,
                 normalised: Optional[tuple[np.ndarray, float]] = None):
        # ``log_mass`` / ``normalised``: :meth:`known_log_mass` / :meth:`known_normalised`
        # recorded as the set is made (the PHD update's kernel summed them)
        s = states
        if not (type(s) is np.ndarray and s.dtype == np.float64 and s.ndim == 2):
            s = np.asarray(states, dtype=np.float64)
            if s.ndim != 2:
                raise ValueError(f"ParticleSet.states: expected shape (N, D), got {s.shape}")
        if labels is not None or extra is not None:     # checked as a ParticleSet checks them
            checked = ParticleSet(s, np.zeros(len(s)), labels, extra)
            labels, extra = checked.labels, checked.extra
        d = self.__dict__
        d["states"], d["labels"], d["extra"], d["_make"] = s, labels, extra, make
        if log_mass is not None:
            d["log_mass"] = float(log_mass)
        if normalised is not None:
            d["_normalised"] = (normalised[0], float(normalised[1]))

    @classmethod
    def unchecked(cls, states: np.ndarray, make: Callable[[], np.ndarray],  # type: ignore[override]
                  log_mass: float, normalised: Optional[tuple[np.ndarray, float]] = None
                  ) -> "LazyParticleSet":
        """A lazy set of float64 ``states`` (N, D) its maker knows valid, no labels or extra
        (the PHD update's particles), its ``log_mass`` and ``normalised`` weights recorded
        (as the constructor's keywords), made without the constructor's checks."""
        ps = object.__new__(cls)
        d = ps.__dict__
        d["states"], d["labels"], d["extra"], d["_make"] = states, None, None, make
        d["log_mass"] = float(log_mass)
        if normalised is not None:
            d["_normalised"] = (normalised[0], float(normalised[1]))
        return ps

    @property
    def log_weights(self) -> np.ndarray:               # type: ignore[override]
        lw = self.__dict__.get("_log_weights")
        if lw is None:
            lw = np.asarray(self._make(), dtype=np.float64).reshape(-1)
            if len(lw) != len(self.states):
                raise ValueError(f"ParticleSet: {len(self.states)} states but {len(lw)} "
                                 f"log-weights")
            self.__dict__["_log_weights"] = lw
        return lw
