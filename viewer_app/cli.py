"""The ``pfscope`` command line: one subcommand per task (record, compare, eval, trackers,
repair, info, view, snapshot, batch, tune, synth, train-dbn, train-classifier).

The parsers below are the documentation's source: ``python -m pfscope.viewer_app.docgen``
writes the README's synopsis and ``docs/cli.md`` from them (tests/test_docs.py checks both).
Every command reads ``--frames`` as ``N`` or ``FIRST:LAST`` (:func:`parse_frames`).

Bad input ends with one line on stderr naming the file/line/frame and exit status 2.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import Optional, Sequence

from pfscope.trackers.errors import InputError, RunFailed

EXIT_RUN_FAILED = 1      # not the user's input: a bug, out of memory, disk full ...
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130   # 128 + SIGINT; SIGTERM gives 143 (128 + 15)


def _interrupted_status() -> int:
    """128 + the signal that stopped the run: 130 for Ctrl-C, 143 for SIGTERM."""
    from pfscope.trackers.jobs import exit_status

    return exit_status(EXIT_INTERRUPTED)



def _number(kind, *, low=None, high=None, low_open=False, what="a number"):
    """An argparse ``type`` that rejects out-of-range values with a one-line usage error."""

    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if kind is float and not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}")
        if low is not None and (v <= low if low_open else v < low):
            raise argparse.ArgumentTypeError(f"{text!r}: must be {'>' if low_open else '>='} {low}")
        if high is not None and v > high:
            raise argparse.ArgumentTypeError(f"{text!r}: must be <= {high}")
        return v

    parse.__name__ = what
    return parse


POSITIVE_INT = _number(int, low=1, what="a positive integer")
NONNEG_INT = _number(int, low=0, what="a non-negative integer")
POSITIVE = _number(float, low=0, low_open=True, what="a positive number")
NONNEG = _number(float, low=0, what="a non-negative number")
#: the synthetic scene's people and false detections per frame: bounded so that a typo
#: (--clutter 1e9) is a usage error, not an allocation of terabytes
MAX_SCENE = 10_000
SCENE_TARGETS = _number(int, low=1, high=MAX_SCENE, what="a positive integer")
SCENE_CLUTTER = _number(float, low=0, high=MAX_SCENE, what="a non-negative number")


FRAMES_HELP = "N (the first N frames) or FIRST:LAST (e.g. 380:450; the video's own numbers)"


def parse_frames(text: str, *, ranges: bool = True):
    """``--frames`` everywhere: ``N`` (frames 1..N) or, with ``ranges``, ``FIRST:LAST``.  The
    dash form ``A-B`` is refused with the right example.  Raises ValueError (one line)."""
    text = str(text).strip()
    a, sep, b = text.partition(":")
    if not sep:
        lo_s, dash, hi_s = text.partition("-")
        if dash and lo_s.isdigit() and hi_s.isdigit():
            raise ValueError(f"{text!r}: write FIRST:LAST, e.g. {lo_s}:{hi_s}")
        try:
            n = int(text)
        except ValueError:
            raise ValueError(f"{text!r}: expected N" + (" or FIRST:LAST, e.g. 401:795"
                                                      if ranges else "")) from None
        if n < 1:
            raise ValueError(f"{text!r}: must be >= 1")
        return n
    if not ranges:
        raise ValueError(f"{text!r}: expected a number of frames N")
    try:
        lo, hi = int(a), int(b)
    except ValueError:
        raise ValueError(f"{text!r}: expected FIRST:LAST, e.g. 401:795") from None
    if lo < 1 or hi < lo:
        raise ValueError(f"{text!r}: expected 1 <= FIRST <= LAST")
    return lo, hi


def _argtype(parse, name: str):
    def f(text: str):
        try:
            return parse(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    f.__name__ = name
    return f


def _frame_range(text: str) -> tuple[int, int]:
    """FIRST:LAST, or N for 1:N."""
    v = parse_frames(text)
    return (1, v) if isinstance(v, int) else v


def _strict_range(text: str) -> tuple[int, int]:
    if ":" not in str(text):
        parse_frames(text)  # the dash form gets its example
        raise ValueError(f"{text!r}: expected FIRST:LAST, e.g. 401:795")
    return _frame_range(text)


def frames_within(frames, length, source) -> tuple[int, int]:
    """The (FIRST, LAST) a training command runs on: ``--frames`` as parsed (N or a range),
    checked against the source's length; all of it when not given."""
    if frames is None:
        if not length:
            raise InputError(f"{source}: length unknown, give --frames FIRST:LAST")
        return 1, int(length)
    lo, hi = (1, frames) if isinstance(frames, int) else frames
    if length and hi > length:
        raise InputError(f"--frames {lo}:{hi}: {source} has {length} frames")
    return lo, hi


def _synth_config(args, frames: Optional[int]):
    from pfscope.trackers.data.synthetic import demo_config

    kw = {"seed": args.seed}
    for name in ("targets", "clutter"):
        v = getattr(args, name, None)
        if v is not None:
            kw[name] = v
    if frames is not None:
        kw["frames"] = frames
    return demo_config(**kw)


FRAME_RANGE = _argtype(_frame_range, "N or FIRST:LAST")
STRICT_RANGE = _argtype(_strict_range, "FIRST:LAST")
FRAMES = _argtype(parse_frames, "N or FIRST:LAST")
FRAME_COUNT = _argtype(lambda t: parse_frames(t, ranges=False), "N")
_frames_or_range = FRAMES


def _add_synth_options(p: argparse.ArgumentParser, *, frames_help: str,
                       ranges: bool = False) -> None:
    p.add_argument("--frames", type=FRAMES if ranges else FRAME_COUNT, default=None,
                   help=frames_help + (" or FIRST:LAST (e.g. 380:450)" if ranges else ""))
    p.add_argument("--targets", type=SCENE_TARGETS, default=None,
                   help="synthetic scene: number of people (default 6)")
    p.add_argument("--clutter", type=SCENE_CLUTTER, default=None,
                   help="synthetic scene: mean false detections per frame (default 2)")
    p.add_argument("--seed", type=NONNEG_INT, default=0,
                   help="random seed (scene and tracker)")


class _Parser(argparse.ArgumentParser):
    """argparse with a "did you mean" for a mistyped choice: a subcommand, ``--tracker``,
    ``--detector``, ``--level`` ..."""

    def _check_value(self, action, value):
        if action.choices is not None and value not in action.choices:
            from pfscope.trackers.errors import did_you_mean

            choices = ", ".join(map(str, action.choices))
            raise argparse.ArgumentError(action, f"invalid choice: {value!r}"
                                                 f"{did_you_mean(value, action.choices)}; "
                                                 f"choose from {choices}")
        super()._check_value(action, value)

    def _print_message(self, message, file=None):
        # argparse swallows a failed write (help into a full disk would exit 0 having written
        # nothing): let it reach main(), which says so in one line
        if message:
            (file or sys.stderr).write(message)


ONLINE_HELP = ("treat the source as a stream: no look at the clip ahead of time (dbn-phd and "
               "phd-bgsub then learn their background from the first frames only, instead of "
               "starting from a temporal median of frames sampled over the clip)")


def build_parser() -> argparse.ArgumentParser:
    from pfscope.trackers.api import DEFAULT_TRACKER, tracker_summaries
    from pfscope.trackers.detect import DETECTORS
    from pfscope.trackers.report import LEVELS

    TRACKERS = tracker_summaries()     # (no tracker imported: a run imports its own only)
    tracker_help = "; ".join(f"{n}: {summary}" for n, summary in TRACKERS.items())

    from pfscope.trackers import __version__

    ap = _Parser(prog="pfscope", description=(
        "Particle-filter multi-target tracking that shows its work: run a tracker and "
        "record every stage to a Rerun .rrd file."))
    ap.add_argument("--version", action="version", version=f"pfscope {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)

    r = sub.add_parser("record", help="run a tracker and write a Rerun recording",
                       description="Run a tracker on SOURCE (default: the built-in synthetic "
                                   "scene) and write a Rerun recording.")
    r.add_argument("source", nargs="?", default=None,
                   help="MOTChallenge folder, video file, image folder, or 'synthetic' (default)")
    r.add_argument("--tracker", default=None, choices=list(TRACKERS),
                   help=f"tracker (default: the --params file's, else {DEFAULT_TRACKER}) — "
                        f"{tracker_help}")
    _add_tracker_options(r)
    r.add_argument("--out", type=Path, default=None,
                   help="recording file (default recordings/<source>-<tracker>.rrd)")
    _add_synth_options(r, frames_help="stop after N frames (default: all)", ranges=True)
    r.add_argument("--detector", choices=list(DETECTORS), default=None,
                   help="detections: 'file' = the sequence's det/det.txt (default when present), "
                        "otherwise HOG people")
    r.add_argument("--min-score", type=float, default=float("-inf"),
                   help="drop file detections scoring below this")
    r.add_argument("--level", choices=list(LEVELS), default="particles",
                   help="how much to record: tracks < clusters < particles (default particles: "
                        "the clouds, each thinned to --max-points)")
    r.add_argument("--max-points", type=POSITIVE_INT, default=3000,
                   help="decimate each particle cloud to at most this many points per frame")
    r.add_argument("--video", choices=["encode", "source", "auto"], default="encode",
                   help="the frames in the recording: 'encode' = re-encode as JPEG on a worker "
                        "thread (default), 'source' = the source's own JPEG bytes (no encoding; "
                        "larger files when the source JPEGs are high quality), 'auto' = the "
                        "source's bytes when its first frame is not larger than a re-encode")
    r.add_argument("--fps", type=POSITIVE, default=None,
                   help="frame rate of an image folder or a video file (MOT folders have theirs "
                        "in seqinfo.ini)")
    r.add_argument("--tracks-out", type=Path, default=None, help="also write MOT tracks here")
    r.add_argument("--online", action="store_true", help=ONLINE_HELP)
    r.add_argument("--classifier", type=Path, default=None, metavar="MODEL",
                   help="dlpf: an IKSVM from `pfscope train-classifier` (default OpenCV's people "
                        "SVM); dbn-phd: a DBN from `pfscope train-dbn` (same as --set model=MODEL)")
    r.add_argument("--force", action="store_true", help="overwrite existing output files")
    live = r.add_mutually_exclusive_group()
    live.add_argument("--spawn", action="store_true", help="also stream to a native viewer")
    live.add_argument("--serve", action="store_true",
                      help="also serve a web viewer (127.0.0.1), and keep serving the finished "
                           "file after the run until Ctrl-C, also without a terminal")
    r.add_argument("--serve-exit", action="store_true",
                   help="with --serve: stop serving when the run ends")
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
                   help=f"comma-separated, from {', '.join(TRACKERS)} (default phd,mt); a "
                        "parameter variant is NAME[key=value;...], e.g. \"phd,phd[p_miss=0.2],mt\" "
                        "(its lane is named phd-p_miss-0.2)")
    _add_tracker_options(c)
    c.add_argument("--out", type=Path, default=None,
                   help="recording file (default recordings/<source>-compare.rrd)")
    _add_synth_options(c, frames_help="stop after N frames (default: all)", ranges=True)
    c.add_argument("--detector", choices=list(DETECTORS), default=None)
    c.add_argument("--min-score", type=float, default=float("-inf"))
    c.add_argument("--level", choices=list(LEVELS), default="tracks",
                   help="how much to record per tracker (default tracks)")
    c.add_argument("--max-points", type=POSITIVE_INT, default=3000)
    c.add_argument("--video", choices=["encode", "source", "auto"], default="encode",
                   help="the frames in the recording: encode (default) | source | auto "
                        "(see `pfscope record --help`)")
    c.add_argument("--fps", type=POSITIVE, default=None)
    c.add_argument("--force", action="store_true")
    c.add_argument("--json", action="store_true", help="print the scores as JSON")
    c.add_argument("--online", action="store_true", help=ONLINE_HELP)
    c.add_argument("--quiet", action="store_true")

    e = sub.add_parser("eval", help="score MOT tracks files against ground truth (one "
                                    "sequence, or a folder of them with a COMBINED row)",
                       description="Score TRACKS (MOT text) against ground truth: CLEAR-MOT, "
                                   "VACE, identity, HOTA, OSPA/GOSPA, mean error.  With a "
                                   "folder of tracks files (SEQ.txt, or a `pfscope batch` "
                                   "output: SEQ-LANE-seedS.txt) and --gt a folder of "
                                   "MOTChallenge sequences, one row per sequence and a "
                                   "COMBINED row (counts summed over the sequences, as "
                                   "TrackEval and MOTChallenge do), per tracker and seed.")
    e.add_argument("tracks", type=Path, help="tracks file (frame,id,x,y,w,h,...), or a folder "
                                             "of them")
    e.add_argument("--gt", type=Path, required=True,
                   help="gt.txt, or a MOTChallenge folder (uses gt/gt.txt and seqinfo.ini), "
                        "or (with a folder of tracks) a folder of MOTChallenge sequences")
    e.add_argument("--iou", type=_number(float, low=0, low_open=True, high=1,
                                         what="an IoU in (0, 1]"),
                   default=0.5, help="IoU needed for a match (MOT15: 0.5)")
    e.add_argument("--convention", choices=["auto", "mot15", "mot16"], default="auto",
                   help="mot15: gt conf=0 rows dropped, every track box scored; mot16: track "
                        "boxes on distractors removed first (TrackEval's MOT16+ preprocessing); "
                        "auto (default): mot16 when the gt has MOT16 class/visibility columns, "
                        "else mot15")
    e.add_argument("--ospa-c", type=POSITIVE, default=None, help="OSPA cut-off in pixels")
    e.add_argument("--ospa-p", type=_number(float, low=1, what="an order >= 1"), default=None,
                   help="OSPA order")
    e.add_argument("--frames", type=FRAME_RANGE, default=None, metavar="N|FIRST:LAST",
                   help="score only these frames (e.g. 401:795)")
    e.add_argument("--json", action="store_true", help="print the scores as JSON")

    t = sub.add_parser("trackers", help="list the trackers, their papers, stages and parameters",
                       description="List every registered tracker with its paper, its stages, "
                                   "its presets and its parameters (defaults and docs). Set a "
                                   "parameter with `record --set NAME=VALUE`.")
    t.add_argument("name", nargs="?", default=None, help="show only this tracker")
    t.add_argument("--json", action="store_true", help="print as JSON")

    rp = sub.add_parser("repair", help="make a recording left without its footer (a killed "
                                       "run) whole again",
                        description="Rewrite FILE (e.g. x.incomplete.rrd after SIGKILL) with "
                                    "Rerun's 'rrd optimize', check it with 'rrd verify', and "
                                    "write it as OUT (default: FILE with .repaired before the "
                                    "suffix). FILE itself is never modified.")
    rp.add_argument("file", type=Path, help="the .rrd to repair")
    rp.add_argument("--out", type=Path, default=None, help="where to write the repaired file")
    rp.add_argument("--force", action="store_true", help="overwrite OUT")

    inf = sub.add_parser("info", help="what a recording is: source, trackers, parameters, "
                                      "versions, frames, size, scores, failure index",
                         description="Print what FILE.rrd holds, read from the file alone.")
    inf.add_argument("file", type=Path, help="a .rrd recording")
    inf.add_argument("--json", action="store_true", help="print as JSON")
    inf.add_argument("--top", type=POSITIVE_INT, default=10,
                     help="events and worst frames listed per lane (default 10)")
    inf.add_argument("--no-params", action="store_true", help="do not list every parameter")

    vw = sub.add_parser("view", help="open a recording in the Rerun viewer",
                        description="Open FILE.rrd in the native Rerun viewer; without a display "
                                    "say in one line how to see it.")
    vw.add_argument("file", type=Path)
    vw.add_argument("--web", action="store_true",
                    help="serve the file to a browser (Rerun's web viewer on 127.0.0.1) and "
                         "print the URL; Ctrl-C stops")
    vw.add_argument("--web-port", type=POSITIVE_INT, default=None,
                    help="HTTP port of the web viewer (default: a free one)")

    sn = sub.add_parser("snapshot", help="a PNG of a recording at one frame (headless viewer)",
                        description="Render FILE.rrd at --frame with Rerun's headless viewer "
                                    "(needs Vulkan: mesa-vulkan-drivers libvulkan1 without a GPU).")
    sn.add_argument("file", type=Path)
    sn.add_argument("--frame", type=POSITIVE_INT, default=None, help="frame (default: the last)")
    sn.add_argument("--tab", default=None,
                    help="video tab to show, by title (e.g. Particles, Association); 'all': "
                         "one picture per video tab, OUT-<tab>.png")
    sn.add_argument("--out", type=Path, required=True, help="PNG to write")
    sn.add_argument("--keep-panels", action="store_true",
                    help="keep the viewer's side and time panels in the picture")
    sn.add_argument("--stage", default=None, metavar="NAME",
                    help="picture the frame at this stage (predict, birth, update ...; "
                         "LANE:STAGE in a compare recording); shows the All stages tab unless "
                         "--tab is given")
    sn.add_argument("--frames", type=_frame_range, default=None, metavar="A:B",
                    help="one picture per frame A..B, numbered OUT-000080.png ...")

    ex = sub.add_parser("export", help="an annotated video (mp4, or gif) of a recording, drawn "
                                       "without the viewer",
                        description="Draw each recorded frame with the chosen tab's content "
                                    "(boxes, ids, trails, particles, edges) with OpenCV and write "
                                    "a video: one video frame per recorded frame.")
    ex.add_argument("file", type=Path, help="a .rrd recording")
    ex.add_argument("--out", type=Path, required=True, help="x.mp4 (or .avi, .gif)")
    ex.add_argument("--tab", default=None,
                    help="video tab to draw, by title (default: the first; see pfscope info)")
    ex.add_argument("--frames", type=_frame_range, default=None, metavar="A:B",
                    help="only frames A..B")
    ex.add_argument("--force", action="store_true", help="overwrite OUT")
    ex.add_argument("--quiet", action="store_true", help="no progress")

    from .batch import add_batch_parser
    add_batch_parser(sub, _add_tracker_options)

    _add_tune_parser(sub, TRACKERS, DETECTORS, LEVELS)

    s = sub.add_parser("synth", help="write the synthetic scene as a MOTChallenge folder")
    s.add_argument("--out", type=Path, required=True, help="output folder (must not exist)")
    _add_synth_options(s, frames_help="number of frames (default 150)")
    s.add_argument("--bg-noise", type=NONNEG, default=0.0, metavar="R",
                   help="background-subtraction noise: mean noise patches (random colour "
                        "blotches lasting up to 8 frames, plus salt-and-pepper specks) "
                        "starting per frame (default 0: off, the scene is unchanged)")
    s.add_argument("--flicker", type=NONNEG, default=0.0, metavar="S",
                   help="illumination flicker: std of a per-frame global gain jump, e.g. "
                        "0.05 (default 0: off)")
    s.add_argument("--quiet", action="store_true")

    td = sub.add_parser("train-dbn", help="train the DBN of dbn-phd (feng2015) on sequences' "
                                          "ground truth",
                        description="Train DBN-PHD's deep belief network: people = the ground-"
                                    "truth boxes (and the foreground blobs covering them), not "
                                    "people = background-subtraction noise blobs and random "
                                    "background windows. The last frames of each sequence's "
                                    "range are held out and scored (accuracy, ROC AUC). "
                                    "Use it with: pfscope record SOURCE --tracker dbn-phd "
                                    "--set model=MODEL.pt. The shipped default model: "
                                    "pfscope train-dbn ../shared/data/PETS09-S2L1 "
                                    "../shared/data/PETS09-S3MF1 --holdout 0 --augment --stride 3 "
                                    "--batch 256 --seed 0 --out people_dbn.pt")
    td.add_argument("source", nargs="+",
                    help="MOTChallenge folder(s) with gt/gt.txt, or 'synthetic'")
    td.add_argument("--out", type=Path, required=True, help="model file to write (MODEL.pt)")
    td.add_argument("--frames", type=FRAMES, default=None, metavar="N|FIRST:LAST",
                    help="frames to train on, e.g. 1:400 (default: all; one source only)")
    td.add_argument("--holdout", type=float, default=0.2,
                    help="fraction of each range, at its end, held out for scoring "
                         "(default 0.2; 0: train on everything)")
    td.add_argument("--augment", action="store_true",
                    help="also describe every sampled frame mirrored and colour-jittered")
    td.add_argument("--stride", type=int, default=2, help="sample every N-th frame (default 2)")
    td.add_argument("--epochs", type=int, default=30, help="fine-tuning epochs (default 30)")
    td.add_argument("--batch", type=int, default=64, help="mini-batch size (default 64)")
    td.add_argument("--seed", type=int, default=0, help="random seed (same seed, same model)")
    td.add_argument("--force", action="store_true", help="overwrite an existing model file")
    td.add_argument("--quiet", action="store_true")

    from .dlpf_cli import add_parser as add_train_classifier
    add_train_classifier(sub)
    return ap


def _add_tracker_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", dest="set_options", action="append", metavar="NAME=VALUE",
                   default=[],
                   help="set a tracker parameter, e.g. --set p_miss=0.2 --set rate.gap_s=3 "
                        "(dotted names pick one part: filter.motion.sigma_v; in compare, "
                        "phd.p_miss sets it for phd only). `pfscope trackers` lists them all.")
    p.add_argument("--preset", default=None,
                   help="parameter preset (default: the tracker's first; `pfscope trackers NAME` lists them — phd and mt: practical, paper, …)")
    p.add_argument("--params", type=Path, default=None, metavar="FILE.toml",
                   help="tracker parameters from a TOML file (what `pfscope tune` writes: "
                        "tracker = ..., [params] ...); --set overrides it")


def _add_tune_parser(sub, TRACKERS, DETECTORS, LEVELS) -> None:
    from pfscope.trackers.api import DEFAULT_TRACKER

    tn = sub.add_parser(
        "tune", help="search a tracker's parameters with Optuna against a sequence's ground "
                     "truth; write the best as a --params file",
        description="Search the tracker's documented numeric parameters with Optuna's seeded "
                    "TPE sampler, each trial running the pipeline without recording on the "
                    "tuned-on frames and scoring it against the ground truth. Prints one line "
                    "per trial, then the starting and the best parameters' scores on tuned-on "
                    "and held-out frames separately (mean over --eval-seeds seeds); writes the "
                    "best parameters as TOML (read by `record --params`), a recording of the "
                    "study (objective per trial) and the best parameters' recording. Same "
                    "seed and --batch, same result, whatever --jobs. Needs Optuna: "
                    "pip install \"pfscope[tune]\".")
    tn.add_argument("source", nargs="+",
                    help="MOTChallenge folder with gt/gt.txt, or 'synthetic'; several: tune "
                         "on all of them at once (the objective is the COMBINED score, counts "
                         "summed over the sequences; each is reported apart; --frames and "
                         "--holdout apply to each)")
    tn.add_argument("--tracker", default=None, choices=list(TRACKERS),
                    help=f"tracker to tune (default: the --params file's, else "
                         f"{DEFAULT_TRACKER})")
    _add_tracker_options(tn)
    tn.add_argument("--trials", type=POSITIVE_INT, default=30,
                    help="trials (default 30; the first is the starting values)")
    tn.add_argument("--metric", choices=["hota", "idf1", "mota"], default="hota",
                    help="objective maximised on the tuned-on frames (default hota)")
    tn.add_argument("--frames", type=FRAMES, default=None, metavar="N|FIRST:LAST",
                    help="frames to tune on: FIRST:LAST, or N for 1:N (default: the first "
                         "half of the sequence)")
    tn.add_argument("--holdout", type=STRICT_RANGE, default=None, metavar="FIRST:LAST",
                    help="held-out frames, scored apart (default: the rest of the sequence; "
                         "the synthetic scene is made twice as long as --frames)")
    tn.add_argument("--jobs", type=POSITIVE_INT, default=None,
                    help="parallel processes (default: the cores, at most --batch); the "
                         "result does not depend on it")
    tn.add_argument("--batch", type=POSITIVE_INT, default=4,
                    help="trials asked of the sampler per round (default 4; the result "
                         "depends on it)")
    tn.add_argument("--seed", type=NONNEG_INT, default=0,
                    help="sampler and tracker seed (and the synthetic scene's)")
    tn.add_argument("--trial-seeds", type=POSITIVE_INT, default=1,
                    help="tracker seeds averaged per trial (default 1)")
    tn.add_argument("--eval-seeds", type=POSITIVE_INT, default=3,
                    help="tracker seeds of the final table (default 3: seed .. seed+2)")
    tn.add_argument("--space", action="append", default=[], metavar="NAME[=LO:HI[:log|lin]]",
                    help="search this parameter (repeat; replaces the default list); without "
                         "a range, one is derived from its starting value")
    tn.add_argument("--convention", choices=["auto", "mot15", "mot16"], default="auto",
                    help="evaluation convention (as `pfscope eval`; default auto)")
    tn.add_argument("--detector", choices=list(DETECTORS), default=None)
    tn.add_argument("--min-score", type=float, default=float("-inf"),
                    help="drop file detections scoring below this")
    tn.add_argument("--fps", type=POSITIVE, default=None,
                    help="frame rate of an image folder or a video file")
    tn.add_argument("--targets", type=SCENE_TARGETS, default=None,
                    help="synthetic scene: number of people (default 6)")
    tn.add_argument("--clutter", type=SCENE_CLUTTER, default=None,
                    help="synthetic scene: mean false detections per frame (default 2)")
    tn.add_argument("--out", type=Path, default=Path("best.toml"),
                    help="best parameters, TOML (default best.toml)")
    tn.add_argument("--study-out", type=Path, default=None,
                    help="recording of the study (default recordings/<source>-<tracker>-"
                         "tune.rrd)")
    tn.add_argument("--best-out", type=Path, default=None,
                    help="recording of the best parameters over tuned-on and held-out frames "
                         "(default recordings/<source>-<tracker>-tuned.rrd)")
    tn.add_argument("--no-record", action="store_true",
                    help="do not record the best parameters' run")
    tn.add_argument("--level", choices=list(LEVELS), default="tracks",
                    help="level of the best parameters' recording (default tracks)")
    tn.add_argument("--tracks-out", type=Path, default=None,
                    help="also write the best parameters' tracks (MOT text) here")
    tn.add_argument("--force", action="store_true", help="overwrite existing outputs")
    tn.add_argument("--json", action="store_true", help="print the result as JSON")
    tn.add_argument("--quiet", action="store_true", help="no line per trial")


def _tracker_options(args) -> dict:
    from pfscope.trackers.params import parse_set

    try:
        return parse_set(args.set_options)
    except ValueError as e:
        raise InputError(str(e)) from None


def _read_params(args):
    """The ``--params`` file (a :class:`~pfscope.trackers.params.ParamsFile`) or None."""
    from pfscope.trackers.params import read_params_file

    if getattr(args, "params", None) is None:
        return None
    try:
        return read_params_file(args.params)
    except ValueError as e:
        raise InputError(str(e)) from None


def _check_params_file(pf, tracker: str, preset) -> None:
    """Every key and value of ``pf`` must fit ``tracker`` (one line naming file and key)."""
    from pfscope.trackers.api import make_params

    try:
        base = make_params(tracker, preset)
    except ValueError as e:
        raise InputError(f"{pf.path}: {e}") from None
    try:
        pf.check(base)
    except ValueError as e:
        raise InputError(str(e)) from None


def _single_tracker_params(args) -> tuple[str, object, dict]:
    """``record`` / ``tune``: (tracker, preset, options) from --tracker, --preset, --params
    and --set (--set wins over the file; the file's tracker and preset apply unless given)."""
    from pfscope.trackers.api import DEFAULT_TRACKER

    pf = _read_params(args)
    tracker = args.tracker or (pf.tracker if pf else None) or DEFAULT_TRACKER
    if pf is not None and pf.tracker and args.tracker and pf.tracker != args.tracker:
        raise InputError(f"{pf.path}: these parameters are for tracker {pf.tracker!r}, not "
                         f"{args.tracker!r} (leave out --tracker, or change 'tracker' in "
                         f"the file)")
    preset = args.preset or (pf.preset if pf else None)
    if pf is not None and pf.preset and not args.preset:
        from pfscope.trackers.api import tracker_info

        try:
            presets = tracker_info(tracker).presets
        except ValueError as e:
            raise InputError(f"{pf.path}: tracker: {e}") from None
        if pf.preset not in presets:
            from pfscope.trackers.errors import did_you_mean

            raise InputError(f"{pf.path}: preset: tracker {tracker!r} has no preset "
                             f"{pf.preset!r}{did_you_mean(pf.preset, presets)}; choose one of "
                             f"{', '.join(presets)}")
    options: dict = {}
    if pf is not None:
        _check_params_file(pf, tracker, preset)
        options.update(pf.options)
    options.update(_tracker_options(args))
    classifier = getattr(args, "classifier", None)
    if classifier is not None:
        from pfscope.trackers.api import registry, tracker_info
        from pfscope.trackers.params import leaves

        def has_model(name: str) -> bool:
            return any(n.rsplit(".", 1)[-1] == "model" for n, _, _ in
                       leaves(tracker_info(name).params))

        if not has_model(tracker):
            owners = [n for n in registry() if has_model(n)]
            raise InputError(f"--classifier sets the 'model' parameter, which {tracker!r} does "
                             f"not have (trackers with a classifier model: {', '.join(owners)})")
        options["model"] = str(classifier)
    return tracker, preset, options


def _lane_params_options(args, lane_trackers: list[str]) -> dict:
    """``compare`` / ``batch``: the --params file's options, named ``TRACKER.key`` when the
    file names its tracker (so they reach that tracker's lanes only)."""
    pf = _read_params(args)
    if pf is None:
        return {}
    preset = getattr(args, "preset", None) or pf.preset
    if pf.tracker:
        _check_params_file(pf, pf.tracker, preset)
        return {f"{pf.tracker}.{k}": v for k, v in pf.options.items()}
    errors = []
    for t in dict.fromkeys(lane_trackers):
        try:
            _check_params_file(pf, t, preset)
            break
        except InputError as e:
            errors.append(e)
    else:
        if errors:
            raise errors[0]
    return dict(pf.options)


def _option_text(value) -> str:
    """A typed option value as --set text (what parse_set / with_options read back)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, float) else str(value)


def _start_count(args) -> tuple[int, Optional[int]]:
    """``--frames N`` → (1, N); ``--frames FIRST:LAST`` → (FIRST, LAST - FIRST + 1); and
    ``args.frames`` becomes the synthetic scene's length (LAST)."""
    if isinstance(args.frames, tuple):
        first, last = args.frames
        args.frames = last
        return first, last - first + 1
    return 1, args.frames


def _open(args):
    from pfscope.trackers.data.sources import open_source

    synthetic = args.source in (None, "synthetic")
    if not synthetic and (args.targets is not None or args.clutter is not None):
        raise InputError("--targets/--clutter only apply to the synthetic scene")
    src = open_source(args.source, fps=args.fps,
                      synthetic_config=_synth_config(args, args.frames) if synthetic else None)
    if not getattr(src, "has_frames", True) and not getattr(args, "quiet", False):
        print(f"pfscope: {src.name} has no frames (no {getattr(src, 'im_dir', 'img1').name}/): "
              f"running on its detections with blank {src.width}x{src.height} frames; cues "
              f"that read pixels (PHD-MT's colour) are off", file=sys.stderr)
    return src


def _print_scores(scores: dict, as_json: bool) -> None:
    """Print ``{tracker name: evaluate() dict}`` as tables (or JSON), headed by the evaluation
    convention each dict carries (one line, or one per tracker when they differ)."""
    import json

    from pfscope.trackers.eval import describe_convention, format_table

    # keys starting with "_" are evaluate()'s intermediate counts (for combining sequences)
    scores = {name: {k: v for k, v in sc.items() if not k.startswith("_")}
              for name, sc in scores.items()}
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

    from .lanes import split_specs

    names = split_specs(args.trackers)
    if len(names) < 1:
        raise InputError("--trackers needs at least one tracker name")
    start, count = _start_count(args)
    source = _open(args)
    out = args.out or RECORDINGS_DIR / f"{source.name}-compare.rrd"
    from .lanes import parse_lanes

    file_opts = _lane_params_options(args, [ln.tracker for ln in parse_lanes(names)])
    opts = RecordOptions(detector=args.detector, min_score=args.min_score, level=args.level,
                         max_points=args.max_points, frames=count, start=start, seed=args.seed,
                         force=args.force, preset=args.preset, video=args.video,
                         tracker_options={**file_opts, **_tracker_options(args)},
                         online=args.online)
    res = record(source, out, opts, trackers=names, progress=not args.quiet)
    if res.scores:
        _print_scores(res.scores, args.json)
    else:
        print(f"{source.name} has no ground truth: nothing to score", file=sys.stderr)
    print(f"{res.frames} frames, {res.bytes / 1e6:.1f} MB -> {res.out}", file=sys.stderr)
    print(f"open it with:  rerun {res.out}", file=sys.stderr)
    return _interrupted_status() if res.interrupted else 0


def cmd_eval(args) -> int:
    from pfscope.trackers.data.motio import read_mot
    from pfscope.trackers.data.sources import MOTFolderSource
    from pfscope.trackers.eval import evaluate

    if args.tracks.is_dir():
        return _eval_folder(args)
    frames = None
    if args.gt.is_dir():
        seq = MOTFolderSource(args.gt)
        if seq.gt is None:
            raise InputError(f"{args.gt / 'gt' / 'gt.txt'}: no ground truth in this sequence")
        gt, frames = seq.gt, range(1, seq.length + 1)
    else:
        gt = read_mot(args.gt, "gt")
    tracks = read_mot(args.tracks, "tracks")
    if args.frames is not None:
        frames = range(args.frames[0], args.frames[1] + 1)
    elif len(tracks):
        # tracks that stop early (a run of --frames 30) against a full gt score every later
        # frame as all misses: say so, and how to score only the frames the tracks cover
        gt_last = frames[-1] if frames is not None else gt.last_frame
        t_first, t_last = int(tracks.frame.min()), tracks.last_frame
        if t_last < 0.9 * gt_last or t_first > 0.1 * gt_last + 1:
            print(f"pfscope: warning: {args.tracks} covers frames {t_first}..{t_last} of the "
                  f"ground truth's 1..{gt_last}; every frame outside counts as misses "
                  f"(score only the covered frames with --frames 1:{t_last})", file=sys.stderr)
    kw = {k: v for k, v in (("ospa_c", args.ospa_c), ("ospa_p", args.ospa_p)) if v is not None}
    scores = evaluate(gt, tracks, iou_threshold=args.iou, frames=frames,
                      convention=args.convention, **kw)
    _print_scores({args.tracks.stem: scores}, args.json)
    return 0


def _eval_folder(args) -> int:
    """``pfscope eval TRACKS_DIR --gt SEQS_DIR``: every tracks file matched to its sequence
    (``SEQ.txt`` or ``SEQ-<run>.txt``), one table per run (tracker, seed) with a row per
    sequence and the COMBINED row."""
    import json

    from pfscope.trackers.data.motio import read_mot
    from pfscope.trackers.data.sources import MOTFolderSource
    from pfscope.trackers.eval import combine, evaluate, format_table

    if not args.gt.is_dir():
        raise InputError(f"{args.gt}: with a folder of tracks files, --gt must be a folder of "
                         f"MOTChallenge sequences")
    seqs = sorted(p for p in args.gt.iterdir() if (p / "gt" / "gt.txt").is_file())
    if (args.gt / "gt" / "gt.txt").is_file():
        seqs = [args.gt]
    if not seqs:
        raise InputError(f"{args.gt}: no sequence with gt/gt.txt in this folder")
    files = sorted(p for p in args.tracks.iterdir() if p.suffix == ".txt" and p.is_file())
    runs: dict[str, dict[str, Path]] = {}
    for f in files:
        # the longest sequence name the file's stem starts with (SEQ or SEQ-<run>)
        match = [s for s in seqs if f.stem == s.name or f.stem.startswith(s.name + "-")]
        if not match:
            continue
        seq = max(match, key=lambda s: len(s.name))
        run_name = f.stem[len(seq.name) + 1:] or "tracks"
        runs.setdefault(run_name, {})[seq.name] = f
    if not runs:
        raise InputError(f"{args.tracks}: no tracks file named after a sequence of {args.gt} "
                         f"(expected SEQ.txt or SEQ-<run>.txt for SEQ in "
                         f"{', '.join(s.name for s in seqs[:5])})")
    kw = {k: v for k, v in (("ospa_c", args.ospa_c), ("ospa_p", args.ospa_p)) if v is not None}
    by_name = {s.name: s for s in seqs}
    results: dict[str, dict] = {}
    for run_name, per_seq in sorted(runs.items()):
        table: dict[str, dict] = {}
        for name in sorted(per_seq):
            src = MOTFolderSource(by_name[name])
            frames = range(1, src.length + 1)
            if args.frames is not None:
                frames = range(args.frames[0], min(args.frames[1], src.length) + 1)
            table[name] = evaluate(src.gt, read_mot(per_seq[name], "tracks"),
                                   iou_threshold=args.iou, frames=frames,
                                   convention=args.convention, **kw)
        missing = sorted(set(by_name) - set(per_seq))
        if missing:
            print(f"pfscope: warning: {run_name}: no tracks for {', '.join(missing)}; the "
                  f"COMBINED row covers the {len(per_seq)} sequences it has", file=sys.stderr)
        table["COMBINED"] = combine(list(table.values()))
        results[run_name] = {k: {m: v for m, v in sc.items() if not m.startswith("_")}
                             for k, sc in table.items()}
    if args.json:
        print(json.dumps(results, indent=2, sort_keys=True, default=float))
        return 0
    cols = ("MOTA", "IDF1", "HOTA", "MOTP", "IDSW", "FP", "FN", "OSPA")
    for run_name, table in results.items():
        print(f"== {run_name}")
        print(format_table(table, cols))
        print()
    return 0


def cmd_repair(args) -> int:
    import shutil
    import subprocess

    from pfscope.trackers.outputs import check_output, incomplete_path

    src = args.file
    if not src.is_file():
        raise InputError(f"{src}: no such recording")
    from .info import check_rrd_header

    check_rrd_header(src)
    out = args.out or src.with_name(f"{src.stem}.repaired{src.suffix}")
    check_output(out, args.force)
    rerun = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    tmp = incomplete_path(out)
    try:
        # absolute paths: a name starting with '-' must not reach rerun as an option
        r = subprocess.run([rerun, "rrd", "optimize", os.path.abspath(src), "-o",
                            os.path.abspath(tmp)],
                           capture_output=True, text=True, timeout=600)
        if r.returncode != 0:
            raise InputError(f"{src}: cannot be repaired: {_last_line(r.stderr)}")
        v = subprocess.run([rerun, "rrd", "verify", os.path.abspath(tmp)], capture_output=True,
                           text=True, timeout=600)
        if v.returncode != 0:
            raise InputError(f"{src}: repaired file does not verify: {_last_line(v.stderr)}")
    except (OSError, subprocess.TimeoutExpired) as e:
        raise InputError(f"{src}: cannot run '{rerun} rrd optimize' ({e})") from None
    if tmp.stat().st_size <= _rrd_size_empty():
        tmp.unlink()
        raise InputError(f"{src}: nothing could be recovered (no complete entry in the file)")
    os.replace(tmp, out)
    print(f"repaired: {out} (verified)")
    return 0


def _rrd_size_empty() -> int:
    """Size of an .rrd that holds no entry (header and footer only)."""
    return 256


def _last_line(text: str) -> str:
    lines = [ln for ln in (text or "").strip().splitlines() if ln.strip()]
    return lines[-1][:200] if lines else "no message"


def cmd_record(args) -> int:
    from .run import RecordOptions, default_out_path, record

    tracker, preset, options = _single_tracker_params(args)
    start, count = _start_count(args)
    source = _open(args)
    out = args.out or default_out_path(source, tracker)
    opts = RecordOptions(tracker=tracker, detector=args.detector, min_score=args.min_score,
                         level=args.level, max_points=args.max_points, frames=count, start=start,
                         seed=args.seed, force=args.force, tracks_out=args.tracks_out,
                         spawn=args.spawn, serve=args.serve, preset=preset,
                         timing=args.timing, tracker_options=options, video=args.video,
                         online=args.online,
                         inputs=(args.params,) if args.params else ())
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
              f"OSPA {sc['OSPA']:.1f} px  [{str(sc.get('convention', '?')).upper()} convention]")
    print(f"open it with:  rerun {res.out}")
    if args.serve and not args.serve_exit and res.serve_url:
        from .serve import WebServer

        # the run's own gRPC server closed with the recording: the finished file is served
        # on the same port, so the page already open keeps working
        server = WebServer(res.out, web=False, grpc_port=res.grpc_port)
        print(f"still serving {res.out} at {res.serve_url} until Ctrl-C "
              f"(--serve-exit: stop when the run ends)", flush=True)
        server.wait()
    return _interrupted_status() if res.interrupted else 0


def cmd_trackers(args) -> int:
    import json

    from pfscope.trackers.api import registry
    from pfscope.trackers.params import describe

    reg = registry()
    if args.name is not None and args.name not in reg:
        from pfscope.trackers.errors import did_you_mean

        raise InputError(f"unknown tracker {args.name!r}{did_you_mean(args.name, reg)}; "
                         f"choose one of {', '.join(reg)}")
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

    from dataclasses import replace

    cfg = replace(_synth_config(args, args.frames), bg_noise=args.bg_noise, flicker=args.flicker)
    path = write_sequence(args.out, cfg, progress=progress)
    print(f"wrote synthetic MOT sequence to {path}")
    print(f"record it with:  pfscope record {path}")
    return 0


def cmd_train_dbn(args) -> int:
    """``pfscope train-dbn``: DBN-PHD's classifier from sequences' ground truth."""
    import time

    import numpy as np

    from pfscope.trackers.data.sources import open_source

    from pfscope.trackers.outputs import check_output

    # before training: an unwritable --out must not cost the training run
    check_output(args.out, args.force, "model")
    if not 0.0 <= args.holdout < 1.0:
        raise InputError(f"--holdout must be in [0, 1), got {args.holdout}")
    if args.frames and len(args.source) > 1:
        raise InputError("--frames applies to one source; give one source or no --frames")
    ranges = []
    for spec in args.source:
        src = open_source(spec)
        lo, hi = frames_within(args.frames, getattr(src, "length", None), spec)
        ranges.append((spec, src, lo, hi))
    from pfscope.trackers.dbn.model import collect_samples, train_dbn  # torch, on demand

    t0 = time.perf_counter()
    last_print = [0.0]

    def progress(phase, i, n):
        now = time.perf_counter()
        if not args.quiet and (i == n or now - last_print[0] > 2.0):
            last_print[0] = now
            print(f"train-dbn: {phase} {i}/{n} ({now - t0:.0f} s)", file=sys.stderr)

    Xs, ys, holds, parts, heights = [], [], [], [], []
    for k, (spec, src, lo, hi) in enumerate(ranges):
        stats: dict = {}
        X, y, f = collect_samples(src, range(lo, hi + 1), stride=args.stride,
                                  seed=args.seed + k, augment=args.augment,
                                  progress=progress, with_frames=True, stats=stats)
        if "box_height" in stats:
            heights.append(stats["box_height"])
        cut = hi - int(round(args.holdout * (hi - lo + 1)))
        Xs.append(X)
        ys.append(y)
        holds.append(f > cut)
        parts.append(f"{src.name} frames {lo}-{cut}"
                     + (f" (held out {cut + 1}-{hi})" if cut < hi else ""))
    X, y = np.concatenate(Xs), np.concatenate(ys)
    hold = np.concatenate(holds) if args.holdout > 0 else None
    if args.batch < 1:
        raise InputError(f"--batch must be >= 1, got {args.batch}")
    model = train_dbn(X, y, seed=args.seed, fine_epochs=args.epochs, holdout_mask=hold,
                      holdout=0.0, batch=args.batch, progress=progress,
                      box_height=float(np.median(heights)) if heights else None)
    model.info["trained_on"] = "; ".join(parts)
    model.info["augment"] = bool(args.augment)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    model.save(args.out)
    i = model.info
    people = int(np.sum(y)) - i.get("holdout_positives", 0)
    print(f"trained on {i['samples'] - i['holdout']} samples ({people} people) from "
          f"{i['trained_on']} in {time.perf_counter() - t0:.0f} s")
    if "holdout_auc" in i:
        print(f"held out {i['holdout']} samples ({i['holdout_positives']} people): accuracy "
              f"{i['holdout_accuracy']:.3f}  ROC AUC {i['holdout_auc']:.3f}")
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KB)")
    print(f"use it with:  pfscope record {args.source[0]} --tracker dbn-phd "
          f"--set model={args.out}")
    return 0


def _batch_params(args) -> None:
    """``batch --params FILE``: the file's options go in front of the --set options (so --set
    wins), named ``TRACKER.key`` when the file names its tracker."""
    if getattr(args, "params", None) is None:
        return
    from .lanes import parse_lanes, split_specs

    lanes = parse_lanes(split_specs(args.trackers)) if args.trackers else []
    opts = _lane_params_options(args, [ln.tracker for ln in lanes] or ["phd"])
    args.set_options = [f"{k}={_option_text(v)}" for k, v in opts.items()] + \
        list(args.set_options or [])


def _tune_sequence(T, path, args):
    """A further sequence of ``tune SEQ SEQ ...``: its source and frames (``--frames`` and
    ``--holdout`` as for the first; default the first half, the rest held out)."""
    spec = T.SourceSpec(str(path), args.fps, None)
    source = spec.open()
    if source.gt is None:
        raise InputError(f"{path}: no ground truth (gt/gt.txt): nothing to tune against")
    length = source.length
    if length is None or length < 2:
        raise InputError(f"{path}: tune needs a sequence of known length, at least 2 frames")
    frames = args.frames
    if isinstance(frames, int):
        frames = (1, frames)
    frames, holdout = _tune_ranges(frames, args.holdout, length, source.name)
    return T.TuneSequence(spec, frames, holdout, source.name)


def _tune_ranges(frames, holdout, length: int, name: str):
    """``tune``'s tuned-on and held-out frame ranges of one sequence of ``length`` frames:
    default the first half and the rest; each checked against the length, and not
    overlapping."""
    if frames is None:
        frames = (1, length // 2)
    if holdout is None:
        holdout = (frames[1] + 1, length) if frames[1] < length else \
            ((1, frames[0] - 1) if frames[0] > 1 else None)
    for what, (a, b) in (("--frames", frames), ("--holdout", holdout or (1, 1))):
        if b > length:
            raise InputError(f"{what} {a}:{b}: {name} has {length} frames")
    if holdout is not None and holdout[0] <= frames[1] and frames[0] <= holdout[1]:
        raise InputError(f"--holdout {holdout[0]}:{holdout[1]} overlaps the tuned-on frames "
                         f"{frames[0]}:{frames[1]}")
    return frames, holdout


def cmd_tune(args) -> int:
    """``pfscope tune``: see :mod:`pfscope.viewer_app.tune`."""
    import json
    from dataclasses import asdict

    from pfscope.trackers.api import make_params
    from pfscope.trackers.outputs import check_output
    from pfscope.trackers.params import write_params_file

    from . import tune as T
    from .run import RECORDINGS_DIR, RecordOptions, record

    optuna = T.import_optuna()
    tracker, preset, base_options = _single_tracker_params(args)
    try:
        make_params(tracker, preset, base_options)
    except ValueError as e:
        raise InputError(str(e)) from None
    sources = list(args.source) if isinstance(args.source, (list, tuple)) else [args.source]
    more = []
    if len(sources) > 1:
        if "synthetic" in sources:
            raise InputError("tune on several sequences takes MOT folders, not 'synthetic'")
        if len({str(Path(p).resolve()) for p in sources}) != len(sources):
            raise InputError("tune: a sequence is given twice")
        if args.best_out is not None or args.tracks_out is not None:
            raise InputError("--best-out/--tracks-out record one sequence: give one source "
                             "(or --no-record)")
        args.no_record = True
        more = [_tune_sequence(T, p, args) for p in sources[1:]]
    args.source = sources[0]
    synthetic = args.source in (None, "synthetic")
    if not synthetic and (args.targets is not None or args.clutter is not None):
        raise InputError("--targets/--clutter only apply to the synthetic scene")
    frames = args.frames
    if isinstance(frames, int):
        frames = (1, frames)
    synth = None
    if synthetic:
        from pfscope.trackers.data.synthetic import demo_config

        kw = {"seed": args.seed}
        for name in ("targets", "clutter"):
            if getattr(args, name) is not None:
                kw[name] = getattr(args, name)
        if frames is not None:
            kw["frames"] = max(frames[1], args.holdout[1]) if args.holdout else 2 * frames[1]
        elif args.holdout is not None:
            kw["frames"] = max(demo_config().frames, args.holdout[1])
        synth = tuple(asdict(demo_config(**kw)).items())
    spec = T.SourceSpec(None if synthetic else str(args.source), args.fps, synth)
    source = spec.open()
    if source.gt is None:
        raise InputError(f"{args.source}: no ground truth (gt/gt.txt): nothing to tune against")
    length = source.length
    if length is None:
        raise InputError(f"{args.source}: length unknown; tune needs a sequence with a known "
                         f"number of frames")
    if frames is None and length < 2:
        raise InputError(f"{args.source}: {length} frame(s): too short to tune and hold out")
    frames, holdout = _tune_ranges(frames, args.holdout, length, source.name)
    from pfscope.trackers.outputs import refuse_inputs

    from .run import run_inputs

    refuse_inputs([(args.out, "parameters file"), (args.study_out, "recording"),
                   (args.best_out, "recording"), (args.tracks_out, "tracks file")],
                  run_inputs(source, [make_params(tracker, preset, base_options)],
                             (args.params,) if args.params else ()))
    out = check_output(args.out, args.force, "parameters file")
    label = source.name + (f"+{len(more)}" if more else "")
    study_out = check_output(args.study_out or RECORDINGS_DIR / f"{label}-{tracker}-tune.rrd",
                             args.force)
    best_out = None
    if not args.no_record:
        best_out = check_output(args.best_out or RECORDINGS_DIR / f"{source.name}-{tracker}-"
                                                                   f"tuned.rrd", args.force)
        if args.tracks_out is not None:
            check_output(args.tracks_out, args.force, "tracks file")
    elif args.tracks_out is not None:
        raise InputError("--tracks-out needs the best parameters' run (drop --no-record)")
    names = [p.resolve() for p in (out, study_out, best_out, args.tracks_out) if p is not None]
    if len(set(names)) != len(names):
        raise InputError("--out, --study-out, --best-out and --tracks-out must differ")
    jobs = args.jobs or max(1, min(os.cpu_count() or 1, args.batch))
    cfg = T.TuneConfig(source=spec, tracker=tracker, frames=frames, holdout=holdout,
                       preset=preset, base_options=base_options, trials=args.trials,
                       metric=args.metric, seed=args.seed, batch=args.batch, jobs=jobs,
                       trial_seeds=args.trial_seeds, eval_seeds=args.eval_seeds,
                       space=args.space or None, detector=args.detector,
                       min_score=args.min_score,
                       convention=None if args.convention == "auto" else args.convention,
                       more=tuple(more), name=source.name)
    from pfscope.trackers.api import tracker_info

    preset_name = preset or next(iter(tracker_info(tracker).presets))
    names = ", ".join([source.name] + [q.name for q in more])
    title = f"pfscope tune: {tracker} on {names}"
    dims = T.search_space(tracker, make_params(tracker, preset, base_options), cfg.space)
    log = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    if log:
        log(f"tune: {tracker} (preset {preset_name}) on {names}, {args.trials} "
            f"trials, {T.METRICS[args.metric]} on frames {frames[0]}-{frames[1]} (held out: "
            + (f"{holdout[0]}-{holdout[1]}" if holdout else "none") + f"), seed {args.seed}, "
            f"{jobs} process(es), rounds of {args.batch}; searching "
            + "; ".join(d.describe() for d in dims))
    study = T.StudyRecorder(study_out, title, {
        "tracker": tracker, "preset": preset_name, "source": names,
        "metric": T.METRICS[args.metric], "tuned_on": f"{frames[0]}:{frames[1]}",
        "held_out": f"{holdout[0]}:{holdout[1]}" if holdout else "none",
        "trials": args.trials, "seed": args.seed, "batch": args.batch,
        "trial_seeds": args.trial_seeds, "optuna": optuna.__version__,
        "space": [d.describe() for d in dims]})
    try:
        result = T.run_study(cfg, log=log, on_trial=study.trial)
    except BaseException:
        kept = study.abort()
        print(f"pfscope: tune: the study recording stays incomplete: {kept}", file=sys.stderr)
        raise
    best_params = make_params(tracker, preset, {**base_options, **result.best_options})
    marked = {}
    for d in result.dims:
        for name, v in T._targets(make_params(tracker, preset, base_options), d.name):
            marked[name] = f"tuned (start {v!r})"
    info = T.tune_info(result, names)
    combined = " COMBINED over the sequences" if more else ""
    header = (f"pfscope tune: {tracker} on {names}, best of {len(result.trials)} trials "
              f"({T.METRICS[args.metric]}{combined} on frames {frames[0]}-{frames[1]})\n"
              f"use: pfscope record {args.source} --params {out}")
    write_params_file(out, tracker, best_params, preset=preset_name, info=info, header=header,
                      marked=marked)
    study_path = study.finish(T.markdown_summary(result, title, out),
                              {"trial": result.best["number"],
                               "objective": result.best_value, **result.best_options})
    rec_res = None
    if best_out is not None:
        lo = min(frames[0], holdout[0]) if holdout else frames[0]
        hi = max(frames[1], holdout[1]) if holdout else frames[1]
        opts = RecordOptions(tracker=tracker, detector=args.detector, min_score=args.min_score,
                             level=args.level, frames=hi - lo + 1, start=lo, seed=args.seed,
                             force=args.force, tracks_out=args.tracks_out, preset=preset,
                             tracker_options={**base_options, **result.best_options})
        rec_res = record(source, best_out, opts, progress=not args.quiet)
    if args.json:
        print(json.dumps({
            "tracker": tracker, "preset": preset, "source": names,
            "sequences": [source.name] + [q.name for q in more],
            "metric": T.METRICS[args.metric], "best_trial": result.best["number"],
            "best_value": result.best_value, "start_value": result.start_value,
            "best_options": result.best_options, "table": result.table,
            "trials": [{k: t[k] for k in ("number", "value", "options", "error")}
                       for t in result.trials],
            "params_file": str(out), "study": str(study_path),
            "best_recording": str(rec_res.out) if rec_res else None}, indent=2, default=str))
        return _interrupted_status() if rec_res is not None and rec_res.interrupted else 0
    print(f"{T.METRICS[args.metric]}{combined} on the tuned-on frames "
          f"{frames[0]}-{frames[1]} (the search's runs, over those frames alone): "
          f"{result.best_value:.4f} (trial {result.best['number']} of {len(result.trials)}; "
          f"starting values {result.start_value:.4f})")
    print(f"best: {T._fmt_opts(result.best_options)}")
    print(T.format_table(result))
    print(f"parameters: {out}   (pfscope record {args.source} --params {out})")
    print(f"study: {study_path}" + (f"   best run: {rec_res.out}" if rec_res else "")
          + (f"   tracks: {rec_res.tracks_out}" if rec_res and rec_res.tracks_out else ""))
    return _interrupted_status() if rec_res is not None and rec_res.interrupted else 0


def _early_compile(argv: list) -> None:
    """``record`` of a tracker that runs the PHD kernels, on a first run (empty numba cache):
    start the compile helper (:func:`pfscope.trackers.warmup.start_helper_early`) before the
    run imports its tracker, so it compiles meanwhile.  Only the plain
    ``--tracker NAME`` form is read here (with ``--params`` the file names the tracker:
    ``record`` starts the helper itself later)."""
    if not argv or argv[0] != "record":
        return
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--tracker")
    pre.add_argument("--params")
    try:
        known, _ = pre.parse_known_args(argv[1:])
    except SystemExit:        # malformed: the real parser says why
        return
    if known.params:
        return
    from pfscope.trackers.api import DEFAULT_TRACKER
    from pfscope.trackers.warmup import start_helper_early

    start_helper_early([known.tracker or DEFAULT_TRACKER])


def main(argv: Optional[Sequence[str]] = None) -> int:
    from pfscope.trackers.jobs import Interrupted

    os.environ.setdefault("RERUN_ANALYTICS", "0")
    _early_compile(list(sys.argv[1:] if argv is None else argv))
    try:
        args = build_parser().parse_args(argv)
    except BrokenPipeError:  # `pfscope --help | head`: the reader left
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as e:  # `pfscope --help > /dev/full`: say so, never exit 0 silently
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        print(f"pfscope: error: cannot write ({e.strerror}); nothing more was written",
              file=sys.stderr)
        return EXIT_RUN_FAILED
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
        if args.command == "repair":
            return cmd_repair(args)
        if args.command == "train-dbn":
            return cmd_train_dbn(args)
        if args.command == "train-classifier":
            from .dlpf_cli import cmd_train_classifier
            return cmd_train_classifier(args)
        if args.command == "info":
            from .info import cmd_info
            return cmd_info(args)
        if args.command == "view":
            from .info import cmd_view
            return cmd_view(args)
        if args.command == "export":
            from .export import cmd_export
            return cmd_export(args)
        if args.command == "snapshot":
            from .snapshot import cmd_snapshot
            return cmd_snapshot(args)
        if args.command == "batch":
            from .batch import cmd_batch
            _batch_params(args)
            return cmd_batch(args)
        if args.command == "tune":
            return cmd_tune(args)
    except InputError as e:
        print(f"pfscope: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except RunFailed as e:
        print(f"pfscope: run failed: {e}", file=sys.stderr)
        if os.environ.get("PFSCOPE_DEBUG"):
            raise
        if getattr(e, "stalled", False):
            # Rerun's exit handler would wait forever on the stuck file writer (full disk)
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(EXIT_RUN_FAILED)
        return EXIT_RUN_FAILED
    except MemoryError as e:  # a size the machine cannot hold: one line, not numpy's trace
        print(f"pfscope: run failed: out of memory ({str(e).splitlines()[0] if str(e) else 'MemoryError'})",
              file=sys.stderr)
        return EXIT_RUN_FAILED
    except KeyboardInterrupt:
        print("pfscope: interrupted", file=sys.stderr)
        return _interrupted_status()
    except Interrupted as e:  # a batch or tune stopped by a signal
        print(f"pfscope: {args.command}: {e}", file=sys.stderr)
        return e.exit_status
    except BrokenPipeError:  # `pfscope trackers | head`: the reader left, nothing to report
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as e:
        import errno

        if e.errno not in (errno.ENOSPC, errno.EIO, errno.EFBIG):
            raise
        # stdout (or a file) on a full or failing device: one line, and no second traceback
        # when Python flushes stdout at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        print(f"pfscope: error: cannot write ({e.strerror}); nothing more was written",
              file=sys.stderr)
        return EXIT_RUN_FAILED
    return 1


def exit_process(status: int) -> None:
    """End the process with ``status`` the way the interpreter ends it -- the threads' shutdown
    (thread pools told to stop, the other non-daemon threads joined), the ``atexit`` handlers
    (Rerun's flush among them), stdout and stderr flushed -- but without its teardown of every
    module and object (0.3-1 s after a ``record``, which imports some 1,700 modules; nothing
    of it is output: the outputs are closed and renamed by then).  Without the interpreter's
    ``threading._shutdown`` it exits the ordinary way."""
    import atexit
    import threading

    shutdown = getattr(threading, "_shutdown", None)
    if shutdown is None or threading.current_thread() is not threading.main_thread():
        sys.exit(status)
    try:
        shutdown()
    except KeyboardInterrupt:             # Ctrl-C while the threads are joined: still exit
        status = status or _interrupted_status()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (BrokenPipeError, ValueError):     # a reader that left, a closed stream
            pass
        except OSError as e:              # a full or failing device: say so, never exit 0
            try:
                os.write(2, f"pfscope: error: cannot write ({e.strerror}); nothing more was "
                            f"written\n".encode())
            except OSError:
                pass
            status = status or EXIT_RUN_FAILED
    os._exit(status)


def entry() -> None:
    """The ``pfscope`` command (``[project.scripts]``): :func:`main` on the command line; a
    ``record`` ends through :func:`exit_process`, anything else the ordinary way."""
    status = main()
    if sys.argv[1:2] == ["record"]:
        exit_process(status)
    sys.exit(status)


if __name__ == "__main__":  # pragma: no cover
    entry()
