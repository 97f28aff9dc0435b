"""The Rerun recorder: a pipeline hook that turns each frame's results into a recording.

Entity layout (2D overlays share the image's pixel space under ``video``):

- ``video``                  the frame, JPEG-compressed
- ``video/detections``, ``video/gt``   the frame's detections and ground truth
- ``[<tracker>/]video/<path>``   a tracker's stage items (``video/phd/particles/updated`` ...),
  its tracks, trails and metric marks (misses, false positives, ID switches)
- ``[<tracker>/]plots/<path>``   scalars (``plots/phd/mass``, ``plots/metrics/ospa``,
  ``plots/timing/step_ms``)
- ``[<tracker>/]log``            events; the recording's last entry says why the run stopped
- ``[<tracker>/]events``         with ground truth, the failure index (:mod:`pfscope.trackers.eval.
  events`): ID switches, false tracks, lost tracks, long misses as text-log rows at their
  frame (clicking one jumps there), and ``events/worst_ospa`` the worst frames by OSPA
- ``about``                      a static markdown note on what each tab shows

Properties (``pfscope info`` reads them back): :mod:`.properties`.

With one tracker the root is empty; ``compare`` gives each tracker its own root.

Timelines: ``frame`` (MOT frame number), ``time`` (the video's clock) and ``stage``.  The
``stage`` timeline follows each tracker's own stage list: a frame's slots are ``input``, then
for each tracker its stages and its ``output``; slot = frame × slots-per-frame + index, so a
frame's stages stay in order and frames never overlap, also with several trackers.

Cost (issue 12): the frame loop pays for little more than building the rows.  The frame's JPEG
is encoded on a worker thread while the rows are built (:class:`JpegEncoder`, one frame in flight,
bounded wait); rows are kept per entity and sent as columns every ``flush_frames`` frames
(:class:`~.reporters.base.Columns`: one conversion per entity and group of components for
twenty frames instead of one ``log`` call per entity and frame; 20, not 10: a send costs
mostly per call, and a SIGKILL still loses at most 20 frames); the flush is started without
waiting for it, and only every ``check_flushes``-th one is waited for (bounded), so the writer
builds the chunks while the next frames run.  None of this depends on thread timing: the same
seed and input give the same file.

Files: the recording is written as ``<name>.incomplete.rrd`` and renamed to its final name
only when the run completed; a failed or interrupted run keeps the ``.incomplete`` name (the
file is finished and readable, its last entry says why it stopped).  A previous file under the
final name is replaced only by a completed run.
"""

from __future__ import annotations

import json
import os
import platform
import threading
import uuid
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from datetime import timedelta
from pathlib import Path
from typing import Optional

import cv2
import numpy as np
import rerun as rr

from pfscope.trackers import __version__
from pfscope.trackers.outputs import incomplete_path
from pfscope.trackers.pipeline import BaseHook, FrameReport, Outcome, RunInfo

from .blueprint import compare_blueprint, default_blueprint
from .properties import about_markdown, any_values
from .reporters import Reporter, layout_for
from .tabs import compare_tabs, single_tabs
from .tabs import to_property as tabs_property
from .reporters.base import SERIES_PALETTE, Columns, TimedStream, annotation_context


#: What the ``video`` entity stores (``RerunRecorder(video=...)``): ``encode`` the decoded frame
#: as JPEG at ``jpeg_quality`` (the default); ``source`` the source's own JPEG bytes when it has
#: them (a MOT or image folder of JPEGs: no encoding at all, but high-quality sources make
#: larger files — PETS09's are about twice a quality-75 encoding); ``auto`` the source's bytes
#: when the first frame's are not larger than its encoding, else ``encode`` (decided once per
#: run from the input, so the same input gives the same file).
VIDEO_MODES = ("encode", "source", "auto")

#: Longest wait for a flush or close of the recording, seconds ($PFSCOPE_FLUSH_TIMEOUT).
FLUSH_TIMEOUT = float(os.environ.get("PFSCOPE_FLUSH_TIMEOUT", "30"))


class RecordingStalled(RuntimeError):
    """Writing the recording did not finish within :data:`FLUSH_TIMEOUT`."""


class JpegEncoder:
    """Encodes a frame to JPEG on one worker thread (``cv2.imencode`` releases the GIL), so the
    encoding overlaps the main thread's work (the recorder takes a frame's bytes when the next
    frame arrives, after the trackers stepped on it).  The image is not copied: a source never
    writes to an image it yielded (:class:`~pfscope.trackers.data.sources.Source`).

    Bounded: at most one frame is in flight (:meth:`submit` refuses a second one before
    :meth:`result` took the first), and :meth:`result` waits at most ``timeout`` seconds.  A
    failure in the worker (or a timeout) is raised by :meth:`result` on the caller's thread.
    The encoded bytes do not depend on the thread, so the recording stays the same."""

    def __init__(self, quality: int, timeout: float = FLUSH_TIMEOUT):
        self.params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
        self.timeout = float(timeout)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pfscope-jpeg")
        self._pending = None

    def _encode(self, image: np.ndarray) -> bytes:
        ok, buf = cv2.imencode(".jpg", image, self.params)
        if not ok:
            raise RuntimeError(f"JPEG encoding of a {image.shape} {image.dtype} frame failed")
        return buf.tobytes()

    def submit(self, image: np.ndarray) -> None:
        if self._pending is not None:
            raise RuntimeError("JpegEncoder: a frame is already being encoded")
        self._pending = self._pool.submit(self._encode, image)

    @property
    def pending(self) -> bool:
        return self._pending is not None

    def result(self) -> Optional[bytes]:
        """The bytes of the frame submitted last (None when none is pending)."""
        fut, self._pending = self._pending, None
        if fut is None:
            return None
        try:
            return fut.result(timeout=self.timeout)
        except FutureTimeout:
            raise RecordingStalled(f"JPEG encoding of a frame took more than "
                                   f"{self.timeout:.0f} s") from None

    def close(self) -> None:
        self._pending = None
        self._pool.shutdown(wait=False, cancel_futures=True)


def recording_id_for(config: dict) -> str:
    """A recording id derived from the run's configuration, so the same seed and input give a
    comparable recording (``rerun rrd compare``)."""
    return str(uuid.uuid5(uuid.NAMESPACE_URL, "pfscope:" + repr(sorted(config.items()))))


#: the installed distributions whose version can change a run's tracks or its recording
#: (numba compiles the PHD kernels, torch runs DBN-PHD's network); read from their metadata,
#: so recording a run never imports torch
RESULT_SHAPING = ("numba", "llvmlite", "torch")


def versions() -> dict:
    from importlib import metadata

    import scipy

    out = {"pfscope": __version__, "rerun-sdk": rr.__version__, "numpy": np.__version__,
           "scipy": scipy.__version__, "opencv": cv2.__version__,
           "python": platform.python_version()}
    for dist in RESULT_SHAPING:
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def _frame_size(source) -> Optional[tuple[int, int]]:
    """(width, height) of the source's frames when known (the 2D views are framed on it)."""
    w, h = getattr(source, "width", 0), getattr(source, "height", 0)
    try:
        w, h = int(w), int(h)
    except (TypeError, ValueError):
        return None
    return (w, h) if w > 0 and h > 0 else None


class TrailBuffer:
    """Recent centres of each live track (bounded: ``length`` points per track, tracks unseen
    for ``forget`` frames are dropped).  A trail restarts where its track jumps by more than
    ``jump`` times the box height in one step (an id taken over by another person): a straight
    line across the picture says nothing about where anyone walked."""

    def __init__(self, length: int = 30, forget: int = 50, jump: float = 0.75):
        self.length, self.forget, self.jump = length, forget, float(jump)
        self.trails: dict[int, deque] = {}
        self.last_seen: dict[int, int] = {}

    def update(self, frame: int, ids: np.ndarray, boxes: np.ndarray):
        centres = boxes[:, :2] + boxes[:, 2:] / 2.0
        for tid, c, h in zip(ids.tolist(), centres, boxes[:, 3].tolist()):
            trail = self.trails.setdefault(tid, deque(maxlen=self.length))
            if trail and float(np.hypot(*(c - trail[-1]))) > self.jump * max(h, 1.0):
                trail.clear()
            trail.append(c)
            self.last_seen[tid] = frame
        for tid in [t for t, f in self.last_seen.items() if frame - f > self.forget]:
            del self.trails[tid], self.last_seen[tid]
        live = [t for t in ids.tolist() if len(self.trails[t]) >= 2]
        return np.asarray(live, dtype=np.int64), [np.asarray(self.trails[t]) for t in live]


class RerunRecorder(BaseHook):
    """Pipeline hook writing a Rerun recording to ``out`` (see the module docstring).

    ``sinks``: ``None`` (the file only), ``"spawn"`` (also a native viewer) or ``"serve"`` (also
    a web viewer; its URL goes to ``announce``).  ``config`` is stored as the recording's
    properties and seeds the recording id (same config → comparable recording)."""

    def __init__(self, out: Path, config: dict, *, max_points: int = 3000,
                 jpeg_quality: int = 75, flush_frames: int = 20, live: Optional[str] = None,
                 web_port: int = 9090, announce=print, timing: bool = False,
                 properties: Optional[dict] = None, long_miss: int = 10, worst: int = 10,
                 check_flushes: int = 5, video: str = "encode"):
        if video not in VIDEO_MODES:
            raise ValueError(f"video must be one of {', '.join(VIDEO_MODES)}, got {video!r}")
        self.video = video
        self._passthrough: Optional[bool] = {"encode": False, "source": True}.get(video)
        self.out = Path(out)
        self.partial = incomplete_path(self.out)
        self.config = config
        self.max_points, self.jpeg_quality = max_points, jpeg_quality
        # Flushing bounds what a SIGKILLed run loses.  Counted in frames, not seconds, so the
        # chunks of the file do not depend on the machine's speed (same input → same file).
        self.flush_frames = int(flush_frames)
        # A flush is started every `flush_frames` frames without waiting for it (the chunks are
        # cut where the flush command enters the stream, so the file is the same), and every
        # `check_flushes`-th flush is waited for (bounded): a disk that stopped taking data is
        # found within flush_frames x check_flushes frames, and the main thread does not sit
        # idle while the writer builds the chunks of the other flushes.
        self.check_flushes = max(1, int(check_flushes))
        self._flushes = 0
        self._jpeg: Optional[JpegEncoder] = None
        # the last frame whose picture is still being encoded: (frame, seconds, source bytes)
        self._picture: Optional[tuple[int, float, Optional[bytes]]] = None
        self.live, self.web_port, self.announce = live, web_port, announce
        self.grpc_port: Optional[int] = None
        self.serve_url: Optional[str] = None
        # Wall-clock step times differ run to run: recorded only when asked, so that the same
        # seed and input give the same recording.
        self.timing = timing
        # typed property groups ({"run": {...}, "source": {...}, "tracker.phd": {...}}); without
        # them the flat config is stored as the "config" group
        self.properties = properties
        self.long_miss, self.worst = int(long_miss), int(worst)
        self.events: dict = {}
        self.rec: Optional[rr.RecordingStream] = None
        self.kept_as: Optional[Path] = None
        self._broken: Optional[str] = None
        self._frames = 0

    # -- pipeline hook ---------------------------------------------------------------------
    def begin(self, info: RunInfo) -> None:
        names = list(info.trackers)
        # No time-based batching: chunks are cut by size and by our flush every
        # `flush_frames` frames only, so the same input gives the same chunks (and a
        # `rerun rrd compare`-equal file) however fast or loaded the machine is.
        batcher = rr.ChunkBatcherConfig(flush_tick=timedelta(days=1), flush_num_bytes=2 << 20)
        rec = TimedStream(rr.RecordingStream("pfscope", recording_id=recording_id_for(self.config),
                                             send_properties=False, batcher_config=batcher))
        self.rec = rec
        if len(names) == 1:
            layout = layout_for(info.trackers[names[0]].name)
            plots = [(title, paths) for title, paths in layout.plots
                     if self.timing or not all(p.startswith("timing/") for p in paths)]
            blueprint = default_blueprint(layout.views, plots, size=_frame_size(info.source),
                                          metrics=info.has_gt)
            about = about_markdown(f"{names[0]} on {getattr(info.source, 'name', 'source')}",
                                   layout.views, plots, has_gt=info.has_gt)
            tabs = single_tabs(layout.views)
        else:
            lane_views = [layout_for(info.trackers[n].name).views for n in names]
            blueprint = compare_blueprint(names, size=_frame_size(info.source),
                                          lane_views=lane_views)
            tabs = compare_tabs(list(zip(names, lane_views)))
            about = about_markdown(f"{' vs '.join(names)} on "
                                   f"{getattr(info.source, 'name', 'source')}",
                                   [(f"{v['lane']}: {t['title']}",
                                     [e for e in v["entities"] if e.startswith(v["lane"])])
                                    for t in tabs for v in t["lanes"]],
                                   [("OSPA, ID switches, FP, misses, estimated targets",
                                     [f"{n}/plots/metrics/**" for n in names])],
                                   lanes=names, has_gt=info.has_gt)
        if self.partial.exists():
            self.partial.unlink()
        rec.save(str(self.partial), default_blueprint=blueprint)
        if self.live == "spawn":
            rec.spawn(connect=False)
            rec.set_sinks(rr.FileSink(str(self.partial)), rr.GrpcSink(),
                          default_blueprint=blueprint)
        elif self.live == "serve":
            # localhost only; the gRPC port is kept so that, after the run, a server of the
            # finished file can take it over under the same URL (record --serve)
            from .serve import free_port, viewer_url

            self.grpc_port = self.grpc_port or free_port()
            grpc = rr.GrpcServerSink(bind_ip="127.0.0.1", port=self.grpc_port)
            rec.set_sinks(rr.FileSink(str(self.partial)), grpc, default_blueprint=blueprint)
            rr.serve_web_viewer(web_port=self.web_port, connect_to=grpc.uri, open_browser=False)
            self.serve_url = viewer_url(self.web_port, self.grpc_port)
            self.announce(f"web viewer: {self.serve_url}")
        src = getattr(info.source, "name", "source")
        rec.send_recording_name(f"{src} · {' vs '.join(names)}")
        if self.properties:
            for group, values in self.properties.items():
                rec.send_property(group, any_values(values))
        else:
            rec.send_property("config", any_values(self.config))
        rec.send_property("versions", rr.AnyValues(**versions()))
        rec.send_property("tabs", any_values(tabs_property(tabs)))
        rec.log("/", annotation_context(), static=True)
        rec.log("about", rr.TextDocument(about, media_type=rr.MediaType.MARKDOWN), static=True)
        if info.has_gt:
            from pfscope.trackers.eval.events import EventIndex

            self.events = {name: EventIndex(long_miss=self.long_miss, worst=self.worst)
                           for name in names}

        # stage slots: input, then each lane's stages and its output
        self.slots: dict[tuple[str, str], int] = {("", "input"): 0}
        for name, tracker in info.trackers.items():
            for st in tuple(tracker.stages) + ("output",):
                self.slots[(name, st)] = len(self.slots)
        self.stride = len(self.slots)
        multi = len(names) > 1
        series: dict = {}  # one series registry: every series of the file gets its own colour
        size = _frame_size(info.source)
        # the frames' rows (video, overlays, scalars), kept per entity and sent as columns
        # before each flush (every frame with a live viewer)
        self.columns = Columns(rec)
        self.reporters = {name: Reporter(rec, f"{name}/" if multi else "", self.max_points,
                                         self.jpeg_quality, series=series, size=size,
                                         series_color=(tuple(SERIES_PALETTE[i % len(
                                             SERIES_PALETTE)]) if multi else None),
                                         columns=self.columns)
                          for i, name in enumerate(names)}
        self.base = Reporter(rec, "", self.max_points, self.jpeg_quality, series=series,
                             size=size, columns=self.columns)
        self.trails = {name: TrailBuffer() for name in names}
        self._before: set[str] = set()
        self._jpeg = JpegEncoder(self.jpeg_quality)

    def _stage(self, frame: int, lane: str, stage: str) -> None:
        assert self.rec is not None
        slot = frame * self.stride + self.slots[(lane, stage)]
        self.rec.set_time("stage", sequence=slot)
        self.columns.stage = slot

    def on_frame(self, r: FrameReport) -> None:
        rec = self.rec
        assert rec is not None
        k = r.frame.index
        self._take_picture()  # the previous frame's, encoded while the trackers stepped
        rec.set_time("frame", sequence=k)
        rec.set_time("time", duration=float(r.frame.timestamp))
        self.columns.frame, self.columns.seconds = k, float(r.frame.timestamp)
        self._stage(k, "", "input")
        # this frame's picture: encoded on the worker, its row added when the next frame
        # arrives (or at the next flush, or at the end), at this frame's times
        jpeg = self._jpeg
        assert jpeg is not None
        source_bytes = getattr(r.frame, "encoded", None) if self._passthrough is not False \
            else None
        if source_bytes is None or not self._passthrough:
            jpeg.submit(r.frame.image)
        self._picture = (k, float(r.frame.timestamp), source_bytes)
        base = self.base
        if r.detections is not None:
            d = r.detections
            base.role_boxes("detections", d.boxes, "detection",
                            labels=[f"{s:.2f}" for s in d.scores])
            base.scalar("detections/count", len(d))
        if r.gt is not None:
            base.role_boxes("gt", r.gt.boxes, "gt", labels=[f"gt {i}" for i in r.gt.ids])
        for name, res in r.results.items():
            rep = self.reporters[name]
            rep.frame_stages(res.stages, res.tracks.ids)
            for stage in res.stages:
                self._stage(k, name, stage.name)
                rep.stage(stage)
            self._stage(k, name, "output")
            t = res.tracks
            rep.track_boxes("tracks", t.ids, t.boxes)
            live, strips = self.trails[name].update(k, t.ids, t.boxes)
            rep.track_strips("tracks/trails", live, strips)
            rep.scalar("tracks/count", len(t))
            if self.timing:
                rep.scalar("timing/step_ms", 1000.0 * r.step_seconds.get(name, 0.0))
            m = r.metrics.get(name)
            if m is not None and r.gt is not None:
                self._metrics(rep, k, r.gt, t, m)
        self._clear_stale()
        for name, res in r.results.items():
            m = r.metrics.get(name)
            if m is not None and r.gt is not None and name in self.events:
                self._log_events(name, self.events[name].update(k, r.gt, res.tracks, m), k)
        self._frames += 1
        if self.live or not self.flush_frames:
            self._take_picture()  # a live viewer sees each frame as it ends
            self._send_columns()
        if self.flush_frames and self._frames % self.flush_frames == 0:
            self._take_picture()  # a flushed frame is whole in the file
            self._flushes += 1
            if self._flushes % self.check_flushes == 0:
                self._flush("writing stalled")
            else:
                self._flush_async("writing stalled")

    def _take_picture(self) -> None:
        """Add the row of the picture still pending (its encoding is waited for, bounded)."""
        if self._picture is None:
            return
        (k, seconds, source_bytes), self._picture = self._picture, None
        assert self._jpeg is not None
        blob = self._jpeg.result()
        if source_bytes is not None:
            if self._passthrough is None:  # auto, first frame with bytes: keep the smaller
                self._passthrough = blob is None or len(source_bytes) <= len(blob)
            if self._passthrough:
                blob = source_bytes
        c = self.columns
        now = c.frame, c.seconds, c.stage
        c.frame, c.seconds, c.stage = k, seconds, k * self.stride + self.slots[("", "input")]
        c.add("video", rr.EncodedImage, blob=blob, media_type="image/jpeg")
        c.frame, c.seconds, c.stage = now

    def _metrics(self, rep: Reporter, frame: int, gt, tracks, m) -> None:
        """Per-frame metrics of what the view shows, and marks on the misses, false positives
        and identity switches."""
        for key, v in (("ospa", m.ospa), ("cardinality/true", m.n_true),
                       ("cardinality/estimated", m.n_est), ("fp", m.fp), ("fn", m.fn),
                       ("idsw", m.idsw)):
            rep.scalar(f"metrics/{key}", v)
        rep.role_boxes("metrics/misses", gt.boxes[m.fn_idx], "miss", radii=2.5,
                       labels=[f"miss gt {i}" for i in gt.ids[m.fn_idx]])
        rep.role_boxes("metrics/false_positives", tracks.boxes[m.fp_idx], "false_positive",
                       radii=2.5, labels=[f"FP {i}" for i in tracks.ids[m.fp_idx]])
        rep.role_boxes("metrics/switches", tracks.boxes[m.switch_idx], "switch", radii=3.0,
                       labels=[f"ID switch: {i}" for i in tracks.ids[m.switch_idx]])
        if m.idsw:
            rep.text("metrics", f"frame {frame}: {m.idsw} identity switch(es): tracks "
                                f"{', '.join(str(i) for i in tracks.ids[m.switch_idx])}", "WARN")

    def _clear_stale(self) -> None:
        """Entities a frame did not log are cleared, so no stale cloud from an earlier frame
        shows."""
        now: set[str] = set()
        for rep in list(self.reporters.values()) + [self.base]:
            now |= rep.logged
            rep.logged = set()
        assert self.rec is not None
        for ent in sorted(self._before - now):
            self.rec.log(ent, rr.Clear(recursive=False))
        self._before = now

    def end(self, outcome: Outcome) -> None:
        rec = self.rec
        if rec is None:
            return
        picture_error: Optional[BaseException] = None
        if self._jpeg is not None:
            try:  # the last frame's picture (a frame that failed half-way has none pending)
                if self._broken is None:
                    self._take_picture()
            except Exception as e:  # noqa: BLE001 - the run then failed: said below
                picture_error = e
                if outcome.status != "failed":
                    outcome = Outcome("failed", outcome.frames,
                                      f"failed: {type(e).__name__}: {e}", e)
            self._jpeg.close()
        level = {"completed": "INFO", "interrupted": "WARN"}.get(outcome.status, "ERROR")
        rec.log("log", rr.TextLog(f"run {outcome.reason}", level=level))
        self._finish_index(outcome)
        self.kept_as = self.partial
        try:
            self._flush("could not finish the file")
        finally:
            if self._broken is None:
                self._bounded(rec.disconnect, "could not close the file")
            else:  # the file is already broken: try to close it, but do not wait long
                t = threading.Thread(target=rec.disconnect, daemon=True)
                t.start()
                t.join(5)
        if outcome.status == "completed":
            os.replace(self.partial, self.out)
            self.kept_as = None
        if picture_error is not None:
            raise picture_error

    def _root(self, lane: str) -> str:
        return f"{lane}/" if len(self.reporters) > 1 else ""

    def _log_events(self, lane: str, events: list, now: int) -> None:
        """Failure-index rows, each at its own frame (a false track or a long miss is known only
        when it ends: its row goes back to where it began, so clicking it jumps there)."""
        rec = self.rec
        assert rec is not None
        if not events:
            return
        for ev in events:
            rec.set_time("frame", sequence=ev.frame)
            rec.set_time("stage", sequence=ev.frame * self.stride + self.slots[(lane, "output")])
            rec.log(f"{self._root(lane)}events", rr.TextLog(ev.short, level=ev.severity),
                    # every row has the same columns ("-": no id; an empty string or None drops
                    # the column, and rows of two column sets go to two chunks whose order in
                    # the file varies from run to run: same-seed files would differ)
                    rr.AnyValues(kind=ev.kind,
                                 track_ids=" ".join(map(str, ev.track_ids)) or "-",
                                 gt_ids=" ".join(map(str, ev.gt_ids)) or "-",
                                 last_frame=(ev.last_frame if ev.last_frame is not None
                                             else ev.frame),
                                 message=ev.message))
        rec.set_time("frame", sequence=now)
        self._stage(now, lane, "output")

    def _finish_index(self, outcome: Outcome) -> None:
        """The end of the run: open events, the worst frames by OSPA, and the final scores and
        event counts as properties."""
        rec = self.rec
        assert rec is not None
        for lane, index in self.events.items():
            last = index.last_frame
            self._log_events(lane, index.finish(), last)
            for rank, (frame, value) in enumerate(index.worst_frames(), start=1):
                rec.set_time("frame", sequence=frame)
                rec.set_time("stage",
                             sequence=frame * self.stride + self.slots[(lane, "output")])
                rec.log(f"{self._root(lane)}events/worst_ospa", rr.TextLog(
                    f"worst OSPA #{rank}: frame {frame}, OSPA {value:.1f} px", level="DEBUG"))
            rec.send_property(f"events.{lane}", any_values(dict(index.counts)))
        for lane, sc in (outcome.scores or {}).items():
            rec.send_property(f"scores.{lane}", any_values(
                {k: v for k, v in sc.items() if isinstance(v, (int, float, str))}))

    def _flush(self, what: str) -> None:
        assert self.rec is not None
        rec = self.rec
        self._send_columns()
        self._bounded(lambda: rec.flush(timeout_sec=FLUSH_TIMEOUT), what)

    def _send_columns(self) -> None:
        columns = getattr(self, "columns", None)
        if columns is not None and self._broken is None:
            columns.send()

    def _flush_async(self, what: str) -> None:
        """Start a flush without waiting for it (see ``check_flushes``)."""
        assert self.rec is not None
        if self._broken is not None:
            raise RecordingStalled(self._broken)
        self._send_columns()
        try:
            self.rec.flush(timeout_sec=0)
        except Exception as e:  # noqa: BLE001 - one line, like a failed waited-for flush
            self._broken = f"{self.partial}: {what}: {e} (disk full or unwritable?)"
            raise RecordingStalled(self._broken) from None

    def _bounded(self, fn, what: str, timeout: float = FLUSH_TIMEOUT) -> None:
        """Run ``fn`` (a flush or close) with a bounded wait: a full disk or a viewer that
        never answers must not hang the run (DESIGN.md: no wait is unbounded).  A failure or a
        timeout becomes one :class:`RecordingStalled`; later flushes are then skipped, so a
        broken file costs one wait, not one per flush."""
        if self._broken is not None:
            raise RecordingStalled(self._broken)
        errors: list = []

        def target():
            try:
                fn()
            except Exception as e:  # noqa: BLE001 - reported below as one line
                errors.append(e)

        t = threading.Thread(target=target, daemon=True)
        t.start()
        t.join(timeout + 5)
        if t.is_alive() or errors:
            why = f": {errors[0]}" if errors else f" within {timeout:.0f} s"
            self._broken = f"{self.partial}: {what}{why} (disk full or unwritable?)"
            raise RecordingStalled(self._broken)

    @property
    def broken(self) -> bool:
        """Writing the file failed or stalled."""
        return self._broken is not None

    def describe_kept(self) -> str:
        """Where the partial output is, for an error message."""
        if self.rec is None:
            return "no recording was written"
        return f"partial recording kept as {self.kept_as or self.partial}"

    @property
    def path(self) -> Path:
        """Where the recording is now (final name once completed)."""
        return self.kept_as or self.out


def config_json(obj) -> str:
    return json.dumps(obj, sort_keys=True, default=str)


__all__ = ["RerunRecorder", "recording_id_for", "versions", "TrailBuffer", "config_json"]
