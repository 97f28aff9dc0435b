"""Size and cost of a Rerun recording of PHD-MT at each level (tracks, clusters, particles).

Uses the app's own code path, :func:`viewer_app.run.record` with
``RecordOptions(tracker='phd', level=..., max_points=..., frames=N, force=True)``, writing into
a temporary folder (deleted afterwards unless ``--keep DIR``), on a source's public
detections (``file`` detector, as ``pfscope record`` picks for a MOT folder).

For each source it reports:

- bytes per frame and MB for N frames at level ``tracks``, ``clusters`` and ``particles``,
  the last also with several ``--max-points`` caps (points per cloud; the recorder decimates
  bigger clouds with a fixed stride);
- how much of that is the video frame: every frame is logged as a JPEG
  (``RerunObserver`` default quality), whose bytes are measured by encoding the same frames with
  OpenCV at that quality, and set beside the ``tracks`` level (the smallest recording:
  image + detections + GT + tracks + scalars);
- where the rest goes: the recording is read back (``rerun.chunk.RrdReader``) and its Arrow
  payload summed per kind of entity (image, particle clouds, other overlays, plots, log);
- the recording overhead: fps of ``record()`` against the tracker alone (PHD-MT with a
  NullObserver on preloaded detections) and against the same loop without recording
  (frames read or rendered + file detector + tracker).

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

import _common as C  # noqa: E402  (also puts the repository root on sys.path)
import cv2
import numpy as np

from pfscope.trackers.detect import make_detector
from pfscope.trackers.errors import InputError
from pfscope.trackers.observer import NullObserver
from pfscope.trackers.phd.tracker import PHDTracker
from pfscope.trackers.types import Frame

DEFAULT_MAX_POINTS = 3000
MB = 1e6


def recorder_jpeg_quality() -> int:
    from pfscope.viewer_app.recorder import RerunObserver

    return int(inspect.signature(RerunObserver.__init__).parameters["jpeg_quality"].default)


def record_max_points_default() -> int:
    from pfscope.viewer_app.run import RecordOptions

    return int(RecordOptions().max_points)


# ----------------------------------------------------------------------------- runs

def run_record(source, out: Path, level: str, max_points: int, frames: int, seed: int):
    """One ``record()``; returns (per-frame seconds (F,), RecordResult)."""
    from pfscope.viewer_app.run import RecordOptions, record

    stamps = []
    t0 = time.perf_counter()
    res = record(source, out, RecordOptions(tracker="phd", level=level, max_points=max_points,
                                            frames=frames, seed=seed, force=True),
                 progress=False, on_frame=lambda done: stamps.append(time.perf_counter()))
    if res.frames != frames or res.interrupted:
        raise SystemExit(f"record() stopped after {res.frames} of {frames} frames")
    return np.diff(np.array([t0] + stamps)), res


def run_tracker_only(source, frames: int, seed: int) -> np.ndarray:
    """PHD-MT alone: preloaded detections, NullObserver (per-frame seconds)."""
    dets = [source.det.detections(k) for k in range(1, frames + 1)]
    dummy = np.zeros((1, 1, 3), np.uint8)
    tr = PHDTracker(np.random.default_rng(seed))
    obs = NullObserver()
    out = np.zeros(frames)
    pc = time.perf_counter
    for i, d in enumerate(dets):
        f = Frame(i + 1, i / source.fps, dummy)
        t0 = pc()
        tr.step(f, d, obs)
        out[i] = pc() - t0
    return out


def run_pipeline(source, frames: int, seed: int, jpeg_quality: int | None):
    """The ``record()`` loop without a recording: frames read (or rendered) + ``file`` detector +
    PHD-MT with a NullObserver.  When ``jpeg_quality`` is given, also encode every frame as the
    recorder does (outside the timed part) and return the JPEG sizes."""
    det = make_detector("file", det_table=source.det)
    tr = PHDTracker(np.random.default_rng(seed))
    obs = NullObserver()
    out = np.zeros(frames)
    jpeg = np.zeros(frames, np.int64)
    pc = time.perf_counter
    it = source.frames(frames)
    for i in range(frames):
        t0 = pc()
        f = next(it)
        tr.step(f, det(f), obs)
        out[i] = pc() - t0
        if jpeg_quality is not None:
            ok, buf = cv2.imencode(".jpg", f.image, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
            jpeg[i] = len(buf) if ok else 0
    return out, jpeg


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
    run_tracker_only(source, w, args.seed)
    run_record(source, tmp / "warmup.rrd", "particles", args.default_max_points, w, args.seed)

    trk, pipe, rec_t = [], [], {c: [] for c in configs}
    sizes = {c: [] for c in configs}
    walls = {c: [] for c in configs}
    jpeg = None
    t_start = time.perf_counter()
    for r in range(args.repeat):  # interleaved so a load change hits all alike
        trk.append(run_tracker_only(source, F, args.seed))
        p, j = run_pipeline(source, F, args.seed, q if jpeg is None else None)
        pipe.append(p)
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
    print(f"tracker only (PHD-MT, NullObserver, preloaded detections): "
          f"{C.fps(t_trk, n_steady):.1f} fps; same loop without recording (frames read/rendered "
          f"+ file detector + tracker): {C.fps(t_pipe, n_steady):.1f} fps")
    print(f"fixed cost per file (blueprint, properties, header) ~ {fixed / 1e3:.0f} KB, "
          f"i.e. {fixed / F / 1e3:.1f} KB of the tracks-level KB/frame at {F} frames "
          f"(marginal {marginal / 1e3:.1f} KB/frame)")
    print(f"(fps over frames 2..{F}, per-frame medians over {args.repeat} repeats; "
          f"'/ tracker' = record time / tracker-only time, '/ no-rec loop' = record time / "
          f"same loop without recording; sizes of the repeats differ by at most {spread} bytes, "
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
    print(f"PHD-MT (PHDParams() defaults, T=0.6, K=50) recorded with viewer_app.run.record, "
          f"file detector; record default max_points={default_mp}")
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
