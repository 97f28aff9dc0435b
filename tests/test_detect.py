"""Detectors: file replay, make_detector errors, background-subtraction blobs on a synthetic
scene, HOG people on PETS09-S2L1 and Haar faces on OTB-Girl (real data; skipped when absent)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from pfscope.trackers.data.motio import read_mot
from pfscope.trackers.detect import (DETECTORS, BackgroundSubtractionDetector, Detector, FileDetector,
                             HaarFaceDetector, HOGPeopleDetector, make_detector)
from pfscope.trackers.errors import InputError
from pfscope.trackers.types import Detections, Frame


def data_dir() -> Path:
    env = os.environ.get("PFSCOPE_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "data"


def sequence(name: str) -> Path:
    seq = data_dir() / name
    if not (seq / "img1").is_dir() or not (seq / "gt" / "gt.txt").is_file():
        pytest.skip(f"{name} not found under {data_dir()} (set PFSCOPE_DATA to the data folder)")
    return seq


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) IoU of xywh boxes."""
    a = a[:, None, :]
    b = b[None, :, :]
    iw = np.clip(np.minimum(a[..., 0] + a[..., 2], b[..., 0] + b[..., 2])
                 - np.maximum(a[..., 0], b[..., 0]), 0, None)
    ih = np.clip(np.minimum(a[..., 1] + a[..., 3], b[..., 1] + b[..., 3])
                 - np.maximum(a[..., 1], b[..., 1]), 0, None)
    inter = iw * ih
    return inter / (a[..., 2] * a[..., 3] + b[..., 2] * b[..., 3] - inter)


def blank(index: int) -> Frame:
    return Frame(index, 0.0, np.zeros((4, 4, 3), np.uint8))


# ---------------------------------------------------------------- file detector

DET_TEXT = """\
1,-1,10,20,30,40,0.9,-1,-1,-1
2,-1,11,21,31,41,0.2,-1,-1,-1
2,-1,50,60,10,20,0.7,-1,-1,-1
5,-1,1,2,3,4,0.5,-1,-1,-1
2,-1,100,110,12,24,0.5,-1,-1,-1
"""


@pytest.fixture
def det_table(tmp_path):
    p = tmp_path / "det.txt"
    p.write_text(DET_TEXT)
    return read_mot(p, "det")


def test_file_detector_returns_exactly_the_frames_rows(det_table):
    d = FileDetector(det_table)(blank(2))
    assert isinstance(d, Detections) and d.boxes.dtype == np.float64
    got = sorted(zip(map(tuple, d.boxes), d.scores))
    want = sorted([((11, 21, 31, 41), 0.2), ((50, 60, 10, 20), 0.7), ((100, 110, 12, 24), 0.5)])
    assert got == want
    assert len(FileDetector(det_table)(blank(3))) == 0        # gap inside the file
    assert len(FileDetector(det_table)(blank(1000))) == 0     # past the end: empty, no error


def test_file_detector_applies_the_score_threshold(det_table):
    d = FileDetector(det_table, min_score=0.5)(blank(2))
    assert sorted(d.scores.tolist()) == [0.5, 0.7]            # inclusive threshold
    assert len(FileDetector(det_table, min_score=0.95)(blank(1))) == 0
    via_factory = make_detector("file", det_table=det_table, min_score=0.5)(blank(2))
    assert sorted(via_factory.scores.tolist()) == [0.5, 0.7]


def test_file_detector_from_path(tmp_path):
    p = tmp_path / "det.txt"
    p.write_text(DET_TEXT)
    d = make_detector("file", det_path=p)(blank(5))
    np.testing.assert_array_equal(d.boxes, [[1, 2, 3, 4]])


# ---------------------------------------------------------------- make_detector errors

def _one_line(err: pytest.ExceptionInfo) -> str:
    msg = str(err.value)
    assert "\n" not in msg and msg
    return msg


def test_make_detector_unknown_name():
    with pytest.raises(InputError) as e:
        make_detector("yolo")
    msg = _one_line(e)
    assert "yolo" in msg and all(n in msg for n in DETECTORS)


def test_make_detector_file_without_table_suggests_alternatives():
    with pytest.raises(InputError) as e:
        make_detector("file")
    msg = _one_line(e)
    assert "det/det.txt" in msg and "--detector hog|bgsub" in msg


def test_make_detector_missing_det_file(tmp_path):
    with pytest.raises(InputError) as e:
        make_detector("file", det_path=tmp_path / "nope" / "det.txt")
    assert "nope" in _one_line(e)


def test_make_detector_unknown_and_bad_options():
    with pytest.raises(InputError) as e:
        make_detector("bgsub", min_aera=10)
    msg = _one_line(e)
    assert "min_aera" in msg and "min_area" in msg
    with pytest.raises(InputError):
        make_detector("bgsub", method="codebook")
    with pytest.raises(InputError):
        make_detector("hog", scale=1.0)
    with pytest.raises(InputError):
        make_detector("haar", upscale=0)


def test_make_detector_builds_every_kind(det_table):
    for name in DETECTORS:
        det = make_detector(name, det_table=det_table)
        assert isinstance(det, Detector) and det.name == name


@pytest.mark.parametrize("name", ["hog", "haar", "bgsub"])
def test_image_detectors_reject_bad_images(name):
    det = make_detector(name)
    with pytest.raises(InputError) as e:
        det(Frame(7, 0.0, np.zeros((20, 20, 3), np.float32)))
    assert "frame 7" in _one_line(e)


# ---------------------------------------------------------------- background subtraction

H, W = 120, 160
RECT_W, RECT_H = 24, 40


def noisy_scene(rng: np.random.Generator, n: int, start: int | None):
    """Static textured background + N(0, 4²) sensor noise per frame; from frame ``start`` on
    a bright 24x40 rectangle moves right 6 px/frame.  Yields (frame, true box or None)."""
    bg = rng.integers(40, 120, (H, W, 3)).astype(np.float64)
    for k in range(1, n + 1):
        img = bg + rng.normal(0.0, 4.0, bg.shape)
        box = None
        if start is not None and k >= start:
            x, y = 10 + 6 * (k - start), 35
            img[y:y + RECT_H, x:x + RECT_W] = 230 + rng.normal(0.0, 4.0, (RECT_H, RECT_W, 3))
            box = np.array([[x, y, RECT_W, RECT_H]], np.float64)
        yield Frame(k, k / 25.0, np.clip(img, 0, 255).astype(np.uint8)), box


@pytest.mark.parametrize("method", ["mog2", "knn"])
def test_bgsub_finds_moving_rectangle(method):
    warm = 30  # background-only frames: the model learns the scene first
    det = BackgroundSubtractionDetector(method=method, warmup=warm)
    found = 0
    for frame, box in noisy_scene(np.random.default_rng(1), warm + 10, start=warm + 1):
        d = det(frame)
        if box is None:
            assert len(d) == 0
            continue
        assert len(d) == 1, f"frame {frame.index}: {len(d)} blobs"
        assert iou_matrix(d.boxes, box)[0, 0] > 0.5
        assert 0.0 < d.scores[0] <= 1.0
        found += 1
    assert found == 10


@pytest.mark.parametrize("method", ["mog2", "knn"])
def test_bgsub_static_scene_gives_nothing(method):
    det = BackgroundSubtractionDetector(method=method)  # no warm-up at all
    for frame, _ in noisy_scene(np.random.default_rng(2), 25, start=None):
        assert len(det(frame)) == 0, f"frame {frame.index}"


def test_bgsub_is_deterministic_and_checks_frame_size():
    runs = []
    for _ in range(2):
        det = BackgroundSubtractionDetector(warmup=5)
        out = [det(f) for f, _ in noisy_scene(np.random.default_rng(3), 12, start=6)]
        runs.append(np.concatenate([d.boxes for d in out]))
    np.testing.assert_array_equal(runs[0], runs[1])
    with pytest.raises(InputError) as e:
        det(Frame(13, 0.5, np.zeros((H + 2, W, 3), np.uint8)))
    assert "frame 13" in _one_line(e)


# ---------------------------------------------------------------- real data

def _best_iou(det: Detections, gt_boxes: np.ndarray) -> float:
    if len(det) == 0 or len(gt_boxes) == 0:
        return 0.0
    return float(iou_matrix(det.boxes, gt_boxes).max())


@pytest.mark.parametrize("index", [1, 100])
def test_hog_finds_a_person_on_pets(index):
    seq = sequence("PETS09-S2L1")
    gt = read_mot(seq / "gt" / "gt.txt", "gt").ground_truth(index)
    gt_boxes = gt.boxes[~gt.ignore]
    img = cv2.imread(str(seq / "img1" / f"{index:06d}.jpg"))
    d = HOGPeopleDetector()(Frame(index, 0.0, img))
    assert len(d) >= 1
    assert np.all(np.diff(d.scores) <= 0)                     # best first
    assert _best_iou(d, gt_boxes) > 0.5


def test_hog_upscale_maps_boxes_back_to_original_pixels():
    seq = sequence("PETS09-S2L1")
    gt = read_mot(seq / "gt" / "gt.txt", "gt").ground_truth(1)
    img = cv2.imread(str(seq / "img1" / "000001.jpg"))
    d = HOGPeopleDetector(upscale=1.5)(Frame(1, 0.0, img))
    assert _best_iou(d, gt.boxes[~gt.ignore]) > 0.5
    # trimmed Dalal-Triggs window: person box 32x96 out of 64x128
    np.testing.assert_allclose(d.boxes[:, 2] / d.boxes[:, 3], 32 / 96, rtol=0.05)


@pytest.mark.parametrize("index,upscale", [(1, 1.0), (21, 1.0), (41, 2.0)])
def test_haar_finds_the_face_on_otb_girl(index, upscale):
    seq = sequence("OTB-Girl")
    gt = read_mot(seq / "gt" / "gt.txt", "gt").ground_truth(index)
    img = cv2.imread(str(seq / "img1" / f"{index:06d}.jpg"))
    d = HaarFaceDetector(upscale=upscale)(Frame(index, 0.0, img))
    assert len(d) >= 1
    assert _best_iou(d, gt.boxes) > 0.5
