"""Helpers shared by the benchmark scripts: finding the data, opening a source, timing
statistics, the machine description, tables and the ``--json`` output.

The benchmarks keep no frame loop of their own: every run goes through the engine's
:func:`pfscope.trackers.pipeline.run` (or ``viewer_app.run.record``, which uses it), with
hooks (and, for per-stage timing, a timing subclass of the tracker) doing the measuring.

Benchmarks are scripts run by hand (``.venv/bin/python benchmarks/<name>.py``), not tests.
Real data is looked up in ``$PFSCOPE_DATA`` and then in ``../shared/data`` relative to the
repository root, like the tests do; it is never copied into the repository.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Iterable, Optional, Sequence

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # run from anywhere, installed or not
    sys.path.insert(0, str(REPO))

PETS = "PETS09-S2L1"
EXIT_NO_DATA = 2


class NoData(Exception):
    """The requested real sequence is not available (message says where we looked)."""


def data_roots() -> list[Path]:
    """Where real data is looked for, in order: ``$PFSCOPE_DATA``, ``<repo>/../shared/data``."""
    env = os.environ.get("PFSCOPE_DATA")
    return ([Path(env)] if env else []) + [REPO.parent / "shared" / "data"]


def pets_path() -> Path:
    """The PETS09-S2L1 MOT folder from the first data root that holds it."""
    roots = data_roots()
    for root in roots:
        if (root / PETS / "seqinfo.ini").is_file():
            return root / PETS
    raise NoData(f"{PETS} not found (looked in {', '.join(map(str, roots))}): set PFSCOPE_DATA "
                 f"to the folder holding {PETS}, or use --source synthetic")


def open_bench_source(spec: str, frames: Optional[int] = None, synthetic_frames: int = 150):
    """Open ``pets``, ``synthetic`` or a PATH (anything :func:`open_source` takes).

    The synthetic scene is built with ``frames`` frames when given (else ``synthetic_frames``),
    all other :class:`SceneConfig` fields at their defaults (seed 0)."""
    from pfscope.trackers.data.sources import open_source
    from pfscope.trackers.data.synthetic import SceneConfig

    if spec == "synthetic":
        return open_source("synthetic",
                           synthetic_config=SceneConfig(frames=frames or synthetic_frames))
    if spec == "pets":
        return open_source(pets_path())
    return open_source(spec)


def resolve_sources(specs: Optional[Sequence[str]]) -> list[str]:
    """Default (no ``--source``): PETS when its data is there, and the synthetic scene.
    PETS missing is only an error when it was asked for explicitly."""
    if specs:
        return list(dict.fromkeys(specs))
    try:
        pets_path()
        return ["pets", "synthetic"]
    except NoData as e:
        print(f"note: {e}; benchmarking the synthetic scene only", file=sys.stderr)
        return ["synthetic"]


def n_frames(source, frames: Optional[int]) -> int:
    """Frames to use: ``frames`` capped at the source length."""
    if source.length is None:
        if frames is None:
            raise SystemExit(f"{source.location}: length unknown, pass --frames N")
        return frames
    return source.length if frames is None else min(frames, source.length)


# ----------------------------------------------------------------------------- statistics

def median(xs: Iterable[float]) -> float:
    xs = list(xs)
    return statistics.median(xs) if xs else float("nan")


def fps(seconds: float, frames: int = 1) -> float:
    return frames / seconds if seconds > 0 else float("inf")


# ----------------------------------------------------------------------------- machine, output

def machine() -> dict:
    import numpy as np

    try:
        load = os.getloadavg()
    except OSError:
        load = None
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "loadavg_at_start": load,
            "python": platform.python_version(), "numpy": np.__version__,
            "platform": platform.platform()}


def print_machine(info: dict) -> None:
    load = info["loadavg_at_start"]
    load_s = ", ".join(f"{x:.2f}" for x in load) if load else "n/a"
    print(f"machine: {info['cpu']}, {info['cores']} cores, load average {load_s} "
          f"(shared machine: absolute numbers are indicative, ratios within one run hold better)")
    print(f"python {info['python']}, numpy {info['numpy']}")


def table(headers: Sequence[str], rows: Sequence[Sequence], aligns: Optional[str] = None) -> str:
    """A plain-text table; ``aligns`` one of 'l'/'r' per column (default: first left)."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    aligns = aligns or "l" + "r" * (len(headers) - 1)
    def fmt(r):
        return "  ".join(c.ljust(w) if a == "l" else c.rjust(w)
                         for c, w, a in zip(r, widths, aligns))
    lines = [fmt(cells[0]), "  ".join("-" * w for w in widths)]
    lines += [fmt(r) for r in cells[1:]]
    return "\n".join(lines)


def write_json(path: Optional[str], payload: dict) -> None:
    if not path:
        return
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(payload, indent=2, sort_keys=False, default=_json_default) + "\n")
    print(f"\nwrote {p}")


def _json_default(o):
    try:
        import numpy as np

        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
    except ImportError:  # pragma: no cover
        pass
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def command_line() -> str:
    return " ".join([".venv/bin/python", *sys.argv])


# ----------------------------------------------------------------------------- many-target scene

def _frame_class():
    from pfscope.trackers.data.sources import Source
    from pfscope.trackers.types import Frame, blank_image

    class DetOnlySource(Source):
        """Frames carry a black image of the source's size (one read-only zero-stride view, no
        pixels in memory: only the detections (``det``) and ``gt`` matter, but the image gives
        the frame its size, which the filter's scene clutter model reads)."""

        def frames(self, limit=None):
            n = self.length if limit is None else min(limit, self.length)
            img = blank_image(self.height, self.width)
            for k in range(1, n + 1):
                yield Frame(k, (k - 1) / self.fps, img)

    return DetOnlySource


def _clutter_boxes(rng, m: int, W: float, H: float) -> np.ndarray:
    """``m`` uniformly placed false boxes (x, y, w, h) of person-like shape, as both detection
    scenes draw them."""
    import numpy as np

    cw = rng.uniform(15, 60, m)
    ch = cw * rng.uniform(2, 3, m)
    return np.c_[rng.uniform(0, W, m) - cw / 2, rng.uniform(0, H, m) - ch / 2, cw, ch]


def _frame_detections(true_boxes: np.ndarray, clutter_boxes: np.ndarray) -> np.ndarray:
    """One frame's detections: the detected targets' noisy boxes, then the clutter, sizes
    floored at 2 px."""
    import numpy as np

    d = np.vstack([true_boxes, clutter_boxes])
    d[:, 2:4] = np.maximum(d[:, 2:4], 2.0)
    return d


def _scene_source(name: str, fps: float, frames: int, W: float, H: float, det_frames, det_boxes,
                  gt_frames, gt_ids, gt_boxes, extra: dict):
    """The detections-only source of a scene from its per-frame detection and gt arrays."""
    import numpy as np

    from pfscope.trackers.data.motio import MotTable

    fr = np.concatenate(det_frames).astype(np.int64)
    boxes = np.vstack(det_boxes)
    n = len(fr)
    det = MotTable(frame=fr, id=np.full(n, -1, np.int64), boxes=boxes, score=np.ones(n),
                   cls=np.ones(n), vis=np.ones(n))
    gfr = np.asarray(gt_frames, np.int64)
    ng = len(gfr)
    gt = MotTable(frame=gfr, id=np.asarray(gt_ids, np.int64), boxes=np.asarray(gt_boxes),
                  score=np.ones(ng), cls=np.ones(ng), vis=np.ones(ng))
    cls = _frame_class()
    return cls(name=name, fps=fps, length=frames, width=int(W), height=int(H), gt=gt, det=det,
               kind="synthetic", location="built-in", extra=extra)


def targets_scene(targets: int, frames: int, seed: int = 0, p_detect: float = 0.9,
                  clutter: float = 5.0):
    """A seeded detections-only scene with ``targets`` people visible on every frame.

    The image is 640 x 480 for 4 targets and grows by sqrt(targets / 4) per side, so the target
    density stays the same as their number grows. Each target is a box (w 24-48 px, h 2-3 w)
    moving at 0.5-2 px/frame in a random direction and bouncing off the image borders (so a
    run of any length keeps all of them in view); it is detected with probability ``p_detect``
    (box noise 5 % of its size), and Poisson(``clutter``) clutter boxes of person-like size fall
    uniformly over the image each frame. Ground truth: the true boxes, ids 1..targets."""
    import math

    import numpy as np


    rng = np.random.default_rng([seed, targets, 7])
    side = math.sqrt(max(targets, 4) / 4.0)
    W, H = 640.0 * side, 480.0 * side
    T = targets
    w = rng.uniform(24, 48, T)
    h = w * rng.uniform(2, 3, T)
    lo = np.c_[w / 2, h / 2]
    span = np.c_[W - w, H - h]
    p0 = rng.uniform(0.1, 0.9, (T, 2)) * span
    ang = rng.uniform(0, 2 * math.pi, T)
    v = rng.uniform(0.5, 2.0, T)[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    k = np.arange(frames, dtype=float)[:, None, None]
    x = (p0[None] + k * v[None]) % (2 * span[None])
    c = lo[None] + span[None] - np.abs(x - span[None])          # (frames, T, 2): bouncing
    gt_boxes = np.concatenate([c - np.c_[w, h][None] / 2,
                               np.broadcast_to(np.c_[w, h], c.shape)], axis=2)
    det_mask = rng.random((frames, T)) < p_detect
    noise = rng.standard_normal((frames, T, 4)) * 0.05 * np.c_[w, h, w, h][None]
    n_cl = rng.poisson(clutter, frames)
    fr, boxes = [], []
    for i in range(frames):
        tb = gt_boxes[i][det_mask[i]] + noise[i][det_mask[i]]
        b = _frame_detections(tb, _clutter_boxes(rng, n_cl[i], W, H))
        fr.append(np.full(len(b), i + 1))
        boxes.append(b)
    return _scene_source(f"targets{T}-seed{seed}", 25.0, frames, W, H, fr, boxes,
                         np.repeat(np.arange(1, frames + 1), T),
                         np.tile(np.arange(1, T + 1), frames), gt_boxes.reshape(-1, 4).copy(),
                         {"targets": T, "p_detect": p_detect, "clutter": clutter})



def births_scene(targets: int, frames: int, seed: int = 0, p_detect: float = 0.9,
                 clutter: float = 5.0, life_s: float = 4.0):
    """Random clutter with births anywhere: a seeded detections-only scene, 640 x 480 at 25 fps
    whatever ``targets``, with ``targets`` people at every frame.  Each moves at constant
    velocity (0.5-2 px/frame, random direction; box w 24-48 px, h 2-3 w) and lives until it
    leaves the image or its life ends (exponential, mean ``life_s`` seconds); then a new person
    appears at a uniformly drawn place of the image, with a new id.  Detected with probability
    ``p_detect`` (box noise 5 % of its size); Poisson(``clutter``) person-sized false boxes
    uniform over the image each frame (as :func:`targets_scene`)."""
    import math

    import numpy as np


    rng = np.random.default_rng([seed, targets, 11])
    W, H, fps = 640.0, 480.0, 25.0
    T = targets

    def newborn(n):
        w = rng.uniform(24, 48, n)
        h = w * rng.uniform(2, 3, n)
        c = np.c_[rng.uniform(w / 2, W - w / 2), rng.uniform(h / 2, H - h / 2)]
        ang = rng.uniform(0, 2 * math.pi, n)
        v = rng.uniform(0.5, 2.0, n)[:, None] * np.c_[np.cos(ang), np.sin(ang)]
        life = rng.exponential(life_s * fps, n)
        return c, v, np.c_[w, h], life

    c, v, wh, life = newborn(T)
    ids = np.arange(1, T + 1)
    next_id = T + 1
    gfr, gid, gbox, fr, boxes = [], [], [], [], []
    for i in range(frames):
        if i:
            c = c + v
            life = life - 1
            out = ((c[:, 0] < 0) | (c[:, 0] > W) | (c[:, 1] < 0) | (c[:, 1] > H) | (life <= 0))
            k = int(out.sum())
            if k:
                c[out], v[out], wh[out], life[out] = newborn(k)
                ids = ids.copy()
                ids[out] = np.arange(next_id, next_id + k)
                next_id += k
        b = np.c_[c - wh / 2, wh]
        gfr.append(np.full(T, i + 1))
        gid.append(ids.copy())
        gbox.append(b)
        hit = rng.random(T) < p_detect
        tb = b[hit] + rng.standard_normal((int(hit.sum()), 4)) * 0.05 * np.c_[wh, wh][hit]
        d = _frame_detections(tb, _clutter_boxes(rng, rng.poisson(clutter), W, H))
        fr.append(np.full(len(d), i + 1))
        boxes.append(d)
    return _scene_source(f"births{T}-seed{seed}", fps, frames, W, H, fr, boxes,
                         np.concatenate(gfr), np.concatenate(gid), np.vstack(gbox),
                         {"targets": T, "p_detect": p_detect, "clutter": clutter})

# ----------------------------------------------------------------------------- memory, fits

def rss_mb() -> float:
    """Current resident set size of this process, MB (Linux ``/proc/self/statm``)."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2 ** 20
    except (OSError, ValueError, IndexError):
        return float("nan")


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far, MB: ``VmHWM`` of /proc/self/status where
    there is one, else ``ru_maxrss``.  Linux keeps ``ru_maxrss`` across fork + exec, so in a
    child started by ``subprocess`` it reports the *parent's* peak when that is higher (this
    was the "unattributed transient" of the memory section); ``VmHWM`` belongs to the
    process's own address space."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def loglog_slope(x, y) -> float:
    """Least-squares slope of log y against log x (the exponent b of y ~ a x^b)."""
    import numpy as np

    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = (x > 0) & (y > 0) & np.isfinite(y)
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0])


# ----------------------------------------------------------------------------- stage clocks

class Clock:
    """Per-frame stage seconds (``now``), filled by the installed clocks, emptied per frame."""

    def __init__(self):
        self.now: dict[str, float] = {}
        self.births = 0
        self.clusters = None
        self._marks: list = []

    def take(self) -> dict:
        if self._marks:
            for (name, t0), (_, t1) in zip(self._marks, self._marks[1:]):
                if name is not None:
                    self.now[name] = self.now.get(name, 0.0) + t1 - t0
            self._marks = []
        out, self.now = self.now, {}
        return out


@contextlib.contextmanager
def phd_clocks(clock: Clock):
    """Clocks around the functions PHD-MT / MT call (module attributes, restored after)."""
    from pfscope.trackers.phd import association as assoc_mod
    from pfscope.trackers.phd import filter as filter_mod
    from pfscope.trackers.phd import tracker as tracker_mod

    pc = time.perf_counter
    saved = []
    state = {"birth_end": None}

    def wrap(owner, name, stage, after=None, since_birth=False):
        fn = getattr(owner, name, None)
        if fn is None:
            print(f"note: {getattr(owner, '__name__', owner)}.{name} not found: stage {stage} "
                  f"not timed", file=sys.stderr)
            return

        def timed(*a, **k):
            t = pc()
            out = fn(*a, **k)
            t1 = pc()
            t0 = state["birth_end"] if since_birth and state["birth_end"] is not None else t
            clock.now[stage] = clock.now.get(stage, 0.0) + t1 - t0
            if after is not None:
                after(out, t1)
            return out

        saved.append((owner, name, fn))
        setattr(owner, name, timed)

    def on_birth(b, t1):
        clock.births = len(b.particles)
        state["birth_end"] = t1

    def on_update(_, t1):
        state["birth_end"] = None

    def on_clusters(c, _):
        clock.clusters = c

    wrap(filter_mod, "predict", "predict")
    wrap(filter_mod, "birth", "birth", on_birth)
    # update = from the end of birth to the end of update: concat, clutter density, the gated
    # likelihood (a generator the update consumes) and eq. (5)
    wrap(filter_mod, "update", "update", on_update, since_birth=True)
    wrap(filter_mod, "resample", "resample")
    wrap(tracker_mod, "kmeans_peaks", "cluster", on_clusters)
    wrap(assoc_mod.GraphAssociator, "step", "associate")
    try:
        yield clock
    finally:
        for owner, name, fn in reversed(saved):
            setattr(owner, name, fn)


# ----------------------------------------------------------------------------- the scene's truth

#: The clutter boxes of :func:`targets_scene`: width uniform in CLUTTER_W px, height = width ×
#: uniform in CLUTTER_ASPECT, centre uniform over the image; the target boxes' noise std is
#: BOX_NOISE × (w, h, w, h) on (x, y, w, h).  (Must match the literals in ``targets_scene``;
#: ``tests/test_benchmarks.py`` checks them against a generated scene.)
CLUTTER_W = (15.0, 60.0)
CLUTTER_ASPECT = (2.0, 3.0)
BOX_NOISE = 0.05


def clutter_size_area() -> float:
    """Area (px²) of the (w, h) support of the scene's clutter boxes:
    ∫ (a_hi − a_lo) w dw over CLUTTER_W."""
    (w0, w1), (a0, a1) = CLUTTER_W, CLUTTER_ASPECT
    return (a1 - a0) * (w1 ** 2 - w0 ** 2) / 2.0


def scene_truth(source) -> dict:
    """The true model of a :func:`targets_scene` source, in the (cx, cy, w, h) observation
    space: ``p_detect``, ``clutter_rate`` (per frame), ``clutter_density`` = rate / (image area ×
    area of the clutter's (w, h) support) -- the clutter spread uniformly over the image and
    that support (the uniform density of the same support and rate) -- ``box_noise``, and
    ``targets`` (present on frame 1) and ``birth_rate`` (targets appearing per frame after it:
    0 on :func:`targets_scene`, whose targets stay to the end)."""
    ex = source.extra
    area = float(source.width) * float(source.height)
    return {"targets": int(ex["targets"]), "p_detect": float(ex["p_detect"]),
            "clutter_rate": float(ex["clutter"]),
            "clutter_density": float(ex["clutter"]) / (area * clutter_size_area()),
            "box_noise": BOX_NOISE, "birth_rate": _birth_rate(source)}


def _birth_rate(source) -> float:
    """Targets appearing per frame after the first (new gt ids; 0 on :func:`targets_scene`)."""
    import numpy as np

    gt = source.gt
    if gt is None or not len(gt.frame):
        return 0.0
    first = {}
    for f, i in zip(gt.frame.tolist(), gt.id.tolist()):
        first.setdefault(i, f)
    f0, f1 = int(gt.frame.min()), int(gt.frame.max())
    new = sum(1 for f in first.values() if f > f0)
    return new / max(f1 - f0, 1)


def ospa_parts(est, gt, c: float = 100.0) -> dict:
    """OSPA (order p = 1, cut-off ``c``) of one frame's estimated and true point sets, split in
    its two parts: ``ospa = loc + card`` with ``loc`` = Σ min(d, c) over the optimal assignment
    / n and ``card`` = c |m − k| / n (m estimates, k true, n = max(m, k)); also ``est``, ``true``
    and ``cut`` (assigned pairs at the cut-off: in effect one miss plus one false target)."""
    import numpy as np
    from scipy.optimize import linear_sum_assignment

    est = np.asarray(est, dtype=float).reshape(-1, 2)
    gt = np.asarray(gt, dtype=float).reshape(-1, 2)
    m, k = len(est), len(gt)
    n = max(m, k)
    if n == 0:
        return {"ospa": 0.0, "loc": 0.0, "card": 0.0, "est": 0, "true": 0, "cut": 0}
    loc, cut = 0.0, 0
    if m and k:
        d = np.minimum(np.sqrt(((est[:, None, :] - gt[None, :, :]) ** 2).sum(-1)), c)
        r, q = linear_sum_assignment(d)
        loc, cut = float(d[r, q].sum()), int((d[r, q] >= c).sum())
    card = c * abs(m - k)
    return {"ospa": (loc + card) / n, "loc": loc / n, "card": card / n, "est": m, "true": k,
            "cut": cut}
