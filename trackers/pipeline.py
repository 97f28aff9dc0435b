"""The one frame loop: source → detector (only if a tracker needs it) → trackers → tracks rows
→ online metrics → hooks.

``pfscope record``, ``pfscope compare``, the benchmarks and the tests all run this loop; none
keeps a frame loop of its own.  What happens around it (a Rerun recording, a tracks file, a
progress bar, timing) is a :class:`Hook`.

Outcome rules (DESIGN.md, "nothing is lost"):

- a run ends ``completed`` (all frames), ``interrupted`` (``should_stop()`` became true, or a
  KeyboardInterrupt) or ``failed`` (any other exception, not only bad input);
- every hook's :meth:`Hook.end` sees the :class:`Outcome` (the reason and the frame), also when
  another hook's ``end`` fails, so each output can be finished or marked incomplete;
- a failure is re-raised after the hooks have ended.

Determinism: trackers carry their own seeded generators; the pipeline adds no randomness.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Mapping, Optional, Protocol, Sequence

from .api import Rows, StepResult, Tracker
from .data.sources import prefetch
from .errors import InputError
from .report import level_rank
from .types import Detections, Frame, GroundTruth


@dataclass(frozen=True)
class RunInfo:
    """What hooks learn before the first frame."""

    source: object                    # a pfscope.trackers.data.sources.Source
    trackers: Mapping[str, Tracker]   # lane name → tracker (insertion order = lane order)
    detector: Optional[str]           # detector name, None when no tracker needs one
    total: Optional[int]              # frames that will be read (None: unknown)
    level: Optional[str]
    has_gt: bool


@dataclass(frozen=True)
class FrameReport:
    """One frame, after every tracker stepped.  ``metrics[lane]`` is a
    :class:`~pfscope.trackers.eval.online.FrameMetrics` of the lane's live tracks (None without
    ground truth); ``step_seconds[lane]`` the tracker's wall time."""

    frame: Frame
    detections: Optional[Detections]
    gt: Optional[GroundTruth]
    results: Mapping[str, StepResult]
    metrics: Mapping[str, object]
    step_seconds: Mapping[str, float]


@dataclass(frozen=True)
class Outcome:
    """How a run ended: ``status`` is ``completed``, ``interrupted`` or ``failed``; ``frames``
    the frames fully processed; ``reason`` one line for a person; ``error`` the exception."""

    status: str
    frames: int
    reason: str
    error: Optional[BaseException] = None
    #: lane → sequence scores of its tracks file rows (computed before the hooks end, so a
    #: recorder can store them; empty without ground truth or when the run failed)
    scores: Mapping[str, dict] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status != "failed"


class Hook(Protocol):
    """Something that watches a run.  Every method is optional in spirit: subclass
    :class:`BaseHook` and override what you need."""

    def begin(self, info: RunInfo) -> None: ...

    def on_frame(self, report: FrameReport) -> None: ...

    def on_rows(self, lane: str, rows: Rows) -> None: ...

    def end(self, outcome: Outcome) -> None: ...


class BaseHook:
    def begin(self, info: RunInfo) -> None:
        pass

    def on_frame(self, report: FrameReport) -> None:
        pass

    def on_rows(self, lane: str, rows: Rows) -> None:
        pass

    def end(self, outcome: Outcome) -> None:
        pass


@dataclass
class RunResult:
    outcome: Outcome
    seconds: float
    rows: dict[str, Rows] = field(default_factory=dict)      # lane → tracks-file rows
    scores: dict[str, dict] = field(default_factory=dict)    # lane → evaluate() scores

    @property
    def frames(self) -> int:
        return self.outcome.frames

    @property
    def interrupted(self) -> bool:
        return self.outcome.status == "interrupted"


def resolve_detector_name(source, name: Optional[str]) -> str:
    """``file`` when the source has detections, else HOG people (unless ``name`` is given)."""
    if name:
        return name
    return "file" if getattr(source, "det", None) is not None else "hog"


def frames_to_read(source, frames: Optional[int], start: int = 1) -> Optional[int]:
    """How many frames a run of ``frames`` frames from frame ``start`` reads (None: unknown)."""
    length = getattr(source, "length", None)
    if length is not None:
        length = max(0, length - (start - 1))
    if frames is None:
        return length
    return min(frames, length) if length is not None else frames


def iter_frames(source, total: Optional[int], start: int = 1):
    """Frames ``start .. start + total - 1`` (indices stay those of the video).  A source whose
    ``frames()`` takes ``start`` seeks; any other is read from frame 1 and the first frames are
    skipped."""
    import inspect

    if start <= 1:
        yield from source.frames(total)
        return
    if "start" in inspect.signature(source.frames).parameters:
        yield from source.frames(total, start=start)
        return
    end = None if total is None else start - 1 + total
    for frame in source.frames(end):
        if frame.index >= start:
            yield frame


class TracksFileHook(BaseHook):
    """Writes one lane's rows as MOT text: under ``<name>.part`` while running, renamed to the
    final name when the run completed, to ``<name>.incomplete<suffix>`` when it failed or was
    interrupted (the final name is never touched then)."""

    def __init__(self, path, lane: Optional[str] = None):
        from .data.motio import TrackWriter

        self.lane = lane
        self.writer = TrackWriter(path)
        self.kept_as: Optional[Path] = None

    def on_rows(self, lane: str, rows: Rows) -> None:
        if self.lane is None or lane == self.lane:
            for f, ts in rows:
                self.writer.write(f, ts)

    def end(self, outcome: Outcome) -> None:
        if outcome.status == "completed":
            self.writer.close()
        else:
            self.kept_as = self.writer.abort()


def run(source, trackers: Mapping[str, Tracker] | Sequence[Tracker], *,
        frames: Optional[int] = None, level: Optional[str] = None,
        detector: Optional[str] = None, detector_options: Optional[dict] = None,
        hooks: Sequence[Hook] = (), should_stop: Optional[Callable[[], bool]] = None,
        keep_rows: bool = True, score: bool = True, start: int = 1,
        offline: bool = True) -> RunResult:
    """Run ``trackers`` (lane name → tracker, or a list: lanes named by ``tracker.name``) over
    ``source`` for ``frames`` frames (default all) and hand every frame to ``hooks``.

    ``level``: the report level asked of the trackers (None: no stage items but scalars and
    events).  ``detector``: name for :func:`~pfscope.trackers.detect.make_detector` (default:
    the source's own detections, else HOG), built only if some tracker ``needs_detections``.
    ``keep_rows``: keep each lane's rows in memory (for ``scores``; off for very long runs).
    ``start``: the first frame (1-based; frame indices stay the video's, and the scores cover
    frames ``start .. start + frames - 1``).
    ``offline`` (default): the source is a recording, so a tracker with a ``prepare(source,
    first, last)`` method may look at the frames of the run ahead of time before the first
    step (DBN-PHD: a temporal-median background); False (``--online``): a stream, no look ahead.
    """
    from .detect import make_detector

    if level is not None:
        level_rank(level)
    lanes: dict[str, Tracker] = dict(trackers) if isinstance(trackers, Mapping) else {}
    if not isinstance(trackers, Mapping):
        for t in trackers:
            if t.name in lanes:
                raise InputError(f"tracker listed twice: {t.name}")
            lanes[t.name] = t
    if not lanes:
        raise InputError("no tracker to run")
    need_det = any(t.needs_detections for t in lanes.values())
    det_name = resolve_detector_name(source, detector) if need_det else None
    if not getattr(source, "has_frames", True):
        _check_frameless(source, lanes, det_name)
    det_fn = None
    if det_name is not None:
        det_fn = make_detector(det_name, det_table=getattr(source, "det", None),
                               **(detector_options or {}))
    gt_table = getattr(source, "gt", None)
    evaluators = {}
    if gt_table is not None:
        from .eval import OnlineEvaluator

        evaluators = {name: OnlineEvaluator() for name in lanes}
    start = int(start)
    if start < 1:
        raise InputError(f"first frame must be >= 1, got {start}")
    length = getattr(source, "length", None)
    if length is not None and start > length:
        raise InputError(f"first frame {start} is past the end of "
                         f"{getattr(source, 'name', 'the source')} ({length} frames)")
    total = frames_to_read(source, frames, start)
    info = RunInfo(source, lanes, det_name, total, level, gt_table is not None)
    kept: dict[str, Rows] = {name: [] for name in lanes}

    def emit(name: str, rows: Rows) -> None:
        if keep_rows:
            kept[name].extend(rows)
        for h in hooks:
            h.on_rows(name, rows)

    done = 0
    outcome: Optional[Outcome] = None
    t0 = time.perf_counter()
    begun: list[Hook] = []
    current = None
    stream = None
    try:
        for h in hooks:
            h.begin(info)
            begun.append(h)
        if offline and total is not None:
            for tracker in lanes.values():
                prepare = getattr(tracker, "prepare", None)
                if prepare is not None:
                    prepare(source, start, start + total - 1)
        stream = iter_frames(source, total, start)
        ahead: list = []
        if getattr(source, "has_frames", False) and source.kind != "synthetic":
            stream = prefetch(stream)  # decode the next frames while this one is tracked
            # a recorded clip: trackers with an `upcoming(frame)` hear of the next frame
            # before stepping this one (DBN-PHD starts its background stage on a thread)
            ahead = [up for up in (getattr(t, "upcoming", None) for t in lanes.values())
                     if callable(up)]
        for frame, nxt in (with_next(stream) if ahead else ((f, None) for f in stream)):
            if should_stop is not None and should_stop():
                break
            if nxt is not None:
                for up in ahead:
                    up(nxt)
            current = frame.index
            dets = det_fn(frame) if det_fn is not None else None
            gt = gt_table.ground_truth(frame.index) if gt_table is not None else None
            results, metrics, secs = {}, {}, {}
            for name, tracker in lanes.items():
                ts = time.perf_counter()
                res = tracker.step(frame, dets if tracker.needs_detections else None, level)
                secs[name] = time.perf_counter() - ts
                results[name] = res
                metrics[name] = (evaluators[name].update(frame.index, gt, res.tracks)
                                 if gt is not None else None)
            report = FrameReport(frame, dets, gt, results, metrics, secs)
            for h in hooks:
                h.on_frame(report)
            for name, res in results.items():
                emit(name, res.rows)
            done += 1
        # rows a tracker still holds back belong to frames already done: emit them also when
        # the run was stopped, so an interrupted tracks file has every frame done so far
        for name, tracker in lanes.items():
            emit(name, tracker.finish())
        scores = ({name: score_rows(gt_table, rows, done, start) for name, rows in kept.items()}
                  if score and keep_rows and gt_table is not None and done else {})
        if should_stop is not None and should_stop():
            outcome = Outcome("interrupted", done, f"interrupted after {done} frames",
                              scores=scores)
        else:
            outcome = Outcome("completed", done, f"completed: {done} frames", scores=scores)
    except KeyboardInterrupt as e:
        outcome = Outcome("interrupted", done, f"interrupted after {done} frames", e)
    except BaseException as e:  # noqa: BLE001 - every failure must mark the outputs incomplete
        where = f" at frame {current}" if current is not None else ""
        outcome = Outcome("failed", done, f"failed{where}: {type(e).__name__}: {e}"
                          if not isinstance(e, InputError) else f"failed{where}: {e}", e)
    if stream is not None and hasattr(stream, "close"):
        stream.close()  # stops the frame reader thread (bounded)
    seconds = time.perf_counter() - t0
    hook_error: Optional[BaseException] = None
    for h in begun:
        try:
            h.end(outcome)
        except BaseException as e:  # noqa: BLE001 - end every hook, report the first failure
            hook_error = hook_error or e
    if outcome.status == "failed" and outcome.error is not None:
        raise outcome.error
    if hook_error is not None:
        raise hook_error
    result = RunResult(outcome, seconds, kept if keep_rows else {})
    result.scores = dict(outcome.scores)
    return result


def _check_frameless(source, lanes: Mapping[str, Tracker], det_name: Optional[str]) -> None:
    """A source without frames (blank stand-ins of the declared size) runs only trackers that
    work from detections, on its detections file: anything else is refused in one line."""
    where = getattr(source, "location", "") or getattr(source, "name", "the source")
    for name, t in lanes.items():
        if t.needs_image and not getattr(t, "image_optional", False):
            raise InputError(f"{where}: no frames (img1/ missing, detections only): tracker "
                             f"{t.name} needs pixels; run phd, mt or passthrough on it")
    if det_name is not None and det_name != "file":
        raise InputError(f"{where}: no frames (img1/ missing, detections only): detector "
                         f"{det_name!r} needs pixels; use the detections file (--detector file)")


def with_next(frames: Iterator[Frame]) -> Iterator[tuple[Frame, Optional[Frame]]]:
    """``(frame, next frame or None)`` pairs: the next frame is read before ``frame`` is
    handed out.  An error reading it is raised after ``frame`` (as ``frames`` would)."""
    it = iter(frames)
    cur = next(it, None)
    while cur is not None:
        try:
            nxt = next(it, None)
        except BaseException:
            yield cur, None
            raise
        yield cur, nxt
        cur = nxt


def score_rows(gt_table, rows: Rows, frames: int, start: int = 1) -> dict:
    """Sequence scores of a lane's tracks-file rows over frames ``start..start + frames - 1``."""
    from .data.motio import table_from_tracksets
    from .eval import evaluate

    return evaluate(gt_table, table_from_tracksets(rows), frames=range(start, start + frames))


__all__ = ["run", "RunInfo", "FrameReport", "Outcome", "Hook", "BaseHook", "RunResult",
           "TracksFileHook", "resolve_detector_name", "frames_to_read", "iter_frames",
           "with_next", "score_rows"]
