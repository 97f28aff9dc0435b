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
def bench_path():
    sys.path.insert(0, str(BENCH))
    try:
        yield
    finally:
        sys.path.remove(str(BENCH))


@pytest.fixture(scope="module")
def common(bench_path):
    import _common

    return _common


@pytest.fixture(scope="module")
def bench(bench_path):
    import bench

    return bench


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
        lanes = {"ss_noise", "ss_nonoise", "ss_oracle", "ss_oracle-birth", "ss_standard"}
        assert set(row["mean_mass"]) == {"pf"} | lanes
        assert set(row["ospa_mean"]) == {"pf_tracks", "pf_live", "pf_clusters",
                                         "pf_kmeans"} | lanes
        for parts in row["parts_mean"].values():     # OSPA = localisation + cardinality
            assert parts["ospa"] == pytest.approx(parts["loc"] + parts["card"])
        assert ss["warmup"] == 2 and ss["frames"] == 8
        seed0 = row["seeds"][0]
        assert len(seed0["per_frame"]["pf_tracks"]["ospa"]) == 8
        assert seed0["truth"]["p_detect"] == 0.9 and seed0["truth"]["targets"] == 4


def test_scene_truth_matches_the_scene(common):
    """The true model given to the oracle Stone Soup lanes is the one targets_scene draws
    from: clutter sizes inside the stated support, its rate, and the box noise."""
    cl = common.targets_scene(4, 400, seed=1, p_detect=0.0)           # clutter only
    w, h = cl.det.boxes[:, 2], cl.det.boxes[:, 3]
    (w0, w1), (a0, a1) = common.CLUTTER_W, common.CLUTTER_ASPECT
    assert w.min() >= w0 and w.max() <= w1
    assert (h / w).min() >= a0 - 1e-9 and (h / w).max() <= a1 + 1e-9
    assert len(cl.det) / 400 == pytest.approx(5.0, rel=0.1)
    truth = common.scene_truth(cl)
    assert common.clutter_size_area() == pytest.approx(1687.5)
    assert truth["clutter_density"] == pytest.approx(
        5.0 / (cl.width * cl.height * 1687.5), rel=1e-9)
    tg = common.targets_scene(4, 400, seed=1, p_detect=1.0, clutter=0.0)  # targets only
    err = (tg.det.boxes - tg.gt.boxes) / np.tile(tg.gt.boxes[:, 2:4], 2)
    assert err.std(axis=0) == pytest.approx([common.BOX_NOISE] * 4, rel=0.1)


def test_ospa_parts_add_up_to_ospa(common):
    from pfscope.trackers.eval.ospa import ospa

    rng = np.random.default_rng(0)
    for m, k in ((0, 0), (0, 3), (4, 0), (3, 5), (6, 2), (5, 5)):
        x, y = rng.uniform(0, 300, (m, 2)), rng.uniform(0, 300, (k, 2))
        p = common.ospa_parts(x, y, 100.0)
        assert p["ospa"] == pytest.approx(ospa(x, y, 100.0, 1.0))
        assert p["ospa"] == pytest.approx(p["loc"] + p["card"])
        assert (p["est"], p["true"]) == (m, k)
        assert p["card"] == pytest.approx(100.0 * abs(m - k) / max(m, k, 1))


@pytest.fixture(scope="module")
def bench(common):
    import bench

    return bench


def test_stonesoup_options_override_the_mode(bench, capsys):
    a = bench.parse_args(["--quick", "--ss-targets", "8", "--ss-frames", "30", "--ss-warmup",
                          "5", "--ss-seeds", "3", "4", "--ss-lanes", "oracle", "oracle"])
    assert (a.ss_targets, a.ss_frames, a.ss_warmup, a.ss_seeds, a.ss_lanes) == (
        [8], 30, 5, [3, 4], ["oracle"])
    d = bench.parse_args([])
    assert d.ss_frames >= 60 and d.ss_targets == [4, 16, 64] and d.ss_seeds == [0, 1, 2]
    for bad in (["--ss-frames", "10", "--ss-warmup", "10"], ["--ss-targets", "0"],
                ["--ss-lanes", "bogus"]):
        with pytest.raises(SystemExit) as e:
            bench.parse_args(bad)
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert "error:" in err[-1]                     # argparse's one-line error


def test_oracle_births_count_the_targets_where_pfscope_births_count_the_clutter(bench):
    """Given the true κ and p_D but pfscope's birth mass (0.01 per detection), Stone Soup makes
    nearly every clutter detection a target; with the true births too its mass follows the
    true count."""
    pytest.importorskip("stonesoup")
    r = bench.ss_run(4, 30, 0, ["oracle", "oracle-birth"], "paper")
    m = {k: float(np.mean(v[10:])) for k, v in r["mass"].items()}
    assert m["ss_oracle"] > 1.5 * 4
    assert 0.75 * 4 < m["ss_oracle-birth"] < 1.25 * 4


def test_scene_truth_birth_rate_counts_the_newcomers(common):
    """The true birth rate given to the lanes with true births: none on targets_scene (every
    target stays), the new ids per frame on births_scene."""
    assert common.scene_truth(common.targets_scene(4, 50, seed=0))["birth_rate"] == 0.0
    src = common.births_scene(16, 200, seed=0)
    gt = src.gt
    new = len(set(gt.id.tolist())) - int(np.sum(gt.frame == 1))
    rate = common.scene_truth(src)["birth_rate"]
    assert rate == pytest.approx(new / 199) and rate > 0.05


def test_per_measurement_estimates_take_the_detections_above_half_a_target(common):
    """Stone Soup lane's per-measurement extraction (Ristic et al. 2010): a detection whose
    share of the updated PHD exceeds 0.5 gives one estimate at its weighted particle mean;
    one below gives none, and the missed-detection column never does."""
    pytest.importorskip("stonesoup")
    import _stonesoup as S

    class Pred:                       # state (x, vx, y, vy, w, h) x 4 particles
        state_vector = np.array([[10.0, 30.0, 100.0, 200.0], [0] * 4, [20.0, 40.0, 5.0, 5.0],
                                 [0] * 4, [30.0] * 4, [80.0] * 4])

    w = np.zeros((4, 3))
    w[:, 0] = [0.9, 0.9, 0.9, 0.9]    # missed detection: 3.6 of mass, never an estimate
    w[:, 1] = [0.3, 0.3, 0.0, 0.0]    # detection 1 owns 0.6 of the two first particles
    w[:, 2] = [0.0, 0.0, 0.2, 0.2]    # detection 2 owns 0.4: below half a target
    with np.errstate(divide="ignore"):
        est = S._per_measurement(Pred, np.log(w), 0.5)
    np.testing.assert_allclose(est, [[20.0, 30.0]])
    with np.errstate(divide="ignore"):
        assert len(S._per_measurement(Pred, np.log(w), 0.3)) == 2


def test_detector_free_fps_missing_data_is_said_or_an_error(bench, monkeypatch, capsys):
    """endtoend's detector-free part never skips silently: without PETS09-S2L1 a NOT RUN line
    (and ``skipped`` in the JSON) by default, and the error when the trackers were named."""
    import argparse

    def missing():
        raise bench.C.NoData("PETS09-S2L1 not found (looked in /nowhere)")

    monkeypatch.setattr(bench.C, "pets_path", missing)
    args = argparse.Namespace(e2e_detector_free=["dlpf"], e2e_detector_free_asked=False,
                              e2e_pets_frames=3, seed=0)
    d = bench.detector_free_section(args)
    assert d == {"skipped": "PETS09-S2L1 not found (looked in /nowhere)"}
    assert "NOT RUN: PETS09-S2L1 not found" in capsys.readouterr().out
    args.e2e_detector_free_asked = True
    with pytest.raises(bench.C.NoData):
        bench.detector_free_section(args)


def test_detector_free_fps_and_stage_profile_of_a_fresh_process(bench, capsys):
    """The whole-process fps of `pfscope record PETS09-S2L1 --tracker dbn-phd --level tracks`
    (a fresh process) and its per-stage profile: every declared stage timed on every frame."""
    import argparse
    try:
        bench.C.pets_path()
    except bench.C.NoData as e:
        pytest.skip(str(e))
    from pfscope.trackers.api import make_tracker

    args = argparse.Namespace(e2e_detector_free=["dbn-phd"], e2e_detector_free_asked=True,
                              e2e_pets_frames=4, seed=0)
    d = bench.detector_free_section(args)["trackers"]["dbn-phd"]
    assert d["frames"] == 4
    assert list(d["stages_mean_ms"]) == list(make_tracker("dbn-phd", 0).stages)
    assert all(v > 0 for v in d["stages_mean_ms"].values())
    assert sum(d["stages_mean_ms"].values()) <= 1.5 * d["step_mean_ms"]
    assert 0 < d["loop_seconds"] < d["process_seconds"]
    assert d["fps_process"] == pytest.approx(4 / d["process_seconds"])
    out = capsys.readouterr().out
    assert "fps (whole process)" in out and "dbn-phd: ms per frame of each step stage" in out
