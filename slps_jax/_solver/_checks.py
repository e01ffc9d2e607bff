"""Checks of method options, shared by the constructors and the driver (before compiling)."""

from __future__ import annotations

import math

import numpy as np


def _is_real(x):
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(
        x, (bool, np.bool_))


def check_options(method):
    """Raise a `ValueError` / `TypeError` naming the option if `tol`, `max_iter` or `scale`
    (where the method has them) are not valid. The options are static (hashed into the
    compiled code), so they must be Python or NumPy numbers, not JAX arrays."""
    name = type(method).__name__
    tol = getattr(method, "tol", None)
    if tol is not None:
        if not _is_real(tol):
            raise TypeError(f"{name}: tol must be a positive number or None, got {tol!r}.")
        if not (math.isfinite(tol) and tol > 0):
            raise ValueError(f"{name}: tol must be a positive number, got {tol!r}.")
    if hasattr(method, "max_iter"):
        it = method.max_iter
        if isinstance(it, (bool, np.bool_)) or not isinstance(it, (int, np.integer)) or it < 1:
            raise ValueError(f"{name}: max_iter must be a positive integer, got {it!r}.")
    scale = getattr(method, "scale", None)
    if scale is not None:
        if not _is_real(scale):
            raise TypeError(f"{name}: scale must be a positive number or None, got {scale!r}.")
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"{name}: scale must be a positive number or None, got {scale!r}.")
