"""The progress line shows the recent frame rate (issue 22), on a fake clock."""

import io
import os

from pfscope.viewer_app.run import Progress


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _run(bar, clock, durations):
    done = 0
    for d in durations:
        clock.t += d
        done += 1
        bar.update(done)
    return done


def test_rate_is_recent_not_cumulative():
    clock = FakeClock()
    out = io.StringIO()
    bar = Progress(300, "t", stream=out, clock=clock, window=2.0)
    clock.t = 100.0
    bar.start()
    # a 30-second first frame (a compile, a cold disk), then 50 frames a second
    _run(bar, clock, [30.0] + [0.02] * 200)
    assert abs(bar.rate() - 50.0) < 1.0          # cumulative would be 201 / 34 s ≈ 5.9 fps
    assert abs(bar.eta(201) - 99 / 50.0) < 0.1   # the ETA follows the recent rate
    # the machine slows to 10 frames a second: the rate follows within the window
    _run(bar, clock, [0.1] * 40)
    assert abs(bar.rate() - 10.0) < 0.5


def test_clock_starts_at_start_not_at_construction():
    clock = FakeClock()
    out = io.StringIO()
    bar = Progress(10, "t", stream=out, clock=clock)
    clock.t = 60.0                                # set-up before the frames (kernels, files)
    bar.start()
    clock.t += 0.5
    bar.update(1)
    assert abs(bar.rate() - 2.0) < 1e-9           # 1 frame in 0.5 s, not in 60.5 s


def test_lines_show_the_recent_rate():
    clock = FakeClock()
    out = io.StringIO()                           # not a terminal: a line every 10 %
    bar = Progress(100, "lane", stream=out, clock=clock)
    bar.start()
    _run(bar, clock, [20.0] + [0.04] * 99)
    last = out.getvalue().strip().splitlines()[-1]
    assert last == "lane: 100/100 frames, 25.0 fps"


def test_first_frame_shows_its_time_and_the_rate_counts_from_its_end():
    """The first frame's one-off costs (first calls, the recording's first frame) are not a
    rate: its line says how long it took, and the rate (and so the ETA) from frame 2 on counts
    frames after it."""
    clock = FakeClock()
    out = io.StringIO()                           # not a terminal: a line every 10 %
    bar = Progress(10, "lane", stream=out, clock=clock, window=2.0)
    bar.start()
    for done, secs in enumerate([0.8, 0.1, 0.1], start=1):
        clock.t += secs
        bar.update(done)
        if done == 1:
            assert out.getvalue().splitlines() == ["lane: 1/10 frames, first frame 0.8 s"]
        if done == 2:
            assert abs(bar.rate() - 10.0) < 1e-9  # 1 frame in 0.1 s, not 2 in 0.9 s
            assert out.getvalue().splitlines()[-1] == "lane: 2/10 frames, 10.0 fps"
    assert abs(bar.eta(3) - 0.7) < 1e-9           # 7 frames left at 10 fps


def test_rate_zero_before_frames():
    bar = Progress(10, "t", stream=io.StringIO(), clock=FakeClock())
    bar.start()
    assert bar.rate() == 0.0 and bar.eta(0) is None


class _Lane:
    def __init__(self, name):
        self.name = name


def test_compile_says_so_in_one_line(monkeypatch):
    import time

    import pfscope.trackers.warmup as W
    from pfscope.viewer_app.run import prepare_kernels

    import numpy as np
    from numba import njit

    @njit(cache=False)
    def fresh(a):                                  # never compiled before: a real compile
        return a.sum()

    def compile_one(**kw):
        calls.append(1)
        time.sleep(0.3)                            # the line is out (delay 0.05) ...
        fresh(np.ones(2))                          # ... then numba compiles: it says so

    calls = []
    monkeypatch.setattr(W, "compile_kernels", compile_one)
    out = io.StringIO()                            # a log: the line once, with its total
    secs = prepare_kernels([_Lane("phd")], stream=out, delay=0.05)
    text = out.getvalue()
    assert calls and secs >= 0.3                  # a log says what it was at the end
    assert text.count("\n") == 1 and text.startswith("pfscope: numba kernels ...")
    assert "compiled (first run after an install; cached afterwards): done in " in text

    monkeypatch.setattr(W, "compile_kernels", lambda **kw: (calls.append(1), fresh2(np.ones(2)),
                                                       time.sleep(0.3)))

    @njit(cache=False)
    def fresh2(a):
        return a.sum() + 1.0

    class Tty(io.StringIO):                       # a terminal: the spinner, live
        def isatty(self):
            return True

    out = Tty()
    prepare_kernels([_Lane("phd")], stream=out, delay=0.05)
    last = out.getvalue().split("\r")[-1]
    assert last.startswith("pfscope: compiling numba kernels") and "done in " in last

    monkeypatch.setattr(W, "compile_kernels", lambda **kw: (calls.append(1), time.sleep(0.3)))
    out = io.StringIO()                            # slow, but nothing compiled: "loaded"
    prepare_kernels([_Lane("phd")], stream=out, delay=0.05)
    assert "loaded from the cache: done in 0." in out.getvalue()
    assert "compil" not in out.getvalue()

    out = io.StringIO()                            # fast (kernels cached): nothing printed
    prepare_kernels([_Lane("phd")], stream=out, delay=5.0)
    assert out.getvalue() == ""

    calls.clear()                                  # no kernel tracker: no compile at all
    assert prepare_kernels([_Lane("mt")], stream=io.StringIO()) == 0.0 and not calls


def test_a_compile_during_the_frames_says_so_in_one_line():
    """A kernel compiled on first need while the frames run (the K-means grid search on a
    crowded frame) says so in one line; an already compiled one prints nothing, and no
    kernel tracker means no listener at all."""
    import numpy as np
    from numba import njit

    from pfscope.viewer_app.run import compile_notices

    @njit(cache=False)
    def fresh(a):                                  # never compiled before: a real compile
        return a.sum() * 2.0

    out = io.StringIO()
    with compile_notices([_Lane("phd")], stream=out, delay=0.0):
        assert fresh(np.ones(3)) == 6.0
        first = out.getvalue()
        fresh(np.ones(4))                          # compiled already: silent
    assert first.count("compiling numba kernels this frame needs") == 1
    assert first.startswith("pfscope: ") and first.endswith("s\n") and "done in" in first
    assert out.getvalue() == first

    class Tty(io.StringIO):                        # a terminal: one new line, then the spinner
        def isatty(self):
            return True

    @njit(cache=False)
    def fresh3(a):
        return a.sum() * 3.0

    out = Tty()
    with compile_notices([_Lane("phd")], stream=out, delay=0.0):
        fresh3(np.ones(2))
    text = out.getvalue()
    assert text.startswith("\n\rpfscope: compiling") and text.count("\n") == 2

    @njit(cache=False)
    def other(a):
        return a.sum()

    out = io.StringIO()
    with compile_notices([_Lane("mt")], stream=out, delay=0.0):
        other(np.ones(2))
    assert out.getvalue() == ""


def _signatures():
    from numba.core.registry import CPUDispatcher

    import pfscope.trackers.phd._assoc_kernels as AK
    import pfscope.trackers.phd._kernels as K
    import pfscope.trackers.phd._kmeans_kernels as KM
    import pfscope.trackers.smc.resampling as R

    return {f"{m.__name__}.{n}": set(map(str, d.signatures))
            for m in (K, KM, AK, R) for n, d in vars(m).items() if isinstance(d, CPUDispatcher)}


def test_compile_kernels_covers_a_run():
    """After the warm-up, a PHD-MT run (practical and paper) needs no kernel signature that
    the warm-up did not compile or load (so nothing compiles silently inside frame 1)."""
    import numpy as np

    from pfscope.trackers.api import make_params, tracker_info
    from pfscope.trackers.data.sources import open_source
    from pfscope.trackers.pipeline import run
    from pfscope.trackers.warmup import compile_kernels

    compile_kernels()
    before = _signatures()
    # the kernels called from Python: M(z), the update, the K-means, the association's edge
    # scores and IoU, systematic resampling
    assert sum(map(len, before.values())) >= 6
    for preset in ("practical", "paper"):
        tr = tracker_info("phd").cls(make_params("phd", preset, {}),
                                     rng=np.random.default_rng(0))
        run(open_source(None), {"phd": tr}, frames=20)
    assert _signatures() == before


def test_compile_kernels_covers_a_dbn_phd_run():
    """Given the DBN-PHD tracker, the warm-up also compiles (or loads) the codebook and DBN
    feature kernels with the types a run gives them: a DBN-PHD run's frames then compile no
    kernel signature (a cold run says so in the warm-up's one line, not inside frame 1)."""
    import numpy as np
    from numba.core.registry import CPUDispatcher

    import pfscope.trackers.dbn._codebook_kernels as CB
    import pfscope.trackers.dbn._feature_kernels as FK
    from pfscope.trackers.api import make_params, tracker_info
    from pfscope.trackers.data.sources import open_source
    from pfscope.trackers.pipeline import run
    from pfscope.trackers.warmup import compile_kernels

    def signatures():
        return {**_signatures(),
                **{f"{m.__name__}.{n}": set(map(str, d.signatures))
                   for m in (CB, FK) for n, d in vars(m).items()
                   if isinstance(d, CPUDispatcher)}}

    def tracker():
        return tracker_info("dbn-phd").cls(make_params("dbn-phd", None, {}),
                                           rng=np.random.default_rng(1))

    compile_kernels(trackers=[tracker()])
    before = signatures()
    assert all(before[f"{m.__name__}.{n}"] for m, n in ((CB, "detect"),
                                                        (FK, "region_cell_sums")))
    run(open_source(None), {"dbn-phd": tracker()}, frames=8, level="tracks")
    assert signatures() == before


def test_the_background_trackers_warm_up_without_phd_mt_steps():
    """DBN-PHD's warm-up as ``record`` asks for it (no PHD-MT preset stepped: its twin run
    reaches the filter kernels it calls) covers a DBN-PHD run: no kernel signature of the
    PHD, K-means, association, resampling, codebook or feature kernels is new after 8 frames.
    PHD-MT still gets both presets."""
    import numpy as np
    from numba.core.registry import CPUDispatcher

    import pfscope.trackers.dbn._codebook_kernels as CB
    import pfscope.trackers.dbn._feature_kernels as FK
    from pfscope.trackers.api import make_params, tracker_info
    from pfscope.trackers.data.sources import open_source
    from pfscope.trackers.pipeline import run
    from pfscope.trackers.warmup import PHD_PRESETS, compile_kernels, phd_presets_needed

    def signatures():
        return {**_signatures(),
                **{f"{m.__name__}.{n}": set(map(str, d.signatures))
                   for m in (CB, FK) for n, d in vars(m).items()
                   if isinstance(d, CPUDispatcher)}}

    def tracker(name="dbn-phd"):
        return tracker_info(name).cls(make_params(name, None, {}), rng=np.random.default_rng(1))

    assert phd_presets_needed([_Lane("dbn-phd"), _Lane("phd-bgsub")]) == ()
    assert phd_presets_needed([_Lane("dbn-phd"), _Lane("phd")]) == PHD_PRESETS
    compile_kernels(presets=phd_presets_needed([tracker()]), trackers=[tracker()])
    before = signatures()
    run(open_source(None), {"dbn-phd": tracker()}, frames=8, level="tracks")
    assert signatures() == before


def test_a_dlpf_run_warms_only_the_resampling_kernel(monkeypatch):
    """DLPF calls only systematic resampling: its warm-up does not compile (or load) the PHD
    filter's kernels, which would add seconds to its start; PHD-MT's does."""
    from pfscope.trackers import warmup as W
    from pfscope.viewer_app.run import prepare_kernels

    asked = []
    monkeypatch.setattr(W, "compile_kernels", lambda **kw: asked.append(kw.get("phd", True)))
    prepare_kernels([_Lane("dlpf")], stream=io.StringIO(), delay=5.0)
    prepare_kernels([_Lane("phd")], stream=io.StringIO(), delay=5.0)
    prepare_kernels([_Lane("dlpf"), _Lane("dbn-phd")], stream=io.StringIO(), delay=5.0)
    assert asked == [False, True, True]


def test_first_run_helper_fills_the_cache(tmp_path):
    """On a first run (empty numba cache) the warm-up starts a helper process that compiles the
    PHD filter's kernels into the cache (this process then loads them); on a later run (filled
    cache) it starts none."""
    code = ("import os\n"
            "from pfscope.trackers import warmup as W\n"
            "from pfscope.trackers.phd import _kernels as K\n"
            "os.cpu_count = lambda: 2\n"
            "print(W._cache_cold(K.gauss_update_linear))\n"
            "h = W._start_helper()\n"
            "print(h is not None)\n"
            "W._join(h)\n"
            "print(h.returncode, W._cache_cold(K.gauss_update_linear), "
            "W._start_helper() is None)\n")
    assert _fresh_process(code, tmp_path) == ["True", "True", "0", "False", "True"]


def _fresh_process(code: str, tmp_path) -> list:
    """The words ``code`` prints, run in a fresh interpreter with an empty numba cache."""
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.split()


def test_first_run_compiles_each_kernel_once_in_one_process(tmp_path):
    """A first run's warm-up (empty numba cache, a second core: the helper compiles the filter's
    kernels but M(z), and the IoU of gap filling) compiles in this process the K-means kernel,
    the association's edge scores, input check, frame edges, matching outcome, revive test,
    gap rows and their overlap test, head walk and confirmed test, and M(z) only, one
    specialisation each: none of the helper's kernels again (the helper's calls have the
    run's very signatures, so they load from its cache), none for the 'paper' preset that
    'practical' did not need, and nothing the run does not call.  numba's compile events, a
    fresh process."""
    code = ("import os\n"
            "from numba.core import event as ev\n"
            "os.cpu_count = lambda: 2\n"
            "from pfscope.trackers import warmup as W\n"
            "depth, top = 0, []\n"
            "with ev.install_recorder('numba:compile') as r:\n"
            "    W.compile_kernels()\n"
            "for _, e in r.buffer:\n"
            "    if e.is_start:\n"
            "        if depth == 0:\n"
            "            d = e.data['dispatcher']\n"
            "            top.append(d.py_func.__qualname__)\n"
            "        depth += 1\n"
            "    else:\n"
            "        depth -= 1\n"
            "print(' '.join(top))\n")
    top = _fresh_process(code, tmp_path)
    # ... and, in the warm-up's tracker frames, the scene motion's one pass a frame (links,
    # camera fit, triplets, spreads: _observe; the helper's one filter step reaches none of
    # it) and its robust spreads (the warm-up calls them: four frames do not fill the rings)
    # (the association's frame_step compiles advance and the input check inside it,
    # final_rows the confirmed test; frame_edges is the general path's: colour cue, edge data)
    # (gap filling's usual frame: gap_fill_last, which compiles gap_rows and fill_rows inside
    # it with the types of their own calls on the general path: they do not compile again)
    assert sorted(top) == ["_observe", "_robust_stds", "centre_boxes",
                           "edge_scores", "final_rows", "frame_edges",
                           "frame_step", "gap_fill_last",
                           "head_pick", "mass_near_kernel", "peaks",
                           "revive_hits", "row_boxes", "scene_frame", "scene_learn",
                           "track_boxes"], top


def test_early_helper_only_for_the_phd_kernels(monkeypatch):
    """`pfscope record` starts the first-run helper as soon as it knows its trackers, only
    when one calls the PHD kernels, once; the warm-up then waits for that helper instead of
    starting another."""
    from pfscope.trackers import warmup as W

    started = []

    class Fake:
        def poll(self):
            return 0

        def wait(self, timeout=None):
            started.append("joined")

    monkeypatch.setattr(W, "_early", None)
    monkeypatch.setattr(W, "_start_helper", lambda: started.append("start") or Fake())
    W.start_helper_early(["mt", "dlpf"])
    assert started == []
    W.start_helper_early(["mt", "phd"])
    W.start_helper_early(["phd"])
    assert started == ["start"]
    monkeypatch.setattr(W, "_ready", frozenset())
    W.compile_kernels()
    assert started == ["start", "joined"] and W._early is None


def test_record_starts_the_helper_before_the_parser(monkeypatch):
    """`pfscope record` names its tracker to the first-run helper before building the parser
    (which imports every tracker); other commands, and a --params file (which names the
    tracker itself), leave it to the later start."""
    from pfscope.trackers import warmup as W
    from pfscope.viewer_app import cli

    asked = []
    monkeypatch.setattr(W, "start_helper_early", lambda names: asked.append(list(names)))
    cli._early_compile(["record", "--force", "--out", "x.rrd"])
    cli._early_compile(["record", "--tracker", "dlpf", "--frames", "5"])
    cli._early_compile(["record", "--params", "p.toml"])
    cli._early_compile(["eval", "--tracker", "phd"])
    cli._early_compile([])
    assert asked == [["phd"], ["dlpf"]]
