"""A saved DBN read without torch: what DBN-PHD needs to run (the forward pass in numpy).

``import torch`` costs a DBN-PHD run ~2.6 s of CPU (a tenth of a whole PETS09-S2L1 run) only
to read a few small float arrays back from the model file.  :func:`read_state` reads a file
written by ``torch.save`` of a plain state (the zip layout: ``data.pkl`` and one raw
little-endian buffer per tensor) with a restricted unpickler that knows the tensor rebuild
function and the storage types and nothing else, so a model file cannot run code (the same
guarantee as ``torch.load(weights_only=True)``).  :func:`load_weights` checks the format tag,
version and layout and returns :class:`DBNWeights`; :mod:`.model` (training, torch) checks
files it loads with the same :func:`check_state`.
"""

from __future__ import annotations

import io
import pickle
import zipfile
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.special import expit

from ..errors import InputError
from .features import FeatureConfig

FORMAT = "pfscope-dbn"
VERSION = 1
#: the model shipped with the package (``pfscope train-dbn``'s SHIPPED_COMMAND rebuilds it)
SHIPPED = Path(__file__).with_name("people_dbn.pt")

_STORAGES = {"DoubleStorage": np.float64, "FloatStorage": np.float32,
             "HalfStorage": np.float16, "LongStorage": np.int64, "IntStorage": np.int32,
             "ShortStorage": np.int16, "CharStorage": np.int8, "ByteStorage": np.uint8,
             "BoolStorage": np.bool_}


class _Storage:
    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)


def _rebuild_tensor(storage, offset, size, stride, *_):
    """torch._utils._rebuild_tensor_v2 as a numpy copy (sizes and strides in elements)."""
    item = storage.itemsize
    return np.lib.stride_tricks.as_strided(storage[offset:], tuple(size),
                                           tuple(s * item for s in stride)).copy()


class _Unpickler(pickle.Unpickler):
    def __init__(self, data: bytes, archive: zipfile.ZipFile, prefix: str):
        super().__init__(io.BytesIO(data))
        self.archive, self.prefix = archive, prefix

    def find_class(self, module, name):
        if module == "torch._utils" and name == "_rebuild_tensor_v2":
            return _rebuild_tensor
        if module == "torch" and name in _STORAGES:
            return _Storage(_STORAGES[name])
        if module == "collections" and name == "OrderedDict":
            return dict
        raise pickle.UnpicklingError(f"unexpected object {module}.{name}")

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) >= 5 and pid[0] == "storage"
                and isinstance(pid[1], _Storage)):
            raise pickle.UnpicklingError(f"unexpected persistent id {pid!r:.60}")
        dtype, key, numel = pid[1].dtype, str(pid[2]), int(pid[4])
        raw = self.archive.read(f"{self.prefix}data/{key}")
        return np.frombuffer(raw, dtype=dtype.newbyteorder("<"), count=numel).astype(dtype)


def read_state(path) -> dict:
    """The dict a ``torch.save(state)`` wrote to ``path``, tensors as numpy arrays; any
    problem → one-line InputError (the wording of :func:`.model.load_model`'s)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such DBN model file")
    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
            pkl = next(n for n in names if n.endswith("data.pkl"))
            prefix = pkl[:-len("data.pkl")]
            order = f"{prefix}byteorder"
            if order in names and z.read(order).decode().strip() != "little":
                raise ValueError("big-endian tensors")
            return _Unpickler(z.read(pkl), z, prefix).load()
    except Exception as e:  # noqa: BLE001 - any unreadable file is the user's input
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"{path}: not a pfscope DBN model ({msg[:120]})") from None


def check_state(path, st) -> tuple[FeatureConfig, tuple[int, ...], dict]:
    """A loaded state's feature layout, hidden sizes and training record, after checking its
    format tag and version (one-line InputError otherwise)."""
    if not isinstance(st, dict) or st.get("format") != FORMAT:
        raise InputError(f"{path}: not a pfscope DBN model (no '{FORMAT}' format tag)")
    if st.get("version") != VERSION:
        raise InputError(f"{path}: DBN model version {st.get('version')!r}, this pfscope reads "
                         f"version {VERSION}; retrain it with `pfscope train-dbn`")
    try:
        return (FeatureConfig(**st["features"]), tuple(int(h) for h in st["hidden"]),
                dict(st.get("info") or {}))
    except Exception as e:  # noqa: BLE001
        raise InputError(f"{path}: DBN model does not match its layout "
                         f"({type(e).__name__}: {str(e).splitlines()[0][:120]})") from None


def forward(layers: tuple, X: np.ndarray) -> np.ndarray:
    """Output activations of feature rows ``X`` through ``layers`` = ([(W, b_h), ...] of the
    RBMs, output weights, output bias): σ(h W + b_h) per RBM, then the linear output."""
    rbms, w_out, b_out = layers
    h = X
    for W, b in rbms:
        h = expit(h @ W + b)
    return h @ w_out + b_out


def check_rows(X, dim: int) -> np.ndarray:
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != dim:
        raise ValueError(f"DBN: expected features (N, {dim}), got {X.shape}")
    return X


@dataclass
class DBNWeights:
    """A trained DBN's weights as numpy arrays with its feature layout and training record:
    the part of :class:`.model.DBNModel` the tracker uses (``logits``, ``features``,
    ``hidden``, ``info``), without torch."""

    features: FeatureConfig
    hidden: tuple[int, ...]
    info: dict = field(default_factory=dict)
    layers: tuple = field(default=(), repr=False, compare=False)

    def logits(self, X: np.ndarray) -> np.ndarray:
        X = check_rows(X, self.features.dim)
        return forward(self.layers, X) if len(X) else np.zeros(0)


def load_weights(path) -> DBNWeights:
    """Load a model file saved by :meth:`.model.DBNModel.save`, without torch."""
    st = read_state(path)
    cfg, hidden, info = check_state(path, st)
    try:
        w = st["weights"]
        rbms, prev = [], cfg.dim
        for i, h in enumerate(hidden):
            W, b = np.asarray(w[f"rbms.{i}.W"]), np.asarray(w[f"rbms.{i}.b_h"])
            if W.shape != (prev, h) or b.shape != (h,):
                raise ValueError(f"rbms.{i} has shape {W.shape}, expected {(prev, h)}")
            rbms.append((W, b))
            prev = h
        w_out, b_out = np.asarray(w["out.weight"]), np.asarray(w["out.bias"])
        if w_out.shape != (1, prev) or b_out.shape != (1,):
            raise ValueError(f"out.weight has shape {w_out.shape}, expected {(1, prev)}")
    except Exception as e:  # noqa: BLE001
        raise InputError(f"{path}: DBN model does not match its layout "
                         f"({type(e).__name__}: {str(e).splitlines()[0][:120]})") from None
    return DBNWeights(cfg, hidden, info, (rbms, w_out[0].copy(), float(b_out[0])))


@lru_cache(maxsize=1)
def default_weights() -> DBNWeights:
    """The shipped model's weights, read once per process."""
    return load_weights(shipped())


def shipped() -> Path:
    """:data:`SHIPPED`, or a one-line InputError when the install lost it."""
    if not SHIPPED.is_file():
        raise InputError(f"{SHIPPED}: the shipped DBN model is missing (a broken install?); "
                         f"give one with --set model=FILE (`pfscope train-dbn`)")
    return SHIPPED


__all__ = ["FORMAT", "VERSION", "SHIPPED", "DBNWeights", "load_weights", "default_weights",
           "read_state", "check_state", "forward"]
