"""The training helpers of :mod:`agents.training` called directly, each against a value worked
by hand: the weight average, the seeding of the training slots, the thread limits and the
checks of the hyperparameters."""

from __future__ import annotations

import torch
from threadpoolctl import threadpool_info, threadpool_limits

from agents.training import (
    set_threads,
)


def test_set_threads_limits_torch_and_the_blas_to_one_thread(monkeypatch) -> None:
    """Torch and every BLAS pool set to two threads are back to one after ``set_threads()``;
    the thread variables are set to 1 where unset and kept where set."""
    threads = torch.get_num_threads()
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    try:
        torch.set_num_threads(2)
        threadpool_limits(2)
        set_threads()
        assert torch.get_num_threads() == 1
        assert [pool["num_threads"] for pool in threadpool_info()] == [1] * len(threadpool_info())
    finally:
        torch.set_num_threads(threads)
        threadpool_limits(1)
    import os

    assert os.environ["OMP_NUM_THREADS"] == os.environ["MKL_NUM_THREADS"] == "1"
    assert os.environ["OPENBLAS_NUM_THREADS"] == "3"

