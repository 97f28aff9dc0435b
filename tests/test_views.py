"""Views that tell the truth (issue 21): every stage tab shows its own entities, a palette that
separates ids alive together, the tabs listed by ``info --json``, video export, the web viewer,
quiet snapshots, events ordered for jumping."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from pfscope.viewer_app.cli import main

cv2 = pytest.importorskip("cv2")

from test_viewer_app import _toy  # noqa: E402 - the toy MOT folder (two squares)


def _record(tmp_path, tracker, frames=14, level="particles", source=None):
    out = tmp_path / f"{tracker}.rrd"
    args = ["record"] + ([str(source)] if source else []) + [
        "--tracker", tracker, "--frames", str(frames), "--level", level, "--out", str(out),
        "--quiet", "--force"]
    rc = main(args)
    return out if rc == 0 else None


def _tab_sets(info: dict) -> dict[str, set]:
    """Tab title -> the recorded entities the tab shows, beyond the shared video, detections
    and ground truth."""
    from pfscope.viewer_app.export import _matches
    from pfscope.viewer_app.tabs import BASE_2D

    ents = [e for e in info["entities"] if e.startswith("/video/")
            and e.lstrip("/") not in BASE_2D]
    return {t["title"]: {e for e in ents if _matches(e, t["entities"])} for t in info["tabs"]}


# ------------------------------------------------------------------ 1. stage tabs differ

@pytest.mark.parametrize("tracker", ["phd", "mt", "dlpf", "dbn-phd"])
def test_every_stage_tab_shows_entities_of_its_own(tmp_path, tracker, capsys):
    """Each declared stage tab shows recorded entities (non-empty) and not the same set as the
    tab before it: no tab looks like its neighbour unless the stage changed nothing."""
    from pfscope.viewer_app.info import recording_info

    out = _record(tmp_path, tracker)
    if out is None:
        err = capsys.readouterr().err.strip().splitlines()
        pytest.skip(f"{tracker} cannot run here: {err[-1] if err else '?'}")
    info = recording_info(out)
    sets = _tab_sets(info)
    titles = [t["title"] for t in info["tabs"] if t["title"] != "All stages"]
    assert len(titles) >= 2
    for t in titles:
        assert sets[t], f"{tracker}: tab {t!r} shows nothing of its own"
    for a, b in zip(titles, titles[1:]):
        assert sets[a] != sets[b], f"{tracker}: tabs {a!r} and {b!r} show the same entities"


def test_clusters_take_the_colour_of_their_track_and_births_are_marked(tmp_path):
    """PHD-MT: a kept cluster taken by a confirmed track is drawn in that track's colour
    (the same as the track's box), the others in the neutral grey; newborn particles are the
    white-ish birth class, apart from the survivors' weight colours."""
    from conftest import read_rrd
    from pfscope.viewer_app.reporters.base import ROLES

    out = _record(tmp_path, "phd", frames=25)
    rec = read_rrd(out)
    track_colours = {}
    for t, c in rec["/video/tracks"]:
        for i, col in zip(c.get("Boxes2D:labels") or [], c.get("Boxes2D:colors") or []):
            track_colours.setdefault(int(i), col)
    kept = [c for _, c in rec["/video/phd/clusters/kept"] if c.get("Boxes2D:colors")]
    assert kept
    rgb = {col >> 8 for c in kept for col in c["Boxes2D:colors"]}   # packed RGBA -> RGB
    grey = int.from_bytes(bytes(ROLES["unmatched"][1][:3]), "big")
    matched = rgb - {grey}
    assert matched and matched <= {v >> 8 for v in track_colours.values()}
    births = [c for _, c in rec["/video/phd/particles/birth"] if c.get("Points2D:class_ids")]
    assert births and all(c["Points2D:class_ids"] == [ROLES["birth"][0]] for c in births)


# ------------------------------------------------------------------ 2. palette

def test_palette_separates_fifty_ids_alive_together():
    from pfscope.viewer_app.colors import (RESERVED_RGB, TrackPalette, is_track_colour,
                                           min_distance, palette, srgb_to_oklab)

    rng = np.random.default_rng(3)
    # 50 ids alive at once, numbered anyhow (old long-lived ids among new ones)
    tp = TrackPalette()
    ids = rng.choice(100_000, 50, replace=False)
    assert min_distance(tp.colors(ids)[:, :3]) >= 0.045
    # few ids alive together (the usual case) are far apart: >= 8 JND
    tp = TrackPalette()
    assert min_distance(tp.colors(np.array([2, 7, 10, 31, 64, 128]))[:, :3]) >= 0.16
    # churn: ids come and go for 300 frames with 50 alive; ids alive together stay apart
    tp = TrackPalette()
    alive, nxt, worst = list(range(50)), 50, np.inf
    for f in range(300):
        tp.frame = f
        if f % 3 == 0:
            alive.pop(int(rng.integers(len(alive))))
            alive.append(nxt)
            nxt += 1
        worst = min(worst, min_distance(tp.colors(np.array(alive))[:, :3]))
    assert worst >= 0.04
    # an id keeps its colour
    assert np.array_equal(tp.colors(np.array([alive[0]])), tp.colors(np.array([alive[0]])))
    # every track colour is far from every reserved (semantic, viridis-yellow) colour
    lab = srgb_to_oklab(palette())
    res = srgb_to_oklab(np.array(RESERVED_RGB))
    assert np.linalg.norm(lab[:, None] - res[None], axis=2).min() >= 0.12
    assert all(is_track_colour(c) for c in palette())


def test_semantic_marks_are_distinct_and_drawn_over_tracks():
    from pfscope.viewer_app.colors import is_track_colour, srgb_to_oklab
    from pfscope.viewer_app.reporters.base import MARK_DRAW_ORDER, MARK_INFLATE, ROLES

    marks = ["detection", "gt", "miss", "false_positive", "switch", "birth", "hit"]
    lab = srgb_to_oklab(np.array([ROLES[m][1][:3] for m in marks]))
    d = np.linalg.norm(lab[:, None] - lab[None], axis=2) + np.eye(len(marks))
    assert d.min() >= 0.1, d.round(3)
    for m in marks:
        assert not is_track_colour(np.array(ROLES[m][1][:3])), m
    # false positives and switches sit outside the track box they mark, over it
    assert MARK_INFLATE["false_positive"] >= 3 and MARK_INFLATE["switch"] > \
        MARK_INFLATE["false_positive"] and MARK_DRAW_ORDER > 0


# ------------------------------------------------------------------ 5. info --json tabs

def test_info_json_lists_the_tabs_with_titles_and_entities(tmp_path, capsys):
    from pfscope.viewer_app.reporters import layout_for
    from pfscope.viewer_app.tabs import readme_table

    out = _record(tmp_path, "phd", frames=6)
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    tabs = json.loads(capsys.readouterr().out)["tabs"]
    views = layout_for("phd").views
    assert [t["title"] for t in tabs] == [t for t, _ in views] + ["All stages"]
    part = next(t for t in tabs if t["title"] == "Particles")
    assert "video/phd/particles/updated" in part["entities"]
    # the README's table comes from the same layouts
    table = readme_table(["phd"])
    notes = dict(layout_for("phd").notes)
    for title, paths in views:
        assert f"| phd | {title} | {notes[title]} | " + ", ".join(f"`{p}`" for p in paths) \
            in table


def test_compare_has_a_tab_per_stage_with_every_lane(tmp_path, capsys):
    from pfscope.viewer_app.info import recording_info

    out = tmp_path / "c.rrd"
    assert main(["compare", "--trackers", "phd,phd[p_miss=0.3]", "--frames", "8", "--level",
                 "particles", "--out", str(out), "--quiet"]) == 0
    info = recording_info(out)
    tabs = {t["title"]: t for t in info["tabs"]}
    for title in ("Particles", "Association", "Clusters"):
        lanes = [v["lane"] for v in tabs[title]["lanes"]]
        assert lanes == ["phd", "phd-p_miss-0.3"]
    ents = set(info["entities"])
    for lane in ("phd", "phd-p_miss-0.3"):
        assert f"/{lane}/video/phd/particles/updated" in ents
        assert f"/{lane}/video/assoc/edges/chosen" in ents


# ------------------------------------------------------------------ 6. export

def test_export_writes_one_video_frame_per_recorded_frame(tmp_path, capsys):
    from pfscope.viewer_app.export import Recording, render_frame

    out = tmp_path / "x.rrd"
    assert main(["record", str(_toy(tmp_path)), "--tracker", "phd", "--out", str(out),
                 "--quiet"]) == 0
    mp4 = tmp_path / "x.mp4"
    capsys.readouterr()
    assert main(["export", str(out), "--out", str(mp4), "--tab", "Tracks"]) == 0
    assert "wrote" in capsys.readouterr().out
    cap = cv2.VideoCapture(str(mp4))
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == 12
    # --frames: only those
    assert main(["export", str(out), "--out", str(tmp_path / "y.mp4"), "--frames", "3:7",
                 "--quiet"]) == 0
    cap = cv2.VideoCapture(str(tmp_path / "y.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 5
    # the frames are annotated: the drawn frame differs from the recorded picture
    rec = Recording(out, ["video/tracks/**"])
    tab = {"title": "Tracks", "entities": ["video/tracks/**"]}
    drawn = render_frame(rec, tab, 10)
    plain = cv2.imdecode(np.frombuffer(rec.video[10], np.uint8), cv2.IMREAD_COLOR)
    assert drawn.shape == plain.shape and np.abs(drawn.astype(int) - plain).sum() > 1000
    # an unknown tab: one line naming the tabs
    assert main(["export", str(out), "--out", str(tmp_path / "z.mp4"), "--tab", "Nope"]) == 2
    assert "Particles" in capsys.readouterr().err


# ------------------------------------------------------------------ 7. web viewer

def test_view_web_serves_the_file_over_http(tmp_path):
    out = tmp_path / "x.rrd"
    assert main(["record", str(_toy(tmp_path, n=4)), "--tracker", "passthrough", "--out",
                 str(out), "--quiet", "--level", "tracks"]) == 0
    exe = Path(sys.executable).with_name("pfscope")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "pfscope.viewer_app.cli"]
    proc = subprocess.Popen(cmd + ["view", str(out), "--web"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "RERUN_ANALYTICS": "0"})
    try:
        line = proc.stdout.readline()  # bounded by the server's own 30 s start-up limit
        url = re.search(r"http://127\.0\.0\.1:\d+/\S*", line)
        assert url, (line, proc.stderr.read() if proc.poll() is not None else "")
        with urllib.request.urlopen(url.group(0), timeout=10) as r:
            assert r.status == 200
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


# ------------------------------------------------------------------ 6. quiet snapshots

def test_snapshot_stderr_is_quiet_and_a_stage_can_be_pictured(tmp_path, capfd):
    from pfscope.viewer_app.snapshot import vulkan_problem

    problem = vulkan_problem()
    if problem:
        pytest.skip(problem)
    out = tmp_path / "x.rrd"
    assert main(["record", str(_toy(tmp_path)), "--tracker", "phd", "--out", str(out),
                 "--quiet"]) == 0
    capfd.readouterr()
    png = tmp_path / "s.png"
    rc = main(["snapshot", str(out), "--frames", "5:6", "--stage", "birth", "--out", str(png)])
    cap = capfd.readouterr()
    assert rc == 0, cap.err
    assert "\x1b" not in cap.err and "\x1b" not in cap.out
    assert cap.err.strip() == "" and len(cap.out.strip().splitlines()) == 1
    for f in (5, 6):
        data = (tmp_path / f"s-{f:06d}.png").read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["snapshot", str(out), "--stage", "nope", "--out", str(png)]) == 2
    assert "birth" in capfd.readouterr().err


# ------------------------------------------------------------------ 8. events

def test_worst_ospa_leaves_out_the_start_up_and_events_list_severe_first(tmp_path):
    from pfscope.trackers.eval import OnlineEvaluator
    from pfscope.trackers.eval.events import EventIndex
    from pfscope.trackers.types import GroundTruth, TrackSet
    from pfscope.viewer_app.info import recording_info

    ev, idx = OnlineEvaluator(), EventIndex(worst=5)
    gt = GroundTruth(np.array([1]), np.array([[10, 10, 20, 40]], float))
    for k in range(1, 12):
        # no track for the first 4 frames (start-up: OSPA at its cut-off), then a poor one
        tr = TrackSet(np.zeros(0, int), np.zeros((0, 4))) if k <= 4 else \
            TrackSet(np.array([3]), np.array([[10 + 3 * k, 10, 20, 40]], float))
        idx.update(k, gt, tr, ev.update(k, gt, tr))
    worst = [f for f, _ in idx.worst_frames()]
    assert worst and min(worst) >= 5 and idx.first_shown == 5

    out = tmp_path / "e.rrd"
    assert main(["record", str(_toy(tmp_path, swap_at=6)), "--tracker", "passthrough",
                 "--out", str(out), "--quiet", "--level", "tracks"]) == 0
    events = recording_info(out)["events"]["passthrough"]
    rank = {"ERROR": 0, "WARN": 1, "INFO": 2}
    keys = [(rank[e["level"]], e["frame"]) for e in events]
    assert keys == sorted(keys) and keys
    assert all(isinstance(e["track_ids"], list) for e in events)
