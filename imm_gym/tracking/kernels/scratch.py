"""Scratch arrays of the compiled cycle: on the heap, or on the stack of the calling function.

At N = 1 the cycle's ~57 scratch arrays are a few hundred bytes each; allocating and freeing them
on the heap (numba's reference-counted ``np.empty``, ~23 ns each) took ~1.3 µs of a cycle that
computed for ~4.6 µs. :func:`scratch` puts them in fixed buffers in the compiled function's own
stack frame instead: no allocation, and arrays the compiler knows apart (distinct stack slots do
not alias), so their values can stay in registers. Only for one tracker: a block of trackers
needs far more scratch than a thread's stack should hold (docs/performance.md).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array
from numba.np.numpy_support import as_dtype

#: bytes of each stack scratch buffer (128 doubles: the largest scratch of one tracker of
#: :data:`~imm_gym.tracking.kernels.imm.ONE_SHAPE` is 108)
STACK_BYTES = 1024


@intrinsic
def _stack_empty(typingctx, shape, dtype):  # type: ignore[no-untyped-def]
    """An uninitialized C-contiguous array of ``shape`` and ``dtype`` in a buffer of
    :data:`STACK_BYTES` bytes in the stack frame of the function it is compiled into (``alloca``
    in its entry block; no reference count, freed when that function returns). ``ValueError``
    when ``shape`` does not fit the buffer.

    Only for arrays that do not outlive the compiled function: used through :func:`scratch`,
    inlined into the cycle.
    """
    if not isinstance(shape, types.UniTuple) or not isinstance(
        dtype, (types.NumberClass, types.DType)
    ):
        return None
    ndim = shape.count
    array_type = types.Array(dtype.dtype, ndim, "C")
    itemsize = as_dtype(dtype.dtype).itemsize

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        dims = cgutils.unpack_tuple(builder, args[0], ndim)
        intp = types.intp
        size = context.get_constant(intp, 1)
        for d in dims:
            size = builder.mul(size, d)
        capacity = context.get_constant(intp, STACK_BYTES // itemsize)
        too_big = builder.icmp_signed(">", size, capacity)
        with cgutils.if_unlikely(builder, too_big):
            context.call_conv.return_user_exc(
                builder, ValueError, (f"scratch larger than its {STACK_BYTES}-byte stack buffer",)
            )
        buffer = cgutils.alloca_once(builder, context.get_value_type(types.int8), size=STACK_BYTES)
        buffer.align = 64
        data = builder.bitcast(buffer, context.get_data_type(dtype.dtype).as_pointer())
        strides = []
        stride = context.get_constant(intp, itemsize)
        for d in reversed(dims):
            strides.append(stride)
            stride = builder.mul(stride, d)
        array = make_array(array_type)(context, builder)
        populate_array(
            array,
            data=data,
            shape=dims,
            strides=strides[::-1],
            itemsize=context.get_constant(intp, itemsize),
            meminfo=None,
        )
        return array._getvalue()

    return array_type(shape, dtype), codegen


@numba.njit(cache=True, nogil=True, inline="always")
def scratch(shape: tuple, dtype: type, on_stack: bool) -> np.ndarray:  # pragma: no cover
    """``np.empty(shape, dtype)``, or where ``on_stack`` (a compile-time constant of the caller)
    the same array in a stack buffer of the function this is inlined into (:func:`_stack_empty`:
    at most :data:`STACK_BYTES` bytes, ``ValueError`` beyond)."""
    if on_stack:
        return _stack_empty(shape, dtype)
    return np.empty(shape, dtype)
