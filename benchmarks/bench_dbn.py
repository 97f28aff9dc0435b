"""DBN-PHD (feng2015) against its no-DBN baseline ``phd-bgsub``, per stage, in ONE run.

Both trackers run as two lanes of the same :func:`pfscope.trackers.pipeline.run` on the same
frames (stepped one after the other on every frame, so a change of load on this shared machine
hits both alike).  Per lane the script prints:

- milliseconds per frame of every stage of the tracker (``background``, ``blobs``, ``predict``,
  ``birth``, ``features``, ``update``, ``resample``, ``cluster``, ``associate``), measured by a
  timing subclass whose stage log notes the clock at every stage change (the tracker's own
  code, nothing re-implemented here);
- frames/s of the whole tracker step (the pipeline's ``FrameReport.step_seconds``; image
  reading and scoring are outside it, and common to both lanes);
- OSPA, ME (pixels), MOTA, IDF1, FP, FN over exactly the frames run (the pipeline's scores).

``dbn-phd`` and ``phd-bgsub`` have the same background model, births, filter, resampling,
K-means and association; the DBN lane adds the DBN scores of the blobs (and of the particles
at ``--level particles``).  The DBN model: ``--model FILE`` (``pfscope train-dbn``; for PETS
train it on the other half than the frames benchmarked), else the default model (trained on
first use on the built-in synthetic scene, never on the frames run).

Usage (README numbers)::

    pfscope train-dbn ../shared/data/PETS09-S2L1 --frames 1-400 --out /tmp/pets_1_400.pt
    .venv/bin/python benchmarks/bench_dbn.py --source pets --start 401 --model /tmp/pets_1_400.pt \\
        --seeds 0,1,2 --json /tmp/bench_dbn.json
    .venv/bin/python benchmarks/bench_dbn.py --source synthetic --frames 100 --seeds 0

Absolute times depend on the machine's load (printed); ratios within one run hold better.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Optional

from _common import (EXIT_NO_DATA, NoData, command_line, machine, open_bench_source,
                     pets_path, print_machine, table, write_json)

import numpy as np

from pfscope.trackers.api import make_params
from pfscope.trackers.dbn.tracker import DBNPHDTracker, PHDBgsubTracker
from pfscope.trackers.errors import InputError
from pfscope.trackers.pipeline import BaseHook, FrameReport, run
from pfscope.trackers.report import StageLog

LANES = ("dbn-phd", "phd-bgsub")

#: the stage clock: wall (perf_counter, default) or this thread's CPU time (``--clock cpu``:
#: on a machine shared with other work, CPU time is what the step would take alone)
CLOCK = time.perf_counter
METRICS = ("OSPA", "ME", "MOTA", "IDF1", "FP", "FN")


class TimedStageLog(StageLog):
    """A stage log that notes the clock (:data:`CLOCK`) at every stage change and at the end."""

    def __init__(self, stages, level, sink: dict):
        super().__init__(stages, level)
        self._sink = sink
        self._t: Optional[float] = None
        self._cur: Optional[str] = None

    def _tick(self, nxt: Optional[str]) -> None:
        now = CLOCK()
        if self._cur is not None and self._t is not None:
            self._sink[self._cur] = self._sink.get(self._cur, 0.0) + now - self._t
        self._cur, self._t = nxt, now

    def stage(self, name: str) -> None:
        self._tick(name)
        super().stage(name)

    def result(self):
        self._tick(None)
        return super().result()


def timed(cls):
    """``cls`` (a DBN-PHD tracker class) whose stages are timed into ``self.stage_seconds``
    (stage → list of seconds, one per frame)."""

    class Timed(cls):
        #: no look-ahead (:meth:`DBNPHDTracker.upcoming`): every stage runs inside the step,
        #: on this thread, so the stage clock sees all of it
        upcoming = None

        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            self.stage_seconds: dict[str, list[float]] = {s: [] for s in self.stages}
            self._frame: dict[str, float] = {}

        def _stage_log(self, level):
            self._frame = {}
            return TimedStageLog(self.stages, level, self._frame)

        def step(self, frame, detections, level=None):
            out = super().step(frame, detections, level)
            for s in self.stages:
                self.stage_seconds[s].append(self._frame.get(s, 0.0))
            return out

    Timed.__name__ = f"Timed{cls.__name__}"
    return Timed


class StepTimes(BaseHook):
    def __init__(self):
        self.seconds: dict[str, list[float]] = {}

    def on_frame(self, report: FrameReport) -> None:
        for lane, s in report.step_seconds.items():
            self.seconds.setdefault(lane, []).append(s)


class _TimedModel:
    """The DBN model with its forward pass timed into ``sink['dbn']`` (everything else passed
    through)."""

    def __init__(self, model, sink: dict):
        self._model, self._sink = model, sink

    def __getattr__(self, name):
        return getattr(self._model, name)

    def logits(self, X):
        t = CLOCK()
        out = self._model.logits(X)
        self._sink["dbn"] = self._sink.get("dbn", 0.0) + CLOCK() - t
        return out


def _timed_call(fn, sink: dict, key: str):
    def call(*a, **kw):
        t = CLOCK()
        out = fn(*a, **kw)
        sink[key] = sink.get(key, 0.0) + CLOCK() - t
        return out
    return call


def make_lane(name: str, seed: int, options: dict):
    cls = DBNPHDTracker if name == "dbn-phd" else PHDBgsubTracker
    params = make_params(name, None, options)
    tr = timed(cls)(params, rng=np.random.default_rng(seed))
    tr.parts = {}                 # seconds over the run: 'scored' (features + DBN), 'dbn'
    if tr.dbn is not None:
        tr.dbn.model = _TimedModel(tr.dbn.model, tr.parts)
        tr.dbn.logits = _timed_call(tr.dbn.logits, tr.parts, "scored")
        tr.dbn.logits_union = _timed_call(tr.dbn.logits_union, tr.parts, "scored")
        # the blobs stage describes its blobs and windows together before scoring them
        tr.dbn.describe_ahead = _timed_call(tr.dbn.describe_ahead, tr.parts, "scored")
    return tr


#: the per-part profile: the tracker's stages regrouped by what costs (issue 22)
FILTER_STAGES = ("predict", "birth", "features", "update", "resample", "cluster")


def parts_ms(lane: dict, stage_ms: dict) -> dict:
    """ms/frame of codebook (background stage), colour/HOG features and DBN forward passes
    (wherever they run), blobs (connected components, person size and split bookkeeping),
    the PHD filter (predict … cluster, minus any particle scoring) and association."""
    feat, dbn = lane["features_ms"], lane["dbn_ms"]
    filt = sum(stage_ms[s] for s in FILTER_STAGES)
    blobs = stage_ms["blobs"]
    # features/DBN run in the blobs stage at level tracks; at level particles also in the
    # features stage: take them out of whichever stage holds them, blobs first
    in_blobs = min(feat + dbn, blobs)
    return {"codebook": stage_ms["background"], "features": feat, "dbn": dbn,
            "blobs": blobs - in_blobs, "filter": filt - (feat + dbn - in_blobs),
            "associate": stage_ms["associate"]}


def whole_process(source: str, tracker: str, level: str, frames: Optional[str]) -> dict:
    """``pfscope record SOURCE --tracker T --level L`` in a fresh process, wall clock: the
    whole process (start-up, model load, frame decoding, tracking, scoring, the recording)."""
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        cmd = [sys.executable, "-m", "pfscope.viewer_app.cli", "record", source, "--tracker",
               tracker, "--level", level, "--out", f"{d}/run.rrd", "--quiet", "--force"]
        if frames:
            cmd += ["--frames", frames]
        import resource

        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return {"command": " ".join(cmd[2:]), "seconds": wall, "cpu_seconds": cpu}


def one_run(spec: str, seed: int, start: int, frames: Optional[int], level: Optional[str],
            options: dict) -> dict:
    src = open_bench_source(spec, frames=frames if spec == "synthetic" else None)
    if spec == "synthetic":
        from pfscope.trackers.data.sources import open_source
        from pfscope.trackers.data.synthetic import SceneConfig

        # the noisy scene of the README's Table I (background-subtraction noise, flicker)
        src = open_source("synthetic", synthetic_config=SceneConfig(
            frames=frames or 100, targets=6, width=320, height=240, seed=seed,
            bg_noise=0.6, flicker=0.04))
    length = getattr(src, "length", None)
    n = frames if frames is not None else (length - start + 1 if length else None)
    dbn_opts = dict(options)
    base_opts = {k: v for k, v in options.items() if k != "model"}
    lanes = {"dbn-phd": make_lane("dbn-phd", seed, dbn_opts),
             "phd-bgsub": make_lane("phd-bgsub", seed, base_opts)}
    hook = StepTimes()
    t0 = time.perf_counter()
    res = run(src, lanes, frames=n, start=start, level=level, hooks=[hook])
    wall = time.perf_counter() - t0
    if not res.outcome.ok:
        raise SystemExit(f"run failed: {res.outcome.reason}")
    out = {"source": getattr(src, "name", spec), "seed": seed, "start": start,
           "frames": res.outcome.frames, "wall_seconds": wall, "lanes": {}}
    for name, tr in lanes.items():
        step = np.asarray(hook.seconds[name])
        nfr = max(1, len(step))
        lane = {"fps": float(1.0 / step.mean()), "ms_per_frame": float(1e3 * step.mean()),
                "stage_ms": {s: float(1e3 * np.mean(v)) for s, v in tr.stage_seconds.items()},
                "dbn_ms": 1e3 * tr.parts.get("dbn", 0.0) / nfr,
                "features_ms": 1e3 * (tr.parts.get("scored", 0.0) - tr.parts.get("dbn", 0.0))
                / nfr}
        lane["parts_ms"] = parts_ms(lane, lane["stage_ms"])
        sc = res.scores.get(name) or {}
        lane.update({k: (float(sc[k]) if k in sc else None) for k in METRICS})
        out["lanes"][name] = lane
    return out


def fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.2f}" if abs(v) < 100 else f"{v:.0f}"
    return str(v)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", default="pets", help="pets | synthetic | PATH (default pets)")
    ap.add_argument("--start", type=int, default=None,
                    help="first frame (default 401 for pets: the DBN trained on 1-400; else 1)")
    ap.add_argument("--frames", type=int, default=None,
                    help="frames to run (default: to the end; synthetic: 100)")
    ap.add_argument("--seeds", default="0", help="comma-separated tracker seeds, one run each")
    ap.add_argument("--model", default="", help="DBN model file (default: the default model)")
    ap.add_argument("--level", default="tracks",
                    help="report level asked of the trackers (default tracks, as record "
                         "--level tracks; 'particles' also scores every gated particle)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="parameter override for both lanes (as pfscope record --set)")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                    help="stage clock: wall (default) or this thread's CPU time (a loaded "
                         "machine's stand-in for a quiet one)")
    ap.add_argument("--whole", action="store_true",
                    help="also time `pfscope record SOURCE --tracker T --level LEVEL` for both "
                         "trackers in fresh processes (whole process, frames/s of wall clock)")
    ap.add_argument("--json", default=None, metavar="FILE", help="write every number to FILE")
    a = ap.parse_args(argv)
    start = a.start if a.start is not None else (401 if a.source == "pets" else 1)
    global CLOCK
    CLOCK = time.thread_time if a.clock == "cpu" else time.perf_counter
    options = dict(s.split("=", 1) for s in a.set)
    if a.model:
        options["model"] = a.model
    info = machine()
    print_machine(info)
    from pfscope.trackers.warmup import compile_kernels

    compile_kernels()     # the filter's numba kernels: compiled or loaded before any lane's frame
    runs = []
    try:
        for seed in (int(s) for s in a.seeds.split(",")):
            print(f"seed {seed}: running dbn-phd and phd-bgsub on {a.source} from frame "
                  f"{start} ...", file=sys.stderr, flush=True)
            runs.append(one_run(a.source, seed, start, a.frames, a.level, options))
    except NoData as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_NO_DATA
    except (InputError, ValueError) as e:               # bad --model / --set: one line
        print(f"error: {e}", file=sys.stderr)
        return 1
    r0 = runs[0]
    stages = list(r0["lanes"]["dbn-phd"]["stage_ms"])
    print(f"\n=== {r0['source']}: frames {start}..{start + r0['frames'] - 1} "
          f"({r0['frames']} frames), seeds {a.seeds}, both lanes in one pipeline run each, "
          f"level {a.level} ===")
    print("\nper-stage ms/frame (mean over the runs):")
    rows = []
    for lane in LANES:
        ms = [np.mean([r["lanes"][lane]["stage_ms"][s] for r in runs]) for s in stages]
        rows.append([lane, *[f"{m:.1f}" for m in ms], f"{sum(ms):.1f}"])
    print(table(["lane", *stages, "sum"], rows))
    cols = ["fps", "ms_per_frame", *METRICS]
    rows = []
    for r in runs:
        for lane in LANES:
            rows.append([f"seed {r['seed']}", lane, *[fmt(r["lanes"][lane][k]) for k in cols]])
    if len(runs) > 1:
        for lane in LANES:
            vals = [[r["lanes"][lane][k] for r in runs] for k in cols]
            rows.append(["mean", lane, *[fmt(float(np.mean(v)) if None not in v else None)
                                         for v in vals]])
    print()
    print(table(["run", "lane", *cols], rows))
    d = [r["lanes"]["dbn-phd"]["ms_per_frame"] / r["lanes"]["phd-bgsub"]["ms_per_frame"]
         for r in runs]
    print(f"\nstep time dbn-phd / phd-bgsub: {np.mean(d):.2f} (same frames, same run)")
    parts = list(r0["lanes"]["dbn-phd"]["parts_ms"])
    rows = []
    for lane in LANES:
        ms = [np.mean([r["lanes"][lane]["parts_ms"][k] for r in runs]) for k in parts]
        tot = sum(ms)
        rows.append([lane, *[f"{m:.1f} ({100 * m / tot:.0f}%)" for m in ms], f"{tot:.1f}"])
    print(f"\nper-part ms/frame ({a.clock} clock; share of the step): codebook = background model, features = "
          "colour/HOG of blobs and windows, dbn = forward passes, blobs = components and "
          "split bookkeeping, filter = predict..cluster")
    print(table(["lane", *parts, "step"], rows))
    whole = {}
    if a.whole:
        src_arg = str(pets_path()) if a.source == "pets" else a.source
        whole_n = r0["frames"]
        span = f"{start}:{start + whole_n - 1}"           # the frames the lanes ran
        for lane in LANES:
            whole[lane] = whole_process(src_arg, lane, a.level, span)
        rows = []
        for lane in LANES:
            sec, cpu = whole[lane]["seconds"], whole[lane]["cpu_seconds"]
            whole[lane]["fps"] = whole_n / sec
            whole[lane]["fps_cpu"] = whole_n / cpu
            rows.append([lane, f"{sec:.1f}", f"{whole_n / sec:.1f}", f"{cpu:.1f}",
                         f"{whole_n / cpu:.1f}", whole[lane]["command"]])
        print(f"\nwhole process (fresh `pfscope record`, {whole_n} frames, load "
              f"{__import__('os').getloadavg()[0]:.1f}):")
        print(table(["tracker", "wall s", "fps", "CPU s", "frames/CPU s", "command"], rows))
        print(f"whole-process time dbn-phd / phd-bgsub: "
              f"{whole['dbn-phd']['seconds'] / whole['phd-bgsub']['seconds']:.2f}")
    write_json(a.json, {"command": command_line(), "machine": info, "runs": runs,
                        "whole_process": whole,
                        "load_at_end": list(__import__("os").getloadavg())})
    return 0


if __name__ == "__main__":
    sys.exit(main())
