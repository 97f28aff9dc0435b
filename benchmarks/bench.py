"""The benchmark harness of issue 12: one command, tables on stdout, every number in JSON.

    .venv/bin/python benchmarks/bench.py [--quick] [--out bench.json] [--only SECTION ...]

Sections (all by default; ``--only`` picks some):

``stages``     per-stage time per frame of every registered tracker at its paper preset
               (``--preset``; else its first preset), on the built-in synthetic scene
               (pixels + detections: the image trackers DLPF, DBN-PHD, PHD-bgsub need the
               pixels);
``scaling``    PHD-MT with 4, 16, 64, 256 simultaneous targets (ρ fixed: the memory cap
               ``max_particles`` is raised where it would bind; the
               detections-only scene of ``_common.targets_scene``: p_D 0.9, Poisson clutter
               5/frame, image growing with the targets so their density is fixed), medians
               over frames, and the log-log least-squares exponent of time vs targets, overall
               and per stage;
``recording``  the unrecorded pipeline (``level=None``, no hook) vs ``viewer_app.run.record``
               at each level (tracks, clusters, particles) on the synthetic scene, run
               interleaved in one process (order rotating per repeat): median time between
               frames and whole-call time, their ratios, and bytes per frame;
``memory``     RSS over a 10,000-frame PHD-MT run (4 targets, detections-only scene) in a
               fresh process, sampled every 1,000 frames, its slope, and the peak RSS;
``stonesoup``  Stone Soup's SMC-PHD (``_stonesoup.py``, needs the ``bench`` extra) as a lane
               of the same pipeline run as PHD-MT, on the same detections with the same number
               of particles in every update, measurement-noise draw on and off; speed ratios and
               OSPA (c = 100 px, p = 1) and mean PHD mass at 4, 16, 64 targets over seeds.

Every run goes through the engine's one frame loop (``pfscope.trackers.pipeline.run``) at
``level=None`` without a recorder (``recording`` adds the app's recorder on purpose). Stage
times are read by clocks around the functions a tracker calls (PHD-MT: ``predict``, ``birth``,
``update`` (incl. gating), ``resample``, ``kmeans_peaks``, ``GraphAssociator.step``; MT: the
latter), installed for the run only, or, for the other trackers, from the moments their
``StageLog.stage()`` calls mark (they call it before each stage's work). Time the tracker
spends outside its stages is the ``other`` column. The machine is shared: compare ratios within
one run; absolute times come with the load average.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")   # before numpy loads its BLAS: one core per process

import argparse
import contextlib
import sys
import tempfile
import time
from pathlib import Path

import _common as C
import numpy as np

PHD_STAGES = ("predict", "birth", "update", "resample", "cluster", "associate")
WARMUP = 5           # frames left out of the medians (the filter fills up)


# ----------------------------------------------------------------------------- stage clocks

@contextlib.contextmanager
def stagelog_clocks(clock: C.Clock):
    """Times between a tracker's ``StageLog.stage()`` calls (and ``result()``)."""
    from pfscope.trackers.report import StageLog

    pc = time.perf_counter
    stage0, result0 = StageLog.stage, StageLog.result

    def stage(self, name):
        clock._marks.append((name, pc()))
        return stage0(self, name)

    def result(self):
        clock._marks.append((None, pc()))
        return result0(self)

    StageLog.stage, StageLog.result = stage, result
    try:
        yield clock
    finally:
        StageLog.stage, StageLog.result = stage0, result0


def clocks_for(tracker, clock: C.Clock):
    from pfscope.trackers.phd.tracker import MTTracker, PHDTracker

    if type(tracker) in (PHDTracker, MTTracker):
        return C.phd_clocks(clock)
    return stagelog_clocks(clock)


def make_collector(lane: str, clock: C.Clock, extra=None):
    from pfscope.trackers.pipeline import BaseHook

    class Collect(BaseHook):
        """Per frame: the lane's step seconds, its stage seconds, detections, extras."""

        def __init__(self):
            self.step, self.stages, self.n_det, self.extra = [], [], [], []
            self.births = []

        def begin(self, info):
            self.tracker = info.trackers[lane]

        def on_frame(self, report):
            self.step.append(report.step_seconds[lane])
            self.births.append(clock.births)
            self.stages.append(clock.take())
            self.n_det.append(len(report.detections) if report.detections is not None else 0)
            if extra is not None:
                self.extra.append(extra(self.tracker, report))

    return Collect()


def preset_for(name: str, wanted: str = "paper"):
    """``wanted`` when tracker ``name`` has that preset, else None (its first preset)."""
    from pfscope.trackers.api import tracker_info

    return wanted if wanted in tracker_info(name).presets else None


def in_update(hook, count) -> list:
    """Particles in each frame's update: L_(k-1) (kept after the previous resampling, read by
    ``count`` from the collector's extras) + J_k (newborn)."""
    L = [count(e) for e in hook.extra]
    return [a + j for a, j in zip([0] + L[:-1], hook.births)]


def stage_medians(stages: list[dict], names, skip: int) -> dict:
    rows = stages[skip:] if len(stages) > skip else stages
    return {s: C.median(r.get(s, 0.0) for r in rows) * 1e3 for s in names}


def ms(x: float) -> str:
    if not np.isfinite(x):
        return "-"
    return f"{x:.3g}" if x < 100 else f"{x:,.0f}"


# ----------------------------------------------------------------------------- stages

def bench_stages(args) -> dict:
    from pfscope.trackers.api import make_tracker, registry
    from pfscope.trackers.pipeline import run as run_pipeline

    frames = args.stage_frames
    out = {"source": f"synthetic scene (SceneConfig defaults, seed 0), {frames} frames",
           "trackers": {}}
    print(f"\n=== per-stage time per frame, every tracker, preset {args.preset} where it "
          f"exists (else its first); synthetic scene, {frames} frames, medians over frames "
          f"{WARMUP + 1}..{frames} ===")
    reg = registry()
    for name in args.trackers or reg:
        if name not in reg:
            raise SystemExit(f"bench: unknown tracker {name!r}; choose from {', '.join(reg)}")
        info = reg[name]
        source = C.open_bench_source("synthetic", frames=frames)
        preset = preset_for(name, args.preset) or next(iter(info.presets))
        tracker = make_tracker(name, args.seed, preset=preset)
        clock = C.Clock()
        hook = make_collector(name, clock)
        t = time.perf_counter()
        with clocks_for(tracker, clock):
            res = run_pipeline(source, {name: tracker}, frames=frames, level=None, hooks=[hook],
                               keep_rows=False, score=False)
        wall = time.perf_counter() - t
        if res.outcome.status != "completed":
            raise SystemExit(f"{name}: pipeline stopped: {res.outcome.reason}")
        stages = tuple(tracker.stages)
        med = stage_medians(hook.stages, stages, WARMUP)
        step = np.array(hook.step[WARMUP:] or hook.step) * 1e3
        tot = [sum(r.values()) for r in hook.stages[WARMUP:] or hook.stages]
        other = C.median(s - 1e3 * t for s, t in zip(step, tot))
        out["trackers"][name] = {
            "preset": preset, "stages_median_ms": med,
            "step_median_ms": float(np.median(step)), "step_mean_ms": float(np.mean(step)),
            "other_median_ms": other, "fps_median": 1e3 / float(np.median(step)),
            "run_seconds": wall}
        print(f"\n{name} ({info.paper}; preset {preset}): "
              f"step median {ms(np.median(step))} ms ({1e3 / np.median(step):.0f} fps), "
              f"mean {ms(np.mean(step))} ms")
        print(C.table(["stage", "median ms", "share"],
                      [[s, ms(med[s]), f"{100 * med[s] / np.median(step):.0f}%"]
                       for s in stages] + [["other (outside stages)", ms(other),
                                            f"{100 * other / np.median(step):.0f}%"]]))
    return out


# ----------------------------------------------------------------------------- scaling

def uncapped(targets: int, preset: str = "paper") -> dict:
    """Options keeping ρ fixed with ``targets`` targets: ``max_particles`` (a memory cap, 100,000
    in the paper preset, i.e. ~66 targets at ρ = 1500) raised to 4 ρ targets when lower."""
    from pfscope.trackers.api import make_params

    rp = make_params("phd", preset_for("phd", preset)).filter.resampling
    need = int(4 * rp.rho * targets)
    return {"max_particles": str(need)} if need > rp.max_particles else {}


def run_phd_scene(targets: int, frames: int, seed: int, extra_lanes=None, extra=None,
                  preset: str = "paper"):
    """PHD-MT (+ optional extra lanes, stepping after it) on ``targets_scene``; returns the
    collector of the PHD-MT lane and the run result."""
    from pfscope.trackers.api import make_tracker
    from pfscope.trackers.pipeline import run as run_pipeline

    source = C.targets_scene(targets, frames, seed)
    tracker = make_tracker("phd", seed, preset=preset_for("phd", preset),
                           **uncapped(targets, preset))
    clock = C.Clock()
    hook = make_collector("phd", clock, extra)
    lanes = {"phd": tracker}
    hooks = [hook]
    if extra_lanes is not None:
        more, more_hooks = extra_lanes(tracker, clock, source, seed)
        lanes.update(more)
        hooks += more_hooks
    with C.phd_clocks(clock):
        res = run_pipeline(source, lanes, frames=frames, level=None, hooks=hooks,
                           keep_rows=False, score=False)
    if res.outcome.status != "completed":
        raise SystemExit(f"pipeline stopped: {res.outcome.reason}")
    return hook, res, source


def bench_scaling(args) -> dict:
    frames = args.scale_frames
    print(f"\n=== PHD-MT scaling with simultaneous targets (preset {args.preset}, ρ fixed); "
          f"detections-only scene, p_D 0.9, clutter 5/frame, {frames} frames, "
          f"medians over frames {WARMUP + 1}..{frames} ===")
    rows, data = [], {}
    for T in args.targets:
        t = time.perf_counter()
        hook, _, src = run_phd_scene(
            T, frames, args.seed, preset=args.preset,
            extra=lambda tr, rep: len(tr.filter.particles))
        wall = time.perf_counter() - t
        med = stage_medians(hook.stages, PHD_STAGES, WARMUP)
        step = C.median(hook.step[WARMUP:]) * 1e3
        n_up = in_update(hook, lambda e: e)
        d = {"targets": T, "image": [src.width, src.height],
             "detections_per_frame": float(np.mean(hook.n_det[WARMUP:])),
             "particles_after_resampling": float(np.median(hook.extra[WARMUP:])),
             "particles_in_update": float(np.median(n_up[WARMUP:])),
             "step_median_ms": step, "stages_median_ms": med, "run_seconds": wall}
        data[T] = d
        d["options"] = uncapped(T, args.preset)
        rows.append([T, f"{d['detections_per_frame']:.0f}",
                     f"{d['particles_in_update']:,.0f}",
                     f"{d['particles_after_resampling']:,.0f}", ms(step), f"{1e3 / step:.0f}"]
                    + [ms(med[s]) for s in PHD_STAGES])
        print(f"  {T} targets: {wall:.1f} s", file=sys.stderr)
    print(C.table(["targets", "det/frame", "particles in update", "L_k", "ms/frame", "fps",
                   *PHD_STAGES], rows))
    print("(particles in update = L_(k-1) + J_k; L_k = kept after resampling, ρ × mass: "
          "max_particles is raised where the preset's cap would bind, so ρ stays fixed)")
    Ts = list(data)
    expo = {"step": C.loglog_slope(Ts, [data[T]["step_median_ms"] for T in Ts])}
    for s in PHD_STAGES:
        expo[s] = C.loglog_slope(Ts, [data[T]["stages_median_ms"][s] for T in Ts])
    pair = {}
    for a, b in zip(Ts, Ts[1:]):
        pair[f"{a}-{b}"] = C.loglog_slope([a, b], [data[a]["step_median_ms"],
                                                   data[b]["step_median_ms"]])
    print("fitted exponent b of time ~ targets^b (log-log least squares over "
          f"{', '.join(map(str, Ts))}): "
          + ", ".join(f"{k} {v:.2f}" for k, v in expo.items()))
    print("between neighbours (step): " + ", ".join(f"{k}: {v:.2f}" for k, v in pair.items()))
    return {"frames": frames, "rows": list(data.values()), "exponent": expo,
            "exponent_between": pair}


# ----------------------------------------------------------------------------- recording

def bench_recording(args) -> dict:
    from pfscope.trackers.api import make_tracker
    from pfscope.trackers.pipeline import BaseHook
    from pfscope.trackers.pipeline import run as run_pipeline
    from pfscope.viewer_app.run import RecordOptions, record

    frames, repeats = args.rec_frames, args.rec_repeat
    levels = ("tracks", "clusters", "particles")
    print(f"\n=== recording overhead: PHD-MT on the synthetic scene, {frames} frames, "
          f"{repeats} repeat(s) interleaved; time per frame = median over frames 2..{frames} "
          f"of the time between frames ===")

    class Stamps(BaseHook):
        def __init__(self):
            self.t = []

        def on_frame(self, report):
            self.t.append(time.perf_counter())

    preset = preset_for("phd", args.preset)
    configs = ("none",) + levels
    times = {k: [] for k in configs}     # median time between frames, per repeat
    walls = {k: [] for k in configs}     # whole call (opening and closing the file included)
    sizes = {k: [] for k in levels}
    with tempfile.TemporaryDirectory(prefix="pfscope-bench-") as tmp:
        for r in range(repeats):
            for lv in configs[r % len(configs):] + configs[:r % len(configs)]:  # rotate order
                src = C.open_bench_source("synthetic", frames=frames)
                stamps: list[float] = []
                t0 = time.perf_counter()
                if lv == "none":
                    st = Stamps()
                    run_pipeline(src, {"phd": make_tracker("phd", args.seed, preset=preset)},
                                 frames=frames, level=None, hooks=[st], keep_rows=False,
                                 score=False)
                    stamps = st.t
                else:
                    out = Path(tmp) / f"{lv}-{r}.rrd"
                    res = record(src, out, RecordOptions(tracker="phd", level=lv, frames=frames,
                                                         seed=args.seed, force=True,
                                                         preset=preset),
                                 progress=False,
                                 on_frame=lambda _i, s=stamps: s.append(time.perf_counter()))
                    if res.interrupted:
                        raise SystemExit(f"recording at level {lv} did not complete")
                    sizes[lv].append(out.stat().st_size)
                    out.unlink()
                walls[lv].append(time.perf_counter() - t0)
                times[lv].append(float(np.median(np.diff(stamps))))
            print(f"  repeat {r + 1}/{repeats}", file=sys.stderr)
    base, wbase = C.median(times["none"]), C.median(walls["none"])
    rows = [["none (pipeline, level None)", ms(base * 1e3), "1.00", ms(wbase * 1e3 / frames),
             "1.00", "-", "-"]]
    data = {"none": {"ms_per_frame": base * 1e3, "wall_ms_per_frame": wbase * 1e3 / frames,
                     "raw_seconds_between_frames": times["none"],
                     "raw_wall_seconds": walls["none"]}}
    for lv in levels:
        t, w = C.median(times[lv]), C.median(walls[lv])
        ratio = C.median(a / b for a, b in zip(times[lv], times["none"]))
        wratio = C.median(a / b for a, b in zip(walls[lv], walls["none"]))
        kb = C.median(sizes[lv]) / frames / 1024
        data[lv] = {"ms_per_frame": t * 1e3, "ratio_to_unrecorded": ratio,
                    "wall_ms_per_frame": w * 1e3 / frames, "wall_ratio_to_unrecorded": wratio,
                    "bytes_per_frame": C.median(sizes[lv]) / frames,
                    "file_bytes": C.median(sizes[lv]), "raw_seconds_between_frames": times[lv],
                    "raw_wall_seconds": walls[lv]}
        rows.append([f"record --level {lv}", ms(t * 1e3), f"{ratio:.2f}",
                     ms(w * 1e3 / frames), f"{wratio:.2f}", f"{kb:.1f}",
                     f"{C.median(sizes[lv]) / 2 ** 20:.1f}"])
    print(C.table(["run", "ms/frame", "x unrecorded", "wall ms/frame", "x (wall)", "KB/frame",
                   f"MB/{frames} fr"], rows))
    print("(ms/frame: median time between frames; wall: the whole call / frames, opening, "
          "flushing and closing the file included; x: median over repeats of the ratio to the "
          "unrecorded run of the same repeat, the order of the four runs rotating per repeat; "
          "files include the fixed per-file cost, ~180 KB)")
    return {"frames": frames, "repeats": repeats, "levels": data}


# ----------------------------------------------------------------------------- memory

def memory_child(frames: int, every: int, seed: int, preset: str) -> dict:
    """The memory run itself (in a fresh process, see :func:`bench_memory`)."""
    from pfscope.trackers.api import make_tracker
    from pfscope.trackers.pipeline import BaseHook
    from pfscope.trackers.pipeline import run as run_pipeline

    class Sample(BaseHook):
        def __init__(self):
            self.at, self.rss, self.particles = [], [], []

        def begin(self, info):
            self.tracker = info.trackers["phd"]

        def on_frame(self, report):
            k = report.frame.index
            if k == 1 or k % every == 0:
                self.at.append(k)
                self.rss.append(C.rss_mb())
                self.particles.append(len(self.tracker.filter.particles))

    src = C.targets_scene(4, frames, seed)
    s = Sample()
    rss0 = C.rss_mb()
    t = time.perf_counter()
    run_pipeline(src, {"phd": make_tracker("phd", seed, preset=preset_for("phd", preset))},
                 frames=frames, level=None, hooks=[s], keep_rows=False, score=False)
    return {"frame": s.at, "rss_mb": s.rss, "particles": s.particles, "rss_before_mb": rss0,
            "peak_rss_mb": C.peak_rss_mb(), "run_seconds": time.perf_counter() - t}


def bench_memory(args) -> dict:
    """RSS over a long PHD-MT run, in a fresh Python process: in this one, memory freed by the
    earlier sections would be reused first and hide a slow growth."""
    import json
    import subprocess

    frames, every = args.mem_frames, args.mem_every
    print(f"\n=== memory: PHD-MT, 4 targets, detections-only scene, {frames:,} frames, RSS "
          f"every {every:,} frames, in a fresh process ===")
    cmd = [sys.executable, str(Path(__file__).resolve()), "--memory-child", str(frames),
           str(every), "--seed", str(args.seed), "--preset", args.preset]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"bench: memory run failed: {r.stderr.strip().splitlines()[-1:]}")
    d = json.loads(r.stdout.strip().splitlines()[-1])
    at, rss = np.array(d["frame"]), np.array(d["rss_mb"])
    tail = at >= every
    slope = (float(np.polyfit(at[tail], rss[tail], 1)[0]) * 1000
             if tail.sum() >= 2 else float("nan"))
    print(C.table(["frame", "RSS MB", "particles"],
                  [[f"{a:,}", f"{v:.1f}", f"{n:,}"]
                   for a, v, n in zip(at, rss, d["particles"])]))
    print(f"slope over frames {every:,}..{at[-1]:,}: {slope:+.3f} MB per 1,000 frames; RSS "
          f"{d['rss_before_mb']:.1f} MB before the run (interpreter, numpy, pfscope), peak RSS "
          f"of the process {d['peak_rss_mb']:.1f} MB; {frames / d['run_seconds']:.0f} frames/s")
    return {"frames": frames, "every": every, **d, "slope_mb_per_1000_frames": slope}


# ----------------------------------------------------------------------------- Stone Soup

def _extract(states: np.ndarray, mass: float, rng, cap: int = 5000) -> np.ndarray:
    """Target estimates from particles (equal weights after resampling): round(mass) K-means
    centres (scipy ``kmeans2``, k-means++) of the positions of at most ``cap`` particles."""
    from scipy.cluster.vq import kmeans2

    n = int(round(mass))
    if n <= 0 or len(states) == 0:
        return np.zeros((0, 2))
    pos = states[:, :2]
    if len(pos) > cap:
        pos = pos[rng.choice(len(pos), cap, replace=False)]
    n = min(n, len(pos))
    centres, _ = kmeans2(pos, n, minit="++", seed=rng)
    return centres


def bench_stonesoup(args) -> dict:
    import _stonesoup as S

    why = S.available()
    if why is not None:
        print(f"\n{why}")
        return {"skipped": why}
    from pfscope.trackers.eval.ospa import ospa
    from pfscope.trackers.pipeline import BaseHook

    frames = args.ss_frames
    print(f"\n=== Stone Soup {S.version()} SMC-PHD vs pfscope PHD-MT: same pipeline run, same "
          f"detections (p_D 0.9, clutter 5/frame), same particles in every update; {frames} "
          f"frames, seeds {', '.join(map(str, args.seeds))}; medians and OSPA over frames "
          f"{frames // 2 + 1}..{frames} ===")

    def lanes(tracker, clock, source, seed):
        ss = {f"ss_{tag}": S.StoneSoupPHDLane(tracker, lambda: clock.births, width=source.width,
                                               height=source.height, noise=noise, seed=seed,
                                               clutter_rate=source.extra["clutter"])
              for tag, noise in (("noise", True), ("nonoise", False))}
        return ss, [SSCollect(ss)]

    class SSCollect(BaseHook):
        def __init__(self, ss):
            self.ss = ss
            self.rows = []

        def on_frame(self, report):
            self.rows.append({k: (report.step_seconds[k], lane.mass, lane.states,
                                  lane.n_update) for k, lane in self.ss.items()})

    def extra(tr, report):
        c = tr.filter.particles
        return (len(c), float(c.mass), c.states.copy(),
                None if report.gt is None else report.gt.boxes.copy(),
                np.array(report.results["phd"].tracks.boxes, dtype=float))

    results, rows = {}, []
    for T in args.ss_targets:
        per_seed = []
        for seed in args.seeds:
            captured = {}

            def lanes_capture(tracker, clock, source, seed):
                ss, hooks = lanes(tracker, clock, source, seed)
                captured["hook"] = hooks[0]
                return ss, hooks

            t = time.perf_counter()
            hook, _, _src = run_phd_scene(T, frames, seed, extra_lanes=lanes_capture,
                                         extra=extra, preset=args.preset)
            wall = time.perf_counter() - t
            ssh = captured["hook"]
            rng = np.random.default_rng(seed)
            filt = [sum(r.get(s, 0.0) for s in PHD_STAGES[:4]) for r in hook.stages]
            k0 = frames // 2      # steady state: the PHD-MT tracks need >= 5 frames to show
            d = {"seed": seed, "run_seconds": wall,
                 "pfscope_filter_ms": C.median(filt[k0:]) * 1e3,
                 "pfscope_phdmt_ms": C.median(hook.step[k0:]) * 1e3,
                 "particles_in_update": C.median(in_update(hook, lambda e: e[0])[k0:])}
            # same budget: Stone Soup's update had L_(k-1) + J_k particles too (from frame 2;
            # frame 1 starts Stone Soup from one particle of negligible weight)
            pf_n = in_update(hook, lambda e: e[0])
            d["budget_max_abs_diff"] = max(
                (abs(r[k][3] - n) for r, n in zip(ssh.rows[1:], pf_n[1:])
                 for k in ("ss_noise", "ss_nonoise")), default=0)
            o = {"pf_kmeans": [], "pf_tracks": [], "ss_noise": [],
                 "ss_nonoise": []}
            mass = {"pf": [], "ss_noise": [], "ss_nonoise": []}
            for i in range(k0, frames):
                _n, m, states, gt, tracks = hook.extra[i]
                g = gt[:, :2] + gt[:, 2:4] / 2
                o["pf_kmeans"].append(ospa(_extract(states, m, rng), g, 100, 1))
                tb = tracks.reshape(-1, 4)
                o["pf_tracks"].append(ospa(tb[:, :2] + tb[:, 2:4] / 2, g, 100, 1))
                mass["pf"].append(m)
                for k in ("ss_noise", "ss_nonoise"):
                    _, sm, sst, _ = ssh.rows[i][k]
                    o[k].append(ospa(_extract(sst, sm, rng), g, 100, 1))
                    mass[k].append(sm)
            for k in ("ss_noise", "ss_nonoise"):
                d[f"{k}_ms"] = C.median(r[k][0] for r in ssh.rows[k0:]) * 1e3
            d["ospa"] = {k: float(np.mean(v)) for k, v in o.items() if v}
            d["mean_mass"] = {k: float(np.mean(v)) for k, v in mass.items()}
            per_seed.append(d)
            print(f"  {T} targets, seed {seed}: {wall:.1f} s", file=sys.stderr)
        agg = {"targets": T, "seeds": per_seed}
        agg["budget_max_abs_diff"] = max(d["budget_max_abs_diff"] for d in per_seed)
        for key in ("pfscope_filter_ms", "pfscope_phdmt_ms", "ss_noise_ms", "ss_nonoise_ms",
                    "particles_in_update"):
            agg[key] = C.median(d[key] for d in per_seed)
        for k in ("ss_noise", "ss_nonoise"):
            agg[f"ratio_{k}_vs_filter"] = C.median(d[f"{k}_ms"] / d["pfscope_filter_ms"]
                                                   for d in per_seed)
            agg[f"ratio_{k}_vs_phdmt"] = C.median(d[f"{k}_ms"] / d["pfscope_phdmt_ms"]
                                                  for d in per_seed)
        agg["ospa_mean"] = {k: float(np.mean([d["ospa"][k] for d in per_seed]))
                            for k in per_seed[0]["ospa"]}
        agg["ospa_seed_std"] = {k: float(np.std([d["ospa"][k] for d in per_seed]))
                                for k in per_seed[0]["ospa"]}
        agg["mean_mass"] = {k: float(np.mean([d["mean_mass"][k] for d in per_seed]))
                            for k in per_seed[0]["mean_mass"]}
        results[T] = agg
        rows.append([T, f"{agg['particles_in_update']:,.0f}", ms(agg["pfscope_filter_ms"]),
                     ms(agg["pfscope_phdmt_ms"]), ms(agg["ss_noise_ms"]),
                     ms(agg["ss_nonoise_ms"]),
                     f"{agg['ratio_ss_noise_vs_filter']:.1f}x / "
                     f"{agg['ratio_ss_noise_vs_phdmt']:.1f}x",
                     f"{agg['ratio_ss_nonoise_vs_filter']:.1f}x / "
                     f"{agg['ratio_ss_nonoise_vs_phdmt']:.1f}x"])
    print(C.table(["targets", "particles in update", "pfscope PHD filter ms", "PHD-MT ms",
                   "SS noise=True ms", "SS noise=False ms", "SS(noise) / filter / PHD-MT",
                   "SS(no noise) / filter / PHD-MT"], rows))
    print("particles in the update, Stone Soup lanes vs PHD-MT, largest difference on any "
          f"frame after the first: {max(a['budget_max_abs_diff'] for a in results.values())} "
          "(1 on frames without births: Stone Soup's expansion scheme draws at least one)")
    print("(ms: medians over frames, then over seeds; ratios: Stone Soup time / pfscope time in "
          "the same run; 'filter' = predict+birth+update+resample, PHD-MT = the whole step with "
          "K-means and association)")
    acc_rows = []
    for T, agg in results.items():
        om, sd, mm = agg["ospa_mean"], agg["ospa_seed_std"], agg["mean_mass"]
        for label, ko, km in (("pfscope PHD filter, k-means(round mass)", "pf_kmeans", "pf"),
                              ("pfscope PHD-MT tracks (output)", "pf_tracks", "pf"),
                              ("Stone Soup SMC-PHD noise=True, k-means", "ss_noise", "ss_noise"),
                              ("Stone Soup SMC-PHD noise=False, k-means", "ss_nonoise",
                               "ss_nonoise")):
            acc_rows.append([T, label, f"{om[ko]:.1f} ± {sd[ko]:.1f}", f"{mm[km]:.2f}"])
    print("\naccuracy on the same detections (OSPA c = 100 px, p = 1, on box centres, mean "
          "over frames then seeds ± std over seeds; mass = mean PHD mass after the update; "
          "true count = targets; Stone Soup is given the paper's κ(z), so the comparison is "
          "like for like under the paper preset):")
    print(C.table(["targets", "estimate", "OSPA px", "mean mass"], acc_rows, "rlrr"))
    return {"stonesoup_version": S.version(), "frames": frames, "seeds": list(args.seeds),
            "rows": list(results.values())}


# ----------------------------------------------------------------------------- main

SECTIONS = ("stages", "scaling", "recording", "memory", "stonesoup")


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="a short run (a minute or two): fewer frames, targets 4/16/64, one "
                         "recording repeat, 1,000-frame memory run, one seed")
    ap.add_argument("--out", help="write every number as JSON to this file")
    ap.add_argument("--only", nargs="+", choices=SECTIONS, help="run only these sections")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trackers", nargs="+", metavar="NAME",
                    help="the stages section times only these trackers (default: every "
                         "registered one)")
    ap.add_argument("--preset", default="paper",
                    help="preset of every tracker that has it (default: paper; the others run "
                         "their first preset)")
    ap.add_argument("--tiny", action="store_true", help=argparse.SUPPRESS)  # the smoke test
    ap.add_argument("--memory-child", nargs=2, type=int, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    full = dict(stage_frames=60, scale_frames=30, targets=[4, 16, 64, 256], rec_frames=100,
                rec_repeat=3, mem_frames=10_000, mem_every=1_000, ss_frames=24,
                ss_targets=[4, 16, 64], seeds=[0, 1, 2])
    quick = dict(stage_frames=15, scale_frames=12, targets=[4, 16, 64], rec_frames=25,
                 rec_repeat=1, mem_frames=1_000, mem_every=100, ss_frames=14,
                 ss_targets=[4, 16], seeds=[0])
    tiny = dict(stage_frames=7, scale_frames=7, targets=[4, 8], rec_frames=4, rec_repeat=1,
                mem_frames=30, mem_every=10, ss_frames=8, ss_targets=[4], seeds=[0])
    for k, v in (tiny if args.tiny else quick if args.quick else full).items():
        setattr(args, k, v)
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.memory_child:
        import json

        print(json.dumps(memory_child(*args.memory_child, args.seed, args.preset)))
        return 0
    info = C.machine()
    C.print_machine(info)
    sections = args.only or SECTIONS
    payload = {"command": C.command_line(), "machine": info,
               "mode": "tiny" if args.tiny else "quick" if args.quick else "full",
               "sections": {}}
    # warm-up: imports, first-call costs
    run_phd_scene(4, 3, args.seed, preset=args.preset)
    funcs = {"stages": bench_stages, "scaling": bench_scaling, "recording": bench_recording,
             "memory": bench_memory, "stonesoup": bench_stonesoup}
    t0 = time.perf_counter()
    for name in SECTIONS:
        if name in sections:
            t = time.perf_counter()
            payload["sections"][name] = funcs[name](args)
            payload["sections"][name]["section_seconds"] = time.perf_counter() - t
    payload["loadavg_at_end"] = list(os.getloadavg())
    payload["total_seconds"] = time.perf_counter() - t0
    print(f"\nload average at the end: {', '.join(f'{x:.2f}' for x in os.getloadavg())}; "
          f"{payload['total_seconds']:.0f} s in all")
    C.write_json(args.out, payload)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(130)
    except Exception as e:  # bad input / environment: one line, no traceback
        from pfscope.trackers.errors import InputError

        if isinstance(e, (InputError, C.NoData)):
            print(f"bench: {e}", file=sys.stderr)
            sys.exit(2)
        raise
