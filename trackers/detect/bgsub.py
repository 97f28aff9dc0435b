"""Background-subtraction blobs: foreground mask -> morphology -> connected components -> boxes.

feng2015 §II-B draws new-born targets from background subtraction and notes that the raw
foreground is full of "salt and pepper" noise; maggio2007 §4 feeds its people sequences with a
colour change detector.  feng2015 uses a codebook model (its ref. [11]), which OpenCV does not
ship; this module uses OpenCV's per-pixel mixture-of-Gaussians (MOG2, Zivkovic 2004/2006) or
K-nearest-neighbours (KNN, Zivkovic & van der Heijden 2006) models, which share the codebook's
useful properties here: adaptive, multi-modal, with shadow detection.

Per frame (all OpenCV/numpy array operations, no loop over pixels):

1. ``apply`` the background model -> mask with 255 = foreground, 127 = shadow, 0 = background;
2. drop shadows (keep only 255): cast shadows would glue people to their shadows;
3. morphological opening then closing with an ``morph_kernel`` ellipse: opening removes the
   salt-and-pepper specks feng2015 §II-B warns about, closing fills holes inside a person;
4. ``cv2.connectedComponentsWithStats`` (8-connected); a component is a detection if it has at
   least ``min_area`` foreground pixels.

Score: the component's fill ratio, foreground pixels / box area, in (0, 1].  A compact blob
(a person, a car) fills much of its box; thin streaks of noise or lighting edges do not.

The detector is stateful (the background model): use one instance per sequence.  During the
first ``warmup`` frames it only learns the background and reports nothing.  With the automatic
learning rate 1/min(2n, history) the model adapts fast at first: after n frames, a pixel covered
by an object for about 0.2·n frames is already absorbed into the MOG2 background (the new mode's
weight passes 1 − backgroundRatio = 0.1), so objects present from the start show only their
leading edges until n is a few times their dwell time; ``warmup`` hides that phase.  A frame
whose foreground covers more than ``max_foreground`` of the image reports nothing (see ``__call__``).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError
from ..types import Detections, Frame
from ._common import check_image, positive, to_bgr

_WHO = "bgsub detector"
METHODS = ("mog2", "knn")
FOREGROUND = 255  # OpenCV's foreground label in the mask; shadows are 127 (getShadowValue)


class BackgroundSubtractionDetector:
    """Foreground blobs from an adaptive background model.

    method: ``"mog2"`` or ``"knn"``; history: frames the model remembers (OpenCV default 500,
    here 200 so a stopped person fades into the background within ~30 s at 7 fps);
    var_threshold: MOG2 squared Mahalanobis distance for "matches the background" (16 = 4 sigma);
    dist2_threshold: the KNN equivalent (squared distance, OpenCV default 400);
    learning_rate: model update rate per frame in [0, 1], or -1 for OpenCV's automatic
    1/min(2·frames, history); min_area: smallest blob in foreground pixels; morph_kernel:
    ellipse diameter for opening/closing (0 or 1: no morphology); detect_shadows: let the model
    label shadows (which are then dropped); warmup: frames that only train the model;
    connectivity: 4 or 8; max_foreground: if the cleaned mask covers more than this fraction of
    the image, the frame reports nothing (1.0: never).
    """

    name = "bgsub"

    def __init__(self, method: str = "mog2", history: int = 200, var_threshold: float = 16.0,
                 learning_rate: float = -1.0, min_area: int = 200, morph_kernel: int = 5,
                 detect_shadows: bool = True, warmup: int = 0, dist2_threshold: float = 400.0,
                 connectivity: int = 8, max_foreground: float = 0.5):
        method = str(method).lower()
        if method not in METHODS:
            raise InputError(f"{_WHO}: method must be one of {', '.join(METHODS)}, got {method!r}")
        self.method = method
        self.history = _int_at_least(history, 1, "history")
        self.var_threshold = positive(var_threshold, "var_threshold", _WHO)
        self.dist2_threshold = positive(dist2_threshold, "dist2_threshold", _WHO)
        try:
            lr = float(learning_rate)
        except (TypeError, ValueError):
            raise InputError(f"{_WHO}: learning_rate must be a number, got {learning_rate!r}") from None
        if not (lr == -1.0 or 0.0 <= lr <= 1.0):
            raise InputError(f"{_WHO}: learning_rate must be in [0, 1] or -1 (automatic), "
                             f"got {learning_rate!r}")
        self.learning_rate = lr
        self.min_area = _int_at_least(min_area, 1, "min_area")
        self.morph_kernel = _int_at_least(morph_kernel, 0, "morph_kernel")
        self.detect_shadows = bool(detect_shadows)
        self.warmup = _int_at_least(warmup, 0, "warmup")
        self.connectivity = int(connectivity) if connectivity in (4, 8) else None
        if self.connectivity is None:
            raise InputError(f"{_WHO}: connectivity must be 4 or 8, got {connectivity!r}")
        try:
            self.max_foreground = float(max_foreground)
        except (TypeError, ValueError):
            self.max_foreground = float("nan")
        if not 0.0 < self.max_foreground <= 1.0:
            raise InputError(f"{_WHO}: max_foreground must be a fraction in (0, 1], "
                             f"got {max_foreground!r}")
        self._kernel = (None if self.morph_kernel <= 1 else
                        cv2.getStructuringElement(cv2.MORPH_ELLIPSE,
                                                  (self.morph_kernel, self.morph_kernel)))
        self.reset()

    def reset(self) -> None:
        """Forget the background model (start of a new sequence)."""
        if self.method == "mog2":
            self._model = cv2.createBackgroundSubtractorMOG2(
                history=self.history, varThreshold=self.var_threshold,
                detectShadows=self.detect_shadows)
        else:
            self._model = cv2.createBackgroundSubtractorKNN(
                history=self.history, dist2Threshold=self.dist2_threshold,
                detectShadows=self.detect_shadows)
        self._shape: tuple[int, int] | None = None
        self.frames_seen = 0
        self.last_mask: np.ndarray | None = None  # cleaned foreground mask of the last frame

    def foreground(self, frame: Frame) -> np.ndarray:
        """Update the model with ``frame``; return the cleaned (H, W) uint8 mask (255 = blob)."""
        img = to_bgr(check_image(frame, _WHO))
        shape = img.shape[:2]
        if self._shape is None:
            self._shape = shape
        elif shape != self._shape:
            raise InputError(f"frame {frame.index}: {_WHO}: image is {shape[1]}x{shape[0]} but the "
                             f"background model is {self._shape[1]}x{self._shape[0]} "
                             f"(use one detector per sequence)")
        raw = self._model.apply(img, learningRate=self.learning_rate)
        self.frames_seen += 1
        # step 2: keep confident foreground only; shadows (127) and background (0) go
        mask = np.where(raw == FOREGROUND, np.uint8(255), np.uint8(0))
        if self._kernel is not None:
            # step 3: opening kills specks smaller than the kernel, closing fills small holes
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._kernel)
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._kernel)
        self.last_mask = mask
        return mask

    def __call__(self, frame: Frame) -> Detections:
        mask = self.foreground(frame)
        if self.frames_seen <= self.warmup:
            return Detections.empty()
        if np.count_nonzero(mask) > self.max_foreground * mask.size:
            # Not a target but a model that does not hold the background: KNN labels every
            # pixel foreground for its first ~4 frames, and a global lighting change or camera
            # motion does the same later.  One frame-sized blob would only mislead a tracker.
            return Detections.empty()
        n, _labels, stats, _centroids = cv2.connectedComponentsWithStats(
            mask, connectivity=self.connectivity, ltype=cv2.CV_32S)
        stats = stats[1:n].astype(np.float64)  # row 0 is the background component
        area = stats[:, cv2.CC_STAT_AREA]
        keep = area >= self.min_area
        boxes = stats[keep][:, [cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP,
                                cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT]]
        fill = area[keep] / (boxes[:, 2] * boxes[:, 3])
        order = np.argsort(-area[keep], kind="stable")  # biggest blob first
        return Detections(boxes[order], fill[order])

    def __repr__(self) -> str:
        thr = (f"var_threshold={self.var_threshold}" if self.method == "mog2"
               else f"dist2_threshold={self.dist2_threshold}")
        return (f"BackgroundSubtractionDetector(method={self.method!r}, history={self.history}, "
                f"{thr}, learning_rate={self.learning_rate}, min_area={self.min_area}, "
                f"morph_kernel={self.morph_kernel}, detect_shadows={self.detect_shadows}, "
                f"warmup={self.warmup})")


def _int_at_least(value, minimum: int, name: str) -> int:
    try:
        v = int(value)
        if v != float(value):
            raise ValueError
    except (TypeError, ValueError):
        raise InputError(f"{_WHO}: {name} must be an integer, got {value!r}") from None
    if v < minimum:
        raise InputError(f"{_WHO}: {name} must be >= {minimum}, got {value!r}")
    return v
