"""PHD-MT under clutter storms and with many simultaneous targets: frames/s, per-stage ms/frame,
K-means work (Lloyd iterations, split attempts), peak memory and finiteness of the weights.

Issue 13 item 5 (bounded cost under clutter storms) and issue 12 (cost linear in targets).
Every run goes through the engine's one frame loop, :func:`pfscope.trackers.pipeline.run`, at
``level=None`` (no stage items, as an unrecorded run), on a detections-only synthetic source
(no pixels are rendered: PHD-MT reads detections only, the ``file`` detector replays them).

Scenes (:func:`storm_scene`, seeded): ``targets`` boxes (w 24–48 px, h = 2–3 w) moving on
straight lines at 0.5–2 px/frame, each detected with probability 0.95 with Gaussian noise of
5% of its size, plus uniform clutter boxes of person-like sizes anywhere in the image so that
every frame holds exactly ``detections`` boxes (when ``detections`` >= the targets detected).
The image is 640 x 480 for 4 targets and grows with sqrt(targets / 4) per side, so the target
density (and each target's neighbourhood) stays the same as the number of targets grows.

Lanes: ``storm`` runs 4 targets with 20 / 200 / 2,000 detections per frame (``--storm``);
``scale`` runs 4 / 16 / 64 / 256 targets with ``targets + 4`` detections per frame
(``--targets``).  Per-stage times come from timing wrappers around the functions
``PHDFilter.step`` and ``PHDTracker.step`` call (``predict``, ``birth``, ``update`` — which
consumes the gated likelihood generator, so gating is in it —, ``resample``, ``kmeans_peaks``,
``GraphAssociator.step``), installed for the duration of the run: the tracker's code path is
unchanged.  Each configuration is run ``--repeat`` times with the same seed (identical work);
a frame's time is the median over the repeats.  Configurations run in increasing size in one
process, so ``peak_rss_mb`` (``ru_maxrss`` after a configuration) is the process peak up to
and including it, interpreter and libraries included.  Ratios (fps of 200 vs 20 detections,
time vs targets) are from the same process, interleaved per repeat.

Usage::

    .venv/bin/python benchmarks/bench_storm.py                       # storm + scale, 50 frames
    .venv/bin/python benchmarks/bench_storm.py --frames 20 --repeat 1 --json out/storm.json
    .venv/bin/python benchmarks/bench_storm.py --storm 20,200 --targets 4,16 --frames 30
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import _common as C  # noqa: E402  (also puts the repository root on sys.path)
import numpy as np

from pfscope.trackers.api import make_params, make_tracker, params_config
from pfscope.trackers.data.motio import MotTable
from pfscope.trackers.pipeline import BaseHook, FrameReport
from pfscope.trackers.pipeline import run as run_pipeline

STAGES = ("predict", "birth", "update", "resample", "cluster", "associate")
WARMUP_FRAMES = 3


# ----------------------------------------------------------------------------- the scene

def storm_scene(targets: int, detections: int, frames: int, seed: int = 0):
    """The seeded scene of the module docstring, as a detections-only source."""
    rng = np.random.default_rng([seed, targets, detections])
    side = math.sqrt(max(targets, 4) / 4.0)
    W, H = 640.0 * side, 480.0 * side
    w = rng.uniform(24, 48, targets)
    h = w * rng.uniform(2, 3, targets)
    x0 = np.c_[rng.uniform(0.1 * W, 0.9 * W, targets), rng.uniform(0.15 * H, 0.85 * H, targets)]
    ang = rng.uniform(0, 2 * math.pi, targets)
    v = rng.uniform(0.5, 2.0, targets)[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    fr, ids, boxes = [], [], []
    for k in range(1, frames + 1):
        c = x0 + (k - 1) * v
        det = rng.random(targets) < 0.95
        n_det = int(det.sum())
        noise = rng.standard_normal((n_det, 4)) * 0.05 * np.c_[w[det], h[det], w[det], h[det]]
        bw, bh = w[det] + noise[:, 2], h[det] + noise[:, 3]
        tb = np.c_[c[det, 0] + noise[:, 0] - bw / 2, c[det, 1] + noise[:, 1] - bh / 2, bw, bh]
        n_cl = max(0, detections - n_det)
        cw = rng.uniform(15, 60, n_cl)
        ch = cw * rng.uniform(2, 3, n_cl)
        cb = np.c_[rng.uniform(0, W, n_cl) - cw / 2, rng.uniform(0, H, n_cl) - ch / 2, cw, ch]
        b = np.vstack([tb, cb])
        b[:, 2:4] = np.maximum(b[:, 2:4], 2.0)
        fr.append(np.full(len(b), k))
        ids.append(np.full(len(b), -1))
        boxes.append(b)
    fr, ids, boxes = np.concatenate(fr), np.concatenate(ids), np.vstack(boxes)
    n = len(fr)
    det_table = MotTable(frame=fr.astype(np.int64), id=ids.astype(np.int64),
                         boxes=boxes, score=np.ones(n), cls=np.ones(n), vis=np.ones(n))
    return C._frame_class()(name=f"storm-t{targets}-d{detections}", fps=25.0, length=frames,
                         width=int(W), height=int(H), det=det_table, kind="synthetic",
                         location="built-in")


class Collect(BaseHook):
    """Per frame: step seconds, stage seconds, counts, finiteness of every weight."""

    def __init__(self, clock: C.Clock, lane: str):
        self.clock, self.lane = clock, lane
        self.step, self.stages, self.counts = [], [], []
        self.finite = True

    def begin(self, info):
        self.tracker = info.trackers[self.lane]

    def on_frame(self, report: FrameReport) -> None:
        ps = self.tracker.filter.particles
        self.finite &= bool(np.all(np.isfinite(ps.log_weights)) and np.all(np.isfinite(ps.states)))
        self.step.append(report.step_seconds[self.lane])
        now = self.clock.take()
        self.stages.append([now.get(s, 0.0) for s in STAGES])
        c = self.clock.clusters
        it, sp = (int(c.n_iter), int(c.n_splits)) if c is not None else (0, 0)
        self.counts.append((len(ps), self.clock.births, it, sp,
                            len(report.detections) if report.detections is not None else 0))


def run_once(targets: int, detections: int, frames: int, seed: int, options: dict) -> dict:
    source = storm_scene(targets, detections, frames, seed)
    tracker = make_tracker("phd", seed, preset="paper", **options)
    clock = C.Clock()
    hook = Collect(clock, "phd")
    with C.phd_clocks(clock):
        res = run_pipeline(source, {"phd": tracker}, frames=frames, level=None, hooks=[hook],
                           keep_rows=False, score=False)
    if res.outcome.status != "completed":
        raise SystemExit(f"pipeline stopped: {res.outcome.reason}")
    return {"step": np.array(hook.step), "stages": np.array(hook.stages).reshape(-1, len(STAGES)),
            "counts": np.array(hook.counts, dtype=np.int64).reshape(-1, 5),
            "finite": hook.finite}


def summarise(runs: list[dict], frames: int) -> dict:
    step = np.median(np.stack([r["step"] for r in runs]), axis=0)
    st = np.median(np.stack([r["stages"] for r in runs]), axis=0)
    c = runs[0]["counts"]
    total = float(step.sum())
    return {"frames": frames, "fps": C.fps(total, frames), "ms_per_frame": 1e3 * total / frames,
            "max_ms_per_frame": 1e3 * float(step.max()),
            "stages_ms": {s: 1e3 * float(st[:, j].sum()) / frames for j, s in enumerate(STAGES)},
            "particles_mean": float(c[:, 0].mean()), "particles_max": int(c[:, 0].max()),
            "births_max": int(c[:, 1].max()),
            "kmeans_iter_mean": float(c[:, 2].mean()), "kmeans_iter_max": int(c[:, 2].max()),
            "kmeans_splits_max": int(c[:, 3].max()),
            "detections_mean": float(c[:, 4].mean()),
            "finite": all(r["finite"] for r in runs)}


def bench(configs: list[tuple[str, int, int]], frames: int, repeat: int, seed: int,
          options: dict) -> dict:
    """Run every (lane, targets, detections) ``repeat`` times, interleaved, smallest first."""
    for _, t, d in configs[:1]:
        run_once(t, d, WARMUP_FRAMES, seed, options)        # imports, caches: not measured
    runs = {cfg: [] for cfg in configs}
    rss = {}
    t0 = time.perf_counter()
    for r in range(repeat):
        for cfg in configs:
            runs[cfg].append(run_once(cfg[1], cfg[2], frames, seed, options))
            rss[cfg] = max(rss.get(cfg, 0.0), C.peak_rss_mb())
            print(f"  repeat {r + 1}/{repeat} {cfg[0]} targets={cfg[1]} detections={cfg[2]} "
                  f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
            if r == repeat - 1:                   # last repeat: the row is final
                s = summarise(runs[cfg], frames)
                s["peak_rss_mb"] = rss[cfg]
                s["lane"], s["targets"], s["detections"] = cfg
                print(f"  {cfg[0]} targets={cfg[1]} detections={cfg[2]}: {s['fps']:.2f} fps, "
                      f"{s['ms_per_frame']:.1f} ms/frame (max {s['max_ms_per_frame']:.0f}), "
                      f"K-means {s['stages_ms']['cluster']:.1f} ms/frame, "
                      f"peak RSS {s['peak_rss_mb']:.0f} MB, finite {s['finite']}", flush=True)
    out = {}
    for cfg in configs:
        s = summarise(runs[cfg], frames)
        s["peak_rss_mb"] = rss[cfg]
        s["lane"], s["targets"], s["detections"] = cfg
        out[f"{cfg[0]}:t{cfg[1]}:d{cfg[2]}"] = s
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--storm", default="20,200,2000", metavar="D,D,...",
                    help="detections per frame of the storm lane, 4 targets ('' to skip)")
    ap.add_argument("--targets", default="4,16,64,256", metavar="N,N,...",
                    help="simultaneous targets of the scale lane ('' to skip)")
    ap.add_argument("--frames", type=int, default=50, help="frames per run (default 50)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per configuration (median)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="PHD-MT parameter (as pfscope --set), e.g. max_particles=400000")
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = ap.parse_args(argv)
    if args.frames < 1 or args.repeat < 1:
        ap.error("--frames and --repeat must be >= 1")
    try:
        storm = [int(x) for x in args.storm.split(",") if x.strip()]
        scale = [int(x) for x in args.targets.split(",") if x.strip()]
    except ValueError:
        ap.error("--storm and --targets take comma-separated integers")
    if any(x < 1 for x in storm + scale):
        ap.error("--storm and --targets values must be >= 1")
    options = {}
    for item in args.set:
        name, sep, value = item.partition("=")
        if not sep:
            ap.error(f"--set {item!r}: expected NAME=VALUE")
        options[name.strip()] = value.strip()
    try:
        params = make_params("phd", None, options)
    except (ValueError, KeyError) as e:
        ap.error(str(e))

    info = C.machine()
    C.print_machine(info)
    print(f"PHD-MT, preset 'paper' {options or ''}; {args.frames} frames, {args.repeat} repeat(s), "
          f"seed {args.seed}; pipeline.run(level=None), detections-only scenes")
    configs = sorted([("storm", 4, d) for d in storm] + [("scale", t, t + 4) for t in scale],
                     key=lambda c: (c[2], c[1]))
    configs = list(dict.fromkeys(configs))
    results = bench(configs, args.frames, args.repeat, args.seed, options)

    rows = []
    for s in results.values():
        rows.append((s["lane"], s["targets"], f"{s['detections_mean']:.0f}",
                     f"{s['fps']:.2f}", f"{s['ms_per_frame']:.1f}",
                     *(f"{s['stages_ms'][st]:.1f}" for st in STAGES),
                     f"{s['particles_mean']:.0f}", s["births_max"],
                     f"{s['kmeans_iter_mean']:.1f}/{s['kmeans_iter_max']}",
                     s["kmeans_splits_max"], f"{s['peak_rss_mb']:.0f}",
                     "yes" if s["finite"] else "NO"))
    print(C.table(["lane", "targets", "det/frame", "fps", "ms/frame", *STAGES, "particles",
                   "births max", "Lloyd it mean/max", "splits max", "peak RSS MB", "finite"],
                  rows))
    print("(stage columns: ms per frame, median over repeats; peak RSS: process peak up to "
          "and including the row, configurations run smallest first)")
    summary = {}
    st = {s["detections"]: s for s in results.values() if s["lane"] == "storm"}
    if 20 in st:
        for d, s in st.items():
            if d != 20:
                summary[f"fps_ratio_{d}_to_20"] = s["fps"] / st[20]["fps"]
    sc = sorted((s for s in results.values() if s["lane"] == "scale"), key=lambda s: s["targets"])
    if len(sc) >= 2:
        xs = [s["targets"] for s in sc]
        summary["exponent_time_vs_targets"] = C.loglog_slope(xs, [s["ms_per_frame"] for s in sc])
        summary["exponent_per_stage"] = {
            stg: C.loglog_slope(xs, [max(s["stages_ms"][stg], 1e-6) for s in sc]) for stg in STAGES}
    for k, v in summary.items():
        if isinstance(v, dict):
            print(f"{k}: " + ", ".join(f"{s} {x:.2f}" for s, x in v.items()))
        else:
            print(f"{k}: {v:.3f}")
    C.write_json(args.json, {"benchmark": "storm", "command": C.command_line(), "machine": info,
                             "settings": {"phd": params_config(params), "options": options,
                                          "frames": args.frames, "repeat": args.repeat,
                                          "seed": args.seed},
                             "results": results, "summary": summary})
    return 0


if __name__ == "__main__":
    sys.exit(main())
