"""The Python API (``import pfscope``): :func:`record` writes a recording and returns a
:class:`RecordResult`; :func:`stream` yields per-frame results with no recording at all.

    import pfscope
    res = pfscope.record("../shared/data/PETS09-S2L1", tracker="phd", out="x.rrd",
                         level="particles", frames=200, p_miss=0.1)
    print(res.out, res.frames, res.fps, res.scores["phd"]["MOTA"])

    for fr in pfscope.stream("../shared/data/PETS09-S2L1", tracker="phd", frames=50):
        print(fr.index, fr.tracks.ids, fr.metrics.ospa if fr.metrics else None)

Both run the engine's one pipeline (the CLI is a thin layer over the same functions).
Tracker parameters are keyword arguments (``p_miss=0.2``, dotted names as
``**{"filter.motion.sigma_v": 0.05}``); ``tracker`` may be a variant ``"phd[p_miss=0.2]"`` or,
for :func:`record`, a list of them (one lane each, like ``pfscope compare``).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Optional, Sequence, Union

SourceLike = Union[str, Path, None, Any]


def _api_words(e: BaseException, fn) -> BaseException:
    """The same one-line error in the words of a Python caller: a command-line flag that is a
    keyword of ``fn`` becomes the keyword (``--force`` → ``force=True``, ``--tracks-out`` →
    ``tracks_out``).  The engine's messages speak the CLI's words, as most users type them."""
    import inspect
    import re

    from pfscope.trackers.errors import InputError

    if not isinstance(e, InputError):
        return e
    keywords = set(inspect.signature(fn).parameters)

    def word(m: "re.Match") -> str:
        name = m.group(1).replace("-", "_")
        if name not in keywords:
            return m.group(0)
        return f"{name}=True" if name in ("force", "timing") else name

    msg = re.sub(r"(?<![\w-])--([a-z][a-z0-9-]*)", word, str(e))
    return e if msg == str(e) else type(e)(msg)


def open_source(source: SourceLike, *, frames: Optional[int] = None, start: int = 1,
                fps: Optional[float] = None, synthetic_seed: int = 0, **scene):
    """A :class:`~pfscope.trackers.data.sources.Source` from a path, ``"synthetic"`` / None (the
    built-in scene, ``demo_config``; ``scene`` are :class:`SceneConfig` fields), or a Source itself."""
    from pfscope.trackers.data.sources import Source
    from pfscope.trackers.data.sources import open_source as _open

    if isinstance(source, Source):
        return source
    if source is None or str(source) == "synthetic":
        from pfscope.trackers.data.synthetic import demo_config

        kw = dict(scene, seed=synthetic_seed)
        if frames is not None:
            kw["frames"] = start - 1 + frames
        return _open(None, synthetic_config=demo_config(**kw))
    return _open(source, fps=fps)


@dataclass
class RecordResult:
    """What :func:`record` returns.  ``out``: the recording (``.incomplete.rrd`` when the run
    was interrupted); ``tracks_out``: the MOT tracks file, if asked; ``frames``: frames
    processed, from ``start``; ``seconds``: wall time of the run; ``scores``: lane →
    sequence scores (with ground truth)."""

    out: Path
    tracks_out: Optional[Path]
    frames: int
    start: int
    seconds: float
    bytes: int
    interrupted: bool
    lanes: list
    scores: dict

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    @property
    def paths(self) -> dict:
        return {"recording": self.out, "tracks": self.tracks_out}


def record(source: SourceLike = None, tracker: Union[str, Sequence[str]] = "phd", *,
           out: Union[str, Path, None] = None, level: str = "particles",
           frames: Optional[int] = None, start: int = 1, seed: int = 0,
           detector: Optional[str] = None, min_score: float = float("-inf"),
           preset: Optional[str] = None, tracks_out: Union[str, Path, None] = None,
           force: bool = False, progress: bool = False, max_points: int = 3000,
           timing: bool = False, fps: Optional[float] = None, synthetic_seed: Optional[int] = None,
           stop: Optional[threading.Event] = None, **params) -> RecordResult:
    """Run ``tracker`` on ``source`` and write a Rerun recording (see the module docstring).
    ``out`` defaults to ``recordings/<source>-<tracker>.rrd``; an existing file is refused
    unless ``force``.  Bad input raises :class:`~pfscope.trackers.errors.InputError`."""
    from .lanes import lane_name, split_specs
    from .run import RECORDINGS_DIR, RecordOptions
    from .run import record as _record

    lanes = split_specs(tracker) if isinstance(tracker, str) else list(tracker)
    src = open_source(source, frames=frames, start=start, fps=fps,
                      synthetic_seed=seed if synthetic_seed is None else synthetic_seed)
    if out is None:
        name = lane_name(lanes[0]) if len(lanes) == 1 else "compare"
        out = RECORDINGS_DIR / f"{src.name}-{name}.rrd"
    opts = RecordOptions(tracker=lanes[0], detector=detector, min_score=min_score, level=level,
                         max_points=max_points, frames=frames, start=start, seed=seed,
                         force=force, tracks_out=Path(tracks_out) if tracks_out else None,
                         preset=preset, timing=timing,
                         tracker_options={k: v for k, v in params.items()})
    try:
        res = _record(src, Path(out), opts, trackers=lanes, progress=progress, stop=stop)
    except Exception as e:
        new = _api_words(e, record)
        if new is e:
            raise
        raise new from None
    return RecordResult(out=res.out, tracks_out=res.tracks_out, frames=res.frames,
                        start=res.start, seconds=res.seconds, bytes=res.bytes,
                        interrupted=res.interrupted, lanes=res.lanes, scores=res.scores)


@dataclass(frozen=True)
class FrameResult:
    """One frame of :func:`stream`: ``tracks`` (a TrackSet: ``ids``, ``boxes`` x,y,w,h) the
    tracker reports at this frame, ``rows`` final tracks-file rows, ``metrics`` a FrameMetrics
    (None without ground truth), ``stages`` the typed stage data (with ``level``), ``seconds``
    the tracker's step time.  ``frame`` is the Frame (index, timestamp, image)."""

    frame: Any
    tracks: Any
    rows: list
    metrics: Any
    stages: tuple
    seconds: float
    detections: Any = None
    gt: Any = None

    @property
    def index(self) -> int:
        return int(self.frame.index)


def stream(source: SourceLike = None, tracker: str = "phd", *, frames: Optional[int] = None,
           start: int = 1, seed: int = 0, level: Optional[str] = None,
           detector: Optional[str] = None, min_score: float = float("-inf"),
           preset: Optional[str] = None, fps: Optional[float] = None,
           synthetic_seed: Optional[int] = None, **params) -> Iterator[FrameResult]:
    """Yield a :class:`FrameResult` per frame, recording nothing.  The pipeline runs in a
    helper thread one frame ahead at most; leaving the loop early (``break``) stops it."""
    import queue

    import numpy as np

    from pfscope.trackers.api import make_params, tracker_info
    from pfscope.trackers.errors import InputError
    from pfscope.trackers.pipeline import BaseHook, run

    from .lanes import parse_lane
    from .run import _options_for

    lane = parse_lane(tracker)
    src = open_source(source, frames=frames, start=start, fps=fps,
                      synthetic_seed=seed if synthetic_seed is None else synthetic_seed)
    try:
        info = tracker_info(lane.tracker)
        p = make_params(lane.tracker, preset,
                        {**_options_for(lane.tracker, params, 1), **lane.options})
    except ValueError as e:
        raise _api_words(InputError(str(e)), stream) from None
    trk = info.cls(p, rng=np.random.default_rng(seed))
    det_opts = {"min_score": min_score} if (detector or "file") == "file" else {}
    q: "queue.Queue" = queue.Queue(maxsize=1)
    stop = threading.Event()
    END = object()

    class _Hand(BaseHook):
        def on_frame(self, r) -> None:
            res = r.results[lane.name]
            item = FrameResult(r.frame, res.tracks, list(res.rows), r.metrics.get(lane.name),
                               tuple(res.stages), r.step_seconds.get(lane.name, 0.0),
                               r.detections, r.gt)
            while not stop.is_set():
                try:
                    q.put(item, timeout=0.1)
                    return
                except queue.Full:
                    continue

    def work():
        try:
            run(src, {lane.name: trk}, frames=frames, start=start, level=level,
                detector=detector, detector_options=det_opts if trk.needs_detections else None,
                hooks=[_Hand()], should_stop=stop.is_set, keep_rows=False, score=False)
            q.put(END)
        except BaseException as e:  # noqa: BLE001 - handed to the consumer
            q.put(e)

    t = threading.Thread(target=work, name="pfscope-stream", daemon=True)
    t.start()
    try:
        while True:
            item = q.get()
            if item is END:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        while t.is_alive():
            try:
                q.get(timeout=0.05)
            except queue.Empty:
                pass
        t.join()


__all__ = ["record", "stream", "RecordResult", "FrameResult", "open_source"]
