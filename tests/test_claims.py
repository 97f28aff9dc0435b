"""Claims of maggio2007 (§4–§5, Table 1) checked on the synthetic scene over several seeds.

Each claim is a comparison the paper makes (PHD-MT against its baseline MT, or the PHD mass
against the true count), measured as a mean over ``SEEDS`` (scene seed = tracker seed) with a
stated tolerance, never as stored numbers: a change to a tracker passes as long as the claim
still holds, and fails when it stops holding.  The per-seed numbers are in every assertion
message; ``python tests/test_claims.py`` prints the tables (to re-measure after a change).

Tracker parameters are the paper's (``make_tracker(name, seed, preset="paper")``), never tuned; the
scene is chosen.  Scenes are 320x240, 150 frames, 8 targets (the scene scales with the image).

Measured when the claims were written (seeds 0–5; seeds 0–11 gave the same picture):

- cluttered scene (3 Poisson clutter boxes a frame + 2 persistent spots): PHD-MT FP 108–142,
  MT FP 481–532 (ratio 0.22–0.29 per seed, 0.25 of the means); MOTA PHD-MT 0.01…0.11 vs MT
  −0.13…−0.02, higher on every seed; IDSW 1–15 vs 10–20.
- Poisson clutter only: PHD-MT removes it (FP 0–1 vs 236–280).  But there MT's MOTA is the
  higher one on every seed (0.32–0.38 vs 0.19–0.30; seeds 0–11 too): PHD-MT pays 4x MT's
  misses (a track needs 3–4 coherent detections to rise above T, and one missed detection
  collapses a target's mass to p_M·M), which costs more than the ~255 clutter FP it saves.
  The MOTA/MODA claim is therefore asserted on the cluttered scene with persistent spots
  (the scene the former single-seed regression test used), where it holds; it is *not* a
  claim about every clutter mix.
- clean scene (no clutter, perfect detector): PHD mass / true count in steady state 0.65–0.70
  per seed (the filter docstring's "~0.8 per target" is the upper end; single frames range
  0.5–0.8); over the whole sequence 0.49–0.54 (entering targets take ~10 frames to build
  mass; occluded targets are not detected); never above the true count.  With the default
  p_detect = 0.9 the whole-sequence ratio drops to 0.29–0.36 (each miss resets a target's mass).
"""

from __future__ import annotations

from functools import cache

import numpy as np

from pfscope.trackers.api import make_tracker
from pfscope.trackers.data.sources import open_source
from pfscope.trackers.data.synthetic import SceneConfig
from pfscope.trackers.pipeline import BaseHook, run
from pfscope.trackers.report import Scalar, find

SEEDS = tuple(range(6))
BASE = {"frames": 150, "width": 320, "height": 240, "targets": 8}
#: Cluttered: random false detections plus places that fire on most frames.
CLUTTERED = dict(BASE, clutter=3.0, persistent_clutter=2)
#: Non-persistent clutter only: what §5 says the PHD filter removes.
POISSON = dict(BASE, clutter=3.0, persistent_clutter=0)
#: No clutter, every visible target detected: the PHD mass against the true count.
CLEAN = dict(BASE, clutter=0.0, persistent_clutter=0, p_detect=1.0)

#: Claim tolerances (why: see each test).
FP_RATIO_CLUTTERED = 1 / 3
FP_RATIO_POISSON = 0.05
STEADY_FRAMES = 10                 # a target is "locked on" after this many detected frames
# measured over seeds 0-11: 0.655-0.706 per seed and 0.494-0.544 (6-seed mean ~0.68 and ~0.52,
# its seed noise ~0.007): the bands are the measured means +- ~0.07, ten times that noise
STEADY_MASS_RANGE = (0.61, 0.75)   # mean steady-state mass per true target
SEQUENCE_MASS_RANGE = (0.45, 0.60)  # mean mass / mean true count over the whole sequence
MAX_OVERCOUNT = 0.5                # mass - true count, on any frame

SCORES = ("FP", "FN", "IDSW", "MOTA", "MODA")


class _Trace(BaseHook):
    """Per frame: the PHD lane's ``phd/mass`` and the ids of the (not ignored) true targets."""

    def __init__(self):
        self.frames: list[int] = []
        self.mass: list[float] = []
        self.gt_ids: list[frozenset] = []

    def on_frame(self, report) -> None:
        items = find(report.results["phd"].stages, "phd/mass", Scalar)
        assert len(items) == 1, f"frame {report.frame.index}: {len(items)} phd/mass scalars"
        self.frames.append(report.frame.index)
        self.mass.append(items[0].value)
        gt = report.gt
        self.gt_ids.append(frozenset(gt.ids[~gt.ignore].tolist()))


@cache
def _run(scene: str, seed: int, lanes: tuple = ("phd", "mt")):
    """One pipeline over synthetic scene ``scene`` (a name in this module) with ``seed``."""
    source = open_source("synthetic", synthetic_config=SceneConfig(seed=seed, **globals()[scene]))
    trace = _Trace()
    res = run(source, [make_tracker(name, seed=seed, preset="paper") for name in lanes],
              hooks=[trace])
    assert res.outcome.status == "completed" and res.frames == BASE["frames"], res.outcome
    return source, res, trace


def _scores(scene: str) -> dict:
    """lane -> score -> per-seed array."""
    return {lane: {k: np.array([float(_run(scene, s)[1].scores[lane][k]) for s in SEEDS])
                   for k in SCORES}
            for lane in ("phd", "mt")}


def _table(scene: str, keys=SCORES) -> str:
    sc = _scores(scene)
    head = "seed " + " ".join(f"{k + ' ' + lane:>10}" for k in keys for lane in ("phd", "mt"))
    rows = [f"{s:4d} " + " ".join(f"{sc[lane][k][i]:10.3g}" for k in keys
                                  for lane in ("phd", "mt")) for i, s in enumerate(SEEDS)]
    mean = "mean " + " ".join(f"{sc[lane][k].mean():10.3g}" for k in keys
                              for lane in ("phd", "mt"))
    return f"\n{scene} scene, {len(SEEDS)} seeds:\n" + "\n".join([head, *rows, mean])


def test_phd_mt_removes_most_false_positives_in_clutter():
    """§4/Table 1: PHD-MT filters clutter out; MT tracks it.  On the cluttered scene PHD-MT's
    mean FP is at most 1/3 of MT's.  Measured ≈ 0.25: the FP PHD-MT keeps are the persistent
    spots, which build mass like a real target (§5).  1/3 leaves a margin of ~30% of PHD-MT's
    FP against seed noise (per-seed ratio 0.22–0.29) and fails long before PHD-MT produced as
    many FP as MT."""
    sc = _scores("CLUTTERED")
    phd, mt = sc["phd"]["FP"].mean(), sc["mt"]["FP"].mean()
    assert phd <= FP_RATIO_CLUTTERED * mt, (
        f"mean FP PHD-MT {phd:.1f} > {FP_RATIO_CLUTTERED:.2f} x MT {mt:.1f} "
        f"(ratio {phd / mt:.3f})" + _table("CLUTTERED", ("FP", "FN")))


def test_phd_mt_removes_non_persistent_clutter():
    """§5: the PHD filter removes clutter "when the clutter is not persistent".  With Poisson
    clutter only, PHD-MT's mean FP is at most 5% of MT's.  Measured: 0–1 FP per seed against
    ~255 (ratio < 0.01); 5% (~13 FP a sequence) still means "almost all removed", leaves room
    for a change that lets an occasional clutter track through, and fails if clutter gets
    through in any quantity."""
    sc = _scores("POISSON")
    phd, mt = sc["phd"]["FP"].mean(), sc["mt"]["FP"].mean()
    assert phd <= FP_RATIO_POISSON * mt, (
        f"mean FP PHD-MT {phd:.1f} > {FP_RATIO_POISSON:.2f} x MT {mt:.1f}"
        + _table("POISSON", ("FP", "FN")))


def test_phd_mt_beats_mt_on_moda_and_mota_in_clutter():
    """Table 1: on cluttered sequences PHD-MT's MODA and MOTA are higher than MT's.  Asserted as
    mean(PHD-MT) >= mean(MT) (the claim itself, no slack): measured gap ≈ 0.13 (MOTA) and
    ≈ 0.11 (MODA), PHD-MT higher on every seed, while the seed noise of a 6-seed mean
    difference is ~0.02.  Not claimed for Poisson-only clutter, where MT wins (module
    docstring)."""
    sc = _scores("CLUTTERED")
    bad = [f"{k}: PHD-MT {sc['phd'][k].mean():.3f} < MT {sc['mt'][k].mean():.3f}"
           for k in ("MOTA", "MODA") if sc["phd"][k].mean() < sc["mt"][k].mean()]
    assert not bad, "; ".join(bad) + _table("CLUTTERED", ("MOTA", "MODA", "FP", "FN"))


def test_phd_mt_has_no_more_identity_switches_than_mt():
    """Table 1 / §4: PHD-MT's mean identity switches are at most MT's.  Measured
    ≈ 6 vs ≈ 16 (1–15 vs 10–20 per seed; the margin is large, so no slack).  Part of the gap
    may be that PHD-MT reports fewer target-frames (FN ≈ 4x MT's), so fewer chances to switch; the
    claim is stated as the paper states it, not per tracked frame."""
    sc = _scores("CLUTTERED")
    phd, mt = sc["phd"]["IDSW"].mean(), sc["mt"]["IDSW"].mean()
    assert phd <= mt, (f"mean IDSW PHD-MT {phd:.2f} > MT {mt:.2f}"
                       + _table("CLUTTERED", ("IDSW", "FN")))


def _mass_rows():
    """Per seed: (steady-state mass per target, whole-sequence mass / count, max over frames
    of mass - count, steady frames).  A frame is steady when it has targets and every one of
    them was detected on it and on each of the ``STEADY_FRAMES - 1`` frames before."""
    rows = []
    for s in SEEDS:
        source, _, tr = _run("CLEAN", s, ("phd",))
        scene = source.scene
        detected: dict[int, set] = {}
        for f, origin in zip(scene.det.frame.tolist(), scene.det_origin.tolist()):
            if origin > 0:  # a true detection of target id ``origin``
                detected.setdefault(f, set()).add(origin)
        mass = np.array(tr.mass)
        count = np.array([len(g) for g in tr.gt_ids], dtype=float)
        steady = [m / len(g) for f, m, g in zip(tr.frames, tr.mass, tr.gt_ids)
                  if g and all(g <= detected.get(f - j, set()) for j in range(STEADY_FRAMES))]
        rows.append((float(np.mean(steady)) if steady else float("nan"),
                     mass.mean() / count.mean(), float(np.max(mass - count)), len(steady)))
    return rows


def _mass_table(rows) -> str:
    return ("\nCLEAN scene: seed, steady mass per target, sequence mass/count, "
            "max(mass - count), steady frames\n"
            + "\n".join(f"{s:4d} {a:6.3f} {b:6.3f} {c:+6.3f} {n:4d}"
                        for s, (a, b, c, n) in zip(SEEDS, rows)))


def test_phd_mass_counts_targets_with_the_documented_under_count():
    """§2: the PHD's total mass is the expected number of targets.  With the paper's settings it
    under-counts (trackers/phd/filter.py: a locked-on target settles near 0.8, not 1): on a
    clean scene (no clutter, perfect detector)

    - steady state (every true target detected on each of the last 10 frames): the mean mass
      per true target is in [0.61, 0.75].  Measured 0.655–0.706 per seed (seeds 0–11), 6-seed
      mean ~0.68 with seed noise ~0.007.  The band fails if the under-count moves by ~0.07
      either way: a filter that over-counts or leaks birth mass, or one whose under-count
      grows;
    - over the whole sequence mean mass / mean true count is in [0.45, 0.60] (measured
      0.494–0.544; entering targets build mass over ~10 frames and occluded ones are not
      detected);
    - on no frame does the mass exceed the true count by more than half a target (measured:
      never above it)."""
    rows = _mass_rows()
    steady = np.array([r[0] for r in rows])
    seq = np.array([r[1] for r in rows])
    over = max(r[2] for r in rows)
    msg = _mass_table(rows)
    assert sum(r[3] for r in rows) >= 50, "too few steady frames to measure" + msg
    lo, hi = STEADY_MASS_RANGE
    assert lo <= np.nanmean(steady) <= hi, (
        f"steady-state mass per target {np.nanmean(steady):.3f} not in [{lo}, {hi}]" + msg)
    lo, hi = SEQUENCE_MASS_RANGE
    assert lo <= seq.mean() <= hi, (
        f"sequence mass / true count {seq.mean():.3f} not in [{lo}, {hi}]" + msg)
    assert over <= MAX_OVERCOUNT, (
        f"mass exceeds the true count by {over:.2f} > {MAX_OVERCOUNT} on some frame" + msg)


if __name__ == "__main__":
    for name in ("CLUTTERED", "POISSON"):
        print(_table(name))
    print(_mass_table(_mass_rows()))
