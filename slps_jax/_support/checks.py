"""The argument checks of every public entry point: the same message for the same mistake
wherever it is made. Every check runs in Python on concrete values, before anything
compiles; traced values (inside `jit`, `vmap`, `grad`) pass unchecked. A leaf module: the
checks that need systems or methods (their pairing, `y0` against the algebra) are in
`_driver/plan.py`, `check_system` in `_systems/system.py`.

Dtype policy: the system's dtype (that of its parameters and `c`) is the dtype of the
computation. `y0` and `dW` are cast to it: a float32 `y0` with a float64 system is promoted
(exactly); a float64 `y0` with a float32 system is rounded to float32, which is what a
float32 system asks for. Non-real inputs (complex, bool, strings) are rejected.
"""

from __future__ import annotations

import math
import os
import sys

import equinox as eqx
import jax
import jax.core
import jax.numpy as jnp
import numpy as np


def concrete(x):
    """`x` as a NumPy array, or `None` if it is traced (inside `jit`, `vmap`, `grad`)."""
    if isinstance(x, jax.core.Tracer):
        return None
    return np.asarray(x)


def real_dtype(dtype):
    """The real floating dtype of a (real or complex) floating dtype: that of times, noise,
    residuals and tolerances of a computation whose states have dtype `dtype`."""
    return jnp.finfo(dtype).dtype


def float_dtype(*xs):
    """The floating dtype the computation runs in: the inputs' promoted dtype, at least the
    default float (float32, or float64 with `jax_enable_x64`)."""
    return jnp.result_type(float, *xs)


def numeric_array(name, x, allow_complex=False):
    """`x` as an array of real numbers (with `allow_complex`, of real or complex numbers),
    or a `TypeError` naming the argument."""
    what, kinds = ("numbers", "fiuc") if allow_complex else ("real numbers", "fiu")
    if isinstance(x, str):
        raise TypeError(f"{name} must be {what}, got the string {x!r}.")
    try:
        arr = jnp.asarray(x)  # (also a list of tracers, inside jit)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{name} must be {what}, got {x!r} ({err}).") from None
    # (a key array has an extended dtype, which NumPy cannot describe)
    if jnp.issubdtype(arr.dtype, jax.dtypes.extended) or np.dtype(arr.dtype).kind not in kinds:
        raise TypeError(f"{name} must be {what}, got dtype {arr.dtype}.")
    return arr


def real_array(name, x):
    """`x` as an array of real numbers, or a `TypeError` naming the argument."""
    return numeric_array(name, x)


def is_int(x):
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def check_positive(name, x):
    """A positive finite scalar: its NumPy value, or `None` if traced."""
    if isinstance(x, (bool, np.bool_)) or isinstance(x, str):
        raise TypeError(f"{name} must be a positive number, got {x!r}.")
    if isinstance(x, (int, float, np.integer, np.floating)):
        x_np = np.asarray(x)  # stays concrete inside jit, where jnp.asarray would trace
    else:
        x_np = concrete(real_array(name, x))
    if x_np is not None:
        if np.shape(x_np) != ():
            raise ValueError(f"{name} must be a scalar, got shape {np.shape(x_np)}.")
        if not (np.isfinite(x_np) and x_np > 0):
            raise ValueError(f"{name} must be positive and finite, got {x_np}.")
    return x_np


def check_count(name, n, minimum=1):
    if not is_int(n) or n < minimum:
        raise ValueError(
            f"{name} must be an integer >= {minimum}, got {n!r}"
            + (" (a float: pass int(...))" if isinstance(n, float) else "")
            + "."
        )
    return int(n)


def check_save_every(save_every, n_steps):
    if save_every is None:
        return n_steps
    if not is_int(save_every) or save_every < 1:
        raise ValueError(f"save_every must be a positive integer or None, got {save_every!r}.")
    if n_steps % save_every:
        divisors = [k for k in range(1, n_steps + 1) if n_steps % k == 0]
        near = sorted(sorted(divisors, key=lambda k: abs(k - save_every))[:3])
        raise ValueError(
            f"save_every={save_every} must divide the number of steps {n_steps}; "
            f"the nearest divisors are {near}."
        )
    return int(save_every)


def check_option(caller, name, value, kind):
    """`value`, an option object of class `kind` (`Failures`, `Store`, ...), or a `TypeError`
    naming the argument and the class: the one check of every entry point's option objects."""
    if not isinstance(value, kind):
        article = "an" if kind.__name__[0] in "AEIOU" else "a"
        raise TypeError(f"{caller}: {name} must be {article} {kind.__name__}(...), got {value!r}.")
    return value


def check_retry(retry_substeps):
    if retry_substeps is None:
        return None
    if not is_int(retry_substeps) or retry_substeps < 2:
        raise ValueError(
            f"retry_substeps must be None or an integer >= 2 (the number of "
            f"substeps a failed step is split into), got {retry_substeps!r}."
        )
    return int(retry_substeps)


def check_throw(throw):
    if not isinstance(throw, (bool, np.bool_)):
        raise TypeError(f"throw must be True or False, got {throw!r}.")


GRID_RTOL = 1e-9  # how far from the grid a time may be (relative), for rounding


def steps_on_grid(span, dt) -> tuple[np.ndarray, np.ndarray]:
    """`(n, ok)`, arrays of the shape of `span` (a number or an array): the whole numbers of
    steps `dt` nearest `span / dt`, and whether each span is a positive multiple of `dt` to
    within `GRID_RTOL` relative. The one grid check of the library: the run's `t1`, a
    study's steps, observation times."""
    ratio = np.asarray(span, dtype=float) / float(dt)
    n = np.rint(ratio).astype(int)
    return n, (n >= 1) & (np.abs(ratio - n) <= GRID_RTOL * np.maximum(1.0, ratio))


def check_grid(caller, t1, dt):
    """`(dt, n_steps)` as Python numbers, for concrete positive `t1 = n_steps dt`."""
    dt = check_positive("dt", dt)
    t1 = check_positive("t1", t1)
    if dt is None or t1 is None:
        raise TypeError(
            f"{caller} needs concrete t1 and dt (they fix the number of steps): "
            "call it outside jax.jit, or use integrate inside."
        )
    dt, t1 = float(dt), float(t1)
    n, ok = steps_on_grid(t1, dt)
    n_steps = int(n)
    if not ok:
        raise ValueError(
            f"t1={t1} must be a positive multiple of dt={dt} (t1/dt = {t1 / dt}); "
            f"for example dt={t1 / max(1, n_steps)!r}."
        )
    return dt, n_steps


def is_real(x):
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(
        x, (bool, np.bool_)
    )


def check_options(method):
    """Raise a `ValueError` / `TypeError` naming the option if `tol`, `max_iter` or `scale`
    (where the method has them) are not valid. The options are static (hashed into the
    compiled code), so they must be Python or NumPy numbers, not JAX arrays."""
    name = type(method).__name__

    def positive_or_none(option, value_error):
        value = getattr(method, option, None)
        if value is None:
            return
        if not is_real(value):
            raise TypeError(f"{name}: {option} must be a positive number or None, got {value!r}.")
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name}: {option} must be {value_error}, got {value!r}.")

    positive_or_none("tol", "a positive number")
    if getattr(method, "max_iter", None) is not None:
        it = method.max_iter
        if isinstance(it, (bool, np.bool_)) or not isinstance(it, (int, np.integer)) or it < 1:
            raise ValueError(f"{name}: max_iter must be a positive integer or None, got {it!r}.")
    positive_or_none("scale", "a positive number or None")
    if hasattr(method, "unroll"):
        n = method.unroll
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"{name}: unroll must be an integer >= 0, got {n!r}.")


_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # slps_jax/
# (equinox wraps the methods of its Modules: its frames lie between a user and the library)
_INSIDE = (_PACKAGE, os.path.dirname(os.path.abspath(eqx.__file__)))


def user_stacklevel():
    """The `stacklevel` for a `warnings.warn` in the function that calls this one that points
    at the first line outside this package (and equinox's method wrappers, and a Module's
    generated `__init__`): the user's call,
    however deep the library's own calls (and decorators) are."""
    level, frame = 1, sys._getframe(1)
    while frame is not None and _inside(frame.f_code):
        frame, level = frame.f_back, level + 1
    return level


def _inside(code):
    """Whether a frame's code is the library's, equinox's, or the `__init__` that
    `dataclasses` writes for a Module (a method's options checked in its `__post_init__`)."""
    generated = code.co_filename == "<string>" and code.co_name == "__init__"
    return generated or code.co_filename.startswith(_INSIDE)
