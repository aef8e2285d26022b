"""Sum of absolute differences of two 16-byte descriptors, as one vector operation.

:func:`sad16` is a numba intrinsic that emits target-independent LLVM IR: load two
``<16 x i8>`` vectors, ``umax - umin`` (the per-byte absolute difference),
zero-extend and add-reduce. On x86 LLVM turns this into a single ``psadbw``; on
other targets into their own absolute-difference-and-accumulate instructions.
A plain loop is what numba would otherwise emit, and it does not vectorise
(about 10x slower), which is why this one function is written in IR.

:func:`sad64` does the same over 64 bytes (the four descriptors of a support
candidate). :func:`quad_first_min` matches four neighbouring pixels at once: each
candidate disparity's four 16-byte SADs are one 64-byte SAD, and the four running
minima stay in one vector. There the per-block sums need x86's ``psadbw`` by name
(the generic pattern becomes a long zero-extend-and-add chain), so
:func:`psadbw_width` picks the instruction numba's target has, with the generic IR
elsewhere. :func:`sad_reference` is the plain-loop computation, for tests.
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


def _splat(builder, value, count):
    """``<count x T>`` with every lane ``value``."""
    vec = ir.VectorType(value.type, count)
    undef = ir.Constant(vec, ir.Undefined)
    zeros = ir.Constant(ir.VectorType(ir.IntType(32), count), [0] * count)
    return builder.shuffle_vector(builder.insert_element(undef, value, ir.IntType(32)(0)), undef,
                                  zeros)


#: Entries of the prior table :func:`quad_first_min` keeps in one register (AVX2).
PRIOR_REGISTER = 8


@intrinsic
def quad_first_min(typingctx, own, offset_own, other, offset_other, stride, cell, n_cell,
                   cell_lo, cell_hi, window_lo, window_hi, radius, prior, mu0, mu1, mu2, mu3,
                   hi0, hi1, hi2, hi3, prior0, prior1, prior2, prior3):
    """Dense matching of four neighbouring pixels: each pixel's first lowest cost over
    the grid candidates outside its window, then its window, as a tuple of four int64
    disparities (-1 where a pixel has no candidate).

    Pixel ``k`` (0..3) has the 16-byte descriptor at ``own[offset_own + 16 k]``; its cost
    at disparity ``d`` is the SAD against ``other[offset_other + d * stride + 16 k]``
    (``stride`` = -16 matching the left image, +16 the right), plus, in its window, the
    prior. Pixel ``k`` has the plane prediction ``mu_k``, the largest disparity ``hi_k``
    (-1: not matched) and ``prior_k`` (bool): whether its plane's prior applies.
    Candidates, in this order:

    * ``cell[j]`` for ``j < n_cell`` with ``cell_lo <= d <= cell_hi``: cost SAD,
      skipped by pixel ``k`` where ``|d - mu_k| <= radius`` or ``d > hi_k``;
    * ``d`` in ``[window_lo, window_hi]``: cost ``SAD + prior[|d - mu_k|]`` (``SAD``
      alone where the prior does not apply), skipped where ``|d - mu_k| > radius`` or
      ``d > hi_k``.

    Each pixel keeps the first candidate of lowest cost (strictly lower replaces), with
    its four costs one 64-byte SAD (x86 ``psadbw``, see :func:`psadbw_width`) and the
    four running minima in one vector. No bounds checking: the caller guarantees that
    every candidate's 64 bytes lie inside ``other`` and that ``prior`` holds at least
    ``max(radius + 1, PRIOR_REGISTER)`` entries (with AVX2 and ``radius`` below
    :data:`PRIOR_REGISTER` the prior is looked up in a register, one ``vpermd``).
    """
    if _sad_signature(own, offset_own, other, offset_other) is None:
        return None
    lanes = (mu0, mu1, mu2, mu3, hi0, hi1, hi2, hi3)
    flags = (prior0, prior1, prior2, prior3)
    ints = (stride, n_cell, cell_lo, cell_hi, window_lo, window_hi, radius) + lanes
    if not (all(isinstance(x, types.Integer) for x in ints)
            and all(isinstance(x, (types.Boolean, types.Integer)) for x in flags)
            and all(isinstance(x, types.Array) and x.dtype == types.int32 and x.ndim == 1
                    for x in (cell, prior))):
        return None
    sig = types.UniTuple(types.int64, 4)(own, offset_own, other, offset_other, stride, cell,
                                         n_cell, cell_lo, cell_hi, window_lo, window_hi, radius,
                                         prior, *lanes, *flags)

    def codegen(context, builder, signature, args):
        i8, i32, i64 = ir.IntType(8), ir.IntType(32), ir.IntType(64)
        v4i32, v64i8 = ir.VectorType(i32, 4), ir.VectorType(i8, 64)
        sargs = signature.args

        def scalar(k, ty=types.intp):
            return context.cast(builder, args[k], sargs[k], ty)

        def data(k):
            return context.make_array(sargs[k])(context, builder, args[k]).data

        va = builder.load(_element_pointer(context, builder, sargs[0], args[0], args[1], sargs[1],
                                           v64i8), align=1)
        other_base = builder.gep(data(2), [scalar(3)])
        stride_ = scalar(4)

        def lane_vector(first, ty=types.int32):
            vec = ir.Constant(v4i32, ir.Undefined)
            for k in range(4):
                vec = builder.insert_element(vec, scalar(first + k, ty), i32(k))
            return vec

        mu, hi = lane_vector(13), lane_vector(17)
        prior_on = builder.icmp_signed("!=", lane_vector(21), ir.Constant(v4i32, [0] * 4))
        rvec = _splat(builder, scalar(11, types.int32), 4)
        zero = ir.Constant(v4i32, [0] * 4)
        big = ir.Constant(v4i32, [2147483647] * 4)
        best_e = cgutils.alloca_once_value(builder, big)
        best_d = cgutils.alloca_once_value(builder, ir.Constant(v4i32, [-1] * 4))

        prior_ptr = data(12)
        v8i32 = ir.VectorType(i32, 8)
        permd = _llvm_function(builder.module, "llvm.x86.avx2.permd", v8i32, [v8i32, v8i32])

        def prior_lookup(index, table):
            """``prior[index]`` per lane (``index`` <4 x i32>, every lane <= radius)."""
            if table is not None:       # one register permute: prior[0..7] in a register
                wide = builder.shuffle_vector(index, ir.Constant(v4i32, ir.Undefined),
                                              ir.Constant(v8i32, list(range(4)) + [0] * 4))
                return builder.shuffle_vector(builder.call(permd, [table, wide]),
                                              ir.Constant(v8i32, ir.Undefined),
                                              ir.Constant(v4i32, list(range(4))))
            bonus = ir.Constant(v4i32, ir.Undefined)
            for k in range(4):
                item = builder.sext(builder.extract_element(index, i32(k)), i64)
                bonus = builder.insert_element(bonus, builder.load(builder.gep(prior_ptr, [item])),
                                               i32(k))
            return bonus

        def candidate(d64, window, table=None):
            """Fold the four costs of disparity ``d64`` (i64) into the running minima."""
            ptr = builder.bitcast(builder.gep(other_base, [builder.mul(d64, stride_)]),
                                  v64i8.as_pointer())
            sums = _block_sums(builder, va, builder.load(ptr, align=1))
            dvec = _splat(builder, builder.trunc(d64, i32), 4)
            diff = builder.sub(dvec, mu)
            dist = builder.select(builder.icmp_signed("<", diff, zero), builder.sub(zero, diff),
                                  diff)
            beyond = builder.icmp_signed(">", dvec, hi)
            if window:
                masked = builder.or_(builder.icmp_signed(">", dist, rvec), beyond)
                bonus = prior_lookup(builder.select(masked, zero, dist), table)
                bonus = builder.select(prior_on, bonus, zero)
                cost = builder.select(masked, big, builder.add(sums, bonus))
            else:
                masked = builder.or_(builder.icmp_signed("<=", dist, rvec), beyond)
                cost = builder.select(masked, big, sums)
            old = builder.load(best_e)
            lower = builder.icmp_signed("<", cost, old)
            builder.store(builder.select(lower, cost, old), best_e)
            builder.store(builder.select(lower, dvec, builder.load(best_d)), best_d)

        cell_ptr = data(5)
        lo, hi_ = scalar(7, types.int64), scalar(8, types.int64)
        # a grid candidate inside every pixel's window, [max mu - r, min mu + r], is masked
        # for all four: skipped without its SAD (a third of them on Middlebury 2014)
        mus = [scalar(13 + k, types.int64) for k in range(4)]
        mu_min, mu_max = mus[0], mus[0]
        for m in mus[1:]:
            mu_min = builder.select(builder.icmp_signed("<", m, mu_min), m, mu_min)
            mu_max = builder.select(builder.icmp_signed(">", m, mu_max), m, mu_max)
        r64 = scalar(11, types.int64)
        shared_lo, shared_hi = builder.sub(mu_max, r64), builder.add(mu_min, r64)
        # ``cell`` is increasing: the candidates below the shared window and those above it
        # are two runs of it, found by counting (no branch per candidate)
        n_below_lo = cgutils.alloca_once_value(builder, i64(0))
        n_below_shared = cgutils.alloca_once_value(builder, i64(0))
        n_to_shared = cgutils.alloca_once_value(builder, i64(0))
        n_to_hi = cgutils.alloca_once_value(builder, i64(0))

        def cell_item(index):
            return builder.sext(builder.load(builder.gep(cell_ptr, [index])), i64)

        with cgutils.for_range(builder, scalar(6)) as loop:
            d64 = cell_item(loop.index)
            for counter, op, bound in ((n_below_lo, "<", lo), (n_below_shared, "<", shared_lo),
                                       (n_to_shared, "<=", shared_hi), (n_to_hi, "<=", hi_)):
                hit = builder.zext(builder.icmp_signed(op, d64, bound), i64)
                builder.store(builder.add(builder.load(counter), hit), counter)
        first, stop = builder.load(n_below_lo), builder.load(n_to_hi)
        below_stop = builder.select(builder.icmp_signed("<", builder.load(n_below_shared), stop),
                                    builder.load(n_below_shared), stop)
        above_first = builder.load(n_to_shared)     # (after the first run when they overlap)
        for bound in (first, below_stop):
            above_first = builder.select(builder.icmp_signed(">", bound, above_first), bound,
                                         above_first)
        for run_first, run_stop in ((first, below_stop), (above_first, stop)):
            with cgutils.for_range(builder, builder.sub(run_stop, run_first)) as loop:
                candidate(cell_item(builder.add(run_first, loop.index)), False)
        w_lo = scalar(9, types.int64)
        count = builder.add(builder.sub(scalar(10, types.int64), w_lo), i64(1))

        def window_loop(table):
            with cgutils.for_range(builder, count) as loop:
                candidate(builder.add(w_lo, loop.index), True, table)

        if PSADBW_WIDTH >= 32:          # AVX2: the prior table fits one register
            small = builder.icmp_signed("<", scalar(11, types.int64), i64(PRIOR_REGISTER))
            with builder.if_else(small) as (in_register, in_memory):
                with in_register:
                    table = builder.load(builder.bitcast(prior_ptr, v8i32.as_pointer()), align=4)
                    window_loop(table)
                with in_memory:
                    window_loop(None)
        else:
            window_loop(None)
        result = builder.load(best_d)
        items = [builder.sext(builder.extract_element(result, i32(k)), i64) for k in range(4)]
        return context.make_tuple(builder, signature.return_type, items)

    return sig, codegen
