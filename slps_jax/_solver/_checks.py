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

    def positive_or_none(option, value_error):
        value = getattr(method, option, None)
        if value is None:
            return
        if not _is_real(value):
            raise TypeError(f"{name}: {option} must be a positive number or None, got "
                            f"{value!r}.")
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name}: {option} must be {value_error}, got {value!r}.")

    positive_or_none("tol", "a positive number")
    if hasattr(method, "max_iter"):
        it = method.max_iter
        if isinstance(it, (bool, np.bool_)) or not isinstance(it, (int, np.integer)) or it < 1:
            raise ValueError(f"{name}: max_iter must be a positive integer, got {it!r}.")
    positive_or_none("scale", "a positive number or None")
