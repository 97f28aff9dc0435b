"""The Rerun observer: turns the engine's observer calls into a Rerun recording.

Entity layout (all 2D overlays share the image's pixel space under ``video``):

- ``video``                  the frame, JPEG-compressed
- ``video/<path>``           points / boxes / segments / strips the engine reports
  (``video/detections``, ``video/gt``, ``video/tracks``, ``video/phd/particles/updated`` ...)
- ``plots/<path>``           scalars (``plots/phd/mass`` ...) for the time-series view
- ``log``                    text messages

Timelines: ``frame`` (MOT frame number), ``time`` (the video's time, a duration) and
``stage`` (``frame * len(STAGES) + stage index``) to step through the stages inside one frame.

Levels (``tracks`` < ``clusters`` < ``particles``) gate what the engine builds, and point
clouds above ``max_points`` are decimated with a fixed stride (deterministic, no RNG), so
files stay small.  Entities that a frame did not log are cleared at the end of the frame, so
the viewer never shows a stale cloud from an earlier frame.
"""

from __future__ import annotations

import time
import uuid
from typing import Iterable, Optional, Sequence

import cv2
import numpy as np
import rerun as rr

from pfscope.trackers.observer import LEVELS, STAGES, level_rank
from pfscope.trackers.types import Frame

from .colors import id_colors, weight_colors

# Fixed colours for the app's own overlays (RGBA).
STYLE = {
    "detections": (255, 220, 0, 255),
    "gt": (60, 255, 60, 255),
}
DEFAULT_POINT_RADIUS = 1.5


def recording_id_for(config: dict) -> str:
    """A recording id derived from the run's configuration, so the same seed and input give a
    byte-for-byte comparable recording (``rerun rrd compare``)."""
    return str(uuid.uuid5(uuid.NAMESPACE_URL, "pfscope:" + repr(sorted(config.items()))))


class RerunObserver:
    """Implements :class:`trackers.observer.Observer` on top of a ``rr.RecordingStream``."""

    def __init__(self, rec: rr.RecordingStream, *, level: str = "clusters",
                 max_points: int = 3000, jpeg_quality: int = 75, root: str = "",
                 flush_seconds: float = 1.0):
        level_rank(level)  # validate
        self.rec = rec
        self.flush_seconds = float(flush_seconds)
        self._last_flush = time.monotonic()
        # Several trackers in one recording each get a root: <root>/video/..., <root>/plots/...
        self.root = f"{root.strip('/')}/" if root else ""
        self.level = level
        self._rank = level_rank(level)
        self.max_points = int(max_points)
        self.jpeg_quality = int(jpeg_quality)
        self.frame_index = 0
        self._logged_now: set[str] = set()
        self._logged_before: set[str] = set()
        self._stage_names: dict[str, int] = {s: i for i, s in enumerate(STAGES)}

    # -- frame bookkeeping -------------------------------------------------------------
    def begin_frame(self, frame: Frame, image: bool = True) -> None:
        self.frame_index = frame.index
        self.rec.set_time("frame", sequence=frame.index)
        self.rec.set_time("time", duration=float(frame.timestamp))
        self.stage("input")
        if not image:
            return
        ok, buf = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if ok:
            self.rec.log("video", rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg"))

    def end_frame(self) -> None:
        self.stage("output")
        for ent in sorted(self._logged_before - self._logged_now):
            self.rec.log(ent, rr.Clear(recursive=False))
        self._logged_before = self._logged_now
        self._logged_now = set()
        # Flushing bounds what a killed run (SIGKILL) can lose to `flush_seconds` of frames;
        # flushing every frame would split every entity into its own chunk per frame (~1.8 KB
        # of framing each, a third of a tracks-level file).
        now = time.monotonic()
        if now - self._last_flush >= self.flush_seconds:
            self.rec.flush()
            self._last_flush = now

    # -- Observer protocol ----------------------------------------------------------
    def wants(self, level: str) -> bool:
        return level_rank(level) <= self._rank

    def stage(self, name: str) -> None:
        idx = self._stage_names.get(name)
        if idx is None:
            idx = self._stage_names[name] = len(self._stage_names)
        stride = max(len(STAGES), len(self._stage_names))
        self.rec.set_time("stage", sequence=self.frame_index * stride + idx)

    def _log(self, entity: str, archetype) -> None:
        self._logged_now.add(entity)
        self.rec.log(entity, archetype)

    def points(self, path: str, xy: np.ndarray, *, weights: Optional[np.ndarray] = None,
               class_ids: Optional[np.ndarray] = None, labels: Optional[Sequence[str]] = None,
               radii=None, colors: Optional[np.ndarray] = None) -> None:
        xy = np.asarray(xy, dtype=np.float32).reshape(-1, 2)
        n = len(xy)
        if colors is None:
            if weights is not None:
                colors = weight_colors(weights)
            elif class_ids is not None:
                colors = id_colors(class_ids)
        if n > self.max_points:
            keep = np.linspace(0, n - 1, self.max_points).round().astype(np.int64)
            xy = xy[keep]
            colors = None if colors is None else np.asarray(colors)[keep]
            labels = None if labels is None else [labels[i] for i in keep]
            if radii is not None and np.ndim(radii) > 0:
                radii = np.asarray(radii)[keep]
        self._log(f"{self.root}video/{path}", rr.Points2D(
            xy, colors=colors, labels=labels,
            radii=DEFAULT_POINT_RADIUS if radii is None else radii))

    def boxes(self, path: str, boxes: np.ndarray, *, ids: Optional[np.ndarray] = None,
              labels: Optional[Sequence[str]] = None, class_ids: Optional[np.ndarray] = None,
              colors: Optional[np.ndarray] = None, radii=None) -> None:
        boxes = np.asarray(boxes, dtype=np.float32).reshape(-1, 4)
        if colors is None:
            if ids is not None:
                colors = id_colors(ids)
            elif class_ids is not None:
                colors = id_colors(class_ids)
            else:
                colors = STYLE.get(path.split("/")[0], (255, 255, 255, 255))
        if labels is None and ids is not None:
            labels = [str(int(i)) for i in np.asarray(ids).reshape(-1)]
        self._log(f"{self.root}video/{path}", rr.Boxes2D(
            mins=boxes[:, :2], sizes=boxes[:, 2:], colors=colors, labels=labels,
            radii=radii if radii is not None else 1.0))

    def segments(self, path: str, a: np.ndarray, b: np.ndarray, *,
                 class_ids: Optional[np.ndarray] = None, labels: Optional[Sequence[str]] = None,
                 radii=None, colors: Optional[np.ndarray] = None) -> None:
        a = np.asarray(a, dtype=np.float32).reshape(-1, 2)
        b = np.asarray(b, dtype=np.float32).reshape(-1, 2)
        strips = np.stack([a, b], axis=1)
        if colors is None and class_ids is not None:
            colors = id_colors(class_ids)
        self._log(f"{self.root}video/{path}", rr.LineStrips2D(
            strips, colors=colors, labels=labels, radii=0.75 if radii is None else radii))

    def strips(self, path: str, strips: Iterable[np.ndarray], *, ids: Optional[np.ndarray] = None,
               radii=None, colors: Optional[np.ndarray] = None) -> None:
        strips = [np.asarray(s, dtype=np.float32).reshape(-1, 2) for s in strips]
        if colors is None and ids is not None:
            colors = id_colors(ids)
        self._log(f"{self.root}video/{path}", rr.LineStrips2D(
            strips, colors=colors, radii=1.0 if radii is None else radii))

    def scalar(self, path: str, value: float) -> None:
        self.rec.log(f"{self.root}plots/{path}", rr.Scalars(float(value)))

    def text(self, path: str, message: str, level: str = "INFO") -> None:
        self.rec.log(f"{self.root}log/{path}" if path else f"{self.root}log",
                     rr.TextLog(message, level=level))

    def image(self, path: str, image_bgr: np.ndarray) -> None:
        img = np.ascontiguousarray(image_bgr[..., ::-1]) if image_bgr.ndim == 3 else image_bgr
        model = "RGB" if img.ndim == 3 else "L"
        self._log(f"{self.root}video/{path}", rr.Image(img, color_model=model).compress(
            jpeg_quality=self.jpeg_quality))


__all__ = ["RerunObserver", "recording_id_for", "LEVELS"]
