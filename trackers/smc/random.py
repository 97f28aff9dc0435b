"""Random variates drawn inside numba kernels, keyed by the caller's ``numpy.random.Generator``.

The particle filters draw tens of thousands of normals a frame.  Drawn by numpy they need an
(N, k) temporary per stage and a pass to read it back; drawn inside the kernel that uses them
they cost a few nanoseconds each and no memory.  Numba's own ``np.random`` inside ``njit`` is
one global state per thread (two trackers in one process would share it), so the kernels use
an explicit, counter-based generator instead:

- **key**: one 64-bit word taken from the caller's Generator per kernel call
  (:func:`key_from`, ``bit_generator.random_raw()``).  Same seed and same calls → same keys, so
  a run stays deterministic, and two trackers with their own Generators never share draws.
- **words**: SplitMix64 (Steele, Lea & Flood 2014; Java's ``SplittableRandom``) used as a
  counter-based generator: word ``i`` of key ``K`` is ``mix(K + (i + 1) γ)`` (γ the golden
  gamma, ``mix`` its 64-bit finaliser).  It passes BigCrush; the words of different random keys
  overlap with probability about (draws per call) / 2⁶⁴.  A kernel that needs a second,
  independent family of words uses the key :func:`subkey` ``(K, j)``.
- **normals**: Box–Muller (1958) on two words: pair ``p`` of key ``K`` is
  ``r (cos θ, sin θ)`` with ``r = sqrt(−2 log u)``, ``u = (1 + the top 53 bits of word 2p)
  2⁻⁵³`` uniform on (0, 1], and ``θ`` uniform on [0, 2π) from word ``2p + 1`` (2 bits of
  quadrant, 52 bits of angle in the quadrant, :func:`direction`).  Normal ``i`` of key ``K`` is
  component ``i mod 2`` of pair ``⌊i / 2⌋``: a pure function of ``(K, i)``, with no rejection,
  so a kernel makes a few hundred of them in one vectorised loop (SIMD, no branch, no table
  look-up) and then uses them.  ``log``, ``cos`` and ``sin`` are inline polynomial copies of
  fdlibm's (Sun's freely distributable libm, the C library's until glibc 2.28):
  ``__ieee754_log`` without its special cases (the argument is in [2⁻⁵³, 1]) and the
  ``__kernel_sin`` / ``__kernel_cos`` on [−π/4, π/4]; within one unit in the last place of
  the C library's (tested), so the normals are exact up to the 53-bit grid of ``u`` (none
  beyond 8.57 σ, probability 10⁻¹⁷).

(Before this generator the kernels drew from a SplitMix64 stream through a 256-layer ziggurat:
its rejections consumed extra words, so each normal depended on every earlier one and the loop
ran serially at ~1.6 ns a normal; the seeds' draws changed with it once.)
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_GAMMA2 = np.uint64(0x3C6EF372FE94F82A)       # 2 γ mod 2⁶⁴
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_SUB = np.uint64(0xD1B54A32D192ED03)          # subkey j: mix(K ^ (j + 1) · this)
_U1, _U2, _U3 = np.uint64(1), np.uint64(2), np.uint64(3)
_U11, _U12, _U27, _U30, _U31, _U52 = (np.uint64(k) for k in (11, 12, 27, 30, 31, 52))
_MASK52 = np.uint64(0x000FFFFFFFFFFFFF)
_ONE_BITS = np.uint64(0x3FF0000000000000)
_TO_UNIT = 1.0 / 9007199254740992.0           # 2⁻⁵³
_TO_ANGLE = (0.5 * math.pi) / 4503599627370496.0   # (π/2) 2⁻⁵²
_HALF_2_52 = 2251799813685248.0               # 2⁵¹
_SQRT2 = math.sqrt(2.0)

# fdlibm's e_log.c and k_sin.c / k_cos.c coefficients
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_LG1 = 6.666666666666735130e-01
_LG2 = 3.999999999940941908e-01
_LG3 = 2.857142874366239149e-01
_LG4 = 2.222219843214978396e-01
_LG5 = 1.818357216161805012e-01
_LG6 = 1.531383769920937332e-01
_LG7 = 1.479819860511658591e-01
_S1 = -1.66666666666666324348e-01
_S2 = 8.33333333332248946124e-03
_S3 = -1.98412698298579493134e-04
_S4 = 2.75573137070700676789e-06
_S5 = -2.50507602534068634195e-08
_S6 = 1.58969099521155010221e-10
_C1 = 4.16666666666666019037e-02
_C2 = -1.38888888888741095749e-03
_C3 = 2.48015872894767294178e-05
_C4 = -2.75573143513906633035e-07
_C5 = 2.08757232129817482790e-09
_C6 = -1.13596475577881948265e-11


def key_from(rng: np.random.Generator) -> int:
    """One 64-bit key from ``rng`` (advances it by one word)."""
    return int(rng.bit_generator.random_raw())


def stream(key: int) -> np.ndarray:
    """The key as the kernels take it: a one-element uint64 array."""
    return np.array([key], dtype=np.uint64)


def key_stream(rng: np.random.Generator) -> np.ndarray:
    """``stream(key_from(rng))`` in one call: the generator's next word as a one-element
    uint64 array (``random_raw(1)``: the same word, advancing ``rng`` the same)."""
    return rng.bit_generator.random_raw(1)


@intrinsic
def _fma(typingctx, a, b, c):
    """``a · b + c`` rounded once (LLVM's ``llvm.fma.f64``: one instruction on x86-64 with FMA
    and on arm64, the C library's ``fma`` elsewhere; the same float everywhere)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)
    return sig, codegen


@intrinsic
def _f64_bits(typingctx, a):
    """The IEEE bits of a float64, as uint64."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))
    return types.uint64(types.float64), codegen


@intrinsic
def _bits_f64(typingctx, a):
    """The float64 of IEEE bits (uint64)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.uint64), codegen


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True, inline="always")
def _mix(z):
    """The SplitMix64 finaliser (Stafford's variant 13)."""
    z = (z ^ (z >> _U30)) * _M1
    z = (z ^ (z >> _U27)) * _M2
    return z ^ (z >> _U31)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def subkey(key, j):
    """The key of an independent family of words, number ``j`` (int) of ``key`` (uint64)."""
    return _mix(key ^ (np.uint64(j + 1) * _SUB))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _log_unit(x):
    """``log x`` for x in [2⁻⁵³, 1] (fdlibm's ``__ieee754_log``, its general branch, the
    polynomials by fused multiply-adds)."""
    b = _f64_bits(x)
    k = float(np.int64(b >> _U52) - 1023)
    m = _bits_f64((b & _MASK52) | _ONE_BITS)       # x = m 2^k, m in [1, 2)
    big = m > _SQRT2
    m = 0.5 * m if big else m
    k = k + 1.0 if big else k
    f = m - 1.0
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * _fma(w, _fma(w, _LG6, _LG4), _LG2)
    t2 = z * _fma(w, _fma(w, _fma(w, _LG7, _LG5), _LG3), _LG1)
    r = t2 + t1
    hfsq = 0.5 * f * f
    return _fma(k, _LN2_HI, -((hfsq - _fma(s, hfsq + r, k * _LN2_LO)) - f))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _sin_k(x):
    """``sin x`` on [−π/4, π/4] (fdlibm's ``__kernel_sin``, y = 0)."""
    z = x * x
    v = z * x
    r = _fma(z, _fma(z, _fma(z, _fma(z, _S6, _S5), _S4), _S3), _S2)
    return _fma(v, _fma(z, r, _S1), x)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _cos_k(x):
    """``cos x`` on [−π/4, π/4] (fdlibm's ``__kernel_cos``, y = 0, without its |x| > 0.3
    refinement: within one ulp of the C library's, tested)."""
    z = x * x
    p = _fma(z, _fma(z, _fma(z, _fma(z, _fma(z, _C6, _C5), _C4), _C3), _C2), _C1)
    return 1.0 - _fma(-(z * z), p, 0.5 * z)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def direction(w):
    """``(cos θ, sin θ)`` of θ uniform on the circle from the word ``w``: ``θ = q π/2 + t``
    with the quadrant ``q = w & 3`` and ``t = (π/2) ((w >> 12) 2⁻⁵² − ½)`` in [−π/4, π/4)
    (branch free)."""
    t = (float(np.int64(w >> _U12)) - _HALF_2_52) * _TO_ANGLE
    c = _cos_k(t)
    s = _sin_k(t)
    q = w & _U3
    odd = (q & _U1) != 0
    cq = s if odd else c
    sq = c if odd else s
    # (cos, sin)(q π/2 + t): q = 1 (−sin t, cos t), 2 (−cos t, −sin t), 3 (sin t, −cos t)
    cq = -cq if (q == _U1 or q == _U2) else cq
    sq = -sq if q >= _U2 else sq
    return cq, sq


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def normal_pair(key, p):
    """Pair ``p`` (uint64) of key ``key``: two independent standard normals (Box–Muller on
    words ``2p`` and ``2p + 1``), normals ``2p`` and ``2p + 1`` of the key."""
    s = key + (p + p + _U1) * _GAMMA
    u = float(np.int64((_mix(s) >> _U11) + _U1)) * _TO_UNIT
    r = math.sqrt(-2.0 * _log_unit(u))
    c, sn = direction(_mix(s + _GAMMA))
    return r * c, r * sn


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def normal_pairs_into(key, p0, dp, a, b, n):
    """``a[c], b[c]`` = pair ``p0 + c dp`` of ``key`` for c < n (one vectorised loop)."""
    s = key + (p0 + p0 + _U1) * _GAMMA
    ds = (dp + dp) * _GAMMA
    for c in range(n):
        u = float(np.int64((_mix(s) >> _U11) + _U1)) * _TO_UNIT
        r = math.sqrt(-2.0 * _log_unit(u))
        co, si = direction(_mix(s + _GAMMA))
        a[c] = r * co
        b[c] = r * si
        s += ds


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def directions_into(key, i0, a, b, n):
    """``a[c], b[c]`` = :func:`direction` of word ``i0 + c`` of ``key`` for c < n."""
    s = key + (i0 + _U1) * _GAMMA
    for c in range(n):
        co, si = direction(_mix(s))
        a[c] = co
        b[c] = si
        s += _GAMMA


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def fill_normal(st, out):
    """``out[i]`` = normal ``i0 + i`` of the key ``st[0]`` (``i0`` even: ``st[1]`` if given,
    else 0) for every i: component ``i mod 2`` of pair ``⌊i / 2⌋`` (tests, tools)."""
    key = st[0]
    p0 = st[1] // _U2 if st.shape[0] > 1 else np.uint64(0)
    n = out.shape[0]
    for i in range(0, n - 1, 2):
        out[i], out[i + 1] = normal_pair(key, p0 + np.uint64(i // 2))
    if n % 2:
        out[n - 1], _ = normal_pair(key, p0 + np.uint64(n // 2))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def fill_direction(st, c, s):
    """``(c[i], s[i])`` = :func:`direction` of word ``i`` of the key ``st[0]`` (tests)."""
    directions_into(st[0], np.uint64(0), c, s, c.shape[0])


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def log_cos_sin(x, t, lx, ct, st):
    """``lx = log x``, ``ct, st = cos t, sin t`` with the generator's inline functions
    (x in [2⁻⁵³, 1], t in [−π/4, π/4]; tests)."""
    for i in range(x.shape[0]):
        lx[i] = _log_unit(x[i])
    for i in range(t.shape[0]):
        ct[i] = _cos_k(t[i])
        st[i] = _sin_k(t[i])
