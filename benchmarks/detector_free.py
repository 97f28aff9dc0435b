"""Accuracy of the detector-free trackers (DLPF, DBN-PHD, phd-bgsub) with their defaults on
every development sequence with frames, per seed, per sequence and combined (issue 20).

No detections file, no model argument: what a new user gets.  A video file is scored against a
ground truth given beside it (``VIDEO=GT.txt[:SCALE]``: the gt boxes are multiplied by SCALE,
for a video made by resizing a sequence's frames).

    python benchmarks/detector_free.py --trackers dlpf,dbn-phd,phd-bgsub --seeds 0,1,2 \
        ../shared/data/PETS09-S2L1 ../shared/data/PETS09-S3MF1 \
        /tmp/pets480.mp4=../shared/data/PETS09-S2L1/gt/gt.txt:0.625

Combined row: over the sequences given as folders (not the video files), CLEAR/identity counts summed (MOTA, IDF1 from the sums),
OSPA and its split frame-weighted, ME target-weighted is not available so it is frame-weighted.
``--json`` writes every run's scores for later tables.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np


def _ospa_split(gt, tracks, frames, c=100.0):
    """Mean over frames of OSPA's localisation and cardinality parts (p = 1, cut-off c; their
    sum is OSPA at p = 1)."""
    from scipy.optimize import linear_sum_assignment

    from pfscope.trackers.eval.overlap import box_centers

    loc = card = 0.0
    for f in frames:
        g = gt.ground_truth(f)
        keep = g.boxes[:, 2] > 0
        if hasattr(g, "ignore") and g.ignore is not None:
            keep &= ~np.asarray(g.ignore, bool)
        x = box_centers(g.boxes[keep]) if keep.any() else np.zeros((0, 2))
        t = tracks.tracks(f)
        y = box_centers(t.boxes) if len(t) else np.zeros((0, 2))
        m, n = len(x), len(y)
        if max(m, n) == 0:
            continue
        if min(m, n) == 0:
            card += c
            continue
        d = np.minimum(np.linalg.norm(x[:, None] - y[None], axis=-1), c)
        r, k = linear_sum_assignment(d)
        loc += d[r, k].sum() / max(m, n)
        card += c * abs(m - n) / max(m, n)
    nf = max(1, len(frames))
    return loc / nf, card / nf


def run_one(spec: str, tracker: str, seed: int, preset=None, options=None, frames=None):
    from pfscope.trackers.api import make_tracker
    from pfscope.trackers.data.motio import read_mot, table_from_tracksets
    from pfscope.trackers.data.sources import open_source
    from pfscope.trackers.eval import evaluate
    from pfscope.trackers.pipeline import run

    path, _, gtspec = spec.partition("=")
    src = open_source(path)
    gt = getattr(src, "gt", None)
    if gtspec:
        gpath, _, scale = gtspec.partition(":")
        gt = read_mot(gpath, "gt")
        if scale:
            gt = replace(gt, boxes=gt.boxes * float(scale))
    t0 = time.perf_counter()
    res = run(src, [make_tracker(tracker, seed=seed, preset=preset, **(options or {}))],
              score=False, frames=frames)
    secs = time.perf_counter() - t0
    rows = next(iter(res.rows.values()))
    table = table_from_tracksets(rows)
    frames = range(1, res.outcome.frames + 1)
    s = evaluate(gt, table, frames=frames)
    s["OSPA_loc"], s["OSPA_card"] = _ospa_split(gt, table, frames)
    s["seconds"] = secs
    return s


KEYS = ("OSPA", "OSPA_loc", "OSPA_card", "ME", "MOTA", "IDF1", "FP", "FN", "IDSW")


def combine(runs: list[dict]) -> dict:
    tot = {k: sum(r[k] for r in runs) for k in ("FP", "FN", "IDSW", "GT", "IDTP", "IDFP", "IDFN",
                                                 "num_frames")}
    out = {k: tot[k] for k in ("FP", "FN", "IDSW")}
    out["MOTA"] = 1 - (tot["FP"] + tot["FN"] + tot["IDSW"]) / max(1, tot["GT"])
    out["IDF1"] = 2 * tot["IDTP"] / max(1, 2 * tot["IDTP"] + tot["IDFP"] + tot["IDFN"])
    w = np.array([r["num_frames"] for r in runs], float)
    for k in ("OSPA", "OSPA_loc", "OSPA_card", "ME"):
        out[k] = float(np.nansum(w * np.array([r[k] for r in runs])) / w.sum())
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sources", nargs="+", help="MOT folders, or VIDEO=GT.txt[:SCALE]")
    ap.add_argument("--trackers", default="dlpf,dbn-phd,phd-bgsub")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--preset", default=None)
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="K=V")
    ap.add_argument("--frames", type=int, default=None, help="first N frames of each source")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    seeds = [int(s) for s in a.seeds.split(",")]
    opts = {}
    for kv in a.sets:
        k, _, v = kv.partition("=")
        opts[k] = v
    allruns: dict = {}
    for tr in a.trackers.split(","):
        per_seed_combined = []
        for spec in a.sources:
            name = Path(spec.partition("=")[0]).name
            runs = []
            for seed in seeds:
                s = run_one(spec, tr, seed, a.preset, opts, a.frames)
                runs.append(s)
                allruns.setdefault(tr, {}).setdefault(name, []).append(
                    {k: (float(v) if isinstance(v, (int, float, np.floating, np.integer)) else v)
                     for k, v in s.items()})
                print(f"{tr:10s} {name:22s} seed {seed}: " + "  ".join(
                    f"{k} {s[k]:.3f}" if isinstance(s[k], float) else f"{k} {s[k]}"
                    for k in KEYS) + f"  ({s['seconds']:.0f} s)", flush=True)
            m = {k: float(np.mean([r[k] for r in runs])) for k in KEYS}
            print(f"{tr:10s} {name:22s} MEAN:   " + "  ".join(f"{k} {m[k]:.3f}" for k in KEYS),
                  flush=True)
        # the combined row: the sequences given as folders (a video scored against a
        # rescaled copy of one of them would count that sequence twice)
        dev = [s for s in a.sources if "=" not in s] or a.sources
        for i, seed in enumerate(seeds):
            per_seed_combined.append(combine([allruns[tr][Path(s).name][i] for s in dev]))
        m = {k: float(np.mean([r[k] for r in per_seed_combined])) for k in KEYS}
        print(f"{tr:10s} {'COMBINED':22s} MEAN:   " + "  ".join(f"{k} {m[k]:.3f}" for k in KEYS),
              flush=True)
        allruns.setdefault(tr, {})["COMBINED"] = per_seed_combined
    if a.json:
        a.json.write_text(json.dumps(allruns, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
