"""OSPA and GOSPA distances between the true and the estimated target sets of one frame.

feng2015 §III evaluates its PHD filters with the optimal subpattern assignment (OSPA) metric of
its reference [15] (Ristic, Vo & Clark 2010, which uses the OSPA of Schuhmacher, Vo & Vo 2008)
on target *positions*, in pixels (Fig. 3, Table I).  The paper gives neither the cut-off ``c`` nor
the order ``p``; our defaults are ``c = 100`` px and ``p = 1`` (see ``DEFAULT_C``/``DEFAULT_P``):
with ``p = 1`` OSPA is an average per-target error in pixels, comparable to feng2015's "ME" row,
and 100 px is about the height of a pedestrian in PETS09-S2L1, so an estimate further than that
from every true target counts as a false target plus a miss.

The points are box centres ``(x + w/2, y + h/2)``; box sizes do not enter OSPA.

For X with m points and Y with n points, m <= n (Schuhmacher et al. 2008):

    OSPA_p^(c)(X, Y) = ( (1/n) (min_pi sum_i d^(c)(x_i, y_pi(i))^p + c^p (n - m)) )^(1/p),
    d^(c)(x, y) = min(c, ||x - y||),  OSPA(∅, ∅) = 0,  OSPA(∅, Y) = c.

GOSPA (Rahmathullah, García-Fernández & Svensson 2017) drops the 1/n normalisation and
charges c^p/alpha per unassigned point:

    GOSPA_p^(c,alpha)(X, Y) = ( min_pi sum_i d^(c)(x_i, y_pi(i))^p + (c^p / alpha)(n - m) )^(1/p),

which for alpha = 2 equals "localisation error of the assigned pairs + c^p/2 per miss and per
false target".  Both minimisations are one Hungarian assignment on the cut-off distances.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

#: OSPA / GOSPA cut-off in pixels (feng2015 gives none; see the module docstring).
DEFAULT_C = 100.0
#: OSPA / GOSPA order (feng2015 gives none; p = 1 makes OSPA a mean error in pixels).
DEFAULT_P = 1.0
#: GOSPA alpha: 2 is the value for which GOSPA counts misses and false targets (2017).
DEFAULT_ALPHA = 2.0


def _check(c: float, p: float) -> None:
    if not (np.isfinite(c) and c > 0):
        raise ValueError(f"OSPA cut-off c must be a positive number, got {c!r}")
    if not (np.isfinite(p) and p >= 1):
        raise ValueError(f"OSPA order p must be >= 1, got {p!r}")


def _assigned_cost(x: np.ndarray, y: np.ndarray, c: float, p: float) -> float:
    """min over assignments of the smaller set into the larger of sum d^(c)(x, y)^p."""
    diff = x[:, None, :] - y[None, :, :]
    cost = np.minimum(np.sqrt(np.einsum("ijk,ijk->ij", diff, diff)), c) ** p
    rows, cols = linear_sum_assignment(cost)
    return float(cost[rows, cols].sum())


def _points(a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.size == 0:
        return np.zeros((0, 2))
    if a.ndim != 2:
        raise ValueError(f"expected an (N, D) array of points, got shape {a.shape}")
    return a


def ospa_gospa(x, y, c: float = DEFAULT_C, p: float = DEFAULT_P,
               alpha: float = DEFAULT_ALPHA) -> tuple[float, float]:
    """(:func:`ospa`, :func:`gospa`) of the same point sets from ONE assignment (both minimise
    the same cut-off cost of the smaller set into the larger; a per-frame scorer wants both)."""
    _check(c, p)
    if not (0 < alpha <= 2):
        raise ValueError(f"GOSPA alpha must be in (0, 2], got {alpha!r}")
    x, y = _points(x), _points(y)
    m, n = len(x), len(y)
    if m > n:
        x, y, m, n = y, x, n, m
    loc = _assigned_cost(x, y, c, p) if m else 0.0
    if n == 0:
        o = 0.0
    elif m == 0:
        o = float(c)
    else:
        o = float(((loc + c ** p * (n - m)) / n) ** (1.0 / p))
    return o, float((loc + c ** p / alpha * (n - m)) ** (1.0 / p))


def ospa(x, y, c: float = DEFAULT_C, p: float = DEFAULT_P) -> float:
    """OSPA distance (Schuhmacher et al. 2008) between point sets x (m, D) and y (n, D).

    Returns a value in [0, c]: 0 when both sets are empty, c when exactly one is.
    """
    return ospa_gospa(x, y, c, p)[0]


def gospa(x, y, c: float = DEFAULT_C, p: float = DEFAULT_P,
          alpha: float = DEFAULT_ALPHA) -> float:
    """GOSPA distance (Rahmathullah et al. 2017) between point sets x and y.

    Not normalised by the set size: it grows with the number of targets. 0 when both are empty.
    """
    return ospa_gospa(x, y, c, p, alpha)[1]
