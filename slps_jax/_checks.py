"""Validation of every public entry point, in one place: the same message for the same
mistake wherever it is made. Every check runs in Python on concrete values, before anything
compiles; traced values (inside `jit`, `vmap`, `grad`) pass unchecked.

Dtype policy: the model's dtype (that of its parameters and `c`) is the dtype of the
computation. `y0` and `dW` are cast to it: a float32 `y0` with a float64 model is promoted
(exactly); a float64 `y0` with a float32 model is rounded to float32, which is what a
float32 model asks for. Non-real inputs (complex, bool, strings) are rejected.
"""

from __future__ import annotations

import math

import jax
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
    if jax.dtypes.issubdtype(arr.dtype, jax.dtypes.extended) or \
            np.dtype(arr.dtype).kind not in kinds:
        raise TypeError(f"{name} must be {what}, got dtype {arr.dtype}.")
    return arr


def real_array(name, x):
    """`x` as an array of real numbers, or a `TypeError` naming the argument."""
    return numeric_array(name, x)


def is_int(x):
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def check_model(model):
    from ._system import LiePoissonSystem

    if not isinstance(model, LiePoissonSystem):
        raise TypeError(
            f"model must be a RigidBody or a LiePoissonSystem, got {type(model).__name__}: "
            f"build one with slps_jax.RigidBody(inertia, c).")


def check_pair(method, model):
    """The one check of a method against a system: what the method `requires` (a set of
    structures, such as the rigid body's) the system must offer (`structure`)."""
    from ._methods import METHODS
    from ._system import RIGID_BODY

    missing = method.requires - model.structure
    if missing:
        works = [cls.__name__ for cls in METHODS if cls.requires <= model.structure]
        only = " (it works for a RigidBody only)" if RIGID_BODY in missing else ""
        raise TypeError(
            f"{type(method).__name__} needs a system with the structure "
            f"{', '.join(sorted(missing))}{only}; this {type(model).__name__} does not have "
            f"it. Methods for this system: {', '.join(works)}.")


def check_method(method):
    from ._methods.base import AbstractMethod

    if not isinstance(method, AbstractMethod):
        raise TypeError(
            f"method must be an instance such as LiePoisson(), got {method!r}"
            + (" (a class: call it)" if isinstance(method, type) else "") + "."
        )
    check_options(method)  # again here: a dataclass can be built around its constructor


def _area_methods():
    from ._methods import METHODS

    return ", ".join(cls.__name__ for cls in METHODS if cls.uses_levy_area())


def check_levy_area(area, n_steps, n_noises, method):
    """The Lévy areas given to `integrate`: `None`, or an array of shape
    `(n_steps, s, s)`, finite and antisymmetric, for a method that uses them. Returns the
    array, or `None` for one noise (its areas are zero)."""
    if area is None:
        return None
    if not method.uses_levy_area():
        raise TypeError(f"{type(method).__name__} does not use Lévy areas (its step sees only "
                        f"the increments); methods that do: {_area_methods()}.")
    area = real_array("levy_area", area)
    shape = (n_steps, n_noises, n_noises)
    if area.shape != shape:
        raise ValueError(f"levy_area must have shape (n_steps, s, s) = {shape}, one "
                         f"antisymmetric (s, s) matrix per step, got shape {area.shape}.")
    a_np = concrete(area)
    if a_np is not None:
        if not np.all(np.isfinite(a_np)):
            bad = np.flatnonzero(~np.all(np.isfinite(a_np), axis=(1, 2)))
            raise ValueError(f"levy_area must be finite; steps {bad[:5].tolist()} are not.")
        asym = float(np.max(np.abs(a_np + np.swapaxes(a_np, 1, 2))))
        if asym > 1e-12 * max(1.0, float(np.max(np.abs(a_np)))):
            raise ValueError(f"levy_area must be antisymmetric, A[n, q, r] = -A[n, r, q]; "
                             f"max |A + A^T| = {asym:.3g}.")
    return None if n_noises == 1 else area


def check_levy_option(levy_area, method, model):
    """Whether an ensemble draws Lévy areas: `"auto"` (for a method that uses them and a
    system with several noises), `True` (refused for a method that cannot use them) or
    `False`. One noise never needs areas (they are zero): `False` then."""
    if isinstance(levy_area, str) and levy_area == "auto":
        return bool(method.uses_levy_area() and model.n_noises > 1)
    if not isinstance(levy_area, (bool, np.bool_)):
        raise TypeError(f"levy_area must be 'auto', True or False, got {levy_area!r}.")
    if levy_area and not method.uses_levy_area():
        raise TypeError(f"levy_area=True: {type(method).__name__} does not use Lévy areas; "
                        f"methods that do: {_area_methods()}.")
    return bool(levy_area) and model.n_noises > 1


def check_y0(y0, method, model):
    check_pair(method, model)
    alg = model.algebra
    y0 = numeric_array("y0", y0, alg.is_complex)
    shape = alg.shape
    if y0.shape != shape:
        several = y0.ndim == len(shape) + 1 and y0.shape[1:] == shape
        raise ValueError(
            f"y0 must have shape {shape} (a state of {model.algebra.name}), got shape "
            f"{y0.shape}"
            + ("; for several initial values use jax.vmap over integrate." if several
               else "."))
    y0 = y0.astype(alg.state_dtype(model.dtype))
    y_np = concrete(y0)
    if y_np is not None:
        alg.validate("y0", y_np)
        method.check_initial(model, y_np)
    return y0


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
        raise ValueError(f"{name} must be an integer >= {minimum}, got {n!r}"
                         + (" (a float: pass int(...))" if isinstance(n, float) else "") + ".")
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


def check_retry(retry_substeps):
    if retry_substeps is None:
        return None
    if not is_int(retry_substeps) or retry_substeps < 2:
        raise ValueError(f"retry_substeps must be None or an integer >= 2 (the number of "
                         f"substeps a failed step is split into), got {retry_substeps!r}.")
    return int(retry_substeps)


def check_throw(throw):
    if not isinstance(throw, (bool, np.bool_)):
        raise TypeError(f"throw must be True or False, got {throw!r}.")


def check_grid(caller, t1, dt):
    """`(dt, n_steps)` as Python numbers, for concrete positive `t1 = n_steps dt`."""
    dt = check_positive("dt", dt)
    t1 = check_positive("t1", t1)
    if dt is None or t1 is None:
        raise TypeError(f"{caller} needs concrete t1 and dt (they fix the number of steps): "
                        "call it outside jax.jit, or use integrate inside.")
    dt, t1 = float(dt), float(t1)
    ratio = t1 / dt
    n_steps = int(round(ratio))
    if n_steps < 1 or abs(ratio - n_steps) > 1e-9 * max(1.0, ratio):
        near = max(1, n_steps)
        raise ValueError(f"t1={t1} must be a positive multiple of dt={dt} (t1/dt = {ratio}); "
                         f"for example dt={t1 / near!r}.")
    return dt, n_steps


def is_real(x):
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
        if not is_real(value):
            raise TypeError(f"{name}: {option} must be a positive number or None, got "
                            f"{value!r}.")
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name}: {option} must be {value_error}, got {value!r}.")

    positive_or_none("tol", "a positive number")
    if getattr(method, "max_iter", None) is not None:
        it = method.max_iter
        if isinstance(it, (bool, np.bool_)) or not isinstance(it, (int, np.integer)) or it < 1:
            raise ValueError(f"{name}: max_iter must be a positive integer or None, got "
                             f"{it!r}.")
    positive_or_none("scale", "a positive number or None")
    if hasattr(method, "unroll"):
        n = method.unroll
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"{name}: unroll must be an integer >= 0, got {n!r}.")
