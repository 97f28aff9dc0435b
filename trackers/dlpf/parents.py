"""Parent particles, the first layer (jung2013 §2.1, eqs. (2)–(5), (8)).

A parent is a row of a :class:`~pfscope.trackers.smc.ParticleSet`:

- ``states`` (N, 4): ``s = (x, y, vx, vy)`` in pixels and pixels/frame (§2.1);
- ``labels`` (N,): 0 for a free parent (searching), else the id of the track it detected
  (§2.2: "the PP of a detected object generates CPs" — it is taken out of the search until the
  track ends, then "reset and resampled");
- ``extra`` (N, 2): the person height (pixels) of the window it classifies this frame, drawn at
  random (§2.1: "PPs randomly select the scale"), and the SVM margin its window scored.

Pure functions with an explicit ``numpy.random.Generator``; the tracker composes them.
"""

from __future__ import annotations

import numpy as np

from ..smc import ParticleSet, resample_indices

#: Eq. (4), Δk = 1: constant-velocity transition.
A = np.array([[1.0, 0.0, 1.0, 0.0],
              [0.0, 1.0, 0.0, 1.0],
              [0.0, 0.0, 1.0, 0.0],
              [0.0, 0.0, 0.0, 1.0]])


def uniform_states(n: int, width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` parents spread uniformly over the image, at rest (a reset parent, §2.2)."""
    s = np.zeros((n, 4))
    s[:, 0] = rng.uniform(0.0, width, n)
    s[:, 1] = rng.uniform(0.0, height, n)
    return s


def draw_heights(n: int, lo: float, hi: float, rng: np.random.Generator) -> np.ndarray:
    """Random person heights (pixels), log-uniform in [lo, hi] (scale-invariant: as many draws
    per octave), one per parent."""
    return np.exp(rng.uniform(np.log(lo), np.log(hi), n))


def init_parents(n: int, width: int, height: int, lo: float, hi: float,
                 rng: np.random.Generator) -> ParticleSet:
    """``n`` free parents, uniform over the image, equal weights."""
    return ParticleSet(uniform_states(n, width, height, rng), np.full(n, -np.log(max(n, 1))),
                       np.zeros(n, dtype=np.int64),
                       np.c_[draw_heights(n, lo, hi, rng), np.zeros(n)])


def predict(states: np.ndarray, q_pos: float, q_vel: float, rng: np.random.Generator,
            width: int, height: int) -> np.ndarray:
    """Eqs. (3)–(5): ``s⁻ = A s⁺ + w`` with ``w ~ N(0, diag(Q_pos, Q_pos, Q_vel, Q_vel))``
    (``q_pos``, ``q_vel`` are standard deviations), positions kept inside the image."""
    s = states @ A.T
    n = len(s)
    s[:, :2] += rng.normal(0.0, q_pos, (n, 2))
    s[:, 2:] += rng.normal(0.0, q_vel, (n, 2))
    s[:, 0] = np.clip(s[:, 0], 0.0, width - 1.0)
    s[:, 1] = np.clip(s[:, 1], 0.0, height - 1.0)
    return s


def resample(states: np.ndarray, log_weights: np.ndarray, rng: np.random.Generator,
             scheme: str = "multinomial") -> np.ndarray:
    """Eq. (8): ``s⁺_i ← s⁻_j`` with ``c_{j−1} < u_i ≤ c_j``; u_i i.i.d. uniform is the
    ``multinomial`` scheme.  Returns the ancestor indices."""
    return resample_indices(log_weights, len(states), rng, scheme)


def reset(ps: ParticleSet, which: np.ndarray, width: int, height: int, lo: float, hi: float,
          rng: np.random.Generator) -> ParticleSet:
    """§2.2: parents ``which`` (bool or index) are reset — freed (label 0), re-drawn uniformly
    over the image at rest, with a new scale."""
    idx = np.flatnonzero(which) if np.asarray(which).dtype == bool else np.asarray(which, int)
    if len(idx) == 0:
        return ps
    states = ps.states.copy()
    labels = ps.labels.copy() if ps.labels is not None else np.zeros(len(ps), dtype=np.int64)
    extra = ps.extra.copy() if ps.extra is not None else np.zeros((len(ps), 2))
    states[idx] = uniform_states(len(idx), width, height, rng)
    labels[idx] = 0
    extra[idx, 0] = draw_heights(len(idx), lo, hi, rng)
    extra[idx, 1:] = 0.0
    return ParticleSet(states, ps.log_weights, labels, extra)


__all__ = ["A", "uniform_states", "draw_heights", "init_parents", "predict", "resample", "reset"]
