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
from typing import Optional

import numpy as np
from numba import njit

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


def apply(A: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points (..., 2) mapped by the 2×3 transform ``A``."""
    return pts @ A[:, :2].T + A[:, 2]


def scale(A: np.ndarray) -> float:
    """The similarity's scale ``s`` (``A[:, :2] = s R``)."""
    return float(math.sqrt(abs(A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0])))


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


class _Fit:
    """One frame's robust fit: scale ``s``, shift ``t`` (2,), its information matrix ``H``
    (3×3 over ``(s, t_x, t_y)``, the inverse covariance of the weighted least squares on the
    inliers) and whether it passes the likelihood-ratio test against a still camera."""

    __slots__ = ("s", "t", "H", "significant")

    def __init__(self, s: float, t: np.ndarray, H: np.ndarray, significant: bool):
        self.s, self.t, self.H, self.significant = s, t, H, significant


def _robust_fit(prev: np.ndarray, cur: np.ndarray, links: np.ndarray, pos_std: float,
                size_std: float, speed_var: float) -> Optional[_Fit]:
    """:func:`fit`'s robust estimate on one or more links (None without a link, or without an
    inlier): one numba pass (:func:`_fit_kernel`).

    Per link, its corners (top-left, bottom-right) in both frames and per axis the weight
    ``1 / (var · size²)`` per px², ``var = 2 (σ_y² + σ_size² / 4) + speed_var · w h / size²``
    in box sizes of frame k (a corner = centre ± size / 2: per detection σ_y² + σ_size² / 4,
    two detections a link, plus the person's own step).  Hypotheses: one per link (its size
    ratio and the shift of its centre) and one per pair of links (their weighted least-squares
    ``s p + t``: the scale then also from how far apart they are, not only from their noisy
    sizes), the first :data:`MAX_HYPOTHESES` of each.  Each is scored by its truncated
    residuals over all links (each at most :data:`INLIER_D2`), the best one's inliers are
    refitted by weighted least squares; the likelihood-ratio test: the links' truncated
    squared residual must drop below the identity's by :data:`LR_MARGIN`, on at least
    :data:`MIN_LINKS` inliers (a link either motion calls an outlier costs both the same)."""
    H, out = np.zeros((3, 3)), np.empty(4)
    if not _fit_kernel(np.ascontiguousarray(prev, dtype=np.float64),
                       np.ascontiguousarray(cur, dtype=np.float64),
                       np.ascontiguousarray(links, dtype=np.int64),
                       2.0 * (pos_std ** 2 + size_std ** 2 / 4), float(speed_var), H, out):
        return None
    return _Fit(float(out[0]), out[1:3].copy(), H, bool(out[3]))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _pairwise(a, n):
    """numpy's float64 ``add.reduce`` of the contiguous ``a[:n]``: its pairwise summation,
    the same floats as ``a[:n].sum()``: runs of at most 128 by
    :func:`_pairwise_block`, a longer run as ``pw(lo, h) + pw(lo + h, n − h)`` with ``h`` half
    of it rounded down to 8s -- that recursion walked with an explicit stack (numba's cache
    cannot reload a recursive function: a reloaded one crashed)."""
    lo = np.int64(0)        # not the literal 0: one specialisation of the block (below)
    if n <= 128:
        return _pairwise_block(a, lo, n)
    # per open run: its start, length, and 0 / 1 / 2 = none / its left half / both halves
    # summed (the left half's sum in left[])
    st = np.empty((64, 3), dtype=np.int64)
    left = np.empty(64)
    st[0, 0], st[0, 1], st[0, 2] = lo, n, 0
    sp = 1
    v = 0.0
    while sp > 0:
        top = sp - 1
        if st[top, 1] <= 128 or st[top, 2] == 2:
            v = (_pairwise_block(a, st[top, 0], st[top, 1]) if st[top, 1] <= 128
                 else left[top] + v)
            sp -= 1
            if sp > 0 and st[sp - 1, 2] == 1:
                left[sp - 1] = v
            continue
        h = st[top, 1] // 2
        h -= h % 8
        st[top, 2] += 1
        if st[top, 2] == 1:
            st[sp, 0], st[sp, 1] = st[top, 0], h
        else:
            st[sp, 0], st[sp, 1] = st[top, 0] + h, st[top, 1] - h
        st[sp, 2] = 0
        sp += 1
    return v


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _pairwise_block(a, lo, n):
    """numpy's pairwise sum of ``a[lo:lo + n]``, ``n`` <= 128: under 8 terms in order, else
    eight running sums added as a tree, then the rest in order."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _fit_kernel(prev, cur, links, base, speed_var, H, out):
    """:func:`_robust_fit` in one pass, the same floats as its numpy form (each element's
    expression the same; the 4-term sums over a link's corners and the per-axis sums over
    links in order, as numpy reduces them; the longer sums :func:`_pairwise`).  ``base``: a
    link's still-camera variance per corner coordinate in box sizes, ``2 (σ_y² + σ_size² /
    4)``.  Returns (found, s, t_x, t_y, H, significant); ``found`` False: no link, or no
    inlier."""
    # counters start as np.int64, not as a literal 0: numba would compile the kernels they are
    # passed to once more for the literal (a second specialisation: compile time only)
    m = np.int64(0)
    for i in range(links.shape[0]):
        if links[i] >= 0:
            m += 1
    if m == 0:
        return False
    src = np.empty((m, 2, 2))
    dst = np.empty((m, 2, 2))
    wt = np.empty((m, 2))
    hyp = np.empty((2 * MAX_HYPOTHESES, 3))          # (s, t_x, t_y) per hypothesis
    d2_id = np.empty(m)
    k = np.int64(0)
    for i in range(links.shape[0]):
        if links[i] < 0:
            continue
        p = links[i]
        wh = cur[i, 2] * cur[i, 3]
        for c in range(2):
            hq = prev[p, 2 + c] / 2.0
            hz = cur[i, 2 + c] / 2.0
            src[k, 0, c] = prev[p, c] - hq
            src[k, 1, c] = prev[p, c] + hq
            dst[k, 0, c] = cur[i, c] - hz
            dst[k, 1, c] = cur[i, c] + hz
            sz = cur[i, 2 + c] * cur[i, 2 + c]
            wt[k, c] = 1.0 / ((base + speed_var * wh / sz) * sz)
        d2_id[k] = _link_d2(src, dst, wt, k, 1.0, 0.0, 0.0)
        if k < MAX_HYPOTHESES:
            # one hypothesis per link: its size ratio and the shift of its centre
            s = math.sqrt(wh / (prev[p, 2] * prev[p, 3]))
            hyp[k, 0] = s
            hyp[k, 1] = cur[i, 0] - s * prev[p, 0]
            hyp[k, 2] = cur[i, 1] - s * prev[p, 1]
        k += 1
    nh = n1 = min(m, MAX_HYPOTHESES)
    # ... and one per pair of links (the first ones in np.triu_indices order): their
    # least-squares motion (the scale then also from how far apart they are)
    buf = np.empty(max(8, 4 * m))
    sel = np.empty(m, dtype=np.int64)
    two = np.int64(2)
    for a in range(m):
        for b in range(a + 1, m):
            if nh - n1 >= MAX_HYPOTHESES:
                break
            sel[0], sel[1] = a, b
            hyp[nh, 0], hyp[nh, 1], hyp[nh, 2] = _scale_shift(src, dst, wt, sel, two, buf, H)
            nh += 1
    # every hypothesis scored by its truncated residuals over every link (MSAC)
    best = 0
    low = np.inf
    r = np.empty(m)
    for h in range(nh):
        for i in range(m):
            r[i] = _clip_d2(_link_d2(src, dst, wt, i, hyp[h, 0], hyp[h, 1], hyp[h, 2]))
        cost = _pairwise(r, m)
        if cost != cost:           # np.argmin: the first NaN
            best = h
            break
        if cost < low:
            low = cost
            best = h
    n_in = np.int64(0)
    for i in range(m):
        if _link_d2(src, dst, wt, i, hyp[best, 0], hyp[best, 1], hyp[best, 2]) <= INLIER_D2:
            sel[n_in] = i
            n_in += 1
    if n_in == 0:
        return False
    # the best one's inliers refitted by weighted least squares, with their information
    s, t0, t1 = _scale_shift(src, dst, wt, sel, n_in, buf, H)
    # likelihood-ratio test against a still camera, on at least MIN_LINKS inliers
    n_ok = 0
    for i in range(m):
        d = _link_d2(src, dst, wt, i, s, t0, t1)
        n_ok += d <= INLIER_D2
        r[i] = _clip_d2(d)
        d2_id[i] = _clip_d2(d2_id[i])
    gain = _pairwise(d2_id, m) - _pairwise(r, m)
    out[0], out[1], out[2] = s, t0, t1
    out[3] = 1.0 if n_ok >= MIN_LINKS and gain > LR_MARGIN else 0.0
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _scale_shift(src, dst, wt, sel, n, buf, H):
    """Weighted least squares of ``dst ≈ s src + t`` over the links ``sel[:n]`` (corners
    ``src``, ``dst`` (m, 2, 2), weights ``wt`` (m, 2) per axis): ``(s, t_x, t_y)``; ``H``
    (3×3) gets its information matrix over ``(s, t_x, t_y)`` (the inverse covariance).
    Sums in numpy's order of the array form (per axis over links and corners in order; the
    scalar sums pairwise, ``buf`` (>= 4 n) their terms)."""
    # (the weighted means per axis in locals, not a small array: this runs once per pair
    # hypothesis, and each array is an allocation)
    ps0 = qs0 = ps1 = qs1 = 0.0
    for c in range(2):
        sw = 0.0
        sp = 0.0
        sq = 0.0
        for j in range(n):
            for e in range(2):
                sw += wt[sel[j], c]
                sp += wt[sel[j], c] * src[sel[j], e, c]
                sq += wt[sel[j], c] * dst[sel[j], e, c]
        if c == 0:
            ps0, qs0 = sp / sw, sq / sw
        else:
            ps1, qs1 = sp / sw, sq / sw
        H[0, 1 + c] = H[1 + c, 0] = sp
        H[1 + c, 1 + c] = sw
    for j in range(n):
        for e in range(2):
            dp = src[sel[j], e, 0] - ps0
            buf[4 * j + 2 * e] = wt[sel[j], 0] * dp * dp
            dp = src[sel[j], e, 1] - ps1
            buf[4 * j + 2 * e + 1] = wt[sel[j], 1] * dp * dp
    den = _pairwise(buf, 4 * n)
    for j in range(n):
        for e in range(2):
            buf[4 * j + 2 * e] = (wt[sel[j], 0] * (src[sel[j], e, 0] - ps0)
                                  * (dst[sel[j], e, 0] - qs0))
            buf[4 * j + 2 * e + 1] = (wt[sel[j], 1] * (src[sel[j], e, 1] - ps1)
                                      * (dst[sel[j], e, 1] - qs1))
    s = _pairwise(buf, 4 * n) / den if den > 0 else 1.0
    for j in range(n):
        for e in range(2):
            for c in range(2):
                buf[4 * j + 2 * e + c] = wt[sel[j], c] * src[sel[j], e, c] * src[sel[j], e, c]
    H[0, 0] = _pairwise(buf, 4 * n)
    return s, qs0 - s * ps0, qs1 - s * ps1


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _link_d2(src, dst, wt, i, s, t0, t1):
    """Link ``i``'s squared residual in noise variances under ``s p + t`` (its four terms in
    order)."""
    acc = 0.0
    for e in range(2):
        d = s * src[i, e, 0] + t0 - dst[i, e, 0]
        acc += d * d * wt[i, 0]
        d = s * src[i, e, 1] + t1 - dst[i, e, 1]
        acc += d * d * wt[i, 1]
    return acc


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _clip_d2(d):
    """``np.minimum(d, INLIER_D2)`` (NaN stays NaN)."""
    return d if (d != d or d < INLIER_D2) else INLIER_D2


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
        if r is None:
            return self.advance(None, None, False, memory)
        return self.advance(np.array([r.s, r.t[0], r.t[1]]), r.H, r.significant, memory)

    def advance(self, th_r: Optional[np.ndarray], H_r: Optional[np.ndarray], significant: bool,
                memory: float) -> Optional[np.ndarray]:
        """:meth:`step` once the frame's robust fit is known (:func:`_robust_fit`: ``th_r``
        its ``(s, t_x, t_y)`` and ``H_r`` its information, ``th_r`` None: no fit).
        :meth:`.scene_motion.SceneMotion.observe` does the same in its kernel pass (the
        forgetting and ``H``) and around it (``b``'s updates queued, the rest here's)."""
        lam = math.exp(-1.0 / max(float(memory), 1.0))
        self.H *= lam
        self.b *= lam
        if th_r is not None:
            # two frames in a row whose own links beat a still camera (one such frame on a
            # still camera is the test's 1 % false alarm) and this one contradicts the
            # level: the camera changed its motion beyond what the level's drift allows,
            # so the level's information shrinks until this frame is consistent with it
            self.absorb(th_r, H_r, significant and self.since == 0)
        self.count(th_r is not None and significant)
        if self.still(memory):
            return None
        return self.level()

    def absorb(self, th: np.ndarray, H: np.ndarray, shrink: bool) -> None:
        """Add a frame's fit ``th`` (information ``H``) to the level, its information first
        shrunk until the fit is consistent with it when ``shrink`` (:meth:`_consistent`)."""
        if shrink:
            a = self._consistent(th, H)
            self.H *= a
            self.b *= a
        self.H += H
        self.b += H @ th

    def count(self, significant: bool) -> None:
        """Frames since the last significant fit: 0 on one, +1 otherwise (None: none yet)."""
        if significant:
            self.since = 0
        elif self.since is not None:
            self.since += 1

    def still(self, memory: float) -> bool:
        """No significant fit within ``memory`` frames: the camera is taken as still."""
        return self.since is None or self.since > memory

    def level(self) -> Optional[np.ndarray]:
        """The level's motion (2×3), None where it does not differ from a still camera (χ²₃
        99 % in its own covariance) or is singular."""
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
