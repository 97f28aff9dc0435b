"""The synthetic scene: determinism, detector statistics against their parameters, scene
events (entries, exits, occlusions), pixels, and the MOT folder writer."""

from __future__ import annotations

import configparser
from dataclasses import replace

import cv2
import numpy as np
import pytest

from pfscope.trackers.data.motio import read_mot
from pfscope.trackers.data.synthetic import SceneConfig, SyntheticScene, write_sequence
from pfscope.trackers.errors import InputError

SMALL = SceneConfig(frames=60, targets=6, width=320, height=240, seed=3)


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of (N,4) boxes a against (N,4) boxes b, row by row."""
    x0 = np.maximum(a[:, 0], b[:, 0])
    y0 = np.maximum(a[:, 1], b[:, 1])
    x1 = np.minimum(a[:, 0] + a[:, 2], b[:, 0] + b[:, 2])
    y1 = np.minimum(a[:, 1] + a[:, 3], b[:, 1] + b[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    return inter / (a[:, 2] * a[:, 3] + b[:, 2] * b[:, 3] - inter)


def _tables_equal(a, b) -> bool:
    return all(np.array_equal(getattr(a, c), getattr(b, c))
               for c in ("frame", "id", "boxes", "score", "cls", "vis"))


# -- determinism ------------------------------------------------------------------------------

def test_same_seed_same_scene_and_pixels_in_any_order():
    a, b = SyntheticScene(SMALL), SyntheticScene(SMALL)
    assert _tables_equal(a.gt, b.gt) and _tables_equal(a.det, b.det)
    assert np.array_equal(a.det_origin, b.det_origin)
    a.render(40)  # rendering other frames first must not change frame 7
    assert np.array_equal(a.render(7), b.render(7))

    c = SyntheticScene(replace(SMALL, seed=4))
    assert not (len(c.gt) == len(a.gt) and np.allclose(c.gt.boxes, a.gt.boxes))
    assert not (len(c.det) == len(a.det) and np.allclose(c.det.boxes, a.det.boxes))
    assert not np.array_equal(c.render(7), a.render(7))


def test_sensor_noise_is_per_frame_and_has_its_std():
    cfg = replace(SMALL, illumination=0.0)
    noisy = SyntheticScene(cfg)
    clean = SyntheticScene(replace(cfg, noise_std=0.0))  # same seed: same scene, no noise
    assert _tables_equal(noisy.gt, clean.gt)
    d = noisy.render(5).astype(float) - clean.render(5).astype(float)
    inner = d[20:-20, 20:-20]  # away from saturation; uint8 rounding adds 1/12 variance
    assert abs(inner.mean()) < 0.1
    assert abs(inner.std() - np.sqrt(cfg.noise_std**2 + 1 / 12)) < 0.1
    # different frames get different noise
    d2 = noisy.render(6).astype(float) - clean.render(6).astype(float)
    assert abs(np.corrcoef(d.ravel(), d2.ravel())[0, 1]) < 0.05


# -- detector statistics ----------------------------------------------------------------------

@pytest.mark.parametrize("p_detect,box_noise", [(0.9, 0.05), (0.6, 0.1)])
def test_detection_rate_and_box_noise_match_parameters(p_detect, box_noise):
    cfg = SceneConfig(frames=200, targets=8, width=320, height=240, seed=11,
                      p_detect=p_detect, box_noise=box_noise, clutter=1.0)
    s = SyntheticScene(cfg)
    gt, det = s.gt, s.det
    true = s.det_origin > 0
    # every true detection belongs to a detectable gt row of the same frame and id
    gt_key = {(int(f), int(i)): r for r, (f, i) in enumerate(zip(gt.frame, gt.id))}
    rows = np.array([gt_key[(int(f), int(i))] for f, i in zip(det.frame[true],
                                                              s.det_origin[true])])
    assert len(set(rows.tolist())) == len(rows)  # at most one detection per target and frame
    detectable = gt.vis >= cfg.min_vis_detect
    assert detectable[rows].all()
    n = int(detectable.sum())
    assert n > 400
    rate = len(rows) / n
    assert abs(rate - p_detect) < 4 * np.sqrt(p_detect * (1 - p_detect) / n)

    # box noise: centre and size errors / gt size have std box_noise (4 sigma of a std estimate)
    g, d = gt.boxes[rows], det.boxes[true]
    err = np.concatenate([((d[:, 0] + d[:, 2] / 2) - (g[:, 0] + g[:, 2] / 2)) / g[:, 2],
                          ((d[:, 1] + d[:, 3] / 2) - (g[:, 1] + g[:, 3] / 2)) / g[:, 3],
                          (d[:, 2] - g[:, 2]) / g[:, 2], (d[:, 3] - g[:, 3]) / g[:, 3]])
    assert abs(err.std() - box_noise) < 4 * box_noise / np.sqrt(2 * len(err))
    assert abs(err.mean()) < 4 * box_noise / np.sqrt(len(err))
    # true detections score higher than clutter on average
    assert det.score[true].mean() > det.score[s.det_origin == 0].mean() + 0.2


def test_all_detectable_targets_found_when_p_detect_is_one():
    # label-free: with no clutter and p_detect = 1, det rows are exactly the detectable gt rows
    cfg = replace(SMALL, p_detect=1.0, clutter=0.0, persistent_clutter=0, box_noise=0.0)
    s = SyntheticScene(cfg)
    keep = s.gt.vis >= cfg.min_vis_detect
    assert len(s.det) == keep.sum()
    for f in (10, 30, 50):
        g = s.gt.boxes[(s.gt.frame == f) & keep]
        d = s.det.boxes[s.det.frame == f]
        order_g, order_d = np.lexsort(g.T[::-1]), np.lexsort(d.T[::-1])
        assert np.allclose(g[order_g], d[order_d], atol=1e-3)


@pytest.mark.parametrize("clutter", [0.5, 3.0])
def test_clutter_rate_matches_poisson_parameter(clutter):
    frames = 400
    # label-free: nothing else can fire, so every row is Poisson clutter
    cfg = SceneConfig(frames=frames, targets=4, width=320, height=240, seed=5, clutter=clutter,
                      p_detect=0.0, persistent_clutter=0)
    s = SyntheticScene(cfg)
    assert (s.det_origin == 0).all()
    counts = np.bincount(s.det.frame, minlength=frames + 1)[1:]
    assert abs(counts.mean() - clutter) < 4 * np.sqrt(clutter / frames)
    assert abs(counts.var() - clutter) < 0.25 * clutter + 0.1  # Poisson: variance = mean
    b = s.det.boxes  # person-sized and inside the image
    assert (b[:, 0] >= 0).all() and (b[:, 0] + b[:, 2] <= cfg.width + 1e-3).all()
    assert (b[:, 3] >= cfg.height_far * cfg.height - 1e-3).all()
    assert (b[:, 3] <= cfg.height_near * cfg.height + 1e-3).all()

    # with targets and spots on, the rows labelled clutter keep the same rate
    s2 = SyntheticScene(replace(cfg, p_detect=0.9, persistent_clutter=2))
    n_clutter = (s2.det_origin == 0).sum()
    assert abs(n_clutter / frames - clutter) < 4 * np.sqrt(clutter / frames)


def test_persistent_spots_fire_at_their_place_with_their_probability():
    frames, prob = 300, 0.7
    cfg = SceneConfig(frames=frames, targets=3, width=320, height=240, seed=9, clutter=0.0,
                      p_detect=0.0, persistent_clutter=3, persistent_prob=prob)
    s = SyntheticScene(cfg)
    assert s.spots.shape == (3, 4)
    det = s.det
    for j, spot in enumerate(s.spots):
        near = _iou(det.boxes, np.broadcast_to(spot, det.boxes.shape)) > 0.8
        frames_hit = np.unique(det.frame[near])
        assert len(frames_hit) == near.sum()  # one detection per frame at most
        rate = len(frames_hit) / frames
        assert abs(rate - prob) < 4 * np.sqrt(prob * (1 - prob) / frames)
        assert (s.det_origin[near] == -(j + 1)).all()
    # every row is at some spot
    assert len(det) == sum((s.det_origin == -(j + 1)).sum() for j in range(3))


# -- scene events ----------------------------------------------------------------------------

@pytest.mark.parametrize("seed", [0, 1, 2])
def test_targets_enter_and_leave_through_the_borders(seed):
    cfg = SceneConfig(frames=150, targets=6, width=320, height=240, seed=seed)
    s = SyntheticScene(cfg)
    gt = s.gt
    ids = np.unique(gt.id)
    assert len(ids) == cfg.targets
    first = np.array([gt.frame[gt.id == i].min() for i in ids])
    last = np.array([gt.frame[gt.id == i].max() for i in ids])
    assert ((first > 1) & (last < cfg.frames)).any()
    assert len(np.unique(first)) >= cfg.targets - 1  # staggered entries
    for i, f0, f1 in zip(ids, first, last):
        for f in ([f0] if f0 > 1 else []) + ([f1] if f1 < cfg.frames else []):
            b = gt.boxes[(gt.id == i) & (gt.frame == f)][0]
            assert b[0] < 0 or b[0] + b[2] > cfg.width  # at the border, partly outside
        rows = gt.id == i
        assert np.all(np.diff(gt.frame[rows]) == 1)  # no gaps: one continuous walk


def test_occlusions_happen_and_vis_is_a_fraction():
    s = SyntheticScene(SceneConfig(frames=150, targets=6, width=320, height=240, seed=0))
    gt = s.gt
    assert ((gt.vis >= 0) & (gt.vis <= 1)).all()
    inside = (gt.boxes[:, 0] >= 0) & (gt.boxes[:, 0] + gt.boxes[:, 2] <= 320) \
        & (gt.boxes[:, 1] >= 0) & (gt.boxes[:, 1] + gt.boxes[:, 3] <= 240)
    occluded = inside & (gt.vis < 1)
    assert occluded.sum() >= 3
    assert (gt.vis[inside] < 0.5).any()  # some heavy occlusion (a miss for the detector)
    # an occluded figure overlaps a larger-footed (nearer) figure in the same frame
    r = np.flatnonzero(occluded)[0]
    same = (gt.frame == gt.frame[r]) & (gt.id != gt.id[r])
    feet = gt.boxes[:, 1] + gt.boxes[:, 3]
    ov = _iou(gt.boxes[same], np.broadcast_to(gt.boxes[r], (same.sum(), 4))) > 0
    assert (feet[same][ov] > feet[r]).any()
    # sizes follow the perspective: farther (higher feet) figures are smaller
    assert np.corrcoef(feet, gt.boxes[:, 3])[0, 1] > 0.99


def test_figures_are_drawn_inside_their_gt_boxes():
    cfg = replace(SMALL, noise_std=0.0, illumination=0.0)
    s = SyntheticScene(cfg)
    for f in (5, 25, 45):
        diff = np.abs(s.render(f).astype(int) - s.background.astype(int)).max(axis=2) > 0
        inbox = np.zeros_like(diff)
        for b in s.gt.ground_truth(f).boxes:
            x0, y0 = int(np.floor(b[0])) - 1, int(np.floor(b[1])) - 1
            x1, y1 = int(np.ceil(b[0] + b[2])) + 1, int(np.ceil(b[1] + b[3])) + 1
            inbox[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = True
            if b[0] >= 0 and b[0] + b[2] <= cfg.width:  # a visible figure changes its box
                assert diff[max(y0, 0):y1, x0:x1].mean() > 0.15
        assert not (diff & ~inbox).any()


def test_illumination_drifts_slowly():
    cfg = replace(SMALL, frames=200, targets=0, illumination=0.2, illumination_period=10.0)
    s = SyntheticScene(cfg)
    gains = np.array([s.illumination_gain(i) for i in range(1, 201)])
    assert gains.max() - gains.min() > 0.35 and np.abs(np.diff(gains)).max() < 0.02
    bg = s.background.astype(float).mean()
    for i in (int(gains.argmax()) + 1, int(gains.argmin()) + 1):
        assert abs(s.render(i).astype(float).mean() / bg - gains[i - 1]) < 0.03


def test_frames_and_seqinfo():
    cfg = replace(SMALL, frames=4, fps=5.0)
    s = SyntheticScene(cfg)
    frames = list(s.frames())
    assert [f.index for f in frames] == [1, 2, 3, 4]
    assert np.allclose([f.timestamp for f in frames], [0, 0.2, 0.4, 0.6])
    assert frames[2].image.shape == (240, 320, 3) and frames[2].image.dtype == np.uint8
    assert np.array_equal(frames[2].image, s.render(3))
    info = s.seqinfo()
    assert info["seqLength"] == 4 and info["imWidth"] == 320 and info["imHeight"] == 240
    assert info["frameRate"] == 5.0 and info["imExt"] == ".jpg" and info["name"]
    with pytest.raises(InputError):
        s.render(5)
    with pytest.raises(InputError):
        s.render(0)


@pytest.mark.parametrize("bad", [dict(p_detect=1.5), dict(frames=0), dict(clutter=-1.0),
                                 dict(seed=-2), dict(box_noise=-0.1)])
def test_bad_config_is_an_input_error(bad):
    with pytest.raises(InputError):
        SceneConfig(**bad)


# -- MOT folder --------------------------------------------------------------------------------

def test_write_sequence_round_trips_and_refuses_non_empty_dir(tmp_path):
    cfg = SceneConfig(frames=12, targets=4, width=160, height=120, seed=2, clutter=1.5)
    calls = []
    out = write_sequence(tmp_path / "seq", cfg, progress=lambda i, n: calls.append((i, n)))
    assert out == tmp_path / "seq"
    assert calls == [(i, 12) for i in range(1, 13)]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]  # no temp folder left behind
    imgs = sorted((out / "img1").iterdir())
    assert [p.name for p in imgs] == [f"{i:06d}.jpg" for i in range(1, 13)]
    scene = SyntheticScene(cfg)
    img = cv2.imread(str(imgs[4]))
    assert img.shape == (120, 160, 3)
    # the JPEG of the same frame (JPEG smooths the sensor noise, so compare blurred frames)
    def blur(im):
        return cv2.GaussianBlur(im.astype(np.float32), (0, 0), 1.5)
    assert np.abs(blur(img) - blur(scene.render(5))).mean() < 1.2

    cp = configparser.ConfigParser()
    cp.read(out / "seqinfo.ini")
    seq = cp["Sequence"]
    assert int(seq["seqLength"]) == 12 and float(seq["frameRate"]) == cfg.fps
    assert int(seq["imWidth"]) == 160 and int(seq["imHeight"]) == 120
    assert seq["imDir"] == "img1" and seq["imExt"] == ".jpg"

    gt, det = read_mot(out / "gt" / "gt.txt", "gt"), read_mot(out / "det" / "det.txt", "det")
    for mine, back in ((scene.gt, gt), (scene.det, det)):
        assert len(back) == len(mine) > 0
        assert np.array_equal(back.frame, mine.frame) and np.array_equal(back.id, mine.id)
        for col in ("boxes", "score", "cls", "vis"):
            assert np.allclose(getattr(back, col), getattr(mine, col), atol=1e-6, rtol=0), col

    # a non-empty folder is refused and left as it was; an empty one is accepted
    with pytest.raises(InputError, match="not empty"):
        write_sequence(out, cfg)
    assert len(list((out / "img1").iterdir())) == 12
    (tmp_path / "empty").mkdir()
    write_sequence(tmp_path / "empty", replace(cfg, frames=2))
    assert (tmp_path / "empty" / "det" / "det.txt").is_file()
    (tmp_path / "afile").write_text("x")
    with pytest.raises(InputError):
        write_sequence(tmp_path / "afile", cfg)
