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

#: maggio2007 §4 defaults.
SIGMA_V = 0.03        # velocity (acceleration) noise std per frame, as a fraction of w / h
SIGMA_SIZE = 0.1      # size noise std per frame, as a fraction of w / h
ACCEL_TO_POSITION = 0.5
MIN_SIZE = 1.0        # pixels


def propagate(states: np.ndarray, rng: np.random.Generator, *, sigma_v: float = SIGMA_V,
              sigma_size: float = SIGMA_SIZE, accel_to_position: float = ACCEL_TO_POSITION,
              min_size: float = MIN_SIZE) -> np.ndarray:
    """Draw ``x_k ~ f(. | x_{k-1})`` for every row of ``states`` (N, 6); returns a new (N, 6).

    Noise std is proportional to each particle's own size at k-1 (maggio2007 §2, §4).
    Consumes exactly one ``rng.standard_normal((N, 4))`` draw."""
    x = np.asarray(states, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 6:
        raise ValueError(f"propagate: expected states (N, 6), got {x.shape}")
    n = len(x)
    out = x.copy()
    if n == 0:
        return out
    eps = rng.standard_normal((n, 4))
    size = x[:, 4:6]                       # (w, h) at k-1 scale every noise term
    acc = sigma_v * size * eps[:, 0:2]     # acceleration on (v1, v2)
    out[:, 0:2] += x[:, 2:4] + accel_to_position * acc   # first order on position
    out[:, 2:4] += acc
    out[:, 4:6] = np.maximum(size + sigma_size * size * eps[:, 2:4], min_size)  # zero order
    return out


def predict_mean(states: np.ndarray, gap: int | np.ndarray = 1) -> np.ndarray:
    """Noise-free constant-velocity prediction ``gap`` frames ahead: (N, 6)."""
    x = np.asarray(states, dtype=np.float64)
    g = np.asarray(gap, dtype=np.float64).reshape(-1, 1) if np.ndim(gap) else float(gap)
    out = x.copy()
    out[:, 0:2] += g * x[:, 2:4]
    return out


def transition_logpdf(x_to: np.ndarray, x_from: np.ndarray, gap: int | np.ndarray = 1, *,
                      sigma_v: float = SIGMA_V, sigma_size: float = SIGMA_SIZE,
                      accel_to_position: float = ACCEL_TO_POSITION, min_std: float = 1.0,
                      include_velocity: bool = False) -> np.ndarray:
    """Gaussian approximation of ``log f(x_to | x_from)`` after ``gap`` frames: (B, A) matrix
    for ``x_from`` (B, 6) and ``x_to`` (A, 6); ``gap`` a scalar or (B,) ints >= 1.

    This is the gain ``log f(x̂_k | x̂_{k-i})`` of the graph matching of maggio2007 §3.
    Covariances are those of :func:`propagate` accumulated over ``gap`` steps with the noise
    scale frozen at ``x_from``'s size (exact for position/velocity, first-order for the
    multiplicative size walk).  ``min_std`` (pixels, pixels/frame) is added in quadrature to
    every variance: at ``gap = 1`` position and velocity share one noise draw, so the 2-D
    (y, v) density is degenerate without it.  With ``include_velocity=False`` (default) the
    density is the marginal on ``(y1, y2, w, h)``.
    """
    xt = np.asarray(x_to, dtype=np.float64)
    xf = np.asarray(x_from, dtype=np.float64)
    if xt.ndim != 2 or xt.shape[1] != 6 or xf.ndim != 2 or xf.shape[1] != 6:
        raise ValueError(f"transition_logpdf: expected (A, 6) and (B, 6), got {xt.shape}, {xf.shape}")
    g = np.broadcast_to(np.asarray(gap, dtype=np.float64), (len(xf),)).reshape(-1, 1)
    if np.any(g < 1):
        raise ValueError("transition_logpdf: gap must be >= 1")
    c = accel_to_position
    m2 = min_std ** 2
    # Sums over the `gap` accelerations a_t, t = 1..g: y_g picks up a_t * (c + g - t).
    s1 = g * c + g * (g - 1) / 2.0                                  # sum (c + j)
    s2 = g * c * c + c * g * (g - 1) + (g - 1) * g * (2 * g - 1) / 6.0  # sum (c + j)^2
    size = xf[:, 4:6]                                               # (B, 2)
    var_a = (sigma_v * size) ** 2                                   # (B, 2)
    s_yy = var_a * s2 + m2
    s_vv = var_a * g + m2
    s_yv = var_a * s1
    mean_y = xf[:, 0:2] + g * xf[:, 2:4]                            # (B, 2)
    dy = xt[None, :, 0:2] - mean_y[:, None, :]                      # (B, A, 2)
    out = np.zeros((len(xf), len(xt)))
    if include_velocity:
        dv = xt[None, :, 2:4] - xf[:, None, 2:4]
        det = s_yy * s_vv - s_yv ** 2                               # (B, 2)
        q = (s_vv[:, None] * dy ** 2 - 2 * s_yv[:, None] * dy * dv + s_yy[:, None] * dv ** 2) \
            / det[:, None]
        out += -0.5 * q.sum(-1) - 0.5 * np.log(det).sum(-1)[:, None] - 2 * np.log(2 * np.pi)
    else:
        out += (-0.5 * (dy ** 2 / s_yy[:, None]).sum(-1) - 0.5 * np.log(s_yy).sum(-1)[:, None]
                - np.log(2 * np.pi))
    var_s = (sigma_size * size) ** 2 * g + m2                       # (B, 2)
    ds = xt[None, :, 4:6] - xf[:, None, 4:6]
    out += (-0.5 * (ds ** 2 / var_s[:, None]).sum(-1) - 0.5 * np.log(var_s).sum(-1)[:, None]
            - np.log(2 * np.pi))
    return out
