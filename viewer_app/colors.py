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


# -- track colours: chosen in OKLab (Ottosson 2020), a perceptual space where Euclidean distance
# follows how different two colours look (about 0.02 is a just-noticeable difference)

_M1 = np.array([[0.4122214708, 0.5363325363, 0.0514459929],
                [0.2119034982, 0.6806995451, 0.1073969566],
                [0.0883024619, 0.2817188376, 0.6299787005]])
_M2 = np.array([[0.2104542553, 0.7936177850, -0.0040720468],
                [1.9779984951, -2.4285922050, 0.4505937099],
                [0.0259040371, 0.7827717662, -0.8086757660]])


def srgb_to_oklab(rgb) -> np.ndarray:
    """(..., 3) sRGB 0-255 -> (..., 3) OKLab (L in [0, 1])."""
    c = np.asarray(rgb, dtype=np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return np.cbrt(lin @ _M1.T) @ _M2.T


def oklab_to_srgb(lab) -> np.ndarray:
    """(..., 3) OKLab -> (..., 3) sRGB 0-255 (float, unclipped: out of [0, 255] = out of gamut)."""
    lin = (np.asarray(lab, dtype=np.float64) @ np.linalg.inv(_M2).T) ** 3 @ np.linalg.inv(_M1).T
    return np.where(lin <= 0.0031308, 12.92 * lin,
                    1.055 * np.clip(lin, 0, None) ** (1 / 2.4) - 0.055) * 255.0


#: Colours no track may look like (OKLab distance >= RESERVED_DISTANCE): the semantic marks
#: (misses red, false positives magenta, classifier hits cyan, births pink; detections,
#: candidates, dropped in greys; ground truth white; switches black) and the heavy end of the
#: particles' viridis (yellow).  Greys and white are also kept away by MIN_CHROMA.
RESERVED_RGB = ((255, 30, 30), (255, 0, 190), (0, 230, 255), (255, 170, 220), (253, 231, 37),
                (250, 250, 250),
                (175, 175, 175), (150, 150, 150), (110, 110, 110), (0, 0, 0))
RESERVED_DISTANCE = 0.12
MIN_CHROMA = 0.09
#: The candidates: OKLCh lightness x chroma x hue grid, hues outside the red-magenta band
#: (OKLab hue of the miss red ~28 deg, of the false-positive magenta ~344 deg).
_L_STEPS = (0.55, 0.63, 0.71, 0.79, 0.87)
_C_STEPS = (0.09, 0.12, 0.15, 0.18, 0.21)
_HUE_RANGE = (45.0, 300.0)
#: How many colours the palette holds, in farthest-point order: the first k are as far apart
#: as a greedy packing gets (8 colours >= 0.17 apart, 50 >= 0.05).
PALETTE_SIZE = 64


def _candidates() -> np.ndarray:
    L, C, H = np.meshgrid(_L_STEPS, _C_STEPS, np.arange(0.0, 360.0, 3.0), indexing="ij")
    L, C, H = L.ravel(), C.ravel(), H.ravel()
    lab = np.stack([L, C * np.cos(np.radians(H)), C * np.sin(np.radians(H))], axis=1)
    rgb = oklab_to_srgb(lab)
    ok = np.all((rgb >= -0.5) & (rgb <= 255.5), axis=1)
    ok &= (H >= _HUE_RANGE[0]) & (H <= _HUE_RANGE[1]) & (C >= MIN_CHROMA)
    rgb = np.clip(np.round(rgb[ok]), 0, 255)
    lab = srgb_to_oklab(rgb)
    far = np.linalg.norm(lab[:, None] - srgb_to_oklab(np.array(RESERVED_RGB))[None],
                         axis=2).min(axis=1) >= RESERVED_DISTANCE
    return rgb[far].astype(np.uint8)


def _farthest_first(rgb: np.ndarray, n: int) -> np.ndarray:
    """``n`` of the colours in farthest-point order (deterministic: starts at the orange
    nearest (255, 160, 60); ties take the first candidate)."""
    lab = srgb_to_oklab(rgb)
    first = int(np.argmin(np.linalg.norm(lab - srgb_to_oklab(np.array([255, 160, 60])), axis=1)))
    sel = [first]
    dmin = np.linalg.norm(lab - lab[first], axis=1)
    for _ in range(n - 1):
        j = int(np.argmax(dmin))
        sel.append(j)
        dmin = np.minimum(dmin, np.linalg.norm(lab - lab[j], axis=1))
    return rgb[sel]


_PALETTE: Optional[np.ndarray] = None


def palette() -> np.ndarray:
    """(PALETTE_SIZE, 3) uint8: the track colours, farthest-first."""
    global _PALETTE
    if _PALETTE is None:
        _PALETTE = _farthest_first(_candidates(), PALETTE_SIZE)
    return _PALETTE


def id_colors(ids: np.ndarray, alpha: int = 255) -> np.ndarray:
    """(N,) integer ids -> (N,4) uint8 RGBA without state: id k gets palette colour
    k mod PALETTE_SIZE (consecutive ids far apart).  What a recording uses for track ids is
    :class:`TrackPalette`, which also separates ids that are not consecutive."""
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    pal = palette()
    out = np.empty((len(ids), 4), dtype=np.uint8)
    out[:, :3] = pal[np.mod(ids, len(pal))]
    out[:, 3] = alpha
    return out


class TrackPalette:
    """One colour per track id for a whole recording lane, chosen when the id is first seen:
    the palette colour farthest (OKLab) from the colours of the ids seen in the last
    ``live_frames`` frames (ties: palette order), so ids alive at the same time are as far
    apart as the palette allows whatever their numbers.  Deterministic: the same sequence of
    calls gives the same colours.  ``frame`` is the current frame (the reporter sets it)."""

    def __init__(self, live_frames: int = 10):
        self.live_frames = int(live_frames)
        self.frame = 0
        self._pal = palette()
        self._lab = srgb_to_oklab(self._pal)
        self._index: dict[int, int] = {}
        self._seen: dict[int, int] = {}

    def index_of(self, tid: int) -> int:
        k = self._index.get(tid)
        if k is None:
            live = [self._index[t] for t, f in self._seen.items()
                    if self.frame - f <= self.live_frames and t in self._index]
            if live:
                d = np.linalg.norm(self._lab[:, None] - self._lab[live][None], axis=2).min(1)
                k = int(np.argmax(d))
            else:
                k = len(self._index) % len(self._pal)
            self._index[tid] = k
            self._seen[tid] = self.frame  # live from now: the next new id avoids it too
        return k

    def colors(self, ids, alpha: int = 255, register: bool = True) -> np.ndarray:
        """(N,) ids -> (N,4) uint8; the ids are marked as seen at :attr:`frame`.  With
        ``register=False`` (ids that may never become tracks: tentative vertices) an id
        without a colour yet gets the stateless :func:`id_colors` and takes no palette slot."""
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        if len(ids) == 0:
            return np.zeros((0, 4), dtype=np.uint8)
        if not register:
            out = id_colors(ids, alpha)
            known = np.array([t in self._index for t in ids.tolist()], dtype=bool)
            if known.any():
                out[known] = self.colors(ids[known], alpha)
            return out
        # the distinct ids in increasing order (np.unique's), in Python: a frame has a few ids
        # and this runs several times a frame, where np.unique's own cost was most of it
        uniq = sorted(set(ids.tolist()))
        for t in uniq:  # alive now (those with a colour count as live for the new)
            if t in self._index:
                self._seen[t] = self.frame
        ks = {t: self.index_of(t) for t in uniq}
        if len(self._seen) > 4 * len(self._pal):  # bounded: forget ids long gone
            self._seen = {t: f for t, f in self._seen.items()
                          if self.frame - f <= self.live_frames}
        out = np.empty((len(ids), 4), dtype=np.uint8)
        out[:, :3] = self._pal[[ks[t] for t in ids.tolist()]]
        out[:, 3] = alpha
        return out


def min_distance(rgb) -> float:
    """The smallest OKLab distance between any two of the (N, 3) colours."""
    lab = srgb_to_oklab(np.asarray(rgb)[:, :3])
    d = np.linalg.norm(lab[:, None] - lab[None], axis=2)
    d[np.diag_indices(len(lab))] = np.inf
    return float(d.min()) if len(lab) > 1 else float("inf")


def is_track_colour(rgb) -> bool:
    """Whether an RGB colour could be a track's: chroma >= MIN_CHROMA, hue outside the
    red-magenta band and at least RESERVED_DISTANCE from every reserved colour (OKLab)."""
    lab = srgb_to_oklab(np.asarray(rgb, dtype=np.float64)[:3])
    chroma = float(np.hypot(lab[1], lab[2]))
    hue = float(np.degrees(np.arctan2(lab[2], lab[1])) % 360)
    if chroma < MIN_CHROMA - 1e-3 or not _HUE_RANGE[0] - 1 <= hue <= _HUE_RANGE[1] + 1:
        return False
    d = np.linalg.norm(srgb_to_oklab(np.array(RESERVED_RGB)) - lab, axis=1).min()
    return bool(d >= RESERVED_DISTANCE - 1e-3)
