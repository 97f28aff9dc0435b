"""Element-wise exp / log / log1p of the C library (``math``), for the references of the
bit-for-bit kernel tests.

The numba kernels call libm (``math.exp`` compiles to the C library's ``exp``). numpy's
``np.exp`` / ``np.log`` do too on most CPUs, but on CPUs with AVX-512 (e.g. AMD Zen 4,
Intel Ice Lake) numpy dispatches them to its own vectorised code, which can differ from libm
in the last bit. A reference written with numpy's ufuncs then differs from the kernel by one
ulp on those machines only; written with these it is the kernel's floats on every CPU."""

from __future__ import annotations

import math

import numpy as np


def _elementwise(fn):
    def f(x):
        a = np.asarray(x, dtype=np.float64)
        out = np.empty(a.shape)
        flat = out.reshape(-1)
        for i, v in enumerate(a.reshape(-1)):
            try:
                flat[i] = fn(v)
            except ValueError:            # log of a negative: numpy's NaN
                flat[i] = np.nan
            except OverflowError:         # exp overflow: numpy's inf
                flat[i] = np.inf
        return out if a.ndim else float(out)
    return f


def _log(v):
    return -math.inf if v == 0.0 else math.log(v)


def _log1p(v):
    return -math.inf if v == -1.0 else math.log1p(v)


exp = _elementwise(math.exp)
log = _elementwise(_log)
log1p = _elementwise(_log1p)
