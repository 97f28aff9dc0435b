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
``stonesoup``  Stone Soup's SMC-PHD (``_stonesoup.py``, needs the ``bench`` extra) as lanes
               of the same pipeline run as PHD-MT, on the same detections with the same number
               of particles in every update (``--ss-lanes``: pfscope's κ(z) without / with
               Stone Soup's noise draw, ``oracle``: the scene's true clutter density, p_D and
               measurement noise, ``oracle-birth``: and its true births, ``standard``: that
               with per-measurement estimates, the reported lane); speed ratios, and
               OSPA (c = 100 px, p = 1; localisation + cardinality) of PHD-MT's tracks file,
               live tracks, cluster estimates and k-means(round mass) and of each Stone Soup
               lane's k-means(round mass), at 4, 16, 64 targets (``--ss-targets``), 60 frames
               (``--ss-frames``), frames after a warm-up (``--ss-warmup``), mean ± std over
               seeds (``--ss-seeds``);
``endtoend``   (only with ``--only``) what a user meets: pfscope's whole PHD-MT step
               (``--e2e-preset``, default practical) vs Stone Soup's SMC-PHD + extraction at
               ``--ss-targets``, one seed, with PHD-MT's per-stage split; fresh-process
               ``pfscope record`` with an empty numba cache (cold) vs filled (warm), and
               the first one after ``pip install -e .``'s kernel compile (its seconds); a
               5-frame DBN-PHD run's wall time; the detector-free trackers' whole-process
               fps on PETS09-S2L1 (``--e2e-detector-free``: ``pfscope record PETS09-S2L1
               --tracker T --level tracks`` in a fresh process, numba's cache warm, frames /
               wall seconds) with the per-stage ms per frame of each tracker's step.

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

T_START = time.perf_counter()      # (a --record-child process's whole time counts from here)

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
                  preset: str = "paper", scene: str = "targets", options=None):
    """PHD-MT (+ optional extra lanes, stepping after it) on ``targets_scene`` (``scene``
    "births": ``births_scene``); returns the collector of the PHD-MT lane and the run result."""
    from pfscope.trackers.api import make_tracker
    from pfscope.trackers.pipeline import run as run_pipeline

    make_scene = C.births_scene if scene == "births" else C.targets_scene
    source = make_scene(targets, frames, seed)
    tracker = make_tracker("phd", seed, preset=preset_for("phd", preset),
                           **{**uncapped(targets, preset), **(options or {})})
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

#: Stone Soup lanes: name → (clutter model, measurement-noise draw in the likelihood, label)
#: Stone Soup lanes: name → (clutter, noise draw, label, births, extraction)
SS_LANES = {
    "standard": ("oracle", False, "Stone Soup SMC-PHD, standard (true κ, p_D, R, births; "
                 "per-measurement estimates)", "truth", "measurement"),
    "nonoise": ("pfscope", False, "Stone Soup SMC-PHD, pfscope κ(z), noise=False, k-means",
                "pfscope", "kmeans"),
    "oracle": ("oracle", False, "Stone Soup SMC-PHD, oracle (true κ, p_D, R), k-means",
               "pfscope", "kmeans"),
    "oracle-birth": ("oracle", False, "Stone Soup SMC-PHD, oracle + true births, k-means",
                     "truth", "kmeans"),
    "noise": ("pfscope", True, "Stone Soup SMC-PHD, pfscope κ(z), noise=True, k-means",
              "pfscope", "kmeans"),
}
#: PHD-MT's estimates that are scored (key → label)
PF_ESTIMATES = {
    "pf_tracks": "PHD-MT tracks file (confirmed, gap-filled)",
    "pf_live": "PHD-MT live tracks (confirmed at frame k)",
    "pf_clusters": "PHD-MT cluster estimates (kept K-means peaks)",
    "pf_kmeans": "PHD-MT filter, k-means(round mass)",
}
OSPA_C = 100.0


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


def _centres(boxes) -> np.ndarray:
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    return b[:, :2] + b[:, 2:4] / 2


def ss_run(T: int, frames: int, seed: int, lanes, preset: str, scene: str = "targets",
           options=None) -> dict:
    """One pipeline run: PHD-MT (``preset``) then the Stone Soup ``lanes`` on
    ``targets_scene(T, frames, seed)``. Per frame: OSPA parts (``_common.ospa_parts``) of every
    estimate, PHD masses, step seconds, particles in the update."""
    import _stonesoup as S

    from pfscope.trackers.pipeline import BaseHook

    # the k-means draws: one generator per estimate, so adding a lane changes no other row
    rngs: dict = {}

    def rng(key):
        if key not in rngs:
            rngs[key] = np.random.default_rng([seed, *key.encode()])
        return rngs[key]

    gts: list[np.ndarray] = []
    holder: dict = {}

    class SSCollect(BaseHook):
        def __init__(self, ss):
            self.ss, self.rows = ss, []

        def on_frame(self, report):
            g = gts[-1]                      # the PHD-MT collector (first hook) stored it
            row = {}
            for k, lane in self.ss.items():
                t = time.perf_counter()
                est = (lane.estimates if lane.estimates is not None    # per measurement
                       else _extract(lane.states, lane.mass, rng(k)))  # k-means(round mass)
                row[k] = {"secs": report.step_seconds[k], "mass": lane.mass,
                          "extract_secs": time.perf_counter() - t, "n_update": lane.n_update,
                          "parts": C.ospa_parts(est, g, OSPA_C)}
            self.rows.append(row)

    class TracksFile(BaseHook):
        """The rows PHD-MT writes to its tracks file, by frame (bounded-lag and ``finish``)."""

        def __init__(self):
            self.by_frame: dict[int, list] = {}

        def on_rows(self, lane, rows):
            if lane == "phd":
                for f, ts in rows:
                    self.by_frame.setdefault(int(f), []).append(_centres(ts.boxes))

    def lanes_capture(tracker, clock, source, seed):
        truth = C.scene_truth(source)
        ss = {f"ss_{name}": S.StoneSoupPHDLane(
            tracker, lambda: clock.births, width=source.width, height=source.height,
            noise=SS_LANES[name][1], seed=seed, clutter_rate=truth["clutter_rate"],
            clutter=SS_LANES[name][0], fps=source.fps, truth=truth,
            birth=SS_LANES[name][3], extract=SS_LANES[name][4]) for name in lanes}
        holder.update(clock=clock, ss=SSCollect(ss), file=TracksFile(), truth=truth,
                      fps=source.fps)
        return ss, [holder["ss"], holder["file"]]

    def extra(tr, report):
        c = tr.filter.particles
        g = _centres(report.gt.boxes)
        gts.append(g)
        cl = holder["clock"].clusters
        cl_est = cl.kept_centers[:, :2] if cl is not None else np.zeros((0, 2))
        return {"n": len(c), "mass": float(c.mass),
                "pf_kmeans": C.ospa_parts(_extract(c.states, c.mass, rng("pf_kmeans")), g,
                                          OSPA_C),
                "pf_clusters": C.ospa_parts(cl_est, g, OSPA_C),
                "pf_live": C.ospa_parts(_centres(report.results["phd"].tracks.boxes), g,
                                        OSPA_C)}

    t = time.perf_counter()
    hook, _, _src = run_phd_scene(T, frames, seed, extra_lanes=lanes_capture, extra=extra,
                                  preset=preset, scene=scene, options=options)
    wall = time.perf_counter() - t
    by_frame = holder["file"].by_frame
    per = {k: [e[k] for e in hook.extra] for k in ("pf_kmeans", "pf_clusters", "pf_live")}
    per["pf_tracks"] = [C.ospa_parts(np.vstack(by_frame.get(i + 1, [np.zeros((0, 2))])), g,
                                     OSPA_C) for i, g in enumerate(gts)]
    ssh = holder["ss"]
    for k in ssh.ss:
        per[k] = [r[k]["parts"] for r in ssh.rows]
    return {"wall": wall, "hook": hook, "ss_rows": ssh.rows, "lanes": list(ssh.ss),
            "per_frame": per, "truth": holder["truth"], "fps": holder["fps"],
            "est_by_frame": {f: np.vstack(v) for f, v in by_frame.items()},
            "mass": {"pf": [e["mass"] for e in hook.extra],
                     **{k: [r[k]["mass"] for r in ssh.rows] for k in ssh.ss}}}


def _summary(parts: list[dict], a: int, b: int) -> dict:
    """Means over frames a+1..b of the OSPA parts, the missing and extra estimates."""
    rows = parts[a:b]
    out = {k: float(np.mean([p[k] for p in rows])) for k in ("ospa", "loc", "card", "est",
                                                              "true", "cut")}
    out["missing"] = float(np.mean([max(p["true"] - p["est"], 0) for p in rows]))
    out["extra"] = float(np.mean([max(p["est"] - p["true"], 0) for p in rows]))
    return out


def bench_stonesoup(args) -> dict:
    import _stonesoup as S

    why = S.available()
    if why is not None:
        print(f"\n{why}")
        return {"skipped": why}

    frames, warm, lanes = args.ss_frames, args.ss_warmup, list(args.ss_lanes)
    print(f"\n=== Stone Soup {S.version()} SMC-PHD vs pfscope PHD-MT (preset {args.preset}): "
          f"same pipeline run, same detections (p_D 0.9, Poisson clutter 5/frame, 25 fps), same "
          f"particles in every update; {frames} frames, targets "
          f"{', '.join(map(str, args.ss_targets))}, seeds {', '.join(map(str, args.ss_seeds))}; "
          f"Stone Soup lanes {', '.join(lanes)}; times and OSPA over frames "
          f"{warm + 1}..{frames} (warm-up 1..{warm} left out of every lane alike) ===")
    keys = list(PF_ESTIMATES) + [f"ss_{name}" for name in lanes]
    results, rows = {}, []
    for T in args.ss_targets:
        per_seed = []
        for seed in args.ss_seeds:
            r = ss_run(T, frames, seed, lanes, args.preset, args.ss_scene,
                       dict(o.split("=", 1) for o in args.ss_set))
            hook, ssr = r["hook"], r["ss_rows"]
            filt = [sum(st.get(s, 0.0) for s in PHD_STAGES[:4]) for st in hook.stages]
            pf_n = in_update(hook, lambda e: e["n"])
            d = {"seed": seed, "run_seconds": r["wall"], "fps": r["fps"], "truth": r["truth"],
                 "pfscope_filter_ms": C.median(filt[warm:]) * 1e3,
                 "pfscope_phdmt_ms": C.median(hook.step[warm:]) * 1e3,
                 "particles_in_update": C.median(pf_n[warm:])}
            # same budget: Stone Soup's update had L_(k-1) + J_k particles too (from frame 2;
            # frame 1 starts Stone Soup from one particle of negligible weight)
            d["budget_max_abs_diff"] = max(
                (abs(row[k]["n_update"] - n) for row, n in zip(ssr[1:], pf_n[1:])
                 for k in r["lanes"]), default=0)
            for k in r["lanes"]:
                d[f"{k}_ms"] = C.median(row[k]["secs"] for row in ssr[warm:]) * 1e3
            d["parts"] = {k: _summary(r["per_frame"][k], warm, frames) for k in keys}
            d["warmup"] = {k: _summary(r["per_frame"][k], 0, warm) if warm else None
                           for k in keys}
            d["ospa"] = {k: d["parts"][k]["ospa"] for k in keys}
            d["mean_mass"] = {k: float(np.mean(v[warm:])) for k, v in r["mass"].items()}
            d["per_frame"] = {k: {"ospa": [p["ospa"] for p in v], "est": [p["est"] for p in v]}
                              for k, v in r["per_frame"].items()}
            per_seed.append(d)
            print(f"  {T} targets, seed {seed}: {r['wall']:.1f} s", file=sys.stderr)
        agg = {"targets": T, "seeds": per_seed}
        agg["budget_max_abs_diff"] = max(d["budget_max_abs_diff"] for d in per_seed)
        for key in ("pfscope_filter_ms", "pfscope_phdmt_ms", "particles_in_update",
                    *(f"ss_{name}_ms" for name in lanes)):
            agg[key] = C.median(d[key] for d in per_seed)
        for name in lanes:
            k = f"ss_{name}"
            agg[f"ratio_{k}_vs_filter"] = C.median(d[f"{k}_ms"] / d["pfscope_filter_ms"]
                                                   for d in per_seed)
            agg[f"ratio_{k}_vs_phdmt"] = C.median(d[f"{k}_ms"] / d["pfscope_phdmt_ms"]
                                                  for d in per_seed)
        agg["ospa_mean"] = {k: float(np.mean([d["ospa"][k] for d in per_seed])) for k in keys}
        agg["ospa_seed_std"] = {k: float(np.std([d["ospa"][k] for d in per_seed]))
                                for k in keys}
        agg["parts_mean"] = {k: {q: float(np.mean([d["parts"][k][q] for d in per_seed]))
                                 for q in per_seed[0]["parts"][k]} for k in keys}
        agg["warmup_ospa_mean"] = ({k: float(np.mean([d["warmup"][k]["ospa"]
                                                      for d in per_seed])) for k in keys}
                                   if warm else {})
        agg["mean_mass"] = {k: float(np.mean([d["mean_mass"][k] for d in per_seed]))
                            for k in per_seed[0]["mean_mass"]}
        best_ss = min(agg["ospa_mean"][f"ss_{name}"] for name in lanes) if lanes else None
        agg["phdmt_tracks_below_stonesoup"] = (None if best_ss is None else
                                               agg["ospa_mean"]["pf_tracks"] < best_ss)
        results[T] = agg
        rows.append([T, f"{agg['particles_in_update']:,.0f}", ms(agg["pfscope_filter_ms"]),
                     ms(agg["pfscope_phdmt_ms"])]
                    + [f"{ms(agg[f'ss_{n}_ms'])} ({agg[f'ratio_ss_{n}_vs_filter']:.1f}x / "
                       f"{agg[f'ratio_ss_{n}_vs_phdmt']:.1f}x)" for n in lanes])
    print(C.table(["targets", "particles in update", "pfscope PHD filter ms", "PHD-MT ms"]
                  + [f"SS {n} ms (/ filter / PHD-MT)" for n in lanes], rows))
    print("particles in the update, Stone Soup lanes vs PHD-MT, largest difference on any "
          f"frame after the first: {max(a['budget_max_abs_diff'] for a in results.values())} "
          "(1 on frames without births: Stone Soup's expansion scheme draws at least one)")
    print(f"(ms: medians over frames {warm + 1}..{frames}, then over seeds; ratios: Stone Soup "
          "time / pfscope time in the same run; 'filter' = predict+birth+update+resample, "
          "PHD-MT = the whole step with K-means and association)")
    labels = {**PF_ESTIMATES, **{f"ss_{n}": SS_LANES[n][2] for n in lanes}}
    acc_rows = []
    for T, agg in results.items():
        om, sd, pm, mm = (agg["ospa_mean"], agg["ospa_seed_std"], agg["parts_mean"],
                          agg["mean_mass"])
        for k in keys:
            p = pm[k]
            mass = mm["pf"] if k.startswith("pf_") else mm[k]
            acc_rows.append([T, labels[k], f"{om[k]:.1f} ± {sd[k]:.1f}", f"{p['loc']:.1f}",
                             f"{p['card']:.1f}", f"{p['est']:.1f}", f"{p['missing']:.1f}",
                             f"{p['extra']:.1f}", f"{p['cut']:.1f}",
                             f"{agg['warmup_ospa_mean'][k]:.1f}" if warm else "-",
                             f"{mass:.2f}"])
    print(f"\naccuracy on the same detections: OSPA (c = {OSPA_C:.0f} px, p = 1, box centres) "
          f"over frames {warm + 1}..{frames}, mean over frames then seeds ± std over seeds = "
          "loc (assigned pairs, d cut at c) + card (c × |#est − #true| / max); est = mean "
          "estimates per frame (true = targets); missing / extra = mean shortfall / excess of "
          "estimates; cut = assigned pairs at the cut-off (a miss + a false target); OSPA "
          f"1..{warm} = the warm-up frames left out; mass = mean PHD mass after the update "
          "(PHD-MT's for every pfscope row). Oracle = Stone Soup given the scene's true clutter "
          "density, p_D and measurement noise:")
    print(C.table(["targets", "estimate", "OSPA px", "loc", "card", "est", "missing", "extra",
                   "cut", f"OSPA 1..{warm}", "mass"], acc_rows, "rlrrrrrrrrr"))
    for T, agg in results.items():
        if lanes:
            if "standard" in lanes:
                om = agg["ospa_mean"]
                print(f"{T} targets: PHD-MT tracks file {om['pf_tracks']:.1f} px vs Stone Soup "
                      f"standard lane {om['ss_standard']:.1f} px: "
                      f"{'lower' if om['pf_tracks'] < om['ss_standard'] else 'NOT lower'}")
            print(f"{T} targets: PHD-MT tracks file {agg['ospa_mean']['pf_tracks']:.1f} px vs "
                  f"best Stone Soup lane "
                  f"{min(agg['ospa_mean'][f'ss_{n}'] for n in lanes):.1f} px: "
                  f"{'lower' if agg['phdmt_tracks_below_stonesoup'] else 'NOT lower'}")
    return {"stonesoup_version": S.version(), "preset": args.preset, "scene": args.ss_scene,
            "options": list(args.ss_set), "frames": frames, "warmup": warm, "seeds": list(args.ss_seeds), "lanes": lanes,
            "rows": list(results.values())}


# ----------------------------------------------------------------------------- end to end

#: the build backend whose editable build compiles the kernels (``pip install -e .``)
INSTALL_BACKEND = C.REPO / "viewer_app" / "_backend" / "pfscope_build_backend.py"


def _install_compile_applies() -> "str | None":
    """None when the ``pfscope`` that runs is this checkout's editable install (the install-time
    compile maps this checkout's folders: numba's cache is keyed by the source files' place),
    else why not."""
    import pfscope.trackers

    where = Path(pfscope.trackers.__file__).resolve().parent
    if where != (C.REPO / "trackers").resolve() or not INSTALL_BACKEND.is_file():
        return f"pfscope runs from {where}, not this checkout's editable install"
    return None


def _first_run(cmd: list, cache: str, cwd: str) -> float:
    """Wall seconds of ``cmd`` (a fresh process) with numba's cache in ``cache``."""
    import subprocess

    env = {**os.environ, "NUMBA_CACHE_DIR": cache}
    t = time.perf_counter()
    p = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=1800)
    secs = time.perf_counter() - t
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({p.returncode}): {p.stderr[-500:]}")
    return secs


#: the detector-free trackers whose whole-process fps on PETS09-S2L1 ``endtoend`` reports
DETECTOR_FREE = ("dlpf", "dbn-phd")


def record_child(out: str, argv: list) -> int:
    """``pfscope record ARGV`` in this process, through the CLI's own code path (``cli.main``),
    with the stage clocks of the ``stages`` section and a hook taking each frame's time; the
    per-frame numbers go to ``out`` as JSON (the parent times the whole process)."""
    import json

    from pfscope.trackers import pipeline

    clock = C.Clock()
    got: dict = {"t": [], "step": [], "stages": [], "stage_names": []}
    run0 = pipeline.run

    class Collect(pipeline.BaseHook):
        def begin(self, info):
            # the last pipeline run is the record's: the warm-up may run a few frames of its
            # own first (DBN-PHD's background kernels), which must not count
            got.update(t=[], step=[], stages=[], begin=time.perf_counter())
            clock.take()
            got["stage_names"] = [list(t.stages) for t in info.trackers.values()][0]

        def on_frame(self, report):
            got["t"].append(time.perf_counter())
            got["step"].append(sum(report.step_seconds.values()))
            got["stages"].append(clock.take())

    def run(*a, hooks=(), **k):          # record() imports pipeline.run when it runs
        return run0(*a, hooks=[*hooks, Collect()], **k)

    pipeline.run = run
    from pfscope.viewer_app.cli import main as cli_main

    with stagelog_clocks(clock):
        rc = cli_main(argv)
    got["process_seconds"] = time.perf_counter() - T_START
    with open(out, "w") as fh:
        json.dump(got, fh)
    return rc


def bench_detector_free(args, exe_py: str, cache: str, tmp: str) -> dict:
    """Whole-process fps of ``pfscope record PETS09-S2L1 --tracker T --level tracks`` for the
    detector-free trackers (a fresh process each, numba's cache filled by a short run first),
    with the per-stage ms per frame of the tracker's step (means over the frames: the parts add
    up) and the time per frame outside the step (reading, decoding, the recording)."""
    import json

    src = str(C.pets_path())
    res = {}
    rows, prof = [], []
    for name in args.e2e_detector_free:
        base = ["record", src, "--tracker", name, "--level", "tracks", "--quiet", "--force",
                "--seed", str(args.seed)]
        if args.e2e_pets_frames:
            base += ["--frames", str(args.e2e_pets_frames)]
        # a short run first: the kernels compiled into the cache (what "warm" means)
        _first_run([exe_py, "-m", "pfscope.viewer_app.cli", "record", src, "--tracker", name,
                    "--level", "tracks", "--quiet", "--force", "--frames", "3",
                    "--out", "w.rrd"], cache, tmp)
        js = str(Path(tmp) / f"{name}.json")
        wall = _first_run([exe_py, str(Path(__file__).resolve()), "--record-child", js, "--",
                           *base, "--out", f"{name}.rrd"], cache, tmp)
        with open(js) as fh:
            got = json.load(fh)
        n = len(got["t"])
        if not n:
            raise RuntimeError(f"{name}: `pfscope {' '.join(base)}` ran no frame")
        loop = got["t"][-1] - got["begin"]
        names = got["stage_names"]
        mean = {s: 1e3 * float(np.mean([f.get(s, 0.0) for f in got["stages"]])) for s in names}
        step = 1e3 * float(np.mean(got["step"]))
        d = {"frames": n, "process_seconds": wall, "fps_process": n / wall,
             "loop_seconds": loop, "fps_loop": n / loop, "setup_seconds": wall - loop,
             "stages_mean_ms": mean, "step_mean_ms": step,
             "other_ms": step - sum(mean.values()),
             "outside_step_ms": 1e3 * loop / n - step}
        res[name] = d
        rows.append([name, n, f"{wall:.1f}", f"{d['fps_process']:.1f}",
                     f"{d['setup_seconds']:.1f}", f"{d['fps_loop']:.1f}", ms(step),
                     ms(d["outside_step_ms"])])
        prof.append((name, d))
        print(f"  {name}: {wall:.1f} s", file=sys.stderr)
    print(f"\n=== detector-free trackers, whole process: `pfscope record {C.PETS} --tracker T "
          f"--level tracks` (a fresh process, numba's cache warm), frames / wall seconds ===")
    print(C.table(["tracker", "frames", "process s", "fps (whole process)", "set-up s",
                   "fps (frame loop)", "step ms", "outside the step ms"], rows))
    for name, d in prof:
        print(f"\n{name}: ms per frame of each step stage (means over the {d['frames']} frames; "
              f"other = the step outside its stages)")
        print(C.table(["stage", "ms", "share of the step"],
                      [[s, ms(v), f"{100 * v / d['step_mean_ms']:.0f}%"]
                       for s, v in d["stages_mean_ms"].items()]
                      + [["other", ms(d["other_ms"]),
                          f"{100 * d['other_ms'] / d['step_mean_ms']:.0f}%"],
                         ["step", ms(d["step_mean_ms"]), "100%"]]))
    return {"source": src, "trackers": res}


def detector_free_section(args) -> dict:
    """:func:`bench_detector_free` in a temporary folder with its own numba cache, when
    PETS09-S2L1 is found; when not, a NOT RUN line (and ``skipped`` in the JSON), or the
    error (:class:`_common.NoData`) when the trackers were named on the command line."""
    try:
        C.pets_path()
    except C.NoData as e:
        if getattr(args, "e2e_detector_free_asked", False):
            raise
        print(f"\n=== detector-free trackers on {C.PETS}: NOT RUN: {e} ===")
        return {"skipped": str(e)}
    with tempfile.TemporaryDirectory(prefix="pfscope-e2e-") as tmp:
        return bench_detector_free(args, sys.executable, str(Path(tmp) / "numba-cache"), tmp)


def bench_endtoend(args) -> dict:
    """What a user meets: (1) pfscope's whole ``PHDTracker.step`` (filter, K-means,
    association; ``--e2e-preset``) next to Stone Soup's SMC-PHD step plus its extraction
    (k-means of round(mass) centres, ``_extract``) on the same detections, one seed, in one
    pipeline run; (2) ``pfscope record`` (the built-in scene, 150 frames) in a fresh process
    with an empty numba cache (cold: the first run after an install) and again with it
    filled (warm), and the install-time compile of ``pip install -e .`` (the build backend's
    subprocess, another empty cache) with the first record after it; (3) the start of a 5-frame DBN-PHD run, first (its own kernels compile:
    the PHD-MT runs before leave only the PHD filter's in the cache) and warm; (4) the
    detector-free trackers' whole-process fps on PETS09-S2L1 (:func:`detector_free_section`)."""
    import _stonesoup as S

    out: dict = {}
    why = S.available()
    if why is not None:
        print(f"\n{why}")
        out["stonesoup"] = {"skipped": why}
    else:
        frames, warm, preset = args.e2e_frames, args.ss_warmup, args.e2e_preset
        print(f"\n=== end to end: pfscope PHD-MT whole step (preset {preset}: filter + K-means "
              f"+ association) vs Stone Soup {S.version()} SMC-PHD + extraction (k-means of "
              f"round(mass) centres), same detections (p_D 0.9, Poisson clutter 5/frame), same "
              f"particles in every update, seed {args.seed}, {frames} frames, medians over "
              f"frames {warm + 1}..{frames} ===")
        rows, res = [], []
        for T in args.ss_targets:
            r = ss_run(T, frames, args.seed, ["nonoise"], preset)
            hook, ssr = r["hook"], r["ss_rows"]
            pf = C.median(hook.step[warm:]) * 1e3
            filt = C.median([sum(st.get(s_, 0.0) for s_ in PHD_STAGES[:4])
                             for st in hook.stages][warm:]) * 1e3
            ss_f = C.median(row["ss_nonoise"]["secs"] for row in ssr[warm:]) * 1e3
            ss_fe = C.median(row["ss_nonoise"]["secs"] + row["ss_nonoise"]["extract_secs"]
                             for row in ssr[warm:]) * 1e3
            d = {"targets": T, "pfscope_phdmt_ms": pf, "pfscope_filter_ms": filt,
                 "ss_filter_ms": ss_f, "ss_filter_extract_ms": ss_fe,
                 "ratio": ss_fe / pf, "ratio_filter_only": ss_f / filt}
            # the split as means over the frames (medians of parts do not add up to the
            # median of the whole); other = the step outside the six stage clocks
            d["stages_ms"] = {st_: float(np.mean([st.get(st_, 0.0) for st in hook.stages[warm:]]))
                              * 1e3 for st_ in PHD_STAGES}
            d["step_mean_ms"] = float(np.mean(hook.step[warm:])) * 1e3
            d["other_ms"] = d["step_mean_ms"] - sum(d["stages_ms"].values())
            d["particles_in_update"] = C.median(in_update(hook, lambda e: e["n"])[warm:])
            res.append(d)
            rows.append([T, ms(pf), ms(ss_fe), f"{d['ratio']:.1f}x", ms(filt), ms(ss_f),
                         f"{d['ratio_filter_only']:.1f}x"])
            print(f"  {T} targets: {r['wall']:.1f} s", file=sys.stderr)
        print(C.table(["targets", "pfscope PHD-MT ms", "Stone Soup SMC-PHD + extraction ms",
                       "ratio", "pfscope filter ms", "Stone Soup filter ms", "filter ratio"],
                      rows))
        print("\nwhere PHD-MT's step goes (ms per frame, MEANS over the same frames, so the "
              "parts add up to the step; other = the step outside the six stage clocks: stage "
              "data, input conversion):")
        print(C.table(["targets", "particles in update", *PHD_STAGES, "other", "step (mean)"],
                      [[d["targets"], f"{d['particles_in_update']:,.0f}",
                        *(ms(d["stages_ms"][st_]) for st_ in PHD_STAGES), ms(d["other_ms"]),
                        ms(d["step_mean_ms"])] for d in res]))
        out["stonesoup"] = {"preset": preset, "frames": frames, "warmup": warm,
                            "stonesoup_version": S.version(), "rows": res}

    if args.e2e_detector_free:
        out["detector_free"] = detector_free_section(args)

    # first run after an install vs a warm run, each a fresh process
    if args.e2e_no_first_run:
        return out
    exe = str(Path(sys.executable).with_name("pfscope"))
    with tempfile.TemporaryDirectory(prefix="pfscope-e2e-") as tmp:
        cache = str(Path(tmp) / "numba-cache")
        cmd = [exe, "record", "--force", "--out", "synthetic.rrd"]
        cold = _first_run(cmd, cache, tmp)
        warm_s = [_first_run(cmd, cache, tmp) for _ in range(args.e2e_warm_repeat)]
        warm_run = C.median(warm_s)
        # the first run after `pip install -e .`: the install's compile (the build backend's
        # subprocess, compile_for_install) into another empty cache, then the same record
        installed = _install_compile_applies()
        if installed is None:
            aot_cache = str(Path(tmp) / "numba-cache-install")
            install_s = _first_run([sys.executable, str(INSTALL_BACKEND), "--editable",
                                    str(C.REPO)],
                                   aot_cache, tmp)
            after_install = _first_run(cmd, aot_cache, tmp)
        # DBN-PHD's own kernels (codebook, features) are not in the cache yet: its first run
        # compiles them; the second is the warm one
        dbn_cmd = [exe, "record", "--tracker", "dbn-phd", "--frames", "5", "--force",
                   "--out", "dbn.rrd"]
        dbn_first = _first_run(dbn_cmd, cache, tmp)
        dbn = _first_run(dbn_cmd, cache, tmp)
    print(f"\n=== first run: `pfscope record` (built-in scene, 150 frames), a fresh process "
          f"each ===")
    aot = ([["`pip install -e .`'s numba compile (empty cache)", f"{install_s:.1f}"],
            ["first run after `pip install -e .`", f"{after_install:.1f}"]]
           if installed is None else [])
    print(C.table(["run", "seconds"], [*aot,
                                       ["warm (median of "
                                        f"{len(warm_s)})", f"{warm_run:.1f}"],
                                       *([["first run after `pip install -e .` / warm",
                                           f"{after_install / warm_run:.2f}x"]] if aot else []),
                                       ["cold: no install-time compile (another CPU, "
                                        "PFSCOPE_INSTALL_COMPILE=0; empty numba cache)",
                                        f"{cold:.1f}"],
                                       ["cold / warm", f"{cold / warm_run:.2f}x"],
                                       ["dbn-phd, 5 frames (its own kernels compile)",
                                        f"{dbn_first:.1f}"],
                                       ["dbn-phd, 5 frames (warm)", f"{dbn:.1f}"]]))
    if installed is not None:
        print(f"NOT RUN: the install-time compile ({installed})")
    out["first_run"] = {"cold_s": cold, "warm_s": warm_s, "ratio": cold / warm_run,
                        **({"install_compile_s": install_s, "after_install_s": after_install,
                            "after_install_ratio": after_install / warm_run} if aot
                           else {"install_compile": f"not run: {installed}"}),
                        "dbn_phd_5_frames_first_s": dbn_first, "dbn_phd_5_frames_s": dbn,
                        "loadavg": list(os.getloadavg())}
    return out


# ----------------------------------------------------------------------------- main

SECTIONS = ("stages", "scaling", "recording", "memory", "stonesoup")
#: every section; ``endtoend`` (fresh processes, a cold numba compile: minutes) only by --only
ALL_SECTIONS = SECTIONS + ("endtoend",)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="a short run (a minute or two): fewer frames, targets 4/16/64, one "
                         "recording repeat, 1,000-frame memory run, one seed")
    ap.add_argument("--out", help="write every number as JSON to this file")
    ap.add_argument("--only", nargs="+", choices=ALL_SECTIONS, help="run only these sections")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trackers", nargs="+", metavar="NAME",
                    help="the stages section times only these trackers (default: every "
                         "registered one)")
    ap.add_argument("--preset", default="paper",
                    help="preset of every tracker that has it (default: paper; the others run "
                         "their first preset)")
    ss = ap.add_argument_group("stonesoup section (override the mode's defaults)")
    ss.add_argument("--ss-scene", choices=("targets", "births"), default="targets",
                    help="targets: all present from frame 1, bouncing, image growing with "
                         "the count (default); births: 640x480 whatever the count, targets "
                         "leave and new ones appear anywhere (_common.births_scene; the "
                         "lanes with true births take its birth rate)")
    ss.add_argument("--ss-set", action="append", default=[], metavar="NAME=VALUE",
                    help="PHD-MT option, as pfscope's --set (repeat), e.g. "
                         "clutter_model=learn")
    ss.add_argument("--ss-targets", nargs="+", type=int, metavar="N",
                    help="target counts (full: 4 16 64; quick: 4 16)")
    ss.add_argument("--ss-frames", type=int, metavar="N",
                    help="frames per run (full and quick: 60)")
    ss.add_argument("--ss-warmup", type=int, metavar="W",
                    help="first frames left out of OSPA and times, for every lane alike "
                         "(full and quick: 10)")
    ss.add_argument("--ss-seeds", nargs="+", type=int, metavar="S",
                    help="scene and filter seeds (full: 0 1 2; quick: 0)")
    ss.add_argument("--ss-lanes", nargs="+", choices=tuple(SS_LANES), metavar="LANE",
                    help="Stone Soup lanes: standard (the scene's true clutter density, p_D, "
                         "measurement noise and birth rate, estimates per measurement: W_z > "
                         "0.5), nonoise (pfscope's κ(z), no noise draw), oracle "
                         "(the scene's true clutter density, p_D and measurement noise), "
                         "oracle-birth (oracle + the scene's true births), noise (pfscope's "
                         "κ(z), Stone Soup's default noise draw) (default: standard nonoise "
                         "oracle oracle-birth)")
    e2e = ap.add_argument_group("endtoend section")
    e2e.add_argument("--e2e-preset", default="practical",
                     help="PHD-MT preset of the end-to-end table (default: practical)")
    e2e.add_argument("--e2e-frames", type=int, metavar="N",
                     help="frames per run (full: 60; quick: 40)")
    e2e.add_argument("--e2e-warm-repeat", type=int, metavar="N",
                     help="warm first runs, median (full: 3; quick: 1)")
    e2e.add_argument("--e2e-no-first-run", action="store_true",
                     help="skip the cold/warm first-run processes (quick iterations on the "
                          "per-step table)")
    e2e.add_argument("--e2e-detector-free", nargs="*", choices=DETECTOR_FREE, metavar="NAME",
                     help="detector-free trackers timed whole-process on PETS09-S2L1 "
                          f"(default: {' '.join(DETECTOR_FREE)} when the sequence is found, "
                          "a NOT RUN line when not; named here: an error when not found; "
                          "given with no name: none)")
    e2e.add_argument("--e2e-pets-frames", type=int, metavar="N",
                     help="PETS09-S2L1 frames of the detector-free runs (full: all 795; "
                          "quick: 200)")
    ap.add_argument("--tiny", action="store_true", help=argparse.SUPPRESS)  # the smoke test
    ap.add_argument("--memory-child", nargs=2, type=int, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    args.e2e_detector_free_asked = args.e2e_detector_free is not None
    if args.e2e_detector_free is None:
        args.e2e_detector_free = list(DETECTOR_FREE)
    full = dict(stage_frames=60, scale_frames=30, targets=[4, 16, 64, 256], rec_frames=100,
                rec_repeat=3, mem_frames=10_000, mem_every=1_000, ss_frames=60, ss_warmup=10,
                ss_targets=[4, 16, 64], ss_seeds=[0, 1, 2],
                ss_lanes=["standard", "nonoise", "oracle", "oracle-birth"], e2e_frames=60,
                e2e_warm_repeat=3, e2e_pets_frames=0)
    quick = dict(stage_frames=15, scale_frames=12, targets=[4, 16, 64], rec_frames=25,
                 rec_repeat=1, mem_frames=1_000, mem_every=100, ss_frames=60, ss_warmup=10,
                 ss_targets=[4, 16], ss_seeds=[0],
                 ss_lanes=["standard", "nonoise", "oracle", "oracle-birth"], e2e_frames=40,
                 e2e_warm_repeat=1, e2e_pets_frames=200)
    tiny = dict(stage_frames=7, scale_frames=7, targets=[4, 8], rec_frames=4, rec_repeat=1,
                mem_frames=30, mem_every=10, ss_frames=8, ss_warmup=2, ss_targets=[4],
                ss_seeds=[0], ss_lanes=list(SS_LANES), e2e_frames=8, e2e_warm_repeat=1,
                e2e_pets_frames=10)
    for k, v in (tiny if args.tiny else quick if args.quick else full).items():
        if getattr(args, k, None) is None:
            setattr(args, k, v)
    args.ss_lanes = list(dict.fromkeys(args.ss_lanes))
    if args.ss_frames < 2:
        ap.error(f"--ss-frames must be >= 2, got {args.ss_frames}")
    if not 0 <= args.ss_warmup < args.ss_frames:
        ap.error(f"--ss-warmup must be in [0, --ss-frames), got {args.ss_warmup} "
                 f"(frames {args.ss_frames})")
    bad = [o for o in args.ss_set if "=" not in o]
    if bad:
        ap.error(f"--ss-set takes NAME=VALUE, got {bad[0]!r}")
    if args.e2e_pets_frames < 0:
        ap.error(f"--e2e-pets-frames must be >= 0 (0: all), got {args.e2e_pets_frames}")
    if any(t < 1 for t in args.ss_targets):
        ap.error(f"--ss-targets must be >= 1, got {' '.join(map(str, args.ss_targets))}")
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
             "memory": bench_memory, "stonesoup": bench_stonesoup, "endtoend": bench_endtoend}
    t0 = time.perf_counter()
    for name in ALL_SECTIONS:
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
    if sys.argv[1:2] == ["--record-child"]:     # bench_detector_free's fresh process
        status = record_child(sys.argv[2], sys.argv[4:])
        from pfscope.viewer_app.cli import exit_process

        exit_process(status)                     # as `pfscope record` ends (cli.entry)
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
