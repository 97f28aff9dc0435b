"""Frames per second of each stage of PHD-MT (maggio2007 §2–§4) at the paper's settings.

Settings: the ``phd`` tracker's ``paper`` preset (``PHDTrackerParams()``: the filter's parts at
maggio2007 §4, ρ = 1500 particles/target, J_max = 1000, p_M = 0.05, e = 0.99 ...; ``T = 0.6``
cluster mass threshold, split rule ``"guarded"``; graph depth ``K = 50``, tracks shorter than
5 frames dropped).

Everything runs through the engine's one frame loop, :func:`pfscope.trackers.pipeline.run`, on
the source's public detections (the pipeline's ``file`` detector, as ``pfscope record`` picks
for a MOT folder).  One run per repeat has three lanes, stepped one after the other on every
frame:

- ``stages``: :class:`StageTimedPHDTracker`, a :class:`~trackers.phd.tracker.PHDTracker`
  whose ``step`` runs with ``bench.py``'s stage clocks installed (:func:`_common.phd_clocks`:
  each of the filter's stage functions ``predict`` → ``birth`` → ``update`` (from the end of
  birth: the gated likelihood and eq. (5)) → ``resample``, then ``cluster``
  (:func:`~trackers.phd.clustering.kmeans_peaks`) and ``associate``
  (:meth:`~trackers.phd.association.GraphAssociator.step`) between two
  ``time.perf_counter()`` calls); the stage data and the step result are built outside the
  clocks;
- ``mt``: the MT baseline (:class:`~trackers.phd.tracker.MTTracker`: the same association on
  the raw detections), timed by the pipeline (``FrameReport.step_seconds``);
- ``phd``: the plain ``PHDTracker``, timed by the pipeline.  A hook checks every frame that
  the ``stages`` lane holds exactly the same particles and reports the same tracks as it.

The pipeline runs at ``level=None`` (no stage items, only scalars and events), as an unrecorded
run does.  For context, the image detectors (``hog``, ``bgsub``, and the ``file`` replay) are
timed on the first ``--det-frames`` frames of the source, again through the pipeline: each is
a :class:`DetectorLane` (a stand-in tracker whose step runs the detector on the frame the
pipeline read), so the tracker:detector split can be set beside maggio2007 §4 (PHD filter 34 %
of the time, detector 64 %).

The same seed gives identical work in every repeat, so the per-frame time of a stage is the
median over ``--repeat`` runs (robust to the noise of a shared machine); a stage's time for
the sequence is the sum of those medians.

Usage::

    .venv/bin/python benchmarks/bench_phd_stages.py                     # PETS (if found) + synthetic
    .venv/bin/python benchmarks/bench_phd_stages.py --source pets --frames 200 --repeat 5
    .venv/bin/python benchmarks/bench_phd_stages.py --source synthetic --json out/phd.json
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Optional

import _common as C  # noqa: E402  (also puts the repository root on sys.path)
import numpy as np

from pfscope.trackers.api import Rows, StepResult, make_params, make_tracker, params_config
from pfscope.trackers.errors import InputError
from pfscope.trackers.phd.tracker import PHDTracker
from pfscope.trackers.pipeline import BaseHook, FrameReport, RunInfo
from pfscope.trackers.pipeline import run as run_pipeline
from pfscope.trackers.types import Detections, Frame, TrackSet

STAGES = ("predict", "birth", "update", "resample", "cluster", "associate")
FILTER_STAGES = STAGES[:4]
WARMUP_FRAMES = 10
LANE_STAGES, LANE_MT, LANE_PHD = "stages", "mt", "phd"


# ----------------------------------------------------------------------------- timing wrappers

PRESET = "paper"   # explicit: the registry's first preset need not be the paper's

class StageTimedPHDTracker(PHDTracker):
    """PHD-MT whose ``step`` times each stage.

    It runs ``PHDTracker.step`` itself, with the clocks of ``bench.py`` (:func:`_common.phd_clocks`:
    the filter's stage functions, ``kmeans_peaks`` and ``GraphAssociator.step`` wrapped in two
    ``time.perf_counter()`` calls) installed for this lane's step only, so the particles, tracks
    and rows are those of ``PHDTracker`` (checked frame by frame by :class:`ReplicationCheck`)
    whatever the step's body becomes.  ``times`` holds one row of six seconds per step,
    ``counts`` the particle counts (after resampling, in the update, newborn) and kept
    clusters."""

    def __init__(self, params=None, *, rng: np.random.Generator):
        super().__init__(params, rng=rng)
        self._clock = C.Clock()
        self.times: list[tuple[float, ...]] = []
        self.counts: list[tuple[int, int, int, int]] = []

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult:
        n_prev = len(self.filter.particles)
        with C.phd_clocks(self._clock):
            result = super().step(frame, detections, level)
        clock = self._clock
        st = clock.take()
        self.times.append(tuple(st.get(s, 0.0) for s in STAGES))
        kept = 0 if clock.clusters is None else int(clock.clusters.kept.sum())
        self.counts.append((len(self.filter.particles), n_prev + clock.births, clock.births,
                            kept))
        return result


class DetectorLane:
    """A stand-in tracker whose step runs one image detector on the frame the pipeline read, so
    the pipeline's ``step_seconds`` of the lane is the detector's time.  Reports no tracks."""

    paper = "-"
    stages = ("detect",)
    needs_detections = False
    needs_image = True

    def __init__(self, name: str, detector):
        self.name = name
        self.detector = detector
        self.boxes = 0

    def step(self, frame: Frame, detections: Optional[Detections],
             level: Optional[str] = None) -> StepResult:
        self.boxes += len(self.detector(frame))
        return StepResult(TrackSet.empty())

    def finish(self) -> Rows:
        return []

    def config(self) -> dict:
        return {"tracker": f"detector:{self.name}"}


# ----------------------------------------------------------------------------- hooks

class StepTimes(BaseHook):
    """Per-frame ``step_seconds`` of every lane."""

    def begin(self, info: RunInfo) -> None:
        self.seconds: dict[str, list[float]] = {lane: [] for lane in info.trackers}

    def on_frame(self, report: FrameReport) -> None:
        for lane, s in report.step_seconds.items():
            self.seconds[lane].append(s)


class ReplicationCheck(BaseHook):
    """After every frame: do lanes ``a`` and ``b`` hold identical particles and report identical
    tracks?  ``mismatch`` is the first frame where they differ (None: never)."""

    def __init__(self, a: str, b: str):
        self.a, self.b = a, b
        self.mismatch: Optional[int] = None

    def begin(self, info: RunInfo) -> None:
        self.ta, self.tb = info.trackers[self.a], info.trackers[self.b]

    def on_frame(self, report: FrameReport) -> None:
        if self.mismatch is not None:
            return
        pa, pb = self.ta.filter.particles, self.tb.filter.particles
        ra, rb = report.results[self.a].tracks, report.results[self.b].tracks
        same = (np.array_equal(pa.states, pb.states)
                and np.array_equal(pa.log_weights, pb.log_weights)
                and np.array_equal(ra.ids, rb.ids) and np.array_equal(ra.boxes, rb.boxes))
        if not same:
            self.mismatch = report.frame.index


# ----------------------------------------------------------------------------- one run each

def run_trackers(source, frames: int, seed: int):
    """One pipeline run with the three lanes; returns (stage times (F, 6), counts dict of (F,)
    arrays, per-lane step seconds dict of (F,) arrays, replication mismatch frame or None)."""
    params = make_params("phd", PRESET)
    timed = StageTimedPHDTracker(params, rng=np.random.default_rng(seed))
    lanes = {LANE_STAGES: timed, LANE_MT: make_tracker("mt", seed, preset=PRESET),
             LANE_PHD: make_tracker("phd", seed, preset=PRESET)}
    steps, check = StepTimes(), ReplicationCheck(LANE_STAGES, LANE_PHD)
    res = run_pipeline(source, lanes, frames=frames, level=None, hooks=[steps, check],
                       keep_rows=False, score=False)
    if res.frames != frames or res.outcome.status != "completed":
        raise SystemExit(f"pipeline stopped: {res.outcome.reason}")
    c = np.array(timed.counts, dtype=np.int64).reshape(-1, 4)
    counts = dict(resampled=c[:, 0], updated=c[:, 1], born=c[:, 2], kept=c[:, 3])
    secs = {lane: np.array(v) for lane, v in steps.seconds.items()}
    return np.array(timed.times).reshape(-1, len(STAGES)), counts, secs, check.mismatch


def time_detectors(source, n: int, names=("hog", "bgsub", "file")) -> dict:
    """Median (and mean) seconds per frame of each detector on the first ``n`` frames, each a
    :class:`DetectorLane` of one pipeline run (the pipeline reads the image before the lanes
    step; ``bgsub`` sees the frames in order, as it must)."""
    from pfscope.trackers.detect import make_detector

    lanes = {}
    for name in names:
        if name == "file" and source.det is None:
            continue
        try:
            lanes[name] = DetectorLane(name, make_detector(name, det_table=source.det))
        except InputError as e:
            print(f"note: detector {name} skipped: {e}", file=sys.stderr)
    if not lanes:
        return {}
    steps = StepTimes()
    res = run_pipeline(source, lanes, frames=n, level=None, hooks=[steps], keep_rows=False,
                       score=False)
    out = {}
    for name, lane in lanes.items():
        t = steps.seconds[name]
        out[name] = {"frames": res.frames, "median_s": C.median(t), "mean_s": float(np.mean(t)),
                     "boxes_per_frame": lane.boxes / max(res.frames, 1)}
    return out


# ----------------------------------------------------------------------------- one source

def bench_source(spec: str, args) -> dict:
    source = C.open_bench_source(spec, args.frames)
    if source.det is None:
        raise SystemExit(f"{source.location}: no public detections (det/det.txt); this benchmark "
                         f"runs PHD-MT on a source's detections")
    F = C.n_frames(source, args.frames)
    n_det = np.array([len(source.det.detections(k)) for k in range(1, F + 1)])
    params = make_params("phd", PRESET)
    print(f"\n=== {source.name}: {F} frames, {n_det.mean():.1f} detections/frame "
          f"(max {n_det.max()}), {args.repeat} repeats, seed {args.seed} ===")

    # warm-up (first calls: imports, lru caches, allocator), not measured
    run_trackers(source, min(WARMUP_FRAMES, F), args.seed)

    st, mt, phd, timed_step = [], [], [], []
    counts, mismatch = None, None
    t_start = time.perf_counter()
    for r in range(args.repeat):  # the lanes step in turn on every frame: load hits them alike
        times, counts, secs, mm = run_trackers(source, F, args.seed)
        st.append(times)
        mt.append(secs[LANE_MT])
        phd.append(secs[LANE_PHD])
        timed_step.append(secs[LANE_STAGES])
        mismatch = mismatch if mismatch is not None else mm
        print(f"  repeat {r + 1}/{args.repeat} done ({time.perf_counter() - t_start:.1f} s)",
              file=sys.stderr)
    same = mismatch is None

    st_med = np.median(np.stack(st), axis=0)       # (F, 6) per-frame medians over repeats
    mt_med = np.median(np.stack(mt), axis=0)
    phd_med = np.median(np.stack(phd), axis=0)
    timed_med = np.median(np.stack(timed_step), axis=0)
    stage_total = st_med.sum(axis=0)                # seconds for the sequence, per stage
    all_total = float(stage_total.sum())

    stages = {}
    for j, name in enumerate(STAGES):
        stages[name] = {"seconds": float(stage_total[j]), "ms_per_frame": 1e3 * stage_total[j] / F,
                        "median_ms": 1e3 * float(np.median(st_med[:, j])),
                        "fps": C.fps(stage_total[j], F), "share": stage_total[j] / all_total}
    filt_s = float(stage_total[:4].sum())
    per_frame = {
        "PHD filter (predict..resample)": st_med[:, :4].sum(1),
        "stages total (6 stages)": st_med.sum(1),
        "MT tracker (association on detections)": mt_med,
        "PHD-MT tracker (pipeline step)": phd_med,
        "PHD-MT stage-timed step (pipeline)": timed_med,
    }
    groups = {name: float(v.sum()) for name, v in per_frame.items()}
    rows = [(name, f"{s['ms_per_frame']:.3f}", f"{s['median_ms']:.3f}", f"{s['fps']:.0f}",
             f"{100 * s['share']:.1f}%") for name, s in stages.items()]
    for name, secs in groups.items():
        share = f"{100 * secs / all_total:.1f}%" if name.startswith("PHD filter") else ""
        rows.append((name, f"{1e3 * secs / F:.3f}", f"{1e3 * float(np.median(per_frame[name])):.3f}",
                     f"{C.fps(secs, F):.0f}", share))
    print(C.table(["stage", "ms/frame", "median ms", "fps", "share"], rows))
    print("(ms/frame = sum over frames of the per-frame median over repeats / frames; "
          "fps = frames / that sum; share = of the 6 stages; tracker rows = the pipeline's "
          "step_seconds of the lane)")
    pc = counts
    print(f"particles: mean L_k after resampling {pc['resampled'].mean():.0f} "
          f"(max {pc['resampled'].max()}), mean in update L_(k-1)+J_k {pc['updated'].mean():.0f}, "
          f"mean newborn J_k {pc['born'].mean():.0f}; kept clusters/frame {pc['kept'].mean():.2f}")
    phd_s, mt_s = groups["PHD-MT tracker (pipeline step)"], groups["MT tracker (association on detections)"]
    print(f"stage-timed lane holds the same particles and tracks as PHDTracker every frame: "
          f"{'yes' if same else f'NO (first difference at frame {mismatch})'}; "
          f"PHDTracker / sum of stages = {phd_s / all_total:.3f}; PHD-MT / MT = {phd_s / mt_s:.1f}x")

    result = {"source": source.describe(), "frames": F, "repeats": args.repeat, "seed": args.seed,
              "settings": {"phd": params_config(params), "preset": PRESET,
                           "T": params.clusters.T, "split_rule": params.clusters.split_rule,
                           "level": None},
              "detections_per_frame": float(n_det.mean()),
              "stages": stages,
              "groups_seconds": groups,
              "groups_fps": {k: C.fps(v, F) for k, v in groups.items()},
              "particles": {"resampled_mean": float(pc["resampled"].mean()),
                            "resampled_max": int(pc["resampled"].max()),
                            "updated_mean": float(pc["updated"].mean()),
                            "born_mean": float(pc["born"].mean()),
                            "kept_clusters_mean": float(pc["kept"].mean())},
              "replication_matches_tracker": same, "replication_first_mismatch": mismatch}

    if args.det_frames > 0:
        dt = time_detectors(source, min(args.det_frames, F))
        result["detectors"] = dt
        trk_s = phd_s / F
        filt_pf = filt_s / F
        rest_pf = float(stage_total[4:].sum()) / F
        print(f"\ndetectors on frames 1..{min(args.det_frames, F)} "
              f"({source.width}x{source.height}; each a pipeline lane, image read before it steps):")
        rows = []
        for name, d in dt.items():
            tot = d["median_s"] + filt_pf + rest_pf
            d["pipeline"] = {"detector_share": d["median_s"] / tot, "phd_filter_share": filt_pf / tot,
                             "cluster_assoc_share": rest_pf / tot,
                             "tracker_to_detector": trk_s / d["median_s"]}
            rows.append((name, f"{1e3 * d['median_s']:.3g}", f"{C.fps(d['median_s']):.4g}",
                         f"{d['boxes_per_frame']:.1f}",
                         f"{100 * d['pipeline']['detector_share']:.1f}%",
                         f"{100 * d['pipeline']['phd_filter_share']:.1f}%",
                         f"{100 * d['pipeline']['cluster_assoc_share']:.1f}%",
                         f"{d['pipeline']['tracker_to_detector']:.3g}"))
        print(C.table(["detector", "median ms", "fps", "boxes/frame", "detector %",
                       "PHD filter %", "cluster+assoc %", "PHD-MT : det"], rows))
        print("(shares of detector + PHD-MT per frame; maggio2007 §4 reports detector 64 %, "
              "PHD filter 34 %)")
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", action="append", metavar="pets|synthetic|PATH",
                    help="sequence to run on (repeatable); default: pets (if found) and synthetic")
    ap.add_argument("--frames", type=int, default=None,
                    help="frames to use (default: all; 795 for PETS, 150 for the synthetic scene, "
                         "which is generated with this many frames)")
    ap.add_argument("--repeat", type=int, default=5,
                    help="runs over the sequence; per-frame times are medians over them (default 5)")
    ap.add_argument("--det-frames", type=int, default=30,
                    help="frames to time the detectors on (default 30, 0 to skip)")
    ap.add_argument("--seed", type=int, default=0, help="tracker seed (default 0)")
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = ap.parse_args(argv)
    if args.repeat < 1 or (args.frames is not None and args.frames < 1):
        ap.error("--repeat and --frames must be >= 1")

    info = C.machine()
    C.print_machine(info)
    p = make_params("phd", PRESET)
    print(f"PHD-MT at maggio2007 §4 settings (tracker 'phd', preset 'paper'): "
          f"rho={p.filter.resampling.rho:g}, J_max={p.filter.birth.j_max}, "
          f"p_M={p.filter.likelihood.p_miss:g}, T={p.clusters.T:g}, K={p.assoc.depth}, "
          f"split rule {p.clusters.split_rule!r}; run through pfscope.trackers.pipeline.run "
          f"(level None, file detector)")
    results = {}
    try:
        for spec in C.resolve_sources(args.source):
            results[spec] = bench_source(spec, args)
    except C.NoData as e:
        print(f"error: {e}", file=sys.stderr)
        return C.EXIT_NO_DATA
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return C.EXIT_NO_DATA
    C.write_json(args.json, {"benchmark": "phd_stages", "command": C.command_line(),
                             "machine": info, "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
