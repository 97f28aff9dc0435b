"""``pfscope batch --cluster ADDRESS`` (issue 10, item 7): the same batch on an existing Dask
distributed cluster, here a ``LocalCluster`` of two worker processes started by the test —
the same files and summary, a failing run does not stop the others, resume skips."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest

from pfscope.viewer_app.cli import main


def test_batch_on_a_local_dask_cluster_writes_the_summary_and_resumes(tmp_path, capsys):
    try:
        from dask.distributed import LocalCluster
    except ImportError as e:
        pytest.skip(f"Dask distributed is not installed ({e}): pip install \"pfscope[distributed]\"")
    out = tmp_path / "runs"
    missing = tmp_path / "missing"
    argv = ["batch", "--sources", f"synthetic,{missing}", "--trackers", "phd,mt",
            "--seeds", "0,1", "--frames", "10", "--out", str(out)]
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                      dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        assert main(argv + ["--cluster", address]) == 1  # the missing source fails, alone
        cap = capsys.readouterr()
        assert f"Dask cluster {address}" in cap.err and "(2 worker thread(s))" in cap.err
        runs = json.loads((out / "summary.json").read_text())["runs"]
        status = {r["run"]: r["status"] for r in runs}
        ok = [f"synthetic-seed{s}-{t}-seed{s}" for t in ("phd", "mt") for s in (0, 1)]
        assert status == {**{r: "ok" for r in ok},
                          **{f"missing-{t}-seed{s}": "failed"
                             for t in ("phd", "mt") for s in (0, 1)}}
        for r in runs:
            if r["status"] == "ok":
                assert r["frames"] == 10 and r["source"] == "synthetic"
                for suffix in (".rrd", ".txt", ".json"):
                    assert (out / f"{r['run']}{suffix}").is_file(), (r["run"], suffix)
            else:
                assert "missing" in r["error"]
        assert all(r in (out / "summary.csv").read_text() for r in ok)
        assert "missing-phd-seed0 failed" in cap.err

        # resume: same command, the finished runs are skipped; only the ok ones this time
        mtimes = {r: (out / f"{r}.rrd").stat().st_mtime_ns for r in ok}
        assert main(["batch", "--sources", "synthetic", "--trackers", "phd,mt", "--seeds", "0,1",
                     "--frames", "10", "--out", str(out), "--backend", "dask",
                     "--cluster", address, "--json"]) == 0
        cap = capsys.readouterr()
        assert f"4 runs, 4 already finished, 0 to run on Dask cluster {address}" in cap.err
        assert {r["status"] for r in json.loads(cap.out)} == {"skipped"}
        assert mtimes == {r: (out / f"{r}.rrd").stat().st_mtime_ns for r in ok}


def test_cluster_without_dask_says_how_to_install_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # import fails like when absent
    argv = ["batch", "--trackers", "passthrough", "--frames", "3", "--out", str(tmp_path / "o"),
            "--cluster", "tcp://127.0.0.1:1"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'pip install "pfscope[distributed]"' in err[0]
    assert not list((tmp_path / "o").glob("*.rrd"))


def test_backend_dask_needs_a_cluster_address(tmp_path, capsys):
    assert main(["batch", "--backend", "dask", "--out", str(tmp_path / "o")]) == 2
    assert "--backend dask needs --cluster" in capsys.readouterr().err


@pytest.mark.slow
def test_sigterm_stops_a_dask_batch_and_the_same_command_resumes(tmp_path):
    """Ctrl-C or `kill PID` on a batch running on a Dask cluster: queued runs never start,
    running ones stop at their next frame (files kept as *.incomplete.*), the summary says so,
    the exit status is 128 + signal, and nothing keeps running on the cluster for this batch."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as e:
        pytest.skip(f"Dask distributed is not installed ({e})")
    from test_jobs import (_running, _signal_when_running, _start, _summary, _wait_for,
                           _wait_group_gone)

    out = tmp_path / "runs"
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        argv = [sys.executable, "-m", "pfscope.viewer_app.cli", "batch", "--sources",
                "synthetic", "--trackers", "passthrough", "--seeds", "0,1,2", "--frames",
                "1200", "--out", str(out), "--cluster", cluster.scheduler_address]
        p = _start(argv)
        err, stopped_in = _signal_when_running(p, out, 2, 180)
        assert p.returncode == 143, err
        assert "Traceback" not in err and "stopped by SIGTERM" in err, err
        assert stopped_in < 40
        assert _wait_group_gone(p.pid, 10)
        status = _summary(out)
        assert sorted(status.values()) == ["interrupted", "interrupted", "not run"], status
        assert len(_running(out)) == 2 and not list(out.glob("*-seed?.json"))
        # the cluster is idle: the runs stopped, they did not go on writing into --out
        assert _wait_for(lambda: not any(client.processing().values()), 10), \
            client.processing()
        listing = sorted(f.name for f in out.iterdir())
        time.sleep(2.0)
        assert sorted(f.name for f in out.iterdir()) == listing

        # the same command resumes to completion
        r = subprocess.run(argv, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        assert "3 runs, 0 already finished, 3 to run" in r.stderr
        assert set(_summary(out).values()) == {"ok"}
        assert not _running(out)
