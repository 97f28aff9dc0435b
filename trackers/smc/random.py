"""Random variates drawn inside numba kernels, keyed by the caller's ``numpy.random.Generator``.

The particle filters draw tens of thousands of normals a frame.  Drawn by numpy they need an
(N, k) temporary per stage and a pass to read it back; drawn inside the kernel that uses them
they cost a few nanoseconds each and no memory.  Numba's own ``np.random`` inside ``njit`` is
one global state per thread (two trackers in one process would share it), so the kernels use
an explicit stream instead:

- **key**: one 64-bit word taken from the caller's Generator per kernel call
  (:func:`key_from`, ``bit_generator.random_raw()``).  Same seed and same calls → same keys, so
  a run stays deterministic, and two trackers with their own Generators never share a stream.
- **stream**: SplitMix64 (Steele, Lea & Flood 2014; Java's ``SplittableRandom``), a counter
  ``s += γ`` passed through a 64-bit finaliser: output ``k`` of the stream keyed ``s₀`` is
  ``mix(s₀ + k γ)``.  It passes BigCrush; streams of different random keys overlap with
  probability about (draws per call) / 2⁶⁴.
- **normals**: the 256-layer ziggurat of Marsaglia & Tsang (2000), in numpy's variant (one
  64-bit word: 8 bits of layer, 1 bit of sign, 52 bits of abscissa; numpy's
  ``random_standard_normal``), tables computed here at import.
- **uniforms**: the top 53 bits of a word, in [0, 1).

A kernel gets the state as a one-element ``uint64`` array (:func:`stream`), loads it once and
passes it by value (``s, x = normal(s)``): kept in a register, a normal costs about a quarter of
numpy's ``standard_normal`` (the array load and store per draw cost 3×).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_U30, _U27, _U31, _U12, _U11, _U8, _U1 = (np.uint64(k) for k in (30, 27, 31, 12, 11, 8, 1))
_MASK8 = np.uint64(0xFF)
_MASK52 = np.uint64(0x000FFFFFFFFFFFFF)
_TO_UNIT = 1.0 / 9007199254740992.0           # 2⁻⁵³

#: ziggurat: right edge of the base layer, and the common area of the 256 layers
_ZIG_R = 3.6541528853610088
_ZIG_INV_R = 1.0 / _ZIG_R
_ZIG_V = 4.92867323399e-3


def _ziggurat_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``ki`` (acceptance thresholds on the 52-bit abscissa), ``wi`` (abscissa scale) and
    ``fi`` (density at the layer edges) of the 256-layer ziggurat (Marsaglia & Tsang 2000,
    ``zigset`` with 2⁵² in place of 2³¹; the tables numpy's ``standard_normal`` uses)."""
    m = 2.0 ** 52
    dn = tn = _ZIG_R
    q = _ZIG_V / math.exp(-0.5 * dn * dn)
    ki = np.zeros(256, np.uint64)
    wi = np.zeros(256)
    fi = np.zeros(256)
    ki[0] = int(dn / q * m)
    wi[0], wi[255] = q / m, dn / m
    fi[0], fi[255] = 1.0, math.exp(-0.5 * dn * dn)
    for i in range(254, 0, -1):
        dn = math.sqrt(-2.0 * math.log(_ZIG_V / dn + math.exp(-0.5 * dn * dn)))
        ki[i + 1] = int(dn / tn * m)
        tn = dn
        fi[i] = math.exp(-0.5 * dn * dn)
        wi[i] = dn / m
    return ki, wi, fi


_KI, _WI, _FI = _ziggurat_tables()


def key_from(rng: np.random.Generator) -> int:
    """One 64-bit stream key from ``rng`` (advances it by one word)."""
    return int(rng.bit_generator.random_raw())


def stream(key: int) -> np.ndarray:
    """The state of the stream keyed ``key``: a one-element uint64 array the kernels advance."""
    return np.array([key], dtype=np.uint64)


_KI_I64 = _KI.astype(np.int64)      # the thresholds, compared as signed 64-bit (cheaper)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True, inline="always")
def _mix(z):
    """The SplitMix64 finaliser (Stafford's variant 13)."""
    z = (z ^ (z >> _U30)) * _M1
    z = (z ^ (z >> _U27)) * _M2
    return z ^ (z >> _U31)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def uniform(s):
    """``(s', u)``: the stream's state after one word, and a uniform on [0, 1) (53 bits).
    The state is passed by value (a register in the caller's loop, not an array store)."""
    s = s + _GAMMA
    return s, float(np.int64(_mix(s) >> _U11)) * _TO_UNIT


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _normal_slow(s, idx, x):
    """The ziggurat's rejected draws: the tail beyond R (Marsaglia 1964) for the base layer,
    the wedge test otherwise, then fresh draws until one is accepted.  ``(s', |x|)``."""
    while True:
        if idx == 0:
            while True:
                s, u = uniform(s)
                xx = -_ZIG_INV_R * math.log1p(-u)
                s, u = uniform(s)
                yy = -math.log1p(-u)
                if yy + yy > xx * xx:
                    return s, _ZIG_R + xx
        else:
            s, u = uniform(s)
            if (_FI[idx - 1] - _FI[idx]) * u + _FI[idx] < math.exp(-0.5 * x * x):
                return s, x
        s = s + _GAMMA
        r = _mix(s)
        idx = int(r & _MASK8)
        rabs = np.int64(r >> _U12)
        x = float(rabs) * _WI[idx]
        if rabs < _KI_I64[idx]:
            return s, x


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def normal(s):
    """``(s', x)``: the stream's next state and a standard normal (ziggurat: ~99 % of the
    draws take one word, a table look-up and no transcendental).  Word layout: bits 0–7 the
    layer, bit 8 the sign, bits 12–63 the abscissa."""
    s = s + _GAMMA
    r = _mix(s)
    idx = int(r & _MASK8)
    rabs = np.int64(r >> _U12)
    sign = 1.0 - 2.0 * float(np.int64((r >> _U8) & _U1))
    x = float(rabs) * _WI[idx]
    if rabs < _KI_I64[idx]:
        return s, sign * x
    s, x = _normal_slow(s, idx, x)
    return s, sign * x


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def fill_normal(st, out):
    """``out`` (N,) filled with standard normals from the stream ``st`` (tests, tools)."""
    s = st[0]
    for i in range(out.shape[0]):
        s, out[i] = normal(s)
    st[0] = s
