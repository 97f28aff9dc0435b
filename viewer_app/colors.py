"""Vectorised colour helpers for weights and identities (no per-point Python loops)."""

from __future__ import annotations

import numpy as np

# A compact viridis-like ramp (5 stops), interpolated per channel.
_RAMP = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]],
                 dtype=np.float64)


def weight_colors(weights: np.ndarray, alpha: int = 200) -> np.ndarray:
    """(N,) non-negative weights -> (N,4) uint8 RGBA, low = dark purple, high = yellow.
    Weights are scaled by their maximum so each cloud uses the whole ramp."""
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(w) == 0:
        return np.zeros((0, 4), dtype=np.uint8)
    top = np.max(w)
    t = np.clip(w / top, 0.0, 1.0) if top > 0 else np.zeros_like(w)
    t = np.sqrt(t)  # spread the many small weights
    pos = t * (len(_RAMP) - 1)
    lo = np.floor(pos).astype(int).clip(0, len(_RAMP) - 2)
    frac = (pos - lo)[:, None]
    rgb = _RAMP[lo] * (1 - frac) + _RAMP[lo + 1] * frac
    out = np.empty((len(w), 4), dtype=np.uint8)
    out[:, :3] = np.round(rgb).astype(np.uint8)
    out[:, 3] = alpha
    return out


def id_colors(ids: np.ndarray, alpha: int = 255) -> np.ndarray:
    """(N,) integer ids -> (N,4) uint8 RGBA, well separated hues (golden-ratio hue walk)."""
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    h = (ids * 0.618033988749895) % 1.0
    s, v = 0.75, 0.95
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
