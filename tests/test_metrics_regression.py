"""Seeded regression: PHD-MT and MT scores on a cluttered synthetic scene must not get worse.

The stored scores are in ``tests/data/regression_metrics.json``. When a change makes a tracker
better, regenerate them with ``python tests/test_metrics_regression.py --update`` and commit
the new file with the change that earned it; a change that makes any score worse fails here.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from pfscope.trackers.base import make_tracker
from pfscope.trackers.data.motio import table_from_tracksets
from pfscope.trackers.data.synthetic import SceneConfig, SyntheticScene
from pfscope.trackers.eval import evaluate
from pfscope.trackers.types import Frame

BASELINE = Path(__file__).parent / "data" / "regression_metrics.json"
SCENE = SceneConfig(frames=150, targets=8, clutter=3.0, persistent_clutter=2, width=320,
                    height=240, seed=7)
HIGHER_IS_BETTER = ("MOTA", "MOTP", "MODA", "MODP", "IDF1", "HOTA")
LOWER_IS_BETTER = ("IDSW", "FP", "FN", "OSPA")
TOL = {"ratio": 1e-6, "count": 0, "OSPA": 1e-6}


def scores(name: str) -> dict:
    scene = SyntheticScene(SCENE)
    tr = make_tracker(name, seed=0)
    blank = np.zeros((4, 4, 3), np.uint8)
    rows = []
    for k in range(1, SCENE.frames + 1):
        tr.step(Frame(k, 0.0, blank), scene.det.detections(k))
        rows += tr.pop_final()
    rows += tr.finish()
    s = evaluate(scene.gt, table_from_tracksets(rows), frames=range(1, SCENE.frames + 1))
    return {k: float(s[k]) for k in HIGHER_IS_BETTER + LOWER_IS_BETTER}


@pytest.mark.parametrize("name", ["phd", "mt"])
def test_scores_do_not_regress(name):
    base = json.loads(BASELINE.read_text())[name]
    now = scores(name)
    worse = [f"{k}: {base[k]:.4f} -> {now[k]:.4f}" for k in HIGHER_IS_BETTER
             if now[k] < base[k] - TOL["ratio"]]
    worse += [f"{k}: {base[k]:.4f} -> {now[k]:.4f}" for k in LOWER_IS_BETTER
              if now[k] > base[k] + (TOL["OSPA"] if k == "OSPA" else TOL["count"])]
    assert not worse, f"{name} got worse on the seeded cluttered scene: " + "; ".join(worse)


def test_phd_beats_mt_where_the_paper_says():
    """maggio2007 Table 1: on cluttered sequences PHD-MT has better MODA/MOTA than MT."""
    base = json.loads(BASELINE.read_text())
    assert base["phd"]["MOTA"] > base["mt"]["MOTA"]
    assert base["phd"]["FP"] < base["mt"]["FP"]


if __name__ == "__main__":
    if "--update" in sys.argv:
        BASELINE.write_text(json.dumps({n: scores(n) for n in ("phd", "mt")}, indent=2,
                                       sort_keys=True) + "\n")
        print(BASELINE.read_text())
