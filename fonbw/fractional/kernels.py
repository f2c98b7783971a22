"""Compiled history sums of the fractional operators (numba, ``cache=True``).

The kernels evaluate the history part h_k of the affine form (*) of
:mod:`fonbw.fractional` and push a sample into an operator's state, on the
flat blocks laid out in :mod:`fonbw.fractional.operators`. Their inner loops
are explicit SIMD intrinsics with a fixed summation order, so the result is
the same wherever numba inlines them (stepper, batch and population runs
give bit-identical numbers).
"""
from __future__ import annotations

import numpy as np
import numba as nb
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

from .operators import KIND_GL, FracOp, pack


@nb.njit(cache=True, inline="always")
def _sizes(P, o):
    """(W, M, m, parameter-block length, state-block length) of the operator at P[o]."""
    W = int(P[o + 2])
    M = int(P[o + 3])
    m = int(P[o + 4])
    psize = 5 + W + 2 * M + m * m + 2 * m
    ssize = 3 + 2 * max(W, 1) + (M if P[o] == KIND_GL else 2 * m)
    return W, M, m, psize, ssize


#: Index type of the kernels: unsigned, so numba emits no negative-index
#: wraparound (a compare and a select on every access, which also blocks
#: vectorization).
_U = nb.uint64


@nb.njit(cache=True, inline="always")
def op_desc(P, o, q):
    """Descriptor of the operator with parameter block at ``P[o]`` and state
    block at ``S[q]``, built once per run (or once per stepper call).

    Returns ``(kind, W, M, m, ow, oc, orr, oA, oB, oC, q, qb, qz, a, Wf)``:
    sizes, offsets of w, c, r, A, B, C in P, of the counters, ring buffer and
    modes in S (all unsigned), the coefficient ``a`` of the current sample in
    (*), and W as a float (for comparing with the float counter). The ring holds the newest sample at ``qb + pos`` and lag j at
    ``qb + pos + j − 1`` with a mirrored copy behind, so the window is always
    contiguous.
    """
    W, M, m, _, _ = _sizes(P, o)
    ow = o + 5
    oc = ow + W
    orr = oc + M
    oA = orr + M
    oB = oA + m * m
    oC = oB + m
    qb = q + 3
    qz = qb + 2 * max(W, 1)
    return (int(P[o]), _U(W), _U(M), _U(m), _U(ow), _U(oc), _U(orr), _U(oA), _U(oB), _U(oC),
            _U(q), _U(qb), _U(qz), P[o + 1], float(W))


# Explicit SIMD for the two inner loops. Without fastmath LLVM vectorizes no
# floating-point reduction (it may not reassociate), and fastmath would let
# the summation order depend on where the compiler inlines the loop, which
# would break the bit-identity of stepper and batch runs. These intrinsics
# emit the vector IR directly: eight lane accumulators (two <4 x double>),
# lane t summing the terms j ≡ t (mod 8), combined in a fixed tree. Every
# operation is a plain IEEE add or multiply (no contraction into fma), so the
# result is the same wherever it is inlined, with or without AVX.

_F64 = ir.DoubleType()
_V4 = ir.VectorType(_F64, 4)
_V4ZERO = ir.Constant(_V4, [ir.Constant(_F64, 0.0)] * 4)


def _v4ptr(builder, base, off):
    return builder.bitcast(builder.gep(base, [off]), _V4.as_pointer())


def _lanes_sum(builder, v0, v1):
    """((s0+s1)+(s2+s3)) + ((s4+s5)+(s6+s7)) of the lanes of v0 ‖ v1."""
    s = [builder.extract_element(v, ir.Constant(ir.IntType(32), t)) for v in (v0, v1) for t in range(4)]
    return builder.fadd(builder.fadd(builder.fadd(s[0], s[1]), builder.fadd(s[2], s[3])),
                        builder.fadd(builder.fadd(s[4], s[5]), builder.fadd(s[6], s[7])))


@intrinsic
def _vdot8(typingctx, a, ao, b, bo, nblk):
    """Σ_{j<8·nblk} a[ao+j] b[bo+j] in eight lanes (see above); unsigned offsets."""
    sig = types.float64(a, ao, b, bo, nblk)

    def codegen(context, builder, signature, args):
        av, ao_, bv, bo_, n_ = args
        pa = builder.gep(context.make_array(signature.args[0])(context, builder, av).data, [ao_])
        pb = builder.gep(context.make_array(signature.args[2])(context, builder, bv).data, [bo_])
        acc0 = cgutils.alloca_once_value(builder, _V4ZERO)
        acc1 = cgutils.alloca_once_value(builder, _V4ZERO)
        i64 = n_.type
        with cgutils.for_range(builder, n_) as loop:
            o0 = builder.shl(loop.index, ir.Constant(i64, 3))
            o1 = builder.add(o0, ir.Constant(i64, 4))
            p0 = builder.fmul(builder.load(_v4ptr(builder, pa, o0), align=8),
                              builder.load(_v4ptr(builder, pb, o0), align=8))
            p1 = builder.fmul(builder.load(_v4ptr(builder, pa, o1), align=8),
                              builder.load(_v4ptr(builder, pb, o1), align=8))
            builder.store(builder.fadd(builder.load(acc0), p0), acc0)
            builder.store(builder.fadd(builder.load(acc1), p1), acc1)
        return _lanes_sum(builder, builder.load(acc0), builder.load(acc1))

    return sig, codegen


@intrinsic
def _vmodes8(typingctx, P, oc, orr, S, qz, nblk, old):
    """For i < 8·nblk: z_i ← r_i (z_i + old) (z at S[qz+i], r at P[orr+i]);
    returns Σ c_i z_i (c at P[oc+i]) in eight lanes (see above)."""
    sig = types.float64(P, oc, orr, S, qz, nblk, old)

    def codegen(context, builder, signature, args):
        Pv, oc_, or_, Sv, qz_, n_, old_ = args
        pdata = context.make_array(signature.args[0])(context, builder, Pv).data
        pc = builder.gep(pdata, [oc_])
        pr = builder.gep(pdata, [or_])
        pz = builder.gep(context.make_array(signature.args[3])(context, builder, Sv).data, [qz_])
        vold = cgutils.alloca_once_value(builder, _V4ZERO)
        v = builder.load(vold)
        for t in range(4):
            v = builder.insert_element(v, old_, ir.Constant(ir.IntType(32), t))
        acc0 = cgutils.alloca_once_value(builder, _V4ZERO)
        acc1 = cgutils.alloca_once_value(builder, _V4ZERO)
        i64 = n_.type
        with cgutils.for_range(builder, n_) as loop:
            for acc, k in ((acc0, 0), (acc1, 4)):
                o = builder.add(builder.shl(loop.index, ir.Constant(i64, 3)), ir.Constant(i64, k))
                zp = _v4ptr(builder, pz, o)
                z = builder.fmul(builder.load(_v4ptr(builder, pr, o), align=8),
                                 builder.fadd(builder.load(zp, align=8), v))
                builder.store(z, zp, align=8)
                builder.store(builder.fadd(builder.load(acc),
                                           builder.fmul(builder.load(_v4ptr(builder, pc, o), align=8), z)), acc)
        return _lanes_sum(builder, builder.load(acc0), builder.load(acc1))

    return sig, codegen


@nb.njit(cache=True, inline="always")
def _dot_off(a, ao, b, bo, n):
    """Σ_{j<n} a[ao+j] b[bo+j] (unsigned offsets): blocks of eight by
    :func:`_vdot8`, then the remainder in order."""
    nb8 = n >> _U(3)
    s = _vdot8(a, ao, b, bo, nb8) if nb8 > _U(0) else 0.0
    j = nb8 << _U(3)
    while j < n:
        s += a[ao + j] * b[bo + j]
        j += _U(1)
    return s


@nb.njit(cache=True, inline="always")
def _modes_push(P, oc, orr, S, qz, M, old):
    """z_i ← r_i (z_i + old) for the M modes; returns the new Σ c_i z_i
    (blocks of eight by :func:`_vmodes8`, then the remainder in order)."""
    nb8 = M >> _U(3)
    s = _vmodes8(P, oc, orr, S, qz, nb8, old)
    i = nb8 << _U(3)
    while i < M:
        z = P[orr + i] * (S[qz + i] + old)
        s += P[oc + i] * z
        S[qz + i] = z
        i += _U(1)
    return s


@nb.njit(cache=True, inline="always")
def op_history(P, S, d):
    """History part h_k of (*) from the state before step k (descriptor ``d``)."""
    kind, W, M, m, ow, oc, orr, oA, oB, oC, q, qb, qz, a, Wf = d
    if kind == KIND_GL:
        # the counters are floats in S (one state array); they are converted
        # through int64, which is one instruction, unlike float <-> uint64
        cnt = S[q + _U(1)]
        n = W if cnt >= Wf else _U(int(cnt))
        return _dot_off(P, ow, S, qb + _U(int(S[q])), n) + S[q + _U(2)]
    return S[q + _U(2)]


@nb.njit(cache=True, inline="always")
def op_push(P, S, d, x):
    """Advance the operator's state with the sample x_k (descriptor ``d``)."""
    kind, W, M, m, ow, oc, orr, oA, oB, oC, q, qb, qz, a, Wf = d
    if kind == KIND_GL:
        pos = _U(int(S[q]))
        if pos == _U(0):
            pos = W
        pos -= _U(1)
        if M > _U(0):
            # S[qb+pos] still holds lag W, the sample leaving the exact window
            S[q + _U(2)] = _modes_push(P, oc, orr, S, qz, M, S[qb + pos])
        S[qb + pos] = x
        S[qb + pos + W] = x
        S[q] = float(nb.int64(pos))
    else:
        qt = qz + m  # scratch: z ← A z + B x needs the old z throughout
        for i in range(m):
            S[qt + i] = P[oB + i] * x + _dot_off(P, oA + i * m, S, qz, m)
        for i in range(m):
            S[qz + i] = S[qt + i]
        S[q + _U(2)] = _dot_off(P, oC, S, qz, m)
    S[q + _U(1)] += 1.0


@nb.njit(cache=True)
def _apply_op(P, x):
    out = np.empty(x.shape[0])
    _, _, _, _, ss = _sizes(P, 0)
    S = np.zeros(ss)
    d = op_desc(P, 0, 0)
    a = d[13]
    for k in range(x.shape[0]):
        out[k] = a * x[k] + op_history(P, S, d)
        op_push(P, S, d, x[k])
    return out


def apply_op(op: FracOp, x) -> np.ndarray:
    """Run an operator over a whole explicit signal (zero before the first sample)."""
    x = np.ascontiguousarray(x, dtype=float)
    if op.growable and len(x) > op.window:
        op = op.grown(len(x))
    return _apply_op(pack(op), x)
