"""Frontal-face detector: the Viola–Jones boosted Haar cascade shipped with OpenCV.

maggio2007 §4 feeds its face sequences with "face detections generated with an Adaboost
classifier [12]" (Viola & Jones, CVPR 2001).  This module runs OpenCV's
``haarcascade_frontalface_default.xml`` (Lienhart's extended Haar features, 24x24 base window)
over a scale pyramid with ``detectMultiScale3``.

Scores: with ``outputRejectLevels=True`` OpenCV returns, for each grouped detection, the sum of
the weak-classifier votes of the last cascade stage ("level weight"); higher means the window
cleared the final stage threshold by more.  They are unbounded, like the paper's detector output
which maggio2007 does not use beyond the box.

Small faces: the base window is 24x24 pixels, so faces smaller than that are invisible at native
size (OTB-Girl is 128x96 with ~30x40 faces).  ``upscale`` enlarges the grey image before
detection and the boxes are mapped back to original pixels; ``min_size``/``max_size`` are given
in original pixels.  On OTB-Girl (every 5th frame) the face is found in 52% of frames at native
size and 60% with ``upscale=2`` (most misses are turned or occluded faces), at ~3 vs ~20 ms/frame.
"""

from __future__ import annotations

import os

import cv2
import numpy as np

from ..errors import InputError
from ..types import Detections, Frame
from ._common import check_image, int_pair, positive, resize, to_gray

_WHO = "haar detector"
CASCADE = "haarcascade_frontalface_default.xml"


def default_cascade_path() -> str:
    """Path of the frontal-face cascade that ships with opencv-python."""
    return os.path.join(cv2.data.haarcascades, CASCADE)


class HaarFaceDetector:
    """Viola–Jones face detector.

    scale_factor: pyramid step (> 1); min_neighbors: overlapping raw hits a detection needs
    (OpenCV's grouping); min_size / max_size: face size limits in original pixels (max None: no
    limit); upscale: enlargement before detection (boxes mapped back); equalize: histogram
    equalisation of the grey image first (off by default: the cascade already normalises each
    window's variance, and on OTB-Girl equalising halves the hit rate); cascade_path: another
    cascade XML (default: OpenCV's frontal face).
    """

    name = "haar"

    def __init__(self, scale_factor: float = 1.1, min_neighbors: int = 4, min_size=(12, 12),
                 max_size=None, upscale: float = 1.0, equalize: bool = False,
                 cascade_path: str | os.PathLike | None = None):
        self.scale_factor = positive(scale_factor, "scale_factor", _WHO)
        if self.scale_factor <= 1.0:
            raise InputError(f"{_WHO}: scale_factor must be > 1, got {scale_factor!r}")
        try:
            self.min_neighbors = int(min_neighbors)
        except (TypeError, ValueError):
            raise InputError(f"{_WHO}: min_neighbors must be an integer, got {min_neighbors!r}") from None
        if self.min_neighbors < 0:
            raise InputError(f"{_WHO}: min_neighbors must be >= 0, got {min_neighbors!r}")
        self.min_size = int_pair(min_size, "min_size", _WHO, minimum=0)
        self.max_size = None if max_size is None else int_pair(max_size, "max_size", _WHO, minimum=1)
        self.upscale = positive(upscale, "upscale", _WHO)
        self.equalize = bool(equalize)
        path = default_cascade_path() if cascade_path is None else os.fspath(cascade_path)
        if not os.path.isfile(path):
            raise InputError(f"{path}: no such cascade file")
        self.cascade_path = path
        self._cascade = cv2.CascadeClassifier(path)
        if self._cascade.empty():
            raise InputError(f"{path}: not a readable OpenCV cascade")

    def __call__(self, frame: Frame) -> Detections:
        gray = to_gray(check_image(frame, _WHO))
        if self.equalize:
            gray = cv2.equalizeHist(gray)
        s = self.upscale
        work = resize(gray, s)
        min_size = (int(round(self.min_size[0] * s)), int(round(self.min_size[1] * s)))
        max_size = ((0, 0) if self.max_size is None
                    else (int(round(self.max_size[0] * s)), int(round(self.max_size[1] * s))))
        rects, _levels, weights = self._cascade.detectMultiScale3(
            work, scaleFactor=self.scale_factor, minNeighbors=self.min_neighbors,
            minSize=min_size, maxSize=max_size, outputRejectLevels=True)
        boxes = np.asarray(rects, dtype=np.float64).reshape(-1, 4) / s
        scores = np.asarray(weights, dtype=np.float64).reshape(-1)
        if len(boxes) == 0:
            return Detections.empty()
        order = np.argsort(-scores, kind="stable")
        return Detections(boxes[order], scores[order])

    def __repr__(self) -> str:
        return (f"HaarFaceDetector(scale_factor={self.scale_factor}, "
                f"min_neighbors={self.min_neighbors}, min_size={self.min_size}, "
                f"max_size={self.max_size}, upscale={self.upscale}, equalize={self.equalize})")
