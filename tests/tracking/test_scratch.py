"""The compiled cycle's scratch arrays (``imm_gym.tracking.kernels.scratch``): a stack buffer
behaves as ``np.empty`` of the same shape and dtype, and refuses a shape it cannot hold."""

import numba
import numpy as np
import pytest

from imm_gym.tracking.kernels.scratch import STACK_BYTES, scratch


@numba.njit
def _fill_and_sum(rows: int, cols: int, on_stack: bool) -> tuple[float, int, bool]:
    a = scratch((rows, cols), np.float64, on_stack)
    b = scratch((cols,), np.int64, on_stack)
    c = scratch((rows,), np.bool_, on_stack)
    for j in range(cols):
        b[j] = 3 * j
    for i in range(rows):
        c[i] = i % 2 == 0
        for j in range(cols):
            a[i, j] = i * cols + j + 0.5 * b[j]
    total = 0.0
    for i in range(rows):
        for j in range(cols):
            total += a[i, j] * (2.0 if c[i] else 1.0)
    return total, b.sum(), c[0] and a.flags.c_contiguous


@numba.njit
def stack_fill(rows: int, cols: int) -> tuple[float, int, bool]:
    return _fill_and_sum(rows, cols, True)


@numba.njit
def heap_fill(rows: int, cols: int) -> tuple[float, int, bool]:
    return _fill_and_sum(rows, cols, False)


@pytest.mark.parametrize("rows, cols", [(1, 1), (3, 4), (4, 32), (16, 8)])
def test_stack_scratch_is_an_array_like_the_heap_one(rows: int, cols: int) -> None:
    expected = np.arange(rows * cols, dtype=float).reshape(rows, cols) + 1.5 * np.arange(cols)
    weights = np.where(np.arange(rows) % 2 == 0, 2.0, 1.0)[:, None]
    for fill in (stack_fill, heap_fill):
        total, b_sum, flags = fill(rows, cols)
        assert total == pytest.approx(float((expected * weights).sum()), rel=1e-15)
        assert b_sum == 3 * cols * (cols - 1) // 2
        assert flags


def test_stack_scratch_refuses_a_shape_beyond_its_buffer() -> None:
    doubles = STACK_BYTES // 8
    stack_fill(1, doubles)  # exactly full
    with pytest.raises(ValueError, match="stack buffer"):
        stack_fill(1, doubles + 1)
    heap_fill(1, doubles + 1)  # the heap has no such bound
