"""Compile the numba kernels before the first frame (issue 22: no silent compile).

The PHD filter, its K-means and systematic resampling are numba kernels compiled on their
first call and cached on disk (``cache=True``): the first run after an install spends its
compile time inside frame 1, and a later run only loads them.  :func:`compile_kernels` makes
those first calls on a throwaway PHD-MT run over a few frames of made-up detections (its own
generator: the real trackers' random streams are untouched), so the app can say what it is
doing while it waits, and the frame counter starts when frames do.

The K-means grid search (frames with ``clustering.INDEX_MIN_CENTERS`` or more centres, i.e.
that many detections) is left out: it is most of the compile, and most scenes never need it.
It compiles on the first frame that does (the app says so then: ``viewer_app.run``'s
``compile_notices``) and is cached like the rest.

On the first run (numba's cache holds no filter kernel yet) and a machine with a second core,
a child process compiles the PHD filter's kernels into the cache while this one compiles the
K-means kernels, the association's edge scores and M(z), then this one loads the helper's
(:func:`_start_helper`): the compile's wall time drops by about the helper's share (its CPU
time does not).  The child starts before the app has imported its trackers
(``start_helper_early``), so it takes the larger share: the two finish about together.

``uses_kernels(tracker)`` tells which trackers call the kernels (by their registered name).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np

#: trackers whose step calls the numba kernels (PHD filter + K-means, or resampling)
KERNEL_TRACKERS = frozenset({"phd", "dbn-phd", "phd-bgsub", "dlpf"})
#: of those, the ones that call only the resampling kernel (not the PHD filter's)
RESAMPLE_ONLY = frozenset({"dlpf"})
_ready: frozenset = frozenset()       # the preset tuples already warmed in this process


def uses_kernels(tracker) -> bool:
    return getattr(tracker, "name", None) in KERNEL_TRACKERS


def phd_kernels_needed(trackers) -> bool:
    """True when one of ``trackers`` runs the PHD filter's kernels (not only resampling)."""
    return any(uses_kernels(t) and getattr(t, "name", None) not in RESAMPLE_ONLY
               for t in trackers)


#: the PHD-MT presets whose steps the warm-up runs (:func:`_compile_core`)
PHD_PRESETS = ("practical", "paper")


def phd_presets_needed(trackers) -> tuple:
    """The PHD-MT presets the warm-up steps for ``trackers``: both when PHD-MT is among them,
    none for the background trackers alone (DBN-PHD, phd-bgsub): their own twin run
    (:func:`_compile_background`) reaches the filter kernels they call, and PHD-MT's steps
    would load ~13 kernels they never call (its learnt clutter, scene and camera motion,
    the Gaussian update)."""
    return PHD_PRESETS if any(getattr(t, "name", None) == "phd" for t in trackers) else ()


def _walkers(k: int, rng: np.random.Generator):
    """Frame ``k``'s made-up detections: eight walkers and three clutter boxes, fewer than
    INDEX_MIN_CENTERS detections (the dense K-means), enough mass for several clusters
    (splits included)."""
    from .types import Detections

    start = np.column_stack([np.linspace(40, 560, 8), np.full(8, 200.0)])
    xy = start + [4.0 * k, 1.0 * k]
    boxes = np.column_stack([xy, np.full(8, 30.0), np.full(8, 70.0)])
    clutter = np.column_stack([rng.uniform(0, 600, (3, 2)), np.full((3, 2), 35.0)])
    return Detections(np.vstack([boxes, clutter]), np.linspace(0.2, 1.0, 11))


def _compile_association(edges: bool = True, iou: bool = True) -> None:
    """The association's kernels (``edges``: the edge scores; ``iou``: the IoU of gap
    filling): the warm-up's tracks need more than its four frames of estimates to reach
    them."""
    from .phd.association import (AssocParams, _iou, compile_step_kernels, score_edges,
                                  tail_velocity)

    s = np.array([[100.0, 100.0, 1.0, 0.0, 30.0, 70.0]])
    if edges:
        ap = AssocParams()
        v, b, c = tail_velocity(s, s, np.zeros(1, dtype=np.int64), ap)
        score_edges(s, v, b, c, np.ones(1, dtype=np.int64), s, ap)
        compile_step_kernels(ap)
    if iou:
        _iou(s[:, [0, 1, 4, 5]], s[:, [0, 1, 4, 5]])


def _compile_filter_share() -> None:
    """The first-run helper's share (:func:`_start_helper`): the PHD filter's kernels but M(z)
    -- one filter step of a practical PHD-MT on the walkers (birth, the update, the resampling
    walk), the prediction of its particles as the next step makes it -- then the IoU of gap
    filling.  It imports the filter and its preset only, not the tracker registry (every
    tracker and their libraries: ~0.4 s of the helper's CPU before its first compile)."""
    from .phd.filter import max_births, predict
    from .phd.tracker import PHD_PRACTICAL, PHDTracker
    from .types import Frame, blank_image

    tr = PHDTracker(PHD_PRACTICAL, rng=np.random.default_rng(0))
    own = np.random.default_rng(2)
    f = tr.filter
    Z = _walkers(0, own)
    f.step(Z, Frame(1, 0.0, blank_image(480, 640)))
    # the next step's prediction, into its buffers (PHDFilter.step)
    n, p = len(f.particles), f.params
    cap = n + max_births(len(Z.observations()), p.birth)
    predict(f.particles, p.motion, f.rng, (np.empty((cap, 6)), np.empty(cap)))
    _compile_association(edges=False)


def _cloud(Z: np.ndarray, per: int, rng: np.random.Generator):
    """A made-up particle cloud around observations ``Z`` as the filter leaves it: ``per``
    particles each, C-ordered float64 states and log-weights, mass ≈ 1 per observation."""
    from .smc import ParticleSet

    n = per * len(Z)
    states = np.empty((n, 6))
    src = np.repeat(np.arange(len(Z)), per)
    states[:, [0, 1, 4, 5]] = Z[src] + rng.normal(0.0, 3.0, (n, 4))
    states[:, 2:4] = rng.normal(0.0, 1.0, (n, 2))
    return ParticleSet(states, np.full(n, np.log(len(Z) / n)))


def _compile_main_share() -> None:
    """The warm-up's own share on a first run while the helper compiles the filter's
    (:func:`compile_kernels`): the K-means kernels (dense specialisation), the association's
    edge scores and M(z) of the birth, on a made-up particle cloud around the walkers as the
    filter leaves it (C-ordered float64 states and log-weights, mass ≈ 1 per walker).  The
    helper starts ~2 s before this process, which first sets the app up, so it takes the
    larger share; M(z) comes last here, when the helper has cached the grid it shares with
    the update (numba then loads it instead of compiling it again)."""
    from .phd.clustering import kmeans_peaks
    from .phd.filter import as_observations, detection_noise, mass_near
    from .phd.tracker import PHD_PRACTICAL

    rng = np.random.default_rng(1)
    params = PHD_PRACTICAL
    Z = as_observations(_walkers(0, rng))
    ps = _cloud(Z, 1500, rng)
    cp, fp = params.clusters, params.filter
    kmeans_peaks(ps, Z, cp.T, params=fp, split_rule=cp.split_rule)
    _compile_association(iou=False)
    mass_near(ps, Z, fp.birth, fp.likelihood, detection_noise(Z, fp.likelihood)[0])


def _cache_cold(dispatcher) -> bool:
    """True when numba's cache has no index for ``dispatcher`` (a first run); False when it
    has one or cannot be told (numba's private layout changed: no helper then)."""
    try:
        return not os.path.exists(dispatcher._cache._cache_file._index_path)
    except Exception:
        return False


def _start_helper() -> "subprocess.Popen | None":
    """A child process compiling :func:`_compile_filter_share` into numba's cache
    (the same ``NUMBA_CACHE_DIR`` and interpreter), started only on a first run on a machine
    with a second core; None otherwise (or when it cannot start: this process then compiles
    everything itself, as it would anyway)."""
    if (os.cpu_count() or 1) < 2 or not _helper_allowed:
        return None
    from .phd import _kernels

    if not _cache_cold(_kernels.gauss_update_linear):
        return None
    try:
        return subprocess.Popen(
            [sys.executable, "-c", "from pfscope.trackers.warmup import "
             "_compile_filter_share as f; f()"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        return None


_early: "subprocess.Popen | None" = None     # the helper started by start_helper_early
#: False: no helper process (the install-time compile: its child could not import pfscope)
_helper_allowed = True


def start_helper_early(names) -> None:
    """Start the first-run helper (:func:`_start_helper`) as soon as the app knows it will run
    trackers ``names`` (registered names) that call the PHD kernels, so it compiles while the
    app still sets up; :func:`compile_kernels` then waits for it.  Stopped at exit if never
    waited for (a run that fails before its first frame)."""
    global _early
    if _early is not None or not any(n in KERNEL_TRACKERS and n not in RESAMPLE_ONLY
                                     for n in names):
        return
    _early = _start_helper()
    if _early is not None:
        import atexit

        atexit.register(_stop_early)


def _stop_early() -> None:
    if _early is not None and _early.poll() is None:
        _early.kill()
        _early.wait()


def _join(helper: "subprocess.Popen | None", timeout: float = 300.0) -> None:
    """Wait for the helper (stop it after ``timeout`` s: this process then compiles what it
    has not cached)."""
    if helper is None:
        return
    try:
        helper.wait(timeout)
    except subprocess.TimeoutExpired:
        helper.kill()
        helper.wait()


#: trackers with kernels of their own besides the PHD filter's: the codebook background
#: (both) and the DBN features (dbn-phd)
BACKGROUND_TRACKERS = frozenset({"dbn-phd", "phd-bgsub"})


def _compile_background(trackers) -> None:
    """The codebook and feature kernels of the ``trackers`` among :data:`BACKGROUND_TRACKERS`:
    a fresh tracker with the same parameters runs 3 frames of a small built-in scene (the
    kernels see the argument types a real run gives them, so no frame of the run compiles
    again).  Once per tracker name and process."""
    global _ready
    todo = {t.name: t for t in trackers if getattr(t, "name", None) in BACKGROUND_TRACKERS
            and ("background", t.name) not in _ready}
    if not todo:
        return
    from .data.sources import open_source
    from .data.synthetic import demo_config
    from .pipeline import run

    for name, t in todo.items():
        twin = type(t)(t.params, rng=np.random.default_rng(0))
        source = open_source(None, synthetic_config=demo_config(frames=3, width=320,
                                                                height=240))
        run(source, {name: twin}, frames=3, level="tracks", score=False, keep_rows=False)
        _ready = _ready | {("background", name)}


def index_kernel_needed(trackers) -> bool:
    """True when one of ``trackers`` resamples by ancestor indices (DLPF), a kernel the PHD
    filter does not call."""
    return any(getattr(t, "name", None) in RESAMPLE_ONLY for t in trackers)


def compile_kernels(presets=("practical", "paper"), phd: bool = True,
                    index: bool | None = None, trackers=()) -> float:
    """:func:`_compile_core`, then the background trackers' own kernels among ``trackers``
    (:func:`_compile_background`); returns the seconds it took."""
    t0 = time.perf_counter()
    _compile_core(presets, phd, index)
    _compile_background(trackers)
    return time.perf_counter() - t0


def _compile_core(presets=PHD_PRESETS, phd: bool = True,
                  index: bool | None = None) -> float:
    """Call every kernel once on made-up data (a compile on the first run after an install,
    a load from numba's cache afterwards); returns the seconds it took.  ``phd=False``: only
    the resampling kernel (DLPF's one).  ``index``: also the systematic resampling's index
    kernel (DLPF's; the PHD filter's resampling copies the rows in its own walk), default
    ``not phd``.  Once per process: later calls return 0 at once (the kernels stay compiled
    in the process).  ``presets=()`` (DBN-PHD or phd-bgsub alone, :func:`phd_presets_needed`):
    no PHD-MT step, only the helper's share, the robust spreads and the association kernels."""
    global _ready, _early
    index = (not phd) if index is None else index
    key = (presets if phd else ()) + (("resample",) if index else ())
    if key in _ready or (not phd and any("resample" in k for k in _ready)):
        return 0.0
    from .smc.resampling import resample_indices

    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    if index:
        resample_indices(np.log(np.full(16, 1 / 16)), 16, rng, "systematic")
    if not phd:
        _ready = _ready | {key}
        return time.perf_counter() - t0
    from .api import make_params        # (after the return: DLPF's run imports no PHD-MT)
    from .phd.tracker import PHDTracker
    from .types import Frame, blank_image
    image = blank_image(480, 640)
    helper, _early = (_early, None) if _early is not None else (_start_helper(), None)
    if helper is not None:
        # the K-means, edge-score and M(z) kernels here while the helper compiles the rest
        _compile_main_share()
        _join(helper)
    for preset in presets:
        tr = PHDTracker(make_params("phd", preset, {}), rng=np.random.default_rng(0))
        for k in range(4):
            tr.step(Frame(k + 1, k / 25.0, image), _walkers(k, rng))
    # the scene motion's robust spreads, which four frames do not reach (their rings fill
    # after scene_motion.MIN_SAMPLES triplets)
    from .phd.scene_motion import robust_stds
    robust_stds(np.ones((4, 8)))
    _compile_association()
    _ready = _ready | {key}
    return time.perf_counter() - t0


#: what :func:`compile_for_install` runs through the real pipeline: (tracker, preset)
INSTALL_RUNS = (("phd", "practical"), ("phd", "paper"), ("dbn-phd", None), ("phd-bgsub", None),
                ("dlpf", None))


def _compiles(fn) -> "tuple[float, list]":
    """Call ``fn()``; returns its seconds and the kernels numba compiled meanwhile (the
    outermost of each compile: a kernel called inside another is part of that one's)."""
    from numba.core import event

    depth, top = 0, []
    t0 = time.perf_counter()
    with event.install_recorder("numba:compile") as rec:
        fn()
    for _, e in rec.buffer:
        if e.is_start:
            if depth == 0:
                top.append(e.data["dispatcher"].py_func.__qualname__)
            depth += 1
        else:
            depth -= 1
    return time.perf_counter() - t0, top


def _compile_dense_kmeans() -> None:
    """The K-means grid search (``clustering.INDEX_MIN_CENTERS`` or more centres), which the
    warm-up leaves to the first crowded frame: a cloud around twice that many walkers."""
    from .phd.clustering import INDEX_MIN_CENTERS, kmeans_peaks
    from .phd.filter import as_observations
    from .phd.tracker import PHD_PRACTICAL
    from .types import Detections

    rng = np.random.default_rng(3)
    m = 2 * int(INDEX_MIN_CENTERS)
    xy = np.column_stack([np.linspace(20, 600, m), np.tile([150.0, 300.0], m // 2)])
    Z = as_observations(Detections(np.column_stack([xy, np.full(m, 30.0), np.full(m, 70.0)]),
                                   np.full(m, 0.9)))
    ps = _cloud(Z, 500, rng)
    cp = PHD_PRACTICAL.clusters
    kmeans_peaks(ps, Z, cp.T, params=PHD_PRACTICAL.filter, split_rule=cp.split_rule)


def compile_for_install(frames: int = 8, stream=None) -> float:
    """Compile every numba kernel the trackers call into numba's cache, for ``pip install -e
    .`` (the build backend, ``viewer_app/_backend``): the warm-up's kernels
    (:func:`compile_kernels`, both presets, the resampling index kernel, the background
    trackers' kernels), the dense K-means it leaves out, then each of :data:`INSTALL_RUNS`
    through the real pipeline over ``frames`` frames of the built-in scene (default
    parameters; every report level's path), so a kernel any of those steps calls is compiled
    whether or not it is listed here.  One line per part on ``stream`` (stdout): its seconds
    and the kernels it compiled.  No helper process.  Returns the seconds."""
    global _helper_allowed
    from .api import make_tracker
    from .data.sources import open_source
    from .pipeline import run

    stream = sys.stdout if stream is None else stream
    _helper_allowed = False
    t0 = time.perf_counter()

    def say(what, secs, top):
        names = ", ".join(sorted(set(top))) or "nothing new"
        stream.write(f"pfscope: {what}: {secs:.1f} s, compiled {names}\n")
        stream.flush()

    bg = [make_tracker(n) for n in sorted(BACKGROUND_TRACKERS)]
    say("warm-up kernels", *_compiles(lambda: compile_kernels(index=True, trackers=bg)))
    say("K-means grid search", *_compiles(_compile_dense_kmeans))
    for name, preset in INSTALL_RUNS:
        def go(name=name, preset=preset):
            for level, k in (("particles", frames), ("tracks", 3)):
                tr = make_tracker(name, preset=preset)
                run(open_source(None), {name: tr}, frames=k, level=level)
        say(f"{name}{f' ({preset})' if preset else ''} on the built-in scene", *_compiles(go))
    return time.perf_counter() - t0


__all__ = ["KERNEL_TRACKERS", "RESAMPLE_ONLY", "uses_kernels", "phd_kernels_needed",
           "index_kernel_needed", "compile_kernels", "start_helper_early", "compile_for_install"]
