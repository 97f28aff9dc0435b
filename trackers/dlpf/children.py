"""Child particles, the second layer (jung2013 §2.2, eqs. (9)–(15)): colour tracking of a
confirmed person (Pérez et al. 2002, jung2013 ref. [8]).

A track's children are a :class:`~pfscope.trackers.smc.ParticleSet` with ``labels`` = the track
id and states ``(cx, cy, h, cx', cy', h')``: the box centre and height now and one frame ago
(the box width is ``aspect · h``, the aspect fixed at confirmation).  Keeping the previous
values in the state is what the **second-order autoregressive** prediction needs:

    x_k = x_{k−1} + d (x_{k−1} − x_{k−2}) + w,   w ~ N(0, σ²)

(d = 1 is constant velocity; ``damping`` < 1 lets a wrong velocity die out), with σ
proportional to the box height for the position and log-normal for the height.

Observation: the HSV histogram of eq. (12) over the *sampled* object region R(x) — a fixed
grid of ``grid`` points inside each child's box (the paper: "R(x) is the sampled object
region"), so the histograms of all children of all tracks come from one gather and one
``bincount``; no per-pixel or per-particle Python loop.  Binning follows Pérez et al.: a pixel
whose saturation and value are both above ``s_min``/``v_min`` goes to one of ``Mh·Ms`` hue–
saturation bins, any other pixel to one of ``Mv`` value-only bins: ``M = Mh·Ms + Mv`` bins.
Bhattacharyya distance eq. (13), weights eq. (14) ``exp(−λ B²)``, MAP estimate eq. (15).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Optional

import cv2
import numpy as np

from ._child_kernels import bin_counts, sample_pixels


@lru_cache(maxsize=8)
def sample_grid(gx: int, gy: int) -> tuple[np.ndarray, np.ndarray]:
    """Relative sample positions in a box, (gx·gy,) each in (−0.5, 0.5) (read-only, cached)."""
    u = (np.arange(gx) + 0.5) / gx - 0.5
    v = (np.arange(gy) + 0.5) / gy - 0.5
    uu, vv = np.meshgrid(u, v)
    uu, vv = uu.ravel(), vv.ravel()
    uu.flags.writeable = vv.flags.writeable = False
    return uu, vv


@lru_cache(maxsize=8)
def _bin_table(mh: int, ms: int, mv: int, s_min: float, v_min: float) -> np.ndarray:
    """``cv2.LUT`` table (1, 256, 3) of :func:`hsv_bins`: hue → hue bin; saturation → its bin,
    +128 when too low for a chromatic bin; value → its bin, +128 when too low."""
    a = np.arange(256)
    lut = np.empty((1, 256, 3), dtype=np.uint8)
    lut[0, :, 0] = np.minimum(np.minimum(a, 179) * mh // 180, mh - 1)
    lut[0, :, 1] = np.minimum(a * ms // 256, ms - 1) + np.where(a >= s_min * 255.0, 0, 128)
    lut[0, :, 2] = np.minimum(a * mv // 256, mv - 1) + np.where(a >= v_min * 255.0, 0, 128)
    lut.flags.writeable = False
    return lut


@lru_cache(maxsize=8)
def _bin_table_small(mh: int, ms: int, mv: int, s_min: float, v_min: float) -> np.ndarray:
    """The table of :func:`hsv_bins` when every bin index fits in 7 bits (``mh·ms + mv`` ≤ 128):
    hue → ``hue bin · ms``; saturation → its bin, +128 when too low for a chromatic bin; value
    → ``mh·ms +`` its bin, +128 when too low.  A chromatic bin is then the sum of the first two
    bytes and a value-only bin the third byte's low 7 bits (fewer array passes per pixel)."""
    lut = _bin_table(mh, ms, mv, s_min, v_min).copy()
    lut[0, :, 0] *= ms
    lut[0, :, 2] += mh * ms
    lut.flags.writeable = False
    return lut


def _table_bytes(bgr_pixels: np.ndarray, mh: int, ms: int, mv: int, s_min: float,
                 v_min: float) -> np.ndarray:
    """(1, N, 3) uint8: the bin table's bytes (:func:`_bin_table_small` when ``mh·ms + mv`` ≤
    128, else :func:`_bin_table`) of the BGR pixels' OpenCV 8-bit HSV (one ``cvtColor``, one
    ``cv2.LUT``)."""
    if max(mh, ms, mv) > 127:
        raise ValueError(f"at most 127 bins per channel, got {mh}, {ms}, {mv}")
    px = np.asarray(bgr_pixels, dtype=np.uint8)
    hsv = cv2.cvtColor(px.reshape(1, -1, 3), cv2.COLOR_BGR2HSV)
    table = _bin_table_small if mh * ms + mv <= 128 else _bin_table
    return cv2.LUT(hsv, table(mh, ms, mv, float(s_min), float(v_min)))


def hsv_bins(bgr_pixels: np.ndarray, mh: int, ms: int, mv: int, s_min: float,
             v_min: float) -> np.ndarray:
    """Bin index (0..M−1) of each BGR pixel, (...,) int, ``M = mh·ms + mv`` (eq. (12)'s h(z)).
    OpenCV 8-bit HSV: H in [0, 180), S, V in [0, 256); a pixel whose S and V are at least
    ``s_min``, ``v_min`` of 255 goes to hue-saturation bin ``hb·ms + sb``, any other to value
    bin ``mh·ms + vb`` (one ``cv2.LUT``, no float maths per pixel)."""
    shape = np.shape(bgr_pixels)[:-1]
    q = _table_bytes(bgr_pixels, mh, ms, mv, s_min, v_min).reshape(-1, 3)
    if mh * ms + mv <= 128:
        low = (q[:, 1] | q[:, 2]) >= 128
        return np.where(low, q[:, 2] & 127, q[:, 0] + q[:, 1]).reshape(shape)
    hb, sb, vb = q[:, 0], q[:, 1], q[:, 2]
    dt = np.uint8 if mh * ms + mv <= 255 else np.int32
    low = (sb | vb) >= 128
    out = np.where(low, (vb & 127).astype(dt) + dt(mh * ms), hb.astype(dt) * dt(ms) + (sb & 127))
    return out.reshape(shape)


def histograms(image: np.ndarray, boxes: np.ndarray, grid: tuple[int, int], mh: int, ms: int,
               mv: int, s_min: float, v_min: float) -> np.ndarray:
    """Eq. (12): normalised HSV histograms (N, M) of ``boxes`` (N, 4) ``(x, y, w, h)``, each from
    the ``grid`` samples of its box (points outside the image are clamped to the border).  All
    boxes in one gather, one colour conversion and one count (:mod:`._child_kernels`)."""
    b = np.ascontiguousarray(boxes, dtype=np.float64).reshape(-1, 4)
    M = mh * ms + mv
    n = len(b)
    if n == 0:
        return np.zeros((0, M))
    u, v = sample_grid(*grid)
    px = sample_pixels(np.ascontiguousarray(image, dtype=np.uint8), b, u, v)
    q = _table_bytes(px, mh, ms, mv, s_min, v_min)
    return bin_counts(q, n, len(u), mh, ms, mv)     # K of eq. (12): every sample is in one bin


def bhattacharyya(q_ref: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Eq. (13): ``B = sqrt(1 − Σ sqrt(q*(m) q(m)))`` of one reference (M,) against (N, M);
    in [0, 1], 0 for identical histograms."""
    bc = np.sqrt(np.asarray(q, dtype=np.float64) * np.asarray(q_ref, dtype=np.float64)).sum(-1)
    return np.sqrt(np.clip(1.0 - bc, 0.0, 1.0))


def log_weights(B: np.ndarray, lam: float) -> np.ndarray:
    """Eq. (14): ``log w = −λ B²`` (unnormalised)."""
    return -lam * np.asarray(B, dtype=np.float64) ** 2


def spawn(box: np.ndarray, n: int, pos_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` child states around a confirmed box ``(x, y, w, h)``, at rest (previous = now)."""
    x, y, w, h = (float(v) for v in box)
    c = np.empty((n, 6))
    c[:, 0] = x + w / 2 + rng.normal(0.0, pos_sigma * h, n)
    c[:, 1] = y + h / 2 + rng.normal(0.0, pos_sigma * h, n)
    c[:, 2] = h
    c[:, 3:] = c[:, :3]
    return c


def predict(states: np.ndarray, damping: float, pos_sigma: float, scale_sigma: float,
            rng: np.random.Generator, shift: Optional[np.ndarray] = None) -> np.ndarray:
    """Second-order AR prediction (module docstring); position noise ``pos_sigma · h``, height
    noise log-normal with ``scale_sigma``.  ``shift`` (2,): a measured motion into this frame
    (the track's optical flow) used instead of the AR velocity term."""
    s = np.asarray(states, dtype=np.float64)
    n = len(s)
    cur, prev = s[:, :3], s[:, 3:]
    new = np.empty_like(s)
    h = cur[:, 2]
    if shift is None:
        dx, dy = damping * (cur[:, 0] - prev[:, 0]), damping * (cur[:, 1] - prev[:, 1])
    else:
        dx, dy = float(shift[0]), float(shift[1])
    new[:, 0] = cur[:, 0] + dx + rng.normal(0, 1, n) * pos_sigma * h
    new[:, 1] = cur[:, 1] + dy + rng.normal(0, 1, n) * pos_sigma * h
    new[:, 2] = h * np.exp(rng.normal(0.0, scale_sigma, n))
    new[:, 3:] = cur
    return new


def predict_tracks(states: list[np.ndarray], shifts: list[Optional[np.ndarray]],
                   damping: float, pos_sigma: float, scale_sigma: float,
                   rng: np.random.Generator) -> list[np.ndarray]:
    """:func:`predict` of several tracks' children (``shifts[k]`` the k-th track's), in one pass:
    the same values and the same draws as one call per track in turn (one standard-normal
    draw, read track by track as the x, y and log-height noise; ``normal(0, s)`` is ``s·z``)."""
    sizes = [len(s) for s in states]
    if not sizes:
        return []
    s = np.concatenate([np.asarray(x, dtype=np.float64).reshape(-1, 6) for x in states])
    n = len(s)
    z = rng.standard_normal(3 * n)
    first = np.repeat(np.cumsum([0] + sizes[:-1]), sizes)     # each row's track's first row
    size = np.repeat(sizes, sizes)
    at = 2 * first + np.arange(n)                 # its x noise: z[3·first + (row − first)]
    cur, prev = s[:, :3], s[:, 3:]
    h = cur[:, 2]
    dx, dy = damping * (cur[:, 0] - prev[:, 0]), damping * (cur[:, 1] - prev[:, 1])
    for k, (a, b) in enumerate(zip(np.cumsum([0] + sizes[:-1]), np.cumsum(sizes))):
        if shifts[k] is not None:
            dx[a:b], dy[a:b] = float(shifts[k][0]), float(shifts[k][1])
    new = np.empty_like(s)
    new[:, 0] = cur[:, 0] + dx + z[at] * pos_sigma * h
    new[:, 1] = cur[:, 1] + dy + z[at + size] * pos_sigma * h
    new[:, 2] = h * np.exp(scale_sigma * z[at + 2 * size])
    new[:, 3:] = cur
    return np.split(new, np.cumsum(sizes)[:-1])


def boxes_of(states: np.ndarray, aspect: float | np.ndarray) -> np.ndarray:
    """Child states (N, 6), or their first three columns ``(cx, cy, h)`` (N, 3) or (3,), →
    boxes ``(x, y, w, h)`` (N, 4)."""
    s = np.asarray(states, dtype=np.float64)
    s = s.reshape(-1, 6 if s.shape[-1] == 6 else 3)
    h = s[:, 2]
    out = np.empty((len(s), 4))
    out[:, 2] = np.multiply(aspect, h)
    out[:, 0] = s[:, 0] - out[:, 2] / 2
    out[:, 1] = s[:, 1] - h / 2
    out[:, 3] = h
    return out


def map_index(log_w: np.ndarray) -> int:
    """Eq. (15): the index of the heaviest child."""
    return int(np.argmax(log_w))


__all__ = ["sample_grid", "hsv_bins", "histograms", "bhattacharyya", "log_weights", "spawn",
           "predict", "predict_tracks", "boxes_of", "map_index"]
