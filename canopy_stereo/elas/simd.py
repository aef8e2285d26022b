"""Sum of absolute differences of two 16-byte descriptors, as one vector operation.

:func:`sad16` is a numba intrinsic that emits target-independent LLVM IR: load two
``<16 x i8>`` vectors, ``umax - umin`` (the per-byte absolute difference),
zero-extend and add-reduce. On x86 LLVM turns this into a single ``psadbw``; on
other targets into their own absolute-difference-and-accumulate instructions.
A plain loop is what numba would otherwise emit, and it does not vectorise
(about 10x slower), which is why this one function is written in IR.

:func:`sad64` does the same over 64 bytes (the four descriptors of a support
candidate). :func:`sad_reference` is the plain-loop computation, for tests.
"""
from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
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


@njit(cache=True)
def sad_reference(a, offset_a, b, offset_b, nbytes):
    """Plain-loop version of :func:`sad16` / :func:`sad64` (for tests)."""
    s = np.int32(0)
    for k in range(nbytes):
        s += abs(np.int32(a[offset_a + k]) - np.int32(b[offset_b + k]))
    return s
