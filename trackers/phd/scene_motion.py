"""The scene's motion noise learnt online from the detections (not in maggio2007).

The filter's motion model (:mod:`.motion`) has one acceleration noise ``σ_v`` and one size
noise ``σ_size`` per frame, as fractions of the box size; the ``practical`` preset gives them
per second (``rate.accel_per_s``, ``rate.size_per_s``).  One pair does not fit every scene: in
a street seen from a moving car (ego-motion, people walking towards the camera) boxes jump by
a quarter of their width from one frame to the next and grow by 5-10 % a frame, while people
seen by a fixed camera move smoothly.  With the smooth scene's noise the prediction never
reaches the next detection in the moving scene, and every frame is a new birth.

:class:`SceneMotion` measures, from the detections alone, how far the filter's own model
misses, and raises ``σ_v`` and ``σ_size`` above the preset by the excess (covariance
matching):

- **pairs and triplets** -- a detection of frame k and one of frame k−1 are linked when each
  is the other's nearest (distance in box sizes: ``Δx / w``, ``Δy / h``) within
  :data:`LINK_DIST` box sizes and their heights differ by less than :data:`LINK_LOG_SIZE`
  (log ratio); a link of k−1 → k that continues a link of k−2 → k−1 makes a triplet;
- **acceleration** -- the triplet's second difference ``d = z_k − 2 z_{k−1} + z_{k−2}``
  (per axis over w, h) is the residual of the constant-velocity prediction from two
  detections.  Under the model its variance is ``½ σ_v² + 6 σ_y²`` (the acceleration of two
  frames, ``(1 − c)² + c² = ½`` for ``c = ½``, and the observation noise ``σ_y`` of the
  likelihood, three detections with weights 1, −2, 1), so ``σ_v² = 2 (s² − 6 σ_y²)`` with ``s``
  the measured robust spread, larger axis: only the part the observation noise cannot explain
  is motion;
- **size** -- over a triplet, the log size change across two frames ``log(w_k / w_{k−2})`` and
  across one ``log(w_k / w_{k−1})`` (w and h pooled): the detector's size jitter adds the same
  ``2 σ_n²`` to both variances, while the random walk adds ``σ_size²`` a frame and a steady
  growth ``g`` a frame adds ``g²`` and ``4 g²``, so ``s₂² − s₁² = σ_size² + 3 g²`` is the motion
  alone -- what a zero-order size model must cover (a detector whose sizes come from a fixed
  pyramid of scales jitters a lot and moves nothing here);
- **robust spread** -- ``√(π/2) × mean |x|`` with ``|x|`` winsorised at its :data:`TRIM`
  quantile, over the last :data:`WINDOW` samples (clutter links and mismatches are the tail);
  nothing is changed before :data:`MIN_SAMPLES` triplets.

With ``camera`` on, the camera's image motion of each frame is also estimated from the same
links (:mod:`.camera_motion`; :attr:`SceneMotion.camera`).  The noise is still measured on the
raw triplets, camera motion included: the estimate exists only where enough people are linked
(on KITTI-13 in ~82 of 340 frames by the per-frame test, 186 with the motion's continuity), so
in many frames of a moving camera the filter predicts uncompensated (a noise
learnt on the residuals, 0.12 instead of 0.23 box sizes on KITTI-13, left the other frames
uncovered and cost IDF1: docs/trackers/phd.md).

The result is never below the preset (``max``): a smooth scene keeps its settings exactly.
Deterministic, no randomness; memory bounded by :data:`WINDOW`.  The links compare every
detection of a frame with every one of the previous frame (a few dozen each on real scenes);
a pair of frames with more than :data:`MAX_PAIRS` such pairs (a clutter storm) is not linked,
so the cost per frame stays bounded whatever the detector outputs.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from numba import njit

from . import camera_motion
from ._assoc_kernels import centre_box
from .camera_motion import _fit_kernel, _pairwise
from .gating import kth

#: detections of two frames are linked within this many box sizes (Δx / w, Δy / h)
LINK_DIST = 1.0
#: ... and when their heights differ by less than this (|log h_k / h_{k−1}|)
LINK_LOG_SIZE = 0.4
#: height ratios beyond these have |log| >= LINK_LOG_SIZE for sure (a relative margin of
#: 1e-6, far above the log's one-ulp error): :func:`_link` skips their log and distance
_RATIO_HI = math.exp(LINK_LOG_SIZE) * (1.0 + 1e-6)
_RATIO_LO = math.exp(-LINK_LOG_SIZE) * (1.0 - 1e-6)
#: two frames whose detections make more pairs than this are not linked (bounded cost)
MAX_PAIRS = 250_000
#: samples kept (the most recent), per statistic
WINDOW = 300
#: samples needed before the measured noise is used
MIN_SAMPLES = 30
#: std of a zero-mean Gaussian from the mean of |x|
MEAN_ABS_TO_STD = math.sqrt(math.pi / 2)
#: |x| is winsorised at this quantile before the mean (the tail: clutter links, mismatches)
TRIM = 0.9


def link(prev: np.ndarray, cur: np.ndarray) -> np.ndarray:
    """Mutual nearest neighbours of two frames' detections ``(cx, cy, w, h)`` (N_p, 4), (N_c, 4):
    for each of ``cur`` the index of its link in ``prev``, −1 where none (module docstring)."""
    return _links(prev, cur, _NO_LENGTHS, _NO_LENGTHS)


#: (no chain lengths to carry: :func:`link`; writable, as Chains' arrays are: one kernel
#: specialisation)
_NO_LENGTHS = np.zeros(0, dtype=np.int64)


def _links(prev: np.ndarray, cur: np.ndarray, prev_length: np.ndarray,
           length: np.ndarray) -> np.ndarray:
    """:func:`link`, and when ``length`` has a row per detection of ``cur`` (zeros), each
    linked one's chain length ``prev_length[link] + 1`` written into it (:class:`Chains`)."""
    out = np.full(len(cur), -1, dtype=np.int64)
    if not len(prev) or not len(cur) or len(prev) * len(cur) > MAX_PAIRS:
        return out
    _link(np.ascontiguousarray(prev, dtype=np.float64),
          np.ascontiguousarray(cur, dtype=np.float64), out, prev_length, length)
    return out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _link(prev, cur, out, prev_length, length):
    """:func:`link`'s pass into ``out`` (−1s): the distance of every pair in box sizes of
    ``cur`` (``hypot(Δx / w, Δy / h)``, ∞ where the heights differ by ``LINK_LOG_SIZE`` or
    more), each side's nearest (the first of equals, as ``np.argmin``), kept where mutual and
    within ``LINK_DIST``; with ``length`` as long as ``cur``, ``length[a] = prev_length[b] +
    1`` for each link ``a → b`` (the rest left as they are)."""
    nc, npv = cur.shape[0], prev.shape[0]
    d = np.empty((nc, npv))
    for a in range(nc):
        for b in range(npv):
            r = cur[a, 3] / prev[b, 3]
            # a height ratio clearly outside e^±LINK_LOG_SIZE needs no log (_RATIO_HI/LO:
            # a margin far above log's error) nor a distance; NaN takes the log's test
            if r > _RATIO_HI or r < _RATIO_LO or not abs(math.log(r)) < LINK_LOG_SIZE:
                d[a, b] = np.inf
            else:
                d[a, b] = math.hypot((cur[a, 0] - prev[b, 0]) / cur[a, 2],
                                     (cur[a, 1] - prev[b, 1]) / cur[a, 3])
    j = np.empty(nc, dtype=np.int64)
    for a in range(nc):
        j[a] = _first_min(d[a])
    col = np.empty(nc)
    for a in range(nc):
        # mutual: the nearest cur of this one's nearest prev is this one
        b = j[a]
        for k in range(nc):
            col[k] = d[k, b]
        if _first_min(col) == a and d[a, b] < LINK_DIST:
            out[a] = b
    if length.shape[0] == nc:
        for a in range(nc):
            if out[a] >= 0:
                length[a] = prev_length[out[a]] + 1


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _first_min(v):
    """``np.argmin(v)``: the first smallest, or the first NaN."""
    best, low = 0, v[0]
    for k in range(1, v.shape[0]):
        if low != low:
            break
        if v[k] < low or v[k] != v[k]:
            best, low = k, v[k]
    return best


def robust_std(x: np.ndarray) -> float:
    """``√(π/2) × mean |x|`` with ``|x|`` winsorised at its :data:`TRIM` quantile: the std of
    a zero-mean Gaussian, insensitive to a tail (clutter links), and smooth where a detector's
    sizes come in steps (a median of |x| would jump between 0 and one step)."""
    return float(robust_stds(np.asarray(x, dtype=np.float64).reshape(1, -1))[0])


def robust_stds(x: np.ndarray) -> np.ndarray:
    """:func:`robust_std` of each row of ``x`` (k, n): one numba pass (:func:`_robust_stds`,
    the same floats as the numpy form below, which non-finite input takes: NaN's place in
    np.partition's order)."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[1]
    if not n:
        return np.zeros(len(x))
    lo, hi, t = _trim_at(n)
    out = np.empty(len(x))
    if _robust_stds(np.ascontiguousarray(x), n, n, _NO_SORTED, _NO_SORTED_AT, _NO_STATE,
                    lo, hi, t, out):
        return out
    return _robust_stds_numpy(x, lo, hi, t)


def _trim_at(n: int) -> tuple[int, int, float]:
    """The ranks ``lo``, ``hi`` and the weight ``t`` of np.quantile's linear rule at
    :data:`TRIM` over ``n`` >= 1 values."""
    pos = TRIM * (n - 1)
    lo = int(math.floor(pos))
    return lo, min(lo + 1, n - 1), pos - lo


def _robust_stds_numpy(x: np.ndarray, lo: int, hi: int, t: float) -> np.ndarray:
    """:func:`robust_stds`' numpy form (non-finite input)."""
    n = x.shape[1]
    a = np.abs(x)
    # np.quantile(a, TRIM) (its 'linear' rule) by a partial sort: a tenth of its time
    part = np.partition(a, (lo, hi), axis=1)
    d = part[:, hi] - part[:, lo]
    q = part[:, hi] - d * (1.0 - t) if t >= 0.5 else part[:, lo] + d * t   # numpy's own lerp
    np.minimum(a, q[:, None], out=a)
    # np.mean's own steps (a sum along each row, then / n) without its wrapper
    return MEAN_ABS_TO_STD * (np.add.reduce(a, axis=1) / n)


#: no sorted copy of the window (:func:`robust_stds`: select instead)
_NO_SORTED = np.zeros((0, 0))
_NO_SORTED_AT = np.zeros((0, 0), dtype=np.int64)
_NO_STATE = np.zeros(1, dtype=np.int64)
#: a ring's sorted copy takes more new samples than this by sorting its window again
RESORT = WINDOW // 4


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _robust_stds(buf, total, width, srt, at, state, lo, hi, t, out):
    """:func:`robust_stds` into ``out`` (k,): per row, |x|'s ``lo``-th and ``hi``-th smallest,
    numpy's lerp at ``t``, |x| winsorised there and summed as numpy's add.reduce
    (:func:`.camera_motion._pairwise`).  The rows are the window of a ring of ``width``
    (:class:`_Ring`: the last ``min(total, width)`` of ``total`` samples, sample g at ``buf[:,
    g % width]``, the window one slice); ``buf`` (k, n) of ``total = width = n`` is n samples.
    The ranked values come from selection (the same values as np.partition's), or with
    ``srt`` (k, width) from a sorted copy of |x| kept along the ring: ``srt`` the values,
    ``at`` their samples, ``state[0]`` the samples it holds (−1: none), moved on by dropping
    the samples that left the window and inserting the new ones (a sorted array's ranks are
    the selected values), sorted again after more than :data:`RESORT` new ones.  False
    (``out`` partly written, the sorted copy dropped) on a non-finite value."""
    m = total if total < width else width
    start = total - m
    off = start % width if total > width else 0
    keep = srt.shape[1] == width
    prev = state[0] if keep else -1
    if keep:
        state[0] = -1
    resort = not (0 <= prev <= total and total - prev <= RESORT)
    a = np.empty(m)
    tmp = np.empty(m)
    # (the new samples' places when merged into the sorted copy: at most RESORT of them)
    new_at = np.empty(RESORT if keep and not resort else 0, dtype=np.int64)
    for r in range(buf.shape[0]):
        for i in range(m):
            v = abs(buf[r, off + i])
            if not math.isfinite(v):
                return False
            a[i] = v
        if keep:
            if resort:
                order = np.argsort(a, kind="mergesort")
                for i in range(m):
                    srt[r, i] = a[order[i]]
                    at[r, i] = start + order[i]
            else:
                # the samples that left the window out, then the new ones in (after equals)
                k = 0
                for i in range(prev if prev < width else width):
                    if at[r, i] >= start:
                        srt[r, k] = srt[r, i]
                        at[r, k] = at[r, i]
                        k += 1
                # (the new ones sorted among themselves -- after equals, so equal values in
                # sample order -- then merged in from the back, a kept value before an equal
                # new one: the order of inserting each after its equals, in one pass over
                # the window instead of a shift per new sample)
                g0 = prev if prev > start else start
                nn = total - g0
                for q in range(nn):
                    v = a[g0 - start + q]
                    p = q
                    while p > 0 and tmp[p - 1] > v:
                        tmp[p] = tmp[p - 1]
                        new_at[p] = new_at[p - 1]
                        p -= 1
                    tmp[p] = v
                    new_at[p] = g0 + q
                i = k - 1
                q = nn - 1
                w = k + nn - 1
                while q >= 0:
                    if i >= 0 and srt[r, i] > tmp[q]:
                        srt[r, w] = srt[r, i]
                        at[r, w] = at[r, i]
                        i -= 1
                    else:
                        srt[r, w] = tmp[q]
                        at[r, w] = new_at[q]
                        q -= 1
                    w -= 1
            v_lo = srt[r, lo]
            v_hi = srt[r, hi]
        else:
            for i in range(m):
                tmp[i] = a[i]
            v_lo = kth(tmp, lo)
            v_hi = v_lo
            if hi > lo:
                # kth left every later element >= a[lo]: the next one is their minimum
                v_hi = tmp[lo + 1]
                for i in range(lo + 2, m):
                    v_hi = tmp[i] if tmp[i] < v_hi else v_hi
        d = v_hi - v_lo
        q = v_hi - d * (1.0 - t) if t >= 0.5 else v_lo + d * t
        for i in range(m):
            a[i] = a[i] if a[i] <= q else q            # np.minimum (no NaN here)
        out[r] = MEAN_ABS_TO_STD * (_pairwise(a, np.int64(m)) / m)
    if keep:
        state[0] = total
    return True


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _triplets(Z, prev, pp, j, prev_link, a_buf, a_n, s_buf, s_n):
    """The triplets of :meth:`SceneMotion.observe` (detection ``a`` of ``Z`` linked to ``b =
    j[a]`` of ``prev``, itself linked to ``prev_link[b]`` of ``pp``), in detection order, into
    the rings' buffers as :meth:`_Ring.extend` writes them (the last :data:`WINDOW` samples of
    the frame, each at ``i`` and ``i + WINDOW``): per triplet the acceleration ``(z − 2q + r) /
    q_size`` over (x, y) into ``a_buf``, and the log size changes ``log(z/q)`` (row 0) and
    ``log(z/r)`` (row 1) over (w, h) into ``s_buf``.  Returns the samples each ring keeps."""
    t = 0
    for a in range(j.shape[0]):
        if j[a] >= 0 and prev_link[j[a]] >= 0:
            t += 1
    skip_a = t - WINDOW if t > WINDOW else 0
    skip_s = 2 * t - WINDOW if 2 * t > WINDOW else 0
    k = 0
    for a in range(j.shape[0]):
        b = j[a]
        if b < 0:
            continue
        c = prev_link[b]
        if c < 0:
            continue
        if k >= skip_a:
            at = (a_n + k - skip_a) % WINDOW
            for x in range(2):
                v = (Z[a, x] - 2.0 * prev[b, x] + pp[c, x]) / prev[b, 2 + x]
                a_buf[x, at] = v
                a_buf[x, at + WINDOW] = v
        for x in range(2):
            col = 2 * k + x
            if col >= skip_s:
                at = (s_n + col - skip_s) % WINDOW
                one = np.log(Z[a, 2 + x] / prev[b, 2 + x])
                two = np.log(Z[a, 2 + x] / pp[c, 2 + x])
                s_buf[0, at] = one
                s_buf[0, at + WINDOW] = one
                s_buf[1, at] = two
                s_buf[1, at + WINDOW] = two
        k += 1
    return t - skip_a, 2 * t - skip_s


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _ring_spreads(buf, total, srt, at, state, out):
    """:meth:`_Ring.spreads` of a ring with ``total`` samples into ``out`` (its rows) inside a
    kernel (the ranks of :func:`_trim_at`, the same floats).  False: a non-finite value (the
    caller takes the numpy form)."""
    m = total if total < WINDOW else WINDOW
    if m == 0:
        for r in range(out.shape[0]):
            out[r] = 0.0
        return True
    pos = TRIM * (m - 1)
    lo = np.int64(math.floor(pos))
    hi = lo + 1 if lo + 1 < m - 1 else m - 1
    return _robust_stds(buf, total, WINDOW, srt, at, state, lo, hi, pos - lo, out)


#: frames whose camera-level update ``b ← λ b + H_k θ_k`` waits for one batched numpy matmul
#: (:meth:`SceneMotion._flush`; ``b`` is read only where the camera moved recently)
PENDING = 64
#: :class:`SceneMotion`'s float state ``F`` (one kernel argument): the camera's fit of the
#: frame (s, t_x, t_y, significant) and its information (3×3), the camera level's ``b`` and
#: ``H`` (:class:`.camera_motion.CameraMotion`), the rings' robust spreads (accel x, y, size
#: 1-frame, 2-frame), the pending level updates (λ, θ, H per frame), the rings' buffers and
#: sorted copies (:class:`_Ring`, rows 0-1 accel, 2-3 size); each piece 16-byte aligned
_F_FIT, _F_FIT_H, _F_B, _F_H, _F_SPREAD, _F_PLAM = 0, 4, 14, 18, 28, 32
_F_PTH = _F_PLAM + PENDING
_F_PH = _F_PTH + 3 * PENDING
_F_BUF = _F_PH + 9 * PENDING
_F_SRT = _F_BUF + 4 * 2 * WINDOW
_F_LEN = _F_SRT + 4 * WINDOW
#: ... and its int state ``I``: the rings' sorted copies' samples and states, the pending
#: updates' count and whether each adds ``H_k θ_k``
_I_AT, _I_STATE = 0, 4 * WINDOW
_I_PEND = _I_STATE + 2
_I_PFLAG = _I_PEND + 1
_I_LEN = _I_PFLAG + PENDING


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _observe(B, xywh, prev, pp, prev_link, prev_length, F, I, a_n, s_n, camera, base,
             speed_var, memory, since0):
    """:meth:`SceneMotion.observe`'s per-frame work in one pass on the detections ``Z`` =
    ``B`` (``xywh`` false) or the centre boxes of the top-left boxes ``B`` (``xywh``:
    :meth:`SceneMotion.observe_boxes`, ``xywh_to_cxcywh``'s floats), the same floats as its parts
    (kept as the reference, :meth:`SceneMotion._observe_parts`: :func:`_links`,
    :meth:`.camera_motion.CameraMotion.step`, :func:`_triplets`, :meth:`_Ring.spreads`):
    this frame's links into ``prev`` and chain lengths (from ``prev_length``); with
    ``camera``, the camera's robust fit on the links that continue a chain (``base``,
    ``speed_var`` as :func:`.camera_motion._fit_kernel`'s), the level's forgetting (``memory``
    frames) and the fit's information added to its ``H`` -- not when ``since0`` (the last
    frame was significant) and this one is too: the caller shrinks the level first
    (:meth:`~.camera_motion.CameraMotion.advance`) -- and the frame's update of the level's
    ``b`` queued (:data:`PENDING`); the triplets into the rings (``a_n``, ``s_n`` samples so
    far); when a ring took samples and the acceleration's window holds :data:`MIN_SAMPLES`,
    both rings' robust spreads.  ``F``, ``I``: :data:`_F_FIT`..., :data:`_I_AT`....  Returns
    ``(links, lengths, samples into the acceleration ring, into the size ring, fit: −1 none
    tried / 0 no inlier / 1 found / 3 found, significant / 2 found, significant after a
    significant frame (H not added), spreads: 0 not computed / 1 computed / −1 a non-finite
    value, pending updates, the four spreads, Z)``."""
    if xywh:
        Z = np.empty((B.shape[0], 4), np.float64)
        for a in range(B.shape[0]):
            centre_box(B, a, Z)
    else:
        Z = B
    nc = Z.shape[0]
    npv = prev.shape[0]
    j = np.full(nc, -1, dtype=np.int64)
    length = np.zeros(nc, dtype=np.int64)
    if npv and nc and npv * nc <= MAX_PAIRS:
        _link(prev, Z, j, prev_length, length)
    found = -1
    pend = I[_I_PEND]
    if camera:
        fit = F[_F_FIT:_F_FIT + 4]
        fit_H = F[_F_FIT_H:_F_FIT_H + 9].reshape((3, 3))
        if npv:
            # links that continue a chain (SceneMotion._observe_parts)
            jl = np.empty(nc, dtype=np.int64)
            for a in range(nc):
                jl[a] = j[a] if length[a] >= 2 else -1
            for r in range(9):
                F[_F_FIT_H + r] = 0.0
            found = 1 if _fit_kernel(prev, Z, jl, base, speed_var, fit_H, fit) else 0
        # the level's forgetting (CameraMotion.advance), then this frame's information
        lam = math.exp(-1.0 / (memory if memory > 1.0 else 1.0))
        for r in range(9):
            F[_F_H + r] *= lam
        sig = found == 1 and fit[3] != 0.0
        if sig and since0:
            found = 2
        elif found == 1:
            for r in range(9):
                F[_F_H + r] += F[_F_FIT_H + r]
            if sig:
                found = 3
        # b's update queued: b ← λ b (+ H_k θ_k where H was added; found 2: the caller's)
        if pend >= PENDING:
            raise ValueError("SceneMotion: the camera level's queue is full (_flush)")
        F[_F_PLAM + pend] = lam
        added = found == 1 or found == 3
        I[_I_PFLAG + pend] = 1 if added else 0
        if added:
            for r in range(3):
                F[_F_PTH + 3 * pend + r] = F[_F_FIT + r]
            for r in range(9):
                F[_F_PH + 9 * pend + r] = F[_F_FIT_H + r]
        pend += 1
        I[_I_PEND] = pend
    na = ns = np.int64(0)
    buf = F[_F_BUF:_F_SRT].reshape((4, 2 * WINDOW))
    if prev_link.shape[0] and nc:
        na, ns = _triplets(Z, prev, pp, j, prev_link, buf[:2], a_n, buf[2:], s_n)
    done = 0
    a_n += na
    s_n += ns
    if (na or ns) and (a_n if a_n < WINDOW else WINDOW) >= MIN_SAMPLES:
        srt = F[_F_SRT:_F_LEN].reshape((4, WINDOW))
        at = I[_I_AT:_I_STATE].reshape((4, WINDOW))
        done = 1
        if not _ring_spreads(buf[:2], a_n, srt[:2], at[:2], I[_I_STATE:_I_STATE + 1],
                             F[_F_SPREAD:_F_SPREAD + 2]):
            done = -1
        elif not _ring_spreads(buf[2:], s_n, srt[2:], at[2:], I[_I_STATE + 1:_I_STATE + 2],
                               F[_F_SPREAD + 2:_F_SPREAD + 4]):
            done = -1
    return (j, length, na, ns, found, done, pend, F[_F_SPREAD], F[_F_SPREAD + 1],
            F[_F_SPREAD + 2], F[_F_SPREAD + 3], Z)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _replay(F, I, V):
    """The queued updates of the camera level's ``b`` in order (:meth:`SceneMotion._flush`):
    ``b ← λ b``, then ``+ V[i]`` (``H_k θ_k``, numpy's matmul) where flagged; the queue
    emptied."""
    for i in range(I[_I_PEND]):
        lam = F[_F_PLAM + i]
        for r in range(3):
            F[_F_B + r] *= lam
        if I[_I_PFLAG + i]:
            for r in range(3):
                F[_F_B + r] += V[i, r, 0]
    I[_I_PEND] = 0


class _Ring:
    """The most recent :data:`WINDOW` samples of ``width`` statistics, one row per statistic
    (a numpy ring: no per-frame conversion of Python lists; each statistic contiguous).  Every
    sample is stored twice, at ``i`` and ``i + WINDOW``, so the window oldest first is one slice
    (no copy)."""

    def __init__(self, width: int, store: Optional[tuple] = None):
        """``store``: ``(buf, srt, at, state)``, views of arrays shared with other rings (one
        kernel argument each for all of them: :class:`SceneMotion`), else its own."""
        if store is None:
            store = (np.empty((width, 2 * WINDOW)), np.empty((width, WINDOW)),
                     np.empty((width, WINDOW), dtype=np.int64), np.empty(1, dtype=np.int64))
        self.buf = store[0]
        self.n = 0          # samples written in all
        # |x| of the window sorted per row, the sample each is, the samples it holds
        # (:func:`_robust_stds`; −1: none yet)
        self._srt, self._at, self._state = store[1:]
        self._state[0] = -1

    def spreads(self) -> np.ndarray:
        """:func:`robust_stds` of :meth:`rows` (the same floats), its ranked values from the
        window's sorted copy kept along (a few new samples a frame: no selection over the
        whole window each frame)."""
        n = len(self)
        if not n:
            return np.zeros(len(self.buf))
        lo, hi, t = _trim_at(n)
        out = np.empty(len(self.buf))
        if _robust_stds(self.buf, self.n, WINDOW, self._srt, self._at, self._state, lo, hi, t,
                        out):
            return out
        return _robust_stds_numpy(self.rows(), lo, hi, t)

    def extend(self, cols: np.ndarray) -> None:
        """Append samples ``cols`` (width, m)."""
        cols = cols[:, -WINDOW:]
        m = cols.shape[1]
        at = (self.n + np.arange(m)) % WINDOW
        self.buf[:, at] = cols
        self.buf[:, at + WINDOW] = cols
        self.n += m

    def rows(self) -> np.ndarray:
        """(width, n) oldest first (the sums then add in the same order as over a list)."""
        if self.n <= WINDOW:
            return self.buf[:, :self.n]
        k = self.n % WINDOW
        return self.buf[:, k:k + WINDOW]

    def __len__(self) -> int:
        return min(self.n, WINDOW)


class Chains:
    """Chains of mutually nearest detections over consecutive frames (:func:`link`), the
    pairing :class:`SceneMotion` measures the motion on and the persistence label of the score
    model (:class:`~.filter.SceneModel`).  ``observe(Z)`` once per frame; :attr:`length` then
    holds, per detection of that frame, how many consecutive earlier frames its chain spans
    (0: it continues nothing).  A person detected frame after frame makes a long chain; random
    clutter seldom finds a mutual nearest neighbour of similar size within one box size in the
    previous frame, so it mostly continues nothing (false detections that repeat in place make
    chains too: :mod:`.clutter`'s place model is what tells those apart).  Deterministic; an
    empty frame breaks every chain.  One instance may serve several readers (PHD-MT's scene
    learner and its score model link the same detections): a second ``observe`` with the
    frame's ``key`` already seen returns that frame's links without moving on."""

    def __init__(self):
        self.prev = np.zeros((0, 4))                    # last frame's detections
        self.prev_link = np.zeros(0, dtype=np.int64)    # their links into the frame before
        self.length = np.zeros(0, dtype=np.int64)       # chain length of the last frame's
        self.key = None                                 # the last frame's key (observe)

    def observe(self, Z: np.ndarray, key=None) -> np.ndarray:
        """This frame's detections (N, 4) ``(cx, cy, w, h)``: their links into the previous
        frame (:func:`link`, −1 where none); :attr:`length` and :attr:`prev` move on.  ``key``
        (e.g. the frame index): when it equals the last call's, the frame was observed
        already and its links are returned as they are."""
        if key is not None and key == self.key:
            return self.prev_link
        self.key = key
        Z = np.asarray(Z, dtype=np.float64).reshape(-1, 4)
        length = np.zeros(len(Z), dtype=np.int64)
        j = _links(self.prev, Z, self.length, length)     # (the lengths in the same pass)
        self.prev, self.prev_link, self.length = Z, j, length
        return j


class SceneMotion:
    """Online estimate of the per-frame acceleration and size noise (module docstring).
    ``observe(Z)`` once per frame with the detections ``(cx, cy, w, h)``; :meth:`sigma_v` and
    :meth:`sigma_size` then give the measured noise (None until enough samples)."""

    def __init__(self, pos_std: float, camera: bool = False):
        #: the likelihood's position std as a fraction of the box size (σ_y / w)
        self.pos_std = float(pos_std)
        self.chains = Chains()
        self._prev_prev = np.zeros((0, 4))
        #: estimate the camera's image motion (:mod:`.camera_motion`) from the links
        self.camera_on = bool(camera)
        #: the camera's similarity frame k−1 → k of the last frame observed (2×3), None when
        #: the identity explains the links (a still camera) or ``camera`` is off
        self.camera: Optional[np.ndarray] = None
        #: variance per axis of a person's own displacement in a frame, px² / (w h): what a
        #: still camera's links may move without the camera moving (set by the tracker from
        #: the newborn speed prior)
        self.speed_var = 0.0
        #: the camera motion's memory in frames (:class:`.camera_motion.CameraMotion`; set by
        #: the tracker from the frame rate)
        self.camera_memory = 1.0
        self._camera = camera_motion.CameraMotion()
        #: the likelihood's size std as a fraction of the box size (σ_size; the camera fit)
        self.size_std = 2.0 * self.pos_std
        # the kernel pass's state (_observe): floats F, ints I, and views of them
        self._F = F = np.zeros(_F_LEN)
        self._I = I = np.zeros(_I_LEN, dtype=np.int64)
        self._camera.H = F[_F_H:_F_H + 9].reshape(3, 3)
        self._camera.b = F[_F_B:_F_B + 3]
        buf = F[_F_BUF:_F_SRT].reshape(4, 2 * WINDOW)
        srt = F[_F_SRT:_F_LEN].reshape(4, WINDOW)
        at = I[_I_AT:_I_STATE].reshape(4, WINDOW)
        self.accel = _Ring(2, (buf[:2], srt[:2], at[:2], I[_I_STATE:_I_STATE + 1]))  # (w, h)
        self.size = _Ring(2, (buf[2:], srt[2:], at[2:], I[_I_STATE + 1:_I_STATE + 2]))
        # the robust spreads of the windows (accel x, y; size 1-frame, 2-frame), kept until a
        # sample comes in (_spreads), and the rings' sample counts they are of
        self._spread = F[_F_SPREAD:_F_SPREAD + 4]
        self._spread_key: Optional[tuple[int, int]] = None
        self._sp = (0.0, 0.0, 0.0, 0.0)       # ... as floats
        # the camera's fit of the last frame (_observe): (s, t_x, t_y), its information; the
        # queued updates of the level's b (_flush)
        self._fit_th = F[_F_FIT:_F_FIT + 3]
        self._fit_H = F[_F_FIT_H:_F_FIT_H + 9].reshape(3, 3)
        self._pend_th = F[_F_PTH:_F_PH].reshape(PENDING, 3, 1)
        self._pend_H = F[_F_PH:_F_BUF].reshape(PENDING, 3, 3)
        # the queue's kernel loaded (or compiled) with the tracker, as _observe is in its
        # first frame: its first real call may come long after the warm-up's frames
        _replay(F, I, np.zeros((0, 3, 1)))

    def observe(self, Z: np.ndarray, key=None) -> None:
        """One frame's detections (N, 4) ``(cx, cy, w, h)``; an empty frame breaks the links.
        ``key``: the frame's key for :class:`Chains` (shared with a reader that observes the
        same frame after this).  One kernel call a frame (:func:`_observe`; the same floats as
        :meth:`_observe_parts`, which a frame its Chains has seen already takes)."""
        ch = self.chains
        if key is not None and key == ch.key:
            self._observe_parts(Z, key)
            return
        Z = np.ascontiguousarray(Z, dtype=np.float64)
        if Z.ndim != 2:
            Z = Z.reshape(-1, 4)
        self._observe_pass(Z, False, key)

    def observe_boxes(self, boxes: np.ndarray, key=None) -> np.ndarray:
        """:meth:`observe` of the detections given as top-left boxes ``(x, y, w, h)`` (N, 4)
        (C-contiguous float64: a frame's ``Detections.boxes``): their centre boxes
        ``(cx, cy, w, h)`` -- ``xywh_to_cxcywh``'s floats -- are computed in the same kernel
        call and returned (one kernel call a frame fewer for the tracker, which needs them
        too)."""
        ch = self.chains
        if key is not None and key == ch.key:
            from ._assoc_kernels import centre_boxes

            Z = centre_boxes(np.ascontiguousarray(boxes, dtype=np.float64).reshape(-1, 4))
            self._observe_parts(Z, key)
            return Z
        boxes = np.ascontiguousarray(boxes, dtype=np.float64)
        if boxes.ndim != 2:
            boxes = boxes.reshape(-1, 4)
        return self._observe_pass(boxes, True, key)

    def _observe_pass(self, B: np.ndarray, xywh: bool, key) -> np.ndarray:
        """:func:`_observe` on ``B`` (its ``xywh``) and the state it hands back; returns the
        frame's detections ``(cx, cy, w, h)``."""
        ch = self.chains
        prev = ch.prev
        a, s = self.accel, self.size
        cam = self.camera_on
        c = self._camera
        memory = self.camera_memory
        j, length, na, ns, found, done, pend, sx, sy, one, two, Z = _observe(
            B, xywh, prev, self._prev_prev, ch.prev_link, ch.length, self._F, self._I, a.n,
            s.n, cam, 2.0 * (self.pos_std ** 2 + self.size_std ** 2 / 4),
            float(self.speed_var), float(memory), c.since == 0)
        ch.key = key
        ch.prev, ch.prev_link, ch.length = Z, j, length
        a.n += na
        s.n += ns
        if done > 0:
            self._spread_key = (a.n, s.n)
            self._sp = (sx, sy, one, two)
        if cam:
            # CameraMotion.advance after the kernel's part of it (forgetting, H; b queued)
            if found == 2:                          # significant, contradicting the level
                self._flush()
                c.absorb(self._fit_th, self._fit_H, True)
            c.count(found > 1)                      # 2, 3: significant
            if c.still(memory):
                self.camera = None
                if pend >= PENDING:
                    self._flush()
            else:
                self._flush()
                self.camera = c.level()
        self._prev_prev = prev
        return Z

    def _flush(self) -> None:
        """The camera level's queued updates of ``b`` (:func:`_observe`) applied in order: their
        ``H_k θ_k`` by one batched numpy matmul (the floats of one ``H_k @ θ_k`` each, as
        :meth:`.camera_motion.CameraMotion.advance` computes them), then :func:`_replay`."""
        n = int(self._I[_I_PEND])
        if n:
            _replay(self._F, self._I, np.matmul(self._pend_H[:n], self._pend_th[:n]))

    def _observe_parts(self, Z: np.ndarray, key=None) -> None:
        """:meth:`observe` a piece at a time (the reference of :func:`_observe`)."""
        self._flush()
        Z = np.asarray(Z, dtype=np.float64).reshape(-1, 4)
        ch = self.chains
        prev, prev_link = ch.prev, ch.prev_link
        j = ch.observe(Z, key)
        if self.camera_on:
            # links that continue a chain (a detection seen in the two frames before): random
            # clutter seldom does, and two clutter links can look like a camera motion
            jl = np.where(ch.length >= 2, j, -1)
            self.camera = self._camera.step(prev, Z, jl, self.pos_std, self.size_std,
                                            self.speed_var, self.camera_memory)
        if len(prev_link) and len(j):
            # triplets: the links k−1 → k that continue a link k−2 → k−1, their second
            # differences and log size changes straight into the rings (one pass)
            c = np.ascontiguousarray
            na, ns = _triplets(c(Z), c(prev), c(self._prev_prev), j, prev_link,
                               self.accel.buf, self.accel.n, self.size.buf, self.size.n)
            self.accel.n += na
            self.size.n += ns
        self._prev_prev = prev

    def _spreads(self) -> np.ndarray:
        """:func:`robust_stds` of both rings' windows (:meth:`_Ring.spreads`; accel x, y, size
        1-frame, 2-frame), recomputed only when a ring changed (:meth:`observe` computes them
        in its pass)."""
        key = (self.accel.n, self.size.n)
        if self._spread_key != key:
            self._spread[:2] = self.accel.spreads()
            self._spread[2:] = self.size.spreads()
            self._spread_key = key
            self._sp = tuple(self._spread.tolist())
        return self._spread

    def sigmas(self) -> tuple[Optional[float], Optional[float]]:
        """``(sigma_v(), sigma_size())`` (the spreads read once)."""
        n_a, n_s = self.accel.n, self.size.n
        if n_a < MIN_SAMPLES:                   # (MIN_SAMPLES <= WINDOW)
            return None, None
        if self._spread_key != (n_a, n_s):
            self._spreads()
        sx, sy, one, two = self._sp
        s = max(sx, sy)
        sv = math.sqrt(max(0.0, 2.0 * (s * s - 6.0 * self.pos_std ** 2)))
        m = n_s if n_s < WINDOW else WINDOW
        if m < 2 * MIN_SAMPLES:
            return sv, None
        margin = 2.0 * math.sqrt(2.0 * (one ** 4 + two ** 4) / m)
        return sv, math.sqrt(max(0.0, two * two - one * one - margin))

    def sigma_v(self) -> Optional[float]:
        """Measured acceleration std per frame (fraction of w, h), 0 when the observation
        noise explains the residuals; None before :data:`MIN_SAMPLES` triplets."""
        if len(self.accel) < MIN_SAMPLES:
            return None
        sx, sy = self._spreads()[:2].tolist()
        s = max(sx, sy)
        return math.sqrt(max(0.0, 2.0 * (s * s - 6.0 * self.pos_std ** 2)))

    def sigma_size(self) -> Optional[float]:
        """Measured size-change std per frame (fraction of w, h), 0 when the detector's
        jitter explains the changes; None before :data:`MIN_SAMPLES` triplets."""
        if len(self.size) < 2 * MIN_SAMPLES:
            return None
        one, two = self._spreads()[2:].tolist()
        # the difference of two sampled variances is noisy (Var(ŝ²) ≈ 2 s⁴ / n each): only
        # its excess over two standard errors is motion, or a jittery detector whose boxes do
        # not change size at all would read as a size noise of ~0.07-0.1 from sampling alone
        margin = 2.0 * math.sqrt(2.0 * (one ** 4 + two ** 4) / len(self.size))
        return math.sqrt(max(0.0, two * two - one * one - margin))
