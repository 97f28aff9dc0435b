"""Smoke test of the benchmark harness (benchmarks/bench.py): it runs end to end on a tiny
configuration through the shared pipeline and writes JSON holding every section's numbers.
Plus the pieces the numbers rest on: the many-target scene and the log-log exponent fit."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"


@pytest.fixture(scope="module")
def common():
    sys.path.insert(0, str(BENCH))
    try:
        import _common

        yield _common
    finally:
        sys.path.remove(str(BENCH))


def test_targets_scene_is_seeded_and_keeps_every_target_in_view(common):
    a = common.targets_scene(16, 40, seed=3)
    b = common.targets_scene(16, 40, seed=3)
    c = common.targets_scene(16, 40, seed=4)
    assert np.array_equal(a.det.boxes, b.det.boxes) and np.array_equal(a.gt.boxes, b.gt.boxes)
    assert not np.array_equal(a.gt.boxes, c.gt.boxes)
    assert len(a.gt) == 16 * 40                       # every target on every frame
    g = a.gt.boxes
    assert (g[:, 0] >= -1e-9).all() and (g[:, 1] >= -1e-9).all()
    assert (g[:, 0] + g[:, 2] <= a.width + 1e-6).all()
    assert (g[:, 1] + g[:, 3] <= a.height + 1e-6).all()
    # detected about p_D of the time, plus Poisson(5) clutter per frame
    det_per_frame = len(a.det) / 40
    assert 0.9 * 16 + 5 - 4 < det_per_frame < 0.9 * 16 + 5 + 4
    # density fixed: the image area grows with the targets
    big = common.targets_scene(64, 2, seed=3)
    assert big.width * big.height == pytest.approx(4 * a.width * a.height, rel=0.02)


def test_loglog_slope_recovers_the_exponent(common):
    x = np.array([4, 16, 64, 256])
    assert common.loglog_slope(x, 3.0 * x ** 1.0) == pytest.approx(1.0)
    assert common.loglog_slope(x, 0.2 * x ** 2.3) == pytest.approx(2.3)
    assert math.isnan(common.loglog_slope([4], [1.0]))


def test_bench_runs_tiny_and_writes_json(tmp_path):
    out = tmp_path / "bench.json"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, str(BENCH / "bench.py"), "--tiny", "--trackers", "phd",
                        "mt", "--out", str(out)], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "not timed" not in r.stderr                 # every PHD-MT stage has its clock
    d = json.loads(out.read_text())
    assert d["mode"] == "tiny" and d["machine"]["cores"] >= 1
    s = d["sections"]
    assert set(s) == {"stages", "scaling", "recording", "memory", "stonesoup"}

    st = s["stages"]["trackers"]
    assert set(st) == {"phd", "mt"}
    phd = st["phd"]["stages_median_ms"]
    assert list(phd) == ["predict", "birth", "update", "resample", "cluster", "associate"]
    assert all(v > 0 for v in phd.values())
    assert sum(phd.values()) <= st["phd"]["step_median_ms"] * 1.5

    sc = s["scaling"]
    assert [row["targets"] for row in sc["rows"]] == [4, 8]
    assert all(row["particles_in_update"] > 0 for row in sc["rows"])
    assert math.isfinite(sc["exponent"]["step"])

    rec = s["recording"]["levels"]
    sizes = [rec[lv]["bytes_per_frame"] for lv in ("tracks", "clusters", "particles")]
    assert sizes[0] > 0 and sizes[2] > sizes[0]        # particles add point clouds
    assert all(rec[lv]["ratio_to_unrecorded"] > 0 for lv in ("tracks", "clusters", "particles"))

    mem = s["memory"]
    assert mem["frame"] == [1, 10, 20, 30] and all(v > 0 for v in mem["rss_mb"])
    assert mem["peak_rss_mb"] >= max(mem["rss_mb"]) * 0.9

    ss = s["stonesoup"]
    try:
        import stonesoup  # noqa: F401
    except ImportError:
        assert ss["skipped"].startswith("Stone Soup comparison skipped")
        assert "Stone Soup comparison skipped" in r.stdout
    else:
        row = ss["rows"][0]
        assert row["targets"] == 4
        # same particle budget: the Stone Soup lanes updated as many particles as PHD-MT
        assert row["particles_in_update"] > 0
        assert row["budget_max_abs_diff"] <= 2
        assert row["ss_noise_ms"] > 0 and row["ss_nonoise_ms"] > 0
        for v in row["ospa_mean"].values():
            assert 0 <= v <= 100
        assert set(row["mean_mass"]) == {"pf", "ss_noise", "ss_nonoise"}
