"""The generic reporter: every item of the engine's vocabulary → a Rerun archetype, styled here.

Styling rules (the engine says *what*, this module says *how it looks*):

- semantic roles (detection, ground truth, miss, false positive, ID switch, dropped cluster,
  candidate edge) are class ids of one static ``AnnotationContext`` logged at the root;
- items whose ids are track ids get the track colour of that id (``id_colors``), the same for
  a box, a trail, a vertex, an edge or a per-track child cloud;
- particle weights go through viridis by rank within their cloud (dark purple = the lightest,
  yellow = the heaviest tenth, equal weights all teal), radius and opacity grow with the rank and
  the heavy particles are drawn last (on top); what ranks hide is plotted under
  ``plots/weights/<path>/top_tenth`` (the share of the weight the yellow tenth holds) and
  ``.../ess`` (effective sample size / N);
- items with neither ids nor a role (classifier windows, candidates) are thin neutral grey, so
  hundreds of them stay a background;
- every scalar series is named (``misses``, ``phd/mass`` ...) and coloured once (static
  ``SeriesLines``): the metric series in their marks' colours (misses red, false positives
  magenta ...), the others from a palette in order of first appearance; in ``compare`` each
  lane's series take the lane's colour;
- labels are shown only on items whose ids are track ids and carry no values (a track's id);
  every other label (detection scores, gt ids, edge gains, cluster values) is logged but hidden
  (``show_labels=False``: select the entity in the viewer and turn labels on);
- masks are ``SegmentationImage`` with their own class names; dense fields are viridis images
  over the video (low values transparent), stretched over the frame when on a coarser grid;
- labels are built from an item's named ``values`` only for small item counts.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np
import rerun as rr

from pfscope.trackers.report import (Boxes, Event, Field, Mask, Points, Scalar, Segments, Stage)

from ..colors import TrackPalette, id_colors, ramp, ramp_table, weight_style, weight_summary

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
    # a particle born this frame (pink dots over the survivors' weight colours)
    "birth": (8, (255, 170, 220, 235)),
    # a classifier hit (a window the classifier accepted; the rest stay thin grey)
    "hit": (9, (0, 230, 255, 255)),
    # a kept cluster no confirmed track took (neutral, dashed-looking thin grey)
    "unmatched": (10, (200, 200, 200, 200)),
}
#: Items styled by what their path says they are (the engine's paths, for items it reports
#: with a generic role): newborn particles, classifier hits, and the blobs DBN-PHD's classifier
#: accepted (cyan like DLPF's hits, so they cannot be taken for the thin white ground truth).
PATH_ROLES = (("particles/birth", "birth"), ("classify/hits", "hit"), ("blobs/accepted", "hit"))
#: Metric marks are drawn outside the track box they mark (inflated by this many pixels per
#: side) and over it (draw order), so a thick track box never hides them.
MARK_INFLATE = {"false_positive": 4.0, "switch": 8.0, "miss": 0.0}
MARK_DRAW_ORDER = 30.0
#: Association edges: their gains are shown as labels when a frame has at most this many
#: chosen edges (a label per edge; more would pile up)
EDGE_LABELS_MAX = 25
MAX_LABELS = 60
DEFAULT_POINT_RADIUS = 1.5
STATIC_FLUSH_TIMEOUT = 10.0  # seconds; see Reporter._static
#: Dense fields (a motion magnitude grid ...) are drawn over the video (images draw at -10 by
#: default) as RGBA PNG of at most FIELD_MAX_PIXELS, opacity FIELD_ALPHA from low to high values.
FIELD_DRAW_ORDER = -5.0
FIELD_MAX_PIXELS = 100_000
FIELD_ALPHA = (0, 170)

#: Series names and colours of the metric plots (the colours of their marks on the video, light
#: enough for the plots' dark background).
SERIES_STYLE: dict[str, tuple[str, tuple[int, int, int]]] = {
    "metrics/ospa": ("OSPA (px)", (255, 200, 60)),
    "metrics/fn": ("misses", ROLES["miss"][1][:3]),
    "metrics/fp": ("false positives", ROLES["false_positive"][1][:3]),
    "metrics/idsw": ("ID switches", (200, 200, 200)),
    "metrics/cardinality/true": ("true count", (250, 250, 250)),
    "metrics/cardinality/estimated": ("estimated count", (170, 130, 255)),
    "detections/count": ("detections", ROLES["detection"][1][:3]),
    "tracks/count": ("tracks", (80, 170, 255)),
    "timing/step_ms": ("step ms", (255, 110, 70)),
}
#: Colours of the other series, in order of first appearance (bright on the dark plots).
SERIES_PALETTE = np.array([(255, 160, 60), (80, 200, 120), (90, 160, 240), (200, 140, 240),
                           (60, 210, 220), (240, 220, 80), (240, 140, 200), (200, 150, 110),
                           (150, 220, 60), (170, 170, 255)], dtype=np.uint8)


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
    #: tab title -> one sentence on what the tab shows (the README's tab table)
    notes: tuple[tuple[str, str], ...] = ()


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


def _path_role(path: str) -> Optional[str]:
    for suffix, role in PATH_ROLES:
        if path.endswith(suffix):
            return role
    return None


class Columns:
    """What the reporters log, kept per entity and sent as columns (``send_columns``: one call
    per entity and component for all the frames since the last :meth:`send`) instead of one
    ``log`` call per entity and frame.  A ``log`` call converts every component on its own
    (tens of microseconds of pyarrow each); a column converts a flush's frames at once (the
    components with the same instances per row in one call), which is most of what recording
    costs the frame loop.

    The recorder keeps :attr:`frame`, :attr:`seconds` and :attr:`stage` equal to the
    recording's timelines and calls :meth:`send` before every flush (so a flushed frame is whole
    in the file).  Entities are sent in the order they first appeared and each entity's rows in
    time order, so the same run gives the same file.  Each row keeps its own instance counts per
    component (a radius for all points in one frame, one per point in the next).  An entity
    whose components or archetype change from one row to the next has its rows so far sent
    first.  ``immediate``: every row is logged at once with ``log`` (no buffering)."""

    def __init__(self, rec: rr.RecordingStream, immediate: bool = False):
        self.rec = rec
        self.immediate = immediate
        self.frame, self.seconds, self.stage = 0, 0.0, 0
        self._rows: dict[str, dict] = {}

    def add(self, entity: str, archetype, **fields) -> None:
        """One row of ``archetype`` (``rr.Points2D`` ...) at ``entity``, the fields named as in
        ``archetype.columns``; a field is an array or list of instances, or one value (a str,
        a number, a bool, bytes); None fields are left out."""
        fields = {k: v for k, v in fields.items() if v is not None}
        if self.immediate:
            self.rec.log(entity, archetype.from_fields(**fields))
            return
        key = (archetype, tuple(fields))
        buf = self._rows.get(entity)
        if buf is not None and buf["key"] != key:
            self._send_one(entity, self._rows.pop(entity))
            buf = None
        if buf is None:
            buf = self._rows[entity] = {"key": key, "frame": [], "seconds": [], "stage": [],
                                        "fields": {k: [] for k in fields}}
        buf["frame"].append(self.frame)
        buf["seconds"].append(self.seconds)
        buf["stage"].append(self.stage)
        for k, v in fields.items():
            buf["fields"][k].append(v)

    def send(self) -> None:
        rows, self._rows = self._rows, {}
        times: dict = {}                 # the time columns of entities logged at the same rows
        for entity, buf in rows.items():
            self._send_one(entity, buf, times)

    def _send_one(self, entity: str, buf: dict, times: Optional[dict] = None) -> None:
        archetype = buf["key"][0]
        # one conversion per group of components with the same instances per row (boxes,
        # their colours and labels), each group cut into rows; the columns in field order
        groups: dict[bytes, tuple[np.ndarray, dict]] = {}
        for name, values in buf["fields"].items():
            data, lengths = _column(values)
            groups.setdefault(lengths.tobytes(), (lengths, {}))[1][name] = data
        parts = {}
        for lengths, fields in groups.values():
            # the archetype returns its columns in its own field order: match them by name
            for col in archetype.columns(**fields).partition(lengths):
                parts[str(col.component_descriptor().component).rpartition(":")[2]] = col
        columns = [parts[name] for name in buf["fields"]]
        key = (tuple(buf["frame"]), tuple(buf["stage"]), tuple(buf["seconds"]))
        indexes = None if times is None else times.get(key)
        if indexes is None:
            indexes = [rr.TimeColumn("frame", sequence=np.asarray(buf["frame"], dtype=np.int64)),
                       rr.TimeColumn("time", duration=np.asarray(buf["seconds"],
                                                                 dtype=np.float64)),
                       rr.TimeColumn("stage", sequence=np.asarray(buf["stage"], dtype=np.int64))]
            if times is not None:
                times[key] = indexes
        self.rec.send_columns(entity, indexes=indexes, columns=columns)


class TimedStream:
    """The recording stream with its timelines set when a row is logged, not when they move.
    The frame loop moves them about ten times a frame (the frame, its time, a stage slot per
    stage), but most rows go through :class:`Columns` with their own time columns; the few
    direct ``log`` calls (events, clears, static items) first set the timelines that changed
    since the last one.  Everything else goes straight to the stream."""

    def __init__(self, rec: rr.RecordingStream):
        self.raw = rec
        self._want: dict[str, dict] = {}
        self._have: dict[str, dict] = {}

    def set_time(self, timeline: str, **kwargs) -> None:
        self._want[timeline] = kwargs

    def log(self, *args, **kwargs):
        for name, value in self._want.items():
            if self._have.get(name) != value:
                self.raw.set_time(name, **value)
                self._have[name] = value
        return self.raw.log(*args, **kwargs)

    def __getattr__(self, name):
        return getattr(self.raw, name)


def _column(values: list) -> tuple[object, np.ndarray]:
    """Rows of one component -> (all instances, instances per row).  A row is an array (its
    first axis: instances), a number (one instance), or a list (strings, line strips), a
    string or bytes (one instance)."""
    if not any(isinstance(v, (list, tuple, str, bytes)) for v in values):
        arrays = [np.asarray(v) for v in values]
        arrays = [a.reshape(1) if a.ndim == 0 else a for a in arrays]
        return (np.concatenate(arrays),
                np.fromiter((len(a) for a in arrays), dtype=np.int64, count=len(arrays)))
    flat: list = []
    lengths = np.empty(len(values), dtype=np.int64)
    for i, v in enumerate(values):
        if isinstance(v, (list, tuple)):
            flat.extend(v)
            lengths[i] = len(v)
        elif isinstance(v, np.ndarray) and v.ndim >= 1:
            flat.extend(v.tolist())
            lengths[i] = len(v)
        else:
            flat.append(v.item() if isinstance(v, np.generic) else v)
            lengths[i] = 1
    return flat, lengths


class Reporter:
    """Logs stage items to ``rec`` under ``root`` (``""`` or ``"<tracker>/"`` in ``compare``).
    Entities logged in a frame are remembered so stale ones can be cleared at the frame's end."""

    def __init__(self, rec: rr.RecordingStream, root: str = "", max_points: int = 3000,
                 jpeg_quality: int = 75, *, series: Optional[dict] = None,
                 series_color: Optional[tuple] = None,
                 size: Optional[tuple[int, int]] = None,
                 columns: Optional[Columns] = None):
        self.rec = rec
        # rows go to `columns` (sent by the recorder); without it they are logged one by one
        self.columns = columns if columns is not None else Columns(rec, immediate=True)
        self.root = root
        self.size = size  # the frames' (width, height), when known: fields are stretched to it
        # entity -> palette index of the scalar series already styled (share one dict between
        # the reporters of a recording so their series get different colours)
        self.series = {} if series is None else series
        self.series_color = series_color
        self.max_points = int(max_points)
        self.jpeg_quality = int(jpeg_quality)
        self.logged: set[str] = set()
        self._mask_classes: dict[str, tuple] = {}
        # one colour per track id for this lane, ids alive together far apart (OKLab)
        self.palette = TrackPalette()
        # this frame's kept clusters -> the confirmed track that took them (-1: none), by
        # cluster prefix ("phd/clusters"): see stages()
        self._cluster_track: dict[str, np.ndarray] = {}

    def video(self, path: str) -> str:
        return f"{self.root}video/{path}"

    def _log(self, entity: str, archetype) -> None:
        self.logged.add(entity)
        self.rec.log(entity, archetype)

    def _row(self, entity: str, archetype, **fields) -> None:
        """One row of ``archetype`` at ``entity`` (sent with the other rows by
        :class:`Columns`)."""
        self.logged.add(entity)
        self.columns.add(entity, archetype, **fields)

    def stage(self, stage: Stage) -> None:
        self.palette.frame = self.columns.frame
        for item in stage.items:
            self.item(item)

    def frame_stages(self, stages, track_ids=None) -> None:
        """Read the frame's stages before they are drawn: ``track_ids`` (the frame's output
        tracks) get their palette colours first, so every item of the frame shows a track in
        the colour of its box; the association's vertices are the kept clusters in order
        (PHD-MT, DBN-PHD: ``assoc/vertices`` = ``clusters/kept``), so a kept cluster can be
        drawn in the colour of the confirmed track that took it."""
        self.palette.frame = self.columns.frame
        if track_ids is not None:
            self.palette.colors(track_ids)
        self._cluster_track = {}
        verts, kept = None, {}
        for st in stages:
            for it in st.items:
                if isinstance(it, Boxes) and it.path == "assoc/vertices":
                    verts = it
                elif isinstance(it, Boxes) and it.path.endswith("clusters/kept") \
                        and it.ids is not None:
                    kept[it.path[:-len("/kept")]] = it.ids
        if verts is None or verts.ids is None:
            return
        conf = verts.values.get("confirmed")
        tids = np.where(conf > 0, verts.ids, -1) if conf is not None else verts.ids
        for prefix, idx in kept.items():
            if len(idx) != len(tids):
                continue  # not the same estimates: leave them neutral
            lut = np.full(int(idx.max()) + 1 if len(idx) else 0, -1, dtype=np.int64)
            lut[idx] = tids
            self._cluster_track[prefix] = lut

    def _track_of_clusters(self, path: str, ids: np.ndarray) -> np.ndarray:
        """Cluster ids -> the confirmed track id that took the cluster, or -1."""
        prefix = path.rsplit("/", 1)[0]
        lut = self._cluster_track.get(prefix)
        out = np.full(len(ids), -1, dtype=np.int64)
        if lut is None or not len(lut):
            return out
        ok = (ids >= 0) & (ids < len(lut))
        out[ok] = lut[ids[ok]]
        return out

    def _id_colors(self, ids: Optional[np.ndarray], id_kind: Optional[str], path: str = "",
                   alpha: int = 255) -> Optional[np.ndarray]:
        """Colours of items with ids: a track id its track colour; a cluster the colour of the
        confirmed track that took it, else the neutral "unmatched" grey; other ids (a detection
        index, a class) the stateless palette."""
        if ids is None:
            return None
        if id_kind == "track":  # the frame's tracks are registered first (frame_stages)
            return self.palette.colors(ids, alpha, register=False)
        if id_kind == "cluster":
            tids = self._track_of_clusters(path, np.asarray(ids, dtype=np.int64))
            out = np.tile(np.array(ROLES["unmatched"][1], dtype=np.uint8), (len(tids), 1))
            out[:, 3] = min(alpha, 200)
            m = tids >= 0
            if m.any():
                out[m] = self.palette.colors(tids[m], alpha, register=False)
            return out
        return id_colors(ids, alpha)

    def item(self, item) -> None:
        if isinstance(item, Scalar):
            self.scalar(item.path, item.value)
        elif isinstance(item, Event):
            self.text(item.path, item.message, item.severity)
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
        n = len(p.xy)
        keep = (np.linspace(0, n - 1, self.max_points).round().astype(np.int64)
                if n > self.max_points else None)  # deterministic stride decimation, no RNG
        # the kept points only are converted (a cloud can hold many times max_points)
        xy = (p.xy if keep is None else p.xy[keep]).astype(np.float32)
        radii = np.float32(DEFAULT_POINT_RADIUS)
        role = _path_role(p.path) or p.role
        if role == "birth":  # newborn: white dots, apart from the survivors' weight colours
            colors = None
        elif p.weights is not None and "score" in p.values:
            # a probability per particle (the DBN score): viridis on its value, 0 → 1, not
            # by rank (the legend says so); the highest drawn last
            w = p.weights if keep is None else p.weights[keep]
            order = np.argsort(w, kind="stable")
            colors = ramp_table(np.clip(w[order], 0.0, 1.0))
            xy = xy[order]
        elif p.weights is not None:
            w = p.weights if keep is None else p.weights[keep]
            order, colors, radii = weight_style(w, DEFAULT_POINT_RADIUS)
            xy = xy[order]  # the heaviest last: drawn on top
        elif p.ids is not None:  # colours of the kept points only
            colors = self._id_colors(p.ids if keep is None else np.asarray(p.ids)[keep],
                                     p.id_kind, p.path, alpha=200)
        elif role is None:
            # a cloud with no weights, ids or role (resampled parents): equal weights, the
            # middle of the weight map (teal), as the legend says
            colors = ramp_table(np.full(len(xy), 0.5))
            colors[:, 3] = 200
        else:
            colors = None
        class_ids = ROLES[role][0] if role in ROLES and colors is None else None
        self._row(self.video(p.path), rr.Points2D, positions=xy, colors=colors,
                  class_ids=class_ids, radii=radii, show_labels=False)
        if p.weights is not None:
            for key, v in weight_summary(p.weights).items():
                self.scalar(f"weights/{p.path}/{key}", v)

    def boxes(self, b: Boxes, radii: float = 1.0) -> None:
        boxes = b.boxes.astype(np.float32)
        colors = self._id_colors(b.ids, b.id_kind, b.path) \
            if b.id_kind in ("track", "cluster") else None
        if colors is not None and b.values:  # evidence about a track (a window, a MAP box
            radii = min(radii, 0.5)          # with its score), not the track: thin
        role = _path_role(b.path) or (b.role if b.role in ROLES else None)
        if role == "hit":
            colors, radii = None, 1.5
        if colors is None and role is None:
            # no identity, no role (classifier windows, candidates): a thin neutral background,
            # fainter the more there are, so hundreds of windows do not hide the frame
            colors = np.tile(np.array(ROLES["candidate"][1], dtype=np.uint8), (len(boxes), 1))
            colors[:, 3] = int(np.clip(140 * np.sqrt(MAX_LABELS / max(len(boxes), 1)), 40, 140))
            radii = min(radii, 0.5)
        class_ids = ROLES[role][0] if role is not None and colors is None else None
        labels = value_labels(b.values, len(b), b.ids if b.id_kind == "track" else None)
        show = labels is not None and b.id_kind == "track" and not b.values
        # show_labels always set: a class id would otherwise show its class name as a label
        self._boxes(self.video(b.path), boxes, colors=colors, class_ids=class_ids,
                    labels=labels, show_labels=show, radii=radii)

    def segments(self, s: Segments) -> None:
        strips = np.stack([s.a, s.b], axis=1).astype(np.float32)
        chosen = s.role is None
        colors = self._id_colors(s.ids, s.id_kind, s.path) if chosen else None
        class_ids = ROLES[s.role][0] if s.role in ROLES else None
        labels = value_labels(s.values, len(s), s.ids if s.id_kind == "track" else None) \
            if chosen else None
        # the chosen edges' gains are shown (few a frame); candidates' labels stay hidden
        show = bool(chosen and labels and len(s) <= EDGE_LABELS_MAX)
        self._row(self.video(s.path), rr.LineStrips2D, strips=list(strips),
                  colors=colors, class_ids=class_ids, labels=labels, show_labels=show,
                  radii=1.5 if chosen else 0.5)

    def mask(self, m: Mask) -> None:
        entity = self.video(m.path)
        if self._mask_classes.get(entity) != m.classes:
            palette = id_colors(np.arange(len(m.classes)), alpha=140)
            palette[0, 3] = 0  # background transparent
            self._static(entity, rr.AnnotationContext(
                [rr.AnnotationInfo(id=i, label=c, color=tuple(int(x) for x in palette[i]))
                 for i, c in enumerate(m.classes)]))
            self._mask_classes[entity] = m.classes
        self._log(entity, rr.SegmentationImage(m.mask))

    def field(self, f: Field) -> None:
        v = f.values
        lo = float(np.nanmin(v)) if f.vmin is None and v.size else (f.vmin or 0.0)
        hi = float(np.nanmax(v)) if f.vmax is None and v.size else (f.vmax or 1.0)
        t = np.clip((v - lo) / (hi - lo), 0, 1) if hi > lo else np.zeros_like(v)
        entity = self.video(f.path)
        if t.size > FIELD_MAX_PIXELS:  # bounded file size: a finer field is shown coarser
            k = np.sqrt(FIELD_MAX_PIXELS / t.size)
            t = cv2.resize(t.astype(np.float32), (max(1, int(t.shape[1] * k)),
                                                  max(1, int(t.shape[0] * k))),
                           interpolation=cv2.INTER_AREA)
        # RGBA PNG, low values nearly transparent so the frame shows through.  (A raw rr.Image
        # drawn over the JPEG video blanks the video in Rerun 0.41; an encoded one blends.)
        rgba = ramp(t.reshape(-1), alpha=255).reshape(t.shape + (4,))
        rgba[..., 3] = np.round(FIELD_ALPHA[0] + (FIELD_ALPHA[1] - FIELD_ALPHA[0])
                                * t).astype(np.uint8)
        ok, png = cv2.imencode(".png", np.ascontiguousarray(rgba[..., [2, 1, 0, 3]]))
        self._log(entity, rr.EncodedImage(contents=png.tobytes(), media_type="image/png",
                                          draw_order=FIELD_DRAW_ORDER))
        if self.size is not None:  # a grid coarser than the frame is stretched over it
            w, h = self.size
            self.rec.log(entity, rr.Transform3D(scale=[w / t.shape[1], h / t.shape[0], 1.0]))
        self.scalar(f"{f.path}/max", hi)

    def track_boxes(self, path: str, ids: np.ndarray, boxes: np.ndarray) -> None:
        boxes = np.asarray(boxes, dtype=np.float32).reshape(-1, 4)
        self.palette.frame = self.columns.frame
        self._boxes(self.video(path), boxes, colors=self.palette.colors(ids),
                    labels=[str(int(i)) for i in ids], radii=2.0)

    def track_strips(self, path: str, ids: np.ndarray, strips: list) -> None:
        self._row(self.video(path), rr.LineStrips2D,
                  strips=[np.asarray(s, dtype=np.float32) for s in strips],
                  colors=self.palette.colors(ids), radii=1.0)

    def role_boxes(self, path: str, boxes: np.ndarray, role: str,
                   labels: Optional[list[str]] = None, radii: float = 1.0) -> None:
        boxes = np.asarray(boxes, dtype=np.float32).reshape(-1, 4)
        grow = MARK_INFLATE.get(role)
        extra = {}
        if grow is not None:  # a metric mark: outside and over the track box it marks
            boxes = boxes + np.array([-grow, -grow, 2 * grow, 2 * grow], dtype=np.float32)
            extra["draw_order"] = MARK_DRAW_ORDER
        self._boxes(self.video(path), boxes, class_ids=np.full(len(boxes), ROLES[role][0]),
                    labels=(labels if len(boxes) <= MAX_LABELS else [])
                    if labels is not None else None, show_labels=False, radii=radii, **extra)

    def _boxes(self, entity: str, boxes: np.ndarray, **fields) -> None:
        """Boxes (N, 4) float32 ``x, y, w, h`` as a ``Boxes2D`` row (centres and half sizes,
        as ``Boxes2D(mins=, sizes=)`` stores them)."""
        half = boxes[:, 2:] / np.float32(2.0)
        self._row(entity, rr.Boxes2D, centers=boxes[:, :2] + half, half_sizes=half,
                  **fields)

    def scalar(self, path: str, value: float) -> None:
        entity = f"{self.root}plots/{path}"
        if entity not in self.series:
            self._style_series(entity, path)
        self.columns.add(entity, rr.Scalars, scalars=np.array([value], dtype=np.float64))

    def _style_series(self, entity: str, path: str) -> None:
        """Name and colour a series the first time it is logged (static ``SeriesLines``)."""
        name, color = SERIES_STYLE.get(path, (path, None))
        if color is None:
            k = sum(1 for v in self.series.values() if v >= 0)
            color = tuple(int(c) for c in SERIES_PALETTE[k % len(SERIES_PALETTE)])
            self.series[entity] = k
        else:
            self.series[entity] = -1
        if self.series_color is not None:  # compare: a lane's series in the lane's colour
            color = tuple(int(c) for c in self.series_color[:3])
        if self.root:
            name = f"{self.root.rstrip('/')}: {name}"
        self._static(entity, rr.SeriesLines(names=[name], colors=[color]))

    def _static(self, entity: str, archetype) -> None:
        """Log static data on an entity that also gets temporal data, and flush it out at once:
        were the static and the temporal rows of one entity pending in the batcher together,
        the order it writes their chunks in would vary from run to run (same seed, different
        file).  Happens once per entity (a new series, a new mask), so the flushes are few."""
        self.rec.log(entity, archetype, static=True)
        try:
            self.rec.flush(timeout_sec=STATIC_FLUSH_TIMEOUT)
        except Exception:  # noqa: BLE001 - a stalled file is the recorder's to report
            pass

    def text(self, path: str, message: str, level: str = "INFO") -> None:
        """A text-log row at ``log/<path>``: a row of the columns, not a ``log`` call (each call
        into the recording stream hands the GIL to the run's other threads and waits to get it
        back: ~1 ms a call at the tracks level); not in :attr:`logged` (a message is not
        cleared)."""
        self.columns.add(f"{self.root}log/{path}" if path else f"{self.root}log",
                         rr.TextLog, text=message, level=level)


__all__ = ["Reporter", "Columns", "TrackerLayout", "ROLES", "annotation_context",
           "value_labels"]
