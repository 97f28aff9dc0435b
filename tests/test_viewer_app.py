"""The viewer app (issue 10): recordings that explain themselves (typed properties, the About
note, final scores, ``pfscope info``), the failure index, what-if lanes on a frame range, the
Python API (``import pfscope``), batch runs (a failing run, resume), snapshots, colours."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import read_rrd, rows_at
from pfscope.trackers.eval import OnlineEvaluator
from pfscope.trackers.eval.events import EventIndex
from pfscope.trackers.types import GroundTruth, TrackSet
from pfscope.viewer_app.cli import main

cv2 = pytest.importorskip("cv2")


def _toy(tmp_path, n=12, swap_at=None, name="toy"):
    """Two squares moving right (gt ids 1, 2); detections listed in gt order, reversed from
    frame ``swap_at`` on, so the pass-through tracker (ids = detection order) switches ids."""
    root = tmp_path / name
    for d in ("img1", "det", "gt"):
        (root / d).mkdir(parents=True)
    det, gtl = [], []
    for k in range(1, n + 1):
        img = np.full((80, 120, 3), 30, np.uint8)
        boxes = [(5 + 3 * k, 10), (5 + 3 * k, 45)]
        for x, y in boxes:
            img[y:y + 20, x:x + 10] = 220
        cv2.imwrite(str(root / "img1" / f"{k:06d}.jpg"), img)
        order = boxes[::-1] if swap_at and k >= swap_at else boxes
        det += [f"{k},-1,{x},{y},10,20,0.9,-1,-1,-1" for x, y in order]
        gtl += [f"{k},{i},{x},{y},10,20,1,1,1" for i, (x, y) in enumerate(boxes, start=1)]
    (root / "seqinfo.ini").write_text(
        f"[Sequence]\nname={name}\nimDir=img1\nframeRate=5\nseqLength={n}\nimWidth=120\n"
        "imHeight=80\nimExt=.jpg\n")
    (root / "det" / "det.txt").write_text("\n".join(det) + "\n")
    (root / "gt" / "gt.txt").write_text("\n".join(gtl) + "\n")
    return root


# ------------------------------------------------------------------ 1. self-explaining recordings

def test_recording_carries_typed_properties_about_note_and_scores(tmp_path, capsys):
    import pfscope

    out = tmp_path / "x.rrd"
    res = pfscope.record(_toy(tmp_path, swap_at=6), tracker="passthrough", out=out,
                         level="tracks", tracks_out=tmp_path / "x.txt", min_score=0.5)
    assert res.out == out and res.frames == 12 and res.tracks_out.exists()
    assert res.fps > 0 and res.paths["recording"] == out
    assert set(res.scores) == {"passthrough"} and "MOTA" in res.scores["passthrough"]
    rec = read_rrd(out)
    run = rec["/__properties/run"][0][1]
    assert run["seed"] == [0] and run["first_frame"] == [1] and run["frames"] == [12]
    assert run["level"] == ["tracks"] and run["trackers"] == ["passthrough"]
    src = rec["/__properties/source"][0][1]
    assert src["width"] == [120] and src["fps"] == [5.0] and src["has_gt"] == [True]
    params = rec["/__properties/tracker.passthrough"][0][1]
    assert params["params.min_score"] == [float("-inf")]  # typed, not a JSON string
    scores = rec["/__properties/scores.passthrough"][0][1]
    assert scores["MOTA"] == [pytest.approx(res.scores["passthrough"]["MOTA"])]
    about = rec["/about"][0][1]["TextDocument:text"][0]
    assert "## Video tabs" in about and "Misses: red" in about
    # pfscope info, text and JSON
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    for needle in ("source:    toy", "seed 0", "12 (1..12)", "MOTA", "rerun-sdk 0.41",
                   "min_score = -inf", "ID switch at frame 6"):
        assert needle in text, needle
    assert main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == {"count": 12, "first": 1, "last": 12}
    assert info["lanes"]["passthrough"]["tracker"] == "passthrough"
    assert info["scores"]["passthrough"]["IDSW"] == res.scores["passthrough"]["IDSW"]
    assert "/video/tracks" in info["entities"] and info["bytes"] > 0
    # view without a display: one line saying how
    assert main(["view", str(out)]) == 0
    line = capsys.readouterr().out.strip()
    assert "\n" not in line and "rerun" in line


def test_info_names_the_preset_a_run_used(tmp_path, capsys):
    """Without --preset the recording names the preset the tracker ran (PHD-MT's first one,
    `practical`), not "default"; with --preset, that one."""
    for preset, want in ((None, "practical"), ("paper", "paper")):
        out = tmp_path / f"{want}.rrd"
        args = ["record", str(_toy(tmp_path, n=4, name=want)), "--out", str(out), "--quiet",
                "--level", "tracks"] + (["--preset", preset] if preset else [])
        assert main(args) == 0
        capsys.readouterr()
        assert read_rrd(out)["/__properties/run"][0][1]["preset"] == [want]
        assert main(["info", str(out)]) == 0
        assert f"preset {want};" in capsys.readouterr().out


def test_info_on_a_missing_file_is_one_line(tmp_path, capsys):
    assert main(["info", str(tmp_path / "nope.rrd")]) == 2
    assert "no such recording" in capsys.readouterr().err


# ------------------------------------------------------------------ 3. the failure index

def _gt(ids, boxes):
    return GroundTruth(np.asarray(ids), np.asarray(boxes, dtype=float))


def test_event_index_finds_switch_lost_false_track_long_miss_and_worst_frames():
    ev, idx = OnlineEvaluator(), EventIndex(long_miss=5, min_track_life=3, track_gap=1,
                                            worst=2)
    found = []
    a, b = [10, 10, 20, 40], [200, 10, 20, 40]
    for k in range(1, 13):
        gt = _gt([1, 2], [a, b])                     # gt 2 is never tracked: a long miss
        if k <= 5:
            tracks = TrackSet(np.array([1]), np.array([a], float))
        else:                                        # from frame 6, track 7 takes over gt 1
            tracks = TrackSet(np.array([7, 9]), np.array([a, [100, 60, 20, 40]], float))
        m = ev.update(k, gt, tracks)
        found += idx.update(k, gt, tracks, m)
    found += idx.finish()
    kinds = {(e.kind, e.frame) for e in found}
    assert ("id_switch", 6) in kinds
    sw = next(e for e in found if e.kind == "id_switch")
    assert sw.track_ids == (1, 7) and sw.gt_ids == (1,) and "track 1 to track 7" in sw.message
    assert ("lost_track", 5) in kinds                 # track 1 ended while gt 1 stayed
    assert ("false_track", 6) in kinds                # track 9 never matched
    miss = next(e for e in found if e.kind == "long_miss")
    assert miss.gt_ids == (2,) and (miss.frame, miss.last_frame) == (1, 12)
    assert idx.counts == {"id_switch": 1, "false_track": 1, "lost_track": 1, "long_miss": 1}
    worst = idx.worst_frames()
    assert len(worst) == 2 and worst[0][1] >= worst[1][1]


def test_recording_holds_the_events_index_at_the_right_frames(tmp_path):
    from pfscope.viewer_app.api import record

    out = tmp_path / "e.rrd"
    record(_toy(tmp_path, swap_at=6), tracker="passthrough", out=out, level="tracks")
    rec = read_rrd(out)
    at6 = [{k.rsplit(":", 1)[-1]: v[0] for k, v in c.items()}
           for t, c in rec["/events"] if t["frame"] == 6]
    # a short body; the ids in their own columns; the full sentence kept beside
    sw = [c for c in at6 if c["kind"] == "id_switch"]
    assert sw and all(c["text"] == "id switch, frame 6" for c in sw)
    assert {(c["gt_ids"], c["track_ids"]) for c in sw} <= {("1", "1 2"), ("2", "2 1")}
    assert all("ID switch at frame 6" in c["message"] for c in sw)
    worst = [c["TextLog:text"][0] for _, c in rec["/events/worst_ospa"]]
    assert worst and worst[0].startswith("worst OSPA #1")


# ------------------------------------------------------------------ 4. what-if lanes, frame range

def test_compare_variants_as_named_lanes_on_a_frame_range(tmp_path, capsys):
    out = tmp_path / "c.rrd"
    rc = main(["compare", str(_toy(tmp_path)), "--trackers",
               "passthrough,passthrough[min_score=0.95]", "--frames", "4:9", "--out", str(out),
               "--quiet", "--json"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    scores = json.loads(captured.out)
    assert set(scores) == {"passthrough", "passthrough-min_score-0.95"}
    assert scores["passthrough"]["num_frames"] == 6
    assert scores["passthrough-min_score-0.95"]["FN"] == 12  # every detection dropped
    rec = read_rrd(out)
    assert sorted({t["frame"] for t, _ in rec["/video"]}) == [4, 5, 6, 7, 8, 9]
    assert rows_at(rec, "/passthrough-min_score-0.95/video/tracks", 5)
    lane = rec["/__properties/tracker.passthrough-min_score-0.95"][0][1]
    assert lane["params.min_score"] == [0.95] and lane["spec"] == ["passthrough[min_score=0.95]"]


def test_lane_specs():
    from pfscope.trackers.errors import InputError
    from pfscope.viewer_app.lanes import parse_lanes, split_specs

    assert split_specs("phd,phd[p_miss=0.2,depth=3],mt") == ["phd", "phd[p_miss=0.2,depth=3]",
                                                             "mt"]
    lanes = parse_lanes("phd,phd[p_miss=0.2;depth=3]")
    assert lanes[1].name == "phd-p_miss-0.2-depth-3" and lanes[1].tracker == "phd"
    assert lanes[1].options == {"p_miss": "0.2", "depth": "3"}
    with pytest.raises(InputError, match="twice"):
        parse_lanes("phd,phd")
    with pytest.raises(InputError):
        parse_lanes("phd[p_miss]")


# ------------------------------------------------------------------ 5. streaming API

def test_stream_yields_frames_from_start_without_recording(tmp_path):
    import pfscope

    root = _toy(tmp_path, swap_at=6)
    got = [(fr.index, fr.tracks.ids.tolist(), fr.metrics.idsw)
           for fr in pfscope.stream(root, tracker="passthrough", start=4, frames=5)]
    assert [g[0] for g in got] == [4, 5, 6, 7, 8]
    assert got[2][2] == 2  # the swap at frame 6 is two ID switches
    it = pfscope.stream(root, tracker="passthrough")
    assert next(it).index == 1
    it.close()  # leaving early stops the helper thread
    assert not list(tmp_path.rglob("*.rrd"))


# ------------------------------------------------------------------ 6. batch

def test_batch_reports_a_failing_run_keeps_going_and_resumes(tmp_path, capsys):
    good = _toy(tmp_path, n=5)
    out = tmp_path / "runs"
    argv = ["batch", "--sources", f"{good},{tmp_path / 'missing'}", "--trackers",
            "passthrough", "--seeds", "0", "--out", str(out), "--workers", "2", "--quiet"]
    assert main(argv) == 1
    cap = capsys.readouterr()
    assert "missing" in cap.err and "failed" in cap.err
    summary = json.loads((out / "summary.json").read_text())["runs"]
    status = {r["run"]: r["status"] for r in summary}
    assert status == {"toy-passthrough-seed0": "ok", "missing-passthrough-seed0": "failed"}
    assert (out / "toy-passthrough-seed0.rrd").exists()
    assert (out / "toy-passthrough-seed0.txt").exists()
    assert "toy-passthrough-seed0" in (out / "summary.csv").read_text()
    # resume: the finished run is skipped, the failed one retried (and fails again)
    spec = tmp_path / "b.toml"
    spec.write_text(f'sources = ["{good}"]\ntrackers = ["passthrough"]\nout = "{out}"\n')
    assert main(["batch", str(spec), "--quiet"]) == 0
    assert "skipped" in capsys.readouterr().out
    # other frames are another run: re-run, never reused as "already finished"
    spec.write_text(spec.read_text() + 'frames = "2:4"\n')
    assert main(["batch", str(spec)]) == 0
    cap = capsys.readouterr()
    assert "skipped" not in cap.out and "changed frames, start" in cap.err, cap.err


# ------------------------------------------------------------------ 7. colours

def test_semantic_colours_are_disjoint_from_the_track_palette():
    from pfscope.viewer_app.colors import id_colors, is_track_colour
    from pfscope.viewer_app.reporters.base import ROLES

    palette = id_colors(np.arange(1, 2000))
    assert all(is_track_colour(c) for c in palette[:, :3])
    for role, (_, rgba) in ROLES.items():
        assert not is_track_colour(np.array(rgba[:3])), role


def test_particle_colours_spread_over_the_map_on_a_real_phd_cloud():
    """The PHD's updated weights are heavy-tailed (most particles hold a tiny share): by rank,
    each fifth of viridis gets about a fifth of the particles, so the cloud does not read as one
    dark colour; heavier is never darker, smaller or drawn earlier."""
    import pfscope
    from pfscope.viewer_app.colors import TOP_FRACTION, _RAMP, weight_style, weight_summary

    clouds = []
    for fr in pfscope.stream(None, tracker="phd", frames=8, level="particles"):
        for st in fr.stages:
            clouds += [it.weights for it in st.items
                       if getattr(it, "path", "") == "phd/particles/updated"
                       and getattr(it, "weights", None) is not None]
    assert clouds, "no updated cloud with weights"
    w = clouds[-1]
    assert np.max(w) / np.median(w) > 10  # heavy-tailed: what made a log scale read dark
    order, colors, radii = weight_style(w, 1.5)
    ws = w[order]
    assert np.all(np.diff(ws) >= 0)  # lightest first, heaviest drawn last (on top)
    dark = np.linalg.norm(colors[:, :3].astype(float) - _RAMP[0], axis=1) < 60
    yellow = np.linalg.norm(colors[:, :3].astype(float) - _RAMP[-1], axis=1) < 60
    assert dark.mean() < 0.25, dark.mean()
    assert yellow.mean() > TOP_FRACTION * 0.5, yellow.mean()
    lum = colors[:, :3].astype(float) @ [0.2126, 0.7152, 0.0722]
    assert np.all(np.diff(lum) >= -1) and np.all(np.diff(radii) >= 0)
    assert np.all(np.diff(colors[:, 3].astype(int)) >= 0)
    summ = weight_summary(w)
    assert TOP_FRACTION < summ["top_tenth"] <= 1 and 0 < summ["ess"] < 1
    # equal weights (a predicted or resampled cloud): one colour, one radius
    _, c_eq, r_eq = weight_style(np.full(50, 0.02), 1.5)
    assert len(np.unique(c_eq, axis=0)) == 1 and len(np.unique(r_eq)) == 1
    assert weight_summary(np.full(50, 0.02))["top_tenth"] == pytest.approx(0.1)


def test_fast_colour_paths_match_the_definitions():
    """The recorder's shortcuts (one sort for ranks and draw order, a sampled viridis, a table of
    id colours) give what the definitions give: rankdata's average ranks, the ramp within one
    unit per channel, the computed id colours (also past the table, and for negative ids)."""
    from scipy.stats import rankdata

    from pfscope.viewer_app import colors as C

    rng = np.random.default_rng(5)
    for w in (rng.random(3000) ** 8, np.round(rng.random(500), 1), np.full(7, 0.3),
              np.array([0.2, np.nan, np.inf, 0.2, 0.0]), np.array([1.0])):
        clean = np.where(np.isfinite(w), w, 0.0)
        ranks = C.weight_scale(w)
        want = (rankdata(clean) - 1) / max(len(w) - 1, 1) if len(w) > 1 else np.full(1, 0.5)
        assert np.allclose(ranks, want)
        order, colors, radii = C.weight_style(w, 1.5)
        assert np.array_equal(order, np.argsort(ranks, kind="stable"))
        exact = C.ramp(ranks[order], 255)
        assert np.abs(colors[:, :3].astype(int) - exact[:, :3].astype(int)).max() <= 1
    ids = np.concatenate([rng.integers(0, 3000, 200), [0, 5, 1 << 17, -4]])
    pal = C.palette()
    assert np.array_equal(C.id_colors(ids)[:, :3], pal[ids % len(pal)])
    assert np.all(C.id_colors(ids[:50], alpha=90)[:, 3] == 90)
    assert C.id_colors(np.arange(0)).shape == (0, 4)


def test_the_legend_in_the_about_note_matches_the_mapping():
    from pfscope.viewer_app.colors import TOP_FRACTION
    from pfscope.viewer_app.properties import about_markdown

    md = about_markdown("x", [("Particles", ["phd/particles/updated"])], [], has_gt=True)
    assert TOP_FRACTION == 0.1 and "heaviest tenth" in md and "ranked within its cloud" in md
    assert "top_tenth" in md and "**OSPA**" in md


def test_a_trail_restarts_where_its_track_jumps():
    from pfscope.viewer_app.recorder import TrailBuffer

    tb = TrailBuffer(jump=0.75)
    box = lambda x: np.array([[x, 0.0, 10.0, 40.0]])  # noqa: E731 - 40 px tall
    for k, x in enumerate([0, 5, 10, 15]):
        live, strips = tb.update(k, np.array([3]), box(x))
    assert len(strips[0]) == 4
    live, strips = tb.update(4, np.array([3]), box(200))  # 185 px in a frame: another person
    assert list(live) == []  # one point: no trail yet
    live, strips = tb.update(5, np.array([3]), box(204))
    assert [len(s) for s in strips] == [2] and strips[0][0][0] == 205.0


def test_series_are_named_and_coloured_and_views_framed_on_the_image(tmp_path):
    import rerun as rr

    from pfscope.viewer_app.reporters.base import ROLES

    out = tmp_path / "x.rrd"
    assert main(["record", str(_toy(tmp_path, swap_at=6)), "--tracker", "passthrough",
                 "--out", str(out), "--quiet"]) == 0
    rec = read_rrd(out)

    def style(entity):
        static = [c for t, c in rec[entity] if not t and "SeriesLines:names" in c]
        assert static, entity
        return static[0]["SeriesLines:names"][0], static[0]["SeriesLines:colors"][0]

    name, color = style("/plots/metrics/fn")
    assert name == "misses"
    assert color == int.from_bytes(bytes(ROLES["miss"][1][:3]) + b"\xff", "big")
    assert style("/plots/metrics/ospa")[0] == "OSPA (px)"
    assert style("/plots/detections/count")[0] == "detections"
    series = [e for e in rec if e.startswith("/plots/")]
    assert len({style(e)[1] for e in series}) == len(series)  # no two series share a colour
    # every 2D view of the stored blueprint is framed on the image (120 x 80)
    reader = rr.chunk.RrdReader(str(out))
    bounds = [row for ch in reader.stream(store=reader.blueprints()[0])
              if ch.entity_path.endswith("/VisualBounds2D")
              for row in ch.to_record_batch().column("VisualBounds2D:range").to_pylist()]
    assert len(bounds) == 2  # passthrough's "Tracks" and "All stages"
    assert all(b == [{"x_range": [0.0, 120.0], "y_range": [0.0, 80.0]}] for b in bounds)


# ------------------------------------------------------------------ 2. pictures

def test_snapshot_of_a_tab_at_a_frame(tmp_path, capsys):
    from pfscope.viewer_app.snapshot import snapshot, vulkan_problem

    problem = vulkan_problem()
    if problem:
        pytest.skip(problem)
    out = tmp_path / "x.rrd"
    assert main(["record", str(_toy(tmp_path)), "--tracker", "passthrough", "--out", str(out),
                 "--quiet"]) == 0
    png = tmp_path / "shot.png"
    try:
        snapshot(out, png, frame=5, tab="Tracks", settle=1.0)
    except Exception as e:  # noqa: BLE001 - a machine where the viewer cannot start
        pytest.skip(f"headless viewer could not start: {e}")
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    img = cv2.imread(str(png))
    assert img.shape[1] >= 640 and img.std() > 5
