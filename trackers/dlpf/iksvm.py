"""The paper's classifier: an intersection-kernel SVM on HOG (jung2013 §2.1, after Maji, Berg &
Malik 2008, "Classification using intersection kernel support vector machines is efficient").

Kernel ``K(x, z) = Σ_d min(x_d, z_d)``.  The decision function of an SVM with support vectors
``x_l`` and signed coefficients ``c_l = α_l y_l`` is **additive** over dimensions::

    h(x) = Σ_l c_l K(x, x_l) + b = Σ_d h_d(x_d) + b,   h_d(s) = Σ_l c_l min(s, x_ld)

and each ``h_d`` is piecewise linear in ``s`` (kinks at the support vectors' values, constant
beyond the largest).  Maji et al.'s fast evaluation replaces ``h_d`` by a lookup table of
``bins`` samples on ``[0, max_l x_ld]`` with linear interpolation: the cost per window is
O(D) — two table reads per dimension — instead of O(D · #SV) for the exact kernel sum.
:meth:`IKSVMTables.exact` keeps the exact sum for checking (``tests/test_dlpf.py``).

Training (:func:`train_iksvm`) uses OpenCV's libsvm port (``cv2.ml.SVM`` with the ``INTER``
kernel: the exact kernel SVM); :func:`collect_samples` takes positives from ground-truth boxes
(their 64×128 HOG windows, context border included) and negatives from random background
windows, windows shifted/rescaled off a person, and (optionally) hard negatives: background
windows the first model scores positive, then the model is retrained.

Model file (``.npz``, :meth:`IKSVMClassifier.save`): ``kind = "dlpf-iksvm"``, ``descriptor``
(the HOG layout it was trained for), ``tables`` (D, bins), ``hi`` (D,), ``bias``, ``info``
(JSON: frames trained on, sample counts, held-out accuracy/AUC).  A missing, unreadable or
mismatched file is a one-line :class:`~pfscope.trackers.errors.InputError`.
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from typing import Callable, Iterable, Optional

import cv2
import numpy as np

from ..errors import InputError
from .classifier import HOGWindowClassifier, window_boxes

KIND = "dlpf-iksvm"
DESCRIPTOR = "opencv-hog-64x128-9bins-l2hys-3780"


@dataclass
class IKSVMTables:
    """Per-dimension lookup tables of ``h_d`` (module docstring)."""

    tables: np.ndarray            # (D, bins) float32: h_d at s = j * hi_d / (bins - 1)
    hi: np.ndarray                # (D,) float32: largest support-vector value per dimension
    bias: float
    sv: Optional[np.ndarray] = None     # (L, D) support vectors (kept after training only)
    coef: Optional[np.ndarray] = None   # (L,) c_l = alpha_l y_l
    _scale: Optional[np.ndarray] = field(default=None, repr=False, compare=False)
    _rows: Optional[np.ndarray] = field(default=None, repr=False, compare=False)
    _slope: Optional[np.ndarray] = field(default=None, repr=False, compare=False)

    @classmethod
    def from_support_vectors(cls, sv: np.ndarray, coef: np.ndarray, bias: float,
                             bins: int = 64) -> IKSVMTables:
        sv = np.asarray(sv, dtype=np.float32)
        coef = np.asarray(coef, dtype=np.float64).reshape(-1)
        if bins < 2 or sv.ndim != 2 or len(sv) != len(coef):
            raise ValueError("iksvm: need bins >= 2 and one coefficient per support vector")
        hi = np.maximum(sv.max(axis=0), 1e-6).astype(np.float32)
        grid = np.linspace(0.0, 1.0, bins)
        tables = np.empty((sv.shape[1], bins), dtype=np.float64)
        for j, g in enumerate(grid):  # bins passes over (L, D): h_d(s_j) = Σ_l c_l min(s_j, x_ld)
            tables[:, j] = coef @ np.minimum(sv, (g * hi)[None, :])
        return cls(tables.astype(np.float32), hi, float(bias), sv, coef)

    @property
    def dim(self) -> int:
        return self.tables.shape[0]

    def decision(self, X: np.ndarray) -> np.ndarray:
        """Fast decision values (N,) by table lookup and linear interpolation."""
        X = np.asarray(X, dtype=np.float32).reshape(-1, self.dim)
        if len(X) == 0:
            return np.zeros(0)
        bins = self.tables.shape[1]
        if self._scale is None:  # cached: bins per unit, row offsets, slopes
            self._scale = ((bins - 1) / self.hi).astype(np.float32)
            self._rows = np.arange(self.dim, dtype=np.intp) * bins
            self._slope = np.diff(self.tables, axis=1, append=self.tables[:, -1:]).reshape(-1)
        t = X * self._scale
        np.clip(t, 0.0, bins - 1.0, out=t)
        i = np.minimum(t.astype(np.intp), bins - 2)
        t -= i                              # fraction within the bin
        i += self._rows                     # flat index into the (D, bins) tables
        v = np.take(self.tables.reshape(-1), i)
        v += t * np.take(self._slope, i)
        return v.sum(axis=1, dtype=np.float64) + self.bias

    def exact(self, X: np.ndarray, chunk: int = 64) -> np.ndarray:
        """The exact kernel sum ``Σ_l c_l Σ_d min(x_d, x_ld) + b`` (needs the support vectors)."""
        if self.sv is None or self.coef is None:
            raise ValueError("iksvm: exact decision needs the support vectors (training only)")
        X = np.asarray(X, dtype=np.float32).reshape(-1, self.dim)
        out = np.empty(len(X))
        for a in range(0, len(X), chunk):
            K = np.minimum(X[a:a + chunk, None, :], self.sv[None, :, :]).sum(-1, dtype=np.float64)
            out[a:a + chunk] = K @ self.coef + self.bias
        return out


class IKSVMClassifier(HOGWindowClassifier):
    """:class:`~.classifier.HOGWindowClassifier` (same windows, descriptors, modes) scoring with
    the intersection-kernel SVM's lookup tables instead of a linear SVM."""

    def __init__(self, tables: IKSVMTables, info: Optional[dict] = None, *,
                 mode: str = "pyramid", scale_step: float = 1.1, path: str = ""):
        super().__init__(mode=mode, scale_step=scale_step)
        if tables.dim != self.hog.getDescriptorSize():
            raise ValueError(f"iksvm: tables for {tables.dim} dimensions, HOG descriptor has "
                             f"{self.hog.getDescriptorSize()}")
        self.iksvm = tables
        self.info = dict(info or {})
        self.path = path

    def decision(self, d: np.ndarray) -> np.ndarray:
        return self.iksvm.decision(d)

    def describe(self) -> str:
        return f"iksvm:{self.path or '(in memory)'}"

    def save(self, path: str) -> None:
        np.savez_compressed(path, kind=np.array(KIND), descriptor=np.array(DESCRIPTOR),
                            tables=self.iksvm.tables, hi=self.iksvm.hi,
                            bias=np.array(self.iksvm.bias),
                            info=np.array(json.dumps(self.info)))

    @classmethod
    def load(cls, path: str, *, mode: str = "pyramid", scale_step: float = 1.1
             ) -> IKSVMClassifier:
        """Read a model file; any problem → one-line :class:`InputError` naming the file."""
        p = os.fspath(path)
        if os.path.isfile(p) and not zipfile.is_zipfile(p):
            raise InputError(f"classifier {p}: not a .npz model file (make one with "
                             "'pfscope train-classifier')")
        try:
            with np.load(p, allow_pickle=False) as z:
                keys = set(z.files)
                need = {"kind", "descriptor", "tables", "hi", "bias"}
                if not need <= keys:
                    raise InputError(f"classifier {p}: not a DLPF classifier file (missing "
                                     f"{', '.join(sorted(need - keys))}; make one with "
                                     "'pfscope train-classifier')")
                kind, desc = str(z["kind"]), str(z["descriptor"])
                tables, hi = np.asarray(z["tables"], np.float32), np.asarray(z["hi"], np.float32)
                bias = float(z["bias"])
                info = json.loads(str(z["info"])) if "info" in keys else {}
        except InputError:
            raise
        except FileNotFoundError:
            raise InputError(f"classifier {p}: no such file") from None
        except (OSError, ValueError, KeyError, json.JSONDecodeError) as e:
            msg = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise InputError(f"classifier {p}: unreadable ({msg})") from None
        if kind != KIND:
            raise InputError(f"classifier {p}: kind {kind!r}, expected {KIND!r}")
        if desc != DESCRIPTOR:
            raise InputError(f"classifier {p}: trained on descriptor {desc!r}, DLPF computes "
                             f"{DESCRIPTOR!r}")
        D = cv2.HOGDescriptor().getDescriptorSize()
        if tables.ndim != 2 or tables.shape[0] != D or tables.shape[1] < 2 or hi.shape != (D,):
            raise InputError(f"classifier {p}: tables of shape {tables.shape} and hi of shape "
                             f"{hi.shape}, expected ({D}, bins >= 2) and ({D},)")
        if not (np.isfinite(tables).all() and np.isfinite(hi).all() and (hi > 0).all()
                and np.isfinite(bias)):
            raise InputError(f"classifier {p}: non-finite or non-positive values in the tables")
        return cls(IKSVMTables(tables, hi, bias), info, mode=mode, scale_step=scale_step,
                   path=p)


# ---------------------------------------------------------------------- training

def train_iksvm(X: np.ndarray, y: np.ndarray, *, C: float = 1.0, bins: int = 64,
                max_iter: int = 20000) -> IKSVMTables:
    """Exact intersection-kernel SVM (``cv2.ml.SVM``, kernel INTER) on descriptors ``X`` (N, D),
    labels ``y`` (N,) in {0, 1}; returns its lookup tables (and support vectors)."""
    X = np.ascontiguousarray(X, dtype=np.float32)
    y = np.asarray(y).astype(np.int32).reshape(-1)
    if len(np.unique(y)) != 2:
        raise InputError("train-classifier: need both people and background samples")
    svm = cv2.ml.SVM_create()
    svm.setType(cv2.ml.SVM_C_SVC)
    svm.setKernel(cv2.ml.SVM_INTER)
    svm.setC(float(C))
    svm.setTermCriteria((cv2.TERM_CRITERIA_MAX_ITER | cv2.TERM_CRITERIA_EPS, max_iter, 1e-4))
    svm.train(X, cv2.ml.ROW_SAMPLE, np.where(y > 0, 1, -1).astype(np.int32))
    sv = svm.getSupportVectors()
    rho, alpha, svidx = svm.getDecisionFunction(0)
    coef = np.zeros(len(sv))
    coef[np.asarray(svidx).reshape(-1)] = np.asarray(alpha).reshape(-1)
    # OpenCV's raw output is Σ alpha K - rho with a sign that depends on its label order:
    # orient the function so that people score positive
    t = IKSVMTables(np.zeros((X.shape[1], 2), np.float32), np.ones(X.shape[1], np.float32),
                    -float(rho), sv, coef)
    probe = t.exact(X[: min(len(X), 400)])
    yy = y[: len(probe)]
    if probe[yy > 0].mean() < probe[yy <= 0].mean():
        coef, rho = -coef, -rho
    return IKSVMTables.from_support_vectors(sv, coef, -float(rho), bins)


def _iou_max(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    if len(b) == 0:
        return np.zeros(len(a))
    x0 = np.maximum(a[:, None, 0], b[None, :, 0])
    y0 = np.maximum(a[:, None, 1], b[None, :, 1])
    x1 = np.minimum(a[:, None, 0] + a[:, None, 2], b[None, :, 0] + b[None, :, 2])
    y1 = np.minimum(a[:, None, 1] + a[:, None, 3], b[None, :, 1] + b[None, :, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    union = (a[:, None, 2] * a[:, None, 3] + b[None, :, 2] * b[None, :, 3] - inter)
    return (inter / np.maximum(union, 1e-9)).max(axis=1)


@dataclass
class Samples:
    X: np.ndarray
    y: np.ndarray
    frame: np.ndarray
    kinds: dict = field(default_factory=dict)


def collect_samples(source, frames: Iterable[int], *, stride: int = 4, negatives: int = 12,
                    seed: int = 0, min_vis: float = 0.5, min_height: float = 24.0,
                    progress: Optional[Callable[[str, int, int], None]] = None) -> Samples:
    """HOG descriptors of ground-truth people (positives) and background windows (negatives)
    on every ``stride``-th frame of ``frames``.  Negatives per frame: ``negatives`` random
    windows (person heights drawn log-uniformly in the range of the frame's gt heights ×[0.7,
    1.4]) overlapping no person (IoU < 0.2 with every gt box, in person-box terms), and one
    window per person shifted by ≥ 0.6 of its width or rescaled ×2 / ×0.5 (near misses)."""
    from ..data.sources import training_frames

    gt, first, last, chosen = training_frames(source, frames, stride, "train-classifier")
    clf = HOGWindowClassifier(mode="window")
    rng = np.random.default_rng(seed)
    from .classifier import person_boxes

    Xs, ys, fs = [], [], []
    kinds = {"people": 0, "random": 0, "near": 0}
    for frame in _frames(source, last):
        if frame.index not in chosen:
            continue
        img = frame.image
        grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        H, W = grey.shape
        r = gt.rows_at(frame.index)
        ok = gt.score[r] != 0
        if np.any(gt.vis[r] >= 0):
            ok &= (gt.vis[r] < 0) | (gt.vis[r] >= min_vis)
        allp = gt.boxes[r]
        people = allp[ok]
        people = people[(people[:, 3] >= min_height)
                        & (people[:, 0] + people[:, 2] / 2 > 0) & (people[:, 0] + people[:, 2] / 2 < W)
                        & (people[:, 1] + people[:, 3] / 2 > 0) & (people[:, 1] + people[:, 3] / 2 < H)]
        wins = [window_boxes(people[:, :2] + people[:, 2:] / 2, people[:, 3])]
        labels = [np.ones(len(people))]
        kinds["people"] += len(people)
        hs = allp[:, 3] if len(allp) else np.array([H * 0.15])
        lo, hi = max(min_height, 0.7 * hs.min()), max(min_height + 1, 1.4 * hs.max())
        cand_h = np.exp(rng.uniform(np.log(lo), np.log(hi), 4 * negatives))
        cand_c = rng.uniform([0, 0], [W, H], (4 * negatives, 2))
        cand = window_boxes(cand_c, cand_h)
        far = _iou_max(person_boxes(cand), allp) < 0.2
        neg = cand[far][:negatives]
        if len(people):
            c = people[:, :2] + people[:, 2:] / 2
            k = rng.integers(0, 4, len(people))
            side = rng.choice([-1.0, 1.0], len(people))
            h = people[:, 3].copy()
            c[k == 0, 0] += side[k == 0] * rng.uniform(0.6, 1.2, (k == 0).sum()) * people[k == 0, 2]
            c[k == 1, 1] += side[k == 1] * rng.uniform(0.4, 0.7, (k == 1).sum()) * people[k == 1, 3]
            h[k == 2] *= 2.0
            h[k == 3] *= 0.5
            near = window_boxes(c, h)
            near = near[_iou_max(person_boxes(near), allp) < 0.3]
            kinds["near"] += len(near)
            neg = np.r_[neg, near]
        kinds["random"] += int(far[:negatives].sum()) if len(far) else 0
        wins.append(neg)
        labels.append(np.zeros(len(neg)))
        w = np.concatenate(wins)
        Xs.append(clf.descriptors(grey, w))
        ys.append(np.concatenate(labels))
        fs.append(np.full(len(w), frame.index, dtype=np.int64))
        if progress:
            progress("features", frame.index - first + 1, last - first + 1)
    if not Xs:
        raise InputError("train-classifier: none of the chosen frames could be read")
    return Samples(np.concatenate(Xs), np.concatenate(ys), np.concatenate(fs), kinds)


def hard_negatives(source, frames: Iterable[int], tables: IKSVMTables, *, stride: int = 4,
                   windows: int = 60, limit: int = 2000, seed: int = 1,
                   progress: Optional[Callable[[str, int, int], None]] = None) -> Samples:
    """Background windows (IoU < 0.2 with every gt person) that ``tables`` scores above 0 on
    every ``stride``-th frame of ``frames`` (offset by ``stride // 2`` from the positives')."""
    gt = source.gt
    wanted = sorted(set(int(f) for f in frames))
    first, last = wanted[0], wanted[-1]
    chosen = set(f for f in wanted if (f - first - stride // 2) % max(1, stride) == 0)
    clf = HOGWindowClassifier(mode="window")
    rng = np.random.default_rng(seed)
    from .classifier import person_boxes

    Xs, fs = [], []
    n = 0
    for frame in _frames(source, last):
        if frame.index not in chosen or n >= limit:
            continue
        img = frame.image
        grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        H, W = grey.shape
        allp = gt.boxes[gt.rows_at(frame.index)]
        hs = allp[:, 3] if len(allp) else np.array([H * 0.15])
        lo, hi = max(24.0, 0.7 * hs.min()), max(25.0, 1.4 * hs.max())
        cand = window_boxes(rng.uniform([0, 0], [W, H], (windows, 2)),
                            np.exp(rng.uniform(np.log(lo), np.log(hi), windows)))
        cand = cand[_iou_max(person_boxes(cand), allp) < 0.2]
        d = clf.descriptors(grey, cand)
        bad = tables.decision(d) > 0
        Xs.append(d[bad])
        fs.append(np.full(int(bad.sum()), frame.index, dtype=np.int64))
        n += int(bad.sum())
        if progress:
            progress("hard negatives", frame.index - first + 1, last - first + 1)
    X = np.concatenate(Xs)[:limit] if Xs else np.zeros((0, tables.dim), np.float32)
    f = np.concatenate(fs)[:limit] if fs else np.zeros(0, np.int64)
    return Samples(X, np.zeros(len(X)), f, {"hard": len(X)})


def _frames(source, last: int):
    try:
        yield from source.frames(last)
    except TypeError:  # sources whose frames() takes no limit
        for fr in source.frames():
            if fr.index > last:
                break
            yield fr


__all__ = ["IKSVMTables", "IKSVMClassifier", "train_iksvm", "collect_samples",
           "hard_negatives", "Samples", "KIND", "DESCRIPTOR"]
