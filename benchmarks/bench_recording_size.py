"""Size and cost of a Rerun recording of PHD-MT at each level (tracks, clusters, particles).

Uses the app's own code path, :func:`viewer_app.run.record` with
``RecordOptions(tracker='phd', level=..., max_points=..., frames=N, seed=..., force=True)``
(``preset='paper'``, given explicitly, ``timing`` off so the same seed gives the
same bytes, no ``tracker_options``), writing into a temporary folder (deleted afterwards unless
``--keep DIR``), on a source's public detections (``file`` detector, as ``pfscope record``
picks for a MOT folder).  ``record`` runs the engine's one frame loop,
:func:`pfscope.trackers.pipeline.run`, with the :class:`~viewer_app.recorder.RerunRecorder`
hook; it writes ``<name>.incomplete.rrd`` and renames it to ``<name>.rrd`` when the run
completed, and this script measures the completed file.

For each source it reports:

- bytes per frame and MB for N frames at level ``tracks``, ``clusters`` and ``particles``,
  the last also with several ``--max-points`` caps (points per cloud; the recorder decimates
  bigger clouds with a fixed stride);
- how much of that is the video frame: every frame is logged as a JPEG
  (``RerunRecorder`` default quality), whose bytes are measured by encoding the same frames with
  OpenCV at that quality, and set beside the ``tracks`` level (the smallest recording:
  image + detections + GT + tracks + scalars + online metrics);
- where the rest goes: the recording is read back (``rerun.chunk.RrdReader``) and its Arrow
  payload summed per kind of entity (image, particle clouds, other overlays, plots, log);
- the recording overhead: fps of ``record()`` against the tracker alone and against the same
  pipeline without the recorder.  Both come from one :func:`~pfscope.trackers.pipeline.run`
  per repeat with only a :class:`LoopTimer` hook (same source, ``file`` detector, PHD-MT,
  online metrics; ``level=None``, as an unrecorded run): the tracker alone is the pipeline's
  ``step_seconds`` of the lane, the loop is the wall time between two frames.

Timing: each configuration runs ``--repeat`` times; a frame's time is the median over the
repeats (``record`` reports each finished frame through ``on_frame``), and fps is computed over
frames 2..N (frame 1 of ``record`` also opens the file).  Same seed, same bytes: the script
says whether the sizes agree across repeats.

Usage::

    .venv/bin/python benchmarks/bench_recording_size.py                  # PETS (if found) + synthetic
    .venv/bin/python benchmarks/bench_recording_size.py --source pets --frames 100 --max-points 1000,3000
    .venv/bin/python benchmarks/bench_recording_size.py --json out/size.json --keep /tmp/rrd
"""

from __future__ import annotations

import argparse
import inspect
import shutil
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Optional

import _common as C  # noqa: E402  (also puts the repository root on sys.path)
import cv2
import numpy as np

from pfscope.trackers.api import make_params, make_tracker
from pfscope.trackers.errors import InputError
from pfscope.trackers.pipeline import BaseHook, FrameReport, RunInfo
from pfscope.trackers.pipeline import run as run_pipeline

DEFAULT_MAX_POINTS = 3000
MB = 1e6
LANE = "phd"
PRESET = "paper"   # explicit: the registry's first preset need not be the paper's


def recorder_jpeg_quality() -> int:
    from pfscope.viewer_app.recorder import RerunRecorder

    return int(inspect.signature(RerunRecorder.__init__).parameters["jpeg_quality"].default)


def record_max_points_default() -> int:
    from pfscope.viewer_app.run import RecordOptions

    return int(RecordOptions().max_points)


# ----------------------------------------------------------------------------- runs

def run_record(source, out: Path, level: str, max_points: int, frames: int, seed: int):
    """One ``record()``; returns (per-frame seconds (F,), RecordResult)."""
    from pfscope.viewer_app.run import RecordOptions, record

    stamps = []
    t0 = time.perf_counter()
    res = record(source, out, RecordOptions(tracker=LANE, level=level, max_points=max_points,
                                            frames=frames, seed=seed, force=True,
                                            preset=PRESET),
                 progress=False, on_frame=lambda done: stamps.append(time.perf_counter()))
    if res.frames != frames or res.interrupted or Path(res.out) != Path(out):
        raise SystemExit(f"record() stopped after {res.frames} of {frames} frames "
                         f"(recording kept as {res.out})")
    return np.diff(np.array([t0] + stamps)), res


class LoopTimer(BaseHook):
    """Per-frame wall time of the pipeline loop (from the end of this hook's previous
    ``on_frame`` to the start of this one: frame read or rendered, detector, trackers, online
    metrics) and of the lane's tracker step (``step_seconds``).  With ``jpeg_quality`` it also
    encodes every frame as the recorder does, outside the timed part, and keeps the JPEG sizes."""

    def __init__(self, lane: str, jpeg_quality: Optional[int] = None):
        self.lane, self.jpeg_quality = lane, jpeg_quality
        self.loop: list[float] = []
        self.step: list[float] = []
        self.jpeg: list[int] = []

    def begin(self, info: RunInfo) -> None:
        self.mark = time.perf_counter()

    def on_frame(self, report: FrameReport) -> None:
        self.loop.append(time.perf_counter() - self.mark)
        self.step.append(report.step_seconds[self.lane])
        if self.jpeg_quality is not None:
            ok, buf = cv2.imencode(".jpg", report.frame.image,
                                   [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
            self.jpeg.append(len(buf) if ok else 0)
        self.mark = time.perf_counter()


def run_without_recording(source, frames: int, seed: int, jpeg_quality: Optional[int]):
    """The pipeline ``record()`` runs, without the recorder: ``file`` detector + PHD-MT (paper
    preset, same seed) + online metrics, ``level=None``.  Returns (loop seconds (F,), tracker
    step seconds (F,), JPEG bytes (F,) or None)."""
    timer = LoopTimer(LANE, jpeg_quality)
    res = run_pipeline(source, {LANE: make_tracker(LANE, seed, preset=PRESET)}, frames=frames, level=None,
                       hooks=[timer])
    if res.frames != frames or res.outcome.status != "completed":
        raise SystemExit(f"pipeline stopped: {res.outcome.reason}")
    jpeg = np.array(timer.jpeg, np.int64) if jpeg_quality is not None else None
    return np.array(timer.loop), np.array(timer.step), jpeg


def payload_breakdown(path: Path) -> dict | None:
    """Arrow payload bytes per kind of entity and the number of chunks, read back from the
    file (None if the reader API is unavailable).  Payload = uncompressed column bytes; it
    leaves out each chunk's framing and schema, so it does not add up to the file size."""
    try:
        import rerun as rr

        reader = rr.chunk.RrdReader(str(path))
        acc: Counter = Counter()
        n = 0
        for ch in reader.stream():
            acc[_kind(ch.entity_path)] += ch.to_record_batch().nbytes
            n += 1
        return {"bytes": dict(acc), "chunks": n}
    except Exception as e:  # noqa: BLE001 — optional diagnostics only
        print(f"note: payload breakdown unavailable ({e.__class__.__name__}: {e})", file=sys.stderr)
        return None


KINDS = ("image", "particle clouds", "other overlays", "plots", "log/properties")


def _kind(entity: str) -> str:
    if entity == "/video":
        return "image"
    if entity.startswith("/video/phd/particles") or entity == "/video/phd/clusters/members":
        return "particle clouds"
    if entity.startswith("/video/"):
        return "other overlays"
    if entity.startswith("/plots"):
        return "plots"
    return "log/properties"


# ----------------------------------------------------------------------------- one source

def bench_source(spec: str, args, tmp: Path) -> dict:
    source = C.open_bench_source(spec, args.frames, synthetic_frames=args.frames)
    if source.det is None:
        raise SystemExit(f"{source.location}: no public detections (det/det.txt); this benchmark "
                         f"records PHD-MT on a source's detections")
    F = C.n_frames(source, args.frames)
    if F < 2:
        raise SystemExit("--frames must be >= 2")
    q = recorder_jpeg_quality()
    configs = [("tracks", args.default_max_points), ("clusters", args.default_max_points)]
    configs += [("particles", m) for m in args.max_points]
    print(f"\n=== {source.name}: {F} frames ({source.width}x{source.height}), "
          f"{args.repeat} repeats, seed {args.seed} ===")

    # warm-up: imports, rerun start-up, caches (not measured)
    w = min(5, F)
    run_without_recording(source, w, args.seed, None)
    run_record(source, tmp / "warmup.rrd", "particles", args.default_max_points, w, args.seed)

    trk, pipe, rec_t = [], [], {c: [] for c in configs}
    sizes = {c: [] for c in configs}
    walls = {c: [] for c in configs}
    jpeg = None
    t_start = time.perf_counter()
    for r in range(args.repeat):  # interleaved so a load change hits all alike
        p, t, j = run_without_recording(source, F, args.seed, q if jpeg is None else None)
        pipe.append(p)
        trk.append(t)
        jpeg = j if jpeg is None else jpeg
        for c in configs:
            level, mp = c
            out = tmp / f"{source.name}-{level}-{mp}.rrd"
            per, res = run_record(source, out, level, mp, F, args.seed)
            rec_t[c].append(per)
            sizes[c].append(res.bytes)
            walls[c].append(res.seconds)
        print(f"  repeat {r + 1}/{args.repeat} done ({time.perf_counter() - t_start:.1f} s)",
              file=sys.stderr)

    def steady(runs):  # seconds for frames 2..F from per-frame medians over repeats
        return float(np.median(np.stack(runs), axis=0)[1:].sum())

    n_steady = F - 1
    t_trk, t_pipe = steady(trk), steady(pipe)
    jpeg_pf = float(jpeg.mean())
    breakdown = {c: payload_breakdown(tmp / f"{source.name}-{c[0]}-{c[1]}.rrd") for c in configs}
    spread = max(max(v) - min(v) for v in sizes.values())
    # fixed cost of a file (blueprint, properties, stream header): a 1-frame tracks recording
    # minus the per-frame increment of the N-frame one
    _, one = run_record(source, tmp / "one-frame.rrd", "tracks", args.default_max_points, 1,
                        args.seed)
    marginal = (float(np.median(sizes[configs[0]])) - one.bytes) / (F - 1)
    fixed = one.bytes - marginal

    tracks_pf = float(np.median(sizes[configs[0]])) / F
    rows, results = [], []
    for c in configs:
        level, mp = c
        b = float(np.median(sizes[c]))
        pf = b / F
        t_rec = steady(rec_t[c])
        entry = {"level": level, "max_points": mp, "bytes": b, "bytes_per_frame": pf,
                 "mb_for_frames": b / MB, "sizes_all_repeats": sizes[c],
                 "jpeg_share": jpeg_pf / pf, "non_image_bytes_per_frame": pf - jpeg_pf,
                 "x_tracks_level": pf / tracks_pf,
                 "record_fps": C.fps(t_rec, n_steady),
                 "record_wall_s_median": float(np.median(walls[c])),
                 "record_over_tracker": t_rec / t_trk, "record_over_pipeline": t_rec / t_pipe,
                 "payload_breakdown": breakdown[c]}
        results.append(entry)
        rows.append((level, mp if level == "particles" else "-", f"{pf / 1e3:.1f}",
                     f"{b / MB:.1f}", f"{pf / tracks_pf:.2f}", f"{100 * jpeg_pf / pf:.0f}%",
                     f"{(pf - jpeg_pf) / 1e3:.1f}", f"{entry['record_fps']:.1f}",
                     f"{entry['record_over_tracker']:.1f}x", f"{entry['record_over_pipeline']:.2f}x"))
    print(C.table(["level", "max pts", "KB/frame", f"MB/{F} fr", "x tracks", "JPEG %",
                   "non-image KB/fr", "record fps", "/ tracker", "/ no-rec loop"], rows))
    print(f"JPEG image (quality {q}, as the recorder writes it): {jpeg_pf / 1e3:.1f} KB/frame = "
          f"{100 * jpeg_pf / tracks_pf:.0f}% of the tracks-level recording")
    print(f"tracker only (PHD-MT step_seconds, pipeline at level None): "
          f"{C.fps(t_trk, n_steady):.1f} fps; same pipeline without the recorder (frames "
          f"read/rendered + file detector + tracker + online metrics): "
          f"{C.fps(t_pipe, n_steady):.1f} fps")
    print(f"fixed cost per file (blueprint, properties, header) ~ {fixed / 1e3:.0f} KB, "
          f"i.e. {fixed / F / 1e3:.1f} KB of the tracks-level KB/frame at {F} frames "
          f"(marginal {marginal / 1e3:.1f} KB/frame)")
    print(f"(fps over frames 2..{F}, per-frame medians over {args.repeat} repeats; "
          f"'/ tracker' = record time / tracker-only time, '/ no-rec loop' = record time / "
          f"same pipeline without the recorder; sizes of the repeats differ by at most {spread} bytes, "
          f"median shown)")

    if any(breakdown.values()):
        rows = []
        for c, e in zip(configs, results):
            bd = e["payload_breakdown"]
            if not bd:
                continue
            by = bd["bytes"]
            tot = sum(by.values())
            rows.append([c[0], c[1] if c[0] == "particles" else "-",
                         f"{bd['chunks'] / F:.1f}", f"{tot / F / 1e3:.1f}",
                         f"{(e['bytes'] - tot) / F / 1e3:.1f}"] +
                        [f"{by.get(k, 0) / F / 1e3:.1f}" for k in KINDS])
        print("\nread back from the file: chunks and Arrow payload per frame, KB/frame per kind of "
              "entity (payload = uncompressed columns; file - payload = per-chunk framing and "
              "schemas, minus what compression saves):")
        print(C.table(["level", "max pts", "chunks/fr", "payload", "file-payload", *KINDS], rows))

    return {"source": source.describe(), "frames": F, "repeats": args.repeat, "seed": args.seed,
            "jpeg_quality": q, "jpeg_bytes_per_frame": jpeg_pf,
            "jpeg_share_of_tracks_level": jpeg_pf / tracks_pf,
            "tracker_only_fps": C.fps(t_trk, n_steady), "no_record_loop_fps": C.fps(t_pipe, n_steady),
            "size_spread_across_repeats_bytes": spread, "fixed_bytes_per_file": fixed,
            "marginal_bytes_per_frame_tracks": marginal, "levels": results}


def _int_list(s: str) -> list[int]:
    try:
        v = [int(x) for x in s.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {s!r}") from None
    if not v or min(v) < 1:
        raise argparse.ArgumentTypeError("max-points values must be >= 1")
    return v


def main(argv=None) -> int:
    default_mp = record_max_points_default()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", action="append", metavar="pets|synthetic|PATH",
                    help="sequence to record (repeatable); default: pets (if found) and synthetic")
    ap.add_argument("--frames", type=int, default=200,
                    help="frames per recording (default 200; the synthetic scene is generated "
                         "with this many frames)")
    ap.add_argument("--max-points", type=_int_list, default=[1000, default_mp, 10000],
                    help=f"comma-separated point caps for level particles "
                         f"(default 1000,{default_mp},10000)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs of each configuration; per-frame times are medians (default 3)")
    ap.add_argument("--seed", type=int, default=0, help="tracker seed (default 0)")
    ap.add_argument("--keep", metavar="DIR", help="write the recordings here and keep them")
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.frames < 2:
        ap.error("--repeat must be >= 1 and --frames >= 2")
    args.default_max_points = default_mp

    info = C.machine()
    C.print_machine(info)
    p = make_params(LANE, PRESET)
    print(f"PHD-MT (tracker 'phd', preset 'paper': T={p.clusters.T:g}, K={p.assoc.depth}) "
          f"recorded with viewer_app.run.record (pipeline + RerunRecorder hook), file detector; "
          f"record default max_points={default_mp}")
    if args.keep:
        tmp = Path(args.keep)
        tmp.mkdir(parents=True, exist_ok=True)
        cleanup = None
    else:
        cleanup = tempfile.mkdtemp(prefix="pfscope-bench-")
        tmp = Path(cleanup)
    results = {}
    try:
        for spec in C.resolve_sources(args.source):
            results[spec] = bench_source(spec, args, tmp)
    except (C.NoData, InputError) as e:
        print(f"error: {e}", file=sys.stderr)
        return C.EXIT_NO_DATA
    finally:
        if cleanup:
            shutil.rmtree(cleanup, ignore_errors=True)
    C.write_json(args.json, {"benchmark": "recording_size", "command": C.command_line(),
                             "machine": info, "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
