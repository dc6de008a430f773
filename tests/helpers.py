"""Helpers shared by the test modules."""

from __future__ import annotations

import numpy as np


def random_pd(rng: np.random.Generator, std: np.ndarray) -> np.ndarray:
    """A random covariance with the given standard deviations and random correlations."""
    n = len(std)
    A = rng.standard_normal((n, n))
    C = A @ A.T + 0.5 * np.eye(n)
    d = 1.0 / np.sqrt(np.diag(C))
    return (std[:, None] * std[None, :]) * (d[:, None] * C * d[None, :])
