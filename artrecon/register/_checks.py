"""Shape checks shared by the registration routes."""

from __future__ import annotations

import numpy as np


def _poses(name: str, T) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"{name} must have shape (n, 4, 4), got {T.shape}")
    return T


def _points(name: str, p, cols: int = 3) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    if p.ndim != 2 or p.shape[1] != cols:
        raise ValueError(f"{name} must have shape (n, {cols}), got {p.shape}")
    return p
