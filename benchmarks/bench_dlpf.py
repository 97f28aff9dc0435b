"""DLPF (jung2013) against an exhaustive sliding-window HOG detector feeding MT, in ONE run.

jung2013 claims "significantly reduced computation" against exhaustive detection without
measuring it.  This measures it: both pipelines run as two lanes of the same
:func:`pfscope.trackers.pipeline.run` on the same frames (stepped one after the other on every
frame, so a change of load on a shared machine hits both alike), and the script prints, per
lane, classifier windows/frame, frames/s, MOTA, IDF1, OSPA (and recall/precision), and the
ratios exhaustive / DLPF.

Lanes:

- ``dlpf``: ``make_tracker("dlpf", seed)`` (its defaults; ``--set NAME=VALUE`` overrides), no
  detections file.  Windows/frame = the tracker's own count of windows its classifier scored
  (parents' windows + the tracks' verification windows).  Time = the pipeline's
  ``FrameReport.step_seconds`` of the lane (the whole DLPF step: LK, parents, classifier,
  confirmation, children).
- ``hog-mt``: :class:`ExhaustiveLane`: the ``hog`` detector (``make_detector("hog")``:
  OpenCV's ``HOGDescriptor.detectMultiScale`` with the same default people SVM as DLPF's
  classifier; ``--hog-upscale`` to enlarge the frame first) followed by the MT tracker
  (``make_tracker("mt")``) on its detections: what ``pipeline.run(..., {"mt":
  make_tracker("mt")}, detector="hog")`` does, but the detector runs inside the lane so that its
  time is counted in the lane's ``step_seconds``.  Windows/frame =
  :func:`~pfscope.trackers.dlpf.classifier.sliding_window_count` of the detector's own pyramid
  parameters (win stride, padding, scale step, upscale / resize cap; OpenCV's 64 levels): the
  number of 64×128 windows ``detectMultiScale`` scores on a frame of that size.

Scores are the pipeline's (``run(...).scores``, CLEAR-MOT / identity / OSPA over exactly the
frames run, ``--start .. --start + --frames − 1``).  The machine is shared: absolute fps are
indicative, the ratios from the same run hold better.

Usage (the README numbers)::

    .venv/bin/python benchmarks/bench_dlpf.py --source pets --start 401 --seeds 0,1,2 --json /tmp/bench_dlpf.json
    .venv/bin/python benchmarks/bench_dlpf.py --source synthetic --seeds 0,1,2

DLPF against DLPF (the speed of a change, e.g. the classifier's pyramid mode against the
per-window HOG), as two lanes of one run, without the exhaustive lane::

    .venv/bin/python benchmarks/bench_dlpf.py --source pets --start 401 --seeds 0,1,2 \
        --baseline classifier.mode=window --no-exhaustive

**Whole-process speed and the per-stage profile** (``--profile``): ``pfscope record SOURCE
--tracker dlpf --level tracks`` as a user runs it, twice: once as a subprocess (wall time from
start to exit, the frame loop's fps the command prints, and what is left outside the loop:
imports, setup, scoring, closing the recording), once in this process through the
same ``record()`` with clocks around the stages (wall and main-thread CPU ms per frame: frame
decode, Lucas-Kanade, the classifier (the parents' windows and the tracks' verification
windows, which overlap on two threads), confirmation,
children, the rest of the DLPF step, the recorder, the rest of the loop)::

    .venv/bin/python benchmarks/bench_dlpf.py --profile --source pets --frames 795

``--seeds`` runs the whole comparison once per seed (DLPF is random, HOG+MT is not; the
synthetic scene is also generated with that seed) and prints each run and the mean.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Optional

from _common import (EXIT_NO_DATA, NoData, command_line, machine, open_bench_source,
                     pets_path, print_machine, table, write_json)

from pfscope.trackers.api import StepResult, make_tracker
from pfscope.trackers.data.sources import open_source
from pfscope.trackers.data.synthetic import SceneConfig
from pfscope.trackers.detect import make_detector
from pfscope.trackers.dlpf.classifier import sliding_window_count
from pfscope.trackers.pipeline import BaseHook, FrameReport, RunInfo, run
from pfscope.trackers.types import Detections, Frame

METRICS = ("MOTA", "IDF1", "OSPA", "Recall", "Precision", "IDSW")


class ExhaustiveLane:
    """Exhaustive HOG detector + MT as one lane: its ``step_seconds`` is detector + tracker."""

    name = "hog-mt"
    paper = "-"
    stages = ("detect", "track")
    needs_detections = False
    needs_image = True

    def __init__(self, detector_options: Optional[dict] = None, seed: int = 0):
        self.detector = make_detector("hog", **(detector_options or {}))
        self.mt = make_tracker("mt", seed)
        self.detect_seconds = 0.0
        self.windows = 0
        self.frames = 0

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult:
        t0 = time.perf_counter()
        dets = self.detector(frame)
        self.detect_seconds += time.perf_counter() - t0
        H, W = frame.image.shape[:2]
        d = self.detector
        self.windows += sliding_window_count(W, H, win_stride=d.win_stride, padding=d.padding,
                                             scale=d.scale, upscale=d.upscale,
                                             resize_to=d.resize_to)
        self.frames += 1
        return self.mt.step(frame, dets, level)

    def finish(self):
        return self.mt.finish()

    def config(self) -> dict:
        return {"tracker": "hog+mt", "detector": repr(self.detector), "mt": self.mt.config()}


class StepTimes(BaseHook):
    def begin(self, info: RunInfo) -> None:
        self.seconds: dict[str, float] = {lane: 0.0 for lane in info.trackers}

    def on_frame(self, report: FrameReport) -> None:
        for lane, s in report.step_seconds.items():
            self.seconds[lane] += s


def open_for(spec: str, seed: int, frames: Optional[int]):
    if spec == "synthetic":  # the scene is generated with the run's seed
        return open_source("synthetic", synthetic_config=SceneConfig(frames=frames or 150,
                                                                     seed=seed))
    return open_bench_source(spec)


def one_run(spec: str, seed: int, start: int, frames: Optional[int], dlpf_options: dict,
            hog_options: Optional[dict], baseline_options: Optional[dict] = None) -> dict:
    """One pipeline run: the ``dlpf`` lane, the ``hog-mt`` lane (unless ``hog_options`` is
    None) and a ``dlpf-base`` lane (DLPF with ``baseline_options``, when given)."""
    src = open_for(spec, seed, frames)
    lanes: dict = {"dlpf": make_tracker("dlpf", seed, **dlpf_options)}
    if baseline_options is not None:
        lanes["dlpf-base"] = make_tracker("dlpf", seed, **baseline_options)
    if hog_options is not None:
        lanes["hog-mt"] = ExhaustiveLane(hog_options, seed)
    times = StepTimes()
    res = run(src, lanes, frames=frames, start=start, hooks=[times])
    n = res.frames
    out = {"source": getattr(src, "name", spec), "seed": seed, "start": start, "frames": n,
           "size": None, "lanes": {}}
    for lane, trk in lanes.items():
        windows = (trk.windows / max(trk.frames, 1) if lane == "hog-mt"
                   else trk.windows_evaluated / max(trk.frames_seen, 1))
        s = res.scores.get(lane, {})
        out["lanes"][lane] = {"windows_per_frame": windows,
                              "fps": n / times.seconds[lane] if times.seconds[lane] else None,
                              "ms_per_frame": 1000 * times.seconds[lane] / max(n, 1),
                              **{m: float(s[m]) for m in METRICS if m in s}}
        out[f"{lane}_config"] = trk.config()
    if "hog-mt" in lanes:
        out["lanes"]["hog-mt"]["detector_ms_per_frame"] = \
            1000 * lanes["hog-mt"].detect_seconds / max(n, 1)
    return out


def ratios(d: dict, h: dict) -> dict:
    r = {"windows (hog/dlpf)": h["windows_per_frame"] / d["windows_per_frame"],
         "fps (dlpf/hog)": (d["fps"] or 0) / (h["fps"] or float("nan"))}
    for m in ("MOTA", "IDF1"):
        if m in d and m in h and h[m]:
            r[f"{m} (dlpf/hog)"] = d[m] / h[m]
    if "OSPA" in d and "OSPA" in h and d["OSPA"]:
        r["OSPA (hog/dlpf)"] = h["OSPA"] / d["OSPA"]
    return r


def mean_lane(runs: list[dict], lane: str) -> dict:
    keys = [k for k in runs[0]["lanes"][lane] if all(runs[i]["lanes"][lane].get(k) is not None
                                                     for i in range(len(runs)))]
    return {k: sum(r["lanes"][lane][k] for r in runs) / len(runs) for k in keys}


def fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.3f}" if abs(v) < 10 else f"{v:.1f}"
    return str(v)


# ----------------------------------------------------------------------------- --profile

#: the profile's stages, in the order printed; "dlpf other" and "loop other" are what is left
STAGES = ("decode", "lk flow", "classify", "confirm", "children", "dlpf other", "recorder",
          "loop other", "lk flow (helper)")


@contextlib.contextmanager
def dlpf_clocks(acc: dict):
    """Clocks (wall and main-thread CPU) around the functions one DLPF frame calls and around
    the frame loop's other parts (module/class attributes, restored after).  ``acc[stage]`` =
    [wall s, cpu s]; ``acc["step"]``, ``acc["loop"]`` the totals the remainders come from."""
    from pfscope.trackers import pipeline as pipe_mod
    from pfscope.trackers.dlpf import motion as mo_mod
    from pfscope.trackers.dlpf import tracker as tr_mod
    from pfscope.trackers.dlpf.classifier import HOGWindowClassifier
    from pfscope.trackers.dlpf.confirm import Confirmer
    from pfscope.viewer_app import recorder as rec_mod

    pc, tc = time.perf_counter, time.thread_time
    saved = []

    def add(stage, w, c):
        a = acc.setdefault(stage, [0.0, 0.0])
        a[0] += w
        a[1] += c

    depth = {}

    def wrap(owner, name, stage):
        fn = getattr(owner, name, None)
        if fn is None:                      # an older DLPF without it (e.g. score_with_exact)
            return

        def timed(*a, **k):
            # a call on another thread (DLPF's look-ahead runs the next frame's LK on a helper
            # while this frame is recorded) is its own stage, overlapped with the main thread's
            on = stage if threading.current_thread() is threading.main_thread() else \
                f"{stage} (helper)"
            if depth.get(on):               # a clocked call inside another of its stage
                return fn(*a, **k)
            depth[on] = True
            w0, c0 = pc(), tc()
            try:
                return fn(*a, **k)
            finally:
                add(on, pc() - w0, tc() - c0)
                depth[on] = False

        saved.append((owner, name, fn))
        setattr(owner, name, timed)

    wrap(mo_mod, "lk_flow", "lk flow")
    wrap(HOGWindowClassifier, "score", "classify")             # parents' and tracks' windows
    wrap(HOGWindowClassifier, "score_with_exact", "classify")  # both at once, overlapped
    wrap(Confirmer, "step", "confirm")
    wrap(tr_mod.DLPFTracker, "_update_children", "children")
    wrap(tr_mod.DLPFTracker, "step", "step")
    wrap(rec_mod.RerunRecorder, "on_frame", "recorder")
    frames_fn = pipe_mod.iter_frames

    def iter_frames(*a, **k):       # the time spent getting each frame (read + decode)
        it = frames_fn(*a, **k)
        while True:
            w0, c0 = pc(), tc()
            try:
                f = next(it)
            except StopIteration:
                return
            finally:
                add("decode", pc() - w0, tc() - c0)
            yield f

    saved.append((pipe_mod, "iter_frames", frames_fn))
    pipe_mod.iter_frames = iter_frames
    run_fn = pipe_mod.run

    def run(*a, **k):
        w0, c0 = pc(), tc()
        try:
            return run_fn(*a, **k)
        finally:
            add("loop", pc() - w0, tc() - c0)

    saved.append((pipe_mod, "run", run_fn))
    pipe_mod.run = run
    try:
        yield acc
    finally:
        for owner, name, fn in reversed(saved):
            setattr(owner, name, fn)


def whole_process(source: str, frames: Optional[int], seed: int, dlpf_options: dict) -> dict:
    """``pfscope record SOURCE --tracker dlpf --level tracks`` as a subprocess: wall seconds from
    start to exit, CPU seconds, and the frame loop's own frames and seconds (its last line)."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "pfscope.viewer_app.cli", "record", source,
               "--tracker", "dlpf", "--level", "tracks", "--seed", str(seed), "--quiet",
               "--out", str(Path(tmp) / "p.rrd")]
        if frames:
            cmd += ["--frames", str(frames)]
        for k, v in dlpf_options.items():
            cmd += ["--set", f"{k}={v}"]
        r0 = os.times()
        t0 = time.perf_counter()
        p = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        r1 = os.times()
    if p.returncode != 0:
        raise RuntimeError(f"pfscope record failed: {p.stderr.strip().splitlines()[-1:]}")
    m = re.search(r"(\d+) frames in ([\d.]+) s", p.stdout + p.stderr)
    n, loop = (int(m.group(1)), float(m.group(2))) if m else (frames or 0, float("nan"))
    cpu = (r1.children_user - r0.children_user) + (r1.children_system - r0.children_system)
    return {"frames": n, "wall_s": wall, "cpu_s": cpu, "loop_s": loop,
            "fps_whole": n / wall, "fps_loop": n / loop if loop else float("nan")}


def profile_run(source: str, frames: Optional[int], seed: int, dlpf_options: dict) -> dict:
    """The same record in this process with :func:`dlpf_clocks`: ms per frame per stage."""
    from pfscope.trackers.data.sources import open_source
    from pfscope.viewer_app.run import RecordOptions, record

    acc: dict = {}
    with tempfile.TemporaryDirectory() as tmp, dlpf_clocks(acc):
        opts = RecordOptions(tracker="dlpf", level="tracks", frames=frames, seed=seed,
                             tracker_options=dict(dlpf_options))
        c0 = time.process_time()
        res = record(open_source(source), Path(tmp) / "p.rrd", opts, progress=False)
        cpu_all = time.process_time() - c0
    n = max(res.frames, 1)
    zero = [0.0, 0.0]
    step, loop = acc.get("step", zero), acc.get("loop", zero)
    inner = [acc.get(s, zero) for s in ("lk flow", "classify", "confirm", "children")]
    acc["dlpf other"] = [step[i] - sum(x[i] for x in inner) for i in (0, 1)]
    acc["loop other"] = [loop[i] - step[i] - acc.get("decode", zero)[i]
                         - acc.get("recorder", zero)[i] for i in (0, 1)]
    stages = {s: {"wall_ms": 1000 * acc.get(s, zero)[0] / n, "cpu_ms": 1000 * acc.get(s, zero)[1] / n}
              for s in STAGES}
    return {"frames": res.frames, "loop_wall_s": loop[0], "loop_cpu_s": loop[1],
            "other_threads_cpu_s": cpu_all - loop[1] if cpu_all >= loop[1] else 0.0,
            "scores": {k: float(v) for k, v in res.scores.get("dlpf", {}).items()
                       if k in ("MOTA", "IDF1")},
            "stages": stages}


def main_profile(a, dlpf_options: dict) -> int:
    info = machine()
    print_machine(info)
    source = a.source
    if source == "pets":
        source = str(pets_path())
    seed = int(a.seeds.split(",")[0])
    print(f"whole process: pfscope record {source} --tracker dlpf --level tracks ...",
          file=sys.stderr, flush=True)
    whole = whole_process(source, a.frames, seed, dlpf_options)
    print("profile: the same run in this process with stage clocks ...", file=sys.stderr,
          flush=True)
    prof = profile_run(source, a.frames, seed, dlpf_options)
    n = prof["frames"]
    print(f"\n=== DLPF whole process on {source}, {n} frames, seed {seed}, --level tracks ===")
    print(f"subprocess: {whole['wall_s']:.1f} s start to exit ({whole['fps_whole']:.1f} frames/s"
          f" whole process), frame loop {whole['loop_s']:.1f} s ({whole['fps_loop']:.1f} fps), "
          f"{whole['cpu_s']:.1f} CPU s")
    outside = whole["wall_s"] - whole["loop_s"]
    print(f"outside the frame loop (imports, setup, scoring, closing the recording): "
          f"{outside:.1f} s wall, {100 * outside / whole['wall_s']:.0f} % of the process")
    loop_ms = 1000 * prof["loop_wall_s"] / max(n, 1)
    cpu_ms = 1000 * prof["loop_cpu_s"] / max(n, 1)
    rows = [[s, f"{v['wall_ms']:.2f}", f"{100 * v['wall_ms'] / loop_ms:.1f}",
             f"{v['cpu_ms']:.2f}", f"{100 * v['cpu_ms'] / cpu_ms:.1f}"]
            for s, v in prof["stages"].items()]
    rows.append(["frame loop", f"{loop_ms:.2f}", "100", f"{cpu_ms:.2f}", "100"])
    print(f"\nper-stage profile (in-process, stage clocks; frame loop {1000 / loop_ms:.1f} fps "
          f"wall, {1000 / cpu_ms:.1f} fps by main-thread CPU; other threads "
          f"{1000 * prof['other_threads_cpu_s'] / max(n, 1):.2f} CPU ms/frame):")
    print(table(["stage", "wall ms/frame", "wall %", "CPU ms/frame", "CPU %"], rows))
    if prof["scores"]:
        print("scores: " + ", ".join(f"{k} {v:.3f}" for k, v in prof["scores"].items()))
    write_json(a.json, {"command": command_line(), "machine": info, "source": source,
                        "seed": seed, "whole_process": whole, "profile": prof})
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", default="pets", help="pets | synthetic | PATH (default pets)")
    ap.add_argument("--start", type=int, default=None,
                    help="first frame (default: 401 for pets — frames 1-400 are where DLPF's "
                         "settings were chosen — else 1)")
    ap.add_argument("--frames", type=int, default=None,
                    help="frames to run (default: to the end; synthetic: 150)")
    ap.add_argument("--seeds", default="0", help="comma-separated seeds, one run each")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="DLPF parameter override (as pfscope record --set)")
    ap.add_argument("--hog-upscale", type=float, default=1.0,
                    help="hog detector upscale (default 1: the pipeline's hog detector as is)")
    ap.add_argument("--baseline", action="append", default=None, metavar="NAME=VALUE",
                    help="also run a 'dlpf-base' lane: DLPF with these overrides (repeatable; "
                         "e.g. classifier.mode=window for the per-window HOG), in the same run")
    ap.add_argument("--no-exhaustive", action="store_true",
                    help="leave out the hog-mt lane (e.g. to time dlpf against dlpf-base only)")
    ap.add_argument("--json", default=None, metavar="FILE", help="write every number to FILE")
    ap.add_argument("--profile", action="store_true",
                    help="whole-process speed of `pfscope record SOURCE --tracker dlpf --level "
                         "tracks` and its per-stage profile (frames from 1; --frames, first seed)")
    a = ap.parse_args(argv)
    start = a.start if a.start is not None else (401 if a.source == "pets" else 1)
    dlpf_options = dict(s.split("=", 1) for s in a.set)
    if a.profile:
        try:
            return main_profile(a, dlpf_options)
        except NoData as e:
            print(f"error: {e}", file=sys.stderr)
            return EXIT_NO_DATA
    hog_options = None if a.no_exhaustive else \
        ({"upscale": a.hog_upscale} if a.hog_upscale != 1.0 else {})
    base_options = None if a.baseline is None else {**dlpf_options, **dict(
        s.split("=", 1) for s in a.baseline)}
    info = machine()
    print_machine(info)
    runs = []
    try:
        for seed in (int(s) for s in a.seeds.split(",")):
            lanes = ["dlpf"] + (["dlpf-base"] if base_options is not None else []) + \
                ([] if hog_options is None else ["hog-mt"])
            print(f"seed {seed}: running {', '.join(lanes)} on {a.source} from frame {start} ...",
                  file=sys.stderr, flush=True)
            runs.append(one_run(a.source, seed, start, a.frames, dlpf_options, hog_options,
                                base_options))
    except NoData as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_NO_DATA
    r0 = runs[0]
    print(f"\n=== {r0['source']}: frames {start}..{start + r0['frames'] - 1} "
          f"({r0['frames']} frames), seeds {a.seeds}, both lanes in one pipeline run ===")
    cols = ["windows_per_frame", "fps", "ms_per_frame", *METRICS]
    rows = []
    names = list(r0["lanes"])
    for r in runs:
        for lane in names:
            rows.append([f"{lane} seed {r['seed']}", *(fmt(r["lanes"][lane].get(c)) for c in cols)])
    means = {lane: mean_lane(runs, lane) for lane in names}
    if len(runs) > 1:
        for lane in names:
            rows.append([f"{lane} mean", *(fmt(means[lane].get(c)) for c in cols)])
    print(table(["lane", "windows/frame", "fps", "ms/frame", *METRICS], rows))
    rat = {}
    if "hog-mt" in means:
        rat = ratios(means["dlpf"], means["hog-mt"])
        print("\nratios (mean over seeds): " + ", ".join(f"{k} = {v:.3g}" for k, v in rat.items()))
        print(f"hog detector alone: {means['hog-mt'].get('detector_ms_per_frame', float('nan')):.1f}"
              f" ms/frame of the hog-mt lane's {means['hog-mt']['ms_per_frame']:.1f}")
    if "dlpf-base" in means:
        d, b = means["dlpf"], means["dlpf-base"]
        rat["fps (dlpf/dlpf-base)"] = (d["fps"] or 0) / (b["fps"] or float("nan"))
        print(f"\ndlpf vs dlpf-base ({' '.join(a.baseline)}), mean over seeds: fps ratio "
              f"{rat['fps (dlpf/dlpf-base)']:.3g}, ms/frame {d['ms_per_frame']:.1f} vs "
              f"{b['ms_per_frame']:.1f}, MOTA {d.get('MOTA', float('nan')):.3f} vs "
              f"{b.get('MOTA', float('nan')):.3f}")
    write_json(a.json, {"command": command_line(), "machine": info, "start": start,
                        "runs": runs, "mean": means, "ratios": rat})
    return 0


if __name__ == "__main__":
    sys.exit(main())
