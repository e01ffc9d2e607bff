"""Strong convergence studies: one batched computation per method and step size."""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

from . import _noise
from ._exact import exact_solution
from ._checks import (check_count, check_method, check_model, check_positive, check_retry,
                      check_y0)
from ._integrate import _ensemble_dynamic_jit, _failure_message
from ._system import NOISE_PROPORTIONAL_TO_DRIFT, RIGID_BODY
from ._solver.base import AbstractMethod
from ._solver.midpoint import Midpoint


@dataclasses.dataclass(frozen=True)
class ConvergenceResult:
    """What `strong_convergence` returns. Dicts are keyed by method name.

    - `dts`: the step sizes, shape `(n_dts,)`.
    - `errors`: RMS error $\\sqrt{E|y_N - y(t_1)|^2}$ per step size.
    - `stderr`: standard error of each RMS estimate (delta method over the samples).
    - `order`: least-squares slope of `log error` against `log dt`.
    - `order_stderr`: its standard error, by bootstrap over the samples (the errors at
      different step sizes share their paths, so they are correlated).
    - `seconds`: wall time of each method's runs (all step sizes, compilation included).
    - `reference_error`: the size of the reference's own error (see `strong_convergence`).
    """

    dts: np.ndarray
    errors: dict
    stderr: dict
    order: dict
    order_stderr: dict
    seconds: dict
    reference_error: float = 0.0

    def table(self):
        """A Markdown table of errors and orders."""
        names = list(self.errors)
        head = "| h | " + " | ".join(names) + " |\n|---|" + "---|" * len(names) + "\n"
        rows = "".join(
            f"| 2^{math.log2(h):.0f} | " + " | ".join(
                f"{self.errors[n][i]:.3e} ± {self.stderr[n][i]:.1e}" for n in names) + " |\n"
            for i, h in enumerate(self.dts))
        order = "| order | " + " | ".join(
            f"{self.order[n]:.3f} ± {self.order_stderr[n]:.3f}" for n in names) + " |\n"
        ref = (f"\nReference's own error (RMS): {self.reference_error:.1e}\n"
               if self.reference_error > 0 else "")
        return head + rows + order + ref


@functools.partial(jax.jit, static_argnames=("n_fine",))
def _brownian_endpoints(keys, fine_dt, bound, n_fine):
    def one(key):
        return jax.lax.fori_loop(
            0, n_fine, lambda n, w: w + _noise.increment(key, n, fine_dt, bound, fine_dt.dtype)[0],
            jnp.zeros((), fine_dt.dtype))

    return jax.vmap(one)(keys)


@jax.jit
def _exact_endpoints(model, y0, t1, w_t):
    return jax.vmap(lambda w: exact_solution(model, y0, t1, w))(w_t)


def _substeps(dt, fine_dt, name):
    ratio = dt / fine_dt
    s = int(round(ratio))
    if s < 1 or abs(ratio - s) > 1e-9 * ratio:
        raise ValueError(f"{name}={dt} must be an integer multiple of the finest step {fine_dt}.")
    return s


def strong_convergence(model, y0, *, t1, dts, n_samples, key, methods, reference="exact",
                       reference_dt=None, reference_factor=None, truncate_k=4,
                       n_bootstrap=200, retry_substeps=None):
    r"""Root-mean-square error at `t1` of each method at each step size, on shared paths.

    Every step size integrates the same Brownian paths: a coarse increment is the sum of the
    fine increments it spans (drawn per sample from `fold_in(key, i)` as in `simulate`, at
    the finest step, truncated there). No path is stored: each run keeps only final states.

    **Arguments:**

    - `model`, `y0`: the model and initial value.
    - `t1`: the final time, a multiple of every step size.
    - `dts`: step sizes, each an integer multiple of the finest.
    - `n_samples`, `key`: number of Brownian samples and a `jax.random.key`.
    - `methods`: a method instance or a dict `{name: method}`, e.g. `LiePoisson()`,
      `LiePoissonSym2()`, `LiePoissonSym4()`, `Strang()`, `Strang4()`, `Midpoint()`.
    - `reference`: what the errors are measured against, on the same paths:
        - `"exact"` (default): $y(t_1) = \varphi_{t_1 + cW(t_1)}(y_0)$, the exact solution of
          a `RigidBody` with one noise proportional to the drift (`c=`), with no
          discretisation error;
        - a method instance, for any system (several noises included): that method at the
          step `min(dts) / reference_factor` (default factor 64, or `reference_dt`);
        - `"midpoint"`: `Midpoint()` at `reference_dt` (default `min(dts)/16`, the paper's
          choice);
        - a callable `flow(times) -> states`, the deterministic flow $\varphi_t(y_0)$ at the
          NumPy array of times $t_1 + cW(t_1)$, shape `(n_samples,)` to `(n_samples, 3)`
          (a system with one noise proportional to the drift: the same time change holds
          for every Hamiltonian).
    - `reference_dt`, `reference_factor`: the reference method's step, or the factor by
      which it is finer than `min(dts)` (not both).
    - `truncate_k`: the truncation parameter of the fine increments (`None` for none).
    - `n_bootstrap`: resamples for the order's standard error.
    - `retry_substeps`: as in `simulate`: redo failing steps as `k, k^2, k^3` substeps.

    **Returns:** a `ConvergenceResult`. For a method reference its `reference_error` is the
    RMS difference between the reference and the same method at twice its step, on the same
    paths: the size of the reference's own error (0 for `"exact"`, `nan` for a flow). Keep it
    well below the errors you fit.
    """
    check_model(model)
    if isinstance(methods, dict):
        if not methods:
            raise ValueError("methods must name at least one method, got an empty dict.")
    else:
        methods = {type(methods).__name__: methods}
    for m in methods.values():
        check_method(m)
        y0 = check_y0(y0, m, model)
    t1_np = check_positive("t1", t1)
    if t1_np is None:
        raise TypeError("strong_convergence needs a concrete t1: call it outside jax.jit.")
    t1 = float(t1_np)
    try:
        dts = np.asarray(dts, float)
    except (TypeError, ValueError):
        raise TypeError(f"dts must be a list of step sizes, got {dts!r}.") from None
    if dts.ndim != 1 or len(dts) < 2 or not np.all(np.isfinite(dts) & (dts > 0)):
        raise ValueError(f"dts must hold at least two positive finite step sizes, got {dts}.")
    if len(np.unique(dts)) != len(dts):
        raise ValueError(f"dts must be distinct, got {dts}.")
    dts = np.sort(dts)[::-1]
    named = reference if isinstance(reference, str) else None
    if named == "midpoint":
        reference = Midpoint()
        if reference_dt is None and reference_factor is None:
            reference_factor = 16
    is_method = isinstance(reference, AbstractMethod)
    if not (is_method or callable(reference) or named == "exact"):
        raise ValueError(f"reference must be 'exact', 'midpoint', a method instance or a "
                         f"callable flow, got {reference!r}.")
    if not is_method and NOISE_PROPORTIONAL_TO_DRIFT not in model.structure:
        raise ValueError("This system's noise is not proportional to its drift: it has no "
                         "time-change solution. Pass a method as the reference, for example "
                         "reference=Midpoint(), computed on the same paths at a fine step.")
    if named == "exact" and RIGID_BODY not in model.structure:
        raise ValueError("reference='exact' needs a RigidBody (the closed-form flow); for a "
                         "LiePoissonSystem pass a deterministic flow as reference (a callable) "
                         "or a method, for example reference=Midpoint().")
    if is_method:
        check_method(reference)
        y0 = check_y0(y0, reference, model)
    if reference_dt is not None and reference_factor is not None:
        raise ValueError("Pass reference_dt or reference_factor, not both.")
    if reference_dt is not None:
        check_positive("reference_dt", reference_dt)
    if reference_factor is not None:
        reference_factor = check_count("reference_factor", reference_factor, minimum=2)
    n_samples = check_count("n_samples", n_samples, minimum=2)
    n_bootstrap = check_count("n_bootstrap", n_bootstrap, minimum=2)
    retry = check_retry(retry_substeps)
    key = _noise.check_key(key)
    fine_dt = float(dts[-1])
    if is_method:
        fine_dt = (float(reference_dt) if reference_dt is not None
                   else fine_dt / (64 if reference_factor is None else reference_factor))
    _noise.check_truncation(fine_dt, truncate_k)
    n_fine = _substeps(float(t1), fine_dt, "t1")
    dtype = y0.dtype
    keys = _noise.sample_keys(key, int(n_samples))
    bound = jnp.asarray(_noise.truncation_bound(fine_dt, truncate_k), dtype)

    def final_states(method, dt, name="dt"):
        s = _substeps(dt, fine_dt, name)
        ys, fail_step, result, _, _ = _ensemble_dynamic_jit(
            method, model, y0, keys, jnp.asarray(dt, dtype), bound, 1, jnp.asarray(n_fine // s),
            False, jnp.asarray(s), retry=retry)
        msg = _failure_message(f"strong_convergence ({type(method).__name__} at dt={dt})",
                               fail_step, result)
        if msg is not None:
            raise RuntimeError(msg + " Use smaller dts.")
        return ys[:, -1]

    if is_method:
        y_ref = final_states(reference, fine_dt, "reference_dt")
        half = final_states(reference, 2 * fine_dt, "reference_dt")
        reference_error = float(jnp.sqrt(jnp.mean(jnp.sum((half - y_ref) ** 2, -1))))
    elif callable(reference):
        # The time change: y(t1) = phi_{t1 + c W(t1)}(y0) for the deterministic flow phi.
        w_t = _brownian_endpoints(keys, jnp.asarray(fine_dt, dtype), bound, n_fine)
        times = float(t1) + np.asarray(model.c) * np.asarray(w_t)
        y_ref = np.asarray(reference(times), dtype=np.float64)
        if y_ref.shape != (n_samples, 3):
            raise ValueError(f"reference(times) must return shape ({n_samples}, 3), got "
                             f"{y_ref.shape}.")
        y_ref = jnp.asarray(y_ref, dtype)
        reference_error = math.nan
    else:
        w_t = _brownian_endpoints(keys, jnp.asarray(fine_dt, dtype), bound, n_fine)
        y_ref = _exact_endpoints(model, y0, jnp.asarray(t1, dtype), w_t)
        reference_error = 0.0

    errors, stderr, order, order_se, seconds = {}, {}, {}, {}, {}
    rng = np.random.default_rng(0)
    boot = rng.integers(0, n_samples, size=(n_bootstrap, n_samples))
    log_h = np.log(dts)
    for name, method in methods.items():
        start = time.perf_counter()
        e2 = np.stack([np.asarray(jnp.sum((final_states(method, float(dt)) - y_ref) ** 2, -1))
                       for dt in dts], axis=1)  # (n_samples, n_dts)
        seconds[name] = time.perf_counter() - start
        ms = e2.mean(0)
        errors[name] = np.sqrt(ms)
        stderr[name] = e2.std(0, ddof=1) / math.sqrt(n_samples) / (2 * np.sqrt(ms))
        order[name] = float(np.polyfit(log_h, np.log(errors[name]), 1)[0])
        slopes = [np.polyfit(log_h, 0.5 * np.log(e2[b].mean(0)), 1)[0] for b in boot]
        order_se[name] = float(np.std(slopes, ddof=1))
    return ConvergenceResult(dts, errors, stderr, order, order_se, seconds, reference_error)
