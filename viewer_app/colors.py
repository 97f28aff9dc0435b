"""Vectorised colour helpers for weights and identities (no per-point Python loops)."""

from __future__ import annotations

from typing import Optional

import numpy as np

# viridis (matplotlib's perceptually uniform map), 9 stops, interpolated per channel.
_RAMP = np.array([[68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
                  [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37]],
                 dtype=np.float64)

#: How particle weights look (per cloud and frame): colour = the weight's rank within its cloud
#: on viridis (dark purple = the lightest, yellow = the heaviest tenth), so every cloud spans the
#: whole map whatever the spread of its weights; equal weights (a predicted or resampled cloud)
#: share one rank, the middle teal.  Radius and opacity grow with the rank too, and heavier
#: particles are drawn over lighter ones.  What a rank hides — how much of the weight the yellow
#: tenth holds — is plotted beside the video (``plots/weights/<cloud>/top_tenth``).
WEIGHT_RADIUS = (0.5, 1.5)   # radius = base x (lo + (hi - lo) x rank)
WEIGHT_ALPHA = (110, 255)    # opacity from the lightest to the heaviest
TOP_FRACTION = 0.1           # "the heaviest tenth": the yellow end of the map

#: Track colours take hues in [TRACK_HUE_MIN, TRACK_HUE_MAX] degrees (orange → green → blue),
#: saturated; the semantic colours (misses red, false positives magenta, detections/gt grey and
#: white, switches black) lie outside, so a track is never mistaken for a mark.
TRACK_HUE_MIN, TRACK_HUE_MAX = 35.0, 265.0
#: Saturation of the deepest track blues (lightened so a blue id label reads on the viewer's grey
#: label background) and the least saturation a track colour has (greys and white are below it).
BLUE_SATURATION = 0.45
MIN_TRACK_SATURATION = 0.4


def ramp(t: np.ndarray, alpha: int = 200) -> np.ndarray:
    """(N,) values in [0, 1] -> (N,4) uint8 RGBA on the viridis ramp."""
    t = np.clip(np.asarray(t, dtype=np.float64).reshape(-1), 0.0, 1.0)
    pos = t * (len(_RAMP) - 1)
    lo = np.floor(pos).astype(int).clip(0, len(_RAMP) - 2)
    frac = (pos - lo)[:, None]
    rgb = _RAMP[lo] * (1 - frac) + _RAMP[lo + 1] * frac
    out = np.empty((len(t), 4), dtype=np.uint8)
    out[:, :3] = np.round(rgb).astype(np.uint8)
    out[:, 3] = alpha
    return out


def _ranks_sorted(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(order, t): ``order`` sorts the cloud from the lightest to the heaviest (stable, so
    deterministic) and ``t`` is each sorted weight's rank in [0, 1] (ties share their mean rank:
    equal weights all map to 0.5), from one sort — the same ranks as
    ``scipy.stats.rankdata(w, "average")``, without a second sort."""
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    n = len(w)
    if n == 0:
        return np.zeros(0, dtype=np.int64), w
    if n == 1:
        return np.zeros(1, dtype=np.int64), np.full(1, 0.5)
    w = np.where(np.isfinite(w), w, 0.0)
    order = np.argsort(w, kind="stable")
    ws = w[order]
    first = np.empty(n, dtype=bool)
    first[0] = True
    np.not_equal(ws[1:], ws[:-1], out=first[1:])
    starts = np.flatnonzero(first)
    ends = np.append(starts[1:], n)
    group_rank = (starts + ends - 1) / 2.0          # mean 0-based rank of each run of ties
    t = group_rank[np.cumsum(first) - 1] / (n - 1.0)
    return order, t


#: The ramp sampled at RAMP_STEPS + 1 evenly spaced values of t, for the particle clouds: a
#: lookup instead of the interpolation per point (at most one unit per channel from
#: :func:`ramp`, the rounding of the sampled value).
RAMP_STEPS = 4096
_RAMP_TABLE: Optional[np.ndarray] = None


def ramp_table(t: np.ndarray) -> np.ndarray:
    """(N,) values in [0, 1] -> (N,4) uint8 RGBA (alpha 255) from the sampled ramp."""
    global _RAMP_TABLE
    if _RAMP_TABLE is None:
        _RAMP_TABLE = ramp(np.linspace(0.0, 1.0, RAMP_STEPS + 1), 255)
    idx = np.clip(np.asarray(t, dtype=np.float64).reshape(-1), 0.0, 1.0) * RAMP_STEPS
    return _RAMP_TABLE[(idx + 0.5).astype(np.intp)]


def weight_scale(weights: np.ndarray) -> np.ndarray:
    """(N,) non-negative weights -> [0, 1]: each weight's rank within the cloud (ties share
    their mean rank: equal weights all map to 0.5).  Sorting-based, no loop over particles."""
    order, t_sorted = _ranks_sorted(weights)
    t = np.empty_like(t_sorted)
    t[order] = t_sorted
    return t


def weight_colors(weights: np.ndarray, alpha: Optional[int] = None) -> np.ndarray:
    """(N,) non-negative weights -> (N,4) uint8 RGBA: viridis by rank within the cloud (see
    :data:`WEIGHT_RADIUS`); opacity from ``WEIGHT_ALPHA`` by rank unless ``alpha`` is given."""
    t = weight_scale(weights)
    out = ramp(t, 255)
    lo, hi = WEIGHT_ALPHA if alpha is None else (alpha, alpha)
    out[:, 3] = np.round(lo + (hi - lo) * t).astype(np.uint8)
    return out


def weight_style(weights: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(order, colors, radii) for drawing a weighted cloud: ``order`` sorts the particles from the
    lightest to the heaviest (so the heavy ones are drawn on top; stable, so deterministic),
    colours and radii by rank, both in that order."""
    order, t = _ranks_sorted(weights)
    colors = ramp_table(t)
    lo, hi = WEIGHT_ALPHA
    colors[:, 3] = np.round(lo + (hi - lo) * t).astype(np.uint8)
    rlo, rhi = WEIGHT_RADIUS
    radii = (radius * (rlo + (rhi - rlo) * t)).astype(np.float32)
    return order, colors, radii


def weight_summary(weights: np.ndarray) -> dict[str, float]:
    """What the rank colours hide: ``top_tenth`` = the share of the cloud's total weight held by
    its heaviest tenth (0.1 when weights are equal, near 1 when a few particles carry it all), and
    ``ess`` = the effective sample size over N, 1 / (N sum w_i^2) for normalised weights."""
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
    total = float(w.sum())
    if len(w) == 0 or not total > 0:
        return {}
    k = max(1, int(np.ceil(TOP_FRACTION * len(w))))
    top = float(np.partition(w, len(w) - k)[len(w) - k:].sum())
    wn = w / total
    return {"top_tenth": top / total, "ess": float(1.0 / (len(w) * np.sum(wn * wn)))}


#: Colours of ids 0 .. len - 1, computed once and grown on demand (up to _ID_TABLE_MAX ids):
#: a cloud of thousands of particles of a few clusters costs one lookup, not the HSV maths.
_ID_TABLE = np.zeros((0, 4), dtype=np.uint8)
_ID_TABLE_MAX = 1 << 16


def id_colors(ids: np.ndarray, alpha: int = 255) -> np.ndarray:
    """(N,) integer ids -> (N,4) uint8 RGBA, well separated hues (golden-ratio walk over the
    track hue range, alternating two saturation/brightness levels; blues lightened)."""
    global _ID_TABLE
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    if len(ids) == 0:
        return np.zeros((0, 4), dtype=np.uint8)
    lo, hi = int(ids.min()), int(ids.max())
    if lo < 0 or hi >= _ID_TABLE_MAX:
        return _id_colors(ids, alpha)
    if hi >= len(_ID_TABLE):
        size = min(_ID_TABLE_MAX, max(1024, 2 * (hi + 1)))
        _ID_TABLE = _id_colors(np.arange(size))
    out = _ID_TABLE[ids]
    if alpha != 255:
        out[:, 3] = alpha
    return out


def _id_colors(ids: np.ndarray, alpha: int = 255) -> np.ndarray:
    """:func:`id_colors` computed (no table)."""
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    frac = (ids * 0.618033988749895) % 1.0
    h = (TRACK_HUE_MIN + frac * (TRACK_HUE_MAX - TRACK_HUE_MIN)) / 360.0
    s = np.where(ids % 2 == 0, 0.85, 0.7)
    # deep blues are dark (a blue id label on the viewer's grey label background hardly reads):
    # from azure on, desaturate towards BLUE_SATURATION, which lightens them (still saturated
    # enough to be told from the grey/white marks: see is_track_colour)
    s = s - np.clip((h * 360.0 - 195.0) / 45.0, 0.0, 1.0) * (s - BLUE_SATURATION)
    v = np.where(ids % 2 == 0, 0.95, 1.0)
    i = np.floor(h * 6).astype(int) % 6
    f = h * 6 - np.floor(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    out = np.empty((len(ids), 4), dtype=np.uint8)
    out[:, 0], out[:, 1], out[:, 2] = (np.stack([r, g, b]) * 255).round().astype(np.uint8)
    out[:, 3] = alpha
    return out


def is_track_colour(rgb) -> bool:
    """Whether an RGB colour could be a track's (saturated, hue in the track range)."""
    r, g, b = (np.asarray(rgb, dtype=np.float64)[:3] / 255.0).tolist()
    mx, mn = max(r, g, b), min(r, g, b)
    if mx == 0 or (mx - mn) / mx < MIN_TRACK_SATURATION:
        return False
    d = mx - mn
    if mx == r:
        hue = (60 * ((g - b) / d)) % 360
    elif mx == g:
        hue = 60 * ((b - r) / d) + 120
    else:
        hue = 60 * ((r - g) / d) + 240
    return TRACK_HUE_MIN - 5 <= hue <= TRACK_HUE_MAX + 5
