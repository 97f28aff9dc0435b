"""``pfscope batch --backend ray`` (issue 10, item 7): the same batch as Ray tasks on a local Ray
instance started by the test (``ray.init(num_cpus=1)``) — the same files and summary, a failing
run does not stop the others, resume skips — and the one-line errors around it."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from pfscope.trackers.errors import InputError
from pfscope.viewer_app.batch import _pick_backend
from pfscope.viewer_app.cli import main


@pytest.fixture(scope="module")
def local_ray():
    try:
        import ray
    except ImportError as e:
        pytest.skip(f"Ray is not installed ({e}): pip install \"pfscope[ray]\"")
    if ray.is_initialized():  # pragma: no cover - another test left one running
        ray.shutdown()
    import logging

    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False,
             logging_level=logging.WARNING)
    try:
        yield ray
    finally:
        ray.shutdown()


def test_batch_as_ray_tasks_writes_the_summary_and_resumes(tmp_path, capsys, local_ray):
    out = tmp_path / "runs"
    missing = tmp_path / "missing"
    argv = ["batch", "--sources", f"synthetic,{missing}", "--trackers", "phd,mt",
            "--seeds", "0", "--frames", "6", "--out", str(out), "--backend", "ray"]
    assert main(argv) == 1  # the missing source fails, alone
    cap = capsys.readouterr()
    assert "on Ray the connected Ray cluster (1 CPU(s))" in cap.err
    runs = json.loads((out / "summary.json").read_text())["runs"]
    status = {r["run"]: r["status"] for r in runs}
    ok = [f"synthetic-seed0-{t}-seed0" for t in ("phd", "mt")]
    assert status == {**{r: "ok" for r in ok},
                      **{f"missing-{t}-seed0": "failed" for t in ("phd", "mt")}}
    for r in runs:
        if r["status"] == "ok":
            assert r["frames"] == 6 and r["source"] == "synthetic"
            for suffix in (".rrd", ".txt", ".json"):
                assert (out / f"{r['run']}{suffix}").is_file(), (r["run"], suffix)
        else:
            assert "missing" in r["error"]
    assert "missing-phd-seed0 failed" in cap.err

    # resume: the finished runs are skipped, nothing is rewritten
    mtimes = {r: (out / f"{r}.rrd").stat().st_mtime_ns for r in ok}
    assert main(["batch", "--sources", "synthetic", "--trackers", "phd,mt", "--seeds", "0",
                 "--frames", "6", "--out", str(out), "--backend", "ray", "--json"]) == 0
    cap = capsys.readouterr()
    assert "2 runs, 2 already finished, 0 to run on Ray" in cap.err
    assert {r["status"] for r in json.loads(cap.out)} == {"skipped"}
    assert mtimes == {r: (out / f"{r}.rrd").stat().st_mtime_ns for r in ok}


def test_backend_ray_without_ray_says_how_to_install_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import fails like when absent
    argv = ["batch", "--trackers", "passthrough", "--frames", "3", "--out", str(tmp_path / "o"),
            "--backend", "ray"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'pip install "pfscope[ray]"' in err[0]
    assert not list((tmp_path / "o").glob("*.rrd"))


def test_a_ray_address_picks_the_ray_backend():
    assert _pick_backend(None, "ray://head:10001") == ("ray://head:10001", "ray")
    assert _pick_backend(None, "tcp://head:8786") == ("tcp://head:8786", "dask")
    assert _pick_backend("ray", None) == (None, "ray")
    assert _pick_backend(None, None) == (None, "local")
    with pytest.raises(InputError, match="Ray address"):
        _pick_backend("dask", "ray://head:10001")


@pytest.mark.slow
def test_sigterm_stops_a_ray_batch_and_the_same_command_resumes(tmp_path):
    """`kill PID` (SIGTERM to the batch alone, not to Ray's workers) on a batch that started its
    own Ray instance: queued tasks are cancelled, running ones stop at once with their files
    kept as *.incomplete.* (well before the grace period that would cancel them by force), the
    summary says so, exit 143, and no process of the batch (Ray's included) outlives it."""
    from pfscope.viewer_app.batch import CLUSTER_GRACE

    pytest.importorskip("ray")
    from test_jobs import _running, _signal_when_running, _start, _summary, _wait_group_gone

    out = tmp_path / "runs"
    argv = [sys.executable, "-m", "pfscope.viewer_app.cli", "batch", "--sources", "synthetic",
            "--trackers", "passthrough", "--seeds", "0,1,2", "--frames", "1200", "--out",
            str(out), "--backend", "ray"]
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    p = _start(argv)
    err, stopped_in = _signal_when_running(p, out, 1, 240)
    assert p.returncode == 143, err
    assert "Traceback" not in err and "stopped by SIGTERM" in err, err
    assert stopped_in < CLUSTER_GRACE - 3
    assert _wait_group_gone(p.pid, 20), "a process of the batch outlived it"
    status = _summary(out)
    assert "not run" in status.values() and "ok" not in status.values(), status
    assert set(status.values()) <= {"interrupted", "not run"}, status
    assert len(_running(out)) == list(status.values()).count("interrupted")

    r = subprocess.run(argv, capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, r.stderr
    assert set(_summary(out).values()) == {"ok"}
    assert not _running(out)
