"""Size-aware motion model of maggio2007 §2 and §4, for states ``x = (y1, y2, v1, v2, w, h)``.

§2: "each target moves according to a first-order Gaussian dynamic on the position and
zero-order on the size. As larger objects (in the image plane) usually accelerate faster than
smaller objects in the same scene, the intensity of the white Gaussian noise modeling
acceleration and change of size is proportional to the size of the target at time k-1."
§4 gives the standard deviations: ``σ_v1 = 0.03 w_{k-1}``, ``σ_v2 = 0.03 h_{k-1}``,
``σ_w = 0.1 w_{k-1}``, ``σ_h = 0.1 h_{k-1}``.

Reading (parameter ``accel_to_position``): the noise is an *acceleration* ``a`` held constant
over one frame (discrete white-noise acceleration model), so

    v_k = v_{k-1} + a,     y_k = y_{k-1} + v_{k-1} + accel_to_position * a,

with ``accel_to_position = 0.5`` (= dt²/2 for dt = 1 frame).  0 lets the noise reach the
position only one frame later; 1 moves with the new velocity.  Sizes follow a random walk
``w_k = w_{k-1} + N(0, (0.1 w_{k-1})²)`` and are clipped to ``>= min_size`` pixels (a box
cannot have zero or negative size; the clip touches < 1e-20 of the mass at paper settings
for boxes larger than ~10 px).
"""

from __future__ import annotations

import numpy as np

from ..smc.random import key_stream
from ._kernels import propagate_into

#: maggio2007 §4 defaults.
SIGMA_V = 0.03        # velocity (acceleration) noise std per frame, as a fraction of w / h
SIGMA_SIZE = 0.1      # size noise std per frame, as a fraction of w / h
ACCEL_TO_POSITION = 0.5
MIN_SIZE = 1.0        # pixels


def propagate(states: np.ndarray, rng: np.random.Generator, *, sigma_v: float = SIGMA_V,
              sigma_size: float = SIGMA_SIZE, accel_to_position: float = ACCEL_TO_POSITION,
              min_size: float = MIN_SIZE, out: np.ndarray | None = None,
              log_weights: np.ndarray | None = None, log_e: float = 0.0,
              lw_out: np.ndarray | None = None) -> np.ndarray:
    """Draw ``x_k ~ f(. | x_{k-1})`` for every row of ``states`` (N, 6); returns a new (N, 6)
    (or the first N rows of ``out``, an (M >= N, 6) float64 array it writes into).

    Noise std is proportional to each particle's own size at k-1 (maggio2007 §2, §4).
    Takes one word of ``rng`` (the key of the generator the kernel draws its 4 N normals from,
    :mod:`~trackers.smc.random`); none when there are no particles.  With ``log_weights`` (N,)
    float64 and ``lw_out`` (>= N,) float64, also writes ``lw_out[:N] = log_weights + log_e``
    in the same pass (the PHD prediction's survival factor)."""
    x = np.asarray(states, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 6:
        raise ValueError(f"propagate: expected states (N, 6), got {x.shape}")
    n = len(x)
    if out is None:
        out = np.empty_like(x)
    elif out.dtype != np.float64 or out.ndim != 2 or out.shape[1] != 6 or len(out) < n:
        raise ValueError(f"propagate: out must be float64 (>= {n}, 6), got {out.shape}")
    out = out[:n]
    if n == 0:
        return out
    # one fused pass (numba) drawing its own normals ε: a = σ_v (w, h) ε, y += v + c a,
    # v += a (first order on position), (w, h) += σ_size (w, h) ε clipped to min_size (zero
    # order on size)
    if log_weights is None:
        log_weights = lw_out = _NO_LW
    elif not (len(log_weights) == n and len(lw_out) >= n):
        raise ValueError(f"propagate: {len(log_weights)} log-weights (out {len(lw_out)}) for "
                         f"{n} states")
    propagate_into(x, key_stream(rng), float(sigma_v), float(sigma_size),
                   float(accel_to_position), float(min_size), out, log_weights, float(log_e),
                   lw_out, _NO_LW)
    return out


_NO_LW = np.empty(0, np.float64)
