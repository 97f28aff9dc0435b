"""Type-check the engine's public API and the trackers' conformance to the Tracker protocol
with mypy, so that protocol drift fails CI (not a user's run)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from conftest import REPO

pytest.importorskip("mypy")

MODULES = ("pfscope.trackers.api", "pfscope.trackers.pipeline", "pfscope.trackers.report",
           "pfscope.trackers.params")


def _mypy(tmp_path, *args) -> subprocess.CompletedProcess:
    # mypy cannot see through setuptools' editable finder, so give it the installed layout:
    # pfscope/trackers -> trackers/, pfscope/viewer_app -> viewer_app/ (a namespace package).
    ns = tmp_path / "layout" / "pfscope"
    ns.mkdir(parents=True, exist_ok=True)
    (ns / "trackers").symlink_to(REPO / "trackers")
    (ns / "viewer_app").symlink_to(REPO / "viewer_app")
    env = {"MYPYPATH": str(ns.parent), "PATH": "/usr/bin:/bin"}
    return subprocess.run([sys.executable, "-m", "mypy", "--follow-imports=silent",
                           "--ignore-missing-imports",
                           # one cache for the session's runs (numpy's stubs dominate the time)
                           "--cache-dir", str(tmp_path.parent.parent / "mypy-cache"), *args],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=300)


def test_engine_api_and_tracker_conformance_type_check(tmp_path):
    args = []
    for m in MODULES:
        args += ["-p", m]
    r = _mypy(tmp_path, *args)
    assert r.returncode == 0, r.stdout + r.stderr
    r = _mypy(tmp_path / "2", "tests/typing/conformance.py")
    assert r.returncode == 0, r.stdout + r.stderr


def test_the_type_check_catches_a_tracker_that_drifts(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(
        "from typing import Optional\n"
        "from pfscope.trackers.api import Tracker, StepResult\n"
        "class Old:\n"
        "    name = 'old'; paper = '-'; stages = ('a',)\n"
        "    needs_detections = True; needs_image = False\n"
        "    def step(self, frame, detections, obs) -> StepResult: ...\n"  # old push signature
        "    def finish(self) -> list: ...\n"
        "    def config(self) -> dict: ...\n"
        "t: Tracker = Old()\n")
    r = _mypy(tmp_path, str(bad))
    assert r.returncode != 0 and "Tracker" in r.stdout, r.stdout + r.stderr
