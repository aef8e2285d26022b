"""Sum of absolute differences of two 16-byte descriptors, as one vector operation.

:func:`sad16` is a numba intrinsic that emits target-independent LLVM IR: load two
``<16 x i8>`` vectors, ``umax - umin`` (the per-byte absolute difference),
zero-extend and add-reduce. On x86 LLVM turns this into a single ``psadbw``; on
other targets into their own absolute-difference-and-accumulate instructions.
A plain loop is what numba would otherwise emit, and it does not vectorise
(about 10x slower), which is why this one function is written in IR.

:func:`sad64` does the same over 64 bytes (the four descriptors of a support
candidate). :func:`sad16x4_store` gives the four 16-byte SADs of 64 bytes at once
(dense matching of four neighbouring pixels): there the per-block sums need x86's
``psadbw`` by name (the generic pattern becomes a long zero-extend-and-add chain),
so :func:`psadbw_width` picks the instruction numba's target has, with the generic
IR elsewhere. :func:`first_min4` keeps four running minima in one vector.
:func:`sad_reference` is the plain-loop computation, for tests.
"""
from __future__ import annotations

import platform

import numpy as np
from llvmlite import binding as llvm_binding
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils, config
from numba.extending import intrinsic

#: Bytes per descriptor.
DESC_BYTES = 16

def _llvm_function(module, name, ret, args):
    fn = module.globals.get(name)
    if fn is None:
        fn = ir.Function(module, ir.FunctionType(ret, args), name=name)
    return fn


def _sad_codegen(nbytes):
    """Code generator of an ``nbytes``-wide SAD (a power of two, 16 or more)."""
    vec_i8 = ir.VectorType(ir.IntType(8), nbytes)
    vec_i32 = ir.VectorType(ir.IntType(32), nbytes)

    def codegen(context, builder, signature, args):
        arr_a = context.make_array(signature.args[0])(context, builder, args[0])
        arr_b = context.make_array(signature.args[2])(context, builder, args[2])
        off_a = context.cast(builder, args[1], signature.args[1], types.intp)
        off_b = context.cast(builder, args[3], signature.args[3], types.intp)
        ptr_a = builder.bitcast(builder.gep(arr_a.data, [off_a]), vec_i8.as_pointer())
        ptr_b = builder.bitcast(builder.gep(arr_b.data, [off_b]), vec_i8.as_pointer())
        va = builder.load(ptr_a, align=1)
        vb = builder.load(ptr_b, align=1)
        module = builder.module
        tag = f"v{nbytes}i8"
        hi = builder.call(_llvm_function(module, f"llvm.umax.{tag}", vec_i8, [vec_i8, vec_i8]),
                          [va, vb])
        lo = builder.call(_llvm_function(module, f"llvm.umin.{tag}", vec_i8, [vec_i8, vec_i8]),
                          [va, vb])
        wide = builder.zext(builder.sub(hi, lo), vec_i32)
        reduce_add = _llvm_function(module, f"llvm.vector.reduce.add.v{nbytes}i32",
                                    ir.IntType(32), [vec_i32])
        return builder.call(reduce_add, [wide])

    return codegen


def _sad_signature(a, offset_a, b, offset_b):
    ok = (isinstance(a, types.Array) and a.dtype == types.uint8 and a.ndim == 1
          and isinstance(b, types.Array) and b.dtype == types.uint8 and b.ndim == 1
          and isinstance(offset_a, types.Integer) and isinstance(offset_b, types.Integer))
    return types.int32(a, offset_a, b, offset_b) if ok else None


@intrinsic
def sad16(typingctx, a, offset_a, b, offset_b):
    """``sum_k |a[offset_a + k] - b[offset_b + k]|`` for k = 0..15, as int32.

    ``a`` and ``b`` are 1-D C-contiguous uint8 arrays; the offsets are integers.
    No bounds checking: the caller guarantees ``offset + 16 <= len``.
    """
    sig = _sad_signature(a, offset_a, b, offset_b)
    return (sig, _sad_codegen(16)) if sig is not None else None


@intrinsic
def sad64(typingctx, a, offset_a, b, offset_b):
    """:func:`sad16` over 64 bytes (four descriptors side by side)."""
    sig = _sad_signature(a, offset_a, b, offset_b)
    return (sig, _sad_codegen(64)) if sig is not None else None


def psadbw_width() -> int:
    """Bytes per x86 ``psadbw`` instruction the compiled code may use: 64 (AVX-512BW),
    32 (AVX2), 16 (SSE2, every x86-64), or 0 (not x86: portable IR instead).

    Follows numba's target: a fixed ``NUMBA_CPU_NAME`` (portable caches) gets the
    SSE2 baseline; otherwise the host CPU's features decide (numba's cache is keyed by
    the CPU, so a cache compiled here is not loaded on a CPU without them).
    """
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return 0
    if config.CPU_NAME not in (None, "host"):
        return 16
    features = llvm_binding.get_host_cpu_features()
    if features.get("avx512bw", False):
        return 64
    if features.get("avx2", False):
        return 32
    return 16


PSADBW_WIDTH = psadbw_width()


def _argument_block_sums(context, builder, signature, args):
    """``<4 x i32>`` block SADs of the 64 bytes at ``(a, offset_a)`` and ``(b, offset_b)``,
    an intrinsic's first four arguments (unaligned loads)."""
    vec_i8 = ir.VectorType(ir.IntType(8), 64)
    pa = _element_pointer(context, builder, signature.args[0], args[0], args[1], signature.args[1], vec_i8)
    pb = _element_pointer(context, builder, signature.args[2], args[2], args[3], signature.args[3], vec_i8)
    return _block_sums(builder, builder.load(pa, align=1), builder.load(pb, align=1))


def _block_sums(builder, va, vb):
    """``<4 x i32>``: the SAD of each 16-byte block of two ``<64 x i8>`` vectors."""
    i8, i32, i64 = ir.IntType(8), ir.IntType(32), ir.IntType(64)
    module = builder.module

    def lanes(vec, start, count):
        mask = ir.Constant(ir.VectorType(i32, count), [i32(start + k) for k in range(count)])
        return builder.shuffle_vector(vec, ir.Constant(vec.type, ir.Undefined), mask)

    if PSADBW_WIDTH:
        width = PSADBW_WIDTH
        name = {64: "llvm.x86.avx512.psad.bw.512", 32: "llvm.x86.avx2.psad.bw",
                16: "llvm.x86.sse2.psad.bw"}[width]
        vin = ir.VectorType(i8, width)
        vout = ir.VectorType(i64, width // 8)
        psad = _llvm_function(module, name, vout, [vin, vin])
        parts = [builder.call(psad, [lanes(va, k, width), lanes(vb, k, width)])
                 for k in range(0, 64, width)]
        # concatenate to <8 x i64>: (low, high) half-sums of blocks 0..3
        while len(parts) > 1:
            n = parts[0].type.count
            mask = ir.Constant(ir.VectorType(i32, 2 * n), [i32(k) for k in range(2 * n)])
            parts = [builder.shuffle_vector(parts[k], parts[k + 1], mask)
                     for k in range(0, len(parts), 2)]
        halves = parts[0]
        even = ir.Constant(ir.VectorType(i32, 4), [i32(2 * k) for k in range(4)])
        odd = ir.Constant(ir.VectorType(i32, 4), [i32(2 * k + 1) for k in range(4)])
        undef = ir.Constant(halves.type, ir.Undefined)
        total = builder.add(builder.shuffle_vector(halves, undef, even),
                            builder.shuffle_vector(halves, undef, odd))
        return builder.trunc(total, ir.VectorType(i32, 4))
    vec_i8 = ir.VectorType(i8, 64)
    hi = builder.call(_llvm_function(module, "llvm.umax.v64i8", vec_i8, [vec_i8, vec_i8]), [va, vb])
    lo = builder.call(_llvm_function(module, "llvm.umin.v64i8", vec_i8, [vec_i8, vec_i8]), [va, vb])
    diff = builder.sub(hi, lo)
    reduce_add = _llvm_function(module, "llvm.vector.reduce.add.v16i32", i32,
                                [ir.VectorType(i32, 16)])
    out = ir.Constant(ir.VectorType(i32, 4), [i32(0)] * 4)
    for k in range(4):
        part = builder.zext(lanes(diff, 16 * k, 16), ir.VectorType(i32, 16))
        out = builder.insert_element(out, builder.call(reduce_add, [part]), i32(k))
    return out


def _element_pointer(context, builder, array_type, array, index, index_type, elem_type):
    arr = context.make_array(array_type)(context, builder, array)
    idx = context.cast(builder, index, index_type, types.intp)
    return builder.bitcast(builder.gep(arr.data, [idx]), elem_type.as_pointer())


#: A :func:`sad16x4_store` bonus at least this large masks its lane (cost INT32_MAX).
MASKED = 1 << 30


@intrinsic
def sad16x4_store(typingctx, a, offset_a, b, offset_b, bonus0, bonus1, bonus2, bonus3, out,
                  out_offset):
    """Store the four :func:`sad16` of 16-byte blocks ``k = 0..3`` plus a bonus per block,
    ``sad16(a, offset_a + 16k, b, offset_b + 16k) + bonus_k``, as int32 at
    ``out[out_offset + k]``; a bonus of :data:`MASKED` or more stores INT32_MAX instead.

    One 64-byte load from each uint8 array and x86 ``psadbw`` (one on AVX-512BW,
    two on AVX2, four on SSE2; portable IR elsewhere). No bounds checking: the
    caller guarantees ``offset + 64 <= len`` and ``out_offset + 4 <= len(out)``.
    """
    if _sad_signature(a, offset_a, b, offset_b) is None:
        return None
    bonuses = (bonus0, bonus1, bonus2, bonus3)
    if not (isinstance(out, types.Array) and out.dtype == types.int32 and out.ndim == 1
            and all(isinstance(x, types.Integer) for x in bonuses)
            and isinstance(out_offset, types.Integer)):
        return None
    sig = types.void(a, offset_a, b, offset_b, *bonuses, out, out_offset)

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        vec_i32 = ir.VectorType(i32, 4)
        sums = _argument_block_sums(context, builder, signature, args)
        extra = ir.Constant(vec_i32, ir.Undefined)
        for k in range(4):
            value = context.cast(builder, args[4 + k], signature.args[4 + k], types.int32)
            extra = builder.insert_element(extra, value, i32(k))
        masked = builder.icmp_signed(">=", extra, ir.Constant(vec_i32, [i32(MASKED)] * 4))
        cost = builder.select(masked, ir.Constant(vec_i32, [i32(2147483647)] * 4),
                              builder.add(sums, extra))
        po = _element_pointer(context, builder, signature.args[8], args[8], args[9],
                              signature.args[9], vec_i32)
        builder.store(cost, po, align=4)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def sad16x4_store_outside(typingctx, a, offset_a, b, offset_b, d, mu0, mu1, mu2, mu3, radius,
                          out, out_offset):
    """:func:`sad16x4_store` of candidate disparity ``d`` with block ``k`` masked
    (INT32_MAX) where ``|d - mu_k| <= radius`` (inside that pixel's plane window) and no
    bonus elsewhere; the masks are one vector compare."""
    if _sad_signature(a, offset_a, b, offset_b) is None:
        return None
    scalars = (d, mu0, mu1, mu2, mu3, radius, out_offset)
    if not (isinstance(out, types.Array) and out.dtype == types.int32 and out.ndim == 1
            and all(isinstance(x, types.Integer) for x in scalars)):
        return None
    sig = types.void(a, offset_a, b, offset_b, d, mu0, mu1, mu2, mu3, radius, out, out_offset)

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        i32 = ir.IntType(32)
        vec_i32 = ir.VectorType(i32, 4)
        vec_i64 = ir.VectorType(i64, 4)
        sums = _argument_block_sums(context, builder, signature, args)

        def as_i64(k):
            return context.cast(builder, args[k], signature.args[k], types.int64)

        mus = ir.Constant(vec_i64, ir.Undefined)
        for k in range(4):
            mus = builder.insert_element(mus, as_i64(5 + k), i32(k))
        undef = ir.Constant(vec_i64, ir.Undefined)
        zeros = ir.Constant(vec_i32, [i32(0)] * 4)
        dvec = builder.shuffle_vector(builder.insert_element(undef, as_i64(4), i32(0)), undef,
                                      zeros)
        rvec = builder.shuffle_vector(builder.insert_element(undef, as_i64(9), i32(0)), undef,
                                      zeros)
        diff = builder.sub(dvec, mus)
        neg = builder.sub(ir.Constant(vec_i64, [i64(0)] * 4), diff)
        dist = builder.select(builder.icmp_signed("<", diff, ir.Constant(vec_i64, [i64(0)] * 4)),
                              neg, diff)
        inside = builder.icmp_signed("<=", dist, rvec)
        cost = builder.select(inside, ir.Constant(vec_i32, [i32(2147483647)] * 4), sums)
        po = _element_pointer(context, builder, signature.args[10], args[10], args[11],
                              signature.args[11], vec_i32)
        builder.store(cost, po, align=4)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def first_min4(typingctx, costs, values, count):
    """Per lane ``k = 0..3``: ``values[j]`` of the first ``j < count`` with the lowest
    ``costs[4j + k]`` (int32), or -1 when ``count`` is 0; a tuple of four int64.

    The same as ``best = INT32_MAX; for j: if costs[4j+k] < best: ...`` for each lane,
    with the four lanes in one vector compare-and-select.
    """
    if not (isinstance(costs, types.Array) and costs.dtype == types.int32 and costs.ndim == 1
            and isinstance(values, types.Array) and values.dtype == types.int64
            and values.ndim == 1 and isinstance(count, types.Integer)):
        return None
    sig = types.UniTuple(types.int64, 4)(costs, values, count)

    def codegen(context, builder, signature, args):
        i32, i64 = ir.IntType(32), ir.IntType(64)
        v4i32, v4i64 = ir.VectorType(i32, 4), ir.VectorType(i64, 4)
        best_e = cgutils.alloca_once_value(builder, ir.Constant(v4i32, [i32(2147483647)] * 4))
        best_v = cgutils.alloca_once_value(builder, ir.Constant(v4i64, [i64(-1)] * 4))
        n = context.cast(builder, args[2], signature.args[2], types.intp)
        carr = context.make_array(signature.args[0])(context, builder, args[0])
        varr = context.make_array(signature.args[1])(context, builder, args[1])
        with cgutils.for_range(builder, n) as loop:
            j = loop.index
            pc = builder.bitcast(builder.gep(carr.data, [builder.mul(j, j.type(4))]),
                                 v4i32.as_pointer())
            cost = builder.load(pc, align=4)
            value = builder.load(builder.gep(varr.data, [j]))
            splat = builder.insert_element(ir.Constant(v4i64, ir.Undefined), value, i32(0))
            splat = builder.shuffle_vector(splat, ir.Constant(v4i64, ir.Undefined),
                                           ir.Constant(v4i32, [i32(0)] * 4))
            old_e = builder.load(best_e)
            lower = builder.icmp_signed("<", cost, old_e)
            builder.store(builder.select(lower, cost, old_e), best_e)
            builder.store(builder.select(lower, splat, builder.load(best_v)), best_v)
        result = builder.load(best_v)
        items = [builder.extract_element(result, i32(k)) for k in range(4)]
        return context.make_tuple(builder, signature.return_type, items)

    return sig, codegen


@njit(cache=True)
def sad_reference(a, offset_a, b, offset_b, nbytes):
    """Plain-loop version of :func:`sad16` / :func:`sad64` (for tests)."""
    s = np.int32(0)
    for k in range(nbytes):
        s += abs(np.int32(a[offset_a + k]) - np.int32(b[offset_b + k]))
    return s


#: Disparities per group of :func:`sad64x8_first_two_min` (one AVX-512 ``psadbw`` each).
SUPPORT_LANES = 8
#: Lane ``k`` of :func:`sad64x8_first_two_min` holds disparity index ``8 g + LANE_ORDER[k]``
#: of group ``g`` (the order its transposing reduction leaves them in).
LANE_ORDER = (0, 4, 2, 6, 1, 5, 3, 7)


def _transpose_sums(builder, parts):
    """``<8 x i64>``: lane ``k`` is the sum of the 8 lanes of ``parts[LANE_ORDER[k]]`` (eight
    ``<8 x i64>``), in three levels of shuffle-and-add (14 shuffles, 7 adds)."""
    i32 = ir.IntType(32)

    def fold(x, y, first, second):
        m1 = ir.Constant(ir.VectorType(i32, 8), [i32(k) for k in first])
        m2 = ir.Constant(ir.VectorType(i32, 8), [i32(k) for k in second])
        return builder.add(builder.shuffle_vector(x, y, m1), builder.shuffle_vector(x, y, m2))

    level1 = [fold(parts[k], parts[k + 1], (0, 1, 2, 3, 8, 9, 10, 11), (4, 5, 6, 7, 12, 13, 14, 15))
              for k in range(0, 8, 2)]           # [P0 x4, P1 x4], [P2, P3], [P4, P5], [P6, P7]
    level2 = [fold(level1[k], level1[k + 1], (0, 1, 8, 9, 4, 5, 12, 13), (2, 3, 10, 11, 6, 7, 14, 15))
              for k in (0, 2)]                   # [P0 P0 P2 P2 P1 P1 P3 P3], [P4 .. P7 likewise]
    return fold(level2[0], level2[1], (0, 8, 2, 10, 4, 12, 6, 14), (1, 9, 3, 11, 5, 13, 7, 15))


@intrinsic
def sad64x8_first_two_min(typingctx, a, offset_a, b, offset_b, stride, groups):
    """The two lowest SADs per lane over ``groups`` groups of 8 disparities (AVX-512BW only).

    Disparity index ``j = 8 g + LANE_ORDER[k]`` (lane ``k`` of group ``g``) costs
    ``sad64(a, offset_a, b, offset_b + j * stride)``. Per lane, in increasing ``j``: the
    lowest cost, the second lowest (of the lane's multiset of costs) and the first ``j``
    with the lowest cost, as a tuple of 24 int64 (``best[0..7], second[0..7],
    index[0..7]``; INT32_MAX / -1 when ``groups`` is 0). No bounds checking. Only compiled
    where :data:`PSADBW_WIDTH` is 64 (one ``vpsadbw zmm`` per cost; the eight costs of a
    group summed by one transposing reduction instead of eight horizontal ones).
    """
    if _sad_signature(a, offset_a, b, offset_b) is None or PSADBW_WIDTH != 64:
        return None
    if not (isinstance(stride, types.Integer) and isinstance(groups, types.Integer)):
        return None
    sig = types.UniTuple(types.int64, 24)(a, offset_a, b, offset_b, stride, groups)

    def codegen(context, builder, signature, args):
        i8, i32, i64 = ir.IntType(8), ir.IntType(32), ir.IntType(64)
        v64i8, v8i64, v8i32 = ir.VectorType(i8, 64), ir.VectorType(i64, 8), ir.VectorType(i32, 8)
        psad = _llvm_function(builder.module, "llvm.x86.avx512.psad.bw.512", v8i64, [v64i8, v64i8])
        pa = _element_pointer(context, builder, signature.args[0], args[0], args[1],
                              signature.args[1], v64i8)
        va = builder.load(pa, align=1)
        arr_b = context.make_array(signature.args[2])(context, builder, args[2])
        base = context.cast(builder, args[3], signature.args[3], types.intp)
        step = context.cast(builder, args[4], signature.args[4], types.intp)
        n = context.cast(builder, args[5], signature.args[5], types.intp)
        big = ir.Constant(v8i32, [i32(2147483647)] * 8)
        best = cgutils.alloca_once_value(builder, big)
        second = cgutils.alloca_once_value(builder, big)
        index = cgutils.alloca_once_value(builder, ir.Constant(v8i32, [i32(-1)] * 8))
        lanes = cgutils.alloca_once_value(builder, ir.Constant(v8i32, [i32(k) for k in LANE_ORDER]))
        eight = ir.Constant(v8i32, [i32(SUPPORT_LANES)] * 8)
        with cgutils.for_range(builder, n) as loop:
            group_base = builder.add(base, builder.mul(loop.index, builder.mul(step, step.type(8))))
            parts = []
            for k in range(SUPPORT_LANES):
                off = builder.add(group_base, builder.mul(step, step.type(k)))
                pb = builder.bitcast(builder.gep(arr_b.data, [off]), v64i8.as_pointer())
                parts.append(builder.call(psad, [va, builder.load(pb, align=1)]))
            cost = builder.trunc(_transpose_sums(builder, parts), v8i32)
            old_best, old_second = builder.load(best), builder.load(second)
            lower = builder.icmp_signed("<", cost, old_best)
            smaller = builder.select(builder.icmp_signed("<", cost, old_second), cost, old_second)
            builder.store(builder.select(lower, old_best, smaller), second)
            here = builder.load(lanes)
            builder.store(builder.select(lower, here, builder.load(index)), index)
            builder.store(builder.select(lower, cost, old_best), best)
            builder.store(builder.add(here, eight), lanes)
        items = []
        for vec in (best, second, index):
            value = builder.load(vec)
            items += [builder.sext(builder.extract_element(value, i32(k)), i64)
                      for k in range(SUPPORT_LANES)]
        return context.make_tuple(builder, signature.return_type, items)

    return sig, codegen
