"""Bit helpers for numba kernels: a 64-bit population count (LLVM ``ctpop`` intrinsic)."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

from numba import types
from numba.extending import intrinsic

__all__ = ["popcount64"]


def _popcount64(typingctx: Any, x: Any) -> tuple[Any, Callable[..., Any]]:  # noqa: ARG001 - numba intrinsic signature
    """Number of set bits of a uint64 (compiles to one ``popcnt`` instruction)."""
    sig = types.uint64(types.uint64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:  # noqa: ARG001
        fn = builder.module.declare_intrinsic("llvm.ctpop", [args[0].type])
        return builder.call(fn, args)

    return sig, codegen


# numba's ``intrinsic`` drops the typing-context argument, which its annotations cannot say, so
# the kernels' view is stated here: a uint64 word in, its bit count (a uint64 there) out
popcount64 = cast("Callable[[Any], int]", intrinsic(_popcount64))
