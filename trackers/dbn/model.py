"""The deep belief network of feng2015 §II-C (Fig. 1, Algorithms 1–2) in torch, on CPU.

Architecture (Fig. 1): input layer (the D colour + HOG features of :mod:`.features`) → two
RBM hidden layers (``hidden``, default 64 and 32 sigmoid units) → a one-unit output.

Training:

1. **Greedy pretraining** (Algorithm 2, Hinton & Salakhutdinov 2006): RBM 1 models the
   features, RBM 2 models RBM 1's *mean activations* p(h¹ = 1 | v) (Alg. 2 step 2 allows means
   or samples; means have less variance), each by **CD-1** (Algorithm 1): ``p(h⁰|v⁰)``, sample
   ``h⁰``, reconstruct ``p(v¹|h⁰)``, ``p(h¹|v¹)``, and
   ``W ← W + λ (v⁰ p(h⁰|v⁰)ᵀ − v¹ p(h¹|v¹)ᵀ)`` — Alg. 1 step 5 with its missing bracket
   restored, averaged over a mini-batch, plus the usual visible/hidden biases (Alg. 1 omits
   them; Hinton's RBM has them).  The visible units are Bernoulli with the feature values in
   [0, 1] as probabilities; ``v¹`` is the reconstruction's mean (Hinton's practical guide: less
   sampling noise than Alg. 1 step 4's sample).
2. **Fine-tuning** (Alg. 2 step 5): a logistic output unit ``W⁽³⁾`` on top, then every weight
   trained by back-propagation of the class-balanced cross-entropy (people = 1).

Training set (:func:`collect_samples`): people are the gt boxes *and the foreground blobs of
people* — the tracker asks the DBN about blobs ("classify the noise and the foreground part of
the human targets", §II-D.2), and a blob is not a gt box (looser, shadow, cut legs); not people
are the noise blobs, random and shifted windows.  The training part is augmented with copies
whose hue histograms are turned by 90°, 180° and 270° (:func:`rotate_hue`): a sequence has few
people (PETS09-S2L1: about ten, feng2015: 34), and without it the DBN learnt their clothes —
on PETS, trained on 1–400 (held out 321–400), it rejected 20 % of the person blobs of 401–795
with P(person) ≈ 0.03, which cost DBN-PHD a person per frame in cardinality (OSPA).

The particle score, eq. (9) ``p(x) = exp(c · 1 · W⁽³⁾ ·)``: we read ``1 · W⁽³⁾`` applied to the
top hidden layer as the output unit's activation ``a(x)`` (the one-class output of Fig. 1)
and offer two log-scores (:mod:`.likelihood`): ``c · a(x)`` (eq. (9) literally) or
``c · log σ(a(x))`` (default: bounded by 0, so a confident person leaves the Gaussian
likelihood unchanged and noise scales it down).

Everything is seeded by one ``seed`` through a ``torch.Generator`` (initial weights,
mini-batch order, hidden samples): same seed and data → the same model, bit for bit.
Models are saved with a format tag and version and load on CPU with ``weights_only=True``;
a bad or mismatched file raises a one-line :class:`~pfscope.trackers.errors.InputError`.

This is the only pfscope module that imports torch at import time; everything else imports it
lazily, so ``pfscope --help`` never loads torch.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Callable, Iterable, Optional

import numpy as np
import torch

from ..errors import InputError
from .features import FeatureConfig, FrameFeatures
from .weights import FORMAT, SHIPPED, VERSION, check_rows, check_state, forward, shipped


@contextmanager
def single_thread():
    """Run torch on one thread inside the block (restored after).  The DBN's matrices are tiny
    (~100 × 64): with torch's default OpenMP pool on a busy 2-core machine each product took
    ~8 ms instead of ~20 µs (threads spinning against each other), so one thread is both
    faster and leaves the other core to the rest of the pipeline."""
    prev = torch.get_num_threads()
    if prev != 1:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if prev != 1:
            torch.set_num_threads(prev)


class RBM(torch.nn.Module):
    """A Bernoulli–Bernoulli restricted Boltzmann machine (weights ``W (n_v, n_h)``)."""

    def __init__(self, n_visible: int, n_hidden: int, gen: torch.Generator):
        super().__init__()
        self.W = torch.nn.Parameter(0.01 * torch.randn(n_visible, n_hidden, generator=gen,
                                                       dtype=torch.float64))
        self.b_v = torch.nn.Parameter(torch.zeros(n_visible, dtype=torch.float64))
        self.b_h = torch.nn.Parameter(torch.zeros(n_hidden, dtype=torch.float64))

    def hidden(self, v: torch.Tensor) -> torch.Tensor:
        """p(h = 1 | v) = σ(v W + b_h)."""
        return torch.sigmoid(v @ self.W + self.b_h)

    def visible(self, h: torch.Tensor) -> torch.Tensor:
        """p(v = 1 | h) = σ(h Wᵀ + b_v)."""
        return torch.sigmoid(h @ self.W.T + self.b_v)

    @torch.no_grad()
    def cd1(self, v0: torch.Tensor, lr: float, gen: torch.Generator) -> None:
        """One CD-1 update on a mini-batch (Algorithm 1)."""
        ph0 = self.hidden(v0)                                  # step 1
        h0 = torch.bernoulli(ph0, generator=gen)               # step 2
        v1 = self.visible(h0)                                  # step 3 (mean reconstruction)
        ph1 = self.hidden(v1)                                  # step 4
        n = v0.shape[0]
        self.W += lr * (v0.T @ ph0 - v1.T @ ph1) / n           # step 5
        self.b_v += lr * (v0 - v1).mean(0)
        self.b_h += lr * (ph0 - ph1).mean(0)

    @torch.no_grad()
    def reconstruction_error(self, v: torch.Tensor) -> float:
        """Mean squared error of the mean-field reconstruction ``p(v | p(h | v))``."""
        return float(((v - self.visible(self.hidden(v))) ** 2).mean())


class DBN(torch.nn.Module):
    """Fig. 1: features → RBM hidden layers → one output unit (its activation is ``logit``)."""

    def __init__(self, n_in: int, hidden: tuple[int, ...], gen: torch.Generator):
        super().__init__()
        sizes = (n_in,) + tuple(hidden)
        self.rbms = torch.nn.ModuleList(RBM(a, b, gen) for a, b in zip(sizes[:-1], sizes[1:]))
        self.out = torch.nn.Linear(sizes[-1], 1, dtype=torch.float64)
        with torch.no_grad():
            self.out.weight.copy_(0.01 * torch.randn(1, sizes[-1], generator=gen,
                                                     dtype=torch.float64))
            self.out.bias.zero_()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x
        for r in self.rbms:
            h = r.hidden(h)
        return self.out(h)[:, 0]


@dataclass
class DBNModel:
    """A trained DBN with the feature layout it was trained on and its training record."""

    net: DBN
    features: FeatureConfig
    hidden: tuple[int, ...]
    info: dict = field(default_factory=dict)
    _layers: Optional[tuple] = field(default=None, init=False, repr=False, compare=False)

    def logits(self, X: np.ndarray) -> np.ndarray:
        """Output activations ``a(x)`` (N,) float64 of feature rows ``X`` (N, D).

        The forward pass runs in numpy on a copy of the trained weights taken at the first
        call (the tracker asks for a few rows at a time, several times a frame: torch's
        per-call dispatch cost more than the products; :meth:`torch_logits` is the same
        network in torch, equal to float rounding — tested)."""
        X = check_rows(X, self.features.dim)
        if len(X) == 0:
            return np.zeros(0)
        if self._layers is None:
            with torch.no_grad():
                self._layers = (
                    [(r.W.detach().numpy().copy(), r.b_h.detach().numpy().copy())
                     for r in self.net.rbms],
                    self.net.out.weight.detach().numpy()[0].copy(),
                    float(self.net.out.bias.detach()[0]))
        return forward(self._layers, X)

    @torch.no_grad()
    def torch_logits(self, X: np.ndarray) -> np.ndarray:
        """:meth:`logits` through the torch network itself."""
        X = np.asarray(X, dtype=np.float64)
        with single_thread():
            return self.net(torch.from_numpy(X)).numpy().astype(np.float64)

    def prob(self, X: np.ndarray) -> np.ndarray:
        """P(person | features) = σ(a)."""
        return 1.0 / (1.0 + np.exp(-self.logits(X)))

    def state(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "features": self.features.to_dict(),
                "hidden": list(self.hidden), "info": _plain(self.info),
                "weights": {k: v.detach().clone() for k, v in self.net.state_dict().items()}}

    def save(self, path) -> Path:
        """Write the model to ``path`` (under a temporary name, renamed on success)."""
        path = Path(path)
        tmp = path.with_name(path.name + ".incomplete")
        torch.save(self.state(), tmp)
        os.replace(tmp, path)
        return path


def _plain(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, (np.floating, np.integer)):
            v = v.item()
        if isinstance(v, dict):
            v = _plain(v)
        out[str(k)] = v
    return out


def load_model(path) -> DBNModel:
    """Load a model saved by :meth:`DBNModel.save`; any problem → one-line InputError."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such DBN model file")
    try:
        st = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file is the user's input
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"{path}: not a pfscope DBN model ({msg[:120]})") from None
    cfg, hidden, info = check_state(path, st)
    try:
        net = DBN(cfg.dim, hidden, torch.Generator().manual_seed(0))
        net.load_state_dict(st["weights"])
    except Exception as e:  # noqa: BLE001
        raise InputError(f"{path}: DBN model does not match its layout "
                         f"({type(e).__name__}: {str(e).splitlines()[0][:120]})") from None
    net.eval()
    return DBNModel(net, cfg, hidden, info)


# ----------------------------------------------------------------------------- training

def _batches(n: int, batch: int, gen: torch.Generator):
    order = torch.randperm(n, generator=gen)
    for i in range(0, n, batch):
        yield order[i:i + batch]


def pretrain_rbm(rbm: RBM, V: torch.Tensor, epochs: int, lr: float, batch: int,
                 gen: torch.Generator) -> list[float]:
    """CD-1 epochs over ``V`` (Algorithm 1); returns the reconstruction error after each."""
    errs = []
    for _ in range(epochs):
        for idx in _batches(len(V), batch, gen):
            rbm.cd1(V[idx], lr, gen)
        errs.append(rbm.reconstruction_error(V))
    return errs


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """Area under the ROC curve (Mann–Whitney statistic, ties counted half)."""
    s = np.asarray(scores, dtype=np.float64)
    y = np.asarray(labels).astype(bool)
    n1, n0 = int(y.sum()), int((~y).sum())
    if n1 == 0 or n0 == 0:
        return float("nan")
    order = np.argsort(s, kind="mergesort")
    ranks = np.empty(len(s))
    ss = s[order]
    # average ranks over ties
    _, first, counts = np.unique(ss, return_index=True, return_counts=True)
    avg = first + (counts - 1) / 2.0 + 1
    ranks[order] = np.repeat(avg, counts)
    return float((ranks[y].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def rotate_hue(X: np.ndarray, features: FeatureConfig, k: int) -> np.ndarray:
    """Feature rows of the same boxes with every chromatic pixel's hue turned by ``k`` hue bins
    (``k · 180/hue_bins`` OpenCV hue units): the hue part of each colour band rolled by ``k``.
    Exact for hue turns that are whole bins (a bin edge maps to a bin edge); HOG and the grey
    bins do not change."""
    Xr = np.array(X, dtype=np.float64, copy=True)
    c = features
    for r in range(c.colour_rows):
        a = c.hog_dim + r * c.colour_bins
        Xr[:, a:a + c.hue_bins] = np.roll(X[:, a:a + c.hue_bins], k, axis=1)
    return Xr


def train_dbn(X: np.ndarray, y: np.ndarray, **kw) -> DBNModel:
    """Pretrain (Alg. 1–2) and fine-tune (Alg. 2 step 5) a DBN on features ``X`` (N, D) with
    labels ``y`` (1 = person); see :func:`_train` for the options.  Single-threaded torch."""
    with single_thread():
        return _train(X, y, **kw)


def _train(X: np.ndarray, y: np.ndarray, *, features: FeatureConfig = FeatureConfig(),
              hidden: tuple[int, ...] = (64, 32), seed: int = 0, pre_epochs: int = 10,
              fine_epochs: int = 30, lr_rbm: float = 0.05, lr: float = 3e-3, batch: int = 64,
              holdout: float = 0.2, holdout_mask: Optional[np.ndarray] = None,
              hue_shifts: tuple[int, ...] = (2, 4, 6), box_height: Optional[float] = None,
              progress: Optional[Callable[[str, int, int], None]] = None) -> DBNModel:
    """Training behind :func:`train_dbn`.  A random ``holdout`` fraction (or the samples where
    ``holdout_mask`` is true, e.g. the last frames) is kept out of training and scored
    (``info['holdout_accuracy']``, ``info['holdout_auc']``).  ``progress(phase, i, n)``
    is called after each epoch.  ``hue_shifts``: the training part is augmented with copies
    whose hue bins are rotated by these many bins (:func:`rotate_hue`), so the DBN learns
    people rather than the clothes of the few people in one sequence."""
    X = np.asarray(X, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64).reshape(-1)
    if X.ndim != 2 or X.shape[1] != features.dim or len(X) != len(y) or len(X) < 4:
        raise InputError(f"train-dbn: need at least 4 samples of {features.dim} features, "
                         f"got {X.shape}")
    if y.min() == y.max():
        raise InputError("train-dbn: the training set has only one class")
    gen = torch.Generator().manual_seed(int(seed))
    n = len(X)
    perm = torch.randperm(n, generator=gen).numpy()
    if holdout_mask is not None:
        hm = np.asarray(holdout_mask, dtype=bool).reshape(-1)
        hold, tr = np.flatnonzero(hm), perm[~hm[perm]]
        n_hold = len(hold)
        if len(np.unique(y[tr])) < 2:
            raise InputError("train-dbn: the training part has only one class")
    else:
        n_hold = int(round(holdout * n)) if holdout > 0 else 0
        hold, tr = perm[:n_hold], perm[n_hold:]
    Xa, ya = X[tr], y[tr]
    if hue_shifts:
        Xa = np.concatenate([Xa] + [rotate_hue(Xa, features, k) for k in hue_shifts])
        ya = np.tile(ya, 1 + len(hue_shifts))
    Xt, yt = torch.from_numpy(Xa), torch.from_numpy(ya)
    net = DBN(features.dim, tuple(hidden), gen)
    recon = []
    V = Xt
    for li, rbm in enumerate(net.rbms):                       # Algorithm 2, steps 1–4
        def cb(i, li=li):
            if progress:
                progress(f"pretrain RBM {li + 1}", i, pre_epochs)
        errs = []
        for e in range(pre_epochs):
            errs += pretrain_rbm(rbm, V, 1, lr_rbm, batch, gen)
            cb(e + 1)
        recon.append(errs)
        with torch.no_grad():
            V = rbm.hidden(V)                                  # mean activations upward
    # Algorithm 2, step 5: supervised fine-tuning of every weight
    pos = float(yt.sum())
    pos_weight = torch.tensor((len(yt) - pos) / max(pos, 1.0), dtype=torch.float64)
    loss_fn = torch.nn.BCEWithLogitsLoss(pos_weight=pos_weight)
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    for e in range(fine_epochs):
        for idx in _batches(len(Xt), batch, gen):
            opt.zero_grad()
            loss = loss_fn(net(Xt[idx]), yt[idx])
            loss.backward()
            opt.step()
        if progress:
            progress("fine-tune", e + 1, fine_epochs)
    net.eval()
    model = DBNModel(net, features, tuple(hidden))
    with torch.no_grad():
        train_loss = float(loss_fn(net(Xt), yt))
    info = {"seed": int(seed), "samples": int(n), "positives": int(y.sum()),
            "holdout": int(n_hold), "train_loss": train_loss,
            "hue_shifts": [int(k) for k in hue_shifts],
            "recon_error": [float(r[-1]) for r in recon],
            "recon_error_first": [float(r[0]) for r in recon]}
    if n_hold:
        s = model.logits(X[hold])
        info["holdout_accuracy"] = float(np.mean((s > 0) == (y[hold] > 0.5)))
        info["holdout_auc"] = roc_auc(s, y[hold])
        info["holdout_positives"] = int(y[hold].sum())
    if box_height:
        info["box_height"] = float(box_height)
    model.info = info
    return model


# ----------------------------------------------------------------------------- training sets

def _jitter(boxes: np.ndarray, rng: np.random.Generator, rel: float) -> np.ndarray:
    e = rng.normal(0.0, rel, boxes.shape)
    w, h = boxes[:, 2:3], boxes[:, 3:4]
    out = boxes.copy()
    out[:, 2:] = boxes[:, 2:] * np.exp(e[:, 2:])
    out[:, 0:1] += e[:, 0:1] * w + (w - out[:, 2:3]) / 2
    out[:, 1:2] += e[:, 1:2] * h + (h - out[:, 3:4]) / 2
    return out


def sample_boxes(image_shape, gt_boxes: np.ndarray, blobs: np.ndarray,
                 rng: np.random.Generator, *, n_random: int = 12, n_near: int = 4,
                 n_jitter: int = 2, max_iou: float = 0.3, blob_iou: float = 0.5,
                 avoid: Optional[np.ndarray] = None) -> tuple[np.ndarray, np.ndarray]:
    """Boxes and labels for one frame: people = the gt boxes and ``n_jitter`` jittered copies
    each (5% of the size, the spread of a particle cloud), and the background-subtraction
    blobs of a person (IoU >= ``blob_iou`` with a gt box: what the tracker asks the DBN about,
    feng2015 §II-D.2 "classify the noise and the foreground part of the human targets");
    not people = the other blobs, ``n_random`` random person-shaped windows and ``n_near``
    windows shifted off each person, all with IoU < ``max_iou`` against every gt box and every
    ``avoid`` box (people not taken as positives, e.g. mostly occluded ones).  Blobs in
    between (a part of a person, two people merged) are left out."""
    from ..eval.overlap import box_iou

    H, W = image_shape[:2]
    gt = np.asarray(gt_boxes, dtype=np.float64).reshape(-1, 4)
    pos = [gt] + [_jitter(gt, rng, 0.05) for _ in range(n_jitter)]
    heights = gt[:, 3] if len(gt) else np.array([0.2 * H])
    hr = rng.uniform(0.7, 1.3, n_random) * rng.choice(heights, n_random)
    wr = hr * rng.uniform(0.3, 0.6, n_random)
    rand = np.stack([rng.uniform(-0.1, 1.0, n_random) * W, rng.uniform(-0.1, 1.0, n_random) * H,
                     wr, hr], axis=1)
    near = np.zeros((0, 4))
    if len(gt) and n_near:
        g = np.repeat(gt, n_near, axis=0)
        ang = rng.uniform(0, 2 * np.pi, len(g))
        d = rng.uniform(0.6, 1.2, len(g))
        near = g.copy()
        near[:, 0] += np.cos(ang) * d * g[:, 2]
        near[:, 1] += np.sin(ang) * d * g[:, 3]
    blobs = np.asarray(blobs, dtype=np.float64).reshape(-1, 4)
    if len(blobs) and len(gt):
        person_blob = box_iou(blobs, gt).max(axis=1) >= blob_iou
        pos.append(blobs[person_blob])
        blobs = blobs[~person_blob]
    neg = np.concatenate([blobs, rand, near])
    people = gt if avoid is None else np.concatenate([gt, np.asarray(avoid).reshape(-1, 4)])
    if len(people) and len(neg):
        neg = neg[box_iou(neg, people).max(axis=1) < max_iou]
    pos = np.concatenate(pos)
    return (np.concatenate([pos, neg]),
            np.concatenate([np.ones(len(pos)), np.zeros(len(neg))]))


def _colour_jitter(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The frame under another light: a random gain (0.75–1.3) and offset (±20) per colour
    channel, so the DBN does not learn one camera's white balance."""
    gain = rng.uniform(0.75, 1.3, 3)
    off = rng.uniform(-20.0, 20.0, 3)
    return np.clip(image.astype(np.float32) * gain + off, 0, 255).astype(np.uint8)


def collect_samples(source, frames: Iterable[int], *, features: FeatureConfig = FeatureConfig(),
                    feature_scale: float = 0.5, background=None, seed: int = 0,
                    stride: int = 2, min_vis: float = 0.5, augment: bool = False,
                    stats: Optional[dict] = None,
                    progress: Optional[Callable[[str, int, int], None]] = None,
                    with_frames: bool = False):
    """Features ``X (N, D)`` and labels ``y (N,)`` from a source with ground truth, over
    ``frames`` (every ``stride``-th is sampled; the background model sees every frame up to
    the last one, starting from the temporal median of the range as the tracker does);
    ``with_frames`` adds the (N,) frame index of every sample.  People: gt
    boxes (visibility >= ``min_vis`` where known, conf != 0) and the background-subtraction
    blobs that cover one (:func:`sample_boxes`).  Not people: blobs that overlap no gt box,
    random and shifted windows.  ``augment``: every sampled frame's boxes are also described
    on the mirrored frame and on a colour-jittered copy (:func:`_colour_jitter`).  ``stats``
    (a dict) receives ``box_height``: the median height of the people as described (px at
    ``feature_scale``), which the tracker's default ``feature_height`` describes boxes at."""
    from .codebook import BackgroundParams, ForegroundModel, blobs_from_mask

    from ..data.sources import sample_frames, training_frames

    gt, first, last, chosen = training_frames(source, frames, stride, "train-dbn")
    bp = background or BackgroundParams()
    fm = ForegroundModel(bp)
    fm.prime(sample_frames(source, bp.median_frames, first, last)
             if bp.initial == "median" else [])
    rng = np.random.default_rng(seed)
    Xs, ys, fs, heights = [], [], [], []
    for frame in source.frames(last):
        mask = fm.mask(frame)
        if frame.index not in chosen:
            continue
        r = gt.rows_at(frame.index)
        ok = gt.score[r] != 0
        if np.any(gt.vis[r] >= 0):
            ok &= (gt.vis[r] < 0) | (gt.vis[r] >= min_vis)
        blobs, _ = blobs_from_mask(mask, bp.scale, bp.min_area, bp.max_foreground)
        boxes, labels = sample_boxes(frame.image.shape, gt.boxes[r][ok], blobs, rng,
                                     avoid=gt.boxes[r][~ok])
        Xs.append(FrameFeatures(frame.image, features, feature_scale).describe(boxes))
        heights.append(boxes[labels > 0, 3] * feature_scale)
        ys.append(labels)
        fs.append(np.full(len(labels), frame.index, dtype=np.int64))
        if augment:
            W = frame.image.shape[1]
            mirrored = boxes.copy()
            mirrored[:, 0] = W - boxes[:, 0] - boxes[:, 2]
            Xs.append(FrameFeatures(np.ascontiguousarray(frame.image[:, ::-1]), features,
                                    feature_scale).describe(mirrored))
            Xs.append(FrameFeatures(_colour_jitter(frame.image, rng), features,
                                    feature_scale).describe(boxes))
            ys += [labels, labels]
            fs += [fs[-1], fs[-1]]
        if progress:
            progress("features", frame.index - first + 1, last - first + 1)
    X = np.concatenate(Xs) if Xs else np.zeros((0, features.dim))
    y = np.concatenate(ys) if ys else np.zeros(0)
    if stats is not None and heights:
        h = np.concatenate(heights)
        if len(h):       # the people's median height as described (px at feature_scale)
            stats["box_height"] = float(np.median(h))
    if with_frames:
        return X, y, (np.concatenate(fs) if fs else np.zeros(0, dtype=np.int64))
    return X, y


#: The model DBN-PHD uses when none is given, shipped in the package (package data): trained on
#: person and non-person crops of the development sequences PETS09-S2L1 and PETS09-S3MF1 by the
#: command in :data:`SHIPPED_COMMAND` (same seed → same file; its info records the people's
#: described height, ``box_height`` 41.8 px, which the tracker describes boxes at).
SHIPPED_COMMAND = ("pfscope train-dbn ../shared/data/PETS09-S2L1 ../shared/data/PETS09-S3MF1 "
                   "--holdout 0 --augment --stride 3 --batch 256 --seed 0 "
                   "--out trackers/dbn/people_dbn.pt")


@lru_cache(maxsize=1)
def default_model() -> DBNModel:
    """The shipped model (:data:`SHIPPED`), loaded once per process with ``weights_only=True``;
    nothing is trained at start-up."""
    if not SHIPPED.is_file():
        raise InputError(f"{SHIPPED}: the shipped DBN model is missing (a broken install?); "
                         f"give one with --set model=FILE (`pfscope train-dbn`)")
    return load_model(SHIPPED)


__all__ = ["RBM", "DBN", "DBNModel", "load_model", "train_dbn", "pretrain_rbm", "roc_auc",
           "collect_samples", "sample_boxes", "rotate_hue", "default_model", "SHIPPED",
           "SHIPPED_COMMAND", "FORMAT", "VERSION"]
