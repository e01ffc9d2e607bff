"""Strong convergence studies: one batched computation per method and step size."""

from __future__ import annotations

import dataclasses
import functools
import math
import statistics
import time
import warnings
from collections.abc import Callable
from typing import Any, cast

import jax
import jax.numpy as jnp
import numpy as np

from .. import _brownian
from .._driver.failures import Failures, check_failures, message, summary, warn_or_raise
from .._driver.integrate import ensemble_dynamic_jit
from .._driver.plan import (
    check_driver,
    check_levy_option,
    check_method,
    check_system,
    check_y0,
)
from .._methods.base import AbstractMethod
from .._methods.midpoint import Midpoint
from .._support.checks import (
    check_count,
    check_positive,
    real_dtype,
    steps_on_grid,
    user_stacklevel,
)
from .._systems.capabilities import NOISE_PROPORTIONAL_TO_DRIFT, RIGID_BODY
from .._systems.flow import drift_flow


@dataclasses.dataclass(frozen=True)
class Reference:
    """A method as the convergence studies' reference (`strong_convergence`,
    `weak_convergence`), run on the same paths at a fine step.

    **Arguments:**

    - `method`: a method instance (for example `Midpoint()`).
    - `dt`: its step, which must divide `t1` and be a divisor of the study's steps; or
    - `factor`: an integer >= 2, its step then `min(dts) / factor`. Not both; neither:
      `factor` 64 (what a bare method as the reference gets).
    """

    method: AbstractMethod
    dt: float | None = None
    factor: int | None = None

    def __post_init__(self):
        if not isinstance(self.method, AbstractMethod):
            raise TypeError(f"Reference: method must be a method instance, got {self.method!r}.")
        if self.dt is not None and self.factor is not None:
            raise ValueError("Reference: give dt or factor, not both.")
        if self.dt is not None:
            object.__setattr__(
                self, "dt", float(np.asarray(check_positive("Reference: dt", self.dt)))
            )
        if self.factor is not None:
            object.__setattr__(
                self, "factor", check_count("Reference: factor", self.factor, minimum=2)
            )


@dataclasses.dataclass(frozen=True)
class ConvergenceResult:
    """What `strong_convergence` returns. Dicts are keyed by method name.

    - `dts`: the step sizes, shape `(n_dts,)`.
    - `errors`: RMS error $\\sqrt{E|y_N - y(t_1)|^2}$ per step size (on so(n) the norm of
      the pairing, $|Y|^2 = \\sum_{i<j}Y_{ij}^2$).
    - `stderr`: standard error of each RMS estimate (delta method over the samples).
    - `order`: least-squares slope of `log error` against `log dt`.
    - `order_stderr`: its standard error, by bootstrap over the samples (the errors at
      different step sizes share their paths, so they are correlated).
    - `seconds`: wall time of each method's runs (all step sizes, compilation included).
    - `reference_error`: the size of the reference's own error (see `strong_convergence`).
    - `n_failed`: samples left out of each method's estimates because it (or a method
      reference) failed on them at some step size, even split into substeps (0: none).
    """

    dts: np.ndarray
    errors: dict
    stderr: dict
    order: dict
    order_stderr: dict
    seconds: dict
    reference_error: float = 0.0
    n_failed: dict = dataclasses.field(default_factory=dict)

    def table(self):
        """A Markdown table of errors and orders."""
        names = list(self.errors)
        head = "| h | " + " | ".join(names) + " |\n|---|" + "---|" * len(names) + "\n"
        rows = "".join(
            f"| 2^{math.log2(h):.0f} | "
            + " | ".join(f"{self.errors[n][i]:.3e} ± {self.stderr[n][i]:.1e}" for n in names)
            + " |\n"
            for i, h in enumerate(self.dts)
        )
        order = (
            "| order | "
            + " | ".join(order_text(self.order[n], self.order_stderr[n]) for n in names)
            + " |\n"
        )
        ref = (
            f"\nReference's own error (RMS): {self.reference_error:.1e}\n"
            if self.reference_error > 0
            else ""
        )
        return head + rows + order + ref


@functools.partial(jax.jit, static_argnames=("n_fine",))
def _brownian_endpoints(keys, path, n_fine):
    """$W(t_1)$ of each sample: its first `n_fine` steps of `path` joined into one."""
    return jax.vmap(lambda key: path.joined(key, n_fine).dW[0])(keys)


def _exact_endpoints(system, y0, t1, w_t):
    """The exact solutions at `t1` on paths ending at `w_t`: the drift's flow at the times
    `t1 + c w_t` (closed form for the rigid body, compiled once; Runge–Kutta on the NumPy
    times otherwise)."""
    if RIGID_BODY(system):
        return _time_changed_flow(system, y0, t1, w_t)
    times = float(t1) + np.asarray(system.c) * np.asarray(w_t)
    return drift_flow(system, y0, times).astype(y0.dtype)


@jax.jit
def _time_changed_flow(system, y0, t1, w_t):
    return drift_flow(system, y0, t1 + system.c * w_t)


def _fine_steps(dt, fine_dt, name):
    n, ok = steps_on_grid(dt, fine_dt)
    s = int(n)
    if not ok:
        raise ValueError(f"{name}={dt} must be an integer multiple of the finest step {fine_dt}.")
    return s


@dataclasses.dataclass(frozen=True)
class _Study:
    """What a convergence study shares: the step sizes (largest first), the methods, the
    final states of a method at a step on the shared paths, and the reference's."""

    caller: str
    dts: np.ndarray
    methods: dict
    final_states: object
    y_ref: jax.Array
    reference_error: float
    n_samples: int
    y0: jax.Array
    t1: float
    kind: str  # "exact", "method" or "flow"
    y_ref_coarse: jax.Array | None  # a method reference at twice its step
    ref_failed: np.ndarray  # samples on which a method reference failed
    ref_why: str | None  # what failed there, in words
    areas: dict  # method name -> whether it gets the Lévy areas
    failures: Failures  # what a failing step does


def order_text(order, stderr):
    """A fitted order with its standard error, as every table of the library writes it
    (`1.130 ± 0.025`)."""
    return f"{order:.3f} ± {stderr:.3f}"


def _warn_single_precision(caller, dtype):
    """A study in float32 measures round-off as soon as errors near its floor: say so, once
    per call (the library never flips `jax_enable_x64` itself)."""
    if jnp.finfo(dtype).bits < 64:
        eps = float(jnp.finfo(dtype).eps)
        warnings.warn(
            f"{caller} runs in {jnp.dtype(dtype).name}: its round-off floor is about {eps:.1e} "
            f"per step (errors below about {100 * eps:.0e} are not resolved, and fitted orders "
            f"near it are wrong). For accuracy work enable float64 before creating any array: "
            f'jax.config.update("jax_enable_x64", True).',
            UserWarning,
            stacklevel=user_stacklevel(),
        )


def _study(
    caller,
    system,
    y0,
    *,
    t1,
    dts,
    n_samples,
    key,
    methods,
    reference,
    failures,
    driver,
):
    """Validate a study's arguments (before anything compiles) and set up its shared paths
    and reference (see `strong_convergence`)."""
    check_system(system)
    driver = check_driver(driver)
    if not driver.coarsens:
        raise TypeError(
            f"{caller}: driver must be None or sj.BrownianMotion(...) (a study integrates "
            f"Brownian paths at several steps), got {driver!r}."
        )
    driver = cast(_brownian.BrownianMotion, driver)  # (the driver that coarsens)
    truncate_k, levy_area = driver.truncate_k, driver.levy_area
    if isinstance(methods, dict):
        if not methods:
            raise ValueError("methods must name at least one method, got an empty dict.")
    else:
        methods = {type(methods).__name__: methods}
    for m in methods.values():
        check_method(m)
        y0 = check_y0(y0, m, system)
    _warn_single_precision(caller, system.dtype)
    t1_np = check_positive("t1", t1)
    if t1_np is None:
        raise TypeError(f"{caller} needs a concrete t1: call it outside jax.jit.")
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
        reference = Reference(Midpoint(), factor=16)
    elif isinstance(reference, AbstractMethod):
        reference = Reference(reference)
    reference_dt = reference_factor = None
    if isinstance(reference, Reference):
        reference, reference_dt, reference_factor = reference.method, reference.dt, reference.factor
    is_method = isinstance(reference, AbstractMethod)
    if not (is_method or callable(reference) or named == "exact"):
        raise ValueError(
            f"reference must be 'exact', 'midpoint', a method instance, a Reference or a "
            f"callable flow, got {reference!r}."
        )
    if not is_method and not NOISE_PROPORTIONAL_TO_DRIFT(system):
        raise ValueError(
            "This system's noise is not proportional to its drift: it has no "
            "time-change solution. Pass a method as the reference, for example "
            "reference=Midpoint(), computed on the same paths at a fine step."
        )
    if is_method:
        check_method(reference)
        y0 = check_y0(y0, reference, system)
    n_samples = check_count("n_samples", n_samples, minimum=2)
    failures = check_failures(caller, failures)
    retry = failures.retry_substeps
    key = _brownian.check_key(key)
    fine_dt = float(dts[-1])
    if is_method:
        fine_dt = (
            float(reference_dt)
            if reference_dt is not None
            else fine_dt / (64 if reference_factor is None else reference_factor)
        )
    _brownian.check_truncation(fine_dt, truncate_k)
    n_fine = _fine_steps(float(t1), fine_dt, "t1")
    dtype = real_dtype(y0.dtype)
    keys = _brownian.sample_keys(key, int(n_samples))

    for dt in dts:
        if n_fine % _fine_steps(float(dt), fine_dt, "dt"):
            raise ValueError(f"t1={t1} must be a multiple of every step size, not of dt={dt}.")
    # Lévy areas (for the methods that use them): drawn at the finest step, joined over the
    # coarse ones by Chen's relation; a dict chooses per method, the reference on "auto"
    chosen, default = (levy_area, "auto") if isinstance(levy_area, dict) else ({}, levy_area)
    unknown = sorted(set(chosen) - set(methods))
    if unknown:
        raise ValueError(
            f"levy_area names methods {unknown} that are not in methods ({sorted(methods)})."
        )
    areas = {n: check_levy_option(chosen.get(n, default), m, system) for n, m in methods.items()}
    ref_areas = is_method and check_levy_option(default, reference, system)
    # (the paths at the finest step, with their areas for the runs that take them: the
    # increments do not depend on whether the areas are drawn)
    fine = driver.path(fine_dt, system.n_noises, dtype, levy_area=True)

    def final_states(method, dt, name="dt", areas=False):
        """The final states, the failed samples (a NumPy mask) and what failed, in words
        (`None` if nothing); with `areas`, the method gets the Lévy areas."""
        s = _fine_steps(dt, fine_dt, name)
        path = (fine if areas else fine.without_areas()).coarsened(
            jnp.asarray(s), jnp.asarray(dt, dtype)
        )
        ys, fail_step, result, _, _ = ensemble_dynamic_jit(
            method, system, y0, keys, path, 1, jnp.asarray(n_fine // s), False, retry=retry
        )
        found = summary(fail_step, result)
        why = None if found is None else f"{found[0]} at dt={dt:g} ({found[3]})"
        return ys[:, -1], np.asarray(fail_step) >= 0, why

    half = None  # a method reference at twice its step
    ref_failed, ref_why = np.zeros(int(n_samples), bool), None
    if is_method:
        y_ref, ref_failed, ref_why = final_states(reference, fine_dt, "Reference.dt", ref_areas)
        # (at twice its step: possible when that divides t1)
        half, half_failed, _ = (
            final_states(reference, 2 * fine_dt, "Reference.dt", ref_areas)
            if n_fine % 2 == 0
            else (None, None, None)
        )
        if half is not None and half_failed is not None:
            ref_failed = ref_failed | half_failed
        reference_error = (
            math.nan
            if half is None or ref_failed.all()
            else float(jnp.sqrt(jnp.mean(system.algebra.norm_sq(half - y_ref)[~ref_failed])))
        )
    elif callable(reference):
        # The time change: y(t1) = phi_{t1 + c W(t1)}(y0) for the deterministic flow phi.
        w_t = _brownian_endpoints(keys, fine.without_areas(), n_fine)
        times = float(t1) + np.asarray(system.c) * np.asarray(w_t)
        y_ref = np.asarray(reference(times), dtype=np.float64)
        if y_ref.shape != (n_samples, *system.algebra.shape):
            raise ValueError(
                f"reference(times) must return shape "
                f"{(n_samples, *system.algebra.shape)}, got {y_ref.shape}."
            )
        y_ref = jnp.asarray(y_ref, dtype)
        reference_error = math.nan
    else:
        w_t = _brownian_endpoints(keys, fine.without_areas(), n_fine)
        y_ref = _exact_endpoints(system, y0, jnp.asarray(t1, dtype), w_t)
        # (the closed form: round-off; Runge–Kutta: about 1e-13, not estimated)
        reference_error = 0.0 if RIGID_BODY(system) else math.nan

    kind = "method" if is_method else "flow" if callable(reference) else "exact"
    return _Study(
        caller,
        dts,
        methods,
        final_states,
        y_ref,
        reference_error,
        int(n_samples),
        y0,
        t1,
        kind,
        half,
        ref_failed,
        ref_why,
        areas,
        failures,
    )


def _runs(st, name, method):
    """The final states of `method` at every step size of the study, `(n_dts, n_samples,
    ...)`, and the samples its estimates use: those on which the reference and every one
    of its runs succeeded (failing steps are split into substeps first, `Failures`).
    The others are left out of all its step sizes alike, so that its errors stay paired,
    and a `RuntimeWarning` says how many, where and why."""
    runs = [st.final_states(method, float(dt), areas=st.areas[name]) for dt in st.dts]
    failed = st.ref_failed | np.any([f for _, f, _ in runs], axis=0)
    n_failed = int(failed.sum())
    if n_failed:
        why = "; ".join(
            w for w in [st.ref_why and f"reference {st.ref_why}"] + [w for _, _, w in runs] if w
        )
        if st.n_samples - n_failed < 2:
            raise RuntimeError(
                f"{st.caller}: {name} failed on {n_failed} of {st.n_samples} "
                f"samples ({why}): nothing left to estimate from. Use "
                f"smaller dts."
            )
        warn_or_raise(
            st.failures,
            message(
                f"{st.caller} ({name})",
                n_failed,
                st.n_samples,
                f"They are left out of {name}'s estimates at every step size "
                f"(n_failed), so that its errors stay paired.",
                why=why,
                retried=st.failures.retried,
            ),
        )
    return np.stack([np.asarray(y) for y, _, _ in runs]), ~failed


def strong_convergence(
    system,
    y0,
    *,
    t1,
    dts,
    n_samples,
    key,
    methods,
    reference="exact",
    n_bootstrap=200,
    failures: Failures = Failures(),
    driver: _brownian.BrownianMotion | None = None,
):
    r"""Root-mean-square error at `t1` of each method at each step size, on shared paths.

    Every step size integrates the same Brownian paths: a coarse increment is the sum of the
    fine increments it spans (drawn per sample from `fold_in(key, i)` as in `simulate`, at
    the finest step, truncated there). No path is stored: each run keeps only final states.

    **Arguments:**

    - `system`, `y0`: the system and initial value.
    - `t1`: the final time, a multiple of every step size.
    - `dts`: step sizes, each an integer multiple of the finest.
    - `n_samples`, `key`: number of Brownian samples and a `jax.random.key`.
    - `methods`: a method instance or a dict `{name: method}`, e.g. `LiePoisson()`,
      `LiePoissonSym2()`, `LiePoissonSym4()`, `Strang()`, `Strang4()`, `Midpoint()`.
    - `reference`: what the errors are measured against, on the same paths:
        - `"exact"` (default): $y(t_1) = \varphi_{t_1 + cW(t_1)}(y_0)$, the exact solution
          of a system with one noise proportional to the drift (`c=`), through `drift_flow`:
          in closed form for a `RigidBody` (no discretisation error), by Runge–Kutta at
          steps of at most 2^-10 otherwise (so(n) and su(N) included; about 1e-13);
        - a method instance, for any system (several noises included): that method at the
          step `min(dts) / 64`; `Reference(method, dt=...)` or `Reference(method,
          factor=...)` at another step;
        - `"midpoint"`: `Reference(Midpoint(), factor=16)` (`min(dts)/16`, the paper's
          choice);
        - a callable `flow(times) -> states`, a flow $\varphi_t(y_0)$ of the user's at the
          NumPy array of times $t_1 + cW(t_1)$, shape `(n_samples,)` to
          `(n_samples, *state_shape)` (a system with one noise proportional to the drift).
    - `n_bootstrap`: resamples for the order's standard error.
    - `failures`: a `Failures`, as for `simulate` (failing steps redone as 4, 16, 64
      substeps; samples that still fail are left out, below).
    - `driver`: `None` or `sj.BrownianMotion(truncate_k=..., levy_area=...)`: the
      truncation of the fine increments (`truncate_k`, default 4; `None` for none), and
      whether a method that `uses_levy_area()` gets the Lévy areas of its steps (`levy_area`:
      `"auto"`, the default, `True` or `False`, as in `simulate`), drawn at the finest step
      and joined over a coarse step by Chen's relation, so that every step size and the
      reference integrate the same path. A method that does not use them never gets them
      (with `True` it is refused). Or `levy_area={method name: True/False}` to choose per
      method (the others and the reference on `"auto"`): the same method with and without
      areas against one reference.

    Samples on which a method fails (even split into substeps) are left out of that
    method's estimates at every step size, counted in `n_failed`, with a `RuntimeWarning`:
    as in `simulate` and `ensemble_statistics`, a long run returns its results and failures
    are never used as data (`Failures(throw=True)`: `RuntimeError` instead).

    **Returns:** a `ConvergenceResult`. For a method reference its `reference_error` is the
    RMS difference between the reference and the same method at twice its step, on the same
    paths: the size of the reference's own error (0 for `"exact"` on a `RigidBody`; `nan` where it is
    not estimated: Runge–Kutta's, about 1e-13, or a callable flow's). Keep it
    well below the errors you fit.
    """
    n_bootstrap = check_count("n_bootstrap", n_bootstrap, minimum=2)
    st = _study(
        "strong_convergence",
        system,
        y0,
        t1=t1,
        dts=dts,
        n_samples=n_samples,
        key=key,
        methods=methods,
        reference=reference,
        failures=failures,
        driver=driver,
    )
    dts, y_ref = st.dts, st.y_ref
    errors, stderr, order, order_se, seconds, n_failed = {}, {}, {}, {}, {}, {}
    log_h = np.log(dts)
    for name, method in st.methods.items():
        start = time.perf_counter()
        ys, ok = _runs(st, name, method)
        seconds[name] = time.perf_counter() - start
        e2 = np.asarray(system.algebra.norm_sq(ys[:, ok] - np.asarray(y_ref)[ok])).T
        n_samples, n_failed[name] = e2.shape[0], st.n_samples - e2.shape[0]  # (n, n_dts)
        ms = e2.mean(0)
        errors[name] = np.sqrt(ms)
        stderr[name] = e2.std(0, ddof=1) / math.sqrt(n_samples) / (2 * np.sqrt(ms))
        boot = np.random.default_rng(0).integers(0, n_samples, size=(n_bootstrap, n_samples))
        order[name] = float(np.polyfit(log_h, np.log(errors[name]), 1)[0])
        slopes = [np.polyfit(log_h, 0.5 * np.log(e2[b].mean(0)), 1)[0] for b in boot]
        order_se[name] = float(np.std(slopes, ddof=1))
    return ConvergenceResult(
        dts, errors, stderr, order, order_se, seconds, st.reference_error, n_failed
    )


@dataclasses.dataclass(frozen=True)
class WeakConvergenceResult:
    """What `weak_convergence` returns. Dicts are keyed by method name; arrays have one
    column per observable component.

    - `dts`: the step sizes, shape `(n_dts,)`.
    - `bias`: the estimated weak error $E_h[g(y_N)] - E[g(y(t_1))]$, shape `(n_dts, m)`: the
      mean of the coupled differences $g(y_N) - g(y_\text{ref})$ over the samples.
    - `ci`: half-width of its confidence interval at level `confidence` (normal
      approximation), from the coupled differences' standard deviation.
    - `order`: least-squares slope of `log |bias|` against `log dt`, per component
      (meaningful only where `|bias|` is above `ci` at every step: `resolved(name)`).
    - `reference_mean`: $E[g(y(t_1))]$: by Gauss–Hermite quadrature of the exact flow for
      `reference="exact"` (exact to quadrature accuracy), else the mean over the reference
      paths.
    - `reference_error`: the reference's own weak error: for `"exact"` on a `RigidBody` the
      quadrature's, the difference of its last two rules (`nan`, not estimated, for
      Runge–Kutta's flow, about 1e-13); for a method, the
      coupled mean difference between it and the same method at twice its step.
    - `seconds`: wall time of each method's runs.
    - `n_failed`: samples left out of each method's estimates (see `ConvergenceResult`).
    """

    dts: np.ndarray
    bias: dict
    ci: dict
    order: dict
    reference_mean: np.ndarray
    reference_error: np.ndarray
    seconds: dict
    n_failed: dict = dataclasses.field(default_factory=dict)

    def table(self):
        """A Markdown table of |bias| ± CI per step size (one column per method and
        observable component) and the fitted orders."""
        cols = [(n, j) for n in self.bias for j in range(self.bias[n].shape[1])]
        label = {(n, j): n if self.bias[n].shape[1] == 1 else f"{n}[{j}]" for n, j in cols}
        head = (
            "| h | " + " | ".join(label[c] for c in cols) + " |\n|---|" + "---|" * len(cols) + "\n"
        )
        rows = "".join(
            f"| 2^{math.log2(h):.0f} | "
            + " | ".join(f"{abs(self.bias[n][i, j]):.2e} ± {self.ci[n][i, j]:.1e}" for n, j in cols)
            + " |\n"
            for i, h in enumerate(self.dts)
        )
        order = (
            "| order | "
            + " | ".join(
                f"{self.order[n][j]:.2f}" if self.resolved(n)[j] else "unresolved" for n, j in cols
            )
            + " |\n"
        )
        return head + rows + order

    def resolved(self, name):
        """Per observable component of method `name`: whether every step size's `|bias|`
        exceeds its confidence interval, so that the fitted order means something (the table
        prints the order only then)."""
        return np.all(np.abs(self.bias[name]) > self.ci[name], axis=0)


GAUSS_HERMITE_NODES = (64, 128, 256, 512, 1024)  # the rules tried, until two agree
GAUSS_HERMITE_RTOL = 1e-12


def _exact_mean(g, system, y0, t1):
    r"""$E[g(\varphi_{t_1 + c\sqrt{t_1} z}(y_0))]$, $z \sim N(0, 1)$, by Gauss–Hermite quadrature:
    the rules of `GAUSS_HERMITE_NODES` in turn until two agree to `GAUSS_HERMITE_RTOL` of
    the mean's scale (a `RuntimeWarning` if none do). **Returns** the last rule's mean and
    its difference from the one before, per component."""
    dtype = real_dtype(y0.dtype)

    def rule(n):
        x, w = np.polynomial.hermite_e.hermegauss(n)
        times = t1 + float(system.c) * math.sqrt(t1) * x
        states = drift_flow(system, y0, np.asarray(times, dtype))
        return np.asarray(w @ np.asarray(g(states))) / math.sqrt(2 * math.pi)

    last = rule(GAUSS_HERMITE_NODES[0])
    for n in GAUSS_HERMITE_NODES[1:]:
        mean = rule(n)
        difference = np.abs(mean - last)
        if np.all(difference <= GAUSS_HERMITE_RTOL * max(1.0, float(np.max(np.abs(mean))))):
            return mean, difference
        last = mean
    warnings.warn(
        f"weak_convergence: the exact expectation's Gauss–Hermite rules of "
        f"{GAUSS_HERMITE_NODES[-2]} and {GAUSS_HERMITE_NODES[-1]} nodes differ by "
        f"{float(np.max(difference)):.1e} (reference_error): the observable is rough in the "
        "noise, or c too large, for the quadrature.",
        RuntimeWarning,
        stacklevel=user_stacklevel(),
    )
    return mean, difference


def weak_convergence(
    system,
    y0,
    *,
    t1,
    dts,
    n_samples,
    key,
    methods,
    observable: Callable[..., Any],
    reference="exact",
    confidence=0.95,
    failures: Failures = Failures(),
    driver: _brownian.BrownianMotion | None = None,
):
    r"""Weak error $|E_h[g(y_N)] - E[g(y(t_1))]|$ of each method at each step size, for an
    observable $g$ you choose, on shared paths, with confidence intervals and fitted orders.

    The paths, step sizes and references are those of `strong_convergence` (same arguments).
    The weak error is estimated from the *coupled* differences $g(y_N) - g(y_\text{ref})$ on
    the same Brownian path, whose variance is far smaller than that of $g(y_N)$, so the
    confidence intervals are narrow for few samples. With `reference="exact"` (a system
    with one noise proportional to the drift) the pathwise reference is the exact solution,
    so $E[g(y_\text{ref})]$ is exactly $E[g(y(t_1))] = \int g(\varphi_{t_1 + c\sqrt{t_1}z}(y_0))
    \,N(dz)$, which is also computed, by Gauss–Hermite quadrature, as `reference_mean` (64
    nodes, doubled until two rules agree to 1e-12 of the mean's scale). For other systems
    pass a method as the reference (for example `Midpoint()`, 64x finer by default); its own
    weak error is reported.

    **Arguments:** as `strong_convergence`, and

    - `observable`: `g(y) -> scalar or shape (m,)`, for one state `y`, traceable by JAX
      (for example `lambda y: y` for the mean, or `system.hamiltonian`).
    - `confidence`: the level of the intervals (default 0.95).

    **Returns:** a `WeakConvergenceResult`.
    """
    if not callable(observable):
        raise TypeError(
            f"observable must be a function g(y) -> scalar or shape (m,), got "
            f"{type(observable).__name__}."
        )
    if not (isinstance(confidence, (float, int)) and 0 < confidence < 1):
        raise ValueError(f"confidence must lie strictly between 0 and 1, got {confidence!r}.")
    check_system(system)
    g = jax.jit(jax.vmap(lambda y: jnp.atleast_1d(observable(y))))
    shape = jax.eval_shape(g, jax.ShapeDtypeStruct((2, *system.algebra.shape), system.dtype)).shape
    if len(shape) != 2:
        raise ValueError(
            f"observable(y) must return a scalar or shape (m,), got shape {shape[1:]}."
        )
    st = _study(
        "weak_convergence",
        system,
        y0,
        t1=t1,
        dts=dts,
        n_samples=n_samples,
        key=key,
        methods=methods,
        reference=reference,
        failures=failures,
        driver=driver,
    )
    z = statistics.NormalDist().inv_cdf(0.5 + confidence / 2)
    g_ref = np.asarray(g(st.y_ref))
    if st.kind == "exact":
        reference_mean, quadrature = _exact_mean(g, system, st.y0, st.t1)
        exact = RIGID_BODY(system)  # (Runge–Kutta: about 1e-13, not estimated)
        reference_error = quadrature if exact else np.full(shape[1], np.nan)
    else:
        good = ~st.ref_failed
        reference_mean = g_ref[good].mean(0)
        reference_error = np.full(shape[1], np.nan)
        if st.y_ref_coarse is not None:
            reference_error = np.abs((np.asarray(g(st.y_ref_coarse)) - g_ref)[good].mean(0))

    bias, ci, order, seconds, n_failed = {}, {}, {}, {}, {}
    log_h = np.log(st.dts)
    for name, method in st.methods.items():
        start = time.perf_counter()
        ys, ok = _runs(st, name, method)
        diffs = np.stack([np.asarray(g(y[ok])) - g_ref[ok] for y in ys])  # (n_dts, n, m)
        seconds[name] = time.perf_counter() - start
        n, n_failed[name] = diffs.shape[1], st.n_samples - diffs.shape[1]
        bias[name] = diffs.mean(1)
        ci[name] = z * diffs.std(1, ddof=1) / math.sqrt(n)
        order[name] = np.array(
            [
                np.polyfit(log_h, np.log(np.maximum(np.abs(b), np.finfo(float).tiny)), 1)[0]
                for b in bias[name].T
            ]
        )
    return WeakConvergenceResult(
        st.dts, bias, ci, order, reference_mean, reference_error, seconds, n_failed
    )
