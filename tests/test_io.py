"""MOT text I/O and frame sources: round trips and every kind of bad input."""

from __future__ import annotations

import numpy as np
import pytest

from pfscope.trackers.data.motio import TrackWriter, read_mot, write_mot
from pfscope.trackers.data.sources import (ImageFolderSource, MOTFolderSource, VideoFileSource,
                                   open_source)
from pfscope.trackers.errors import InputError
from pfscope.trackers.types import TrackSet

cv2 = pytest.importorskip("cv2")


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_read_gt_and_ignore_flag(tmp_path):
    p = _write(tmp_path, "gt.txt", "1,1,10,20,30,40,1,1,1\n1,2,5,5,10,10,0,1,-1\n2,1,11,21,30,40,1,1,1\n")
    t = read_mot(p, "gt")
    assert len(t) == 3 and t.last_frame == 2
    g = t.ground_truth(1)
    assert list(g.ids) == [1, 2] and list(g.ignore) == [False, True]
    assert np.allclose(g.boxes[0], [10, 20, 30, 40])
    assert len(t.ground_truth(3)) == 0


def test_det_score_threshold(tmp_path):
    p = _write(tmp_path, "det.txt", "1,-1,0,0,10,20,0.9,-1,-1,-1\n1,-1,5,5,10,20,0.2,-1,-1,-1\n")
    t = read_mot(p, "det")
    assert len(t.detections(1)) == 2
    d = t.detections(1, min_score=0.5)
    assert len(d) == 1 and d.scores[0] == pytest.approx(0.9)


@pytest.mark.parametrize("line, needle", [
    ("1,-1,0,0,10", "expected at least 7"),
    ("1,-1,0,zero,10,20,0.9", "not a number"),
    ("1,-1,0,0,nan,20,0.9", "NaN"),
    ("1,-1,0,0,-3,20,0.9", "must be positive"),
    ("0,-1,0,0,3,20,0.9", "positive integer"),
    ("1.5,-1,0,0,3,20,0.9", "positive integer"),
])
def test_bad_det_line_names_file_and_line(tmp_path, line, needle):
    p = _write(tmp_path, "det.txt", "1,-1,0,0,10,20,0.9,-1,-1,-1\n" + line + "\n")
    with pytest.raises(InputError) as e:
        read_mot(p, "det")
    msg = str(e.value)
    assert f"{p}:2:" in msg and needle in msg and "\n" not in msg


@pytest.mark.parametrize("kind, text, plain", [
    ("gt", "1,1,10,20,30.5,40.25,1,1,-1\n2,3,1e1,2.5E-1,3,4,0,2,0.5\n", True),
    ("det", "1,-1,0.1,0.2,10,20,0.9,-1,-1,-1,7,8\n1,-1,5,5,10,20,0.2,-1,-1,-1,9,9", True),
    ("tracks", "1,7,1.5,2.25,10,20\n2,8,3,4,5,6\n", True),
    ("gt", "1,1,10,20,30,40,1,1,1\n\n2,1,11,21,30,40,1,1,1\n", False),      # blank line
    ("gt", "1,1,10,20,30,40,1,1,1\r\n2,1,11,21,30,40,1,1,1\r\n", False),  # CRLF
    ("gt", "1, 1,10,20,30,40,1,1,1\n", False),                              # a space
    ("tracks", "1,9007199254740993,1,2,3,4\n", False),                      # id > 2**53
    ("det", "1,-1,0,0,10,20,0.9\n1,-1,0,0,10,20,0.9,-1\n", False),          # ragged
])
def test_plain_files_read_vectorised_as_line_by_line(tmp_path, monkeypatch, kind, text, plain):
    """A plain file (same number of comma-separated numbers on every line) is read in one
    vectorised pass; it gives the line-by-line reader's table exactly, and anything else
    goes to that reader."""
    from pfscope.trackers.data import motio

    p = _write(tmp_path, f"{kind}.txt", text)
    assert (motio._read_plain(text, kind, str(p)) is not None) == plain
    fast = read_mot(p, kind)
    monkeypatch.setattr(motio, "_read_plain", lambda *a: None)
    slow = read_mot(p, kind)
    for col in ("frame", "id", "boxes", "score", "cls", "vis"):
        a, b = getattr(fast, col), getattr(slow, col)
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), col
    assert fast.path == slow.path


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="no such gt file"):
        read_mot(tmp_path / "nope.txt", "gt")


def test_write_read_round_trip(tmp_path):
    p = tmp_path / "tracks.txt"
    boxes = np.array([[1.5, 2.25, 10, 20], [3, 4, 5, 6]])
    write_mot(p, "tracks", [1, 2], [7, 8], boxes)
    t = read_mot(p, "tracks")
    assert list(t.frame) == [1, 2] and list(t.id) == [7, 8]
    assert np.allclose(t.boxes, boxes, atol=1e-3)


def test_track_writer_only_complete_on_close(tmp_path):
    p = tmp_path / "t.txt"
    w = TrackWriter(p)
    w.write(1, TrackSet([3], [[1, 2, 3, 4]]))
    assert not p.exists()  # still .part
    w.close()
    assert read_mot(p, "tracks").id.tolist() == [3]


def _mot_folder(tmp_path, n=3, det=None, ini=True):
    root = tmp_path / "seq"
    (root / "img1").mkdir(parents=True)
    for k in range(1, n + 1):
        cv2.imwrite(str(root / "img1" / f"{k:06d}.jpg"), np.full((48, 64, 3), 10 * k, np.uint8))
    if ini:
        (root / "seqinfo.ini").write_text(
            f"[Sequence]\nname=toy\nimDir=img1\nframeRate=5\nseqLength={n}\n"
            "imWidth=64\nimHeight=48\nimExt=.jpg\n")
    if det is not None:
        (root / "det").mkdir()
        (root / "det" / "det.txt").write_text(det)
    return root


def test_mot_folder_frames_and_timestamps(tmp_path):
    src = open_source(_mot_folder(tmp_path, det="1,-1,1,1,5,5,1,-1,-1,-1\n"))
    assert isinstance(src, MOTFolderSource) and src.det is not None and src.gt is None
    frames = list(src.frames())
    assert [f.index for f in frames] == [1, 2, 3]
    assert [f.timestamp for f in frames] == pytest.approx([0, 0.2, 0.4])
    assert frames[0].image.shape == (48, 64, 3)
    assert len(list(src.frames(2))) == 2


def test_mot_folder_missing_seqinfo(tmp_path):
    root = _mot_folder(tmp_path, ini=False)
    with pytest.raises(InputError, match="seqinfo.ini: missing"):
        open_source(root)


def test_mot_folder_missing_image_names_frame(tmp_path):
    root = _mot_folder(tmp_path)
    (root / "img1" / "000002.jpg").unlink()
    with pytest.raises(InputError) as e:
        list(open_source(root).frames())
    assert "000002.jpg: frame 2" in str(e.value)


def test_mot_folder_corrupt_image(tmp_path):
    root = _mot_folder(tmp_path)
    (root / "img1" / "000003.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(InputError, match="frame 3: cannot decode"):
        list(open_source(root).frames())


def test_image_folder(tmp_path):
    for k in range(4):
        cv2.imwrite(str(tmp_path / f"im{k}.png"), np.zeros((8, 8, 3), np.uint8))
    src = open_source(tmp_path, fps=2)
    assert isinstance(src, ImageFolderSource)
    assert [f.timestamp for f in src.frames()] == [0, 0.5, 1.0, 1.5]


def test_video_file(tmp_path):
    path = tmp_path / "v.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (32, 24))
    for k in range(5):
        vw.write(np.full((24, 32, 3), 40 * k, np.uint8))
    vw.release()
    src = open_source(path)
    assert isinstance(src, VideoFileSource) and src.fps == pytest.approx(10)
    frames = list(src.frames())
    assert len(frames) == 5 and frames[-1].timestamp == pytest.approx(0.4)


@pytest.mark.parametrize("content", [b"", b"garbage that is no video"])
def test_empty_or_unreadable_video(tmp_path, content):
    path = tmp_path / "bad.mp4"
    path.write_bytes(content)
    with pytest.raises(InputError, match="unreadable or empty video"):
        open_source(path)


def test_nonexistent_source(tmp_path):
    with pytest.raises(InputError, match="no such file or folder"):
        open_source(tmp_path / "missing")
