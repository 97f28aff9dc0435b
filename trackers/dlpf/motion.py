"""Motion measurement of the first layer (jung2013 §2.1, eqs. (1), (6)–(8)).

Each parent particle measures the Lucas–Kanade motion (eq. (1)) at its predicted position; the
magnitude ``m = |M(x, y)|`` is capped (eq. (6): "the maximum of M(x, y) is set to 5"), scored by
eq. (7) against the target motion ``y0 = 5`` and turned into resampling weights (eq. (8)).

**Sparse pyramidal LK, not dense flow.**  Eq. (1) is exactly the per-window least-squares
problem that ``cv2.calcOpticalFlowPyrLK`` solves (iterated, on an image pyramid so that
displacements larger than the window — PETS09 walkers move 5–10 px per frame at 7 fps — are
still measured).  Only the parents need a measurement, so the cost is O(parents × window), not
O(pixels) as for dense flow (Farnebäck on 768×576 costs more than the whole DLPF step).  The
dense magnitude image that the viewer shows (:func:`motion_field`) is the same LK run on a coarse
grid, built only when a recording asks for particles.

**Reading of eqs. (7)–(8) ("regularised log-likelihood").**  Eq. (7) is the log of a Gaussian-like
density, ``L = −log(2πR) − ‖y_D‖² / √(2π)`` with ``‖y_D‖ = y0 − m``, which is negative whenever
``2πR > 1``.  Eq. (8) then normalises ``L_i / L_total`` and uses the result as a cumulative
distribution.  Taken literally, with all ``L_i`` negative, the *most negative* (static) particles
get the largest share — the opposite of the paper's stated aim ("resample the PPs by motion
distribution").  The readings offered (parameter ``likelihood``):

- ``"exp"`` (default): ``L`` is a log-likelihood; the weights are ``exp(L_i) / Σ exp(L_j)``
  (computed with log-sum-exp), i.e. eq. (8)'s normalisation applied to the likelihood itself.
  The constant ``−log(2πR)`` cancels, so R only matters for the other readings.
- ``"shift"``: "regularised" as ``L_i − min_j L_j`` (+ a tiny floor so an all-equal frame gives
  uniform weights) normalised as in eq. (8): weights linear in ``L``, zero for the least moving.
- ``"literal"``: ``L_i / Σ L_j`` exactly as printed (valid weights only while every ``L_i`` has
  the same sign; kept to show the inversion, not for use).

Motion inside tracked regions is set to zero before eq. (7) (§2.2, last paragraph: "the motion
in the tracked object region is set to zero"), so parents leave tracked people and search
elsewhere (:func:`mask_tracked`).
"""

from __future__ import annotations

from typing import Optional

import cv2
import numpy as np

from ..dbn.scale import box_fill     # the DBN-PHD's foreground fraction of boxes
from ..smc import logsumexp

READINGS = ("exp", "shift", "literal")


def lk_flow(prev_grey: np.ndarray, grey: np.ndarray, points: np.ndarray, *, win: int = 15,
            levels: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Pyramidal Lucas–Kanade (eq. (1)) of ``points`` (N, 2) from ``prev_grey`` to ``grey``.

    Returns ``flow`` (N, 2) in px/frame and ``ok`` (N,) bool; points LK could not track
    (untextured window, left the image) get flow 0 and ``ok`` False."""
    n = len(points)
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=bool)
    p0 = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 1, 2)
    p1, status, _err = cv2.calcOpticalFlowPyrLK(
        prev_grey, grey, p0, None, winSize=(int(win), int(win)), maxLevel=int(levels),
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 0.03))
    flow = (p1 - p0).reshape(n, 2).astype(np.float64)
    ok = status.reshape(n).astype(bool) & np.all(np.isfinite(flow), axis=1)
    flow[~ok] = 0.0
    return flow, ok


def magnitude(flow: np.ndarray, cap: float) -> np.ndarray:
    """Eq. (6): ``m = min(sqrt(dx² + dy²), cap)`` (N,)."""
    return np.minimum(np.hypot(flow[:, 0], flow[:, 1]), cap)


def inside_boxes(points: np.ndarray, boxes: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """(N,) bool: point inside any ``(x, y, w, h)`` box grown by ``margin`` × its size per side."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    if len(pts) == 0 or len(b) == 0:
        return np.zeros(len(pts), dtype=bool)
    x0 = b[:, 0] - margin * b[:, 2]
    y0 = b[:, 1] - margin * b[:, 3]
    x1 = b[:, 0] + (1 + margin) * b[:, 2]
    y1 = b[:, 1] + (1 + margin) * b[:, 3]
    px, py = pts[:, :1], pts[:, 1:]
    return np.any((px >= x0) & (px <= x1) & (py >= y0) & (py <= y1), axis=1)


def mask_tracked(m: np.ndarray, points: np.ndarray, track_boxes: np.ndarray,
                 margin: float = 0.0) -> np.ndarray:
    """§2.2: the motion at points inside a tracked region is set to zero (a copy of ``m``)."""
    out = np.array(m, dtype=np.float64, copy=True)
    out[inside_boxes(points, track_boxes, margin)] = 0.0
    return out


def log_likelihood(m: np.ndarray, y0: float = 5.0, R: float = 1.0) -> np.ndarray:
    """Eq. (7): ``L = −log(2πR) − (y0 − m)² / √(2π)`` per particle."""
    yd = y0 - np.asarray(m, dtype=np.float64)
    return -np.log(2.0 * np.pi * R) - yd * yd / np.sqrt(2.0 * np.pi)


def resampling_log_weights(L: np.ndarray, reading: str = "exp") -> np.ndarray:
    """Normalised log-weights (log-sum-exp = 0) of eq. (8) under ``reading`` (module docstring).
    Weights of an empty set are empty; a degenerate reading (all zero) falls back to uniform."""
    L = np.asarray(L, dtype=np.float64)
    n = len(L)
    if n == 0:
        return np.zeros(0)
    if reading == "exp":
        lw = L
    elif reading == "shift":
        w = L - L.min() + 1e-6
        with np.errstate(divide="ignore"):
            lw = np.log(w)
    elif reading == "literal":
        total = L.sum()
        w = L / total if total != 0 else np.ones(n)
        with np.errstate(divide="ignore", invalid="ignore"):
            lw = np.log(np.where(w > 0, w, 0.0))
    else:
        raise ValueError(f"unknown motion likelihood reading {reading!r}; choose one of "
                         f"{', '.join(READINGS)}")
    lse = logsumexp(lw)
    if not np.isfinite(lse):
        return np.full(n, -np.log(n))
    return lw - lse


class Foreground:
    """Where the scene differs from its learnt background (ours, ``parents.foreground``):
    OpenCV's MOG2 (Zivkovic 2004/2006; no shadow label) on the grey frame shrunk ``shrink``
    times (``INTER_AREA``: a 768x576 frame becomes 192x144, ~0.5 ms), and the fraction of
    foreground pixels in boxes from its integral image.  Stateful: one per sequence, updated
    once a frame in frame order (deterministic: per-pixel, no randomness).  For its first
    ``warmup`` frames every box is all foreground: the model is learning the background
    behind the people of the first frame (after n frames it knows a pixel that was free for
    ~0.2 n of them; dlpf's only other frame-1 evidence is motion), so nothing is gated before
    the background exists; a moving camera keeps most of the frame foreground, and the gate
    then passes (almost) every window."""

    def __init__(self, shrink: int = 4, history: int = 500, var_threshold: float = 16.0,
                 warmup: int = 25):
        self.shrink = max(1, int(shrink))
        self.warmup = int(warmup)
        self.frames = 0
        self._model = cv2.createBackgroundSubtractorMOG2(history=int(history),
                                                         varThreshold=float(var_threshold),
                                                         detectShadows=False)
        self._integral: Optional[np.ndarray] = None
        self._scale = 1.0

    def update(self, grey: np.ndarray) -> None:
        """Learn ``grey`` (H, W) uint8 and keep its foreground mask's integral image."""
        H, W = grey.shape[:2]
        w, h = max(1, W // self.shrink), max(1, H // self.shrink)
        small = cv2.resize(grey, (w, h), interpolation=cv2.INTER_AREA)
        fg = self._model.apply(small)
        self.frames += 1
        self._integral = cv2.integral((fg > 0).view(np.uint8))
        self._scale = w / W

    def fraction(self, boxes: np.ndarray) -> np.ndarray:
        """(N,) fraction of each ``(x, y, w, h)`` box (frame px) that is foreground; all 1
        during the first ``warmup`` frames."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        if self._integral is None or self.frames <= self.warmup:
            return np.ones(len(b))
        return box_fill(self._integral, b, self._scale)


def motion_field(prev_grey: Optional[np.ndarray], grey: np.ndarray, step: int, cap: float, *,
                 win: int = 15, levels: int = 3,
                 track_boxes: Optional[np.ndarray] = None, margin: float = 0.0) -> np.ndarray:
    """Capped LK magnitude on a grid of spacing ``step`` px (for display), (H/step, W/step),
    masked inside tracked regions like the parents' measurements."""
    H, W = grey.shape[:2]
    ys = np.arange(step / 2.0, H, step)
    xs = np.arange(step / 2.0, W, step)
    if prev_grey is None or len(xs) == 0 or len(ys) == 0:
        return np.zeros((len(ys), len(xs)), dtype=np.float32)
    gx, gy = np.meshgrid(xs, ys)
    pts = np.c_[gx.ravel(), gy.ravel()]
    flow, _ = lk_flow(prev_grey, grey, pts, win=win, levels=levels)
    m = magnitude(flow, cap)
    if track_boxes is not None:
        m = mask_tracked(m, pts, track_boxes, margin)
    return m.reshape(len(ys), len(xs)).astype(np.float32)


__all__ = ["READINGS", "lk_flow", "magnitude", "inside_boxes", "mask_tracked", "log_likelihood",
           "resampling_log_weights", "motion_field", "Foreground"]
