"""Fused numba kernels of the particle PHD filter and its K-means (issue 12, "reach for numba
where a profile shows numpy cannot").

The numpy versions were already gated and vectorised; what was left was numpy's call overhead
and its temporaries (one (pairs,) or (N, K) array per arithmetic step).  Each kernel here is one
or two passes over the particles with no temporary larger than O(N + N_z + grid):

- :func:`propagate_into` — the size-aware motion model, its normals drawn inside (predict).
- :func:`grid_build` / :func:`grid_span` — a uniform grid on the particles' positions (counting
  sort by cell), so a detection visits only the particles in the cells its gate box touches.
- :func:`mass_near_kernel` — M(z) of the birth allocation, the predicted mass in z's gate;
  :func:`mass_near_few` / :func:`mass_near_skip` — the learnt clutter's M'(z) (few
  detections; the skipped ones left at 0, the grid cells included).
- :func:`birth_fill` — the newborn states, their random numbers drawn inside;
  :func:`birth_alloc_fill` — J_z (:func:`birth_counts`), the newborn log-weights and the
  fill in one call (the filter's birth); :func:`grid_cell` — the grids' cell size.
- :func:`gauss_update` — eq. (5) with the Gaussian g(z|x) evaluated on the fly inside each
  detection's gate: C(z) by an online log-sum-exp per detection, then each particle's bracket
  ``p_M + Σ_z ψ/(κ + C)`` by an online log-sum-exp per particle; no pair arrays.
- (systematic resampling, one walk over the CDF: ``trackers.smc.resampling._systematic_index``)
- (the K-means kernels: :mod:`._kmeans_kernels`)

The random numbers of predict and birth are drawn inside the kernels from a generator keyed by
one word of the caller's ``numpy.random.Generator`` (:mod:`~trackers.smc.random`: counter-based
SplitMix64 words, Box–Muller normals), a few hundred at a time in a vectorised loop into a
small buffer, then used: no (N, k) temporaries; the seed still fixes every draw.  The K-means kernels
do their arithmetic in the same order as the numpy code they replace (bit for bit the same
floats); the update's sums run in a different order, in linear space when the weights allow
(float reordering only).  No kernel uses ``fastmath``.  They use numpy's error model (every
divisor is positive, so no zero-division branches to compile), and the helpers only kernels
call have no CPython wrapper: less to compile on the first run after an install.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from ..smc.random import _bits_f64 as _from_bits, _f64_bits as _bits, _fma  # (intrinsics)
from ..smc.random import directions_into, normal_pairs_into, subkey
from .gating import kth

_HALF_LOG_2PI_4 = 2.0 * math.log(2.0 * math.pi)     # 0.5 · OBS_DIM · log(2π), OBS_DIM = 4


# ----------------------------------------------------------------------------- exp, inline

#: exp's table: 2^(k/128) for k = 0 .. 127 as (tail, bits − (k << 45)) pairs (Szabolcs Nagy's
#: exp of ARM's optimized-routines, the C library's since glibc 2.28: ``__exp_data.tab``)
_EXP_TAB = np.array([
    0x0000000000000000, 0x3ff0000000000000, 0x3c9b3b4f1a88bf6e, 0x3feff63da9fb3335,
    0xbc7160139cd8dc5d, 0x3fefec9a3e778061, 0xbc905e7a108766d1, 0x3fefe315e86e7f85,
    0x3c8cd2523567f613, 0x3fefd9b0d3158574, 0xbc8bce8023f98efa, 0x3fefd06b29ddf6de,
    0x3c60f74e61e6c861, 0x3fefc74518759bc8, 0x3c90a3e45b33d399, 0x3fefbe3ecac6f383,
    0x3c979aa65d837b6d, 0x3fefb5586cf9890f, 0x3c8eb51a92fdeffc, 0x3fefac922b7247f7,
    0x3c3ebe3d702f9cd1, 0x3fefa3ec32d3d1a2, 0xbc6a033489906e0b, 0x3fef9b66affed31b,
    0xbc9556522a2fbd0e, 0x3fef9301d0125b51, 0xbc5080ef8c4eea55, 0x3fef8abdc06c31cc,
    0xbc91c923b9d5f416, 0x3fef829aaea92de0, 0x3c80d3e3e95c55af, 0x3fef7a98c8a58e51,
    0xbc801b15eaa59348, 0x3fef72b83c7d517b, 0xbc8f1ff055de323d, 0x3fef6af9388c8dea,
    0x3c8b898c3f1353bf, 0x3fef635beb6fcb75, 0xbc96d99c7611eb26, 0x3fef5be084045cd4,
    0x3c9aecf73e3a2f60, 0x3fef54873168b9aa, 0xbc8fe782cb86389d, 0x3fef4d5022fcd91d,
    0x3c8a6f4144a6c38d, 0x3fef463b88628cd6, 0x3c807a05b0e4047d, 0x3fef3f49917ddc96,
    0x3c968efde3a8a894, 0x3fef387a6e756238, 0x3c875e18f274487d, 0x3fef31ce4fb2a63f,
    0x3c80472b981fe7f2, 0x3fef2b4565e27cdd, 0xbc96b87b3f71085e, 0x3fef24dfe1f56381,
    0x3c82f7e16d09ab31, 0x3fef1e9df51fdee1, 0xbc3d219b1a6fbffa, 0x3fef187fd0dad990,
    0x3c8b3782720c0ab4, 0x3fef1285a6e4030b, 0x3c6e149289cecb8f, 0x3fef0cafa93e2f56,
    0x3c834d754db0abb6, 0x3fef06fe0a31b715, 0x3c864201e2ac744c, 0x3fef0170fc4cd831,
    0x3c8fdd395dd3f84a, 0x3feefc08b26416ff, 0xbc86a3803b8e5b04, 0x3feef6c55f929ff1,
    0xbc924aedcc4b5068, 0x3feef1a7373aa9cb, 0xbc9907f81b512d8e, 0x3feeecae6d05d866,
    0xbc71d1e83e9436d2, 0x3feee7db34e59ff7, 0xbc991919b3ce1b15, 0x3feee32dc313a8e5,
    0x3c859f48a72a4c6d, 0x3feedea64c123422, 0xbc9312607a28698a, 0x3feeda4504ac801c,
    0xbc58a78f4817895b, 0x3feed60a21f72e2a, 0xbc7c2c9b67499a1b, 0x3feed1f5d950a897,
    0x3c4363ed60c2ac11, 0x3feece086061892d, 0x3c9666093b0664ef, 0x3feeca41ed1d0057,
    0x3c6ecce1daa10379, 0x3feec6a2b5c13cd0, 0x3c93ff8e3f0f1230, 0x3feec32af0d7d3de,
    0x3c7690cebb7aafb0, 0x3feebfdad5362a27, 0x3c931dbdeb54e077, 0x3feebcb299fddd0d,
    0xbc8f94340071a38e, 0x3feeb9b2769d2ca7, 0xbc87deccdc93a349, 0x3feeb6daa2cf6642,
    0xbc78dec6bd0f385f, 0x3feeb42b569d4f82, 0xbc861246ec7b5cf6, 0x3feeb1a4ca5d920f,
    0x3c93350518fdd78e, 0x3feeaf4736b527da, 0x3c7b98b72f8a9b05, 0x3feead12d497c7fd,
    0x3c9063e1e21c5409, 0x3feeab07dd485429, 0x3c34c7855019c6ea, 0x3feea9268a5946b7,
    0x3c9432e62b64c035, 0x3feea76f15ad2148, 0xbc8ce44a6199769f, 0x3feea5e1b976dc09,
    0xbc8c33c53bef4da8, 0x3feea47eb03a5585, 0xbc845378892be9ae, 0x3feea34634ccc320,
    0xbc93cedd78565858, 0x3feea23882552225, 0x3c5710aa807e1964, 0x3feea155d44ca973,
    0xbc93b3efbf5e2228, 0x3feea09e667f3bcd, 0xbc6a12ad8734b982, 0x3feea012750bdabf,
    0xbc6367efb86da9ee, 0x3fee9fb23c651a2f, 0xbc80dc3d54e08851, 0x3fee9f7df9519484,
    0xbc781f647e5a3ecf, 0x3fee9f75e8ec5f74, 0xbc86ee4ac08b7db0, 0x3fee9f9a48a58174,
    0xbc8619321e55e68a, 0x3fee9feb564267c9, 0x3c909ccb5e09d4d3, 0x3feea0694fde5d3f,
    0xbc7b32dcb94da51d, 0x3feea11473eb0187, 0x3c94ecfd5467c06b, 0x3feea1ed0130c132,
    0x3c65ebe1abd66c55, 0x3feea2f336cf4e62, 0xbc88a1c52fb3cf42, 0x3feea427543e1a12,
    0xbc9369b6f13b3734, 0x3feea589994cce13, 0xbc805e843a19ff1e, 0x3feea71a4623c7ad,
    0xbc94d450d872576e, 0x3feea8d99b4492ed, 0x3c90ad675b0e8a00, 0x3feeaac7d98a6699,
    0x3c8db72fc1f0eab4, 0x3feeace5422aa0db, 0xbc65b6609cc5e7ff, 0x3feeaf3216b5448c,
    0x3c7bf68359f35f44, 0x3feeb1ae99157736, 0xbc93091fa71e3d83, 0x3feeb45b0b91ffc6,
    0xbc5da9b88b6c1e29, 0x3feeb737b0cdc5e5, 0xbc6c23f97c90b959, 0x3feeba44cbc8520f,
    0xbc92434322f4f9aa, 0x3feebd829fde4e50, 0xbc85ca6cd7668e4b, 0x3feec0f170ca07ba,
    0x3c71affc2b91ce27, 0x3feec49182a3f090, 0x3c6dd235e10a73bb, 0x3feec86319e32323,
    0xbc87c50422622263, 0x3feecc667b5de565, 0x3c8b1c86e3e231d5, 0x3feed09bec4a2d33,
    0xbc91bbd1d3bcbb15, 0x3feed503b23e255d, 0x3c90cc319cee31d2, 0x3feed99e1330b358,
    0x3c8469846e735ab3, 0x3feede6b5579fdbf, 0xbc82dfcd978e9db4, 0x3feee36bbfd3f37a,
    0x3c8c1a7792cb3387, 0x3feee89f995ad3ad, 0xbc907b8f4ad1d9fa, 0x3feeee07298db666,
    0xbc55c3d956dcaeba, 0x3feef3a2b84f15fb, 0xbc90a40e3da6f640, 0x3feef9728de5593a,
    0xbc68d6f438ad9334, 0x3feeff76f2fb5e47, 0xbc91eee26b588a35, 0x3fef05b030a1064a,
    0x3c74ffd70a5fddcd, 0x3fef0c1e904bc1d2, 0xbc91bdfbfa9298ac, 0x3fef12c25bd71e09,
    0x3c736eae30af0cb3, 0x3fef199bdd85529c, 0x3c8ee3325c9ffd94, 0x3fef20ab5fffd07a,
    0x3c84e08fd10959ac, 0x3fef27f12e57d14b, 0x3c63cdaf384e1a67, 0x3fef2f6d9406e7b5,
    0x3c676b2c6c921968, 0x3fef3720dcef9069, 0xbc808a1883ccb5d2, 0x3fef3f0b555dc3fa,
    0xbc8fad5d3ffffa6f, 0x3fef472d4a07897c, 0xbc900dae3875a949, 0x3fef4f87080d89f2,
    0x3c74a385a63d07a7, 0x3fef5818dcfba487, 0xbc82919e2040220f, 0x3fef60e316c98398,
    0x3c8e5a50d5c192ac, 0x3fef69e603db3285, 0x3c843a59ac016b4b, 0x3fef7321f301b460,
    0xbc82d52107b43e1f, 0x3fef7c97337b9b5f, 0xbc892ab93b470dc9, 0x3fef864614f5a129,
    0x3c74b604603a88d3, 0x3fef902ee78b3ff6, 0x3c83c5ec519d7271, 0x3fef9a51fbc74c83,
    0xbc8ff7128fd391f0, 0x3fefa4afa2a490da, 0xbc8dae98e223747d, 0x3fefaf482d8e67f1,
    0x3c8ec3bc41aa2008, 0x3fefba1bee615a27, 0x3c842b94c3a9eb32, 0x3fefc52b376bba97,
    0x3c8a64a931d185ee, 0x3fefd0765b6e4540, 0xbc8e37bae43be3ed, 0x3fefdbfdad9cbe14,
    0x3c77893b4d91cd9d, 0x3fefe7c1819e90d8, 0x3c5305c14160cc89, 0x3feff3c22b8f71f1,
], dtype=np.uint64)
_EXP_INVLN2N = float.fromhex("0x1.71547652b82fep+7")      # 128 / ln 2
_EXP_NEGLN2HIN = float.fromhex("-0x1.62e42fefa0000p-8")   # −ln 2 / 128, high and low parts
_EXP_NEGLN2LON = float.fromhex("-0x1.cf79abc9e3b3ap-47")
_EXP_C2 = float.fromhex("0x1.ffffffffffdbdp-2")
_EXP_C3 = float.fromhex("0x1.555555555543cp-3")
_EXP_C4 = float.fromhex("0x1.55555cf172b91p-5")
_EXP_C5 = float.fromhex("0x1.1111167a4d017p-7")
_EXP_SHIFT = float.fromhex("0x1.8p52")
_EXP_TINY = 2.0 ** -54
_U127 = np.uint64(127)
_U1 = np.uint64(1)
_U45 = np.uint64(45)
#: the arguments :func:`_exp_gate` takes: ``-EXP_GATE_MAX < x <= 0``
EXP_GATE_MAX = 512.0


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _exp_gate(x):
    """``exp(x)`` for ``-512 < x <= 0`` (a Gaussian inside its gate), the C library's floats
    (glibc >= 2.28 on a CPU with FMA, whose ``exp`` numba's ``math.exp`` calls: the same
    operations -- table look-up, a degree-5 polynomial, its fused multiply-adds where that
    build has them -- checked bit for bit against it on 1.2e8 arguments), inline and branch
    free: a loop of them vectorises (4x faster than a call a value)."""
    kd = _fma(x, _EXP_INVLN2N, _EXP_SHIFT)
    ki = _bits(kd)
    kd = kd - _EXP_SHIFT
    r = _fma(kd, _EXP_NEGLN2HIN, x)
    r = _fma(kd, _EXP_NEGLN2LON, r)
    idx = (ki & _U127) << _U1
    tail = _from_bits(_EXP_TAB[idx])
    sbits = _EXP_TAB[idx + _U1] + (ki << _U45)
    p23 = _fma(r, _EXP_C3, _EXP_C2)
    tr = r + tail
    r2 = r * r
    p45 = _fma(r, _EXP_C5, _EXP_C4)
    tmp = _fma(r2 * r2, p45, _fma(p23, r2, tr))
    scale = _from_bits(sbits)
    v = _fma(scale, tmp, scale)
    return v if -x >= _EXP_TINY else 1.0 + x          # |x| < 2^-54: the C library's 1 + x


# ----------------------------------------------------------------------------- predict

def _prefetcher(rw):
    """An intrinsic ``prefetch(arr, i)``: a hint (``llvm.prefetch``, read ``rw`` = 0 or write
    1, into L1) for the cache line of ``arr[i, 0, …]``; no effect on any result."""
    @intrinsic
    def prefetch(typingctx, arr, i):
        if not isinstance(arr, types.Array):
            return None

        def codegen(context, builder, signature, args):
            aryty = signature.args[0]
            ary = context.make_array(aryty)(context, builder, args[0])
            idx = [args[1]] + [context.get_constant(types.intp, 0)] * (aryty.ndim - 1)
            ptr = cgutils.get_item_pointer(context, builder, aryty, ary, idx, wraparound=False)
            i8p = ir.IntType(8).as_pointer()
            i32 = ir.IntType(32)
            fn = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                "llvm.prefetch.p0i8")          # (the typed-pointer name LLVM ≥ 17 upgrades)
            builder.call(fn, [builder.bitcast(ptr, i8p), i32(rw), i32(3), i32(1)])
            return context.get_dummy_value()
        return types.void(arr, types.intp), codegen
    return prefetch


_prefetch_read = _prefetcher(0)
_prefetch_write = _prefetcher(1)
#: rows ahead of the one in use whose lines predict / birth ask for (with the caches cold, as
#: the benchmark's Stone Soup leaves them, the prediction's pass ~15 % shorter; a whole chunk
#: asked for at once was slower)
_AHEAD = 64


#: particles (predict) or newborn (birth) whose normals a kernel makes in one vectorised loop
#: before using them (their few KB stay in L1)
_CHUNK = 256


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def propagate_into(x, st, sigma_v, sigma_size, accel_to_position, min_size, out, lw, log_e,
                   lw_out, ext):
    """``out[:N]`` (N, 6) = f(x) with four normals ``ε`` per particle, particle i's normals
    4i … 4i + 3 of the key ``st[0]`` (:mod:`~trackers.smc.random`, pairs 2i and 2i + 1):
    ``a = σ_v (w, h) ε₀₁``, ``y += v + c a``, ``v += a``,
    ``(w, h) = max((w, h) + σ_s (w, h) ε₂₃, min_size)`` (:func:`~.motion.propagate`); with
    ``lw`` (N,) (else empty), also ``lw_out[:N] = lw + log_e`` in the same pass (the
    prediction's survival factor, numpy's add).  With ``ext`` (5,) (else empty), also the new
    positions' extent ``(x0, y0, x1, y1, finite)`` in the same pass -- :func:`grid_shape`'s
    minima / maxima of ``out[:N, 0]``, ``out[:N, 1]`` (its rule, in its order: the same
    floats) and 1.0 when each column's sum is finite (then every value is), else 0.0 (a value
    not finite, or a sum that overflowed: :func:`grid_build_at` then takes grid_shape's own
    pass) -- so :func:`grid_build_at` needs no pass of its own over them.  The normals of
    ``_CHUNK`` particles at a time are made in one vectorised loop, then used."""
    key = st[0]
    n = x.shape[0]
    with_lw = lw.shape[0] == n
    with_ext = ext.shape[0] >= 5
    x0 = np.inf
    y0 = np.inf
    x1 = -np.inf
    y1 = -np.inf
    sx = 0.0
    sy = 0.0
    eps = np.empty((4, _CHUNK))
    e0, e1, e2, e3 = eps[0], eps[1], eps[2], eps[3]
    for k0 in range(0, n, _CHUNK):
        m = min(_CHUNK, n - k0)
        p0 = np.uint64(2 * k0)
        normal_pairs_into(key, p0, np.uint64(2), e0, e1, m)
        normal_pairs_into(key, p0 + np.uint64(1), np.uint64(2), e2, e3, m)
        for c in range(m):
            i = k0 + c
            if i + _AHEAD < n:
                _prefetch_read(x, i + _AHEAD)
                _prefetch_write(out, i + _AHEAD)
            if with_lw:
                lw_out[i] = lw[i] + log_e
            w = x[i, 4]
            h = x[i, 5]
            a0 = sigma_v * w * e0[c]
            a1 = sigma_v * h * e1[c]
            px = x[i, 0] + (x[i, 2] + accel_to_position * a0)
            py = x[i, 1] + (x[i, 3] + accel_to_position * a1)
            out[i, 0] = px
            out[i, 1] = py
            out[i, 2] = x[i, 2] + a0
            out[i, 3] = x[i, 3] + a1
            nw = w + sigma_size * w * e2[c]
            nh = h + sigma_size * h * e3[c]
            out[i, 4] = nw if not nw < min_size else min_size
            out[i, 5] = nh if not nh < min_size else min_size
            if with_ext:
                x0 = px if px < x0 else x0     # grid_shape's rule and order
                x1 = px if px > x1 else x1
                y0 = py if py < y0 else y0
                y1 = py if py > y1 else y1
                sx += px                       # (NaN or inf stays: no branch a particle)
                sy += py
    if with_ext:
        ext[0] = x0
        ext[1] = y0
        ext[2] = x1
        ext[3] = y1
        ext[4] = 1.0 if math.isfinite(sx) and math.isfinite(sy) else 0.0


# ----------------------------------------------------------------------------- detections

@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def observation_noise(Z, sigma_obs, sigma_min, pos_ratio):
    """``filter.as_observations``' checks and ``filter.obs_std`` of the sizes in one pass over
    the detections ``Z`` (N_z, 4): ``(code, std)``, ``code`` 0 when every value is finite and
    every width and height > 0, 1 when a value is not finite (the check made first), 2 when a
    size is <= 0; ``std`` (N_z, 4) ``(r σ_w, r σ_h, σ_w, σ_h)``, ``σ = max(sigma_obs · size,
    sigma_min)`` -- numpy's floats (``np.maximum`` keeps its first operand on a tie: the same
    value)."""
    n = Z.shape[0]
    std = np.empty((n, 4), np.float64)
    finite = True
    positive = True
    for i in range(n):
        for d in range(4):
            finite = finite and math.isfinite(Z[i, d])
        w = Z[i, 2]
        h = Z[i, 3]
        positive = positive and not (w <= 0.0 or h <= 0.0)
        sw = sigma_obs * w
        sw = sw if sw >= sigma_min else sigma_min
        sh = sigma_obs * h
        sh = sh if sh >= sigma_min else sigma_min
        std[i, 0] = pos_ratio * sw
        std[i, 1] = pos_ratio * sh
        std[i, 2] = sw
        std[i, 3] = sh
    return (0 if positive else 2) if finite else 1, std


# ----------------------------------------------------------------------------- grid index

@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _zero_start():
    """``starts`` = [0] of an empty grid (np.empty, not np.zeros: one allocation overload
    fewer to compile on a first run)."""
    a = np.empty(1, np.int64)
    a[0] = 0
    return a


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def grid_shape(px, py, cell_x, cell_y):
    """:func:`grid_build`'s grid without the bucketing: ``(ok, x0, y0, cell_x, cell_y, ni,
    nj)``, the origin at the points' minima, the cells grown (×2) until there are at most
    ``4 N + 64`` of them; ``ok`` False when a coordinate is not finite (``ni = nj = 0`` also
    when there is no point)."""
    n = px.shape[0]
    x0 = np.inf
    y0 = np.inf
    x1 = -np.inf
    y1 = -np.inf
    for i in range(n):
        a = px[i]
        b = py[i]
        if not (math.isfinite(a) and math.isfinite(b)):
            return False, 0.0, 0.0, cell_x, cell_y, 0, 0
        x0 = a if a < x0 else x0           # min(x0, a), max(x1, a), ... spelt out as numba's
        x1 = a if a > x1 else x1           # own rule (v if v < acc else acc): the same floats,
        y0 = b if b < y0 else y0           # and no builtin min/max overload to compile on a
        y1 = b if b > y1 else y1           # first run
    return _grid_grow(n, x0, y0, x1, y1, cell_x, cell_y)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _grid_grow(n, x0, y0, x1, y1, cell_x, cell_y):
    """:func:`grid_shape` after its pass: ``n`` finite points of extent ``(x0, y0, x1, y1)``."""
    if n == 0:
        return True, 0.0, 0.0, cell_x, cell_y, 0, 0
    max_cells = 4.0 * n + 64.0
    while True:
        fi = math.floor((x1 - x0) / cell_x) + 1.0
        fj = math.floor((y1 - y0) / cell_y) + 1.0
        if fi * fj <= max_cells:
            break
        cell_x *= 2.0
        cell_y *= 2.0
    return True, x0, y0, cell_x, cell_y, int(fi), int(fj)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True, inline="always")
def _cell_key(x, y, x0, y0, cell_x, cell_y, ni, nj):
    """The key ``i·nj + j`` of the grid cell holding the point ``(x, y)`` (the last row / column
    takes what lies beyond it): :func:`grid_build`'s and :func:`_bucket_four`'s one spelling."""
    ci = int((x - x0) / cell_x)
    ci = ni - 1 if ni - 1 < ci else ci
    cj = int((y - y0) / cell_y)
    cj = nj - 1 if nj - 1 < cj else cj
    return ci * nj + cj


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _bucket_four(px, py, x0, y0, cell_x, cell_y, ni, nj, n):
    """:func:`grid_build`'s counting sort (its ``order``, ``starts``: the same cells, the same
    stable order) on four consecutive chunks of the points at once, their counts kept apart
    (chunk after chunk within a cell): points of one cell one after the other (a target's
    particles come together) then do not wait on each other's count in memory.  For
    ``4 ni nj <= n`` (four counts a cell stay few beside the points) and ``n < 2**28`` (the
    int32 keys)."""
    nc = ni * nj
    q = n // 4
    cnt = np.empty((4, nc), np.int64)
    for l in range(4):
        for k in range(nc):
            cnt[l, k] = 0
    keys = np.empty(n, np.int32)
    for t in range(q):
        for l in range(4):
            i = l * q + t
            k = _cell_key(px[i], py[i], x0, y0, cell_x, cell_y, ni, nj)
            keys[i] = k
            cnt[l, k] += 1
    for i in range(4 * q, n):                 # (the rest: the last chunk's, after it)
        k = _cell_key(px[i], py[i], x0, y0, cell_x, cell_y, ni, nj)
        keys[i] = k
        cnt[3, k] += 1
    starts = np.empty(nc + 1, np.int64)
    s = np.int64(0)
    for k in range(nc):                       # each chunk's first place in each cell
        starts[k] = s
        for l in range(4):
            c = cnt[l, k]
            cnt[l, k] = s
            s += c
    starts[nc] = s
    order = np.empty(n, np.int64)
    for t in range(q):
        for l in range(4):
            i = l * q + t
            k = keys[i]
            order[cnt[l, k]] = i
            cnt[l, k] += 1
    for i in range(4 * q, n):
        k = keys[i]
        order[cnt[3, k]] = i
        cnt[3, k] += 1
    return order, starts


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def grid_build(px, py, cell_x, cell_y):
    """Bucket the points ``(px, py)`` (N,) on a uniform grid of ``cell_x × cell_y``.

    Returns ``(ok, x0, y0, cell_x, cell_y, ni, nj, order, starts)``: ``order`` (N,) the point
    indices sorted by cell key ``i·nj + j`` (stable), ``starts`` (ni·nj + 1,) the first position
    in ``order`` of each cell.  The cells grow (×2) until there are at most ``4 N + 64`` of them,
    so memory stays O(N) however far apart the points are.  ``ok`` is False when a coordinate
    is not finite (nothing else is valid then).  Where the cells are few beside the points,
    :func:`_bucket_four` sorts them (the same order and starts)."""
    return _grid_fill(px, py, *grid_shape(px, py, cell_x, cell_y))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def grid_build_at(px, py, cell_x, cell_y, ext):
    """:func:`grid_build` where ``ext`` (5,) is the points' extent ``(x0, y0, x1, y1, finite)``
    as :func:`propagate_into` made it (their minima / maxima by grid_shape's rule and order:
    the same grid, order and starts without grid_shape's pass); ``ext`` empty or not known
    finite (``ext[4]`` 0): grid_build."""
    if ext.shape[0] < 5 or ext[4] == 0.0:
        return grid_build(px, py, cell_x, cell_y)
    return _grid_fill(px, py, *_grid_grow(px.shape[0], ext[0], ext[1], ext[2], ext[3],
                                          cell_x, cell_y))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _grid_fill(px, py, ok, x0, y0, cell_x, cell_y, ni, nj):
    """:func:`grid_build` after :func:`grid_shape` (its returns): the bucketing."""
    if not ok:
        return False, 0.0, 0.0, cell_x, cell_y, 0, 0, np.empty(0, np.int64), _zero_start()
    n = px.shape[0]
    if n == 0:
        return True, 0.0, 0.0, cell_x, cell_y, 0, 0, np.empty(0, np.int64), _zero_start()
    nc = ni * nj
    if 4 * nc <= n and n < 2 ** 28:
        order, starts = _bucket_four(px, py, x0, y0, cell_x, cell_y, ni, nj, n)
        return True, x0, y0, cell_x, cell_y, ni, nj, order, starts
    starts = np.empty(ni * nj + 1, np.int64)
    for k in range(ni * nj + 1):
        starts[k] = 0
    keys = np.empty(n, np.int64)
    for i in range(n):
        k = _cell_key(px[i], py[i], x0, y0, cell_x, cell_y, ni, nj)
        keys[i] = k
        starts[k + 1] += 1
    for k in range(ni * nj):
        starts[k + 1] += starts[k]
    fill = np.empty(ni * nj, np.int64)
    for k in range(ni * nj):
        fill[k] = starts[k]
    order = np.empty(n, np.int64)
    for i in range(n):
        k = keys[i]
        order[fill[k]] = i
        fill[k] += 1
    return True, x0, y0, cell_x, cell_y, ni, nj, order, starts


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def grid_span(lo, hi, origin, cell, n_cells):
    """Cells ``[c0, c1]`` along one axis that the interval ``[lo, hi]`` touches, clipped to the
    grid; ``c1 < c0`` when it misses the grid."""
    a = math.floor((lo - origin) / cell)
    b = math.floor((hi - origin) / cell)
    if not b >= 0.0 or not a <= n_cells - 1.0:      # also catches NaN
        return 0, -1
    c0 = 0 if a < 0.0 else a                        # (math.floor is an int already)
    c1 = n_cells - 1 if b > n_cells - 1.0 else b
    return c0, c1


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def gate_cells(zx, zy, sx, sy, r, x0, cx, ni, y0, cy, nj):
    """Grid cells ``(i0, i1, j0, j1)`` of the gate box around a detection at ``(zx, zy)``:
    ``r`` stds ``(sx, sy)`` each side, widened by a hair so that a particle exactly on the
    gate's edge is never left out by rounding."""
    hx = r * sx * (1.0 + 1e-6) + 1e-9
    hy = r * sy * (1.0 + 1e-6) + 1e-9
    i0, i1 = grid_span(zx - hx, zx + hx, x0, cx, ni)
    j0, j1 = grid_span(zy - hy, zy + hy, y0, cy, nj)
    return i0, i1, j0, j1


#: the most detections :func:`grid_cell` takes (its insertion sort is quadratic)
GRID_CELL_MAX = 64


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def grid_cell(std, r2):
    """:func:`~.filter._grid_cell`'s cells (2,) of numpy's floats: ``2 sqrt(r2)`` times the
    median of each of the first two columns of ``std`` (N, 4) -- the middle value or the mean
    of the two middle ones of ``np.sort``'s order -- 1 where that is not > 0.  Without NaN the
    middle values come by selection (:func:`.gating.kth`, linear); a column with NaN (last in
    np.sort's order, a broken detection's size) is insertion-sorted, quadratic, so
    ``filter._grid_cell`` calls it for N <= :data:`GRID_CELL_MAX` only (np.sort in numba costs
    ~2 s of compile); :func:`mass_near_skip` for any N."""
    n = std.shape[0]
    h = n // 2
    r = 2.0 * math.sqrt(r2)
    out = np.empty(2, np.float64)
    s = np.empty(n, np.float64)
    for d in range(2):
        nan = False
        for i in range(n):
            s[i] = std[i, d]
            nan = nan or s[i] != s[i]
        if not nan:
            hi = kth(s, h)                   # leaves s[:h] <= s[h]: the next is their max
            lo = hi
            if n % 2 == 0:
                lo = s[0]
                for i in range(1, h):
                    lo = s[i] if s[i] > lo else lo
        else:
            for i in range(n):
                v = std[i, d]
                k = i
                # shift the larger ones (NaN is larger than any number, as np.sort orders it)
                while k > 0 and (s[k - 1] > v or (s[k - 1] != s[k - 1] and v == v)):
                    s[k] = s[k - 1]
                    k -= 1
                s[k] = v
            hi = s[h]
            lo = s[h - 1] if n % 2 == 0 else hi
        med = hi if n % 2 else (lo + hi) / 2.0
        c = r * med
        out[d] = c if c > 0 else 1.0
    return out


# ----------------------------------------------------------------------------- birth

@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _gate_d2(states, i, Z, j, std, k, r2):
    """``Σ_d ((x_id − z_jd)/σ_kd)²`` on the observed columns (0, 1, 4, 5), or inf when it
    exceeds ``r2`` (or is NaN).  The position terms are tested first: adding squares cannot
    bring a sum back under ``r2`` (rounding is monotone), so the decision and the floats are
    those of the whole sum."""
    q0 = (states[i, 0] - Z[j, 0]) / std[k, 0]
    q1 = (states[i, 1] - Z[j, 1]) / std[k, 1]
    d2 = q0 * q0 + q1 * q1
    if not d2 <= r2:
        return np.inf
    q2 = (states[i, 4] - Z[j, 2]) / std[k, 2]
    q3 = (states[i, 5] - Z[j, 3]) / std[k, 3]
    d2 = d2 + q2 * q2 + q3 * q3
    return d2 if d2 <= r2 else np.inf


#: :func:`_gate_consts`' margin: a product by the reciprocal std is within ~1.6e-15 (14
#: roundings) of the quotient, so a distance outside ``r2 (1 ± FAST_GATE_MARGIN)`` by the
#: products is on the same side of ``r2`` by the quotients
FAST_GATE_MARGIN = 1e-12


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _gate_consts(Z, j, std, r2):
    """Detection j's values for :func:`_in_gate_fast`: ``(z0, z1, z2, z3, a0, a1, a2, a3,
    b0, b1, b2, b3, lo, hi)`` -- its observed values, stds ``std[j]``, their reciprocals and
    the band ``r2 (1 ± FAST_GATE_MARGIN)`` outside which the products decide.  Stds outside
    [1e-150, 1e150] in magnitude (a reciprocal that would overflow or lose bits) or NaN, or an
    r2 not in [1e-100, 1e100]: an empty band's opposite (lo = -inf, hi = inf): every particle
    takes :func:`_gate_d2`'s quotients."""
    a0, a1, a2, a3 = std[j, 0], std[j, 1], std[j, 2], std[j, 3]
    lo = r2 * (1.0 - FAST_GATE_MARGIN)
    hi = r2 * (1.0 + FAST_GATE_MARGIN)
    ok = r2 >= 1e-100 and r2 <= 1e100
    for a in (a0, a1, a2, a3):
        ok = ok and abs(a) >= 1e-150 and abs(a) <= 1e150
    if not ok:
        lo, hi = -np.inf, np.inf
    return (Z[j, 0], Z[j, 1], Z[j, 2], Z[j, 3], a0, a1, a2, a3,
            1.0 / a0, 1.0 / a1, 1.0 / a2, 1.0 / a3, lo, hi)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _in_gate_fast(states, i, c, r2):
    """``_gate_d2(states, i, Z, j, std, j, r2) <= r2`` -- the same answer -- with products by
    the reciprocal stds (``c`` = :func:`_gate_consts` of detection j) instead of four
    divisions: each q = (x - z)/σ as a product is within 3 roundings of the quotient, d² within
    14 (~1.6e-15 relative), so a d² by the products outside ``[lo, hi]`` (a band of ±1e-12)
    is on the side of ``r2`` the quotients put it; inside the band (or NaN) the quotients
    decide, :func:`_gate_d2`'s operations."""
    z0, z1, z2, z3, a0, a1, a2, a3, b0, b1, b2, b3, lo, hi = c
    e0 = states[i, 0] - z0
    e1 = states[i, 1] - z1
    e2 = states[i, 4] - z2
    e3 = states[i, 5] - z3
    q0 = e0 * b0
    q1 = e1 * b1
    q2 = e2 * b2
    q3 = e3 * b3
    d2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
    if d2 < lo:
        return True
    if d2 > hi:
        return False
    q0 = e0 / a0                        # _gate_d2's floats
    q1 = e1 / a1
    d2 = q0 * q0 + q1 * q1
    if not d2 <= r2:
        return False
    q2 = e2 / a2
    q3 = e3 / a3
    d2 = d2 + q2 * q2 + q3 * q3
    return d2 <= r2


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _weight_in_gate(states, w, ws, Z, j, std, r, r2, x0, cx, ni, y0, cy, nj, order, starts):
    """The weight ``w`` of the particles ``states`` (bucketed on the grid ``x0 .. starts``)
    inside detection j's gate ``d² <= r2`` under the stds ``std[j]`` (``r`` = sqrt(r2)), summed
    in the grid's order; particle i's weight is ``w[i · ws]`` (``ws`` 0: one value for all).
    Branch-free sum: adding 0.0 leaves the sum as it is (it is never -0.0: it starts at +0.0,
    and only -0.0 + -0.0 makes -0.0)."""
    i0, i1, j0, j1 = gate_cells(Z[j, 0], Z[j, 1], std[j, 0], std[j, 1], r,
                                x0, cx, ni, y0, cy, nj)
    c = _gate_consts(Z, j, std, r2)
    s = 0.0
    for ci in range(i0, i1 + 1):
        for p in range(starts[ci * nj + j0], starts[ci * nj + j1 + 1]):
            i = order[p]
            s += w[i * ws] if _in_gate_fast(states, i, c, r2) else 0.0
    return s


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def mass_near_kernel(states, w, Z, std_z, r2, cell_x, cell_y):
    """M(z) (N_z,): ``Σ w_i`` over the particles with ``Σ_d ((x_id − z_d)/σ_zd)² <= r2``
    on the observed columns (0, 1, 4, 5) of ``states`` (N, 6), ``std_z`` (N_z, 4) per detection.
    ``w`` (N,) the weights, or (1,) the one weight of every particle.
    Returns ``(ok, out, grid)``; ``ok`` False on non-finite positions; ``grid`` =
    ``(x0, y0, cx, cy, ni, nj, order, starts)`` of :func:`grid_build` on the particles'
    positions (no cell when there is no particle or no detection), which the update reuses
    for the same particles (:func:`gauss_update_linear`)."""
    return _mass_near_at(states, w, Z, std_z, r2, cell_x, cell_y, np.empty(0))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _mass_near_at(states, w, Z, std_z, r2, cell_x, cell_y, ext):
    """:func:`mass_near_kernel` with the positions' extent ``ext`` (:func:`grid_build_at`;
    empty: none known)."""
    nz = Z.shape[0]
    out = np.empty(nz, np.float64)
    for j in range(nz):
        out[j] = 0.0
    if states.shape[0] == 0 or nz == 0:
        return True, out, (0.0, 0.0, cell_x, cell_y, 0, 0, np.empty(0, np.int64), _zero_start())
    ok, x0, y0, cx, cy, ni, nj, order, starts = grid_build_at(states[:, 0], states[:, 1],
                                                              cell_x, cell_y, ext)
    grid = (x0, y0, cx, cy, ni, nj, order, starts)
    if not ok:
        return False, out, grid
    r = math.sqrt(r2)
    ws = 1 if w.shape[0] == states.shape[0] else 0
    for j in range(nz):
        out[j] = _weight_in_gate(states, w, ws, Z, j, std_z, r, r2, x0, cx, ni, y0, cy, nj,
                                 order, starts)
    return True, out, grid


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def mass_near_few(states, w, Z, std_z, r2, cell_x, cell_y):
    """:func:`mass_near_kernel`'s M(z) bit for bit -- on its grid of ``cell_x × cell_y`` over
    every particle, each detection's sum in the same order (cell key ``i·nj + j``, then
    particle index) -- without bucketing every particle: only those in a cell some gate box
    touches are kept (one pass), then bucketed as grid_build does (stable counting sort).
    For a few detections among many particles (κ_n's M'(z) of the unchained detections).
    ``w`` (N,), or (1,) the one weight of every particle.  Returns ``(ok, out)``."""
    nz = Z.shape[0]
    out = np.empty(nz, np.float64)       # np.empty and fills: no np.zeros overload to compile
    for j in range(nz):
        out[j] = 0.0
    n = states.shape[0]
    if n == 0 or nz == 0:
        return True, out
    ok, x0, y0, cx, cy, ni, nj = grid_shape(states[:, 0], states[:, 1], cell_x, cell_y)
    if not ok:
        return False, out
    r = math.sqrt(r2)
    box = np.empty((nz, 4), np.int64)
    mark = np.empty(ni * nj, np.bool_)
    for k in range(ni * nj):
        mark[k] = False
    for j in range(nz):
        i0, i1, j0, j1 = gate_cells(Z[j, 0], Z[j, 1], std_z[j, 0], std_z[j, 1], r,
                                    x0, cx, ni, y0, cy, nj)
        box[j, 0] = i0
        box[j, 1] = i1
        box[j, 2] = j0
        box[j, 3] = j1
        for ci in range(i0, i1 + 1):
            for cj in range(j0, j1 + 1):
                mark[ci * nj + cj] = True
    sel = np.empty(n, np.int64)
    key = np.empty(n, np.int64)
    m = np.int64(0)
    for i in range(n):
        ci = int((states[i, 0] - x0) / cx)       # grid_build's cell of the particle
        ci = ni - 1 if ni - 1 < ci else ci
        cj = int((states[i, 1] - y0) / cy)
        cj = nj - 1 if nj - 1 < cj else cj
        k = ci * nj + cj
        if mark[k]:
            sel[m] = i
            key[m] = k
            m += 1
    # grid_build's stable counting sort, on the kept particles and the touched cells only:
    # those numbered c = 0, 1, ... in key order (cid, read at touched cells only), their
    # runs in order[] from first[c]
    cid = np.empty(ni * nj, np.int64)
    nc = np.int64(0)
    for k in range(ni * nj):
        if mark[k]:
            cid[k] = nc
            nc += 1
    first = np.empty(nc + 1, np.int64)
    for c in range(nc + 1):
        first[c] = 0
    for q in range(m):
        first[cid[key[q]] + 1] += 1
    for c in range(nc):
        first[c + 1] += first[c]
    fill = np.empty(nc, np.int64)
    for c in range(nc):
        fill[c] = first[c]
    order = np.empty(m, np.int64)
    for q in range(m):
        c = cid[key[q]]
        order[fill[c]] = sel[q]
        fill[c] += 1
    ws = 1 if w.shape[0] == n else 0            # (one weight for all: w[0])
    for j in range(nz):
        s = 0.0
        if box[j, 3] < box[j, 2]:               # the gate misses the grid's columns
            continue
        c = _gate_consts(Z, j, std_z, r2)
        for ci in range(box[j, 0], box[j, 1] + 1):
            # the row's touched cells j0..j1 are consecutive in cid (all marked)
            for p in range(first[cid[ci * nj + box[j, 2]]],
                           first[cid[ci * nj + box[j, 3]] + 1]):
                i = order[p]
                s += w[i * ws] if _in_gate_fast(states, i, c, r2) else 0.0
        out[j] = s
    return True, out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _log_norms(log_std):
    """``Σ_d log σ_d`` per row of ``log_std`` (M, 4) = numpy's ``log(std)``: the sum
    ``((l₀ + l₁) + l₂) + l₃``, numpy's ``add.reduce`` along a row's four values (the filter
    hands the logs over, not their sums: one numpy reduction a frame fewer)."""
    m = log_std.shape[0]
    out = np.empty(m, np.float64)
    for k in range(m):
        out[k] = ((log_std[k, 0] + log_std[k, 1]) + log_std[k, 2]) + log_std[k, 3]
    return out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def birth_counts(m_near, j_max, complement, max_per_frame):
    """J_z (N_z,) int64 of :func:`~.filter.allocate_births`, numpy's floats spelt out:
    ``rint(J_max max(0, 1 − M(z)))`` (``complement``) or ``J_max``, then, when the total
    exceeds ``max_per_frame``, ``floor(J_z · (max_per_frame / ΣJ))``."""
    nz = m_near.shape[0]
    j = np.empty(nz, np.int64)
    total = 0
    for z in range(nz):
        if complement:
            v = 1.0 - m_near[z]
            v = 0.0 if 0.0 >= v else v          # np.maximum(0.0, v): NaN stays NaN
            j[z] = np.int64(np.rint(j_max * v))
        else:
            j[z] = j_max
        total += j[z]
    if total > max_per_frame:
        f = max_per_frame / total
        for z in range(nz):
            j[z] = np.int64(math.floor(j[z] * f))
    return j


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def birth_alloc_fill(m_near, consts, lw_base, lw_mode, log_std, revive, log_revive, Z, st,
                     states, log_w, det):
    """:func:`birth_counts`, each detection's newborn log-weight ``base_z − log max(J_z, 1)``
    (``+ log_revive`` where ``revive``, else ``+ 0``; ``revive`` empty: none) and
    :func:`birth_fill` into the first J = ΣJ_z rows of ``states``, ``log_w``, ``det`` (which
    must hold them: ``max_births`` rows), in one call: ``(j, J)``; ``J`` = -1 (nothing
    written) when a J_z is negative (a NaN M(z)) or the total does not fit the buffers.

    ``consts`` (float64): the settings, read once per frame from one array (an argument
    costs the call more than a load): ``j_max, complement (0/1), max_per_frame, sigma_obs,
    sigma_min, pos_ratio, spread, speed_mean, speed_std, min_size`` (``j_max`` and
    ``max_per_frame`` whole numbers), then ``lw_c`` from index :data:`BIRTH_LW_C`.

    ``base_z`` (``filter.log_birth_weight``'s floats, its numpy operations in their order):
    ``lw_mode`` 0: ``lw_base[z]``; 1: the constant ``lw_c[0]``; 2: the ``birth_odds`` weight
    of ``lw_base`` = log κ and ``log_norm`` = Σ log σ(z) (:func:`_log_norms` of ``log_std``
    (N_z, 4), the detections' log σ; read in mode 2 only), ``lw_c`` = (log odds, log(1 − p_M),
    ½ d log 2π, ½ d log(1 + spread²)): ``((c₀ + log κ) − c₁) − ((−log_norm − c₂) − c₃)``."""
    j = birth_counts(m_near, np.int64(consts[0]), consts[1] != 0.0, np.int64(consts[2]))
    nz = j.shape[0]
    n = 0
    for z in range(nz):
        if j[z] < 0:
            return j, -1
        n += j[z]
    if n > states.shape[0] or n > log_w.shape[0] or n > det.shape[0]:
        return j, -1
    lw_det = np.empty(nz, np.float64)
    c = BIRTH_LW_C
    log_norm = _log_norms(log_std) if lw_mode == 2 else lw_det
    n = 0
    for z in range(nz):
        jz = j[z]
        if lw_mode == 0:
            base = lw_base[z]
        elif lw_mode == 1:
            base = consts[c]
        else:
            base = (((consts[c] + lw_base[z]) - consts[c + 1])
                    - ((-log_norm[z] - consts[c + 2]) - consts[c + 3]))
        lw_det[z] = base - math.log(float(jz if jz > 1 else 1))
        if revive.shape[0] == nz:
            lw_det[z] = lw_det[z] + (log_revive if revive[z] else 0.0)
        n += jz
    birth_fill(Z, j, lw_det, st, consts[3], consts[4], consts[5], consts[6], consts[7],
               consts[8], consts[9], states, log_w, det)     # (writes their first n rows)
    return j, n


#: where :func:`birth_alloc_fill`'s ``consts`` hold the newborn weight's constants ``lw_c``
BIRTH_LW_C = 10


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def mass_near_skip(states, w, Z, std_z, skip, r2):
    """``filter.mass_near(..., skip=skip)`` in one call: the grid cells of ``filter._grid_cell``
    (:func:`grid_cell`: ``2 r`` times the per-axis median of ``std_z[:, :2]`` over every
    detection, 1 where not > 0), then
    :func:`mass_near_few` on the detections not skipped, scattered back (0 at the skipped).
    Returns ``(code, out)``: 1 done, 0 non-finite particle positions."""
    nz = Z.shape[0]
    full = np.empty(nz, np.float64)
    for j in range(nz):
        full[j] = 0.0
    cell = grid_cell(std_z, r2)
    cx, cy = cell[0], cell[1]
    m = np.int64(0)
    for j in range(nz):
        m += not skip[j]
    if m == 0:
        return 1, full
    need = np.empty(m, np.int64)
    k = np.int64(0)
    for j in range(nz):
        if not skip[j]:
            need[k] = j
            k += 1
    Zn = np.empty((m, Z.shape[1]))
    sn = np.empty((m, std_z.shape[1]))
    for k in range(m):
        for c in range(Z.shape[1]):
            Zn[k, c] = Z[need[k], c]
        for c in range(std_z.shape[1]):
            sn[k, c] = std_z[need[k], c]
    ok, part = mass_near_few(states, w, Zn, sn, r2, cx, cy)
    if not ok:
        return 0, full
    for k in range(m):
        full[need[k]] = part[k]
    return 1, full


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def mass_near_two(states, w, Z, std_z, r2, cell_x, cell_y, std_wide, skip):
    """:func:`mass_near_kernel` (``std_z``, ``r2``, cells ``(cell_x, cell_y)``) and
    :func:`mass_near_skip` (``std_wide``, ``skip``, the same ``r2``) in one pass over the
    particles: ``(code, out, grid, near)``, ``code`` 1 done, 0 non-finite particle positions.
    The birth's M(z) and κ_n's M'(z) of one frame (:meth:`.filter.SceneModel.log_kappa`):
    with ``std_wide = 2 std_z`` (:data:`.clutter.NEAR_SCALE`) M'(z)'s grid cells are twice
    M(z)'s, and both grids grow from the particles' same minima by doubling, so M'(z)'s grid
    is M(z)'s grown grid (when that grew at least once) or its cells merged 2 × 2 (a power of
    two scales a float exactly: a particle's cell there is its cell here halved, rounded
    down); its sums then run over M(z)'s buckets in mass_near_few's order (cell key, then
    particle index: the merged cells' runs merged by index), so the very floats of both calls
    -- without mass_near_skip's two passes over every particle.  Other wide cells (a cell
    of 1 where a median is not > 0, NaN stds): mass_near_skip itself."""
    return mass_near_two_at(states, w, Z, std_z, r2, cell_x, cell_y, std_wide, skip,
                            np.empty(0))


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def mass_near_two_at(states, w, Z, std_z, r2, cell_x, cell_y, std_wide, skip, ext):
    """:func:`mass_near_two` with the positions' extent ``ext`` (:func:`grid_build_at`; empty:
    none known): the same floats and grid."""
    ok, out, grid = _mass_near_at(states, w, Z, std_z, r2, cell_x, cell_y, ext)
    if not ok:
        return 0, out, grid, out
    nz = Z.shape[0]
    cw = grid_cell(std_wide, r2)
    if not (cw[0] == 2.0 * cell_x and cw[1] == 2.0 * cell_y) or nz == 0 \
            or states.shape[0] == 0:
        code, near = mass_near_skip(states, w, Z, std_wide, skip, r2)
        return code, out, grid, near
    x0, y0, cx, cy, ni, nj, order, starts = grid
    near = np.empty(nz, np.float64)
    for j in range(nz):
        near[j] = 0.0
    r = math.sqrt(r2)
    ws = 1 if w.shape[0] == states.shape[0] else 0
    if cx != cell_x or cy != cell_y:
        # the grid grew: M'(z)'s grid is this one
        for j in range(nz):
            if not skip[j]:
                near[j] = _weight_in_gate(states, w, ws, Z, j, std_wide, r, r2, x0, cx, ni, y0,
                                          cy, nj, order, starts)
        return 1, out, grid, near
    # M'(z)'s grid: these cells merged 2 x 2 (its cell of a particle is ours // 2)
    wx, wy = 2.0 * cx, 2.0 * cy
    wi, wj = (ni - 1) // 2 + 1, (nj - 1) // 2 + 1
    for j in range(nz):
        if skip[j]:
            continue
        i0, i1, j0, j1 = gate_cells(Z[j, 0], Z[j, 1], std_wide[j, 0], std_wide[j, 1], r,
                                    x0, wx, wi, y0, wy, wj)
        c = _gate_consts(Z, j, std_wide, r2)
        s = 0.0
        for ci in range(i0, i1 + 1):
            # the two rows of our cells in this wide row
            ra = 2 * ci
            rb = ra + 1
            for cj in range(j0, j1 + 1):
                ca = 2 * cj
                cb = ca + 2 if ca + 2 <= nj else nj
                a, a_end = starts[ra * nj + ca], starts[ra * nj + cb]
                b, b_end = a_end, a_end             # (no second row: empty runs)
                if rb < ni:
                    b, b_end = starts[rb * nj + ca], starts[rb * nj + cb]
                # each row's run holds two cells, each sorted by index: four sorted runs
                am = starts[ra * nj + ca + 1] if ca + 1 < cb else a_end
                bm = b_end
                if rb < ni:
                    bm = starts[rb * nj + ca + 1] if ca + 1 < cb else b_end
                p0, e0, p1, e1, p2, e2, p3, e3 = a, am, am, a_end, b, bm, bm, b_end
                while True:
                    best = -1
                    bi = np.int64(0)
                    if p0 < e0:
                        best, bi = 0, order[p0]
                    if p1 < e1 and (best < 0 or order[p1] < bi):
                        best, bi = 1, order[p1]
                    if p2 < e2 and (best < 0 or order[p2] < bi):
                        best, bi = 2, order[p2]
                    if p3 < e3 and (best < 0 or order[p3] < bi):
                        best, bi = 3, order[p3]
                    if best < 0:
                        break
                    if best == 0:
                        p0 += 1
                    elif best == 1:
                        p1 += 1
                    elif best == 2:
                        p2 += 1
                    else:
                        p3 += 1
                    s += w[bi * ws] if _in_gate_fast(states, bi, c, r2) else 0.0
        near[j] = s
    return 1, out, grid, near


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def birth_fill(Z, j, lw_det, st, sigma_obs, sigma_min, pos_ratio, spread, speed_mean,
               speed_std, min_size, states, log_w, det):
    """The J = Σ j newborn into ``states[:J]`` (J, 6), ``log_w[:J]``, ``det[:J]``: detection
    z's ``j[z]`` rows get ``(y, w, h) = z + spread σ(z) ε``, velocity
    ``(mean + std n) sqrt(w_z h_z) (cos θ, sin θ)``, sizes clipped to ``min_size``, log-weight
    ``lw_det[z]``.  Newborn k's draws (k counts over all detections), of the key
    ``K = st[0]`` (:mod:`~trackers.smc.random`): ε its normals 4k … 4k + 3 of K, n normal k of
    ``subkey(K, 0)``, θ the direction of word k of ``subkey(K, 1)``.  The draws of ``_CHUNK``
    newborn at a time are made in vectorised loops, then used."""
    key = st[0]
    key_n = subkey(key, 0)
    key_d = subkey(key, 1)
    n_all = 0
    for z in range(Z.shape[0]):
        n_all += j[z]
    buf = np.empty((8, _CHUNK))
    e0, e1, e2, e3, n0, n1, dc, ds = buf[0], buf[1], buf[2], buf[3], buf[4], buf[5], \
        buf[6], buf[7]
    k = 0
    for z in range(Z.shape[0]):
        sw = sigma_obs * Z[z, 2]
        sw = sigma_min if sigma_min > sw else sw      # max(sw, sigma_min), spelt out
        sh = sigma_obs * Z[z, 3]
        sh = sigma_min if sigma_min > sh else sh
        s0 = spread * (pos_ratio * sw)
        s1 = spread * (pos_ratio * sh)
        s2 = spread * sw
        s3 = spread * sh
        scale = math.sqrt(Z[z, 2] * Z[z, 3])
        z0, z1, z2, z3, lw = Z[z, 0], Z[z, 1], Z[z, 2], Z[z, 3], lw_det[z]
        for _ in range(j[z]):
            c = k % _CHUNK
            if c == 0:                             # the next chunk's draws (_CHUNK even)
                m = min(_CHUNK, n_all - k)
                p0 = np.uint64(2 * k)
                normal_pairs_into(key, p0, np.uint64(2), e0, e1, m)
                normal_pairs_into(key, p0 + np.uint64(1), np.uint64(2), e2, e3, m)
                normal_pairs_into(key_n, np.uint64(k // 2), np.uint64(1), n0, n1, (m + 1) // 2)
                directions_into(key_d, np.uint64(k), dc, ds, m)
            if k + _AHEAD < n_all:
                _prefetch_write(states, k + _AHEAD)
            states[k, 0] = z0 + s0 * e0[c]
            states[k, 1] = z1 + s1 * e1[c]
            ww = z2 + s2 * e2[c]
            hh = z3 + s3 * e3[c]
            states[k, 4] = ww if not ww < min_size else min_size
            states[k, 5] = hh if not hh < min_size else min_size
            n = n0[c // 2] if c % 2 == 0 else n1[c // 2]
            speed = (speed_mean + speed_std * n) * scale
            states[k, 2] = speed * dc[c]
            states[k, 3] = speed * ds[c]
            log_w[k] = lw
            det[k] = z
            k += 1


# ----------------------------------------------------------------------------- update

@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _gate_d2_inv(states, i, Z, j, inv, k, r2):
    """:func:`_gate_d2` with the inverse stds ``inv`` (multiplications, not divisions)."""
    q0 = (states[i, 0] - Z[j, 0]) * inv[k, 0]
    q1 = (states[i, 1] - Z[j, 1]) * inv[k, 1]
    d2 = q0 * q0 + q1 * q1
    if not d2 <= r2:
        return np.inf
    q2 = (states[i, 4] - Z[j, 2]) * inv[k, 2]
    q3 = (states[i, 5] - Z[j, 3]) * inv[k, 3]
    d2 = d2 + q2 * q2 + q3 * q3
    return d2 if d2 <= r2 else np.inf


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _lse_add(m, s, a):
    """Online log-sum-exp: the pair (shift m, sum s) with log Σ = m + log s, plus term a."""
    if s == 0.0:
        return a, 1.0
    if a <= m:
        return m, s + math.exp(a - m)
    return a, s * math.exp(m - a) + 1.0


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _d2_at(states, i, z0, z1, z2, z3, a0, a1, a2, a3):
    """:func:`_gate_d2_inv`'s sum of one detection ``z`` (inverse stds ``a``) without its
    tests: ``((q0² + q1²) + q2²) + q3²``, the same float."""
    q0 = (states[i, 0] - z0) * a0
    q1 = (states[i, 1] - z1) * a1
    q2 = (states[i, 4] - z2) * a2
    q3 = (states[i, 5] - z3) * a3
    return q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3


#: the linear-domain route of :func:`gauss_update` needs every finite weight within e^-600 of
#: the largest (no underflow) and every factor ψ/(κ + C) / g below e^600 (no overflow)
_LIN_RANGE = 600.0


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def gauss_update_linear(states, lw, Z, std, log_std, log_kappa, log_pd, log_pm, r2,
                        cell_x, cell_y, n_grid, grid, j_born, equal):
    """:func:`gauss_update`'s linear route alone (per-detection stds), the same floats:
    ``(ok, done, bracket, log_c, log_mass, log_pred, lin, scale, log_share)``, ``bracket`` (N,) each
    particle's ``p_M + Σ_z ψ_z/(κ_z + C_z)`` (:func:`bracket_log_weights` makes the new
    log-weights of it, only when someone reads them: a run reads the mass and ``lin``),
    ``lin · scale`` (N,) the normalised weights ``e^{new_lw − log_mass}`` as the update's sums
    made them (for the resampling walk: no exp a particle there); ``done`` False when the
    weights span more than e^600 (nothing computed: call :func:`gauss_update`); ``log_share``
    (N_z,) ``log C − log(κ + C)``, the log of the mass each detection wins, with ``log(κ + C)``
    as numpy's ``np.logaddexp(log_kappa, log_c)`` (its formula, libm's exp and log1p), 0 where
    not finite (κ = C = 0: the filter's ``np.where``), and the subtraction numpy's (the
    filter's ``np.exp`` of it is the share: one numpy call where there were two).  A run whose weights never
    spread that wide compiles this kernel only, not the log-space route (first-run compile).

    A detection's gated pairs come from two kinds of rows: the first ``n_grid`` through
    ``grid`` (:func:`grid_build` of their positions, as :func:`mass_near_kernel` returns it for
    the predicted particles; built here with cells ``cell_x × cell_y`` when its ``order`` does
    not hold ``n_grid`` points), then ``len(j_born)`` blocks of ``j_born[z]`` rows each (the
    newborn of each detection, rows ``n_grid ...``, which must end at ``N``), a block looked at
    only when the bounding box of its positions meets the detection's gate box.  So the
    filter buckets its particles once a frame; with ``n_grid = N`` and no block this is the
    one grid on every particle.  ``equal``: the caller knows the first ``n_grid`` log-weights
    equal (the persistent particles after an equal-weights resampling and the prediction's
    common factor): their largest and smallest is the first, not a pass over them.  The
    weights' largest and smallest otherwise come with the blocks' boxes (the newborn's in the
    pass that reads their positions)."""
    n = states.shape[0]
    nz = Z.shape[0]
    log_c = np.empty(nz, np.float64)
    for j in range(nz):
        log_c[j] = -np.inf
    # the blocks' ends (each detection's newborn after the grid's n_grid rows)
    n_blk = j_born.shape[0]
    b_end = np.empty(n_blk + 1, np.int64)
    b_end[0] = n_grid
    for z in range(n_blk):
        b_end[z + 1] = b_end[z] + j_born[z]
    fits = b_end[n_blk] == n and n_grid >= 0
    top = -np.inf
    low = np.inf
    scan_from = 0
    if equal and fits and n_grid > 0:
        scan_from = n_grid
        if lw[0] > -np.inf:
            top = lw[0]
            low = lw[0]
    for i in range(scan_from, n_grid if fits else n):
        if lw[i] > -np.inf:
            v = lw[i]                     # max(top, v), min(low, v), spelt out
            top = v if v > top else top
            low = v if v < low else low
    # the blocks' bounding boxes (y1 lo, hi, y2 lo, hi; an empty block's never meets a gate)
    # and the newborn's largest and smallest weights in the same pass
    box = np.empty((n_blk, 4), np.float64)
    finite = True
    for z in range(n_blk if fits else 0):
        lo0 = np.inf
        hi0 = -np.inf
        lo1 = np.inf
        hi1 = -np.inf
        for i in range(b_end[z], b_end[z + 1]):
            a = states[i, 0]
            c = states[i, 1]
            finite = finite and math.isfinite(a) and math.isfinite(c)
            lo0 = a if a < lo0 else lo0
            hi0 = a if a > hi0 else hi0
            lo1 = c if c < lo1 else lo1
            hi1 = c if c > hi1 else hi1
            if lw[i] > -np.inf:
                v = lw[i]
                top = v if v > top else top
                low = v if v < low else low
        box[z, 0] = lo0
        box[z, 1] = hi0
        box[z, 2] = lo1
        box[z, 3] = hi1
    if not (top > -np.inf and top - low <= _LIN_RANGE and top < np.inf):
        return True, False, lw, log_c, -np.inf, -np.inf, lw, 0.0, log_c
    x0, y0, cx, cy, ni, nj, order, starts = grid
    if order.shape[0] != n_grid:
        ok, x0, y0, cx, cy, ni, nj, order, starts = grid_build(states[:n_grid, 0],
                                                               states[:n_grid, 1],
                                                               cell_x, cell_y)
        if not ok:
            return False, True, lw, log_c, -np.inf, -np.inf, lw, 0.0, log_c
    if not (finite and fits):
        return False, True, lw, log_c, -np.inf, -np.inf, lw, 0.0, log_c
    inv = np.empty((std.shape[0], 4), np.float64)
    for k in range(std.shape[0]):
        for d in range(4):
            inv[k, d] = 1.0 / std[k, d]
    log_norm = _log_norms(log_std)
    r = math.sqrt(r2)
    e = np.empty(n, np.float64)
    b = np.empty(n, np.float64)
    pm = math.exp(log_pm)
    prev = np.nan                         # e^{lw - top} once per run of equal weights (the
    ev = 0.0                              # persistent particles share one, each detection's
    i_from = 0                            # newborn another): the same floats, ~N_z + 1 exps
    if equal and n_grid > 0:
        prev = lw[0]
        ev = math.exp(prev - top)
        for i in range(n_grid):           # (known equal: no compare a particle)
            e[i] = ev
            b[i] = pm
        i_from = n_grid
    for i in range(i_from, n):
        if lw[i] != prev:
            prev = lw[i]
            ev = math.exp(prev - top)
        e[i] = ev
        b[i] = pm
    buf_i = np.empty(n, np.int64)
    buf_v = np.empty(n, np.float64)
    den = np.empty(nz, np.float64)
    for j in range(nz):
        # C = 0 (no pair, or p_D = 0): log(κ + 0) = np.logaddexp(log κ, -inf), 0 unless finite
        lk = log_kappa[j]
        den[j] = lk if math.isfinite(lk) else 0.0
        i0, i1, j0, j1 = gate_cells(Z[j, 0], Z[j, 1], std[j, 0], std[j, 1], r,
                                    x0, cx, ni, y0, cy, nj)
        hx = r * std[j, 0] * (1.0 + 1e-6) + 1e-9          # gate_cells' box
        hy = r * std[j, 1] * (1.0 + 1e-6) + 1e-9
        s = 0.0
        nb = 0
        z0, z1, z2, z3 = Z[j, 0], Z[j, 1], Z[j, 2], Z[j, 3]
        a0, a1, a2, a3 = inv[j, 0], inv[j, 1], inv[j, 2], inv[j, 3]
        n_col = i1 - i0 + 1 if i1 >= i0 else 0
        for seg in range(n_col + n_blk):  # the grid's columns of cells, then the blocks
            if seg < n_col:
                ci = i0 + seg
                p0 = starts[ci * nj + j0]
                p1 = starts[ci * nj + j1 + 1]
            else:
                z = seg - n_col
                if not (box[z, 0] <= Z[j, 0] + hx and box[z, 1] >= Z[j, 0] - hx
                        and box[z, 2] <= Z[j, 1] + hy and box[z, 3] >= Z[j, 1] - hy):
                    continue
                p0 = b_end[z]
                p1 = b_end[z + 1]
            # the gate test alone first (its d² kept), then the exps and C(z)'s sum over
            # the kept pairs in the same order: the same floats, and tight loops (-20 %)
            # (z and 1/σ in locals: the buffers' stores could alias them for the compiler)
            # branch free: every pair written, kept (nb advanced) when d² <= r2 -- the
            # position terms' own test is implied (adding squares never lowers a float
            # sum) and a NaN is not kept; a detection tests each row once, so nb < N
            if seg < n_col:
                for p in range(p0, p1):
                    i = order[p]
                    d2 = _d2_at(states, i, z0, z1, z2, z3, a0, a1, a2, a3)
                    buf_i[nb] = i
                    buf_v[nb] = d2
                    nb += d2 <= r2
            else:
                for p in range(p0, p1):
                    d2 = _d2_at(states, p, z0, z1, z2, z3, a0, a1, a2, a3)
                    buf_i[nb] = p
                    buf_v[nb] = d2
                    nb += d2 <= r2
        # g = e^{−d²/2} of every kept pair (inline exp, vectorised: d² <= r2 keeps its
        # argument in _exp_gate's range), then C(z)'s sum in the pairs' order
        if r2 < 2.0 * EXP_GATE_MAX:
            for q in range(nb):
                buf_v[q] = _exp_gate(-0.5 * buf_v[q])
        else:
            for q in range(nb):
                buf_v[q] = math.exp(-0.5 * buf_v[q])
        for q in range(nb):
            s += buf_v[q] * e[buf_i[q]]
        if not (s > 0.0 and log_pd > -np.inf):
            continue                      # C = 0: ψ = 0 on every pair of z
        log_scale = log_pd - log_norm[j] - _HALF_LOG_2PI_4    # log ψ = log_scale − d²/2
        log_c[j] = math.log(s) + top + log_scale
        lk = log_kappa[j]
        lc = log_c[j]
        hi = lc if lc > lk else lk        # max(lk, lc), min(lk, lc), spelt out
        lo = lc if lc < lk else lk
        log_den = hi + math.log1p(math.exp(lo - hi))
        den[j] = log_den if math.isfinite(log_den) else 0.0
        log_f = log_scale - log_den       # ψ/(κ + C) = f e^{−d²/2}
        if log_f <= _LIN_RANGE:
            f = math.exp(log_f)
            for q in range(nb):
                b[buf_i[q]] += f * buf_v[q]
        else:
            for q in range(nb):
                b[buf_i[q]] += math.exp(math.log(buf_v[q]) + log_f)
    # the predicted mass's sum and the updated one's in one pass (two independent chains of
    # adds: each in index order, as two passes would make them)
    tot_pred = 0.0
    tot = 0.0
    for i in range(n):
        ei = e[i]
        tot_pred += ei
        v = ei * b[i]
        tot += v
        e[i] = v                          # the linear weight, e^{new_lw − top}
    log_pred = top + math.log(tot_pred) if tot_pred > 0.0 else -np.inf
    for j in range(nz):                   # log C − log(κ + C): numpy's subtraction
        den[j] = log_c[j] - den[j]
    return (True, True, b, log_c, (top + math.log(tot)) if tot > 0.0 else -np.inf,
            log_pred, e, 1.0 / tot if tot > 0.0 else 0.0, den)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True,
      no_cpython_wrapper=True)
def _bracket_logs(lw, b, log_pm):
    """The new log-weights ``lw + log b`` of :func:`gauss_update_linear`'s bracket ``b``
    (``lw + log p_M`` where no detection reached the particle, -inf where ``b`` is 0): the
    kernel route of :func:`bracket_log_weights`, for :func:`gauss_update`."""
    n = lw.shape[0]
    new_lw = np.empty(n, np.float64)
    pm = math.exp(log_pm)
    log_pm_b = math.log(pm) if pm > 0.0 else -np.inf
    for i in range(n):
        if b[i] == pm:
            new_lw[i] = lw[i] + log_pm_b
        elif b[i] > 0.0:
            new_lw[i] = lw[i] + math.log(b[i])
        else:
            new_lw[i] = -np.inf
    return new_lw


def bracket_log_weights(lw: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`_bracket_logs` in numpy, ``lw + log b`` (the kernel's floats: its p_M branch
    only skips a log of the same value, ``log`` is the C library's on both sides, log 0 =
    -inf), for a reader of the updated set's log-weights (particle-level stage data): a
    normal run never reads them, and this compiles nothing on a first run."""
    with np.errstate(divide="ignore"):
        return lw + np.log(b)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def gauss_update(states, lw, Z, std, log_std, by_det, log_kappa, log_pd, log_pm, r2,
                 cell_x, cell_y):
    """Eq. (5) of maggio2007 with the Gaussian g(z|x) of §2/§4 on the pairs inside the gate
    ``d² <= r2`` (``d² = Σ_d ((x_d − z_d)/σ_d)²`` on the observed columns (0, 1, 4, 5)).

    ``std`` (N_z, 4) and ``log_std`` its numpy ``log`` per detection (``by_det``) or (N, 4)
    per particle; ``log g = −d²/2 − log_norm − 2 log 2π`` with ``log_norm = Σ log σ``
    (:func:`_log_norms`, numpy's sum).  Returns
    ``(ok, new_lw (N,), log_c (N_z,), log_mass, log_pred)`` with
    ``log C(z) = log Σ_i (1 − p_M) g(z|x_i) ω_i``, ``new_lw = lw + log[p_M + Σ_z ψ_z/(κ_z + C_z)]``
    (κ = C = 0: the term is 0), ``log_mass = log Σ_i exp(new_lw_i)`` and ``log_pred`` the same
    sum over ``lw`` (the predicted mass M_{k|k-1}).  The Mahalanobis
    distances multiply by the inverse stds (float reordering against the dense reference).

    Two routes, the same sums: with per-detection stds and weights within e^600 of each other
    (every PHD frame), in linear space -- ``e^{−d²/2}`` once per pair serves both C(z) and the
    bracket, the weights ``e^{lw − max}`` once per particle, one log per particle; otherwise
    in log space (online log-sum-exps: two exps per pair).  The linear route is
    :func:`gauss_update_linear` (called first here; :func:`..filter.update` calls it alone
    when it can, so a first run compiles the log route only if a frame needs it)."""
    if by_det:
        ok, done, b, log_c, log_mass, log_pred, _, _, _ = gauss_update_linear(
            states, lw, Z, std, log_std, log_kappa, log_pd, log_pm, r2, cell_x, cell_y,
            states.shape[0], (0.0, 0.0, cell_x, cell_y, 0, 0, np.empty(0, np.int64),
                              _zero_start()), np.empty(0, np.int64), False)
        if done:
            return ok, _bracket_logs(lw, b, log_pm) if ok else b, log_c, log_mass, log_pred
    n = states.shape[0]
    nz = Z.shape[0]
    log_c = np.empty(nz, np.float64)
    for j in range(nz):
        log_c[j] = -np.inf
    new_lw = lw.copy()
    ok, x0, y0, cx, cy, ni, nj, order, starts = grid_build(states[:, 0], states[:, 1],
                                                           cell_x, cell_y)
    if not ok:
        return False, new_lw, log_c, -np.inf, -np.inf
    inv = np.empty_like(std)
    for k in range(std.shape[0]):
        for d in range(4):
            inv[k, d] = 1.0 / std[k, d]
    log_norm = _log_norms(log_std)
    r = math.sqrt(r2)
    hx_all = 0.0
    hy_all = 0.0
    if not by_det:
        for i in range(n):
            hx_all = max(hx_all, std[i, 0])
            hy_all = max(hy_all, std[i, 1])
    top = -np.inf
    for i in range(n):
        if lw[i] > -np.inf:
            top = max(top, lw[i])
    tot_pred = 0.0
    for i in range(n):
        tot_pred += math.exp(lw[i] - top) if top > -np.inf else 0.0
    log_pred = top + math.log(tot_pred) if tot_pred > 0.0 else -np.inf
    sh = np.zeros(n, np.float64)
    sm = np.zeros(n, np.float64)
    if log_pm > -np.inf:
        for i in range(n):
            sh[i] = log_pm
            sm[i] = 1.0
    # one detection at a time: its gated pairs once (C(z); their log ψ kept in a buffer of at
    # most N), then ψ/(κ + C) into each of those particles' brackets
    buf_i = np.empty(n, np.int64)
    buf_v = np.empty(n, np.float64)
    for j in range(nz):
        sx, sy = (std[j, 0], std[j, 1]) if by_det else (hx_all, hy_all)
        i0, i1, j0, j1 = gate_cells(Z[j, 0], Z[j, 1], sx, sy, r, x0, cx, ni, y0, cy, nj)
        m = -np.inf
        s = 0.0
        nb = 0
        for ci in range(i0, i1 + 1):
            for p in range(starts[ci * nj + j0], starts[ci * nj + j1 + 1]):
                i = order[p]
                k = j if by_det else i
                d2 = _gate_d2_inv(states, i, Z, j, inv, k, r2)
                if not d2 <= r2:
                    continue
                buf_i[nb] = i
                log_psi = log_pd + (-0.5 * d2 - log_norm[k] - _HALF_LOG_2PI_4)
                buf_v[nb] = log_psi
                a = log_psi + lw[i]
                if a > -np.inf:
                    m, s = _lse_add(m, s, a)
                nb += 1
        if not (s > 0.0 and log_pd > -np.inf):
            continue                      # C = 0: ψ = 0 on every pair of z
        log_c[j] = m + math.log(s)
        lk = log_kappa[j]
        lc = log_c[j]
        hi = max(lk, lc)
        log_den = hi + math.log1p(math.exp(min(lk, lc) - hi))
        for q in range(nb):
            t = buf_v[q] - log_den
            if t > -np.inf:
                i = buf_i[q]
                sh[i], sm[i] = _lse_add(sh[i], sm[i], t)
    top = -np.inf
    for i in range(n):
        if sm[i] > 0.0:
            new_lw[i] = lw[i] + (sh[i] + math.log(sm[i]))
        else:
            new_lw[i] = -np.inf
        top = max(top, new_lw[i])
    if not top > -np.inf:
        return True, new_lw, log_c, -np.inf, log_pred
    tot = 0.0
    for i in range(n):
        tot += math.exp(new_lw[i] - top)
    return True, new_lw, log_c, top + math.log(tot), log_pred
