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
from collections.abc import Callable
from typing import Any

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


def _block_sums_paired(builder, va, vb):
    """``<8 x i32>``: lanes ``2k`` and ``2k + 1`` both hold the SAD of 16-byte block ``k`` of
    two ``<64 x i8>`` vectors (with ``psadbw``: one truncation, one in-lane swap and one
    add, no lane crossing)."""
    i32 = ir.IntType(32)
    v8i32 = ir.VectorType(i32, 8)
    halves = _block_halves(builder, va, vb)
    if halves is None:
        sums = _block_sums_portable(builder, va, vb)
        return builder.shuffle_vector(sums, ir.Constant(sums.type, ir.Undefined),
                                      ir.Constant(v8i32, [k // 2 for k in range(8)]))
    pairs = builder.trunc(halves, v8i32)
    swapped = builder.shuffle_vector(pairs, ir.Constant(v8i32, ir.Undefined),
                                     ir.Constant(v8i32, [k ^ 1 for k in range(8)]))
    return builder.add(pairs, swapped)


def _block_halves(builder, va, vb):
    """``<8 x i64>``: the SADs of the low and high 8 bytes of each 16-byte block (lanes
    ``2k``, ``2k + 1``) of two ``<64 x i8>`` vectors, by x86 ``psadbw``; None without it."""
    i8, i32, i64 = ir.IntType(8), ir.IntType(32), ir.IntType(64)
    module = builder.module

    def lanes(vec, start, count):
        mask = ir.Constant(ir.VectorType(i32, count), [i32(start + k) for k in range(count)])
        return builder.shuffle_vector(vec, ir.Constant(vec.type, ir.Undefined), mask)

    if not PSADBW_WIDTH:
        return None
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
    return parts[0]


def _block_sums_portable(builder, va, vb):
    """``<4 x i32>``: the SAD of each 16-byte block of two ``<64 x i8>`` vectors, in
    target-independent IR (``umax - umin``, four reductions)."""
    i8, i32 = ir.IntType(8), ir.IntType(32)
    module = builder.module
    vec_i8 = ir.VectorType(i8, 64)
    hi = builder.call(_llvm_function(module, "llvm.umax.v64i8", vec_i8, [vec_i8, vec_i8]), [va, vb])
    lo = builder.call(_llvm_function(module, "llvm.umin.v64i8", vec_i8, [vec_i8, vec_i8]), [va, vb])
    diff = builder.sub(hi, lo)
    reduce_add = _llvm_function(module, "llvm.vector.reduce.add.v16i32", i32,
                                [ir.VectorType(i32, 16)])
    out = ir.Constant(ir.VectorType(i32, 4), [i32(0)] * 4)
    for k in range(4):
        mask = ir.Constant(ir.VectorType(i32, 16), [i32(16 * k + j) for j in range(16)])
        part = builder.shuffle_vector(diff, ir.Constant(diff.type, ir.Undefined), mask)
        part = builder.zext(part, ir.VectorType(i32, 16))
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


#: Disparities per group of :func:`sad64_chunks_first_two_min` (one AVX-512 vector).
SUPPORT_LANES = 8


def _splat(builder, value, count):
    """``<count x T>`` with every lane ``value``."""
    vec = ir.VectorType(value.type, count)
    undef = ir.Constant(vec, ir.Undefined)
    zeros = ir.Constant(ir.VectorType(ir.IntType(32), count), [0] * count)
    return builder.shuffle_vector(builder.insert_element(undef, value, ir.IntType(32)(0)), undef,
                                  zeros)


#: Entries of the window prior :func:`quad_first_min` keeps in one register (AVX2).
PRIOR_REGISTER = 8
#: Entries of the window prior :func:`octo_first_min` keeps in one register (AVX-512).
PRIOR_REGISTER_WIDE = 16


def _concat(builder, parts):
    """One vector of the lanes of ``parts`` (vectors of one type, a power-of-two count), in
    order, joined pairwise."""
    while len(parts) > 1:
        n = parts[0].type.count
        mask = ir.Constant(ir.VectorType(ir.IntType(32), 2 * n), list(range(2 * n)))
        parts = [builder.shuffle_vector(parts[k], parts[k + 1], mask)
                 for k in range(0, len(parts), 2)]
    return parts[0]


def _load_halves(builder, first, second):
    """``<64 x i8>``: 16-byte blocks 0 and 2 of the 64 bytes at i8 pointer ``first``, then
    of those at ``second`` (two loads and one x86 ``vshufi64x2``)."""
    v64i8 = ir.VectorType(ir.IntType(8), 64)
    a, b = (builder.load(builder.bitcast(ptr, v64i8.as_pointer()), align=1)
            for ptr in (first, second))
    mask = [32 * block + k for block in range(4) for k in range(16)]
    return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(ir.IntType(32), 64), mask))


def _quad_loader(builder, spread, per_row=0, row_bytes=None):
    """``load(base, q)``: the ``<64 x i8>`` descriptors of pixels ``4q .. 4q + 3`` of a
    group at i8 pointer ``base``. ``spread`` 1: pixel ``k`` at byte ``16 k`` (one load);
    ``spread`` 2: at ``32 k`` (every second column, :func:`_load_halves`), and with
    ``per_row`` > 0 the pixels ``2 per_row ..`` start ``row_bytes`` (i64) further (the
    group's second row) instead."""
    i64 = ir.IntType(64)
    v64i8 = ir.VectorType(ir.IntType(8), 64)

    def pair(base, j):              # pixels 2j and 2j + 1 (spread 2): one 64-byte load
        if per_row and j >= per_row:
            return builder.gep(builder.gep(base, [row_bytes]), [i64(64 * (j - per_row))])
        return builder.gep(base, [i64(64 * j)])

    def load(base, q):
        if spread == 1:
            return builder.load(builder.bitcast(builder.gep(base, [i64(64 * q)]),
                                                v64i8.as_pointer()), align=1)
        return _load_halves(builder, pair(base, 2 * q), pair(base, 2 * q + 1))

    return load


def _first_min_body(context, builder, own, other_base, stride, cell_ptr, runs, window, radius,
                    prior_ptr, lane_vectors, load_quad):
    """The candidate loops of :func:`quad_first_min` and the wider intrinsics.

    ``own``: one ``<64 x i8>`` vector per group of four pixels (their descriptors), taken
    two groups per block (a last odd group alone); ``other_base``: i8 pointer to the first
    candidate's match, advanced by ``d * stride`` (i64) bytes per disparity ``d``;
    ``cell_ptr``: i32 pointer to the cell's candidates; ``runs``: i64 ``(first0, stop0,
    first1, stop1)``; ``window``: i64 ``(lo, hi)``; ``radius``: i32; ``prior_ptr``: i32
    pointer to the window prior; ``lane_vectors(first, count)``: the ``(mu, hi, flag)``
    vectors of pixels ``first .. first + count - 1`` (pixel ``k`` in lanes ``2k`` and
    ``2k + 1``, as the paired block sums come); ``load_quad(base, q)``: the matches of group
    ``q`` when the group's first pixel's match is at ``base`` (:func:`_quad_loader`).
    Returns, per block, the first minima's disparities (-1: none), in the same lanes.
    """
    i32, i64 = ir.IntType(32), ir.IntType(64)
    blocks = []
    for q in range(0, len(own), 2):
        quads = own[q:q + 2]
        n = 8 * len(quads)
        vni32 = ir.VectorType(i32, n)
        mu, hi, flag = lane_vectors(4 * q, 4 * len(quads))
        blocks.append(dict(
            quads=quads, first=q, n=n, type=vni32, hi=hi,
            # t = d - (mu - r): inside the window iff 0 <= t <= 2r, one unsigned compare
            mu_low=builder.sub(mu, _splat(builder, radius, n)),
            prior_on=builder.icmp_signed("!=", flag, ir.Constant(vni32, [0] * n)),
            span=_splat(builder, builder.mul(radius, i32(2)), n),
            zero=ir.Constant(vni32, [0] * n), big=ir.Constant(vni32, [2147483647] * n),
            best_e=cgutils.alloca_once_value(builder, ir.Constant(vni32, [2147483647] * n)),
            best_d=cgutils.alloca_once_value(builder, ir.Constant(vni32, [-1] * n))))
    # the prior in one register: vpermd on 16 lanes (AVX-512) or 8 (AVX2)
    entries = None
    for b in blocks:
        if b["n"] == 16 and PSADBW_WIDTH == 64:
            name, size = "llvm.x86.avx512.permvar.si.512", PRIOR_REGISTER_WIDE
        elif b["n"] == 8 and PSADBW_WIDTH >= 32:
            name, size = "llvm.x86.avx2.permd", PRIOR_REGISTER
        else:
            entries = 0
            break
        b["permd"] = _llvm_function(builder.module, name, b["type"], [b["type"], b["type"]])
        entries = size if entries is None else min(entries, size)

    def prior_lookup(b, index, table):
        """``prior_window[index]`` per lane of block ``b`` (every lane <= 2r)."""
        if table is not None:       # one register permute: the table in a register
            return builder.call(b["permd"], [table, index])
        bonus = ir.Constant(b["type"], ir.Undefined)
        for lane in range(0, b["n"], 2):
            item = builder.sext(builder.extract_element(index, i32(lane)), i64)
            value = builder.load(builder.gep(prior_ptr, [item]))
            bonus = builder.insert_element(bonus, value, i32(lane))
            bonus = builder.insert_element(bonus, value, i32(lane + 1))
        return bonus

    def block_sums(b, at):
        """The block's costs at the match address ``at``: pixel k's SAD in lanes 2k, 2k+1."""
        others = [load_quad(at, b["first"] + q) for q in range(len(b["quads"]))]
        halves = [_block_halves(builder, va, vb) for va, vb in zip(b["quads"], others)]
        if len(halves) == 2 and halves[0] is not None:
            # the half-sums' low dwords of both groups in one <16 x i32> (a two-source
            # permute instead of two truncations and a concatenation), then each pixel's
            # two halves added pairwise
            v16i32 = ir.VectorType(i32, 16)
            pairs = builder.shuffle_vector(builder.bitcast(halves[0], v16i32),
                                           builder.bitcast(halves[1], v16i32),
                                           ir.Constant(v16i32, [2 * k for k in range(16)]))
            swapped = builder.shuffle_vector(pairs, ir.Constant(v16i32, ir.Undefined),
                                             ir.Constant(v16i32, [k ^ 1 for k in range(16)]))
            return builder.add(pairs, swapped)
        return _concat(builder, [_block_sums_paired(builder, va, vb)
                                 for va, vb in zip(b["quads"], others)])

    def candidate(d64, window, tables):
        """Fold the costs of disparity ``d64`` (i64) into the running minima."""
        at = builder.gep(other_base, [builder.mul(d64, stride)])
        d32 = builder.trunc(d64, i32)
        for b, table in zip(blocks, tables):
            sums = block_sums(b, at)
            dvec = _splat(builder, d32, b["n"])
            t = builder.sub(dvec, b["mu_low"])
            beyond = builder.icmp_signed(">", dvec, b["hi"])
            if window:
                masked = builder.or_(builder.icmp_unsigned(">", t, b["span"]), beyond)
                bonus = prior_lookup(b, builder.select(masked, b["zero"], t), table)
                bonus = builder.select(b["prior_on"], bonus, b["zero"])
                cost = builder.select(masked, b["big"], builder.add(sums, bonus))
            else:
                masked = builder.or_(builder.icmp_unsigned("<=", t, b["span"]), beyond)
                cost = builder.select(masked, b["big"], sums)
            old = builder.load(b["best_e"])
            lower = builder.icmp_signed("<", cost, old)
            builder.store(builder.select(lower, cost, old), b["best_e"])
            builder.store(builder.select(lower, dvec, builder.load(b["best_d"])), b["best_d"])

    no_tables = [None] * len(blocks)
    for run in (0, 2):
        count = builder.sub(runs[run + 1], runs[run])
        with cgutils.for_range(builder, count) as loop:
            index = builder.add(runs[run], loop.index)
            candidate(builder.sext(builder.load(builder.gep(cell_ptr, [index])), i64), False,
                      no_tables)
    w_lo = window[0]
    count = builder.add(builder.sub(window[1], w_lo), i64(1))

    def window_loop(tables):
        with cgutils.for_range(builder, count) as loop:
            candidate(builder.add(w_lo, loop.index), True, tables)

    if entries:                     # a window of up to `entries` disparities in registers
        small = builder.icmp_signed("<", builder.mul(builder.sext(radius, i64), i64(2)),
                                    i64(entries))
        with builder.if_else(small) as (in_register, in_memory):
            with in_register:
                window_loop([builder.load(builder.bitcast(prior_ptr, b["type"].as_pointer()),
                                          align=4) for b in blocks])
            with in_memory:
                window_loop(no_tables)
    else:
        window_loop(no_tables)
    return [builder.load(b["best_d"]) for b in blocks]


def _first_min_types(own, offset_own, other, offset_other, ints, arrays) -> bool:
    """Whether the arguments of a first-minimum intrinsic have the types it takes."""
    return (_sad_signature(own, offset_own, other, offset_other) is not None
            and all(isinstance(x, types.Integer) for x in ints)
            and all(isinstance(x, types.Array) and x.dtype == types.int32 and x.ndim == 1
                    and x.layout == "C" for x in arrays))


def _first_min_args(context, builder, sargs, args):
    """(scalar(k, type), data pointer(k)) readers of an intrinsic's arguments."""
    def scalar(k, ty=types.intp):
        return context.cast(builder, args[k], sargs[k], ty)

    def data(k):
        return context.make_array(sargs[k])(context, builder, args[k]).data

    return scalar, data


def _run_arguments(scalar):
    """The runs ``(first0, stop0, first1, stop1)`` (arguments 6-9) and window (10-11), i64."""
    return ([scalar(6 + k, types.int64) for k in range(4)],
            [scalar(10 + k, types.int64) for k in range(2)])


@intrinsic
def quad_first_min(typingctx, own, offset_own, other, offset_other, stride, cell, first0, stop0,
                   first1, stop1, window_lo, window_hi, radius, prior, mu0, mu1, mu2, mu3,
                   hi0, hi1, hi2, hi3, prior0, prior1, prior2, prior3):
    """Dense matching of four neighbouring pixels: each pixel's first lowest cost over
    grid candidates outside its window, then its window, as a tuple of four int64
    disparities (-1 where a pixel has no candidate).

    Pixel ``k`` (0..3) has the 16-byte descriptor at ``own[offset_own + 16 k]``; its cost
    at disparity ``d`` is the SAD against ``other[offset_other + d * stride + 16 k]``
    (``stride`` = -16 matching the left image, +16 the right), plus, in its window, the
    prior. Pixel ``k`` has the plane prediction ``mu_k``, the largest disparity ``hi_k``
    (-1: not matched) and ``prior_k`` (bool): whether its plane's prior applies.
    Candidates, in this order:

    * ``d = cell[j]`` for ``j`` in ``[first0, stop0)``, then in ``[first1, stop1)``:
      cost SAD, skipped by pixel ``k`` where ``|d - mu_k| <= radius`` or ``d > hi_k``;
    * ``d`` in ``[window_lo, window_hi]``: cost ``SAD + prior[d - mu_k + radius]``
      (``SAD`` alone where the prior does not apply), skipped where ``|d - mu_k| > radius``
      or ``d > hi_k``; ``prior`` is the window's prior, ``2 radius + 1`` entries (the
      plane prior at ``|d - mu_k|`` in ELAS, :func:`~canopy_stereo.elas.matching.window_prior`).

    Each pixel keeps the first candidate of lowest cost (strictly lower replaces), with
    its four costs one 64-byte SAD (x86 ``psadbw``, see :func:`psadbw_width`) and the
    four running minima in one vector. No bounds checking: the caller guarantees that
    every candidate's 64 bytes lie inside ``other`` and that ``prior`` holds at least
    ``max(2 radius + 1, PRIOR_REGISTER)`` entries (with AVX2 and ``2 radius + 1`` at most
    :data:`PRIOR_REGISTER` the prior is looked up in a register, one ``vpermd``).
    """
    lanes = (mu0, mu1, mu2, mu3, hi0, hi1, hi2, hi3)
    flags = (prior0, prior1, prior2, prior3)
    ints = (stride, first0, stop0, first1, stop1, window_lo, window_hi, radius) + lanes
    if not (_first_min_types(own, offset_own, other, offset_other, ints, (cell, prior))
            and all(isinstance(x, (types.Boolean, types.Integer)) for x in flags)):
        return None
    sig = types.UniTuple(types.int64, 4)(own, offset_own, other, offset_other, stride, cell,
                                         first0, stop0, first1, stop1, window_lo, window_hi,
                                         radius, prior, *lanes, *flags)

    def codegen(context, builder, signature, args):
        i8, i32, i64 = ir.IntType(8), ir.IntType(32), ir.IntType(64)
        v8i32 = ir.VectorType(i32, 8)
        scalar, data = _first_min_args(context, builder, signature.args, args)

        # eight lanes, pixel k in lanes 2k and 2k + 1 (as the paired block sums come)
        def lane_vector(first):
            vec = ir.Constant(v8i32, ir.Undefined)
            for lane in range(8):
                vec = builder.insert_element(vec, scalar(first + lane // 2, types.int32),
                                             i32(lane))
            return vec

        va = builder.load(builder.bitcast(builder.gep(data(0), [scalar(1)]),
                                          ir.VectorType(i8, 64).as_pointer()), align=1)
        runs, window = _run_arguments(scalar)
        [result] = _first_min_body(
            context, builder, [va], builder.gep(data(2), [scalar(3)]), scalar(4), data(5), runs,
            window, scalar(12, types.int32), data(13),
            lambda first, count: (lane_vector(14), lane_vector(18), lane_vector(22)),
            _quad_loader(builder, 1))
        items = [builder.sext(builder.extract_element(result, i32(2 * k)), i64) for k in range(4)]
        return context.make_tuple(builder, signature.return_type, items)

    return sig, codegen


#: Entries per row of the ``lanes`` array of :func:`octo_first_min` / :func:`hexa_first_min`.
GROUP_LANES = 20


def _group_first_min(pixels: int, spread: int = 1, rows: int = 1):
    """The first-minimum intrinsic of ``pixels`` (a multiple of 4, at most 20) pixels,
    ``spread`` (1 or 2) columns apart; ``rows`` 2 (with ``spread`` 2): half of them on a
    second row, ``row_bytes`` (a last argument) further in both images."""
    per_row = pixels // 4 if rows == 2 else 0      # spread-2 load pairs per row

    def typer(own, offset_own, other, offset_other, stride, cell, first0, stop0, first1, stop1,
              window_lo, window_hi, radius, prior, lanes, best, *extra):
        ints = (stride, first0, stop0, first1, stop1, window_lo, window_hi, radius) + extra
        if not _first_min_types(own, offset_own, other, offset_other, ints,
                                (cell, prior, lanes, best)):
            return None
        sig = types.void(own, offset_own, other, offset_other, stride, cell, first0, stop0,
                         first1, stop1, window_lo, window_hi, radius, prior, lanes, best, *extra)

        def codegen(context, builder, signature, args):
            i32 = ir.IntType(32)
            scalar, data = _first_min_args(context, builder, signature.args, args)
            load_quad = _quad_loader(builder, spread, per_row,
                                     scalar(16, types.int64) if rows == 2 else None)
            own_at = builder.gep(data(0), [scalar(1)])
            own = [load_quad(own_at, q) for q in range(pixels // 4)]
            lane_data = data(14)

            def lane_vectors(first, count):     # pixel k in lanes 2k and 2k + 1
                v_count = ir.VectorType(i32, count)
                out = []
                for row in range(3):
                    at = builder.gep(lane_data, [ir.IntType(64)(row * GROUP_LANES + first)])
                    vec = builder.load(builder.bitcast(at, v_count.as_pointer()), align=4)
                    out.append(builder.shuffle_vector(
                        vec, ir.Constant(v_count, ir.Undefined),
                        ir.Constant(ir.VectorType(i32, 2 * count),
                                    [k // 2 for k in range(2 * count)])))
                return out

            runs, window = _run_arguments(scalar)
            results = _first_min_body(context, builder, own, builder.gep(data(2), [scalar(3)]),
                                      scalar(4), data(5), runs, window, scalar(12, types.int32),
                                      data(13), lane_vectors, load_quad)
            best_ptr = data(15)
            done = 0
            for result in results:
                count = result.type.count // 2
                even = builder.shuffle_vector(result, ir.Constant(result.type, ir.Undefined),
                                              ir.Constant(ir.VectorType(i32, count),
                                                          [2 * k for k in range(count)]))
                at = builder.gep(best_ptr, [ir.IntType(64)(done)])
                builder.store(even, builder.bitcast(at, even.type.as_pointer()), align=4)
                done += count
            return context.get_dummy_value()

        return sig, codegen

    def one_row(typingctx, own, offset_own, other, offset_other, stride, cell, first0, stop0,
                first1, stop1, window_lo, window_hi, radius, prior, lanes, best):
        return typer(own, offset_own, other, offset_other, stride, cell, first0, stop0, first1,
                     stop1, window_lo, window_hi, radius, prior, lanes, best)

    def two_rows(typingctx, own, offset_own, other, offset_other, stride, cell, first0, stop0,
                 first1, stop1, window_lo, window_hi, radius, prior, lanes, best, row_bytes):
        return typer(own, offset_own, other, offset_other, stride, cell, first0, stop0, first1,
                     stop1, window_lo, window_hi, radius, prior, lanes, best, row_bytes)

    group_first_min: Callable[..., Any] = one_row if rows == 1 else two_rows

    name = {4: "quad", 8: "octo", 16: "hexa", 20: "penta"}[pixels]
    name = f"{name}_first_min" if spread == 1 else f"{name}_first_min_spread{spread}"
    name += "_two_rows" if rows == 2 else ""
    group_first_min.__name__ = group_first_min.__qualname__ = name
    second = "" if rows == 1 else (f" (pixels {pixels // 2}.. on the second row: "
                                   f"``{16 * spread} (k - {pixels // 2}) + row_bytes`` instead)")
    apart = "neighbouring pixels" if spread == 1 else f"pixels {spread} columns apart"
    gather = "" if spread == 1 else (" (each group's descriptors and matches: two 64-byte "
                                     "loads and one shuffle, :func:`_load_halves`)")
    group_first_min.__doc__ = f""":func:`quad_first_min` of {pixels} {apart}
    ({pixels // 4} groups of four: {pixels // 4} 64-byte SADs per candidate{gather}, the
    running minima of two groups in one 16-lane vector, of a last odd group in an 8-lane one).

    Pixel ``k`` (0..{pixels - 1}) has the descriptor at ``own[offset_own + {16 * spread} k]``
    and its match at ``other[offset_other + d * stride + {16 * spread} k]``{second}; ``lanes`` (int32, 3 x
    :data:`GROUP_LANES` entries) holds the plane predictions ``mu_k`` (entry ``k``), largest
    disparities ``hi_k`` (``GROUP_LANES + k``, -1: not matched) and prior flags
    (``2 GROUP_LANES + k``, non-zero: the prior applies). The candidates, their order and
    costs are those of :func:`quad_first_min`; each pixel's disparity is written to
    ``best[k]`` (int32, -1 where it has no candidate). ``prior`` holds at least
    ``max(2 radius + 1, PRIOR_REGISTER_WIDE)`` entries (with AVX-512 and ``2 radius + 1`` at
    most :data:`PRIOR_REGISTER_WIDE`, or :data:`PRIOR_REGISTER` with an odd group, it is
    looked up in registers). No bounds checking.
    """
    return intrinsic(group_first_min)


#: Eight, sixteen and twenty pixels per call (see :func:`_group_first_min`).
octo_first_min = _group_first_min(8)
hexa_first_min = _group_first_min(16)
penta_first_min = _group_first_min(20)
#: Ten pixels every second column on each of two rows per call (subsampled matching: the ten
#: matched pixels of a 20-pixel grid cell's row and of its next matched row).
penta_first_min_spread2_two_rows = _group_first_min(20, 2, 2)


@intrinsic
def sad64_chunks_first_two_min(typingctx, own, own_at, other, other_at, chunk_stride, group_step,
                               groups, first_index, index_step, count):
    """The two lowest 64-byte SADs per lane over ``groups`` groups of 8 (AVX-512BW only),
    with the cost vectors stored chunk-major: qword ``c`` (0..7) of the vector at column
    ``x`` is ``own[c * chunk_stride + x]`` (``other`` likewise), so that chunk ``c`` of 8
    neighbouring columns is one 64-byte load.

    Lane ``k`` of group ``g`` compares ``own``'s column ``own_at`` with ``other``'s column
    ``other_at + g * group_step + k``; its cost is the sum over the 8 chunks of one
    ``vpsadbw`` each (no horizontal sums), and its index ``j = first_index + k * index_step
    + 8 g``; costs with ``j >= count`` do not count. Per lane, in increasing ``g``: the
    lowest cost, the second lowest (of the lane's multiset) and the ``j`` of the first
    lowest, as 24 int64 (``best[0..7], second[0..7], index[0..7]``; INT32_MAX / -1 where
    a lane has no cost). No bounds checking: the caller guarantees every load lies inside
    the arrays.
    """
    if PSADBW_WIDTH != 64:
        return None
    if not all(isinstance(x, types.Array) and x.dtype == types.uint64 and x.ndim == 1
               for x in (own, other)):
        return None
    ints = (own_at, other_at, chunk_stride, group_step, groups, first_index, index_step, count)
    if not all(isinstance(x, types.Integer) for x in ints):
        return None
    sig = types.UniTuple(types.int64, 24)(own, own_at, other, other_at, chunk_stride, group_step,
                                          groups, first_index, index_step, count)

    def codegen(context, builder, signature, args):
        i8, i32, i64 = ir.IntType(8), ir.IntType(32), ir.IntType(64)
        v64i8, v8i64 = ir.VectorType(i8, 64), ir.VectorType(i64, 8)
        sargs = signature.args

        def scalar(k):
            return context.cast(builder, args[k], sargs[k], types.int64)

        def data(k):
            return context.make_array(sargs[k])(context, builder, args[k]).data

        psad = _llvm_function(builder.module, "llvm.x86.avx512.psad.bw.512", v8i64, [v64i8, v64i8])
        own_ptr, other_ptr = data(0), data(2)
        stride = scalar(4)
        own_chunks = []
        for c in range(SUPPORT_LANES):
            at = builder.add(scalar(1), builder.mul(stride, i64(c)))
            word = builder.load(builder.gep(own_ptr, [at]))
            own_chunks.append(builder.bitcast(_splat(builder, word, 8), v64i8))
        big = ir.Constant(v8i64, [2147483647] * 8)
        best = cgutils.alloca_once_value(builder, big)
        second = cgutils.alloca_once_value(builder, big)
        index = cgutils.alloca_once_value(builder, ir.Constant(v8i64, [-1] * 8))
        lane = ir.Constant(v8i64, list(range(8)))
        first_j = builder.add(_splat(builder, scalar(7), 8),
                              builder.mul(lane, _splat(builder, scalar(8), 8)))
        lanes_j = cgutils.alloca_once_value(builder, first_j)
        count = _splat(builder, scalar(9), 8)
        eight = ir.Constant(v8i64, [SUPPORT_LANES] * 8)
        with cgutils.for_range(builder, scalar(6)) as loop:
            base = builder.add(scalar(3), builder.mul(loop.index, scalar(5)))
            cost = None
            for c in range(SUPPORT_LANES):
                at = builder.add(base, builder.mul(stride, i64(c)))
                ptr = builder.bitcast(builder.gep(other_ptr, [at]), v64i8.as_pointer())
                part = builder.call(psad, [own_chunks[c], builder.load(ptr, align=1)])
                cost = part if cost is None else builder.add(cost, part)
            here = builder.load(lanes_j)
            cost = builder.select(builder.icmp_signed("<", here, count), cost, big)
            old_best, old_second = builder.load(best), builder.load(second)
            lower = builder.icmp_signed("<", cost, old_best)
            smaller = builder.select(builder.icmp_signed("<", cost, old_second), cost, old_second)
            builder.store(builder.select(lower, old_best, smaller), second)
            builder.store(builder.select(lower, here, builder.load(index)), index)
            builder.store(builder.select(lower, cost, old_best), best)
            builder.store(builder.add(here, eight), lanes_j)
        items = []
        for vec in (best, second, index):
            value = builder.load(vec)
            items += [builder.extract_element(value, i32(k)) for k in range(SUPPORT_LANES)]
        return context.make_tuple(builder, signature.return_type, items)

    return sig, codegen


#: Pixels per call of :func:`lr_keep8`.
LR_LANES = 8


@intrinsic
def lr_keep8(typingctx, row, c, other, step, inv_step, direction, threshold, dst):
    """The left-right check of pixels ``c .. c+7`` of a row, as one vector operation.

    For each pixel, ``d = row[c + k]`` (float32) and its partner column
    ``c2 = int(x)`` for ``x = (((c + k) * step + direction * d) * inv_step + 0.5`` (float64;
    ``direction`` -1.0 checking the left map, +1.0 the right) when ``x >= 0``, else -1;
    ``dst[c + k]`` is -1.0 where ``d >= 0`` and the partner ``other[c2]`` is missing
    (``c2`` outside ``[0, len(other))``, or negative) or differs from ``d`` by more than
    ``threshold`` (``|d - partner|`` in float32), else ``d``: the scalar check of
    :func:`~canopy_stereo.elas.postprocess.left_right_check` bit for bit, with the eight
    partners loaded one by one. No bounds checking: ``c + 8 <= len(row), len(dst)``.
    """
    arrays = (row, other, dst)
    if not all(isinstance(a, types.Array) and a.dtype == types.float32 and a.ndim == 1
               for a in arrays):
        return None
    if not (isinstance(c, types.Integer) and isinstance(step, types.Integer)
            and all(isinstance(x, types.Float) for x in (inv_step, direction, threshold))):
        return None
    sig = types.void(row, c, other, step, inv_step, direction, threshold, dst)

    def codegen(context, builder, signature, args):
        i32, i64 = ir.IntType(32), ir.IntType(64)
        f32, f64 = ir.FloatType(), ir.DoubleType()
        n = LR_LANES
        vf32, vf64, vi64 = ir.VectorType(f32, n), ir.VectorType(f64, n), ir.VectorType(i64, n)
        sargs = signature.args
        row_a = context.make_array(sargs[0])(context, builder, args[0])
        other_a = context.make_array(sargs[2])(context, builder, args[2])
        dst_a = context.make_array(sargs[7])(context, builder, args[7])
        c0 = context.cast(builder, args[1], sargs[1], types.int64)
        step_ = context.cast(builder, args[3], sargs[3], types.int64)
        inv = _splat(builder, context.cast(builder, args[4], sargs[4], types.float64), n)
        sgn = _splat(builder, context.cast(builder, args[5], sargs[5], types.float64), n)
        thr = _splat(builder, context.cast(builder, args[6], sargs[6], types.float64), n)
        width = builder.extract_value(other_a.shape, 0)
        d = builder.load(builder.bitcast(builder.gep(row_a.data, [c0]), vf32.as_pointer()),
                         align=4)
        cols = builder.add(_splat(builder, c0, n), ir.Constant(vi64, list(range(n))))
        pos = builder.sitofp(builder.mul(cols, _splat(builder, step_, n)), vf64)
        x = builder.fadd(builder.fmul(builder.fadd(pos, builder.fmul(sgn, builder.fpext(d, vf64))),
                                      inv), ir.Constant(vf64, [0.5] * n))
        # x < 0 (or NaN) -> -1; x clipped to the width before the conversion (outside either way)
        w64 = _splat(builder, builder.sitofp(width, f64), n)
        clipped = builder.select(builder.fcmp_ordered("<", x, w64), x, w64)
        c2 = builder.select(builder.fcmp_ordered(">=", x, ir.Constant(vf64, [0.0] * n)),
                            builder.fptosi(clipped, vi64), ir.Constant(vi64, [-1] * n))
        zero64 = ir.Constant(vi64, [0] * n)
        wvec = _splat(builder, width, n)
        outside = builder.or_(builder.icmp_signed("<", c2, zero64),
                              builder.icmp_signed(">=", c2, wvec))
        index = builder.select(outside, zero64, c2)
        partner = ir.Constant(vf32, ir.Undefined)
        for k in range(n):
            item = builder.extract_element(index, i32(k))
            partner = builder.insert_element(partner, builder.load(builder.gep(other_a.data, [item])),
                                             i32(k))
        zero32 = ir.Constant(vf32, [0.0] * n)
        fabs = _llvm_function(builder.module, "llvm.fabs.v8f32", vf32, [vf32])
        far = builder.fcmp_ordered(">", builder.fpext(builder.call(fabs, [builder.fsub(d, partner)]),
                                                      vf64), thr)
        bad = builder.or_(builder.or_(outside, builder.fcmp_ordered("<", partner, zero32)), far)
        drop = builder.and_(builder.fcmp_ordered(">=", d, zero32), bad)
        out = builder.select(drop, ir.Constant(vf32, [-1.0] * n), d)
        builder.store(out, builder.bitcast(builder.gep(dst_a.data, [c0]), vf32.as_pointer()),
                      align=4)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def transpose16x16(typingctx, s0, s1, s2, s3, s4, s5, s6, s7, s8, s9, s10, s11, s12, s13, s14,
                   s15, index, dst, dst_index):
    """Byte ``k`` of pixel ``p`` (``p, k = 0..15``): ``dst[dst_index + 16 p + k] =
    s_k[index + p]``, i.e. sixteen 16-byte descriptors from sixteen sample rows, as one
    256-byte shuffle. No bounds checking."""
    sources = (s0, s1, s2, s3, s4, s5, s6, s7, s8, s9, s10, s11, s12, s13, s14, s15)
    if not all(isinstance(a, types.Array) and a.dtype == types.uint8 and a.ndim == 1
               for a in sources + (dst,)):
        return None
    if not (isinstance(index, types.Integer) and isinstance(dst_index, types.Integer)):
        return None
    sig = types.void(*sources, index, dst, dst_index)

    def codegen(context, builder, signature, args):
        i8, i32 = ir.IntType(8), ir.IntType(32)
        v16 = ir.VectorType(i8, 16)
        sargs = signature.args
        at = context.cast(builder, args[16], sargs[16], types.intp)
        parts = []
        for k in range(16):
            data = context.make_array(sargs[k])(context, builder, args[k]).data
            parts.append(builder.load(builder.bitcast(builder.gep(data, [at]), v16.as_pointer()),
                                      align=1))
        while len(parts) > 1:
            n = parts[0].type.count
            mask = ir.Constant(ir.VectorType(i32, 2 * n), list(range(2 * n)))
            parts = [builder.shuffle_vector(parts[j], parts[j + 1], mask)
                     for j in range(0, len(parts), 2)]
        whole = parts[0]
        mask = ir.Constant(ir.VectorType(i32, 256), [16 * k + p for p in range(16) for k in range(16)])
        out = builder.shuffle_vector(whole, ir.Constant(whole.type, ir.Undefined), mask)
        dst_a = context.make_array(sargs[17])(context, builder, args[17])
        off = context.cast(builder, args[18], sargs[18], types.intp)
        ptr = builder.bitcast(builder.gep(dst_a.data, [off]), ir.VectorType(i8, 256).as_pointer())
        builder.store(out, ptr, align=1)
        return context.get_dummy_value()

    return sig, codegen


#: Pixels per call of :func:`step_mean16`.
MEAN_LANES = 16


@intrinsic
def step_mean16(typingctx, taps, first, tap_stride, n_taps, centre, centre_at, dst, dst_at):
    """The adaptive mean (step weights) of 16 neighbouring pixels, in registers.

    Pixel ``p`` (0..15) with centre ``c = centre[centre_at + p]`` has taps
    ``t_k = taps[first + k * tap_stride + p]``, ``k = 0 .. n_taps - 1``, each weighing
    ``w_k = (2 [|t_k - c| < 8] + 2 [|t_k - c| < 2]) * [t_k >= 0]`` (float32); then
    ``dst[dst_at + p] = s / sw`` with ``s = 0 + w_0 t_0 + w_1 t_1 + ...`` and
    ``sw = 0 + w_0 + w_1 + ...`` added in that order (float32) where ``c >= 0``, else ``c``:
    :func:`~canopy_stereo.elas.postprocess.adaptive_mean` bit for bit, without the sums'
    round trips through memory. No bounds checking.
    """
    arrays = (taps, centre, dst)
    if not all(isinstance(a, types.Array) and a.dtype == types.float32 and a.ndim == 1
               for a in arrays):
        return None
    if not all(isinstance(x, types.Integer) for x in (first, tap_stride, n_taps, centre_at,
                                                       dst_at)):
        return None
    sig = types.void(taps, first, tap_stride, n_taps, centre, centre_at, dst, dst_at)

    def codegen(context, builder, signature, args):
        f32 = ir.FloatType()
        n = MEAN_LANES
        vf = ir.VectorType(f32, n)
        sargs = signature.args

        def pointer(k, at_k):
            data = context.make_array(sargs[k])(context, builder, args[k]).data
            at = context.cast(builder, args[at_k], sargs[at_k], types.intp)
            return data, at

        def load(data, at):
            return builder.load(builder.bitcast(builder.gep(data, [at]), vf.as_pointer()), align=4)

        taps_data, first_ = pointer(0, 1)
        stride = context.cast(builder, args[2], sargs[2], types.intp)
        c_data, c_at = pointer(4, 5)
        c = load(c_data, c_at)
        zero, one = ir.Constant(vf, [0.0] * n), ir.Constant(vf, [1.0] * n)
        two = ir.Constant(vf, [2.0] * n)
        fabs = _llvm_function(builder.module, "llvm.fabs.v16f32", vf, [vf])
        s = cgutils.alloca_once_value(builder, zero)
        sw = cgutils.alloca_once_value(builder, zero)
        with cgutils.for_range(builder, context.cast(builder, args[3], sargs[3], types.intp)) as loop:
            t = load(taps_data, builder.add(first_, builder.mul(loop.index, stride)))
            delta = builder.call(fabs, [builder.fsub(t, c)])
            near = builder.fmul(two, builder.select(builder.fcmp_ordered("<", delta,
                                                                         ir.Constant(vf, [8.0] * n)),
                                                    one, zero))
            close = builder.fmul(two, builder.select(builder.fcmp_ordered("<", delta,
                                                                          ir.Constant(vf, [2.0] * n)),
                                                     one, zero))
            valid = builder.select(builder.fcmp_ordered(">=", t, zero), one, zero)
            weight = builder.fmul(builder.fadd(near, close), valid)
            builder.store(builder.fadd(builder.load(s), builder.fmul(weight, t)), s)
            builder.store(builder.fadd(builder.load(sw), weight), sw)
        q = builder.fdiv(builder.load(s), builder.load(sw))
        out = builder.select(builder.fcmp_ordered(">=", c, zero), q, c)
        d_data, d_at = pointer(6, 7)
        builder.store(out, builder.bitcast(builder.gep(d_data, [d_at]), vf.as_pointer()), align=4)
        return context.get_dummy_value()

    return sig, codegen
