"""Frames per second of each stage of PHD-MT (maggio2007 §2–§4) at the paper's settings.

Settings: ``PHDParams()`` defaults (maggio2007 §4: ρ = 1500 particles/target, J_max = 1000,
p_M = 0.05, e = 0.99 ...), ``T = 0.6`` (cluster mass threshold) and ``AssocParams()`` defaults
(graph depth ``K = 50``, tracks shorter than 5 frames dropped), split rule ``"guarded"``
(the :class:`~trackers.phd.tracker.PHDTracker` default).

What is timed, per frame, on the source's public detections (``.det``):

- the six stages of PHD-MT, calling the stage functions in the order of
  :meth:`trackers.phd.filter.PHDFilter.step` and :meth:`trackers.phd.tracker.PHDTracker.step`,
  each between two ``time.perf_counter()`` calls:
  ``predict`` → ``birth`` → ``update`` (including the concatenation of persistent and newborn
  particles, as in ``PHDFilter.step``) → ``resample`` → ``cluster``
  (:func:`~trackers.phd.clustering.kmeans_peaks`) → ``associate``
  (:meth:`~trackers.phd.association.GraphAssociator.step` on the kept centres);
- the MT baseline (:class:`~trackers.phd.tracker.MTTracker`: the same association on the raw
  detections) and the whole :class:`PHDTracker` with a :class:`NullObserver`;
- for context, the image detectors (``hog``, ``bgsub``, and the ``file`` replay) on the first
  ``--det-frames`` frames of the source, so the tracker:detector split can be set beside
  maggio2007 §4 (PHD filter 34 % of the time, detector 64 %).

The same seed gives identical work in every repeat, so the per-frame time of a stage is the
median over ``--repeat`` runs (robust to the noise of a shared machine); a stage's time for
the sequence is the sum of those medians.  The script checks that its stage-by-stage
replication draws the same particles as ``PHDTracker`` (same particle count every frame).

Usage::

    .venv/bin/python benchmarks/bench_phd_stages.py                     # PETS (if found) + synthetic
    .venv/bin/python benchmarks/bench_phd_stages.py --source pets --frames 200 --repeat 5
    .venv/bin/python benchmarks/bench_phd_stages.py --source synthetic --json out/phd.json
"""

from __future__ import annotations

import argparse
import sys
import time

import _common as C  # noqa: E402  (also puts the repository root on sys.path)
import numpy as np

from pfscope.trackers.errors import InputError
from pfscope.trackers.observer import NullObserver
from pfscope.trackers.phd.association import AssocParams, GraphAssociator
from pfscope.trackers.phd.clustering import kmeans_peaks
from pfscope.trackers.phd.filter import (STATE_DIM, PHDParams, as_observations, birth, predict,
                                 resample, update)
from pfscope.trackers.phd.tracker import MTTracker, PHDTracker
from pfscope.trackers.smc.weights import ParticleSet
from pfscope.trackers.types import Frame

STAGES = ("predict", "birth", "update", "resample", "cluster", "associate")
FILTER_STAGES = STAGES[:4]
T_DEFAULT = 0.6          # maggio2007 §4
SPLIT_RULE = "guarded"   # PHDTracker default
WARMUP_FRAMES = 10


# ----------------------------------------------------------------------------- one run each

def run_stages(dets, params: PHDParams, T: float, seed: int):
    """PHDFilter.step + kmeans_peaks + GraphAssociator.step, stage by stage.

    Returns (times (F, 6) seconds, counts dict of (F,) arrays)."""
    rng = np.random.default_rng(seed)
    assoc = GraphAssociator(AssocParams())
    particles = ParticleSet.empty(STATE_DIM)
    F = len(dets)
    times = np.zeros((F, len(STAGES)))
    n_resampled = np.zeros(F, np.int64)
    n_updated = np.zeros(F, np.int64)
    n_born = np.zeros(F, np.int64)
    n_kept = np.zeros(F, np.int64)
    pc = time.perf_counter
    for i, d in enumerate(dets):
        Z = as_observations(d)  # input conversion, outside the stages (negligible)
        t0 = pc()
        predicted = predict(particles, params, rng)
        t1 = pc()
        born = birth(predicted, Z, params, rng)
        t2 = pc()
        updated = update(predicted.concat(born.particles), Z, params)
        t3 = pc()
        resampled = resample(updated.particles, params, rng)
        t4 = pc()
        clusters = kmeans_peaks(resampled, Z, T, params=params, split_rule=SPLIT_RULE)
        t5 = pc()
        assoc.step(i + 1, clusters.kept_centers)
        t6 = pc()
        particles = resampled
        times[i] = (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4, t6 - t5)
        n_resampled[i] = len(resampled)
        n_updated[i] = len(updated.particles)
        n_born[i] = len(born.particles)
        n_kept[i] = int(clusters.kept.sum())
    return times, dict(resampled=n_resampled, updated=n_updated, born=n_born, kept=n_kept)


def run_tracker(tracker, frames, dets):
    """Per-frame wall time of ``tracker.step(frame, dets, NullObserver())``; also the particle
    count after each step when the tracker has a PHD filter."""
    obs = NullObserver()
    times = np.zeros(len(frames))
    counts = np.zeros(len(frames), np.int64)
    filt = getattr(tracker, "filter", None)
    pc = time.perf_counter
    for i, (f, d) in enumerate(zip(frames, dets)):
        t0 = pc()
        tracker.step(f, d, obs)
        times[i] = pc() - t0
        if filt is not None:
            counts[i] = len(filt.particles)
    return times, counts


def time_detectors(source, n: int, names=("hog", "bgsub", "file")) -> dict:
    """Median (and mean) seconds per frame of each detector on the first ``n`` frames (images
    read before timing; ``bgsub`` sees the frames in order, as it must)."""
    from pfscope.trackers.detect import make_detector

    frames = list(source.frames(n))
    out = {}
    for name in names:
        if name == "file" and source.det is None:
            continue
        try:
            det = make_detector(name, det_table=source.det)
        except InputError as e:
            print(f"note: detector {name} skipped: {e}", file=sys.stderr)
            continue
        t = []
        n_boxes = 0
        for f in frames:
            t0 = time.perf_counter()
            r = det(f)
            t.append(time.perf_counter() - t0)
            n_boxes += len(r)
        out[name] = {"frames": len(frames), "median_s": C.median(t), "mean_s": float(np.mean(t)),
                     "boxes_per_frame": n_boxes / max(len(frames), 1)}
    return out


# ----------------------------------------------------------------------------- one source

def bench_source(spec: str, args) -> dict:
    source = C.open_bench_source(spec, args.frames)
    if source.det is None:
        raise SystemExit(f"{source.location}: no public detections (det/det.txt); this benchmark "
                         f"runs PHD-MT on a source's detections")
    F = C.n_frames(source, args.frames)
    dets = [source.det.detections(k) for k in range(1, F + 1)]
    dummy = np.zeros((1, 1, 3), np.uint8)  # the trackers never look at the pixels
    frames = [Frame(k, (k - 1) / source.fps, dummy) for k in range(1, F + 1)]
    params = PHDParams()
    T = T_DEFAULT
    n_det = np.array([len(d) for d in dets])
    print(f"\n=== {source.name}: {F} frames, {n_det.mean():.1f} detections/frame "
          f"(max {n_det.max()}), {args.repeat} repeats, seed {args.seed} ===")

    # warm-up (first calls: imports, lru caches, allocator), not measured
    w = min(WARMUP_FRAMES, F)
    run_stages(dets[:w], params, T, args.seed)
    run_tracker(PHDTracker(np.random.default_rng(args.seed), T=T), frames[:w], dets[:w])
    run_tracker(MTTracker(), frames[:w], dets[:w])

    st, mt, phd = [], [], []
    counts = tracker_counts = None
    t_start = time.perf_counter()
    for r in range(args.repeat):  # interleaved so a load change hits all three alike
        times, counts = run_stages(dets, params, T, args.seed)
        st.append(times)
        mt.append(run_tracker(MTTracker(), frames, dets)[0])
        t_phd, tracker_counts = run_tracker(PHDTracker(np.random.default_rng(args.seed), T=T),
                                            frames, dets)
        phd.append(t_phd)
        print(f"  repeat {r + 1}/{args.repeat} done ({time.perf_counter() - t_start:.1f} s)",
              file=sys.stderr)
    same = bool(np.array_equal(counts["resampled"], tracker_counts))

    st_med = np.median(np.stack(st), axis=0)       # (F, 6) per-frame medians over repeats
    mt_med = np.median(np.stack(mt), axis=0)
    phd_med = np.median(np.stack(phd), axis=0)
    stage_total = st_med.sum(axis=0)                # seconds for the sequence, per stage
    all_total = float(stage_total.sum())

    stages = {}
    for j, name in enumerate(STAGES):
        stages[name] = {"seconds": float(stage_total[j]), "ms_per_frame": 1e3 * stage_total[j] / F,
                        "median_ms": 1e3 * float(np.median(st_med[:, j])),
                        "fps": C.fps(stage_total[j], F), "share": stage_total[j] / all_total}
    filt_s = float(stage_total[:4].sum())
    groups = {
        "PHD filter (predict..resample)": filt_s,
        "stages total (6 stages)": all_total,
        "MT tracker (association on detections)": float(mt_med.sum()),
        "PHD-MT tracker, NullObserver": float(phd_med.sum()),
    }
    rows = [(name, f"{s['ms_per_frame']:.3f}", f"{s['median_ms']:.3f}", f"{s['fps']:.0f}",
             f"{100 * s['share']:.1f}%") for name, s in stages.items()]
    for name, secs in groups.items():
        per = {"PHD filter (predict..resample)": st_med[:, :4].sum(1),
               "stages total (6 stages)": st_med.sum(1),
               "MT tracker (association on detections)": mt_med,
               "PHD-MT tracker, NullObserver": phd_med}[name]
        share = f"{100 * secs / all_total:.1f}%" if name.startswith("PHD filter") else ""
        rows.append((name, f"{1e3 * secs / F:.3f}", f"{1e3 * float(np.median(per)):.3f}",
                     f"{C.fps(secs, F):.0f}", share))
    print(C.table(["stage", "ms/frame", "median ms", "fps", "share"], rows))
    print("(ms/frame = sum over frames of the per-frame median over repeats / frames; "
          "fps = frames / that sum; share = of the 6 stages)")
    pc = counts
    print(f"particles: mean L_k after resampling {pc['resampled'].mean():.0f} "
          f"(max {pc['resampled'].max()}), mean in update L_(k-1)+J_k {pc['updated'].mean():.0f}, "
          f"mean newborn J_k {pc['born'].mean():.0f}; kept clusters/frame {pc['kept'].mean():.2f}")
    print(f"stage replication draws the same particles as PHDTracker: {'yes' if same else 'NO'}; "
          f"PHDTracker / sum of stages = {groups['PHD-MT tracker, NullObserver'] / all_total:.3f}; "
          f"PHD-MT / MT = {groups['PHD-MT tracker, NullObserver'] / groups['MT tracker (association on detections)']:.1f}x")

    result = {"source": source.describe(), "frames": F, "repeats": args.repeat, "seed": args.seed,
              "settings": {"phd": vars_of(params), "assoc": vars_of(AssocParams()), "T": T,
                           "split_rule": SPLIT_RULE},
              "detections_per_frame": float(n_det.mean()),
              "stages": stages,
              "groups_seconds": groups,
              "groups_fps": {k: C.fps(v, F) for k, v in groups.items()},
              "particles": {"resampled_mean": float(pc["resampled"].mean()),
                            "resampled_max": int(pc["resampled"].max()),
                            "updated_mean": float(pc["updated"].mean()),
                            "born_mean": float(pc["born"].mean()),
                            "kept_clusters_mean": float(pc["kept"].mean())},
              "replication_matches_tracker": same}

    if args.det_frames > 0:
        dt = time_detectors(source, min(args.det_frames, F))
        result["detectors"] = dt
        trk_s = groups["PHD-MT tracker, NullObserver"] / F
        filt_pf = filt_s / F
        rest_pf = float(stage_total[4:].sum()) / F
        print(f"\ndetectors on frames 1..{min(args.det_frames, F)} "
              f"({source.width}x{source.height}; images decoded before timing):")
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


def vars_of(dc) -> dict:
    from dataclasses import asdict

    return asdict(dc)


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
    print(f"PHD-MT at maggio2007 §4 settings: PHDParams() defaults, T={T_DEFAULT}, "
          f"K={AssocParams().depth}, split rule {SPLIT_RULE!r}")
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
