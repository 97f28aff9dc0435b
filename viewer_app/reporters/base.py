"""The generic reporter: every item of the engine's vocabulary → a Rerun archetype, styled here.

Styling rules (the engine says *what*, this module says *how it looks*):

- semantic roles (detection, ground truth, miss, false positive, ID switch, dropped cluster,
  candidate edge) are class ids of one static ``AnnotationContext`` logged at the root;
- items whose ids are track ids get the track colour of that id (``id_colors``), the same for
  a box, a trail, a vertex, an edge or a per-track child cloud;
- particle weights go through viridis on a per-cloud log scale (yellow = the cloud's
  95th-percentile weight or more, 2 decades down to dark purple), and the scale (that largest weight) is plotted under
  ``plots/weights/<path>``;
- labels are shown only on items whose ids are track ids and carry no values (a track's id);
  every other label (detection scores, gt ids, edge gains, cluster values) is logged but hidden
  (``show_labels=False``: select the entity in the viewer and turn labels on);
- masks are ``SegmentationImage`` with their own class names; dense fields are colormapped
  images;
- labels are built from an item's named ``values`` only for small item counts.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import rerun as rr

from pfscope.trackers.report import (Boxes, Event, Field, Mask, Points, Scalar, Segments, Stage)

from ..colors import id_colors, ramp, weight_colors

#: Semantic class ids of the static AnnotationContext (ids >= 1; 0 is "no class").
#: Disjoint from the track palette (colors.TRACK_HUE_MIN..MAX): greys, white, black, red,
#: magenta (tests/test_viewer_app.py checks it).
ROLES: dict[str, tuple[int, tuple[int, int, int, int]]] = {
    "detection": (1, (175, 175, 175, 220)),
    "gt": (2, (250, 250, 250, 230)),
    "miss": (3, (255, 30, 30, 255)),
    "false_positive": (4, (255, 0, 190, 255)),
    "switch": (5, (0, 0, 0, 255)),
    "dropped": (6, (110, 110, 110, 200)),
    "candidate": (7, (150, 150, 150, 140)),
}
MAX_LABELS = 60
DEFAULT_POINT_RADIUS = 1.5


def annotation_context() -> rr.AnnotationContext:
    return rr.AnnotationContext([rr.AnnotationInfo(id=i, label=name, color=color)
                                 for name, (i, color) in ROLES.items()])


@dataclass(frozen=True)
class TrackerLayout:
    """A tracker's blueprint: ``views`` (title, engine paths) 2D tabs over the video and
    ``plots`` (title, paths) time series.  Paths are the engine's (``phd/particles/**``)."""

    views: tuple[tuple[str, tuple[str, ...]], ...] = (("Tracks", ("tracks/**",)),)
    plots: tuple[tuple[str, tuple[str, ...]], ...] = (("Counts", ("tracks/count",
                                                                  "detections/count")),
                                                      ("Step ms", ("timing/**",)))


def _fmt(v: float) -> str:
    if float(v).is_integer():
        return str(int(v))
    return f"{v:.2f}"


def value_labels(values: dict, n: int, ids: Optional[np.ndarray] = None) -> Optional[list[str]]:
    """``"5: gap=2 log f=-3.10"`` per item; ``[]`` when there are too many to read; None for
    items that never carry labels.  (An entity keeps the same components from frame to frame:
    a component that comes and goes splits its chunks in an order Rerun does not fix, and two
    same-seed recordings would no longer compare equal.)"""
    if not values and ids is None:
        return None
    if n == 0 or n > MAX_LABELS:
        return []
    out = []
    for i in range(n):
        parts = [f"{k}={_fmt(v[i])}" for k, v in values.items()]
        head = f"{int(ids[i])}" if ids is not None else ""
        out.append(" ".join(([head + ":"] if head and parts else [head] if head else []) + parts))
    return out


def _colors(ids: Optional[np.ndarray], id_kind: Optional[str]) -> Optional[np.ndarray]:
    if ids is None:
        return None
    return id_colors(ids)


class Reporter:
    """Logs stage items to ``rec`` under ``root`` (``""`` or ``"<tracker>/"`` in ``compare``).
    Entities logged in a frame are remembered so stale ones can be cleared at the frame's end."""

    def __init__(self, rec: rr.RecordingStream, root: str = "", max_points: int = 3000,
                 jpeg_quality: int = 75):
        self.rec = rec
        self.root = root
        self.max_points = int(max_points)
        self.jpeg_quality = int(jpeg_quality)
        self.logged: set[str] = set()
        self._mask_classes: dict[str, tuple] = {}

    def video(self, path: str) -> str:
        return f"{self.root}video/{path}"

    def _log(self, entity: str, archetype) -> None:
        self.logged.add(entity)
        self.rec.log(entity, archetype)

    def stage(self, stage: Stage) -> None:
        for item in stage.items:
            self.item(item)

    def item(self, item) -> None:
        if isinstance(item, Scalar):
            self.rec.log(f"{self.root}plots/{item.path}", rr.Scalars(item.value))
        elif isinstance(item, Event):
            self.rec.log(f"{self.root}log/{item.path}" if item.path else f"{self.root}log",
                         rr.TextLog(item.message, level=item.severity))
        elif isinstance(item, Points):
            self.points(item)
        elif isinstance(item, Boxes):
            self.boxes(item)
        elif isinstance(item, Segments):
            self.segments(item)
        elif isinstance(item, Mask):
            self.mask(item)
        elif isinstance(item, Field):
            self.field(item)
        else:  # pragma: no cover - StageLog only admits vocabulary items
            raise TypeError(f"unknown report item {type(item).__name__}")

    def points(self, p: Points) -> None:
        xy = p.xy.astype(np.float32)
        colors = (weight_colors(p.weights) if p.weights is not None
                  else _colors(p.ids, p.id_kind))
        n = len(xy)
        if n > self.max_points:  # deterministic stride decimation, no RNG
            keep = np.linspace(0, n - 1, self.max_points).round().astype(np.int64)
            xy = xy[keep]
            colors = None if colors is None else colors[keep]
        class_ids = ROLES[p.role][0] if p.role in ROLES and colors is None else None
        self._log(self.video(p.path), rr.Points2D(xy, colors=colors, class_ids=class_ids,
                                                  radii=DEFAULT_POINT_RADIUS))
        if p.weights is not None:
            top = float(np.max(p.weights)) if len(p.weights) else 0.0
            self.rec.log(f"{self.root}plots/weights/{p.path}", rr.Scalars(top))

    def boxes(self, b: Boxes, radii: float = 1.0) -> None:
        boxes = b.boxes.astype(np.float32)
        colors = _colors(b.ids, b.id_kind) if b.id_kind in ("track", "cluster") else None
        class_ids = ROLES[b.role][0] if b.role in ROLES and colors is None else None
        labels = value_labels(b.values, len(b), b.ids if b.id_kind == "track" else None)
        show = labels is not None and b.id_kind == "track" and not b.values
        self._log(self.video(b.path), rr.Boxes2D(
            mins=boxes[:, :2], sizes=boxes[:, 2:], colors=colors, class_ids=class_ids,
            labels=labels, show_labels=show if labels is not None else None, radii=radii))

    def segments(self, s: Segments) -> None:
        strips = np.stack([s.a, s.b], axis=1).astype(np.float32)
        chosen = s.role is None
        colors = _colors(s.ids, s.id_kind) if chosen else None
        class_ids = ROLES[s.role][0] if s.role in ROLES else None
        labels = value_labels(s.values, len(s), s.ids if s.id_kind == "track" else None) \
            if chosen else None
        self._log(self.video(s.path), rr.LineStrips2D(
            strips, colors=colors, class_ids=class_ids, labels=labels,
            show_labels=False if labels is not None else None,
            radii=1.5 if chosen else 0.5))

    def mask(self, m: Mask) -> None:
        entity = self.video(m.path)
        if self._mask_classes.get(entity) != m.classes:
            palette = id_colors(np.arange(len(m.classes)), alpha=140)
            palette[0, 3] = 0  # background transparent
            self.rec.log(entity, rr.AnnotationContext(
                [rr.AnnotationInfo(id=i, label=c, color=tuple(int(x) for x in palette[i]))
                 for i, c in enumerate(m.classes)]), static=True)
            self._mask_classes[entity] = m.classes
        self._log(entity, rr.SegmentationImage(m.mask))

    def field(self, f: Field) -> None:
        v = f.values
        lo = float(np.nanmin(v)) if f.vmin is None and v.size else (f.vmin or 0.0)
        hi = float(np.nanmax(v)) if f.vmax is None and v.size else (f.vmax or 1.0)
        t = np.clip((v - lo) / (hi - lo), 0, 1) if hi > lo else np.zeros_like(v)
        rgb = ramp(t.reshape(-1), alpha=255)[:, :3].reshape(v.shape + (3,))
        self._log(self.video(f.path), rr.Image(rgb, color_model="RGB").compress(
            jpeg_quality=self.jpeg_quality))
        self.rec.log(f"{self.root}plots/{f.path}/max", rr.Scalars(hi))

    def track_boxes(self, path: str, ids: np.ndarray, boxes: np.ndarray) -> None:
        boxes = np.asarray(boxes, dtype=np.float32).reshape(-1, 4)
        self._log(self.video(path), rr.Boxes2D(
            mins=boxes[:, :2], sizes=boxes[:, 2:], colors=id_colors(ids),
            labels=[str(int(i)) for i in ids], radii=2.0))

    def track_strips(self, path: str, ids: np.ndarray, strips: list) -> None:
        self._log(self.video(path), rr.LineStrips2D(
            [np.asarray(s, dtype=np.float32) for s in strips], colors=id_colors(ids), radii=1.0))

    def role_boxes(self, path: str, boxes: np.ndarray, role: str,
                   labels: Optional[list[str]] = None, radii: float = 1.0) -> None:
        boxes = np.asarray(boxes, dtype=np.float32).reshape(-1, 4)
        self._log(self.video(path), rr.Boxes2D(
            mins=boxes[:, :2], sizes=boxes[:, 2:], class_ids=np.full(len(boxes), ROLES[role][0]),
            labels=(labels if len(boxes) <= MAX_LABELS else []) if labels is not None else None,
            show_labels=False if labels is not None else None, radii=radii))

    def scalar(self, path: str, value: float) -> None:
        self.rec.log(f"{self.root}plots/{path}", rr.Scalars(float(value)))

    def text(self, path: str, message: str, level: str = "INFO") -> None:
        self.rec.log(f"{self.root}log/{path}" if path else f"{self.root}log",
                     rr.TextLog(message, level=level))


__all__ = ["Reporter", "TrackerLayout", "ROLES", "annotation_context", "value_labels"]
