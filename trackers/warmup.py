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

``uses_kernels(tracker)`` tells which trackers call the kernels (by their registered name).
"""

from __future__ import annotations

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


def compile_kernels(presets=("practical", "paper"), phd: bool = True) -> float:
    """Call every kernel once on made-up data (a compile on the first run after an install,
    a load from numba's cache afterwards); returns the seconds it took.  ``phd=False``: only
    the resampling kernel (DLPF's one).  Once per process: later calls return 0 at once (the
    kernels stay compiled in the process)."""
    global _ready
    key = presets if phd else ("resample",)
    if key in _ready or (not phd and _ready):
        return 0.0
    from .api import make_params
    from .phd.tracker import PHDTracker
    from .smc.resampling import resample_indices
    from .types import Detections, Frame, blank_image

    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    resample_indices(np.log(np.full(16, 1 / 16)), 16, rng, "systematic")
    if not phd:
        _ready = _ready | {key}
        return time.perf_counter() - t0
    image = blank_image(480, 640)
    # eight walkers and some clutter, enough mass for several clusters (splits included),
    # fewer than INDEX_MIN_CENTERS detections: the dense K-means
    start = np.column_stack([np.linspace(40, 560, 8), np.full(8, 200.0)])
    for preset in presets:
        tr = PHDTracker(make_params("phd", preset, {}), rng=np.random.default_rng(0))
        for k in range(4):
            xy = start + [4.0 * k, 1.0 * k]
            boxes = np.column_stack([xy, np.full(8, 30.0), np.full(8, 70.0)])
            clutter = np.column_stack([rng.uniform(0, 600, (3, 2)), np.full((3, 2), 35.0)])
            dets = Detections(np.vstack([boxes, clutter]), np.linspace(0.2, 1.0, 11))
            tr.step(Frame(k + 1, k / 25.0, image), dets)
    # the association's kernels (edge scores, the IoU of gap filling): its tracks need more
    # than four frames of estimates
    from .phd.association import AssocParams, _iou, score_edges, tail_velocity

    s = np.array([[100.0, 100.0, 1.0, 0.0, 30.0, 70.0]])
    ap = AssocParams()
    v, b, c = tail_velocity(s, s, np.zeros(1, dtype=np.int64), ap)
    score_edges(s, v, b, c, np.ones(1, dtype=np.int64), s, ap)
    _iou(s[:, [0, 1, 4, 5]], s[:, [0, 1, 4, 5]])
    _ready = _ready | {key}
    return time.perf_counter() - t0


__all__ = ["KERNEL_TRACKERS", "RESAMPLE_ONLY", "uses_kernels", "phd_kernels_needed",
           "compile_kernels"]
