"""Checks and conversions shared by the image detectors (no paper: plumbing).

Every detector checks its frame once here, at the boundary, so that a bad image gives a one-line
:class:`~trackers.errors.InputError` naming the frame instead of an OpenCV assertion deep inside.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError
from ..types import Frame


def check_image(frame: Frame, who: str) -> np.ndarray:
    """Return ``frame.image`` if it is an ``(H, W, 3)`` BGR or ``(H, W)`` grey uint8 array."""
    img = getattr(frame, "image", None)
    index = getattr(frame, "index", "?")
    if not isinstance(img, np.ndarray):
        raise InputError(f"frame {index}: {who} needs a numpy image, got {type(img).__name__}")
    ok_shape = img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (1, 3))
    if img.dtype != np.uint8 or not ok_shape or img.shape[0] == 0 or img.shape[1] == 0:
        raise InputError(f"frame {index}: {who} needs an (H, W, 3) uint8 BGR image, "
                         f"got {img.dtype} array of shape {img.shape}")
    return img


def to_gray(img: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey version of a checked image (no copy when it already is grey)."""
    if img.ndim == 2:
        return img
    if img.shape[2] == 1:
        return img[:, :, 0]
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


def to_bgr(img: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 BGR version of a checked image."""
    if img.ndim == 3 and img.shape[2] == 3:
        return img
    return cv2.cvtColor(img.reshape(img.shape[0], img.shape[1]), cv2.COLOR_GRAY2BGR)


def resize(img: np.ndarray, factor: float) -> np.ndarray:
    """Scale ``img`` by ``factor`` (bilinear up, area-averaging down); identity for 1."""
    if factor == 1.0:
        return img
    interp = cv2.INTER_LINEAR if factor > 1.0 else cv2.INTER_AREA
    h, w = img.shape[:2]
    size = (max(1, int(round(w * factor))), max(1, int(round(h * factor))))
    return cv2.resize(img, size, interpolation=interp)


def positive(value, name: str, who: str) -> float:
    """``float(value)`` if it is finite and > 0, else a one-line InputError."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{who}: {name} must be a number, got {value!r}") from None
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"{who}: {name} must be a positive number, got {value!r}")
    return v


def int_pair(value, name: str, who: str, *, minimum: int = 0) -> tuple[int, int]:
    """``(a, b)`` ints >= ``minimum`` from a pair (or one int used twice)."""
    try:
        arr = np.broadcast_to(np.asarray(value), (2,))
        a, b = (int(v) for v in arr)
        if not np.all(np.asarray(arr, dtype=np.float64) == (a, b)):
            raise ValueError
    except (TypeError, ValueError):
        raise InputError(f"{who}: {name} must be an integer pair like (8, 8), got {value!r}") from None
    if a < minimum or b < minimum:
        raise InputError(f"{who}: {name} must be >= {minimum}, got {value!r}")
    return a, b
