"""The built-in synthetic scene: rendered pedestrians with exact ground truth and a simulated
detector, so trackers and metrics can be exercised (and compared) without real video.

The detector simulation follows the observation model of maggio2007 §2–§4: each visible target
produces an observation ``z = (y, w, h)`` with probability ``1 - p_M`` (``p_M`` uniform, §4),
the observation noise is Gaussian with standard deviations *proportional to the box size*
(§4, "standard deviations proportional to the sizes w and h"), and clutter is a Poisson point
process (§3, clutter intensity κ_k(z)).  On top of that the scene has *persistent* clutter
spots: fixed places that fire on most frames.  maggio2007 §5 notes that the PHD filter removes
clutter "when the clutter is not persistent" — persistent spots are the hard case where the
filtered mass builds up exactly as for a real target, so a scene needs both kinds to show
what the filter does and where it stops.

Scene (all sizes are fractions of the image, so a reduced-resolution scene is the same scene):

- Static textured background: sky, a row of buildings with windows, a paved ground plane with
  perspective tile lines, low-frequency shading and fine grain.
- Slow global illumination drift: gain ``1 + A sin(2π t / T + φ)`` applied to the whole frame.
- Per-frame Gaussian sensor noise from a Generator seeded by ``(seed, frame index)``, so any
  frame can be rendered alone and in any order.
- Walking person-like figures (hair/face ellipses, torso polygon, swinging arms and legs drawn
  with OpenCV fill/line functions) with distinct shirt/trouser colours.  Figures stand on a flat
  ground plane: image height ``h = k (y_feet - y_horizon)`` (pinhole camera over a plane), so
  farther figures are smaller (60–140 px at 640x480).  Figures walk along straight lines and
  enter and leave through the left/right image borders at staggered times.  Targets come in
  pairs that meet at a common point walking in opposite directions with a small depth offset,
  so every pair crosses and the nearer figure occludes the farther one.
- Ground truth: the figure's full box (``x, y, w, h``, not clipped to the image), present while
  at least one pixel column of it is inside the image; ``vis`` is the exact fraction of the box
  that is inside the image and not covered by the boxes of nearer figures.
- Detector: a target with ``vis >= min_vis_detect`` is detected with probability ``p_detect``;
  box centre and size get Gaussian noise with std ``box_noise * w`` (x, w) and
  ``box_noise * h`` (y, h); ``Poisson(clutter)`` clutter boxes per frame with person-like sizes
  anywhere in the image; ``persistent_clutter`` fixed spots each firing with probability
  ``persistent_prob`` per frame with jitter ``persistent_jitter`` (fraction of the spot size).
  Scores are Beta-distributed: higher for true detections than for clutter.

Background-subtraction noise (off by default; ``bg_noise = flicker = 0`` leaves every pixel of a
scene unchanged and draws nothing from any random stream): ``bg_noise`` is the mean number of
*noise patches* starting per frame (Poisson), each an axis-aligned blotch of random colour,
texture and shape (ellipse or rectangle, 0.02–0.25 of the image height, some person-sized),
lasting 1–``bg_noise_duration`` frames at a fixed place, plus salt-and-pepper specks; this is
what feng2015 §II-B/Fig. 2 calls noise patches and salt and pepper.  ``flicker`` is the std of a
per-frame global gain jump ``1 + flicker·N(0, 1)`` (illumination flicker) on top of the slow
drift.  They come from their own streams, so turning them on changes no trajectory, detection
or other pixel noise; they are not in ``det``/``gt`` (pixels only: a background-subtraction
tracker sees them, a detections-file tracker does not).

Everything derives from ``SceneConfig.seed`` through named :class:`numpy.random.SeedSequence`
streams: the same config gives identical ground truth, detections and pixels.
"""

from __future__ import annotations

import math
import os
import secrets
import shutil
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Callable, Iterator, Optional

import cv2
import numpy as np
from scipy.special import ndtri

from ..errors import InputError
from ..types import Frame
from .motio import MotTable, write_mot

# Independent random streams (spawn keys of SeedSequence(seed)); frames use (_FRAME, index).
_TRAJ, _LOOK, _BACKGROUND, _DETECT, _FRAME = 0, 1, 2, 3, 1000
_BGNOISE, _FLICKER = 2000, 2001  # background-subtraction noise (off by default)
_SUBPIX = 4  # OpenCV fixed-point shift: coordinates in 1/16 px, so motion is smooth
_AA_INSET = 1.0  # px: OpenCV's anti-aliased edges spread about one pixel past the geometry
_NOISE_LEVELS = 65536  # size of the Gaussian quantile table used for sensor noise


@dataclass(frozen=True)
class SceneConfig:
    """Parameters of the synthetic scene.  Sizes are fractions of the image height (h) or width.

    ``targets`` is the number of distinct people over the whole sequence (not at once).
    """

    frames: int = 150
    targets: int = 6
    width: int = 640
    height: int = 480
    fps: float = 10.0
    clutter: float = 2.0            # mean Poisson clutter detections per frame
    persistent_clutter: int = 2     # fixed clutter spots
    persistent_prob: float = 0.8    # per-frame firing probability of a spot
    p_detect: float = 0.9           # detection probability of a visible target (1 - p_M)
    box_noise: float = 0.05         # detection box noise std, fraction of box w / h
    seed: int = 0
    name: str = "synthetic"
    min_vis_detect: float = 0.5     # a target is detectable when vis >= this
    persistent_jitter: float = 0.02  # spot box jitter std, fraction of spot w / h
    # ground plane / perspective (fractions of image height)
    horizon: float = 0.35           # y of the horizon line
    feet_near: float = 0.97         # lowest feet position (nearest figures)
    height_near: float = 0.29       # figure height at feet_near (140 px of 480)
    height_far: float = 0.125       # figure height at the farthest feet position (60 px of 480)
    aspect: tuple = (0.36, 0.44)    # figure width / height range
    speed: tuple = (0.6, 1.0)       # walking speed, body heights per second
    stride: float = 0.8             # distance per gait cycle, body heights
    max_slope: float = 0.3          # |dy/dx| of a walking path
    cross_offset: tuple = (0.1, 0.4)  # depth offset of a crossing pair, figure heights
    # detector scores: Beta(a, b) per origin
    score_true: tuple = (8.0, 2.0)
    score_clutter: tuple = (2.0, 4.0)
    score_persistent: tuple = (5.0, 3.0)
    # appearance of the pixels
    noise_std: float = 3.0          # sensor noise std, grey levels
    illumination: float = 0.12      # amplitude of the brightness drift (fraction)
    illumination_period: float = 20.0  # seconds per brightness cycle
    jpeg_quality: int = 95
    # background-subtraction noise (module docstring); 0 = off, the scene is unchanged
    bg_noise: float = 0.0           # mean noise patches starting per frame (Poisson)
    bg_noise_duration: int = 8      # a patch lasts 1..this many frames
    flicker: float = 0.0            # std of the per-frame global gain jump

    def __post_init__(self):
        def bad(msg):
            raise InputError(f"synthetic scene: {msg}")

        for name in ("frames", "targets", "width", "height", "persistent_clutter", "seed",
                     "jpeg_quality"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                bad(f"{name} must be an integer, got {v!r}")
        if self.frames < 1:
            bad(f"frames must be >= 1, got {self.frames}")
        if self.targets < 0 or self.persistent_clutter < 0:
            bad("targets and persistent_clutter must be >= 0")
        if self.width < 32 or self.height < 32:
            bad(f"image must be at least 32x32, got {self.width}x{self.height}")
        if self.seed < 0:
            bad(f"seed must be >= 0, got {self.seed}")
        if not (self.fps > 0 and math.isfinite(self.fps)):
            bad(f"fps must be positive, got {self.fps}")
        if not (self.clutter >= 0 and math.isfinite(self.clutter)):
            bad(f"clutter must be >= 0, got {self.clutter}")
        for name in ("p_detect", "persistent_prob", "min_vis_detect"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                bad(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if not (self.bg_noise >= 0 and math.isfinite(self.bg_noise)):
            bad(f"bg_noise must be >= 0, got {self.bg_noise}")
        if not (0 <= self.flicker < 1):
            bad(f"flicker must be in [0, 1), got {self.flicker}")
        if isinstance(self.bg_noise_duration, bool) or \
                not isinstance(self.bg_noise_duration, (int, np.integer)) or \
                self.bg_noise_duration < 1:
            bad(f"bg_noise_duration must be an integer >= 1, got {self.bg_noise_duration!r}")
        if self.box_noise < 0 or self.persistent_jitter < 0 or self.noise_std < 0:
            bad("box_noise, persistent_jitter and noise_std must be >= 0")
        if not 0 <= self.horizon < self.feet_near <= 1:
            bad("need 0 <= horizon < feet_near <= 1")
        if not 0 < self.height_far < self.height_near:
            bad("need 0 < height_far < height_near")
        if self.feet_far >= self.feet_near or self.feet_near - self.height_near < 0:
            bad("figure heights do not fit between horizon and feet_near")
        for name in ("aspect", "speed", "cross_offset", "score_true", "score_clutter",
                     "score_persistent"):
            lo_hi = getattr(self, name)
            is_range = name in ("aspect", "speed", "cross_offset")
            if len(lo_hi) != 2 or not (lo_hi[0] > 0 and lo_hi[1] > 0) or (
                    is_range and lo_hi[0] > lo_hi[1]):
                bad(f"{name} must be a pair of positive numbers (low, high), got {lo_hi!r}")
        if not 0 <= self.illumination < 1 or self.illumination_period <= 0 or self.stride <= 0:
            bad("need 0 <= illumination < 1, illumination_period > 0, stride > 0")
        if not 1 <= self.jpeg_quality <= 100:
            bad(f"jpeg_quality must be in 1..100, got {self.jpeg_quality}")

    # Pinhole camera over a flat ground: h = k (y_feet - y_horizon) (fractions of image height).
    @property
    def ground_k(self) -> float:
        return self.height_near / (self.feet_near - self.horizon)

    @property
    def feet_far(self) -> float:
        """Highest (farthest) feet position, where a figure is ``height_far`` tall."""
        return self.horizon + self.height_far / self.ground_k


#: The built-in scene as ``pfscope record`` (no source), ``compare`` and ``synth`` show it:
#: the :class:`SceneConfig` defaults with the two persistent clutter spots firing in 35 % of the
#: frames instead of 80 %.  Still clutter and misses to learn from (2 Poisson clutter boxes a
#: frame, p_D 0.9, crossings), but no spot that fires almost every frame -- which no tracker
#: can tell from a person standing still, and which made the first picture a user sees one of
#: two false tracks (PHD-MT MOTA 0.19 on seed 0; 0.81-0.86 on seeds 0-2 with this scene).
DEMO_SCENE = {"persistent_prob": 0.35}


def demo_config(**overrides) -> "SceneConfig":
    """The built-in scene (:data:`DEMO_SCENE` over the defaults) with ``overrides``."""
    return SceneConfig(**{**DEMO_SCENE, **overrides})


def _rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


# ---------------------------------------------------------------------------------------------
# trajectories and ground truth


def _trajectories(cfg: SceneConfig, rng: np.random.Generator):
    """Straight walks on the ground plane. Returns per-target arrays: meeting frame t_m, feet
    point (x_m, y_m) at t_m, velocity (vx, vy) in px/frame, aspect, gait phase at t_m, phase
    rate (rad/frame). Targets 2g and 2g+1 meet at the same x at frame t_m (a crossing)."""
    K, F, W, H = cfg.targets, cfg.frames, cfg.width, cfg.height
    y_lo, y_hi = cfg.feet_far * H, cfg.feet_near * H
    band = y_hi - y_lo
    groups = (K + 1) // 2
    t_m, x_m, y_m = np.zeros(K), np.zeros(K), np.zeros(K)
    direction = np.zeros(K)
    for g in range(groups):
        members = [i for i in (2 * g, 2 * g + 1) if i < K]
        # staggered meetings spread over the sequence -> staggered entries and exits
        tg = 1.0 + (F - 1) * (g + rng.uniform(0.25, 0.75)) / groups
        xg = rng.uniform(0.25, 0.75) * W
        yg = rng.uniform(y_lo + 0.15 * band, y_hi - 0.15 * band)
        d0 = rng.choice([-1.0, 1.0])
        t_m[members] = tg
        x_m[members] = xg
        y_m[members[0]] = yg
        direction[members[0]] = d0
        if len(members) == 2:
            # partner walks the other way with a depth offset so the nearer one occludes
            hg = _height_at(cfg, yg)
            off = rng.uniform(*cfg.cross_offset) * hg * rng.choice([-1.0, 1.0])
            if not y_lo <= yg + off <= y_hi:
                off = -off
            y_m[members[1]] = np.clip(yg + off, y_lo, y_hi)
            direction[members[1]] = -d0
    h_m = _height_at(cfg, y_m)
    speed = rng.uniform(*cfg.speed, size=K)  # body heights per second
    v = speed * h_m / cfg.fps  # px per frame
    # slope bounded so the feet stay on the ground band while the figure can be in the image
    xa, xb = -0.25 * W, 1.25 * W
    s_hi = np.minimum((y_hi - y_m) / (xb - x_m), (y_m - y_lo) / (x_m - xa))
    s_lo = -np.minimum((y_m - y_lo) / (xb - x_m), (y_hi - y_m) / (x_m - xa))
    s_hi = np.minimum(s_hi, cfg.max_slope)
    s_lo = np.maximum(s_lo, -cfg.max_slope)
    slope = s_lo + (s_hi - s_lo) * rng.random(K)
    vx = direction * v / np.sqrt(1.0 + slope**2)
    vy = np.abs(vx) * slope
    aspect = rng.uniform(*cfg.aspect, size=K)
    phase0 = rng.uniform(0, 2 * np.pi, size=K)
    # one gait cycle per `stride` body heights walked
    phase_rate = 2 * np.pi * speed / (cfg.fps * cfg.stride)
    return dict(t_m=t_m, x_m=x_m, y_m=y_m, vx=vx, vy=vy, aspect=aspect, phase0=phase0,
                phase_rate=phase_rate)


def _height_at(cfg: SceneConfig, y_feet):
    return cfg.ground_k * (np.asarray(y_feet, dtype=np.float64) - cfg.horizon * cfg.height)


def _uncovered_area(box: np.ndarray, occ: np.ndarray) -> float:
    """Exact area of ``box`` (x0, y0, x1, y1) not covered by the union of ``occ`` (M, 4),
    by coordinate compression: the box edges and occluder edges cut it into cells that are
    either fully covered or fully free."""
    occ = occ.copy()
    occ[:, [0, 2]] = np.clip(occ[:, [0, 2]], box[0], box[2])
    occ[:, [1, 3]] = np.clip(occ[:, [1, 3]], box[1], box[3])
    xs = np.unique(np.concatenate([box[[0, 2]], occ[:, 0], occ[:, 2]]))
    ys = np.unique(np.concatenate([box[[1, 3]], occ[:, 1], occ[:, 3]]))
    cx, cy = (xs[:-1] + xs[1:]) / 2, (ys[:-1] + ys[1:]) / 2
    inx = (occ[:, 0, None] <= cx) & (cx <= occ[:, 2, None])  # (M, nx)
    iny = (occ[:, 1, None] <= cy) & (cy <= occ[:, 3, None])  # (M, ny)
    covered = (inx[:, :, None] & iny[:, None, :]).any(axis=0)  # (nx, ny)
    area = np.diff(xs)[:, None] * np.diff(ys)[None, :]
    return float(area[~covered].sum())


def _visibility(boxes: np.ndarray, present: np.ndarray, rank: np.ndarray, W: int, H: int):
    """(F, K) visible fraction of each box: inside the image and not behind a nearer box."""
    x0, y0 = boxes[..., 0], boxes[..., 1]
    x1, y1 = x0 + boxes[..., 2], y0 + boxes[..., 3]
    clipped = np.stack([np.clip(x0, 0, W), np.clip(y0, 0, H), np.clip(x1, 0, W),
                        np.clip(y1, 0, H)], axis=-1)  # (F, K, 4)
    full = boxes[..., 2] * boxes[..., 3]
    inside = (clipped[..., 2] - clipped[..., 0]) * (clipped[..., 3] - clipped[..., 1])
    vis = np.where(present, inside / full, 0.0)
    # pairs (i occluded by j): both present, j nearer, clipped boxes intersect
    ix = (np.minimum(clipped[:, :, None, 2], clipped[:, None, :, 2])
          - np.maximum(clipped[:, :, None, 0], clipped[:, None, :, 0]))
    iy = (np.minimum(clipped[:, :, None, 3], clipped[:, None, :, 3])
          - np.maximum(clipped[:, :, None, 1], clipped[:, None, :, 1]))
    occl = ((ix > 0) & (iy > 0) & present[:, :, None] & present[:, None, :]
            & (rank[:, None, :] > rank[:, :, None]))
    for f, i in zip(*np.nonzero(occl.any(axis=2))):
        free = _uncovered_area(clipped[f, i], clipped[f, occl[f, i]])
        vis[f, i] = free / full[f, i]
    return np.clip(vis, 0.0, 1.0)


# ---------------------------------------------------------------------------------------------
# appearance


def _distinct_colours(rng: np.random.Generator, n: int, sat, val) -> np.ndarray:
    """(n, 3) uint8 BGR colours with hues spread by the golden ratio (well separated for any n)."""
    if n == 0:
        return np.zeros((0, 3), np.uint8)
    hue = (rng.random() + np.arange(n) * 0.6180339887) % 1.0
    hsv = np.stack([np.round(hue * 179), np.round(rng.uniform(*sat, n) * 255),
                    np.round(rng.uniform(*val, n) * 255)], axis=-1).astype(np.uint8)
    return cv2.cvtColor(hsv[:, None, :], cv2.COLOR_HSV2BGR)[:, 0, :]


def _make_background(cfg: SceneConfig, rng: np.random.Generator) -> np.ndarray:
    """Static (H, W, 3) uint8 scene: sky, buildings with windows, paved ground, texture."""
    W, H = cfg.width, cfg.height
    img = np.zeros((H, W, 3), np.float32)
    horizon = cfg.horizon * H
    base = int(round(cfg.feet_far * H - 0.03 * H))  # buildings stand just behind the far walkers
    yy = np.arange(H, dtype=np.float32)[:, None]
    a = (yy[:base] / max(base, 1))[..., None]
    img[:base] = (1 - a) * np.array([205, 170, 140], np.float32) + a * np.array([225, 215, 205],
                                                                                 np.float32)
    x = int(rng.uniform(-0.05, 0.02) * W)
    while x < W:
        bw = int(rng.uniform(0.08, 0.22) * W) + 1
        x0, x1 = max(x, 0), min(W, x + bw)
        if rng.random() < 0.85 and x1 > x0:
            top = int(rng.uniform(0.05, 0.7) * base)
            colour = rng.uniform(80, 175) + rng.normal(0, 12, 3)
            img[top:base, x0:x1] = colour
            sy, sx = rng.uniform(0.035, 0.06) * H, rng.uniform(0.03, 0.05) * W
            ry = (np.arange(top, base) - top - 0.3 * sy) % sy
            rx = (np.arange(x0, x1) - x0 - 0.3 * sx) % sx
            mask = (ry < 0.5 * sy)[:, None] & (rx < 0.55 * sx)[None, :]
            rows = ((np.arange(top, base) - top) // sy).astype(int)
            cols = ((np.arange(x0, x1) - x0) // sx).astype(int)
            lit = rng.random((rows.max() + 1, cols.max() + 1)) < 0.3
            win = np.where(lit[rows[:, None], cols[None, :]][..., None],
                           np.array([120, 200, 230], np.float32), np.array([90, 70, 60],
                                                                           np.float32))
            block = img[top:base, x0:x1]
            block[mask] = win[mask]
        x = x1 + int(rng.uniform(0, 0.03) * W)
    # paved ground, darker towards the camera
    g = ((yy[base:] - base) / max(H - base, 1))[..., None]
    img[base:] = (1 - g) * np.array([150, 160, 168], np.float32) + g * np.array([105, 115, 122],
                                                                                np.float32)
    line = (90, 98, 104)
    vx = W / 2.0
    s = (base - horizon) / (H - horizon)
    for xb in np.linspace(-1.5 * W, 2.5 * W, 29):  # tile seams converging to the vanishing point
        cv2.line(img, (int(vx + (xb - vx) * s), base), (int(xb), H), line, 1, cv2.LINE_AA)
    d = 1.0
    while True:  # cross seams at equal ground spacing: y = horizon + c / depth
        y = horizon + (H - horizon) / d
        if y < base:
            break
        cv2.line(img, (0, int(y)), (W, int(y)), line, 1, cv2.LINE_AA)
        d += 0.35
    for _ in range(3):  # a few benches / planters
        bh = rng.uniform(0.02, 0.04) * H
        by = rng.uniform(base + bh, H - 0.02 * H)
        bx = rng.uniform(0, W)
        bwid = rng.uniform(0.05, 0.12) * W * (by - horizon) / (H - horizon)
        cv2.rectangle(img, (int(bx), int(by - bh)), (int(bx + bwid), int(by)),
                      (50, 75 + rng.uniform(0, 40), 60), -1)
    # low-frequency shading and fine grain (sensor noise is added per frame, not here)
    lf = rng.standard_normal((H // 32 + 3, W // 32 + 3)).astype(np.float32)
    img += 9.0 * cv2.resize(lf, (W, H), interpolation=cv2.INTER_CUBIC)[..., None]
    grain = cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), 0.8)
    img += 10.0 * grain[..., None]
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def _pt(x, y):
    return (int(round(x * (1 << _SUBPIX))), int(round(y * (1 << _SUBPIX))))


def _draw_figure(img: np.ndarray, box, phase: float, look) -> None:
    """A side-view walker that fills its box: hair/face ellipses, torso, arms and legs that
    swing in opposite phase.  Every part stays inside ``box`` (the ground-truth extent)."""
    x, y, w, h = box
    # inset by the ~1 px anti-aliasing feather so no painted pixel leaves the box
    x, y, w, h = x + _AA_INSET, y + _AA_INSET, w - 2 * _AA_INSET, h - 2 * _AA_INSET
    cx = x + w / 2
    shirt, trousers, skin, hair = look
    sw = math.sin(phase)
    t_leg = max(1, int(round(0.2 * w)))
    t_arm = max(1, int(round(0.13 * w)))
    hip, foot = y + 0.5 * h, y + h - t_leg / 2
    reach = 0.5 * w - t_leg / 2 - 0.02 * w  # foot swing amplitude that keeps the leg inside
    back = tuple(int(c * 0.75) for c in trousers)
    cv2.line(img, _pt(cx, hip), _pt(cx - reach * sw, foot), back, t_leg, cv2.LINE_AA, _SUBPIX)
    sleeve_back = tuple(int(c * 0.75) for c in shirt)
    hand = 0.5 * w - t_arm / 2 - 0.08 * w
    sh = y + 0.19 * h
    cv2.line(img, _pt(cx, sh), _pt(cx + hand * sw, y + 0.5 * h), sleeve_back, t_arm, cv2.LINE_AA,
             _SUBPIX)
    torso = np.array([_pt(cx - 0.26 * w, y + 0.16 * h), _pt(cx + 0.26 * w, y + 0.16 * h),
                      _pt(cx + 0.22 * w, y + 0.54 * h), _pt(cx - 0.22 * w, y + 0.54 * h)],
                     np.int32)
    cv2.fillConvexPoly(img, torso, shirt, cv2.LINE_AA, _SUBPIX)
    cv2.line(img, _pt(cx, hip), _pt(cx + reach * sw, foot), trousers, t_leg, cv2.LINE_AA,
             _SUBPIX)
    cv2.line(img, _pt(cx, sh), _pt(cx - hand * sw, y + 0.5 * h), shirt, t_arm, cv2.LINE_AA,
             _SUBPIX)
    s = 1 << _SUBPIX
    cv2.ellipse(img, _pt(cx, y + 0.075 * h), (int(0.058 * h * s), int(0.075 * h * s)), 0, 0, 360,
                hair, -1, cv2.LINE_AA, _SUBPIX)
    cv2.ellipse(img, _pt(cx, y + 0.088 * h), (int(0.05 * h * s), int(0.06 * h * s)), 0, 0, 360,
                skin, -1, cv2.LINE_AA, _SUBPIX)


# ---------------------------------------------------------------------------------------------


class SyntheticScene:
    """A seeded synthetic sequence: trajectories, ground truth and detections are computed at
    construction (cheap arrays); pixels are rendered on demand by :meth:`render`.

    Attributes: ``config``; ``gt`` (MOT gt: conf=1, class=1, vis in [0, 1]); ``det`` (MOT det,
    id=-1, score filled); ``det_origin (N,) int64`` aligned with ``det`` rows: the target id of a
    true detection, 0 for Poisson clutter, ``-(j+1)`` for persistent spot ``j``;
    ``spots (P, 4)`` the persistent spot boxes; ``boxes (F, K, 4)``, ``present (F, K)``,
    ``vis (F, K)`` per frame and target (target ``k`` has id ``k + 1``).
    Values in ``gt``/``det`` are rounded to the 3 decimals the MOT files hold, so the scene in
    memory and the written folder are the same data.
    """

    def __init__(self, config: SceneConfig):
        self.config = cfg = config
        F, K, W, H = cfg.frames, cfg.targets, cfg.width, cfg.height
        self._traj = tr = _trajectories(cfg, _rng(cfg.seed, _TRAJ))
        t = np.arange(1, F + 1, dtype=np.float64)[:, None] - tr["t_m"][None, :]  # (F, K)
        xf = tr["x_m"] + tr["vx"] * t
        yf = tr["y_m"] + tr["vy"] * t
        h = _height_at(cfg, yf)
        w = tr["aspect"] * h
        self.boxes = np.stack([xf - w / 2, yf - h, w, h], axis=-1)  # (F, K, 4) full extent
        self.phase = tr["phase0"] + tr["phase_rate"] * t
        in_w = np.minimum(xf + w / 2, W) - np.maximum(xf - w / 2, 0)
        in_h = np.minimum(yf, H) - np.maximum(yf - h, 0)
        self.present = (in_w >= 1.0) & (in_h >= 1.0)
        # draw/depth order: larger feet y = nearer the camera; stable for ties
        self._order = np.argsort(yf, axis=1, kind="stable")  # (F, K) far -> near
        rank = np.argsort(self._order, axis=1, kind="stable")
        self.vis = _visibility(self.boxes, self.present, rank, W, H)

        fi, ki = np.nonzero(self.present)  # row-major: sorted by frame, then id
        self.gt = MotTable(frame=fi + 1, id=ki + 1, boxes=np.round(self.boxes[fi, ki], 3),
                           score=np.ones(len(fi)), cls=np.ones(len(fi)),
                           vis=np.round(self.vis[fi, ki], 3))

        look_rng = _rng(cfg.seed, _LOOK)
        shirts = _distinct_colours(look_rng, K, (0.55, 0.9), (0.6, 0.95))
        trousers = _distinct_colours(look_rng, K, (0.3, 0.7), (0.25, 0.55))
        skins = np.array([[120, 150, 200], [90, 125, 175], [60, 90, 140], [150, 180, 225]])
        skin = skins[look_rng.integers(0, len(skins), K)]
        hair = np.round(look_rng.uniform(15, 70, K)[:, None] * np.array([1.0, 1.1, 1.3]))
        self._looks = [tuple(tuple(int(c) for c in col) for col in (shirts[k], trousers[k],
                                                                    skin[k], hair[k]))
                       for k in range(K)]

        self._simulate_detector(_rng(cfg.seed, _DETECT), fi, ki)

    # -- detector --------------------------------------------------------------------------

    def _simulate_detector(self, rng: np.random.Generator, fi, ki) -> None:
        cfg = self.config
        F, W, H = cfg.frames, cfg.width, cfg.height
        parts = []  # (frame, boxes (n,4) xywh, origin, scores)

        # true detections: detectable if mostly visible, then Bernoulli(1 - p_M)
        detectable = self.vis[fi, ki] >= cfg.min_vis_detect
        hit = detectable & (rng.random(len(fi)) < cfg.p_detect)
        f_t, k_t = fi[hit], ki[hit]
        parts.append((f_t + 1, _noisy(rng, self.boxes[f_t, k_t], cfg.box_noise), k_t + 1,
                      rng.beta(*cfg.score_true, size=len(f_t))))

        # Poisson clutter: person-like boxes anywhere in the image
        n = rng.poisson(cfg.clutter, size=F)
        f_c = np.repeat(np.arange(1, F + 1), n)
        hc = rng.uniform(cfg.height_far, cfg.height_near, size=len(f_c)) * H
        wc = rng.uniform(*cfg.aspect, size=len(f_c)) * hc
        xc = rng.random(len(f_c)) * (W - wc)
        yc = rng.random(len(f_c)) * (H - hc)
        parts.append((f_c, np.stack([xc, yc, wc, hc], axis=1), np.zeros(len(f_c), np.int64),
                      rng.beta(*cfg.score_clutter, size=len(f_c))))

        # persistent spots: fixed person-like boxes standing on the ground band
        P = cfg.persistent_clutter
        feet = rng.uniform(cfg.feet_far, cfg.feet_near, size=P) * H
        hs = _height_at(cfg, feet)
        ws = rng.uniform(*cfg.aspect, size=P) * hs
        xs = rng.random(P) * (W - ws)
        self.spots = np.stack([xs, feet - hs, ws, hs], axis=1).reshape(P, 4)
        fires = rng.random((F, P)) < cfg.persistent_prob
        f_p, j_p = np.nonzero(fires)
        parts.append((f_p + 1, _noisy(rng, self.spots[j_p], cfg.persistent_jitter), -(j_p + 1),
                      rng.beta(*cfg.score_persistent, size=len(f_p))))

        frame = np.concatenate([p[0] for p in parts]).astype(np.int64)
        boxes = np.concatenate([p[1].reshape(-1, 4) for p in parts])
        origin = np.concatenate([p[2] for p in parts]).astype(np.int64)
        score = np.concatenate([p[3] for p in parts])
        # a detector lists its boxes in no meaningful order: shuffle within each frame
        order = np.lexsort((rng.random(len(frame)), frame))
        n = len(frame)
        self.det = MotTable(frame=frame[order], id=np.full(n, -1, np.int64),
                            boxes=np.round(boxes[order], 3), score=np.round(score[order], 3),
                            cls=np.full(n, -1.0), vis=np.full(n, -1.0))
        self.det_origin = origin[order]

    # -- pixels ----------------------------------------------------------------------------

    @cached_property
    def background(self) -> np.ndarray:
        """The static (H, W, 3) uint8 BGR background, before illumination and sensor noise."""
        img = _make_background(self.config, _rng(self.config.seed, _BACKGROUND))
        img.flags.writeable = False
        return img

    @cached_property
    def _noise_table(self) -> np.ndarray:
        # Standard-normal quantiles: indexing with uniform 16-bit integers gives Gaussian noise
        # (truncated at ±4.3σ) several times faster than Generator.standard_normal.
        return ndtri((np.arange(_NOISE_LEVELS) + 0.5) / _NOISE_LEVELS).astype(np.float32)

    def illumination_gain(self, index: int) -> float:
        """Global brightness factor of frame ``index``: 1 + A sin(2π t / T + φ)."""
        cfg = self.config
        phi = self._illum_phase
        t = (index - 1) / cfg.fps
        return 1.0 + cfg.illumination * math.sin(2 * math.pi * t / cfg.illumination_period + phi)

    @cached_property
    def _illum_phase(self) -> float:
        return float(_rng(self.config.seed, _BACKGROUND, 1).uniform(0, 2 * np.pi))

    def render(self, index: int) -> np.ndarray:
        """Frame ``index`` (1-based) as (H, W, 3) uint8 BGR. Depends only on the config and
        ``index`` (the sensor noise Generator is seeded from ``(seed, index)``)."""
        cfg = self.config
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) \
                or not 1 <= index <= cfg.frames:
            raise InputError(f"synthetic scene: frame {index!r} out of range 1..{cfg.frames}")
        f = int(index) - 1
        img = self.background.copy()
        for k in self._order[f]:  # far to near: nearer figures paint over farther ones
            if self.present[f, k]:
                _draw_figure(img, self.boxes[f, k], float(self.phase[f, k]), self._looks[k])
        gain = self.illumination_gain(index)
        if cfg.bg_noise > 0:
            self._draw_noise_patches(img, index)
        if cfg.flicker > 0:
            gain *= 1.0 + cfg.flicker * float(_rng(cfg.seed, _FLICKER, index).standard_normal())
        if cfg.noise_std == 0:
            return cv2.convertScaleAbs(img, alpha=gain)
        u = _rng(cfg.seed, _FRAME, f + 1).integers(0, _NOISE_LEVELS, img.size, dtype=np.uint16)
        noise = np.take(self._noise_table, u).reshape(img.shape)
        # gain * img + noise_std * N(0, 1), rounded and saturated to uint8 in one pass
        return cv2.addWeighted(img, gain, noise, cfg.noise_std, 0.0, dtype=cv2.CV_8U)

    @cached_property
    def noise_patches(self) -> np.ndarray:
        """(P, 12) background-subtraction noise patches (``bg_noise > 0``): first frame,
        last frame, x, y, w, h, shape (0 ellipse, 1 rectangle), B, G, R, texture amplitude,
        texture seed.  Empty when off."""
        cfg = self.config
        if cfg.bg_noise <= 0:
            return np.zeros((0, 12))
        rng = _rng(cfg.seed, _BGNOISE)
        n = rng.poisson(cfg.bg_noise, size=cfg.frames)
        first = np.repeat(np.arange(1, cfg.frames + 1), n).astype(np.float64)
        P = len(first)
        last = first + rng.integers(0, cfg.bg_noise_duration, P)
        H, W = cfg.height, cfg.width
        h = np.exp(rng.uniform(np.log(0.02), np.log(0.25), P)) * H
        w = h * np.exp(rng.uniform(np.log(0.3), np.log(3.0), P))
        x = rng.random(P) * np.maximum(W - w, 1.0)
        y = rng.random(P) * np.maximum(H - h, 1.0)
        shape = (rng.random(P) < 0.5).astype(np.float64)
        col = rng.uniform(0, 255, (P, 3))
        tex = rng.uniform(0, 60, P)
        tseed = rng.integers(0, 2 ** 31, P).astype(np.float64)
        return np.column_stack([first, last, x, y, w, h, shape, col, tex, tseed])

    def _draw_noise_patches(self, img: np.ndarray, index: int) -> None:
        """Paint the noise patches alive at frame ``index`` and salt-and-pepper specks."""
        cfg = self.config
        pt = self.noise_patches
        H, W = img.shape[:2]
        for r in pt[(pt[:, 0] <= index) & (index <= pt[:, 1])]:
            x, y, w, h = r[2:6]
            x0, y0 = int(max(x, 0)), int(max(y, 0))
            x1, y1 = int(min(x + w, W)), int(min(y + h, H))
            if x1 <= x0 or y1 <= y0:
                continue
            trng = np.random.default_rng(int(r[11]))
            patch = np.empty((y1 - y0, x1 - x0, 3), np.float32)
            patch[:] = r[7:10]
            patch += trng.standard_normal(patch.shape[:2] + (1,)).astype(np.float32) * r[10]
            if r[6] == 0:                      # ellipse: blend only inside it
                yy, xx = np.mgrid[0:y1 - y0, 0:x1 - x0]
                m = (((xx + x0 + 0.5 - (x + w / 2)) / (w / 2)) ** 2
                     + ((yy + y0 + 0.5 - (y + h / 2)) / (h / 2)) ** 2) <= 1.0
            else:
                m = np.ones(patch.shape[:2], bool)
            region = img[y0:y1, x0:x1]
            region[m] = np.clip(patch[m], 0, 255).astype(np.uint8)
        # salt and pepper: ~bg_noise·20 specks of 2-5 px
        rng = _rng(cfg.seed, _BGNOISE, index)
        k = rng.poisson(cfg.bg_noise * 20)
        if k:
            xs, ys = rng.integers(0, W, k), rng.integers(0, H, k)
            rs = rng.integers(1, 3, k)
            vs = rng.choice([0, 255], k)
            for xi, yi, ri, vi in zip(xs, ys, rs, vs):
                img[max(yi - ri, 0):yi + ri + 1, max(xi - ri, 0):xi + ri + 1] = vi

    def frames(self) -> Iterator[Frame]:
        fps = self.config.fps
        for k in range(1, self.config.frames + 1):
            yield Frame(k, (k - 1) / fps, self.render(k))

    def __len__(self) -> int:
        return self.config.frames

    def seqinfo(self) -> dict:
        c = self.config
        return dict(name=c.name, imDir="img1", frameRate=c.fps, seqLength=c.frames,
                    imWidth=c.width, imHeight=c.height, imExt=".jpg")


def _noisy(rng: np.random.Generator, boxes: np.ndarray, rel: float) -> np.ndarray:
    """Gaussian noise on centre and size with std ``rel * w`` (x, w) and ``rel * h`` (y, h)
    (maggio2007 §4: observation noise proportional to the target size)."""
    boxes = boxes.reshape(-1, 4)
    w, h = boxes[:, 2], boxes[:, 3]
    e = rng.standard_normal((len(boxes), 4)) * rel
    cx = boxes[:, 0] + w / 2 + e[:, 0] * w
    cy = boxes[:, 1] + h / 2 + e[:, 1] * h
    nw = np.maximum(w + e[:, 2] * w, 1.0)  # a box keeps a positive size (MOT files need it)
    nh = np.maximum(h + e[:, 3] * h, 1.0)
    return np.stack([cx - nw / 2, cy - nh / 2, nw, nh], axis=1)


def write_sequence(out_dir, config: SceneConfig, *,
                   progress: Optional[Callable[[int, int], None]] = None) -> Path:
    """Write the scene as a MOTChallenge folder: ``img1/000001.jpg ...``, ``seqinfo.ini``,
    ``gt/gt.txt``, ``det/det.txt``; ``seqinfo.ini`` names the sequence after the folder.  Refuses an existing non-empty ``out_dir``.  Everything is
    written into a hidden sibling folder that is renamed to ``out_dir`` at the end, so a
    half-written sequence never looks complete.  ``progress(i, n)`` is called per frame."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        raise InputError(f"{out}: folder exists and is not empty (choose a new --out)")
    scene = SyntheticScene(config)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.parent / f".{out.name}.{secrets.token_hex(4)}.part"
        tmp.mkdir()
    except OSError as e:
        raise InputError(f"{out}: cannot create ({e.strerror or e})") from None
    try:
        for sub in ("img1", "gt", "det"):
            (tmp / sub).mkdir()
        n = config.frames
        params = [cv2.IMWRITE_JPEG_QUALITY, int(config.jpeg_quality)]
        for i in range(1, n + 1):
            path = tmp / "img1" / f"{i:06d}.jpg"
            if not cv2.imwrite(str(path), scene.render(i), params):
                raise InputError(f"{path}: frame {i}: cannot write image")
            if progress is not None:
                progress(i, n)
        g, d = scene.gt, scene.det
        write_mot(tmp / "gt" / "gt.txt", "gt", g.frame, g.id, g.boxes, g.score, g.cls, g.vis)
        write_mot(tmp / "det" / "det.txt", "det", d.frame, d.id, d.boxes, d.score)
        info = scene.seqinfo()
        info["frameRate"] = f"{config.fps:g}"
        info["name"] = out.resolve().name  # the folder's name, as in a MOTChallenge sequence
        (tmp / "seqinfo.ini").write_text(
            "[Sequence]\n" + "".join(f"{k}={v}\n" for k, v in info.items()))
        os.replace(tmp, out)  # atomic; replaces only an empty folder
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        raise InputError(f"{out}: cannot write the sequence ({e.strerror or e})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


__all__ = ["SceneConfig", "SyntheticScene", "write_sequence", "DEMO_SCENE", "demo_config"]
