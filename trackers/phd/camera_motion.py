"""The camera's image motion between two frames, estimated from the detections alone (not in
maggio2007).

On a moving camera (a car driving through a street, a panning or zooming camera) everything in
the image moves with the camera: a person standing still jumps by a tenth of their height from
one frame to the next, and the constant-velocity prediction of the filter and the association
(which model the *target's* motion) lands beside the next detection.  Between two frames close
in time the camera's image motion is modelled as a **scale about a point plus a shift**,
``p' = s p + t`` (a similarity without rotation), applied to every position, and the scale to
every size and velocity (a zoom or a drive towards the scene makes everything larger by ``s``
and its image motion faster by ``s``).  What remains is the people's own motion, which the
motion models then describe.  No rotation: detection boxes are axis-aligned, so they carry no
rotation of their own -- it could only come from the relative positions of a few people, which
their own steps blur -- and a camera rolls far less than it pans, drives or zooms.

Estimate (:func:`fit`): the detections of frame k−1 and k linked by :class:`.scene_motion.Chains`
(mutually nearest within one box size, similar height; :class:`.scene_motion.SceneMotion` hands
over the links that continue a chain from frame k−2, as random clutter seldom does) give, per link, the two boxes' corners
(top-left, bottom-right): four coordinates that fix the shift and the size change, so each link
alone is a hypothesis of the camera's motion.  Residuals are measured in box sizes (``Δx / w``,
``Δy / h``, as the likelihood measures them) against the noise of a link under a still camera,
per axis ``2 σ_y² + σ_walk²``: two detections, each with the likelihood's position noise ``σ_y``,
and the person's own displacement in one frame ``σ_walk`` (the newborn speed prior of the
filter, per axis).  Robust to links that are clutter or mismatches: every link's hypothesis is
scored by its truncated residuals over all links (MSAC: :data:`INLIER_D2`, a link's χ² 99 %
gate), the best one's inliers are refitted by weighted least squares.  The motion is used only
when it is **significantly better than a still camera**: it must lower its inliers' summed
squared residual (in noise variances) by more than the 99 % quantile of a χ² with 3 degrees of
freedom (its parameters) -- a likelihood-ratio test of "the camera moved" against "the camera is
still", with the margin set by the noise the filter assumes, not by a sequence -- on at least
:data:`MIN_LINKS` inlier links (one link is one person's own motion).  A frame without such
evidence is taken as still (carrying the last frame's motion over such frames was measured
worse on KITTI-13: a car's image motion changes from frame to frame).

Deterministic; cost quadratic in the links of a frame (one hypothesis per link; a frame's links
are capped by :class:`.scene_motion.Chains`'s pair bound, and at most :data:`MAX_HYPOTHESES`
hypotheses are scored).
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

#: inlier links needed before a camera motion is believed (one link is a person's own motion)
MIN_LINKS = 2
#: χ²(3 dof) 99 % quantile: the fit must beat the identity by this many noise variances
LR_MARGIN = 11.3449
#: χ²(4 dof: two corners × two axes) 99 % quantile: a link whose residual under the motion is
#: within it is an inlier
INLIER_D2 = 13.2767
#: links tried as hypotheses (the first ones; each is scored against every link)
MAX_HYPOTHESES = 64

IDENTITY = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def corners(boxes: np.ndarray) -> np.ndarray:
    """(N, 2, 2) top-left and bottom-right corners of boxes ``(cx, cy, w, h)`` (N, 4)."""
    half = boxes[:, 2:4] / 2.0
    return np.stack([boxes[:, :2] - half, boxes[:, :2] + half], axis=1)


def apply(A: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points (..., 2) mapped by the 2×3 transform ``A``."""
    return pts @ A[:, :2].T + A[:, 2]


def scale(A: np.ndarray) -> float:
    """The similarity's scale ``s`` (``A[:, :2] = s R``)."""
    return float(math.sqrt(abs(A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0])))


def _scale_shift(src: np.ndarray, dst: np.ndarray, wt: np.ndarray) -> tuple:
    """Weighted least squares of ``dst ≈ s src + t`` over points (..., n, 2, 2) with weights
    ``wt`` (..., n, 1 or 2, 2) per coordinate: ``(s, t)`` of shapes (...) and (..., 2) (one
    fit per leading index)."""
    w = np.broadcast_to(wt, src.shape)
    sw = w.sum(axis=(-3, -2))
    ps = (w * src).sum(axis=(-3, -2)) / sw
    qs = (w * dst).sum(axis=(-3, -2)) / sw
    dp, dq = src - ps[..., None, None, :], dst - qs[..., None, None, :]
    den = (w * dp * dp).sum(axis=(-3, -2, -1))
    s = np.where(den > 0, (w * dp * dq).sum(axis=(-3, -2, -1)) / np.where(den > 0, den, 1.0),
                 1.0)
    return s, qs - s[..., None] * ps


def _matrix(s: float, t: np.ndarray) -> np.ndarray:
    return np.array([[s, 0.0, t[0]], [0.0, s, t[1]]])


def fit(prev: np.ndarray, cur: np.ndarray, links: np.ndarray,
        pos_std: float, size_std: float, speed_var: float = 0.0) -> Optional[np.ndarray]:
    """The camera's motion (2×3, frame k−1 → frame k coordinates) from the linked detections
    ``prev`` (N_p, 4) and ``cur`` (N_c, 4) ``(cx, cy, w, h)`` (``links[i]``: the index in
    ``prev`` of ``cur[i]``'s link, −1 none), or None where a still camera explains the links as
    well (module docstring).  ``pos_std``, ``size_std``: the likelihood's position and size noise
    (σ_y, σ_size) as fractions of the box size; ``speed_var``: the variance per axis of a
    person's own displacement in one frame, in units of ``w h`` (px² / (w h))."""
    has = np.flatnonzero(links >= 0)
    if len(has) < MIN_LINKS:
        return None
    q, z = prev[links[has]], cur[has]
    src, dst = corners(q), corners(z)
    size = z[:, None, 2:4]                              # residuals in box sizes of frame k
    wh = z[:, 2] * z[:, 3]
    # a corner = centre ± size / 2: per detection σ_y² + σ_size² / 4, two detections a link
    var = 2.0 * (pos_std ** 2 + size_std ** 2 / 4) + speed_var * wh[:, None, None] / size ** 2
    wt = 1.0 / (var * size ** 2)                        # per px² of each link and axis
    d2_id = np.sum((src - dst) ** 2 * wt, axis=(1, 2))

    def d2(s, t) -> np.ndarray:
        """(..., n) squared residuals in noise variances of every link under ``s p + t``."""
        s = np.asarray(s, dtype=np.float64)[..., None, None, None]
        return np.sum((s * src + np.asarray(t)[..., None, None, :] - dst) ** 2 * wt,
                      axis=(-2, -1))

    def gain(r: np.ndarray, need: int) -> float:
        """How much a motion of residuals ``r`` lowers the links' truncated squared residual
        (each link's at most :data:`INLIER_D2`: a link either motion calls an outlier costs
        both the same) below the identity's; −inf with fewer than ``need`` inliers."""
        inl = r <= INLIER_D2
        if inl.sum() < need:
            return -np.inf
        return float(np.minimum(d2_id, INLIER_D2).sum() - np.minimum(r, INLIER_D2).sum())

    # one hypothesis per link: its size ratio and the shift of its centre
    h = slice(0, MAX_HYPOTHESES)
    sh = np.sqrt(wh[h] / (q[h, 2] * q[h, 3]))
    th = z[h, :2] - sh[:, None] * q[h, :2]
    # ... and one per pair of links: their least-squares motion (the scale then also
    # from how far apart they are, not only from their noisy sizes)
    ii, jj = np.triu_indices(len(has), 1)
    k = np.stack([ii[:MAX_HYPOTHESES], jj[:MAX_HYPOTHESES]], axis=1)      # (P, 2)
    s_ab, t_ab = _scale_shift(src[k], dst[k], wt[k])
    sh, th = np.concatenate([sh, s_ab]), np.concatenate([th, t_ab])
    cost = np.minimum(d2(sh, th), INLIER_D2).sum(axis=1)
    best = int(np.argmin(cost))
    inl = d2(sh[best], th[best]) <= INLIER_D2
    if inl.sum() >= MIN_LINKS:
        s, t = _scale_shift(src[inl], dst[inl], wt[inl])
        s = float(s)
        if gain(d2(s, t), MIN_LINKS) > LR_MARGIN:
            return _matrix(s, t)
    return None


def warp_boxes(boxes: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Boxes ``(cx, cy, w, h)`` (N, 4) of frame k−1 in frame k's image coordinates (a new
    array): centres by ``A``, sizes by its scale."""
    out = np.empty_like(boxes)
    out[:, :2] = apply(A, boxes[:, :2])
    out[:, 2:4] = boxes[:, 2:4] * scale(A)
    return out


def warp_states(states: np.ndarray, A: np.ndarray) -> None:
    """Map states ``(x, y, vx, vy, w, h)`` (N, 6) of frame k−1 into frame k's image
    coordinates by the similarity ``A``, in place: the position by ``A``, the velocity by its
    linear part, the size by its scale (NaN velocities stay NaN)."""
    if not len(states):
        return
    L = A[:, :2]
    states[:, 0:2] = states[:, 0:2] @ L.T + A[:, 2]
    states[:, 2:4] = states[:, 2:4] @ L.T
    states[:, 4:6] *= scale(A)


def compose(B: np.ndarray, A: np.ndarray) -> np.ndarray:
    """The transform ``B ∘ A`` (first ``A``, then ``B``), 2×3."""
    L = B[:, :2] @ A[:, :2]
    return np.concatenate([L, (B[:, :2] @ A[:, 2] + B[:, 2])[:, None]], axis=1)


def invert(A: np.ndarray) -> np.ndarray:
    """The inverse of the 2×3 transform ``A``."""
    Li = np.linalg.inv(A[:, :2])
    return np.concatenate([Li, (-Li @ A[:, 2])[:, None]], axis=1)
