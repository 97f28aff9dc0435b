"""Vectorised colour helpers for weights and identities (no per-point Python loops)."""

from __future__ import annotations

import numpy as np

# viridis (matplotlib's perceptually uniform map), 9 stops, interpolated per channel.
_RAMP = np.array([[68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
                  [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37]],
                 dtype=np.float64)

#: Decades of weight the ramp spans: yellow = the cloud's 95th-percentile weight or more, dark
#: purple = that weight / 10**WEIGHT_DECADES or less (log scale, so a cloud of many small weights still reads).
WEIGHT_DECADES = 2.0

#: Track colours take hues in [TRACK_HUE_MIN, TRACK_HUE_MAX] degrees (orange → green → blue),
#: saturated; the semantic colours (misses red, false positives magenta, detections/gt grey and
#: white, switches black) lie outside, so a track is never mistaken for a mark.
TRACK_HUE_MIN, TRACK_HUE_MAX = 35.0, 265.0


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


def weight_scale(weights: np.ndarray) -> np.ndarray:
    """(N,) non-negative weights -> [0, 1]: log10(w / w95) over WEIGHT_DECADES decades (w95: the
    95th percentile)."""
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(w) == 0:
        return w
    # the 95th percentile, not the maximum: one outlier must not push the whole cloud to the
    # dark end (weights above it saturate at yellow)
    top = float(np.quantile(w, 0.95)) if len(w) > 20 else float(np.max(w))
    if not top > 0:
        top = float(np.max(w))
    if not top > 0:
        return np.zeros_like(w)
    with np.errstate(divide="ignore"):
        lg = np.log10(np.maximum(w, 0.0) / top)
    return np.clip(1.0 + lg / WEIGHT_DECADES, 0.0, 1.0)


def weight_colors(weights: np.ndarray, alpha: int = 200) -> np.ndarray:
    """(N,) non-negative weights -> (N,4) uint8 RGBA: viridis on a per-cloud log scale (yellow =
    the cloud's 95th-percentile weight or more, dark purple = 1/100 of it or less)."""
    return ramp(weight_scale(weights), alpha)


def id_colors(ids: np.ndarray, alpha: int = 255) -> np.ndarray:
    """(N,) integer ids -> (N,4) uint8 RGBA, well separated hues (golden-ratio walk over the
    track hue range, alternating two brightness levels)."""
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    frac = (ids * 0.618033988749895) % 1.0
    h = (TRACK_HUE_MIN + frac * (TRACK_HUE_MAX - TRACK_HUE_MIN)) / 360.0
    s = np.where(ids % 2 == 0, 0.85, 0.7)
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
    if mx == 0 or (mx - mn) / mx < 0.5:
        return False
    d = mx - mn
    if mx == r:
        hue = (60 * ((g - b) / d)) % 360
    elif mx == g:
        hue = 60 * ((b - r) / d) + 120
    else:
        hue = 60 * ((r - g) / d) + 240
    return TRACK_HUE_MIN - 5 <= hue <= TRACK_HUE_MAX + 5
