"""The other subcommands: synth, eval, compare, and the metrics a recording carries."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import read_rrd, rows_at
from test_record import _toy
from pfscope.trackers.data.motio import read_mot
from pfscope.viewer_app.cli import main


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_synth_writes_a_mot_folder_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "scene"
    rc, stdout, _ = _run(["synth", "--out", out, "--frames", "20", "--targets", "3",
                          "--clutter", "1", "--seed", "2", "--quiet"], capsys)
    assert rc == 0 and f"pfscope record {out}" in stdout
    assert (out / "seqinfo.ini").is_file() and len(list((out / "img1").glob("*.jpg"))) == 20
    assert read_mot(out / "gt" / "gt.txt", "gt").last_frame <= 20
    assert len(read_mot(out / "det" / "det.txt", "det")) > 0
    rc, _, err = _run(["synth", "--out", out, "--frames", "5", "--quiet"], capsys)
    assert rc == 2 and str(out) in err


def _gt_file(tmp_path):
    p = tmp_path / "gt.txt"
    p.write_text("".join(f"{k},1,{10 + k},20,10,20,1,1,1\n{k},2,60,{5 + k},12,24,1,1,1\n"
                         for k in range(1, 11)))
    return p


def test_eval_perfect_tracks(tmp_path, capsys):
    gt = _gt_file(tmp_path)
    tracks = tmp_path / "tracks.txt"
    tracks.write_text("".join(f"{k},7,{10 + k},20,10,20,-1,-1,-1,-1\n{k},8,60,{5 + k},12,24,-1,-1,-1,-1\n"
                              for k in range(1, 11)))
    rc, out, _ = _run(["eval", tracks, "--gt", gt, "--json"], capsys)
    assert rc == 0
    s = json.loads(out)["tracks"]
    assert s["MOTA"] == 1 and s["IDF1"] == 1 and s["IDSW"] == 0 and s["OSPA"] == 0
    rc, out, _ = _run(["eval", tracks, "--gt", gt], capsys)
    assert rc == 0 and "MODP" in out and "MOTA" in out and "IDF1" in out


def test_eval_counts_a_miss_and_a_false_positive(tmp_path, capsys):
    gt = _gt_file(tmp_path)
    tracks = tmp_path / "t.txt"
    # target 2 never tracked, one box far away from everything
    tracks.write_text("".join(f"{k},7,{10 + k},20,10,20,-1,-1,-1,-1\n" for k in range(1, 11))
                      + "5,9,300,300,10,10,-1,-1,-1,-1\n")
    rc, out, _ = _run(["eval", tracks, "--gt", gt, "--json"], capsys)
    s = json.loads(out)["t"]
    assert (s["FN"], s["FP"], s["TP"]) == (10, 1, 10)
    assert s["MOTA"] == pytest.approx(1 - 11 / 20)


def test_eval_bad_tracks_line(tmp_path, capsys):
    gt = _gt_file(tmp_path)
    tracks = tmp_path / "t.txt"
    tracks.write_text("1,7,10,20,10,20,-1,-1,-1,-1\n2,7,10,20,-5,20,-1,-1,-1,-1\n")
    rc, _, err = _run(["eval", tracks, "--gt", gt], capsys)
    assert rc == 2 and f"{tracks}:2:" in err and err.count("\n") == 1


def test_eval_against_sequence_folder(tmp_path, capsys):
    root = _toy(tmp_path)
    tracks = tmp_path / "t.txt"
    tracks.write_text("1,3,9,20,10,20,-1,-1,-1,-1\n")
    rc, out, _ = _run(["eval", tracks, "--gt", root, "--json"], capsys)
    s = json.loads(out)["t"]
    assert rc == 0 and s["num_frames"] == 6 and s["TP"] == 1 and s["FN"] == 5


def test_recording_carries_per_frame_metrics_and_marks(tmp_path, capsys):
    # detections miss the target in frame 3 -> the pass-through tracker misses it there
    dets = [f"{k},-1,{5 + 4 * k},20,10,20,0.9,-1,-1,-1" for k in (1, 2, 4, 5, 6)]
    dets.append("2,-1,60,40,8,8,0.5,-1,-1,-1")  # a false positive in frame 2
    root = _toy(tmp_path, det_lines=dets)
    out = tmp_path / "x.rrd"
    rc, stdout, _ = _run(["record", root, "--tracker", "passthrough", "--out", out, "--quiet"],
                         capsys)
    assert rc == 0 and "MOTA" in stdout
    rec = read_rrd(out)
    fn = {t["frame"]: c["Scalars:scalars"][0] for t, c in rec["/plots/metrics/fn"]
          if "frame" in t}  # the static style row (name, colour) has no frame
    fp = {t["frame"]: c["Scalars:scalars"][0] for t, c in rec["/plots/metrics/fp"]
          if "frame" in t}
    assert fn == {1: 0, 2: 0, 3: 1, 4: 0, 5: 0, 6: 0}
    assert fp[2] == 1 and fp[1] == 0
    miss = rows_at(rec, "/video/metrics/misses", 3)[0]
    assert miss["Boxes2D:labels"] == ["miss gt 1"]
    fpb = rows_at(rec, "/video/metrics/false_positives", 2)[0]
    assert np.allclose(fpb["Boxes2D:centers"], [[64, 44]])
    card = {t["frame"]: c["Scalars:scalars"][0] for t, c in rec["/plots/metrics/cardinality/true"]
            if "frame" in t}
    assert set(card.values()) == {1}
    ospa = {t["frame"]: c["Scalars:scalars"][0] for t, c in rec["/plots/metrics/ospa"]
            if "frame" in t}
    assert ospa[1] == 0 and ospa[3] > 0


def test_compare_runs_trackers_side_by_side(tmp_path, capsys):
    out = tmp_path / "cmp.rrd"
    rc, stdout, err = _run(["compare", "--trackers", "phd,mt", "--frames", "25", "--out", out,
                            "--quiet", "--json"], capsys)
    assert rc == 0, err
    scores = json.loads(stdout)
    assert set(scores) == {"phd", "mt"}
    for s in scores.values():
        assert {"MODP", "MODA", "MOTP", "MOTA", "IDF1", "HOTA", "OSPA"} <= set(s)
    ents = set(read_rrd(out))
    assert {"/video", "/video/detections", "/video/gt", "/phd/video/tracks", "/mt/video/tracks",
            "/phd/plots/metrics/ospa", "/mt/plots/metrics/ospa"} <= ents
    assert "/phd/video" not in ents  # the frame is stored once and shared


def test_compare_rejects_unknown_tracker(tmp_path, capsys):
    rc, _, err = _run(["compare", "--trackers", "phd,nope", "--frames", "5",
                       "--out", tmp_path / "c.rrd", "--quiet"], capsys)
    assert rc == 2 and "nope" in err and not (tmp_path / "c.rrd").exists()


def test_classifier_option_reaches_the_trackers_that_have_one(tmp_path, capsys):
    """`record --classifier MODEL` is `--set model=MODEL` for dlpf / dbn-phd; elsewhere it is a
    one-line usage error, and a missing model file is one line naming it (no recording left)."""
    out = tmp_path / "x.rrd"
    rc, _, err = _run(["record", "--classifier", tmp_path / "m.npz", "--frames", "2",
                       "--out", out, "--quiet"], capsys)
    assert rc == 2 and "--classifier" in err and "dlpf" in err and "Traceback" not in err
    rc, _, err = _run(["record", "--tracker", "dlpf", "--classifier", tmp_path / "m.npz",
                       "--frames", "2", "--out", out, "--quiet"], capsys)
    assert rc == 2 and "m.npz" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_video_option_offers_exactly_the_recorder_modes():
    """`--video` of record and compare lists the recorder's modes (a mode added to the recorder
    but not to the CLI, or the reverse, fails here)."""
    from pfscope.viewer_app.cli import build_parser
    from pfscope.viewer_app.recorder import VIDEO_MODES

    parser = build_parser()
    subs = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for cmd in ("record", "compare"):
        video = next(a for a in subs.choices[cmd]._actions if "--video" in a.option_strings)
        assert tuple(video.choices) == VIDEO_MODES and video.default == "encode"


def _entry(args, stdout, tmp_path):
    """``pfscope`` as installed (``cli.entry``: a ``record`` ends through ``exit_process``)."""
    import subprocess
    import sys

    code = ("import sys; from pfscope.viewer_app.cli import entry; "
            f"sys.argv = ['pfscope', *{list(args)!r}]; entry()")
    return subprocess.run([sys.executable, "-c", code], stdout=stdout, stderr=subprocess.PIPE,
                          text=True, cwd=tmp_path, timeout=600)


def test_the_command_ends_a_record_with_its_outputs_whole_and_its_status(tmp_path):
    """``entry`` ends ``record`` without the interpreter's teardown (``exit_process``): the
    recording and the tracks file are complete and renamed, status 0; stdout on a full device
    gives one error line and a failure status, never a silent 0."""
    import os
    import subprocess

    out, tracks = tmp_path / "r.rrd", tmp_path / "t.txt"
    args = ["record", "--frames", "20", "--out", str(out), "--tracks-out", str(tracks)]
    p = _entry(args, subprocess.PIPE, tmp_path)
    assert p.returncode == 0, p.stderr
    assert out.stat().st_size > 0 and tracks.read_text().strip()
    assert not [f for f in tmp_path.iterdir() if "incomplete" in f.name or f.suffix == ".part"]
    assert "frames" in p.stdout
    if os.path.exists("/dev/full"):
        with open("/dev/full", "w") as full:
            p = _entry([*args, "--force"], full, tmp_path)
        assert p.returncode != 0
        assert "cannot write" in p.stderr and "Traceback" not in p.stderr
