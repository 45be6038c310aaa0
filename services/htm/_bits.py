"""Bit helpers for numba kernels: a 64-bit population count (LLVM ``ctpop`` intrinsic) and the
packing of sorted bit indices into uint64 words."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import numpy as np
from numba import njit, types
from numba.extending import intrinsic
from numpy.typing import NDArray

__all__ = ["pack_bits", "popcount64"]


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


@njit(cache=True)
def pack_bits(d: NDArray[np.int64], words: int) -> NDArray[np.uint64]:
    """Sorted bit indices -> little-endian uint64 words (bit i in word i // 64, position i % 64)."""
    out = np.zeros(words, np.uint64)
    for b in d:
        out[b >> 6] |= np.uint64(1) << np.uint64(b & 63)
    return out
