"""Frozen dataclasses of arrays passed between sources, detectors, trackers and the app.

Boxes are always MOT convention: ``(x, y, w, h)`` with ``(x, y)`` the top-left corner, in
pixels, float64.  Frames are numbered like MOTChallenge: the first frame is 1.
Shapes are checked once here, at the boundary.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def _as_boxes(boxes, name: str) -> np.ndarray:
    arr = np.asarray(boxes, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 4), dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"{name}: expected shape (N, 4), got {arr.shape}")
    return arr


def xywh_to_cxcywh(boxes: np.ndarray) -> np.ndarray:
    """(N,4) top-left boxes -> (N,4) centre boxes ``(cx, cy, w, h)``."""
    out = np.array(boxes, dtype=np.float64, copy=True).reshape(-1, 4)
    out[:, :2] += out[:, 2:] / 2.0      # (both columns in one operation: the same floats)
    return out


def cxcywh_to_xywh(boxes: np.ndarray) -> np.ndarray:
    """(N,4) centre boxes ``(cx, cy, w, h)`` -> (N,4) top-left boxes."""
    out = np.array(boxes, dtype=np.float64, copy=True).reshape(-1, 4)
    out[:, :2] -= out[:, 2:] / 2.0
    return out


@dataclass(frozen=True)
class Frame:
    """One video frame.

    index: MOT frame number (1-based).
    timestamp: seconds since the start of the sequence.
    image: (H, W, 3) uint8, **BGR** (OpenCV order).
    """

    index: int
    timestamp: float
    image: np.ndarray

    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def has_pixels(self) -> bool:
        """Whether :attr:`image` holds real pixels, not a :func:`blank_image` stand-in (which
        only gives the frame its size)."""
        im = self.image
        return (im is not None and getattr(im, "ndim", 0) == 3 and im.size > 0
                and 0 not in im.strides)


def blank_image(height: int, width: int) -> np.ndarray:
    """A black (height, width, 3) uint8 image that takes no memory (a read-only zero-stride
    view): what a frame carries when nothing decodes its pixels (the tuner and the
    detections-only benchmarks, for trackers that do not read them); ``Frame.has_pixels`` is
    False for it."""
    return np.broadcast_to(np.zeros((1, 1, 3), np.uint8), (int(height), int(width), 3))


@dataclass(frozen=True)
class Detections:
    """Detector output for one frame.

    boxes: (N, 4) float64 ``(x, y, w, h)`` top-left; scores: (N,) float64.
    """

    boxes: np.ndarray
    scores: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self):
        boxes = _as_boxes(self.boxes, "Detections.boxes")
        scores = (np.ones(len(boxes)) if self.scores is None
                  else np.asarray(self.scores, dtype=np.float64).reshape(-1))
        if len(scores) != len(boxes):
            raise ValueError(f"Detections: {len(boxes)} boxes but {len(scores)} scores")
        object.__setattr__(self, "boxes", boxes)
        object.__setattr__(self, "scores", scores)

    @classmethod
    def empty(cls) -> "Detections":
        return cls(np.zeros((0, 4)), np.zeros(0))

    def __len__(self) -> int:
        return len(self.boxes)

    @property
    def centers(self) -> np.ndarray:
        """(N, 2) box centres."""
        return self.boxes[:, :2] + self.boxes[:, 2:] / 2.0

    def observations(self) -> np.ndarray:
        """(N, 4) observation vectors ``z = (y1, y2, w, h)`` (centre + size) as in maggio2007 §2."""
        return xywh_to_cxcywh(self.boxes)

    def select(self, mask) -> "Detections":
        return Detections(self.boxes[mask], self.scores[mask])


@dataclass(frozen=True)
class TrackSet:
    """Tracker output for one frame: the confirmed targets and their identities.

    ids: (M,) int64; boxes: (M, 4) float64 ``(x, y, w, h)``; conf: None (not given: the tracks
    file's conf column is -1) or (M,) float64 per-row flags for that column (PHD-MT / MT with
    ``fill_gaps``: 1.0 an estimate, 0.5 a box interpolated inside a linked gap).
    """

    ids: np.ndarray
    boxes: np.ndarray
    conf: np.ndarray | None = None

    def __post_init__(self):
        boxes = _as_boxes(self.boxes, "TrackSet.boxes")
        ids = np.asarray(self.ids, dtype=np.int64).reshape(-1)
        if len(ids) != len(boxes):
            raise ValueError(f"TrackSet: {len(boxes)} boxes but {len(ids)} ids")
        object.__setattr__(self, "boxes", boxes)
        object.__setattr__(self, "ids", ids)
        if self.conf is not None:
            conf = np.asarray(self.conf, dtype=np.float64).reshape(-1)
            if len(conf) != len(ids):
                raise ValueError(f"TrackSet: {len(ids)} ids but {len(conf)} conf values")
            object.__setattr__(self, "conf", conf)

    @classmethod
    def of(cls, ids: np.ndarray, boxes: np.ndarray, conf: np.ndarray | None = None) -> "TrackSet":
        """A TrackSet of arrays already in their final form -- ``ids`` (M,) int64, ``boxes``
        (M, 4) float64, ``conf`` None or (M,) float64 -- taken as given, without the
        constructor's conversions and checks (a tracker's own output, built every frame)."""
        ts = object.__new__(cls)
        ts.__dict__.update(ids=ids, boxes=boxes, conf=conf)
        return ts

    @classmethod
    def empty(cls) -> "TrackSet":
        return cls(np.zeros(0, dtype=np.int64), np.zeros((0, 4)))

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class GroundTruth:
    """Ground truth of one frame. ``ignore`` marks ``conf=0`` boxes (MOT15 "ambiguous", MOT16+
    "not to be scored"); ``cls`` holds the MOT16+ class ids (1 pedestrian, 2 person on vehicle,
    ... 13 crowd) when the gt file has them, else None (MOT15 layout: no classes)."""

    ids: np.ndarray
    boxes: np.ndarray
    ignore: np.ndarray = field(default=None)  # type: ignore[assignment]
    cls: np.ndarray | None = None

    def __post_init__(self):
        boxes = _as_boxes(self.boxes, "GroundTruth.boxes")
        ids = np.asarray(self.ids, dtype=np.int64).reshape(-1)
        ignore = (np.zeros(len(ids), dtype=bool) if self.ignore is None
                  else np.asarray(self.ignore, dtype=bool).reshape(-1))
        cls = None if self.cls is None else np.asarray(self.cls, dtype=np.int64).reshape(-1)
        if not (len(ids) == len(boxes) == len(ignore) == (len(ids) if cls is None else len(cls))):
            raise ValueError("GroundTruth: ids, boxes, ignore and cls differ in length")
        object.__setattr__(self, "boxes", boxes)
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "ignore", ignore)
        object.__setattr__(self, "cls", cls)

    @classmethod
    def empty(cls) -> "GroundTruth":
        return cls(np.zeros(0, dtype=np.int64), np.zeros((0, 4)), np.zeros(0, dtype=bool))

    def __len__(self) -> int:
        return len(self.ids)
