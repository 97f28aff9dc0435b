"""``pfscope record`` / ``compare``: the engine's pipeline with the app's hooks (the Rerun
recorder, the tracks file, the progress bar) and signal handling.

Safety rules the code keeps:
- an existing recording or tracks file is never overwritten unless ``force``, and then only
  by a run that completed;
- all input is opened and validated before the output file is created;
- outputs are written as ``*.incomplete.rrd`` / ``*.txt.part`` and take their final names only
  when the run completed; a run that failed (for any reason) or was interrupted keeps
  ``*.incomplete.*`` names, and the recording's last entry says why it stopped;
- Ctrl-C (SIGINT) and SIGTERM stop at the next frame and finish the file so it stays readable;
- data is flushed every 20 frames, so even SIGKILL leaves a readable file.
"""

from __future__ import annotations

import collections
import contextlib
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from pfscope.trackers.data.sources import Source
from pfscope.trackers.errors import InputError, RunFailed
from pfscope.trackers.pipeline import BaseHook
from pfscope.trackers.outputs import OutputLock, incomplete_path, refuse_inputs
from pfscope.trackers.outputs import check_output as _check_output
from pfscope.trackers.report import level_rank

RECORDINGS_DIR = Path("recordings")
WEB_PORT = 9090


class StopFlag:
    """SIGINT/SIGTERM set a flag that the frame loop checks, instead of raising at an arbitrary
    point (possibly inside the recording library, holding its locks).  A second signal raises
    KeyboardInterrupt for a user who really wants out.

    Signal handlers can only be installed from the main thread: from another thread (a server,
    a notebook's worker) none are, and the run stops when ``event`` (a ``threading.Event``
    the caller holds) is set."""

    def __init__(self, event: Optional[threading.Event] = None):
        self._requested = False
        self.event = event
        self._old: dict = {}

    @property
    def requested(self) -> bool:
        return self._requested or (self.event is not None and self.event.is_set())

    def _handler(self, signum, frame):
        from pfscope.trackers.jobs import note_signal

        if self._requested:
            raise KeyboardInterrupt
        self._requested = True
        note_signal(signum)  # the exit status says which signal (130 SIGINT, 143 SIGTERM)
        old = self._old.get(signum)
        if callable(old) and old not in (self._handler, signal.default_int_handler):
            old(signum, frame)  # a job runner around this run stops its queue too

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
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
    level: str = "particles"
    max_points: int = 3000
    frames: Optional[int] = None
    start: int = 1                     # first frame (frame indices stay the video's)
    seed: int = 0
    force: bool = False
    tracks_out: Optional[Path] = None
    spawn: bool = False
    serve: bool = False
    preset: Optional[str] = None       # None: each tracker's first (default) preset
    timing: bool = False               # record per-step wall time (breaks byte-identical reruns)
    tracker_options: dict = field(default_factory=dict)
    long_miss: int = 10                # failure index: a gt unmatched this many frames in a row
    video: str = "encode"              # encode | source | auto (recorder.VIDEO_MODES)
    online: bool = False               # a stream: trackers get no look at the clip ahead
    inputs: tuple = ()                 # other files the run reads (a --params file)


@dataclass
class RecordResult:
    out: Path
    frames: int
    seconds: float
    interrupted: bool
    tracks_out: Optional[Path]
    bytes: int
    scores: dict = field(default_factory=dict)  # lane name -> evaluate() keys, when gt exists
    start: int = 1                              # first frame of the run
    lanes: list = field(default_factory=list)   # lane names, in order
    serve_url: Optional[str] = None             # record --serve: the web viewer's URL
    grpc_port: Optional[int] = None             # ... and the port of its gRPC server


def _web_port() -> int:
    """WEB_PORT when it is free here, else any free port (the URL is printed)."""
    import socket

    from .serve import free_port

    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", WEB_PORT))
            return WEB_PORT
        except OSError:
            return free_port()


def default_out_path(source: Source, tracker: str) -> Path:
    return RECORDINGS_DIR / f"{source.name}-{tracker}.rrd"


def check_output(path: Path, force: bool, what: str = "recording") -> Path:
    """See :func:`pfscope.trackers.outputs.check_output`."""
    return _check_output(path, force, what)


def run_inputs(source: Source, params=(), extra=()) -> list:
    """The files and folders a run reads: the source (a sequence folder stands for its images,
    det, gt and seqinfo), files named by parameters (a model), and ``extra`` (a --params file)."""
    from pfscope.trackers.params import leaves

    reads: list = []
    loc = getattr(source, "location", "")
    if loc and Path(loc).exists():
        reads.append(Path(loc))
    for p in params:
        for _, _, v in leaves(p):
            if isinstance(v, (str, os.PathLike)) and str(v) and os.path.isfile(str(v)):
                reads.append(Path(v))
    reads += [Path(x) for x in extra if x]
    return reads


def display_available() -> bool:
    """A native viewer needs a display (and the ``rerun`` binary)."""
    import shutil

    has_display = sys.platform in ("darwin", "win32") or bool(
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    viewer = shutil.which("rerun") or Path(sys.executable).with_name("rerun").exists()
    return has_display and bool(viewer)


class Progress:
    """A one-line progress bar on stderr (a line every ~10 % when stderr is not a terminal).

    The fps shown is the *recent* rate: frames over the last ``window`` seconds (at least the
    last two frame times), so a busy minute does not colour the rest of the run; the ETA is
    the frames left at that rate.  The first frame carries one-off costs (first calls, the
    recording's first frame: 0.2-0.8 s where later frames take 0.04-0.2): its line shows its
    time instead of a rate, and from the second frame on the rate counts from its end.  The
    clock starts at :meth:`start` (the pipeline's ``begin``, after the kernels are ready), or
    at the first :meth:`update` if nobody called it.  ``clock`` is injectable for tests."""

    def __init__(self, total: Optional[int], label: str, stream=None, enabled: bool = True,
                 clock: Callable[[], float] = time.perf_counter, window: float = 2.0):
        self.total, self.label, self.enabled = total, label, enabled
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.clock, self.window = clock, window
        self.t0: Optional[float] = None
        self._marks: collections.deque = collections.deque()   # (time, frames done)
        self._last_draw = -float("inf")
        self._last_decile = -1

    def start(self) -> None:
        """Frames start now: the rate's zero point."""
        self.t0 = self.clock()
        self._marks.clear()
        self._marks.append((self.t0, 0))

    def rate(self) -> float:
        """Frames per second over the recent window (0 before the first frame)."""
        if len(self._marks) < 2:
            return 0.0
        (t_a, n_a), (t_b, n_b) = self._marks[0], self._marks[-1]
        return (n_b - n_a) / max(t_b - t_a, 1e-9)

    def eta(self, done: int) -> Optional[float]:
        r = self.rate()
        return (self.total - done) / r if self.total and r > 0 else None

    def _mark(self, now: float, done: int) -> None:
        if self.t0 is None:        # no start(): the rate counts from this first update
            self.t0 = now
            self._marks.append((now, done))
            return
        self._marks.append((now, done))
        if done >= 2 and self._marks[0][1] == 0:     # the first frame's one-off costs out
            self._marks.popleft()
        # keep the marks of the last `window` seconds, and at least two frame intervals
        while len(self._marks) > 3 and now - self._marks[1][0] >= self.window:
            self._marks.popleft()

    def _first(self, done: int) -> Optional[float]:
        """The first frame's seconds while it is the only frame done (else None)."""
        if done == 1 and len(self._marks) == 2 and self._marks[0][1] == 0:
            return self._marks[1][0] - self._marks[0][0]
        return None

    def update(self, done: int) -> None:
        if not self.enabled:
            return
        now = self.clock()
        self._mark(now, done)
        rate, first = self.rate(), self._first(done)
        if self.tty:
            if now - self._last_draw < 0.1 and done != self.total:
                return
            self._last_draw = now
            speed = (f"first frame {first:.1f} s" if first is not None else
                     f"{rate:5.1f} fps")
            if self.total:
                frac = min(done / self.total, 1.0)
                bar = "#" * int(frac * 30)
                eta = self.eta(done)
                msg = (f"\r{self.label} [{bar:<30}] {done}/{self.total} {speed}" +
                       (f" ETA {eta if eta is not None else 0:4.0f}s" if first is None
                        else "        "))
            else:
                msg = f"\r{self.label} {done} frames {speed}"
            self.stream.write(msg)
            self.stream.flush()
        else:
            decile = int(10 * done / self.total) if self.total else done // 100
            if decile != self._last_decile:
                self._last_decile = decile
                tot = f"/{self.total}" if self.total else ""
                speed = (f"first frame {first:.1f} s" if first is not None else
                         f"{rate:.1f} fps")
                self.stream.write(f"{self.label}: {done}{tot} frames, {speed}\n")
                self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


SPINNER = "|/-\\"


class _CompileNotice:
    """ONE line on ``stream`` while numba compiles, once it has taken ``delay`` seconds: a
    spinner with ``msg`` (read live: it may change) and the seconds so far on a terminal,
    else ``log_msg`` (default ``msg``) once; ``stop`` ends the line with the total and, in a
    log, ``log_end()`` when given (what it turned out to be).  Nothing is written for a wait
    shorter than ``delay``."""

    def __init__(self, msg: str, stream=None, enabled: bool = True, delay: float = 1.0,
                 log_msg: Optional[str] = None, log_end: Optional[Callable[[], str]] = None,
                 tty_lead: str = ""):
        self.msg, self.enabled, self.delay = msg, enabled, delay
        self.log_msg, self.log_end = log_msg or msg, log_end
        self.tty_lead = tty_lead        # written once before the spinner (a terminal only)
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._done = threading.Event()
        self._shown: list = []
        self._th: Optional[threading.Thread] = None
        self.t0 = 0.0

    def start(self) -> None:
        self.t0 = time.perf_counter()
        self._done.clear()
        self._shown.clear()
        self._th = threading.Thread(target=self._spin, name="pfscope-compile-spinner",
                                    daemon=True)
        self._th.start()

    def _spin(self) -> None:
        if self._done.wait(self.delay) or not self.enabled:
            return
        self._shown.append(True)
        if self.tty and self.tty_lead:
            self.stream.write(self.tty_lead)
        i = 0
        while True:
            if self.tty:
                # (msg may change while it spins -- loading turns out to be compiling: pad)
                self.stream.write(f"\r{self.msg} {SPINNER[i % 4]} "
                                  f"{time.perf_counter() - self.t0:4.0f} s    ")
                self.stream.flush()
            elif i == 0:
                self.stream.write(f"{self.log_msg} ...")
                self.stream.flush()
            i += 1
            if self._done.wait(0.1):
                return

    def stop(self) -> float:
        self._done.set()
        if self._th is not None:
            self._th.join()
        secs = time.perf_counter() - self.t0
        if self._shown:
            end = f" {self.log_end()}" if self.log_end is not None else ""
            self.stream.write(f"\r{self.msg}: done in {secs:.1f} s          \n" if self.tty
                              else f"{end} done in {secs:.1f} s\n")
            self.stream.flush()
        return secs


def prepare_kernels(trackers, *, enabled: bool = True, stream=None, delay: float = 1.0) -> float:
    """Compile (first run after an install) or load (later runs) the numba kernels that
    ``trackers`` call, before the first frame, so the frame counter and its fps start with the
    frames.  When it takes longer than ``delay`` seconds, ONE line says so with a spinner and
    the seconds so far (a terminal), or once with its total (a log): "compiling" once numba
    has compiled something (its ``numba:compile`` event: a real compile, not a cache load),
    "loading" until then.  Returns the seconds."""
    from pfscope.trackers.warmup import (compile_kernels, index_kernel_needed,
                                         phd_kernels_needed, phd_presets_needed, uses_kernels)

    if not any(uses_kernels(t) for t in trackers):
        return 0.0
    from numba.core import event

    compiled: list = []
    notice = _CompileNotice(
        "pfscope: loading numba kernels from the cache", stream, enabled, delay,
        log_msg="pfscope: numba kernels",
        log_end=lambda: ("compiled (first run after an install; cached afterwards):"
                         if compiled else "loaded from the cache:"))

    class Compiling(event.Listener):
        def on_start(self, ev):
            compiled.append(True)
            notice.msg = ("pfscope: compiling numba kernels (first run after an install; "
                          "cached afterwards)")

        def on_end(self, ev):
            pass

    notice.start()
    try:
        with event.install_listener("numba:compile", Compiling()):
            compile_kernels(presets=phd_presets_needed(trackers),
                            phd=phd_kernels_needed(trackers),
                            index=index_kernel_needed(trackers), trackers=list(trackers))
    finally:
        secs = notice.stop()
    return secs


@contextlib.contextmanager
def compile_notices(trackers, *, enabled: bool = True, stream=None, delay: float = 1.0):
    """While the frames run: a kernel compiled on first need (the K-means grid search, for a
    frame with many detections; :mod:`pfscope.trackers.warmup`) says so in ONE line as
    :func:`prepare_kernels` does.  numba reports only real compiles (a load from its cache is
    silent), through its event API."""
    from pfscope.trackers.warmup import uses_kernels

    if not any(uses_kernels(t) for t in trackers):
        yield
        return
    from numba.core import event

    # (on a terminal the progress bar's line is open: the notice starts a line of its own)
    notice = _CompileNotice("pfscope: compiling numba kernels this frame needs (first time "
                            "after an install; cached afterwards)", stream, enabled, delay,
                            tty_lead="\n")
    depth = [0]

    class Listener(event.Listener):
        def on_start(self, ev):
            depth[0] += 1
            if depth[0] == 1:
                notice.start()

        def on_end(self, ev):
            depth[0] -= 1
            if depth[0] == 0:
                notice.stop()

    with event.install_listener("numba:compile", Listener()):
        yield


class ProgressHook(BaseHook):
    """The progress bar as a pipeline hook (its clock starts when the pipeline begins)."""

    def __init__(self, bar: Progress):
        self.bar = bar
        self.done = 0

    def begin(self, info) -> None:
        self.bar.start()

    def on_frame(self, report) -> None:
        self.done += 1
        self.bar.update(self.done)

    def end(self, outcome) -> None:
        self.bar.close()


def record(source: Source, out: Path, opts: RecordOptions, *, trackers: Optional[list] = None,
           progress: bool = True, on_frame: Optional[Callable[[int], None]] = None,
           stop: Optional[threading.Event] = None) -> RecordResult:
    """Run ``opts.tracker`` (or each of ``trackers``, each under its own root) on ``source``
    through the engine's pipeline and write the recording to ``out`` (and the tracks file).

    Safe to call from any thread: signals are handled only on the main thread; elsewhere set
    ``stop`` to end the run after the current frame (the outputs then stay ``.incomplete``)."""
    from pfscope.trackers.api import make_params, tracker_info

    try:
        level_rank(opts.level)
    except ValueError as e:
        raise InputError(str(e)) from None
    from .recorder import VIDEO_MODES

    if opts.video not in VIDEO_MODES:
        raise InputError(f"video: expected one of {', '.join(VIDEO_MODES)}, got {opts.video!r}")
    from .lanes import parse_lanes

    lanes = parse_lanes(list(trackers or [opts.tracker]))
    names = [ln.name for ln in lanes]
    if opts.start < 1:
        raise InputError(f"first frame must be >= 1, got {opts.start}")
    try:
        infos = [tracker_info(ln.tracker) for ln in lanes]
        params = [make_params(ln.tracker, opts.preset,
                              {**_options_for(ln.tracker, opts.tracker_options, len(names)),
                               **ln.options})
                  for ln in lanes]
    except ValueError as e:
        raise InputError(str(e)) from None
    from pfscope.trackers.warmup import start_helper_early

    start_helper_early([ln.tracker for ln in lanes])   # first run: compiles while we set up
    refuse_inputs([(Path(out), "recording"), (opts.tracks_out, "tracks file")],
                  run_inputs(source, params, opts.inputs))
    out = check_output(Path(out), opts.force)
    partial = incomplete_path(out)
    if partial.exists() and not opts.force:
        raise InputError(f"{partial}: left by an earlier run that did not complete (make it "
                         f"whole with `pfscope repair {partial}`); pass --force to replace it")
    tracks_out = check_output(Path(opts.tracks_out), opts.force, "tracks file") \
        if opts.tracks_out and len(names) == 1 else None
    if tracks_out is not None and tracks_out.resolve() == out.resolve():
        raise InputError(f"{tracks_out}: --tracks-out must differ from the recording file")
    live = "spawn" if opts.spawn else "serve" if opts.serve else None
    if live == "spawn" and not display_available():
        print("pfscope: --spawn: no display or no 'rerun' viewer here; writing the file only "
              "(use --serve for a web viewer)", file=sys.stderr)
        live = None
    locks = [OutputLock(p) for p in ([out] + ([tracks_out] if tracks_out else []))]
    held: list = []
    try:
        for lock in locks:
            held.append(lock.acquire())
        return _record_locked(source, out, opts, lanes, infos, params, tracks_out, live,
                              progress, on_frame, stop)
    finally:
        for lock in held:
            lock.release()


def _record_locked(source, out, opts, lanes, infos, params, tracks_out, live, progress,
                   on_frame, stop) -> RecordResult:
    from pfscope.trackers.pipeline import TracksFileHook, frames_to_read, resolve_detector_name
    from pfscope.trackers.pipeline import run as run_pipeline

    from .recorder import RerunRecorder, config_json

    names = [ln.name for ln in lanes]
    built = {n: info.cls(p, rng=np.random.default_rng(opts.seed))
             for n, info, p in zip(names, infos, params)}
    need_det = any(t.needs_detections for t in built.values())
    det_name = resolve_detector_name(source, opts.detector) if need_det else None
    det_opts = {"min_score": opts.min_score} if det_name == "file" else {}
    total = frames_to_read(source, opts.frames, opts.start)

    # what `pfscope info` shows: the preset each lane runs (its first one when none was given)
    preset_name = opts.preset or ", ".join(dict.fromkeys(next(iter(i.presets)) for i in infos))
    config = {
        "trackers": ",".join(names), "detector": det_name or "none",
        "min_score": opts.min_score, "level": opts.level, "max_points": opts.max_points,
        "frames": total, "seed": opts.seed, "preset": opts.preset or "default",
        "source": config_json(source.describe()),
        "tracker_config": config_json([t.config() for t in built.values()]),
    }
    if opts.start > 1:
        config["start"] = opts.start
    if opts.video != "encode":  # (absent by default: earlier recording ids stay the same)
        config["video"] = opts.video
    properties = {
        "run": {"lanes": names, "trackers": [ln.tracker for ln in lanes],
                "detector": det_name or "none", "min_score": opts.min_score,
                "level": opts.level, "max_points": opts.max_points, "first_frame": opts.start,
                "frames": total, "seed": opts.seed, "preset": preset_name,
                **({"video": opts.video} if opts.video != "encode" else {})},
        "source": source.describe(),
    }
    from pfscope.trackers.api import param_origins

    for ln, t, p in zip(lanes, built.values(), params):
        cfg = t.config()
        origins = param_origins(ln.tracker, opts.preset, p, source.fps)
        properties[f"tracker.{ln.name}"] = {
            "tracker": ln.tracker, "spec": ln.spec,
            "params": cfg.get("params", {}),
            # what `pfscope info` shows beside each value: the value in effect, and why
            "effective": {n: v for n, (v, _) in origins.items()},
            "origin": {n: o for n, (_, o) in origins.items()},
            **{k: v for k, v in cfg.items() if k not in ("params", "tracker")}}
    recorder = RerunRecorder(out, config, max_points=opts.max_points, live=live,
                             web_port=_web_port() if live == "serve" else WEB_PORT,
                             timing=opts.timing,
                             announce=lambda msg: print(msg, file=sys.stderr),
                             properties=properties, long_miss=opts.long_miss,
                             video=opts.video)
    hooks: list = [recorder]
    writer = None
    if tracks_out is not None:
        try:
            writer = TracksFileHook(tracks_out)
        except InputError:
            raise
        hooks.append(writer)
    hooks.append(ProgressHook(Progress(total, f"{' + '.join(names)} on {source.name}",
                                       enabled=progress)))
    if on_frame is not None:
        hooks.append(_CallbackHook(on_frame))
    prepare_kernels(built.values(), enabled=progress)
    with StopFlag(stop) as flag, compile_notices(built.values(), enabled=progress):
        try:
            res = run_pipeline(source, built, frames=opts.frames, start=opts.start,
                               level=opts.level,
                               detector=det_name, detector_options=det_opts, hooks=hooks,
                               should_stop=lambda: flag.requested,
                               offline=not opts.online)
        except InputError as e:
            raise InputError(f"{e} ({recorder.describe_kept()})") from None
        except Exception as e:
            failed = RunFailed(f"{type(e).__name__}: {e} ({recorder.describe_kept()})")
            # a recording whose writer is stuck (full disk) would also hang Rerun's exit
            # handler: the CLI must leave without it
            failed.stalled = recorder.broken  # type: ignore[attr-defined]
            raise failed from e
    final = recorder.path
    return RecordResult(out=final, frames=res.frames, seconds=res.seconds,
                        interrupted=res.interrupted,
                        tracks_out=(writer.kept_as or tracks_out) if writer else None,
                        bytes=final.stat().st_size, scores=res.scores, start=opts.start,
                        lanes=names, serve_url=recorder.serve_url,
                        grpc_port=recorder.grpc_port)


class _CallbackHook(BaseHook):
    def __init__(self, fn):
        self.fn, self.done = fn, 0

    def on_frame(self, report) -> None:
        self.done += 1
        self.fn(self.done)


def _options_for(name: str, options: dict, n_trackers: int) -> dict:
    """``--set`` options for tracker ``name``: ``phd.p_miss=0.2`` goes to ``phd`` only; a bare
    name goes to every tracker that has it (and must exist in at least one)."""
    from pfscope.trackers.api import tracker_info
    from pfscope.trackers.params import leaves

    out = {}
    for key, value in options.items():
        head, dot, rest = key.partition(".")
        if dot and head in _tracker_names():
            if head == name:
                out[rest] = value
            continue
        if n_trackers == 1:
            out[key] = value
            continue
        leaf_names = {n.rsplit(".", 1)[-1] for n, _, _ in leaves(tracker_info(name).params)}
        full_names = {n for n, _, _ in leaves(tracker_info(name).params)}
        if key in leaf_names or key in full_names:
            out[key] = value
    return out


def _tracker_names() -> set:
    from pfscope.trackers.api import tracker_summaries     # the names, no tracker imported

    return set(tracker_summaries())
