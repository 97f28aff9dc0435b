"""Codebook background subtraction (Kim, Chalidabhongse, Harwood & Davis 2005), vectorised over
pixels, and the foreground blobs that feed DBN-PHD — feng2015 §II-B ("we used a codebook method
for background subtraction [11]") and §II-D.1.

Model (Kim et al. 2005, §2): every pixel keeps up to ``L`` *codewords*, each an RGB vector ``v``
and ``aux = (Ǐ, Î, f, λ, p, q)``: min/max brightness seen, frequency, maximum negative
run-length (MNRL: the longest stretch of frames the codeword was *not* seen), first and last
access.  A pixel ``x`` (brightness ``I = ‖x‖``) matches a codeword when

- ``colordist(x, v) = sqrt(‖x‖² − (x·v)²/‖v‖²) <= ε`` (colour distortion, eq. (2)), and
- ``brightness(I, Ǐ, Î)``: ``α Î <= I <= min(β Î, Ǐ / α)`` (eq. (3)), so the model tolerates
  illumination changes (shadows, flicker) within ``[α, β]``.

Training (Alg. 1) runs for the first ``train_frames`` frames: a matched codeword is updated
(running mean of ``v``, brightness bounds, ``f + 1``, ``λ = max(λ, t − q)``, ``q = t``); an
unmatched pixel gets a new codeword (or replaces its stalest one when all ``L`` are used).
At the end ``λ = max(λ, N − q + p − 1)`` (wrap-around) and codewords with ``λ > N/2`` are
dropped: a moving person seen for less than half the training period is not background, which
is why the model can be trained on frames that contain people (Kim §2.1, "temporal filtering").

Detection during training (our addition, so the tracker does not stay blind for N frames): at
frame ``t <= N`` a codeword counts as background if its wrap-around MNRL at ``t`` is ``<= t/2``
(the same temporal filter applied to the frames seen so far).

After training (Kim §3, layered modelling): a pixel is background if it matches a codeword
with the looser ``ε_detect``; that codeword keeps learning.  Unmatched pixels are foreground and
are modelled in a *cache* codebook ``H``; a cache codeword seen for more than ``cache_add``
frames is promoted into the background (a parked car, a moved chair), cache codewords unseen
for ``cache_forget`` frames are dropped, and background codewords unseen for ``stale_delete``
frames are dropped.

Training is numpy over ``(L, pixels)`` views (a pixel is matched slot by slot only until its
first match) — no Python loop over pixels; detection is one numba pass over the pixels
(:mod:`._codebook_kernels`), on the same codewords stored pixel-major.  ``scale < 1``
runs the model on a down-sampled image (area averaging also removes sensor noise); blobs are
reported in full-resolution pixels.

Blobs (:func:`blobs_from_mask`): morphological opening (removes salt-and-pepper specks) then
closing (fills holes inside a person), 8-connected components, components of at least
``min_area`` full-resolution pixels.  :class:`ForegroundModel` wraps the codebook or OpenCV's
MOG2/KNN (:mod:`pfscope.trackers.detect.bgsub`) behind one ``mask(frame)``.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError
from ..params import param
from ..types import Frame

METHODS = ("codebook", "mog2", "knn")
INITIAL = ("median", "online")


@dataclass(frozen=True)
class BackgroundParams:
    """Background subtraction and blob extraction (feng2015 §II-B, Kim et al. 2005)."""

    method: str = param("codebook", "background model: 'codebook' (feng2015 [11], Kim 2005), "
                                    "'mog2' or 'knn' (OpenCV)", paper="feng2015 §II-B")
    scale: float = param(0.5, "image scale the background model runs at (speed; blobs are "
                              "reported in full-resolution pixels)")
    train_frames: int = param(40, "codebook training period N (frames); codewords with MNRL "
                                  "> N/2 are dropped at its end (Kim §2.1)")
    max_codewords: int = param(5, "codewords per pixel L")
    eps_train: float = param(12.0, "colour distortion threshold while training (RGB units)")
    eps_detect: float = param(18.0, "colour distortion threshold when detecting (RGB units)")
    alpha: float = param(0.6, "brightness lower factor α (Kim: 0.4–0.7)")
    beta: float = param(1.25, "brightness upper factor β (Kim: 1.1–1.5)")
    cache_add: int = param(80, "frames a cache codeword must be seen to join the background")
    cache_forget: int = param(20, "cache codewords unseen this many frames are dropped")
    stale_delete: int = param(400, "background codewords unseen this many frames are dropped")
    morph_kernel: int = param(5, "opening/closing ellipse diameter, full-resolution px "
                                 "(0: no morphology)")
    min_area: int = param(150, "smallest blob, full-resolution foreground pixels")
    max_foreground: float = param(0.5, "a frame whose foreground exceeds this fraction has no "
                                       "blobs (lighting change, camera moved)")
    initial: str = param("median", "initial background of a recorded clip: 'median' (an "
                                   "offline choice: the per-pixel temporal median of "
                                   "median_frames frames sampled evenly over the run seeds the "
                                   "codebook, which then detects and adapts as Kim §3 has it); "
                                   "'online' (also `--online`): the codebook trains on the "
                                   "first train_frames frames (Kim §2)")
    median_frames: int = param(30, "frames sampled for the temporal-median background")

    def __post_init__(self):
        def check(name, ok, rule):
            if not ok:
                raise ValueError(f"BackgroundParams.{name} must be {rule}, "
                                 f"got {getattr(self, name)!r}")
        check("method", self.method in METHODS, f"one of {', '.join(METHODS)}")
        check("scale", 0 < self.scale <= 1, "in (0, 1]")
        check("train_frames", self.train_frames >= 1, ">= 1")
        check("max_codewords", self.max_codewords >= 1, ">= 1")
        check("eps_train", self.eps_train > 0, "> 0")
        check("eps_detect", self.eps_detect > 0, "> 0")
        check("alpha", 0 < self.alpha < 1, "in (0, 1)")
        check("beta", self.beta > 1, "> 1")
        check("min_area", self.min_area >= 1, ">= 1")
        check("max_foreground", 0 < self.max_foreground <= 1, "in (0, 1]")
        check("initial", self.initial in INITIAL, f"one of {', '.join(INITIAL)}")
        check("median_frames", self.median_frames >= 3, ">= 3")


class _Book:
    """Codewords of every pixel: a structure of arrays stored *pixel-major*, (P pixels, L
    slots[, 3]), so one pixel's codewords are adjacent (the numba detection pass walks the
    pixels: :mod:`._codebook_kernels`).  The attributes ``v``, ``vv``, ``imin``, ... are (L, P)
    transposed views of that storage (``_store``: the same memory), which the numpy code
    below (training, priming, the reference detection step) reads slot by slot."""

    FIELDS = ("v", "vv", "imin", "imax", "f", "lam", "p", "q")

    def __init__(self, n_pix: int, L: int):
        f32, i32 = np.float32, np.int32
        self._store = {"v": np.zeros((n_pix, L, 3), f32),
                       "vv": np.zeros((n_pix, L), f32),      # ‖v‖², cached
                       "imin": np.zeros((n_pix, L), f32),
                       "imax": np.zeros((n_pix, L), f32),
                       "f": np.zeros((n_pix, L), i32),       # 0: empty slot
                       "lam": np.zeros((n_pix, L), i32),
                       "p": np.zeros((n_pix, L), i32),
                       "q": np.zeros((n_pix, L), i32)}
        for name, arr in self._store.items():
            setattr(self, name, np.swapaxes(arr, 0, 1))     # (L, P[, 3]) view

    def pixel_major(self) -> tuple:
        """The (P, L[, 3]) storage in :attr:`FIELDS` order (what the kernel updates)."""
        return tuple(self._store[name] for name in self.FIELDS)

    def first_match(self, x, xx, inten, eps, alpha, beta, usable=None):
        """``(hit (P,) bool, slot (P,) int64)``: whether some codeword matches each pixel
        (Kim eqs. (2), (3)) and the first one that does, computed slot by slot on the pixels
        still unmatched (most background pixels match their first codeword, so the later
        slots see a small fraction of the image).  ``usable`` (L, P): codewords allowed."""
        L, P = self.f.shape
        hit = np.zeros(P, bool)
        slot = np.zeros(P, np.int64)
        left = None                                   # None: every pixel (slot 0)
        e2 = np.float32(eps * eps)
        for s in range(L):
            if left is None:
                xs, xxs, ins = x, xx, inten
                v, vv, imin, imax, f = self.v[s], self.vv[s], self.imin[s], self.imax[s], self.f[s]
                us = None if usable is None else usable[s]
            else:
                if not len(left):
                    break
                xs, xxs, ins = x[left], xx[left], inten[left]
                v, vv, imin, imax, f = (self.v[s, left], self.vv[s, left], self.imin[s, left],
                                        self.imax[s, left], self.f[s, left])
                us = None if usable is None else usable[s, left]
            xv = np.einsum("pc,pc->p", xs, v)
            with np.errstate(divide="ignore", invalid="ignore"):
                cd2 = xxs - xv * xv / np.maximum(vv, 1e-6)
            ok = ((f > 0) & (cd2 <= e2) & (ins >= alpha * imax)
                  & (ins <= np.minimum(beta * imax, imin / alpha)))
            if us is not None:
                ok &= us
            if left is None:
                hit[ok] = True
                left = np.flatnonzero(~ok)
            else:
                got = left[ok]
                hit[got] = True
                slot[got] = s
                left = left[~ok]
        return hit, slot

    def update(self, pix, slot, x, inten, t):
        """Kim Alg. 1 step II(v): running mean and aux update of codeword ``slot`` of ``pix``."""
        k = (slot, pix)
        fk = self.f[k]
        f = fk.astype(np.float32)[:, None]
        xp = x[pix]
        v = (f * self.v[k] + xp) / (f + 1)
        self.v[k] = v
        self.vv[k] = np.einsum("pc,pc->p", v, v)
        ip = inten[pix]
        self.imin[k] = np.minimum(self.imin[k], ip)
        self.imax[k] = np.maximum(self.imax[k], ip)
        self.f[k] = fk + 1
        self.lam[k] = np.maximum(self.lam[k], t - self.q[k])
        self.q[k] = t

    def update_hits(self, hit, slot, x, inten, t):
        """:meth:`update` of codeword ``slot[p]`` of every pixel ``p`` with ``hit[p]``.  A slot
        that most pixels matched is updated row-wise with masked writes (no gather/scatter of
        a fancy index over the whole image); the others through :meth:`update`."""
        L, P = self.f.shape
        for s in range(L):
            sel = hit & (slot == s)
            n = int(np.count_nonzero(sel))
            if n == 0:
                continue
            if n < P // 4:
                self.update(np.flatnonzero(sel), np.full(n, s), x, inten, t)
                continue
            f = self.f[s]
            ff = f.astype(np.float32)[:, None]
            v = self.v[s]
            nv = (ff * v + x) / (ff + 1)
            np.copyto(v, nv, where=sel[:, None])
            np.copyto(self.vv[s], np.einsum("pc,pc->p", nv, nv), where=sel)
            np.copyto(self.imin[s], np.minimum(self.imin[s], inten), where=sel)
            np.copyto(self.imax[s], np.maximum(self.imax[s], inten), where=sel)
            np.add(f, 1, out=f, where=sel)
            q = self.q[s]
            np.copyto(self.lam[s], np.maximum(self.lam[s], t - q), where=sel)
            np.copyto(q, t, where=sel)

    def add(self, pix, slot, x, inten, t):
        """Kim Alg. 1 step II(iv): a new codeword ``v = x``, ``aux = (I, I, 1, t − 1, t, t)``."""
        self.v[slot, pix] = x[pix]
        self.vv[slot, pix] = np.einsum("pc,pc->p", x[pix], x[pix])
        self.imin[slot, pix] = inten[pix]
        self.imax[slot, pix] = inten[pix]
        self.f[slot, pix] = 1
        self.lam[slot, pix] = t - 1
        self.p[slot, pix] = t
        self.q[slot, pix] = t

    def clear(self, where):
        """Empty the codewords at ``where`` (an (L, P) mask or a (slots, pixels) index)."""
        self.f[where] = 0
        self.lam[where] = 0

    def wrap_lambda(self, t):
        """MNRL with the wrap-around of Kim §2.1 after ``t`` frames."""
        return np.maximum(self.lam, t - self.q + self.p - 1)

    def free_or_stalest(self, pix, key):
        """A slot per pixel: the first empty one, else the one with the largest ``key``."""
        empty = self.f[:, pix] == 0
        k = np.where(empty, np.int64(1) << 40, key[:, pix].astype(np.int64))
        return np.argmax(k, axis=0)


def _median0(stack: np.ndarray) -> np.ndarray:
    """``np.median(stack, axis=0)`` of a float stack, the same numbers (the middle value, or
    the mean of the two middle ones, of each pixel's sorted values) from one ``np.sort``:
    ~2.3x faster than numpy's per-pixel partition of a few dozen values (the offline
    background's start).  A NaN falls back to ``np.median`` (which returns NaN there)."""
    s = np.sort(stack, axis=0)
    if np.isnan(s[-1]).any():
        return np.median(stack, axis=0)
    k = len(s)
    if k % 2:
        return s[k // 2].copy()
    return np.mean(s[k // 2 - 1:k // 2 + 1], axis=0)


class Codebook:
    """The codebook background model of Kim et al. (2005) over a whole image, vectorised.

    ``apply(image)`` (H, W, 3) uint8 BGR → (H, W) bool raw foreground at the model's scale."""

    def __init__(self, params: BackgroundParams = BackgroundParams(), kernel: bool = True):
        self.params = params
        self.kernel = kernel          # False: the numpy reference detection step (tests)
        self.t = 0
        self._shape: tuple[int, int] | None = None

    def _init(self, shape):
        L = self.params.max_codewords
        n = shape[0] * shape[1]
        self._shape = shape
        self.book = _Book(n, L)
        self.cache = _Book(n, 2)

    def prime(self, images) -> np.ndarray:
        """Seed the model with a background learnt offline: the per-pixel temporal median of
        ``images`` (K, H', W', 3) at the model's scale, one codeword per pixel, its brightness
        bounds the 25th–75th percentile of the pixel's brightness over the images (widened to
        hold the median's).  The training period is then over (as if the median had been seen
        for ``train_frames`` frames): the next frame is detected with the layered model of
        Kim §3 (cache, promotion, deletion), and matched codewords keep learning.  Returns the
        median image (uint8).  A person who walks through is in few of the images, so the
        median shows the empty scene; one standing still in more than half of them is
        background until the cache/stale rules move them out (as in Kim's own model)."""
        p = self.params
        stack = np.asarray(images, dtype=np.float32)
        if stack.ndim != 4 or stack.shape[-1] != 3 or len(stack) < 1:
            raise ValueError(f"codebook.prime: expected (K, H, W, 3) images, got {stack.shape}")
        med = _median0(stack)
        self._init(stack.shape[1:3])
        n = med.shape[0] * med.shape[1]
        x = med.reshape(-1, 3)
        inten = np.sqrt(np.einsum("pc,pc->p", x, x))
        bright = np.sqrt(np.einsum("kpc,kpc->kp", stack.reshape(len(stack), n, 3),
                                   stack.reshape(len(stack), n, 3)))
        # (sorted first: the same quantiles, np.percentile's partition is then ~1/4 faster)
        lo, hi = np.percentile(np.sort(bright, axis=0), [25.0, 75.0], axis=0).astype(np.float32)
        b = self.book
        self.t = p.train_frames
        pix = np.arange(n)
        b.add(pix, np.zeros(n, np.int64), x, inten, self.t)
        b.imin[0] = np.minimum(lo, inten)
        b.imax[0] = np.maximum(hi, inten)
        b.f[0] = p.train_frames
        b.lam[0] = 0
        return np.clip(np.round(med), 0, 255).astype(np.uint8)

    def apply(self, image: np.ndarray) -> np.ndarray:
        p = self.params
        img = np.asarray(image)
        if self._shape is None:
            self._init(img.shape[:2])
        elif img.shape[:2] != self._shape:
            raise InputError(f"codebook: image is {img.shape[1]}x{img.shape[0]} but the model "
                             f"is {self._shape[1]}x{self._shape[0]}")
        self.t += 1
        t = self.t
        if t > p.train_frames and self.kernel:        # the kernel reads the pixels as they are
            return self._detect_kernel(np.ascontiguousarray(img).reshape(-1, 3), t)
        x = img.reshape(-1, 3).astype(np.float32)
        xx = np.einsum("pc,pc->p", x, x)
        inten = np.sqrt(xx)
        b = self.book
        if t <= p.train_frames:
            hit, slot = b.first_match(x, xx, inten, p.eps_train, p.alpha, p.beta)
            b.update_hits(hit, slot, x, inten, t)
            miss = np.flatnonzero(~hit)
            if len(miss):
                b.add(miss, b.free_or_stalest(miss, b.wrap_lambda(t)), x, inten, t)
            # provisional detection: temporal filter over the t frames seen so far
            usable = b.wrap_lambda(t) <= t / 2.0
            fg = ~b.first_match(x, xx, inten, p.eps_detect, p.alpha, p.beta, usable)[0]
            if t == p.train_frames:
                b.clear(b.wrap_lambda(t) > p.train_frames / 2.0)   # Kim §2.1 temporal filter
            return fg.reshape(self._shape)
        return self._detect_numpy(x, xx, inten, t)

    def _detect_kernel(self, x: np.ndarray, t: int) -> np.ndarray:
        """Detection with layered modelling (Kim §3), one numba pass over the pixels
        (:mod:`._codebook_kernels`; the same rules as :meth:`_detect_numpy`)."""
        from ._codebook_kernels import detect

        p, b, c = self.params, self.book, self.cache
        fg = np.empty(len(x), bool)
        f32 = np.float32
        detect(x, t, f32(p.eps_detect * p.eps_detect),
               f32(p.eps_train * p.eps_train), f32(p.alpha), f32(p.beta), p.cache_add,
               p.cache_forget, p.stale_delete, *b.pixel_major(), *c.pixel_major(), fg)
        return fg.reshape(self._shape)

    def _detect_numpy(self, x, xx, inten, t) -> np.ndarray:
        """The numpy reference of the detection step (Kim §3), slot by slot."""
        p = self.params
        b = self.book
        # detection with layered modelling (Kim §3)
        hit, slot = b.first_match(x, xx, inten, p.eps_detect, p.alpha, p.beta)
        b.update_hits(hit, slot, x, inten, t)
        fg = ~hit
        miss = np.flatnonzero(fg)
        c = self.cache
        if len(miss):
            # match the cache only on the foreground pixels (the cache is per pixel too)
            sub = _take(c, miss)
            chit, cslot = sub.first_match(x[miss], xx[miss], inten[miss], p.eps_train, p.alpha,
                                          p.beta)
            c.update(miss[chit], cslot[chit], x, inten, t)
            new = miss[~chit]
            if len(new):
                c.add(new, c.free_or_stalest(new, t - c.q), x, inten, t)
        # cache housekeeping: forget what vanished, promote what stayed
        c.clear((c.f > 0) & (t - c.q > p.cache_forget))
        promote = np.argwhere((c.f > 0) & (c.f > p.cache_add))
        if len(promote):
            cs, pp = promote[:, 0], promote[:, 1]
            bs = b.free_or_stalest(pp, t - b.q)
            for arr in _Book.FIELDS:
                getattr(b, arr)[bs, pp] = getattr(c, arr)[cs, pp]
            b.lam[bs, pp] = 0
            c.clear((cs, pp))
        b.clear((b.f > 0) & (t - b.q > p.stale_delete))
        return fg.reshape(self._shape)


def _take(book: _Book, pix: np.ndarray) -> _Book:
    """A view-like copy of ``book`` restricted to pixels ``pix`` (for matching only)."""
    sub = _Book.__new__(_Book)
    for arr in _Book.FIELDS:
        setattr(sub, arr, getattr(book, arr)[:, pix])
    return sub


_HELPER: list[ThreadPoolExecutor] = []


def _helper() -> ThreadPoolExecutor:
    """The one thread :meth:`ForegroundModel.upcoming` runs the next frames' stage on (one
    worker: the stages of a model run in the order they were submitted)."""
    if not _HELPER:
        _HELPER.append(ThreadPoolExecutor(1, thread_name_prefix="pfscope-background"))
    return _HELPER[0]


class ForegroundModel:
    """One ``mask(frame)`` over the codebook or OpenCV's MOG2/KNN: the cleaned (H', W') uint8
    foreground mask at ``params.scale`` (1 = foreground), after opening and closing."""

    def __init__(self, params: BackgroundParams = BackgroundParams()):
        self.params = params
        self.small: np.ndarray | None = None   # the last frame at the model's scale
        self._next: Frame | None = None         # upcoming(): the frame after this one
        self._ahead: tuple[Frame, Future] | None = None   # its stage, running on the helper
        k = int(round(params.morph_kernel * params.scale))
        self._kernel = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)) if k > 1 else None)
        if params.method == "codebook":
            self._model = Codebook(params)
        else:
            from ..detect.bgsub import BackgroundSubtractionDetector

            self._model = BackgroundSubtractionDetector(method=params.method, morph_kernel=0)

    def _small(self, image: np.ndarray) -> np.ndarray:
        s = self.params.scale
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        if s == 1.0:
            return image
        h, w = image.shape[:2]
        return cv2.resize(image, (max(1, round(w * s)), max(1, round(h * s))),
                          interpolation=cv2.INTER_AREA)

    def prime(self, images) -> np.ndarray | None:
        """Offline initial background (``BackgroundParams.initial == 'median'``) from full-
        resolution frames ``images``: the codebook is seeded with their temporal median
        (:meth:`Codebook.prime`); returns the median at the model's scale, or None when nothing
        was done (MOG2/KNN, 'online', or no images)."""
        if (not isinstance(self._model, Codebook) or self.params.initial != "median"
                or not len(images)):
            return None
        return self._model.prime(np.stack([self._small(im) for im in images]))

    def _stage(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """``(small, mask)`` of ``frame``: resize, background model, opening and closing."""
        small = self._small(frame.image)
        if isinstance(self._model, Codebook):
            raw = self._model.apply(small).view(np.uint8)      # bool as 0/1 bytes, no copy
        else:
            raw = (self._model.foreground(Frame(frame.index, frame.timestamp, small)) > 0
                   ).astype(np.uint8)
        if self._kernel is not None:
            raw = cv2.morphologyEx(raw, cv2.MORPH_OPEN, self._kernel)
            raw = cv2.morphologyEx(raw, cv2.MORPH_CLOSE, self._kernel)
        return small, raw

    def upcoming(self, frame: Frame) -> None:
        """``frame`` is the one the next :meth:`mask` call gets (a recorded clip's look-ahead,
        :func:`pfscope.trackers.pipeline.run`): once this frame's mask is done, the next
        frame's stage runs on a helper thread while the caller goes on (OpenCV and the
        codebook kernel release the GIL).  The model still sees the frames one after the
        other, in order: the same masks and model as without the look-ahead."""
        self._next = frame

    def mask(self, frame: Frame) -> np.ndarray:
        ahead, self._ahead = self._ahead, None
        if ahead is not None:
            small, raw = ahead[1].result()
            if ahead[0] is not frame:
                raise RuntimeError(f"ForegroundModel: frame {ahead[0].index} was announced "
                                   f"as the next one (upcoming) but frame {frame.index} came")
        else:
            small, raw = self._stage(frame)
        self.small = small
        nxt, self._next = self._next, None
        if nxt is not None and nxt is not frame:
            self._ahead = (nxt, _helper().submit(self._stage, nxt))
        return raw


def blobs_from_mask(mask: np.ndarray, scale: float, min_area: int,
                    max_foreground: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of a cleaned mask (at ``scale``) → ``(boxes (N, 4) xywh in
    full-resolution px, fill (N,) foreground fraction of the box)``, biggest first."""
    if mask.size == 0 or np.count_nonzero(mask) > max_foreground * mask.size:
        return np.zeros((0, 4)), np.zeros(0)
    m8 = mask if mask.dtype == np.uint8 else mask.astype(np.uint8)
    # the components of the box around all the foreground are the image's (~0.4x the time)
    x, y, w, h = cv2.boundingRect(m8)
    if w == 0 or h == 0:                                  # no foreground
        return np.zeros((0, 4)), np.zeros(0)
    st, area, keep = _components(m8[y:y + h, x:x + w], min_area * scale * scale)
    st[:, cv2.CC_STAT_LEFT] += x
    st[:, cv2.CC_STAT_TOP] += y
    if len(np.unique(area[keep])) < np.count_nonzero(keep):
        # equal areas: the order below keeps OpenCV's label order for them, which depends on
        # the image's size (its parallel labelling's stripes), so label the whole image
        st, area, keep = _components(m8, min_area * scale * scale)
    boxes = st[keep][:, [cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH,
                         cv2.CC_STAT_HEIGHT]]
    fill = area[keep] / (boxes[:, 2] * boxes[:, 3])
    order = np.argsort(-area[keep], kind="stable")
    return boxes[order] / scale, fill[order]


def _components(m8: np.ndarray, min_area: float):
    """8-connected components of a 0/1 uint8 mask: ``(stats (N, 5) float64, area (N,), keep
    (N,) area >= min_area)`` without the background label."""
    n, _lab, stats, _c = cv2.connectedComponentsWithStats(m8, connectivity=8, ltype=cv2.CV_32S)
    st = stats[1:n].astype(np.float64)
    area = st[:, cv2.CC_STAT_AREA]
    return st, area, area >= min_area


__all__ = ["BackgroundParams", "Codebook", "ForegroundModel", "blobs_from_mask", "METHODS",
           "INITIAL"]
