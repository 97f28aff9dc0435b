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
evidence is taken as still by :func:`fit` (carrying the last frame's motion over such frames
was measured worse on KITTI-13: a single frame's motion from two or three links is noisy).

Continuity (:class:`CameraMotion`, what the tracker uses): the camera moves smoothly, so its
motion is also kept as a level over about a second of frames (an information filter with
forgetting), to which every frame's links add their evidence -- a frame with a single linked
person too.  Frames that :func:`fit` alone calls still then get the level, but only within a
second of a frame that passed the test above (on KITTI-13, 2.8 detections a frame: 186 of 340
frames get a motion instead of 82; the ground truth's motion left over per frame, median,
0.104 -> 0.060 box heights).

Deterministic; cost quadratic in the links of a frame (one hypothesis per link; a frame's links
are capped by :class:`.scene_motion.Chains`'s pair bound, and at most :data:`MAX_HYPOTHESES`
hypotheses are scored).
"""

from __future__ import annotations

import math
from functools import lru_cache
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
#: seconds over which the camera's motion is assumed steady (:class:`CameraMotion`'s memory)
MEMORY_S = 1.0

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
    r = _robust_fit(prev, cur, links, pos_std, size_std, speed_var)
    return None if r is None or not r.significant else _matrix(r.s, r.t)


@lru_cache(maxsize=64)
def _link_pairs(n: int) -> np.ndarray:
    """(P, 2) the first :data:`MAX_HYPOTHESES` pairs ``i < j`` of ``n`` links, in
    ``np.triu_indices`` order (read-only; the same few ``n`` come back every frame)."""
    ii, jj = np.triu_indices(n, 1)
    k = np.stack([ii[:MAX_HYPOTHESES], jj[:MAX_HYPOTHESES]], axis=1)
    k.flags.writeable = False
    return k


class _Fit:
    """One frame's robust fit: scale ``s``, shift ``t`` (2,), its information matrix ``H``
    (3×3 over ``(s, t_x, t_y)``, the inverse covariance of the weighted least squares on the
    inliers) and whether it passes the likelihood-ratio test against a still camera."""

    __slots__ = ("s", "t", "H", "significant")

    def __init__(self, s: float, t: np.ndarray, H: np.ndarray, significant: bool):
        self.s, self.t, self.H, self.significant = s, t, H, significant


def _information(src: np.ndarray, wt: np.ndarray) -> np.ndarray:
    """Information matrix (3×3 over ``(s, t_x, t_y)``) of ``dst = s src + t`` from points
    ``src`` (n, 2, 2) with weights ``wt`` (n, 1 or 2, 2) per coordinate."""
    w = np.broadcast_to(wt, src.shape)
    sw = w.sum(axis=(0, 1))                        # per axis
    swx = (w * src).sum(axis=(0, 1))
    H = np.zeros((3, 3))
    H[0, 0] = float((w * src * src).sum())
    H[0, 1:] = H[1:, 0] = swx
    H[1, 1], H[2, 2] = sw
    return H


def _robust_fit(prev: np.ndarray, cur: np.ndarray, links: np.ndarray, pos_std: float,
                size_std: float, speed_var: float) -> Optional[_Fit]:
    """:func:`fit`'s robust estimate on one or more links (None without a link)."""
    has = np.flatnonzero(links >= 0)
    if not len(has):
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

    # one hypothesis per link: its size ratio and the shift of its centre
    h = slice(0, MAX_HYPOTHESES)
    sh = np.sqrt(wh[h] / (q[h, 2] * q[h, 3]))
    th = z[h, :2] - sh[:, None] * q[h, :2]
    # ... and one per pair of links: their least-squares motion (the scale then also
    # from how far apart they are, not only from their noisy sizes)
    if len(has) > 1:
        k = _link_pairs(len(has))                                              # (P, 2)
        s_ab, t_ab = _scale_shift(src[k], dst[k], wt[k])
        sh, th = np.concatenate([sh, s_ab]), np.concatenate([th, t_ab])
    cost = np.minimum(d2(sh, th), INLIER_D2).sum(axis=1)
    best = int(np.argmin(cost))
    inl = d2(sh[best], th[best]) <= INLIER_D2
    if not inl.any():
        return None
    s, t = _scale_shift(src[inl], dst[inl], wt[inl])
    s = float(s)
    # likelihood-ratio test: the links' truncated squared residual (each link's at most
    # INLIER_D2: a link either motion calls an outlier costs both the same) must drop below
    # the identity's by LR_MARGIN, on at least MIN_LINKS inliers
    r = d2(s, t)
    gain = float(np.minimum(d2_id, INLIER_D2).sum() - np.minimum(r, INLIER_D2).sum())
    ok = int((r <= INLIER_D2).sum()) >= MIN_LINKS and gain > LR_MARGIN
    return _Fit(s, np.asarray(t, dtype=np.float64), _information(src[inl], wt[inl]), ok)


class CameraMotion:
    """The camera's motion frame by frame, with its continuity: a camera on a car or in a hand
    moves smoothly, so its image motion of frame k is close to that of the frames just before.

    Model: the motion ``θ = (s, t_x, t_y)`` is a level that drifts (a random walk); each frame's
    links measure it with the information matrix of their weighted least squares (:func:`fit`'s
    noise model; a frame with a single link measures it too, only less precisely).  The level is
    kept as an information filter with exponential forgetting -- ``H ← λ H + H_k``,
    ``b ← λ b + H_k θ_k``, ``θ = H⁻¹ b`` with ``λ = exp(−1 / memory)`` -- which is the Kalman
    filter of a random walk whose drift over ``memory`` frames is as large as the level's own
    uncertainty: measurements older than ``memory`` frames (one second of video, set by the
    tracker from the frame rate) fade out.

    Adaptive forgetting: when two frames in a row pass :func:`fit`'s likelihood-ratio test and
    the second contradicts the level (its innovation beyond the χ²₃ 99 % gate), the camera
    changed its motion faster than the drift allows, and the level's information is shrunk
    until that frame is consistent with it.  A single such frame is not enough: on a still
    camera it is the test's 1 % false alarm, and the level (full of still frames) then stays
    still.

    Called moving only while both hold: (1) a frame's own links passed :func:`fit`'s
    likelihood-ratio test against a still camera within the last ``memory`` frames (the level
    alone would call people who walk the same way for a while a slow pan once their evidence
    piles up -- a person keeps their velocity, so their steps are not independent from frame
    to frame as the level assumes; the per-frame test, which counts a person's own step as
    noise, is what opens it); (2) the level itself differs from the identity by more than the
    χ²₃ 99 % quantile in its own covariance (``(θ − θ_id)ᵀ H (θ − θ_id) > LR_MARGIN``).
    Frames with one link or none between frames that moved then get the level (the camera's
    recent motion, refined by whatever links they have) instead of a still camera.  Limit: on
    a still camera, a false alarm while a group walks the same way (people walking away from
    the camera shrink together) opens the level for up to ``memory`` frames."""

    def __init__(self):
        self.H = np.zeros((3, 3))
        self.b = np.zeros(3)
        #: frames since a frame's own links passed the test
        self.since = None

    def _consistent(self, th: np.ndarray, H: np.ndarray) -> float:
        """The factor ``α`` in (0, 1] for the level's information so that a frame's
        significant motion ``th`` (information ``H``) is within the χ²₃ 99 % gate of the
        level's (its innovation in the summed covariance ``H⁻¹ + (α H_level)⁻¹``): 1 when it is
        already, else found by bisection (an adaptive forgetting: the camera changed its
        motion more than the drift allows)."""

        try:
            d = th - np.linalg.solve(self.H, self.b)          # innovation against the level
            level_cov, frame_cov = np.linalg.inv(self.H), np.linalg.inv(H)
        except np.linalg.LinAlgError:
            return 0.0

        def d2(a: float) -> float:
            return float(d @ np.linalg.solve(level_cov / a + frame_cov, d))

        try:
            if d2(1.0) <= LR_MARGIN:
                return 1.0
            lo, hi = 0.0, 1.0
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                if mid > 0 and d2(mid) <= LR_MARGIN:
                    lo = mid
                else:
                    hi = mid
            return lo
        except np.linalg.LinAlgError:
            return 0.0

    def step(self, prev: np.ndarray, cur: np.ndarray, links: np.ndarray, pos_std: float,
             size_std: float, speed_var: float, memory: float) -> Optional[np.ndarray]:
        """The camera's motion into this frame (2×3), or None: still.  Arguments as
        :func:`fit`; ``memory``: the level's time constant in frames."""
        r = _robust_fit(prev, cur, links, pos_std, size_std, speed_var) if len(prev) else None
        lam = math.exp(-1.0 / max(float(memory), 1.0))
        self.H *= lam
        self.b *= lam
        if r is not None:
            th_r = np.array([r.s, r.t[0], r.t[1]])
            if r.significant and self.since == 0:
                # two frames in a row whose own links beat a still camera (one such frame on a
                # still camera is the test's 1 % false alarm) and this one contradicts the
                # level: the camera changed its motion beyond what the level's drift allows,
                # so the level's information shrinks until this frame is consistent with it
                a = self._consistent(th_r, r.H)
                self.H *= a
                self.b *= a
            self.H += r.H
            self.b += r.H @ th_r
        if r is not None and r.significant:
            self.since = 0
        elif self.since is not None:
            self.since += 1
        if self.since is None or self.since > memory:
            return None
        try:
            th = np.linalg.solve(self.H, self.b)
        except np.linalg.LinAlgError:
            return None
        d = th - np.array([1.0, 0.0, 0.0])
        if not np.isfinite(th).all() or float(d @ self.H @ d) <= LR_MARGIN:
            return None
        return _matrix(float(th[0]), th[1:])


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
