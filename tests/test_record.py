"""`pfscope record` end to end: what lands in the recording, bad input, interruption,
determinism."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO, read_rrd, rows_at
from pfscope.trackers.data.motio import read_mot
from pfscope.viewer_app.cli import main

cv2 = pytest.importorskip("cv2")


def _toy(tmp_path, n=6, det_lines=None, gt=True):
    """A small MOT folder with a bright square moving right, its gt and dets."""
    root = tmp_path / "toy"
    (root / "img1").mkdir(parents=True)
    (root / "det").mkdir()
    (root / "gt").mkdir()
    det, gtl = [], []
    for k in range(1, n + 1):
        img = np.full((60, 80, 3), 30, np.uint8)
        x = 5 + 4 * k
        img[20:40, x:x + 10] = 220
        cv2.imwrite(str(root / "img1" / f"{k:06d}.jpg"), img)
        det.append(f"{k},-1,{x},20,10,20,0.9,-1,-1,-1")
        gtl.append(f"{k},1,{x},20,10,20,1,1,1")
    (root / "seqinfo.ini").write_text(
        f"[Sequence]\nname=toy\nimDir=img1\nframeRate=5\nseqLength={n}\nimWidth=80\n"
        "imHeight=60\nimExt=.jpg\n")
    (root / "det" / "det.txt").write_text("\n".join(det_lines or det) + "\n")
    if gt:
        (root / "gt" / "gt.txt").write_text("\n".join(gtl) + "\n")
    return root


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_record_toy_sequence_contents(tmp_path, capsys):
    root = _toy(tmp_path)
    out = tmp_path / "x.rrd"
    rc, stdout, _ = _run(["record", root, "--tracker", "passthrough", "--out", out,
                          "--tracks-out", tmp_path / "t.txt", "--quiet"], capsys)
    assert rc == 0
    assert f"rerun {out}" in stdout
    rec = read_rrd(out)
    for ent in ("/video", "/video/detections", "/video/gt", "/video/tracks"):
        assert ent in rec, ent
    frames = sorted({t["frame"] for t, _ in rec["/video"]})
    assert frames == [1, 2, 3, 4, 5, 6]
    # detections and gt of frame 3 are where the files say (Boxes2D stored as centre/half size)
    det = rows_at(rec, "/video/detections", 3)[0]
    assert np.allclose(det["Boxes2D:centers"], [[17 + 5, 30]])
    assert np.allclose(det["Boxes2D:half_sizes"], [[5, 10]])
    gt = rows_at(rec, "/video/gt", 3)[0]
    assert gt["Boxes2D:labels"] == ["gt 1"]
    # every frame's image is a JPEG
    img = rows_at(rec, "/video", 1)[0]
    assert img["EncodedImage:media_type"] == ["image/jpeg"]
    tracks = read_mot(tmp_path / "t.txt", "tracks")
    assert sorted(set(tracks.frame.tolist())) == frames


def test_refuses_to_overwrite_without_force(tmp_path, capsys):
    root = _toy(tmp_path)
    out = tmp_path / "x.rrd"
    out.write_bytes(b"precious")
    rc, _, err = _run(["record", root, "--tracker", "passthrough", "--out", out, "--quiet"], capsys)
    assert rc == 2 and "--force" in err and out.read_bytes() == b"precious"
    rc, _, _ = _run(["record", root, "--tracker", "passthrough", "--out", out, "--quiet",
                     "--force"], capsys)
    assert rc == 0 and out.stat().st_size > 1000


@pytest.mark.parametrize("bad, needle", [
    ("3,-1,10,20,nan,20,0.9,-1,-1,-1", "det.txt:3: NaN"),
    ("3,-1,10,20,-10,20,0.9,-1,-1,-1", "det.txt:3: box width and height must be positive"),
    ("3,-1,10,20", "det.txt:3: expected at least 7"),
])
def test_bad_det_line_one_line_error_and_no_output(tmp_path, capsys, bad, needle):
    good = [f"{k},-1,10,20,10,20,0.9,-1,-1,-1" for k in (1, 2)]
    root = _toy(tmp_path, det_lines=good + [bad])
    out = tmp_path / "x.rrd"
    rc, _, err = _run(["record", root, "--tracker", "passthrough", "--out", out, "--quiet"], capsys)
    assert rc == 2
    assert needle in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_missing_image_mid_run_leaves_incomplete_file(tmp_path, capsys):
    root = _toy(tmp_path)
    (root / "img1" / "000004.jpg").unlink()
    out = tmp_path / "x.rrd"
    rc, _, err = _run(["record", root, "--tracker", "passthrough", "--out", out, "--quiet"], capsys)
    assert rc == 2 and "000004.jpg: frame 4" in err and err.count("\n") == 1
    assert not out.exists()  # nothing half-written looks complete
    partial = tmp_path / "x.incomplete.rrd"
    rec = read_rrd(partial)
    assert sorted({t["frame"] for t, _ in rec["/video"]}) == [1, 2, 3]


def test_missing_seqinfo(tmp_path, capsys):
    root = _toy(tmp_path)
    (root / "seqinfo.ini").unlink()
    rc, _, err = _run(["record", root, "--out", tmp_path / "x.rrd", "--quiet"], capsys)
    assert rc == 2 and "seqinfo.ini: missing" in err


def test_empty_video(tmp_path, capsys):
    (tmp_path / "v.mp4").write_bytes(b"")
    rc, _, err = _run(["record", tmp_path / "v.mp4", "--out", tmp_path / "x.rrd", "--quiet"], capsys)
    assert rc == 2 and "v.mp4: unreadable or empty video" in err


def test_unwritable_output_folder(tmp_path, capsys):
    root = _toy(tmp_path)
    blocker = tmp_path / "file"
    blocker.write_text("I am a file, not a folder")
    rc, _, err = _run(["record", root, "--tracker", "passthrough",
                       "--out", blocker / "sub" / "x.rrd", "--quiet"], capsys)
    assert rc == 2 and "cannot create output folder" in err


def test_file_detector_without_det_file(tmp_path, capsys):
    root = _toy(tmp_path)
    (root / "det" / "det.txt").unlink()
    rc, _, err = _run(["record", root, "--detector", "file", "--out", tmp_path / "x.rrd",
                       "--quiet"], capsys)
    assert rc == 2 and "det" in err


def _spawn_record(out: Path, extra=()) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "pfscope.viewer_app.cli", "record", "--tracker", "passthrough",
           "--frames", "100000", "--out", str(out), "--quiet", *extra]
    env = dict(os.environ, RERUN_ANALYTICS="0")
    return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)


def _wait_for_frames(out: Path, proc, min_bytes=200_000, timeout=60):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if out.exists() and out.stat().st_size > min_bytes:
            return
        if proc.poll() is not None:
            raise AssertionError(f"recorder ended early: {proc.stderr.read().decode()}")
        time.sleep(0.2)
    raise AssertionError("recorder wrote nothing in time")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_finishes_a_readable_file(tmp_path, sig):
    out = tmp_path / "run.rrd"
    partial = tmp_path / "run.incomplete.rrd"
    proc = _spawn_record(out)
    _wait_for_frames(partial, proc)
    proc.send_signal(sig)
    proc.wait(timeout=60)
    assert proc.returncode == 128 + sig, proc.stderr.read().decode()
    assert not out.exists()  # an interrupted run never takes the final name
    rec = read_rrd(partial, footer=True)  # footer written: the full store loads
    frames = {t["frame"] for t, _ in rec["/video"]}
    assert len(frames) >= 2
    last = [c.get("TextLog:text") for _, c in rec.get("/log", [])][-1]
    assert "interrupted" in str(last)  # the last entry says why the run stopped


def test_sigkill_still_leaves_a_readable_file(tmp_path):
    out = tmp_path / "run.rrd"
    partial = tmp_path / "run.incomplete.rrd"
    proc = _spawn_record(out)
    _wait_for_frames(partial, proc)
    proc.kill()
    proc.wait(timeout=30)
    assert not out.exists()
    rec = read_rrd(partial, footer=False)
    assert len({t["frame"] for t, _ in rec["/video"]}) >= 2


def test_same_seed_same_recording(tmp_path, capsys):
    a, b, c = tmp_path / "a.rrd", tmp_path / "b.rrd", tmp_path / "c.rrd"
    for out, seed in ((a, 3), (b, 3), (c, 4)):
        rc, _, _ = _run(["record", "--frames", "12", "--seed", seed, "--out", out,
                         "--level", "particles", "--quiet"], capsys)
        assert rc == 0
    rerun = Path(sys.executable).with_name("rerun")
    same = subprocess.run([str(rerun), "rrd", "compare", str(a), str(b)], capture_output=True)
    assert same.returncode == 0, same.stderr.decode()[-2000:]
    diff = subprocess.run([str(rerun), "rrd", "compare", str(a), str(c)], capture_output=True)
    assert diff.returncode != 0


def test_levels_change_what_is_recorded(tmp_path, capsys):
    sizes = {}
    for level in ("tracks", "particles"):
        out = tmp_path / f"{level}.rrd"
        rc, _, _ = _run(["record", "--frames", "10", "--level", level, "--out", out, "--quiet"],
                        capsys)
        assert rc == 0
        sizes[level] = out.stat().st_size
        ents = set(read_rrd(out))
        has_particles = any(e.startswith("/video/phd/particles") for e in ents)
        assert has_particles == (level == "particles"), (level, sorted(ents))
    assert sizes["particles"] > sizes["tracks"]


def test_default_record_writes_under_recordings(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rc, stdout, _ = _run(["record", "--frames", "5", "--quiet"], capsys)
    assert rc == 0
    files = list((tmp_path / "recordings").glob("*.rrd"))
    assert len(files) == 1 and "phd" in files[0].name
    assert f"rerun {Path('recordings') / files[0].name}" in stdout


def test_stage_timeline_orders_the_stages_inside_a_frame(tmp_path, capsys):
    out = tmp_path / "s.rrd"
    rc, _, _ = _run(["record", "--frames", "8", "--level", "particles", "--out", out, "--quiet"],
                    capsys)
    assert rc == 0
    rec = read_rrd(out)
    order = ["predicted", "birth", "updated", "resampled"]
    for frame in (5, 8):
        stages = []
        for name in order:
            rows = [t for t, _ in rec[f"/video/phd/particles/{name}"] if t["frame"] == frame]
            assert rows, (name, frame)
            stages.append(rows[0]["stage"])
        clusters = [t["stage"] for t, _ in rec["/video/phd/clusters/members"] if t["frame"] == frame]
        edges = [t["stage"] for t, _ in rec["/video/assoc/vertices"] if t["frame"] == frame]
        tracks = [t["stage"] for t, _ in rec["/video/tracks"] if t["frame"] == frame]
        stages += [clusters[0], edges[0], tracks[0]]
        assert stages == sorted(stages) and len(set(stages)) == len(stages), stages


# ----------------------------------------------------------------------------- cheap recording

def test_columns_give_the_rows_that_logging_each_frame_gives(tmp_path):
    """The recorder sends each entity's rows as columns (one call per flush): the file must hold
    the rows that a `log` call per entity and frame gives — same times, same instances per row
    (a radius for all points in one frame, one per point in the next), same values."""
    import rerun as rr

    from pfscope.viewer_app.reporters.base import Columns

    rng = np.random.default_rng(0)
    frames = []
    for k in range(1, 6):
        n = int(rng.integers(0, 5))
        frames.append(dict(
            k=k, xy=rng.random((n, 2)).astype(np.float32) * 100,
            colors=rng.integers(0, 255, (n, 4)).astype(np.uint8),
            radii=np.float32(1.5) if k % 2 else rng.random(n).astype(np.float32),
            boxes=rng.random((n, 2)).astype(np.float32) * 50,
            labels=[f"id {i}" for i in range(n)] if k != 3 else [],
            strips=[rng.random((int(rng.integers(2, 5)), 2)).astype(np.float32)
                    for _ in range(n)],
            value=float(rng.random()), blob=bytes(rng.integers(0, 255, 10 + k).astype(np.uint8)),
            tag=k <= 2))  # a component that goes away after frame 2

    def write(path, buffered):
        rec = rr.RecordingStream("t", recording_id="same")
        rec.save(str(path))
        cols = Columns(rec, immediate=not buffered)
        for f in frames:
            rec.set_time("frame", sequence=f["k"])
            rec.set_time("time", duration=f["k"] / 10)
            rec.set_time("stage", sequence=10 * f["k"])
            cols.frame, cols.seconds, cols.stage = f["k"], f["k"] / 10, 10 * f["k"]
            cols.add("p", rr.Points2D, positions=f["xy"], colors=f["colors"], radii=f["radii"],
                     show_labels=False, class_ids=7 if f["tag"] else None)
            cols.add("b", rr.Boxes2D, centers=f["boxes"], half_sizes=f["boxes"] / 4,
                     labels=f["labels"], show_labels=False, radii=1.0)
            cols.add("s", rr.LineStrips2D, strips=f["strips"], radii=0.5)
            cols.add("v", rr.Scalars, scalars=np.array([f["value"]]))
            cols.add("i", rr.EncodedImage, blob=f["blob"], media_type="image/jpeg")
            if f["k"] == 3:
                cols.send()
        cols.send()
        rec.flush()
        rec.disconnect()
        return read_rrd(path)

    def rows(rec):
        return {e: sorted((sorted(t.items()), sorted((k, repr(v)) for k, v in c.items()
                                                     if v is not None))
                          for t, c in r) for e, r in rec.items() if not e.startswith("/__")}

    logged, sent = write(tmp_path / "log.rrd", False), write(tmp_path / "cols.rrd", True)
    assert set(logged) >= {"/p", "/b", "/s", "/v", "/i"}
    assert rows(sent) == rows(logged)
    radii = [c["Points2D:radii"] for _, c in sorted(sent["/p"], key=lambda r: r[0]["frame"])]
    assert [len(r) for r in radii[::2]] == [1, 1, 1]  # one radius for the cloud: not repeated


def test_jpeg_worker_is_bounded_and_its_failure_is_one_line(tmp_path, capsys, monkeypatch):
    from pfscope.viewer_app import recorder as R

    enc = R.JpegEncoder(75, timeout=5)
    img = np.zeros((8, 8, 3), np.uint8)
    enc.submit(img)
    with pytest.raises(RuntimeError, match="already"):
        enc.submit(img)  # one frame in flight at most
    assert enc.result()[:2] == b"\xff\xd8" and enc.result() is None
    enc.close()

    orig = R.JpegEncoder._encode

    def fails_on_frame_4(self, image):
        self.calls = getattr(self, "calls", 0) + 1
        if self.calls == 4:
            raise RuntimeError("simulated encoder failure")
        return orig(self, image)

    monkeypatch.setattr(R.JpegEncoder, "_encode", fails_on_frame_4)
    out = tmp_path / "x.rrd"
    rc, _, err = _run(["record", "--frames", "8", "--out", out, "--quiet"], capsys)
    assert rc == 1 and "simulated encoder failure" in err and err.count("\n") == 1, err
    assert not out.exists()
    rec = read_rrd(tmp_path / "x.incomplete.rrd")
    assert sorted({t["frame"] for t, _ in rec["/video"]}) == [1, 2, 3]
    assert "simulated encoder failure" in str(rec["/log"][-1][1]["TextLog:text"])


def test_video_from_the_source_jpeg_bytes(tmp_path):
    """``video="source"`` stores each frame's JPEG file as it is (no encoding); ``auto`` does so
    only when the first frame's file is not larger than its encoding; ``encode`` never."""
    from pfscope.trackers.data.sources import open_source
    from pfscope.trackers.errors import InputError
    from pfscope.viewer_app.run import RecordOptions, record

    root = _toy(tmp_path, n=4)
    files = [(root / "img1" / f"{k:06d}.jpg").read_bytes() for k in range(1, 5)]
    q75 = len(cv2.imencode(".jpg", cv2.imread(str(root / "img1" / "000001.jpg")),
                           [cv2.IMWRITE_JPEG_QUALITY, 75])[1])
    blobs = {}
    for mode in ("encode", "source", "auto"):
        out = tmp_path / f"{mode}.rrd"
        record(open_source(root), out, RecordOptions(tracker="passthrough", video=mode),
               progress=False)
        rows = sorted(read_rrd(out)["/video"], key=lambda r: r[0]["frame"])
        blobs[mode] = [bytes(c["EncodedImage:blob"][0]) for _, c in rows]
    assert blobs["source"] == files
    assert all(b != f for b, f in zip(blobs["encode"], files))
    assert blobs["auto"] == (files if len(files[0]) <= q75 else blobs["encode"])
    with pytest.raises(InputError, match="video"):
        record(open_source(root), tmp_path / "x.rrd", RecordOptions(video="raw"), progress=False)


def test_timed_stream_logs_at_the_latest_timelines(tmp_path):
    """The recorder moves its timelines ~10 times a frame but sets them on the stream only
    before a direct ``log``: each row lands at the values current at its log call."""
    import rerun as rr

    from pfscope.viewer_app.reporters.base import TimedStream

    rec = rr.RecordingStream("t", recording_id="timed")
    rec.save(str(tmp_path / "t.rrd"))
    ts = TimedStream(rec)
    ts.set_time("frame", sequence=1)
    ts.set_time("stage", sequence=10)
    ts.set_time("frame", sequence=5)
    ts.log("e", rr.TextLog("a"))
    ts.set_time("frame", sequence=7)                   # moved, never logged at
    ts.set_time("frame", sequence=9)
    ts.log("e", rr.TextLog("b"))
    ts.set_time("stage", sequence=95)
    ts.log("e", rr.TextLog("c"))
    ts.flush()
    ts.disconnect()
    got = sorted((t["frame"], t["stage"], str(c["TextLog:text"]))
                 for t, c in read_rrd(tmp_path / "t.rrd")["/e"])
    assert [(f, s) for f, s, _ in got] == [(5, 10), (9, 10), (9, 95)]
    assert ["a" in got[0][2], "b" in got[1][2], "c" in got[2][2]] == [True, True, True]


def test_tracker_messages_land_at_their_frame(tmp_path, capsys):
    """A tracker's messages (the stages' Event items, sent with the column rows) are rows of
    their frame: the frame each message names, inside that frame's stage slots."""
    out = tmp_path / "m.rrd"
    rc, _, _ = _run(["record", "--frames", "30", "--out", out, "--quiet"], capsys)
    assert rc == 0
    rec = read_rrd(out)
    rows = [(e, t, str(c["TextLog:text"][0])) for e, rs in rec.items()
            if e.startswith("/log/") for t, c in rs]
    assert len(rows) >= 3, sorted(rec)  # tracks confirmed at least
    video = {t["frame"]: t["stage"] for t, _ in rec["/video"]}
    for entity, t, text in rows:
        assert text.startswith(f"frame {t['frame']}:"), (entity, t, text)
        nxt = video.get(t["frame"] + 1)
        assert video[t["frame"]] < t["stage"] and (nxt is None or t["stage"] < nxt), (entity, t)
