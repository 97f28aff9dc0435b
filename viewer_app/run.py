"""``pfscope record``: run a tracker over a source and write tracks and a Rerun recording.

Safety rules the code keeps:
- an existing recording or tracks file is never overwritten unless ``force``;
- all input is opened and validated before the output file is created;
- Ctrl-C (SIGINT) and SIGTERM finish the file so it stays readable (and say so inside it);
- data is flushed about once a second, so even SIGKILL leaves a readable file missing at most
  about a second of frames;
- a run that fails on bad input mid-way is closed and renamed ``*.incomplete.rrd`` so it
  never looks like a complete recording.
"""

from __future__ import annotations

import json
import os
import platform
import signal
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from pfscope.trackers import __version__
from pfscope.trackers.base import make_tracker
from pfscope.trackers.data.motio import TrackWriter
from pfscope.trackers.data.sources import Source
from pfscope.trackers.detect import make_detector
from pfscope.trackers.errors import InputError
from pfscope.trackers.observer import level_rank

RECORDINGS_DIR = Path("recordings")
WEB_PORT = 9090


class StopFlag:
    """SIGINT/SIGTERM set a flag that the frame loop checks, instead of raising at an arbitrary
    point (possibly inside the recording library, holding its locks).  A second signal raises
    KeyboardInterrupt for a user who really wants out."""

    def __init__(self):
        self.requested = False
        self._old = {}

    def _handler(self, signum, _frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)
        return False


@dataclass
class RecordOptions:
    tracker: str = "phd"
    detector: Optional[str] = None  # None: 'file' when the source has detections, else 'hog'
    min_score: float = float("-inf")
    level: str = "clusters"
    max_points: int = 3000
    frames: Optional[int] = None
    seed: int = 0
    force: bool = False
    tracks_out: Optional[Path] = None
    spawn: bool = False
    serve: bool = False
    trails: int = 30
    tracker_options: dict = field(default_factory=dict)


@dataclass
class RecordResult:
    out: Path
    frames: int
    seconds: float
    interrupted: bool
    tracks_out: Optional[Path]
    bytes: int
    scores: dict = field(default_factory=dict)  # tracker name -> evaluate() keys, when gt exists


def default_out_path(source: Source, tracker: str) -> Path:
    return RECORDINGS_DIR / f"{source.name}-{tracker}.rrd"


def check_output(path: Path, force: bool, what: str = "recording") -> Path:
    """Refuse to overwrite without ``force``; make sure the folder exists and is writable."""
    path = Path(path)
    if path.exists() and not force:
        raise InputError(f"{path}: {what} exists; pass --force to overwrite it")
    if path.exists() and path.is_dir():
        raise InputError(f"{path}: is a folder, not a {what} file")
    parent = path.parent if str(path.parent) else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"{parent}: cannot create output folder ({e.strerror or e})") from None
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{parent}: output folder is not writable")
    return path


def _versions() -> dict:
    import cv2
    import rerun
    import scipy

    return {"pfscope": __version__, "rerun-sdk": rerun.__version__, "numpy": np.__version__,
            "scipy": scipy.__version__, "opencv": cv2.__version__,
            "python": platform.python_version()}


class Progress:
    """A one-line progress bar on stderr (a line every ~10 % when stderr is not a terminal)."""

    def __init__(self, total: Optional[int], label: str, stream=None, enabled: bool = True):
        self.total, self.label, self.enabled = total, label, enabled
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.perf_counter()
        self._last_draw = 0.0
        self._last_decile = -1

    def update(self, done: int) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        rate = done / max(now - self.t0, 1e-9)
        if self.tty:
            if now - self._last_draw < 0.1 and done != self.total:
                return
            self._last_draw = now
            if self.total:
                frac = min(done / self.total, 1.0)
                bar = "#" * int(frac * 30)
                eta = (self.total - done) / rate if rate > 0 else 0
                msg = f"\r{self.label} [{bar:<30}] {done}/{self.total} {rate:5.1f} fps ETA {eta:4.0f}s"
            else:
                msg = f"\r{self.label} {done} frames {rate:5.1f} fps"
            self.stream.write(msg)
            self.stream.flush()
        else:
            decile = int(10 * done / self.total) if self.total else done // 100
            if decile != self._last_decile:
                self._last_decile = decile
                tot = f"/{self.total}" if self.total else ""
                self.stream.write(f"{self.label}: {done}{tot} frames, {rate:.1f} fps\n")
                self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


class TrailBuffer:
    """Recent centres of each live track (bounded: ``length`` points per track, tracks unseen
    for ``forget`` frames are dropped)."""

    def __init__(self, length: int = 30, forget: int = 50):
        self.length, self.forget = length, forget
        self.trails: dict[int, deque] = {}
        self.last_seen: dict[int, int] = {}

    def update(self, frame: int, ids: np.ndarray, boxes: np.ndarray):
        centres = boxes[:, :2] + boxes[:, 2:] / 2.0
        for tid, c in zip(ids.tolist(), centres):
            self.trails.setdefault(tid, deque(maxlen=self.length)).append(c)
            self.last_seen[tid] = frame
        for tid in [t for t, f in self.last_seen.items() if frame - f > self.forget]:
            del self.trails[tid], self.last_seen[tid]
        live = [t for t in ids.tolist() if len(self.trails[t]) >= 2]
        return np.asarray(live, dtype=np.int64), [np.asarray(self.trails[t]) for t in live]


def resolve_detector_name(source: Source, name: Optional[str]) -> str:
    if name:
        return name
    return "file" if source.det is not None else "hog"


class _Lane:
    """One tracker's run inside a recording: its observer (under its own root when several
    trackers share a recording), trails, online metrics and output rows."""

    def __init__(self, name: str, tracker, obs, gt_available: bool, writer=None):
        from pfscope.trackers.eval import OnlineEvaluator

        self.name, self.tracker, self.obs, self.writer = name, tracker, obs, writer
        self.trails = TrailBuffer()
        self.lagged = hasattr(tracker, "pop_final")  # rows finalised with a bounded lag
        self.rows: list = []  # (frame, TrackSet) as written to the tracks file
        self.evaluator = OnlineEvaluator() if gt_available else None

    def step(self, frame, dets, gt) -> None:
        obs = self.obs
        tracks = self.tracker.step(frame, dets, obs)
        obs.stage("output")
        obs.boxes("tracks", tracks.boxes, ids=tracks.ids, radii=2.0)
        live, strips = self.trails.update(frame.index, tracks.ids, tracks.boxes)
        obs.strips("tracks/trails", strips, ids=live)
        obs.scalar("tracks/count", len(tracks))
        if self.evaluator is not None:
            self._metrics(frame.index, gt, tracks)
        self._emit(self.tracker.pop_final() if self.lagged else [(frame.index, tracks)])

    def _emit(self, rows) -> None:
        self.rows.extend(rows)
        if self.writer:
            for f_index, ts in rows:
                self.writer.write(f_index, ts)

    def finish(self, completed: bool) -> None:
        if self.lagged and completed:
            self._emit(self.tracker.finish())
        if self.writer:
            self.writer.close()

    def _metrics(self, frame: int, gt, tracks) -> None:
        """Per-frame metrics of what the view shows at this frame, plus marks on the boxes
        that are misses, false positives and identity switches."""
        m = self.evaluator.update(frame, gt, tracks)
        obs = self.obs
        obs.scalar("metrics/ospa", m.ospa)
        obs.scalar("metrics/cardinality/true", m.n_true)
        obs.scalar("metrics/cardinality/estimated", m.n_est)
        obs.scalar("metrics/fp", m.fp)
        obs.scalar("metrics/fn", m.fn)
        obs.scalar("metrics/idsw", m.idsw)
        obs.boxes("metrics/misses", gt.boxes[m.fn_idx], colors=(255, 40, 40, 255), radii=2.5,
                  labels=[f"miss gt {i}" for i in gt.ids[m.fn_idx]])
        obs.boxes("metrics/false_positives", tracks.boxes[m.fp_idx], colors=(255, 0, 255, 255),
                  radii=2.5, labels=[f"FP {i}" for i in tracks.ids[m.fp_idx]])
        obs.boxes("metrics/switches", tracks.boxes[m.switch_idx], colors=(255, 255, 255, 255),
                  radii=3.0, labels=[f"ID switch: {i}" for i in tracks.ids[m.switch_idx]])
        if m.idsw:
            obs.text("metrics", f"frame {frame}: {m.idsw} identity switch(es): tracks "
                                f"{', '.join(str(i) for i in tracks.ids[m.switch_idx])}", "WARN")


def record(source: Source, out: Path, opts: RecordOptions, *, trackers: Optional[list] = None,
           progress: bool = True, on_frame: Optional[Callable[[int], None]] = None) -> RecordResult:
    """Run ``opts.tracker`` (or each of ``trackers``, each under its own root) on ``source`` and
    write the recording to ``out``."""
    import rerun as rr

    from .blueprint import compare_blueprint, default_blueprint
    from .recorder import RerunObserver, recording_id_for

    level_rank(opts.level)
    names = list(trackers or [opts.tracker])
    if len(set(names)) != len(names):
        raise InputError(f"tracker listed twice: {','.join(names)}")
    out = check_output(Path(out), opts.force)
    tracks_out = check_output(Path(opts.tracks_out), opts.force, "tracks file") \
        if opts.tracks_out and len(names) == 1 else None
    det_name = resolve_detector_name(source, opts.detector)
    detector = make_detector(det_name, det_table=source.det,
                             **({"min_score": opts.min_score} if det_name == "file" else {}))
    try:
        built = [make_tracker(n, seed=opts.seed, **opts.tracker_options) for n in names]
    except ValueError as e:
        raise InputError(str(e)) from None
    total = source.length if opts.frames is None else (
        min(opts.frames, source.length) if source.length else opts.frames)

    config = {
        "trackers": ",".join(names), "detector": det_name, "min_score": opts.min_score,
        "level": opts.level, "max_points": opts.max_points, "frames": total, "seed": opts.seed,
        "source": json.dumps(source.describe(), sort_keys=True, default=str),
        "tracker_config": json.dumps([t.config() for t in built], sort_keys=True, default=str),
    }
    rec = rr.RecordingStream("pfscope", recording_id=recording_id_for(config),
                             send_properties=False)
    if len(built) == 1:
        blueprint = default_blueprint(*getattr(built[0], "views", lambda: ([], []))())
    else:
        blueprint = compare_blueprint(names)
    rec.save(str(out), default_blueprint=blueprint)
    if opts.spawn:
        rec.spawn(connect=False)
        rec.set_sinks(rr.FileSink(str(out)), rr.GrpcSink(), default_blueprint=blueprint)
    elif opts.serve:
        grpc = rr.GrpcServerSink()
        rec.set_sinks(rr.FileSink(str(out)), grpc, default_blueprint=blueprint)
        rr.serve_web_viewer(web_port=WEB_PORT, connect_to=grpc.uri, open_browser=False)
        uri = grpc.uri.replace("0.0.0.0", "127.0.0.1")
        print(f"web viewer: http://127.0.0.1:{WEB_PORT}/?url={uri}", file=sys.stderr)
    rec.send_recording_name(f"{source.name} · {' vs '.join(names)}")
    rec.send_property("config", rr.AnyValues(**{k: str(v) for k, v in config.items()}))
    rec.send_property("versions", rr.AnyValues(**_versions()))

    obs = RerunObserver(rec, level=opts.level, max_points=opts.max_points)
    has_gt = source.gt is not None
    lanes = []
    for name, tracker in zip(names, built):
        lane_obs = obs if len(built) == 1 else RerunObserver(
            rec, level=opts.level, max_points=opts.max_points, root=name)
        lanes.append(_Lane(name, tracker, lane_obs, has_gt,
                           TrackWriter(tracks_out) if tracks_out else None))
    bar = Progress(total, f"{' + '.join(names)} on {source.name}", enabled=progress)
    interrupted = False
    failed: Optional[InputError] = None
    done = 0
    stop = StopFlag().__enter__()
    t0 = time.perf_counter()
    try:
        for frame in source.frames(total):
            if stop.requested:
                break
            obs.begin_frame(frame)
            dets = detector(frame)
            obs.boxes("detections", dets.boxes,
                      labels=[f"{s:.2f}" for s in dets.scores] if len(dets) < 100 else None)
            obs.scalar("detections/count", len(dets))
            gt = source.gt.ground_truth(frame.index) if has_gt else None
            if has_gt:
                obs.boxes("gt", gt.boxes, labels=[f"gt {i}" for i in gt.ids],
                          colors=(60, 255, 60, 255))
            for lane in lanes:
                if lane.obs is not obs:
                    lane.obs.begin_frame(frame, image=False)
                lane.step(frame, dets, gt)
                if lane.obs is not obs:
                    lane.obs.end_frame()
            obs.end_frame()
            done += 1
            bar.update(done)
            if on_frame:
                on_frame(done)
    except KeyboardInterrupt:
        stop.requested = True
    except InputError as e:
        failed = e
        obs.text("", f"run failed: {e}", level="ERROR")
    finally:
        if stop.requested:
            interrupted = True
            obs.text("", f"run interrupted after {done} frames", level="WARN")
        stop.__exit__()
        bar.close()
        for lane in lanes:
            lane.finish(completed=failed is None)
        rec.flush()
        rec.disconnect()
    seconds = time.perf_counter() - t0
    if failed is not None:
        bad = out.with_name(out.stem + ".incomplete.rrd")
        os.replace(out, bad)
        raise InputError(f"{failed} (partial recording kept as {bad})")
    scores = {}
    if has_gt and done:
        scores = {lane.name: score_rows(source, lane.rows, done) for lane in lanes}
    return RecordResult(out=out, frames=done, seconds=seconds, interrupted=interrupted,
                        tracks_out=tracks_out, bytes=out.stat().st_size, scores=scores)


def score_rows(source: Source, rows, frames: int) -> dict:
    """Sequence scores of a run's tracks (as written to the tracks file) over its frames."""
    from pfscope.trackers.data.motio import table_from_tracksets
    from pfscope.trackers.eval import evaluate

    return evaluate(source.gt, table_from_tracksets(rows), frames=range(1, frames + 1))
