"""OpenCV's HOG + linear-SVM people detector (Dalal & Triggs, CVPR 2005).

jung2013 §2.1 detects pedestrians at each parent particle with a HOG classifier trained by an
intersection-kernel SVM (Maji et al. 2008); OpenCV ships no IKSVM model, so this module uses the
linear-SVM pedestrian model of Dalal & Triggs that OpenCV ships
(``cv2.HOGDescriptor_getDefaultPeopleDetector``), run densely over a scale pyramid.

Pipeline for one frame:

1. optional resize: ``upscale`` enlarges small people (the model's 64x128 window holds a person
   about 32x96 pixels, so PETS09 people of ~75 px are missed at native size), ``resize_to``
   caps the working width for speed;
2. ``detectMultiScale`` with ``groupThreshold=0``: every window whose SVM score exceeds
   ``hit_threshold`` (the score is the signed distance ``w·x + b`` of the linear SVM);
3. non-maximum suppression by IoU (``cv2.dnn.NMSBoxes``) instead of OpenCV's rectangle grouping,
   so each kept box carries its own SVM score;
4. boxes mapped back to the original image and trimmed by ``window_margin``: Dalal & Triggs
   (§6, "Detector Window and Context") train the 64x128 window with about 16 pixels of context
   on every side of the person, i.e. 16/64 of the width and 16/128 of the height per side.
   Trimming it makes the box a person box, like MOT ground truth.

Scores are SVM margins (unbounded, > ``hit_threshold``), higher is more confident.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError
from ..types import Detections, Frame
from ._common import check_image, int_pair, positive, resize, to_bgr

_WHO = "hog detector"


class HOGPeopleDetector:
    """Dalal–Triggs HOG pedestrian detector with IoU non-maximum suppression.

    win_stride: window step in pixels (x, y) on each pyramid level; padding: image border added
    before scanning; scale: pyramid step (> 1); hit_threshold: SVM score a window must exceed;
    nms_iou: IoU above which a lower-scored box is suppressed (>= 1 disables NMS);
    resize_to: maximum working width in pixels (None: no cap); upscale: enlargement applied
    before the cap; window_margin: fraction of the window width/height trimmed on each side
    (Dalal & Triggs' context border; (0, 0) returns the raw windows).
    """

    name = "hog"

    def __init__(self, win_stride=(8, 8), padding=(8, 8), scale: float = 1.05,
                 hit_threshold: float = 0.0, nms_iou: float = 0.5, resize_to: int | None = None,
                 upscale: float = 1.0, window_margin=(0.25, 0.125)):
        self.win_stride = int_pair(win_stride, "win_stride", _WHO, minimum=1)
        self.padding = int_pair(padding, "padding", _WHO, minimum=0)
        self.scale = positive(scale, "scale", _WHO)
        if self.scale <= 1.0:
            raise InputError(f"{_WHO}: scale (pyramid step) must be > 1, got {scale!r}")
        try:
            self.hit_threshold = float(hit_threshold)
        except (TypeError, ValueError):
            raise InputError(f"{_WHO}: hit_threshold must be a number, got {hit_threshold!r}") from None
        if not np.isfinite(self.hit_threshold):
            raise InputError(f"{_WHO}: hit_threshold must be finite, got {hit_threshold!r}")
        self.nms_iou = positive(nms_iou, "nms_iou", _WHO)
        self.resize_to = None if resize_to is None else int(positive(resize_to, "resize_to", _WHO))
        self.upscale = positive(upscale, "upscale", _WHO)
        try:
            mx, my = (float(v) for v in np.broadcast_to(np.asarray(window_margin, float), (2,)))
        except (TypeError, ValueError):
            raise InputError(f"{_WHO}: window_margin must be a pair of fractions, "
                             f"got {window_margin!r}") from None
        if not (0.0 <= mx < 0.5 and 0.0 <= my < 0.5):
            raise InputError(f"{_WHO}: window_margin fractions must be in [0, 0.5), "
                             f"got {window_margin!r}")
        self.window_margin = (mx, my)
        self._hog = cv2.HOGDescriptor()
        self._hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())

    def working_scale(self, width: int) -> float:
        """Factor from original to working image: ``upscale``, capped at ``resize_to`` wide."""
        s = self.upscale
        if self.resize_to is not None and width * s > self.resize_to:
            s = self.resize_to / width
        return s

    def __call__(self, frame: Frame) -> Detections:
        img = to_bgr(check_image(frame, _WHO))
        s = self.working_scale(img.shape[1])
        work = resize(img, s)
        win_w, win_h = self._hog.winSize
        if work.shape[0] < win_h or work.shape[1] < win_w:
            return Detections.empty()  # smaller than one detection window: nothing to find
        rects, weights = self._hog.detectMultiScale(
            work, hitThreshold=self.hit_threshold, winStride=self.win_stride,
            padding=self.padding, scale=self.scale, groupThreshold=0)
        boxes = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
        scores = np.asarray(weights, dtype=np.float64).reshape(-1)
        if len(boxes) == 0:
            return Detections.empty()
        if self.nms_iou < 1.0:
            # The SVM already applied hit_threshold; NMSBoxes wants a threshold >= 0 and keeps
            # scores strictly above it, so rank on scores shifted to >= 1 (order unchanged).
            shifted = scores - scores.min() + 1.0
            keep = np.asarray(cv2.dnn.NMSBoxes(boxes.tolist(), shifted.tolist(), 0.0, self.nms_iou),
                              dtype=np.int64).reshape(-1)
            boxes, scores = boxes[keep], scores[keep]
        boxes /= s  # back to original pixels
        mx, my = self.window_margin
        boxes[:, 0] += mx * boxes[:, 2]
        boxes[:, 1] += my * boxes[:, 3]
        boxes[:, 2] *= 1.0 - 2.0 * mx
        boxes[:, 3] *= 1.0 - 2.0 * my
        order = np.argsort(-scores, kind="stable")
        return Detections(boxes[order], scores[order])

    def __repr__(self) -> str:
        return (f"HOGPeopleDetector(win_stride={self.win_stride}, padding={self.padding}, "
                f"scale={self.scale}, hit_threshold={self.hit_threshold}, nms_iou={self.nms_iou}, "
                f"resize_to={self.resize_to}, upscale={self.upscale}, "
                f"window_margin={self.window_margin})")
