"""The parents' pedestrian classifier: HOG + linear SVM evaluated one window at a time
(jung2013 §2.1; Dalal & Triggs 2005 features).

jung2013 trains an intersection-kernel SVM (Maji et al. 2008).  The default here needs no
training: OpenCV's pre-trained Dalal–Triggs people SVM
(``cv2.HOGDescriptor_getDefaultPeopleDetector``: 3780 weights + bias over the 64×128 HOG window),
applied to *single windows* instead of a sliding-window scan.

One parent = one window.  A parent at ``(x, y)`` with person height ``h`` (its randomly drawn
scale) looks at the window centred on ``(x, y)`` whose person part is ``h`` tall: Dalal & Triggs
train the 64×128 window with a 16-px context border, so the person fills the central 96 rows and
32 columns; the window is ``h·128/96`` tall and half as wide.  The window is cut from the frame
(replicated at the borders) and **resampled to 64×128 whatever its size**: people smaller than
the HOG window (PETS09: ~80 px tall at 768×576, half that at 480×360) are enlarged, not skipped.

Cost: one ``cv2.resize`` + one ``HOGDescriptor.compute`` per window (a loop over a few hundred
windows, measured ~0.1 ms per window; stacking the resized windows into one mosaic image and
calling ``compute`` once with ``winStride`` = window size was *not* faster on our machine and
lets gradients leak across neighbouring windows), descriptors stacked into (N, 3780) and scored
with one matrix product ``D·w + b``.

:func:`sliding_window_count` counts the windows OpenCV's exhaustive ``detectMultiScale`` scores
on a frame, for the efficiency comparison.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

WIN_W, WIN_H = 64, 128
#: Fraction of the window the person occupies (Dalal & Triggs' 16-px context border).
PERSON_W, PERSON_H = 0.5, 0.75


def window_boxes(centres: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """HOG windows (N, 4) ``(x, y, w, h)`` centred on ``centres`` (N, 2) holding a person
    ``heights`` (N,) tall."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    wh = np.asarray(heights, dtype=np.float64).reshape(-1) / PERSON_H
    ww = wh * WIN_W / WIN_H
    return np.c_[c[:, 0] - ww / 2, c[:, 1] - wh / 2, ww, wh]


def person_boxes(windows: np.ndarray) -> np.ndarray:
    """The person box inside each window (the window without its context border)."""
    w = np.asarray(windows, dtype=np.float64).reshape(-1, 4)
    pw, ph = w[:, 2] * PERSON_W, w[:, 3] * PERSON_H
    return np.c_[w[:, 0] + (w[:, 2] - pw) / 2, w[:, 1] + (w[:, 3] - ph) / 2, pw, ph]


class HOGWindowClassifier:
    """Linear SVM on HOG descriptors of single windows.  ``weights`` (3780,) and ``bias``
    default to OpenCV's people detector; the score is the signed margin ``w·x + b``."""

    def __init__(self, weights: np.ndarray | None = None, bias: float | None = None):
        self.hog = cv2.HOGDescriptor()
        if weights is None:
            det = np.asarray(cv2.HOGDescriptor_getDefaultPeopleDetector(),
                             dtype=np.float32).reshape(-1)
            weights, bias = det[:-1], float(det[-1])
        self.weights = np.asarray(weights, dtype=np.float32).reshape(-1)
        self.bias = float(bias or 0.0)
        size = self.hog.getDescriptorSize()
        if len(self.weights) != size:
            raise ValueError(f"classifier: {len(self.weights)} SVM weights for a HOG descriptor "
                             f"of {size}")

    def descriptors(self, grey: np.ndarray, windows: np.ndarray) -> np.ndarray:
        """(N, 3780) float32 HOG descriptors of ``windows`` resampled to 64×128."""
        w = np.asarray(windows, dtype=np.float64).reshape(-1, 4)
        n = len(w)
        out = np.empty((n, self.hog.getDescriptorSize()), dtype=np.float32)
        if n == 0:
            return out
        H, W = grey.shape[:2]
        # one replicated border for every window that sticks out of the frame
        pad = int(math.ceil(max(0.0, float(np.max(np.r_[-w[:, 0], -w[:, 1],
                                                      w[:, 0] + w[:, 2] - W,
                                                      w[:, 1] + w[:, 3] - H, 0.0]))))) + 1
        padded = cv2.copyMakeBorder(grey, pad, pad, pad, pad, cv2.BORDER_REPLICATE) \
            if pad > 1 else grey
        off = pad if pad > 1 else 0
        x0 = np.floor(w[:, 0] + off).astype(np.int64)
        y0 = np.floor(w[:, 1] + off).astype(np.int64)
        x1 = np.maximum(x0 + 1, np.round(w[:, 0] + w[:, 2] + off).astype(np.int64))
        y1 = np.maximum(y0 + 1, np.round(w[:, 1] + w[:, 3] + off).astype(np.int64))
        x0, y0 = np.maximum(x0, 0), np.maximum(y0, 0)
        x1 = np.minimum(x1, padded.shape[1])
        y1 = np.minimum(y1, padded.shape[0])
        buf = np.empty((WIN_H, WIN_W), dtype=np.uint8)
        compute = self.hog.compute
        for i in range(n):  # a few hundred windows: resize + HOG each (see the module docstring)
            cv2.resize(padded[y0[i]:y1[i], x0[i]:x1[i]], (WIN_W, WIN_H), dst=buf,
                       interpolation=cv2.INTER_LINEAR)
            out[i] = compute(buf).reshape(-1)
        return out

    def score(self, grey: np.ndarray, windows: np.ndarray) -> np.ndarray:
        """SVM margins (N,) float64 of ``windows`` (N, 4) on the grey frame."""
        d = self.descriptors(grey, windows)
        if len(d) == 0:
            return np.zeros(0)
        # einsum, not ``@``: a BLAS gemv this small gains nothing from threads, and OpenBLAS's
        # spinning worker threads then slowed the OpenCV calls after it ~3x on a 2-core machine
        return np.einsum("ij,j->i", d, self.weights).astype(np.float64) + self.bias


def sliding_window_count(width: int, height: int, *, win_stride=(8, 8), padding=(8, 8),
                         scale: float = 1.05, upscale: float = 1.0,
                         resize_to: int | None = None, nlevels: int = 64) -> int:
    """Windows OpenCV's ``HOGDescriptor.detectMultiScale`` scores on a ``width``×``height`` frame
    with these settings (the pyramid and the window grid of ``HOGDescriptor::detect``), after
    :class:`~pfscope.trackers.detect.hog.HOGPeopleDetector`'s ``upscale``/``resize_to``."""
    s = upscale
    if resize_to is not None and width * s > resize_to:
        s = resize_to / width
    W, H = int(round(width * s)), int(round(height * s))
    total, level_scale = 0, 1.0
    for _ in range(nlevels):
        sw, sh = int(round(W / level_scale)), int(round(H / level_scale))
        if sw < WIN_W or sh < WIN_H:
            break
        pw, ph = sw + 2 * padding[0], sh + 2 * padding[1]
        total += ((pw - WIN_W) // win_stride[0] + 1) * ((ph - WIN_H) // win_stride[1] + 1)
        level_scale *= scale
    return total


__all__ = ["HOGWindowClassifier", "window_boxes", "person_boxes", "sliding_window_count",
           "WIN_W", "WIN_H"]
