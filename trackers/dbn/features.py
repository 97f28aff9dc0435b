"""Colour and oriented-gradient (HOG) histogram features of a particle's box, by integral
histograms — feng2015 §II-C/§II-D.2 ("colour and oriented gradient histograms").

Cost: per frame, one pass builds an *integral histogram* per bin (Porikli 2005): for every bin
``b`` a per-pixel map (one-hot colour bin; gradient magnitude in its orientation bin) and its
2-D cumulative sum ``II[y, x, b] = Σ_{y'<y, x'<x} map[y', x', b]`` (zero-padded, (H+1, W+1, B)).
Then any axis-aligned cell's histogram is 4 look-ups per bin,
``II[y1, x1] − II[y0, x1] − II[y1, x0] + II[y0, x0]``, vectorised over all particles and cells:
a particle costs ``O(cells × bins)`` whatever its box area.  The integral histograms are
built only when many boxes are asked for (the particles); the few blobs of a frame are
described from their own crops (:class:`FrameFeatures`), which is cheaper than a pass over
the whole image and gives the same numbers.  The integrals come straight from the per-pixel
bins in numba (:mod:`._feature_kernels`, in ``cv2.integral``'s order: the same floats), and a
frame's crops share one set of numpy calls and one kernel call.

Feature layout of one box (``FeatureConfig``, stored in the model file; defaults give D = 96):

=====================================  ===================================================
slice                                  content
=====================================  ===================================================
``[0, R_h·C_h·O)``                     HOG: the box split into ``hog_rows × hog_cols`` cells
                                       (row-major), ``orientations`` unsigned-orientation
                                       bins per cell (0–180°, magnitude-weighted), the whole
                                       block L2-normalised (Dalal–Triggs, one block = the
                                       box): invariant to a brightness/contrast gain
``[R_h·C_h·O, … + R_c·(Hb + G))``      colour: the box split into ``colour_rows`` horizontal
                                       bands (head/torso vs legs); per band ``hue_bins`` hue
                                       bins for chromatic pixels (S >= ``sat_min``, V >=
                                       ``val_min``) then ``grey_bins`` value bins for the
                                       others; each band's histogram is divided by its pixel
                                       count (a distribution) and square-rooted (Hellinger
                                       map), so every non-empty band has unit L2 norm
=====================================  ===================================================

All entries lie in [0, 1] (inputs for the Bernoulli visible units of the first RBM).

Borders and tiny boxes: cell edges are computed on the *whole* box (so a cell keeps its place
on the body when the box leaves the image), rounded down, forced strictly increasing (every
cell at least one pixel wide and tall, so a 1-pixel box still has a histogram) and then
clipped to the image.  A cell entirely outside the image is empty: its HOG bins are 0 and a
colour band with no pixel inside the image is all zeros (the only non-normalised case).
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass, replace

import cv2
import numpy as np


@dataclass(frozen=True)
class FeatureConfig:
    """The feature layout (module docstring).  Part of a saved model: a model only scores the
    features it was trained on."""

    hog_rows: int = 4
    hog_cols: int = 2
    orientations: int = 9
    colour_rows: int = 2
    hue_bins: int = 8
    grey_bins: int = 4
    sat_min: float = 0.25      # chromatic pixel: saturation >= this fraction of 255
    val_min: float = 0.2       # ... and value >= this fraction of 255
    #: > 0: every box is described on the image pyramid level (scales 2^-k, k >= 0: octaves,
    #: each a fast exact 2x area reduction) that brings its height nearest this many pixels
    #: (within a factor sqrt(2)), so a person is described at about the same size whatever the
    #: camera's resolution or distance; 0: one fixed scale for every box
    box_height: float = 0.0

    @property
    def hog_dim(self) -> int:
        return self.hog_rows * self.hog_cols * self.orientations

    @property
    def colour_bins(self) -> int:
        return self.hue_bins + self.grey_bins

    @property
    def dim(self) -> int:
        return self.hog_dim + self.colour_rows * self.colour_bins

    def to_dict(self) -> dict:
        return asdict(self)


def _gradients_hsv(image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(gx, gy, hsv)`` of a BGR (or grey) uint8 image: the centred [-1, 0, 1] gradients of
    its grey level (float32, Dalal–Triggs) and its HSV (H in [0, 180), S, V in [0, 255])."""
    img = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float32)
    return (cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=1), cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=1),
            cv2.cvtColor(img, cv2.COLOR_BGR2HSV))


def _bins(gx: np.ndarray, gy: np.ndarray, hsv: np.ndarray, cfg: FeatureConfig
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel by pixel (any shape; ``hsv`` with a last axis of 3): ``(ob, mag, cb)`` of
    :func:`bin_indices`."""
    mag = np.sqrt(gx * gx + gy * gy)
    ang = np.mod(np.arctan2(gy, gx), np.pi)            # unsigned orientation
    ob = np.minimum((ang * (cfg.orientations / np.pi)).astype(np.int64), cfg.orientations - 1)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    chrom = (s >= cfg.sat_min * 255) & (v >= cfg.val_min * 255)
    if hsv.dtype == np.uint8:       # (OpenCV's HSV) the same ints from 256-entry tables
        hue, grey = _colour_tables(cfg.hue_bins, cfg.grey_bins)
        return ob, mag, np.where(chrom, hue[h], grey[v])
    hb = np.minimum(h.astype(np.int64) * cfg.hue_bins // 180, cfg.hue_bins - 1)
    gb = cfg.hue_bins + np.minimum(v.astype(np.int64) * cfg.grey_bins // 256, cfg.grey_bins - 1)
    return ob, mag, np.where(chrom, hb, gb)


@functools.lru_cache(maxsize=8)
def _colour_tables(hue_bins: int, grey_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """(256,) int64 tables of :func:`_bins`' colour bins by uint8 hue and by value."""
    x = np.arange(256, dtype=np.int64)
    return (np.minimum(x * hue_bins // 180, hue_bins - 1),
            hue_bins + np.minimum(x * grey_bins // 256, grey_bins - 1))


def bin_indices(image: np.ndarray, cfg: FeatureConfig
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel bins of a BGR uint8 image: ``(ob (H, W) int64, mag (H, W) float32,
    cb (H, W) int64)`` — the unsigned-orientation bin of the gradient, its magnitude, and the
    colour bin (hue bin for a chromatic pixel, else ``hue_bins`` + value bin)."""
    return _bins(*_gradients_hsv(image), cfg)


def bin_maps(image: np.ndarray, cfg: FeatureConfig) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel bin maps of a BGR uint8 image: ``hog (H, W, O)`` gradient magnitude in its
    orientation bin, ``colour (H, W, Hb + G)`` one-hot colour bin.  float64."""
    ob, mag, cb = bin_indices(image, cfg)
    H, W = ob.shape
    n = H * W
    pix = np.arange(n)
    hog = np.zeros((H, W, cfg.orientations))
    hog.reshape(n, -1)[pix, ob.reshape(-1)] = mag.reshape(-1)   # one-hot by orientation bin
    colour = np.zeros((H, W, cfg.colour_bins))
    colour.reshape(n, -1)[pix, cb.reshape(-1)] = 1.0
    return hog, colour


def bin_integrals(image: np.ndarray, cfg: FeatureConfig) -> tuple[np.ndarray, np.ndarray]:
    """:func:`integral` of both :func:`bin_maps` of ``image``, in one numba pass from
    :func:`bin_indices` without the maps (:mod:`._feature_kernels`): the same floats."""
    from ._feature_kernels import one_hot_integrals

    return one_hot_integrals(*bin_indices(image, cfg), cfg.orientations, cfg.colour_bins)


def integral(maps: np.ndarray) -> np.ndarray:
    """Zero-padded integral histogram ``(H+1, W+1, B)`` of per-pixel bin maps ``(H, W, B)``."""
    H, W, B = maps.shape
    if B <= 512:   # OpenCV's channel limit; cv2.integral is ~3x faster than two numpy cumsums
        return cv2.integral(np.ascontiguousarray(maps), sdepth=cv2.CV_64F).reshape(H + 1, W + 1, B)
    ii = np.zeros((H + 1, W + 1, B))
    np.cumsum(maps, axis=0, out=ii[1:, 1:])
    np.cumsum(ii[1:, 1:], axis=1, out=ii[1:, 1:])
    return ii


def cell_edges(lo: np.ndarray, size: np.ndarray, n: int, limit: int) -> np.ndarray:
    """(N, n+1) int64 edges of ``n`` equal cells over ``[lo, lo + size)`` (pixels at the
    feature scale): floored, strictly increasing (cells >= 1 px), clipped to ``[0, limit]``."""
    j = np.arange(n + 1)
    e = np.floor(lo[:, None] + size[:, None] * (j / n)[None, :]).astype(np.int64)
    e = np.maximum(e, e[:, :1] + j[None, :])
    return np.minimum(np.maximum(e, 0), limit)    # np.clip's ints, without its overhead


def _cell_sums(ii: np.ndarray, ye: np.ndarray, xe: np.ndarray) -> np.ndarray:
    """(N, R, C, B) sums of the cells ``[ye[r], ye[r+1]) × [xe[c], xe[c+1])``: 4 look-ups."""
    W1 = ii.shape[1]
    flat = ii.reshape(-1, ii.shape[2])
    idx = ye[:, :, None] * W1 + xe[:, None, :]               # (N, R+1, C+1)
    A = flat[idx]                                             # (N, R+1, C+1, B)
    return A[:, 1:, 1:] - A[:, :-1, 1:] - A[:, 1:, :-1] + A[:, :-1, :-1]


class FrameFeatures:
    """One frame's features; :meth:`describe` gives the features of any boxes.

    ``scale``: the image is resized by this factor first (boxes are given in full-resolution
    pixels and scaled the same way).

    Two routes, same numbers (up to float rounding; tested): a few boxes (at most
    ``crop_max`` whose cells cover less than half the image — the blobs of a frame) are
    described from their own crops: bin maps and integral histograms over each box's pixels
    (plus a one-pixel margin, so the gradients equal the whole-image ones).  Many boxes (the
    particles) use the whole frame's integral histograms, built on first use and kept: each box
    then costs ``O(cells × bins)`` whatever its area."""

    #: at most this many boxes take the per-box crop route
    crop_max = 32

    #: coarsest pyramid level used when ``cfg.box_height > 0`` (scale 2^-max_level)
    max_level = 5

    def __init__(self, image: np.ndarray, cfg: FeatureConfig = FeatureConfig(),
                 scale: float = 1.0, scaled: dict[float, np.ndarray] | None = None):
        self.cfg = cfg
        self._full = image
        self._levels: dict[int, FrameFeatures] = {}
        #: ``image`` already reduced at these scales by the same cv2.resize (INTER_AREA) call,
        #: e.g. the background model's copy: used instead of resizing again
        self._scaled = scaled or {}
        if cfg.box_height > 0:           # pyramid mode: levels built on demand
            scale = 1.0
        self.scale = float(scale)
        if self.scale != 1.0:
            h, w = image.shape[:2]
            size = (max(1, round(w * scale)), max(1, round(h * scale)))
            pre = self._scaled.get(self.scale)
            image = (pre if pre is not None and pre.shape == (size[1], size[0]) + image.shape[2:]
                     else cv2.resize(image, size, interpolation=cv2.INTER_AREA))
        self.image = image
        self.height, self.width = image.shape[:2]
        self._ii: tuple[np.ndarray, np.ndarray] | None = None

    def levels(self, boxes_xywh: np.ndarray) -> np.ndarray:
        """(N,) pyramid level k of every box (scale 2^-k): the one whose scaled height is
        nearest ``cfg.box_height`` in ratio, never enlarged (k >= 0)."""
        h = np.maximum(np.asarray(boxes_xywh, dtype=np.float64).reshape(-1, 4)[:, 3], 1e-6)
        k = np.round(np.log2(h / self.cfg.box_height))
        return np.minimum(np.maximum(k, 0), self.max_level).astype(np.int64)

    def _level(self, k: int) -> "FrameFeatures":
        if k not in self._levels:
            self._levels[k] = FrameFeatures(self._full, replace(self.cfg, box_height=0.0),
                                            2.0 ** -k, self._scaled)
        return self._levels[k]

    @property
    def ii_hog(self) -> np.ndarray:
        return self._integrals()[0]

    @property
    def ii_colour(self) -> np.ndarray:
        return self._integrals()[1]

    def _integrals(self) -> tuple[np.ndarray, np.ndarray]:
        if self._ii is None:
            self._ii = bin_integrals(self.image, self.cfg)
        return self._ii

    def edges(self, boxes_xywh: np.ndarray, rows: int, cols: int):
        b = np.asarray(boxes_xywh, dtype=np.float64).reshape(-1, 4) * self.scale
        ye = cell_edges(b[:, 1], b[:, 3], rows, self.height)
        xe = cell_edges(b[:, 0], b[:, 2], cols, self.width)
        return ye, xe

    def describe_union(self, boxes_xywh: np.ndarray) -> np.ndarray:
        """:meth:`describe` for boxes that lie close together (the person-sized windows inside
        one blob): one crop over the union of their cells, its bin maps and integral
        histograms, then 4 look-ups per cell — the same numbers as the whole-frame route,
        without a pass over the whole frame."""
        return self.describe_many([(boxes_xywh, True)])[0]

    def describe(self, boxes_xywh: np.ndarray) -> np.ndarray:
        """(N, D) float64 features of boxes ``(x, y, w, h)`` top-left, full-resolution px."""
        return self.describe_many([(boxes_xywh, False)])[0]

    def describe_many(self, requests) -> list[np.ndarray]:
        """``[describe_union(b) if union else describe(b) for b, union in requests]``, the same
        floats in the same route, with the crop-route parts of all requests (a frame's blobs
        and the windows of every blob it splits) computed together: one set of numpy calls
        for the pixels' bins, one kernel call for the cell sums and one normalisation, instead
        of one each per request and pyramid level (:meth:`_plan`, :func:`_run_crops`)."""
        jobs: list[_CropJob] = []
        outs = []
        for boxes, union in requests:
            b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
            out = np.zeros((len(b), self.cfg.dim))
            self._plan(b, union, jobs, out, np.arange(len(b)))
            outs.append(out)
        _run_crops(jobs, self.cfg)
        return outs

    def _plan(self, b: np.ndarray, union: bool, jobs: list, out: np.ndarray,
              rows: np.ndarray) -> None:
        """Features of boxes ``b`` into ``out[rows]``: now (the whole-frame integral route,
        which builds this level's integrals, so later requests see them as before), or as a
        crop job run later by :func:`_run_crops`.

        Routes: a pyramid splits the boxes by level; a union request is one crop over the
        union of the boxes' cells (the whole-frame route once this level's integrals exist);
        a plain request takes the per-box crop route for a few boxes (at most ``crop_max``
        covering less than half the image: the blobs) and the whole-frame integrals
        otherwise (the particles)."""
        c = self.cfg
        n = len(b)
        if n == 0:
            return
        if c.box_height > 0:
            lv = self.levels(b)
            for k in np.unique(lv):
                sel = np.flatnonzero(lv == k)
                self._level(int(k))._plan(b[sel], union, jobs, out, rows[sel])
            return
        yh, xh = self.edges(b, c.hog_rows, c.hog_cols)
        yc, xc = self.edges(b, c.colour_rows, 1)
        if union and self._ii is None:
            y0 = int(min(yh[:, 0].min(), yc[:, 0].min()))
            y1 = int(max(yh[:, -1].max(), yc[:, -1].max()))
            x0 = int(min(xh[:, 0].min(), xc[:, 0].min()))
            x1 = int(max(xh[:, -1].max(), xc[:, -1].max()))
            if y1 <= y0 or x1 <= x0:
                out[rows] = _normalise(np.zeros((n, c.hog_dim)),
                                       np.zeros((n, c.colour_rows, c.colour_bins)), c)
                return
            jobs.append(_CropJob(self, [(y0, y1, x0, x1)], np.zeros(n, np.int64), yh - y0,
                                 xh - x0, yc - y0, xc - x0, np.arange(n), out, rows))
            return
        y0 = np.minimum(yh[:, 0], yc[:, 0])
        y1 = np.maximum(yh[:, -1], yc[:, -1])
        x0 = np.minimum(xh[:, 0], xc[:, 0])
        x1 = np.maximum(xh[:, -1], xc[:, -1])
        area = np.maximum(y1 - y0, 0) * np.maximum(x1 - x0, 0)
        if self._ii is None and n <= self.crop_max and area.sum() < self.height * self.width / 2:
            i = np.flatnonzero(area > 0)                # a few boxes (the blobs), not particles
            oy, ox = y0[i, None], x0[i, None]
            jobs.append(_CropJob(self, [(int(y0[k]), int(y1[k]), int(x0[k]), int(x1[k]))
                                        for k in i], np.arange(len(i)), yh[i] - oy,
                                 xh[i] - ox, yc[i] - oy, xc[i] - ox, i, out, rows))
            return
        ii_hog, ii_colour = self._integrals()
        hog = _cell_sums(ii_hog, yh, xh)
        col = _cell_sums(ii_colour, yc, xc)
        out[rows] = _normalise(hog.reshape(n, -1), col[:, :, 0, :], c)


@dataclass
class _CropJob:
    """Boxes of one request (and pyramid level) described from crops of ``ff``'s image:
    ``regions`` ``(y0, y1, x0, x1)`` at the feature scale; box ``crop[j]`` of the job's
    ``len(rows)`` boxes lies in region ``region_of[j]``, its cell edges relative to it (the
    job's other boxes have no pixel: all-zero cells); the features go to ``out[rows]``."""

    ff: FrameFeatures
    regions: list
    region_of: np.ndarray
    yh: np.ndarray
    xh: np.ndarray
    yc: np.ndarray
    xc: np.ndarray
    crop: np.ndarray
    out: np.ndarray
    rows: np.ndarray


def _run_crops(jobs: list[_CropJob], c: FeatureConfig) -> None:
    """Run crop jobs together.  Each region's gradients come from its crop plus a one-pixel
    margin (so they equal the whole image's); the pixels' bins are computed for all regions
    at once, the integral histograms and cell sums in one numba call
    (:func:`._feature_kernels.region_cell_sums`): the same floats as :func:`bin_integrals`
    and :func:`_cell_sums` per crop.  The feature rows are normalised together (row by row:
    the same floats as per request)."""
    from ._feature_kernels import region_cell_sums

    if not jobs:
        return
    gxs, gys, hsvs, shape = [], [], [], []
    n = 0
    for job in jobs:
        ff = job.ff
        for y0, y1, x0, x1 in job.regions:
            cy0, cx0 = max(y0 - 1, 0), max(x0 - 1, 0)
            gx, gy, hsv = _gradients_hsv(ff.image[cy0:min(y1 + 1, ff.height),
                                                  cx0:min(x1 + 1, ff.width)])
            reg = (slice(y0 - cy0, y1 - cy0), slice(x0 - cx0, x1 - cx0))
            gxs.append(gx[reg].reshape(-1))
            gys.append(gy[reg].reshape(-1))
            hsvs.append(hsv[reg].reshape(-1, 3))
            shape.append((n, y1 - y0, x1 - x0))
            n += (y1 - y0) * (x1 - x0)
    total = sum(len(job.rows) for job in jobs)
    hog = np.zeros((total, c.hog_rows, c.hog_cols, c.orientations))
    col = np.zeros((total, c.colour_rows, 1, c.colour_bins))
    first = np.cumsum([0] + [len(job.rows) for job in jobs])
    if shape:
        ob, mag, cb = _bins(np.concatenate(gxs), np.concatenate(gys), np.concatenate(hsvs), c)
        # (rows of the transposed copy: always C-contiguous, so numba compiles one
        # specialisation; a column of `shape` is contiguous only when there is one region)
        starts, heights, widths = np.ascontiguousarray(np.array(shape, np.int64).T)
        n_reg = np.cumsum([0] + [len(job.regions) for job in jobs])
        h, k = region_cell_sums(
            ob, mag, cb, starts, heights, widths,
            np.concatenate([job.region_of + n_reg[j] for j, job in enumerate(jobs)]),
            *(np.concatenate([getattr(job, e) for job in jobs]) for e in ("yh", "xh", "yc",
                                                                            "xc")),
            c.orientations, c.colour_bins)
        at = np.concatenate([job.crop + first[j] for j, job in enumerate(jobs)])
        hog[at], col[at] = h, k
    feats = _normalise(hog.reshape(total, -1), col[:, :, 0, :], c)
    for j, job in enumerate(jobs):
        job.out[job.rows] = feats[first[j]:first[j + 1]]


def _normalise(hog: np.ndarray, col: np.ndarray, c: FeatureConfig) -> np.ndarray:
    """The feature rows from cell sums: HOG (N, R·C·O) L2-normalised as one block, colour
    bands (N, R_c, bins) as Hellinger-mapped distributions (module docstring)."""
    n = len(hog)
    out = np.zeros((n, c.dim))
    norm = np.sqrt(np.einsum("nd,nd->n", hog, hog))
    out[:, :c.hog_dim] = hog / (norm[:, None] + 1e-6)
    count = col.sum(axis=2, keepdims=True)
    col = np.sqrt(np.where(count > 0, col / np.maximum(count, 1e-12), 0.0))
    out[:, c.hog_dim:] = col.reshape(n, -1)
    return out


def describe_brute_force(image: np.ndarray, boxes_xywh: np.ndarray,
                         cfg: FeatureConfig = FeatureConfig(), scale: float = 1.0) -> np.ndarray:
    """The same features summed pixel by pixel over each cell (for tests; slow)."""
    ff = FrameFeatures(image, cfg, scale)
    img = image
    if scale != 1.0:
        h, w = image.shape[:2]
        img = cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))),
                         interpolation=cv2.INTER_AREA)
    hog_map, col_map = bin_maps(img, cfg)
    boxes = np.asarray(boxes_xywh, dtype=np.float64).reshape(-1, 4)
    out = np.zeros((len(boxes), cfg.dim))
    for i in range(len(boxes)):
        ye, xe = ff.edges(boxes[i:i + 1], cfg.hog_rows, cfg.hog_cols)
        hog = np.array([hog_map[ye[0, r]:ye[0, r + 1], xe[0, k]:xe[0, k + 1]].sum(axis=(0, 1))
                        for r in range(cfg.hog_rows) for k in range(cfg.hog_cols)]).reshape(-1)
        out[i, :cfg.hog_dim] = hog / (np.linalg.norm(hog) + 1e-6)
        ye, xe = ff.edges(boxes[i:i + 1], cfg.colour_rows, 1)
        for r in range(cfg.colour_rows):
            h = col_map[ye[0, r]:ye[0, r + 1], xe[0, 0]:xe[0, 1]].sum(axis=(0, 1))
            s = h.sum()
            a = cfg.hog_dim + r * cfg.colour_bins
            out[i, a:a + cfg.colour_bins] = np.sqrt(h / s) if s > 0 else 0.0
    return out


__all__ = ["FeatureConfig", "FrameFeatures", "bin_indices", "bin_maps", "bin_integrals",
           "integral", "cell_edges", "describe_brute_force"]
