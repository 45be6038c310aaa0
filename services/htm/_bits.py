"""Bit helpers for numba kernels: a 64-bit population count (LLVM ``ctpop`` intrinsic)."""
from __future__ import annotations

from numba import types
from numba.extending import intrinsic

__all__ = ["popcount64"]


@intrinsic
def popcount64(typingctx, x):  # noqa: ARG001 - numba intrinsic signature
    """Number of set bits of a uint64 (compiles to one ``popcnt`` instruction)."""
    sig = types.uint64(types.uint64)

    def codegen(context, builder, signature, args):  # noqa: ARG001
        fn = builder.module.declare_intrinsic("llvm.ctpop", [args[0].type])
        return builder.call(fn, args)

    return sig, codegen
