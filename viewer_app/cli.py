"""The ``pfscope`` command line.

    pfscope record [SOURCE] [--tracker phd|mt|passthrough] [--out FILE.rrd] [--frames N]
                   [--seed S] [--detector file|hog|haar|bgsub] [--level tracks|clusters|particles]
                   [--tracks-out FILE.txt] [--force] [--spawn | --serve]
    pfscope synth --out DIR [--frames N --targets K --clutter R --seed S]
    pfscope eval TRACKS.txt --gt GT.txt|SEQUENCE_DIR [--json]
    pfscope compare [SOURCE] --trackers phd,mt [--out FILE.rrd] [--frames N] [--json]

Bad input ends with one line on stderr naming the file/line/frame and exit status 2.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Optional, Sequence

from pfscope.trackers.errors import InputError, RunFailed

EXIT_RUN_FAILED = 1      # not the user's input: a bug, out of memory, disk full ...
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130



def _synth_config(args, frames: Optional[int]):
    from pfscope.trackers.data.synthetic import SceneConfig

    kw = {"seed": args.seed}
    for name in ("targets", "clutter"):
        v = getattr(args, name, None)
        if v is not None:
            kw[name] = v
    if frames is not None:
        kw["frames"] = frames
    return SceneConfig(**kw)


def _add_synth_options(p: argparse.ArgumentParser, *, frames_help: str) -> None:
    p.add_argument("--frames", type=int, default=None, help=frames_help)
    p.add_argument("--targets", type=int, default=None,
                   help="synthetic scene: number of people (default 6)")
    p.add_argument("--clutter", type=float, default=None,
                   help="synthetic scene: mean false detections per frame (default 2)")
    p.add_argument("--seed", type=int, default=0, help="random seed (scene and tracker)")


def build_parser() -> argparse.ArgumentParser:
    from pfscope.trackers.api import DEFAULT_TRACKER, registry
    from pfscope.trackers.detect import DETECTORS
    from pfscope.trackers.report import LEVELS

    TRACKERS = registry()
    tracker_help = "; ".join(f"{n}: {i.summary}" for n, i in TRACKERS.items())

    ap = argparse.ArgumentParser(prog="pfscope", description=(
        "Particle-filter multi-target tracking that shows its work: run a tracker and "
        "record every stage to a Rerun .rrd file."))
    sub = ap.add_subparsers(dest="command", required=True)

    r = sub.add_parser("record", help="run a tracker and write a Rerun recording",
                       description="Run a tracker on SOURCE (default: the built-in synthetic "
                                   "scene) and write a Rerun recording.")
    r.add_argument("source", nargs="?", default=None,
                   help="MOTChallenge folder, video file, image folder, or 'synthetic' (default)")
    r.add_argument("--tracker", default=DEFAULT_TRACKER, choices=list(TRACKERS),
                   help=f"tracker (default {DEFAULT_TRACKER}) — {tracker_help}")
    _add_tracker_options(r)
    r.add_argument("--out", type=Path, default=None,
                   help="recording file (default recordings/<source>-<tracker>.rrd)")
    _add_synth_options(r, frames_help="stop after N frames (default: all)")
    r.add_argument("--detector", choices=list(DETECTORS), default=None,
                   help="detections: 'file' = the sequence's det/det.txt (default when present), "
                        "otherwise HOG people")
    r.add_argument("--min-score", type=float, default=float("-inf"),
                   help="drop file detections scoring below this")
    r.add_argument("--level", choices=list(LEVELS), default="clusters",
                   help="how much to record: tracks < clusters < particles (default clusters)")
    r.add_argument("--max-points", type=int, default=3000,
                   help="decimate each particle cloud to at most this many points per frame")
    r.add_argument("--fps", type=float, default=None, help="frame rate of an image folder")
    r.add_argument("--tracks-out", type=Path, default=None, help="also write MOT tracks here")
    r.add_argument("--force", action="store_true", help="overwrite existing output files")
    live = r.add_mutually_exclusive_group()
    live.add_argument("--spawn", action="store_true", help="also stream to a native viewer")
    live.add_argument("--serve", action="store_true", help="also serve a web viewer")
    r.add_argument("--timing", action="store_true",
                   help="also record each step's wall time (plots/timing; the recording then "
                        "differs from run to run)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")

    c = sub.add_parser("compare", help="run several trackers into one recording and score them",
                       description="Run several trackers on the same input into one recording "
                                   "(side by side) and print maggio2007's Table 1 scores "
                                   "(MODP, MODA, MOTP, MOTA) plus IDF1, HOTA and OSPA.")
    c.add_argument("source", nargs="?", default=None, help="as for record (default: synthetic)")
    c.add_argument("--trackers", default="phd,mt",
                   help=f"comma-separated, from {', '.join(TRACKERS)} (default phd,mt)")
    _add_tracker_options(c)
    c.add_argument("--out", type=Path, default=None,
                   help="recording file (default recordings/<source>-compare.rrd)")
    _add_synth_options(c, frames_help="stop after N frames (default: all)")
    c.add_argument("--detector", choices=list(DETECTORS), default=None)
    c.add_argument("--min-score", type=float, default=float("-inf"))
    c.add_argument("--level", choices=list(LEVELS), default="tracks",
                   help="how much to record per tracker (default tracks)")
    c.add_argument("--max-points", type=int, default=3000)
    c.add_argument("--fps", type=float, default=None)
    c.add_argument("--force", action="store_true")
    c.add_argument("--json", action="store_true", help="print the scores as JSON")
    c.add_argument("--quiet", action="store_true")

    e = sub.add_parser("eval", help="score a MOT tracks file against ground truth",
                       description="Score TRACKS (MOT text) against ground truth: CLEAR-MOT, "
                                   "VACE, identity, HOTA, OSPA/GOSPA, mean error.")
    e.add_argument("tracks", type=Path, help="tracks file (frame,id,x,y,w,h,...)")
    e.add_argument("--gt", type=Path, required=True,
                   help="gt.txt, or a MOTChallenge folder (uses gt/gt.txt and seqinfo.ini)")
    e.add_argument("--iou", type=float, default=0.5, help="IoU needed for a match (MOT15: 0.5)")
    e.add_argument("--convention", choices=["auto", "mot15", "mot16"], default="auto",
                   help="mot15: gt conf=0 rows dropped, every track box scored; mot16: track "
                        "boxes on distractors removed first (TrackEval's MOT16+ preprocessing); "
                        "auto (default): mot16 when the gt has MOT16 class/visibility columns, "
                        "else mot15")
    e.add_argument("--ospa-c", type=float, default=None, help="OSPA cut-off in pixels")
    e.add_argument("--ospa-p", type=float, default=None, help="OSPA order")
    e.add_argument("--json", action="store_true", help="print the scores as JSON")

    t = sub.add_parser("trackers", help="list the trackers, their papers, stages and parameters",
                       description="List every registered tracker with its paper, its stages, "
                                   "its presets and its parameters (defaults and docs). Set a "
                                   "parameter with `record --set NAME=VALUE`.")
    t.add_argument("name", nargs="?", default=None, help="show only this tracker")
    t.add_argument("--json", action="store_true", help="print as JSON")

    s = sub.add_parser("synth", help="write the synthetic scene as a MOTChallenge folder")
    s.add_argument("--out", type=Path, required=True, help="output folder (must not exist)")
    _add_synth_options(s, frames_help="number of frames (default 150)")
    s.add_argument("--quiet", action="store_true")
    return ap


def _add_tracker_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", dest="set_options", action="append", metavar="NAME=VALUE",
                   default=[],
                   help="set a tracker parameter, e.g. --set p_miss=0.2 --set depth=30 "
                        "(dotted names pick one part: filter.motion.sigma_v; in compare, "
                        "phd.p_miss sets it for phd only). `pfscope trackers` lists them all.")
    p.add_argument("--preset", default=None,
                   help="parameter preset (default: the tracker's first, its paper's settings)")


def _tracker_options(args) -> dict:
    from pfscope.trackers.params import parse_set

    try:
        return parse_set(args.set_options)
    except ValueError as e:
        raise InputError(str(e)) from None


def _open(args):
    from pfscope.trackers.data.sources import open_source

    if args.max_points <= 0:
        raise InputError("--max-points must be positive")
    if args.frames is not None and args.frames <= 0:
        raise InputError("--frames must be positive")
    synthetic = args.source in (None, "synthetic")
    if not synthetic and (args.targets is not None or args.clutter is not None):
        raise InputError("--targets/--clutter only apply to the synthetic scene")
    return open_source(args.source, fps=args.fps,
                       synthetic_config=_synth_config(args, args.frames) if synthetic else None)


def _print_scores(scores: dict, as_json: bool) -> None:
    """Print ``{tracker name: evaluate() dict}`` as tables (or JSON), headed by the evaluation
    convention each dict carries (one line, or one per tracker when they differ)."""
    import json

    from pfscope.trackers.eval import describe_convention, format_table

    if as_json:
        print(json.dumps(scores, indent=2, sort_keys=True, default=float))
        return
    conv = {name: describe_convention(sc["convention"], sc.get("iou_threshold", 0.5))
            if sc.get("convention") else "not stated" for name, sc in scores.items()}
    if len(set(conv.values())) == 1:
        print(f"convention: {next(iter(conv.values()))}")
    else:
        for name, desc in conv.items():
            print(f"convention ({name}): {desc}")
    print("maggio2007 Table 1 layout (VACE / CLEAR-MOT):")
    print(format_table(scores, ("MODP", "MODA", "MOTP", "MOTA")))
    print()
    print(format_table(scores, ("IDF1", "HOTA", "IDSW", "FP", "FN", "OSPA", "GOSPA", "ME")))


def cmd_compare(args) -> int:
    from .run import RecordOptions, RECORDINGS_DIR, record

    names = [n.strip() for n in args.trackers.split(",") if n.strip()]
    if len(names) < 1:
        raise InputError("--trackers needs at least one tracker name")
    source = _open(args)
    out = args.out or RECORDINGS_DIR / f"{source.name}-compare.rrd"
    opts = RecordOptions(detector=args.detector, min_score=args.min_score, level=args.level,
                         max_points=args.max_points, frames=args.frames, seed=args.seed,
                         force=args.force, preset=args.preset,
                         tracker_options=_tracker_options(args))
    res = record(source, out, opts, trackers=names, progress=not args.quiet)
    if res.scores:
        _print_scores(res.scores, args.json)
    else:
        print(f"{source.name} has no ground truth: nothing to score", file=sys.stderr)
    print(f"{res.frames} frames, {res.bytes / 1e6:.1f} MB -> {res.out}", file=sys.stderr)
    print(f"open it with:  rerun {res.out}", file=sys.stderr)
    return EXIT_INTERRUPTED if res.interrupted else 0


def cmd_eval(args) -> int:
    from pfscope.trackers.data.motio import read_mot
    from pfscope.trackers.data.sources import MOTFolderSource
    from pfscope.trackers.eval import evaluate

    frames = None
    if args.gt.is_dir():
        seq = MOTFolderSource(args.gt)
        if seq.gt is None:
            raise InputError(f"{args.gt / 'gt' / 'gt.txt'}: no ground truth in this sequence")
        gt, frames = seq.gt, range(1, seq.length + 1)
    else:
        gt = read_mot(args.gt, "gt")
    tracks = read_mot(args.tracks, "tracks")
    kw = {k: v for k, v in (("ospa_c", args.ospa_c), ("ospa_p", args.ospa_p)) if v is not None}
    scores = evaluate(gt, tracks, iou_threshold=args.iou, frames=frames,
                      convention=args.convention, **kw)
    _print_scores({args.tracks.stem: scores}, args.json)
    return 0


def cmd_record(args) -> int:
    from .run import RecordOptions, default_out_path, record

    source = _open(args)
    out = args.out or default_out_path(source, args.tracker)
    opts = RecordOptions(tracker=args.tracker, detector=args.detector, min_score=args.min_score,
                         level=args.level, max_points=args.max_points, frames=args.frames,
                         seed=args.seed, force=args.force, tracks_out=args.tracks_out,
                         spawn=args.spawn, serve=args.serve, preset=args.preset,
                         timing=args.timing, tracker_options=_tracker_options(args))
    res = record(source, out, opts, progress=not args.quiet)
    size = res.bytes / 1e6
    state = ("interrupted; recording finished, readable and kept as incomplete"
             if res.interrupted else "done")
    print(f"{state}: {res.frames} frames in {res.seconds:.1f} s "
          f"({res.frames / max(res.seconds, 1e-9):.1f} fps), {size:.1f} MB -> {res.out}")
    if res.tracks_out:
        print(f"tracks (MOT format): {res.tracks_out}")
    for name, sc in res.scores.items():
        print(f"scores vs ground truth ({name}): MOTA {sc['MOTA']:.3f}  MOTP {sc['MOTP']:.3f}  "
              f"IDF1 {sc['IDF1']:.3f}  HOTA {sc['HOTA']:.3f}  IDSW {int(sc['IDSW'])}  "
              f"OSPA {sc['OSPA']:.1f} px")
    print(f"open it with:  rerun {res.out}")
    if args.serve and sys.stdin.isatty():
        input("web viewer running; press Enter to stop\n")
    return EXIT_INTERRUPTED if res.interrupted else 0


def cmd_trackers(args) -> int:
    import json

    from pfscope.trackers.api import registry
    from pfscope.trackers.params import describe

    reg = registry()
    if args.name is not None and args.name not in reg:
        raise InputError(f"unknown tracker {args.name!r}; choose one of {', '.join(reg)}")
    infos = [reg[args.name]] if args.name else list(reg.values())
    if args.json:
        print(json.dumps([{"name": i.name, "paper": i.paper, "summary": i.summary,
                           "stages": list(i.stages), "presets": list(i.presets),
                           "needs": {"detections": i.cls.needs_detections,
                                     "image": i.cls.needs_image},
                           "params": describe(i.params)} for i in infos],
                         indent=2, default=str))
        return 0
    for i in infos:
        needs = [w for w, f in (("detections", i.cls.needs_detections),
                                ("image", i.cls.needs_image)) if f]
        print(f"{i.name} — {i.summary}")
        print(f"  paper: {i.paper}   needs: {', '.join(needs) or 'nothing'}   "
              f"presets: {', '.join(i.presets)}")
        print(f"  stages: {' → '.join(i.stages)}")
        rows = describe(i.params)
        if rows:
            width = max(len(r["name"]) for r in rows)
            print("  parameters (--set NAME=VALUE; the last part of a dotted name is enough):")
            for r in rows:
                paper = f" [{r['paper']}]" if r["paper"] else ""
                print(f"    {r['name']:<{width}}  {r['default']!r:<12} {r['doc']}{paper}")
        print()
    return 0


def cmd_synth(args) -> int:
    from pfscope.trackers.data.synthetic import write_sequence

    def progress(i, n):
        if not args.quiet and (i == n or i % max(1, n // 10) == 0):
            print(f"synth: {i}/{n} frames", file=sys.stderr)

    path = write_sequence(args.out, _synth_config(args, args.frames), progress=progress)
    print(f"wrote synthetic MOT sequence to {path}")
    print(f"record it with:  pfscope record {path}")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    args = build_parser().parse_args(argv)
    try:
        if args.command == "record":
            return cmd_record(args)
        if args.command == "synth":
            return cmd_synth(args)
        if args.command == "eval":
            return cmd_eval(args)
        if args.command == "compare":
            return cmd_compare(args)
        if args.command == "trackers":
            return cmd_trackers(args)
    except InputError as e:
        print(f"pfscope: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except RunFailed as e:
        print(f"pfscope: run failed: {e}", file=sys.stderr)
        if os.environ.get("PFSCOPE_DEBUG"):
            raise
        return EXIT_RUN_FAILED
    except KeyboardInterrupt:
        print("pfscope: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # `pfscope trackers | head`: the reader left, nothing to report
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
