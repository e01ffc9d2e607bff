r"""A fitted closure trained on its forecasts: the closure's parameters moved by gradient
descent on the fair CRPS of short ensemble forecasts, differentiated pathwise through the
integrator (after Woodfield 2024; Ephrati & Woodfield 2025). `docs/data-driven-noise.md`
says what it is measured to do."""

from __future__ import annotations

import dataclasses
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._brownian import check_key
from .._driver.failures import Failures
from .._studies.calibrate import Optimisation
from .._support.checks import check_positive
from .closure import PARTS, ClosureFit
from .verification import _forecasts, forecast_setup, refuse_failed

_NO_RETRY = Failures(retry_substeps=None)  # (see train_closure)

UNITS = {"transport": 1.0, "additive": 1.0, "hamiltonian": 0.05, "damping": 0.1}
r"""What one unit of each part's trained parameter changes (`train_closure`): the logarithm
of each mode's or degree's noise amplitude, the stream's gain $g_\ell$ (in 0.05), the damping
rate $d_\ell$ (in 0.1 per second)."""


@dataclasses.dataclass(frozen=True)
class _Closure:
    """The closed system at a factor and what its trained leaves are made of (NumPy)."""

    parts: tuple
    chi: np.ndarray | None  # (r, N, N): the transport noise at the start
    own: np.ndarray | None  # (band,): the coarse system's own additive variance per degree
    fitted: np.ndarray | None  # (band,): the fitted additive amplitude at the start
    band: int  # the first degree of the closed system's additive forcing
    gain: np.ndarray | None  # (N,): the stream's gain at the start
    alpha: np.ndarray | None  # (N,): the coarse system's own damping
    damping: np.ndarray  # (N,): the fitted damping

    def system(self, base, theta):
        """`base` (the closed system at the start) with the trained leaves at `theta`."""
        if "transport" in self.parts:
            chi = jnp.asarray(self.chi) * jnp.exp(theta["transport"])[:, None, None]
            base = eqx.tree_at(lambda s: s.noise.chi, base, chi.astype(base.noise.chi.dtype))
        if "additive" in self.parts:
            sigma = jnp.asarray(self.fitted) * jnp.exp(theta["additive"][self.band :])
            variance = jnp.asarray(self.own) + sigma**2
            positive = variance > 0  # (a degree without either forcing: 0, and no NaN in
            # the gradient of the square root there)
            amplitude = jnp.where(positive, jnp.sqrt(jnp.where(positive, variance, 1.0)), 0.0)
            base = eqx.tree_at(lambda s: s.additive.amplitude, base, amplitude)
        if "hamiltonian" in self.parts:
            change = (UNITS["hamiltonian"] * theta["hamiltonian"]).at[0].set(0.0)
            gain = jnp.asarray(self.gain) + change
            base = eqx.tree_at(lambda s: s.stream_operator.gain, base, gain)
        if "damping" in self.parts:
            alpha = jnp.asarray(self.alpha) + self.damping_at(theta)
            base = eqx.tree_at(lambda s: s.linear.alpha, base, alpha)
        return base

    def damping_at(self, theta):
        """The fitted damping at `theta`, bounded below by 0."""
        change = UNITS["damping"] * theta["damping"]
        return jnp.maximum(jnp.asarray(self.damping) + change, 0.0).at[0].set(0.0)


def _closure(fit, factor, parts, base):
    """The `_Closure` of `fit` at `factor`, `base` its closed system there."""
    chi = own = fitted = gain = alpha = None
    band = 0
    if "transport" in parts:
        chi = np.asarray(base.noise.chi)
    if "additive" in parts:
        band = base.additive.band[0]
        white = fit.time_model == "white"
        fitted = (factor * fit.additive_std * np.sqrt(2.0 * fit.additive_time if white else 1.0))[
            band:
        ]
        own = np.maximum(np.asarray(base.additive.amplitude) ** 2 - fitted**2, 0.0)
    if "hamiltonian" in parts:
        gain = np.asarray(base.stream_operator.gain)
    if "damping" in parts:
        alpha = np.asarray(base.linear.alpha) - fit.damping
    return _Closure(parts, chi, own, fitted, band, gain, alpha, np.asarray(fit.damping, float))


def fair_crps(ensembles, truth):
    r"""The mean fair CRPS (Ferro 2014) of `ensembles` `(n_starts, m, ...)` against `truth`
    `(n_starts, ...)`, differentiable: $\frac1m\sum_i|x_i - y| - \frac{1}{2m(m-1)}
    \sum_{i,j}|x_i - x_j|$, averaged over every start and entry."""
    m = ensembles.shape[1]
    error = jnp.mean(jnp.abs(ensembles - truth[:, None]), axis=1)
    pairs = jnp.abs(ensembles[:, :, None] - ensembles[:, None, :])
    return jnp.mean(error - jnp.sum(pairs, axis=(1, 2)) / (2.0 * m * (m - 1)))


def _trained(fit, factor, closure, theta):
    """`fit` with the parameters at `theta` (at factor 1: the start's factor absorbed)."""
    t = {k: np.asarray(v, float) for k, v in theta.items()}
    replace: dict = dict(
        transport_scale=fit.transport_scale * factor,
        additive_std=factor * fit.additive_std,
        shares=None,
    )
    if "transport" in closure.parts:
        replace["transport_scale"] = replace["transport_scale"] * np.exp(t["transport"])
    if "additive" in closure.parts:
        replace["additive_std"] = np.where(
            fit.additive_std > 0, replace["additive_std"] * np.exp(t["additive"]), 0.0
        )
    if "hamiltonian" in closure.parts:
        gain = fit.gain + UNITS["hamiltonian"] * t["hamiltonian"]
        replace["gain"] = np.r_[0.0, gain[1:]]
    if "damping" in closure.parts:
        replace["damping"] = np.asarray(closure.damping_at(theta), float)
    return dataclasses.replace(fit, **replace)


def _training(fit, starts, truth, lead, dt, every, members, key, observe, factor, parts):
    """`train_closure`'s problem: its loss `theta -> (fair CRPS, failed members)`, the
    parameters at the start (zeros), the `_Closure`, and the checked `ForecastRun` (the
    default method, no substep retries)."""
    base, driver = fit._closed(factor)
    run = forecast_setup(
        "train_closure", base, starts, lead, dt, every, members, key, driver, "auto", _NO_RETRY
    )
    n_starts, n_leads = run.arguments[2].shape[0], run.arguments[5]
    truth = np.asarray(truth)
    if truth.shape != (n_starts, n_leads, *base.algebra.shape) or not np.all(np.isfinite(truth)):
        raise ValueError(
            f"train_closure: truth must be finite, (n_starts, lead // every, N, N) = "
            f"{(n_starts, n_leads, *base.algebra.shape)}, got shape {truth.shape}."
        )
    closure = _closure(fit, factor, parts, base)
    sizes = {"transport": closure.chi.shape[0] if closure.chi is not None else 0}
    theta = {p: jnp.zeros(sizes.get(p, fit.coarse.N), base.dtype) for p in parts}
    observed = observe(jnp.asarray(truth, run.arguments[2].dtype))
    method_, _, y0, keys, path, n_blocks, every_, retry = run.arguments

    def loss(theta):
        system = closure.system(base, theta)
        ys, fail_step = _forecasts(method_, system, y0, keys, path, n_blocks, every_, retry)
        return fair_crps(observe(ys), observed), jnp.sum(fail_step >= 0)

    return loss, theta, closure, run


def train_closure(
    fit,
    starts,
    truth,
    *,
    lead,
    dt,
    every,
    members,
    key,
    observe,
    factor=1.0,
    parts=None,
    optimisation=Optimisation(steps=40),
):
    r"""`fit`'s closure trained on its forecasts: its parameters moved by gradient descent on
    the mean fair CRPS of ensemble forecasts from `starts`, scored against `truth`.

    The trained parameters, per part of the closure (`parts`, all of `fit.parts` by
    default), each in the units of `UNITS` and starting at 0 (the fit, its noises times
    `factor`):

    - `"transport"`: the logarithm of each transport mode's amplitude, `(r,)`;
    - `"additive"`: the logarithm of each degree's fitted additive amplitude, `(N,)` (the
      coarse system's own forcing is kept as it is);
    - `"hamiltonian"`: the change of the stream's gain $g_\ell$ of each degree, `(N,)`;
    - `"damping"`: the change of the fitted damping rate $d_\ell$ of each degree, `(N,)`,
      the rate bounded below by 0.

    The loss is the fair CRPS of `observe` of each start's ensemble at the lead times
    `every, 2 every, ..., lead` steps of `dt`, against `observe(truth)`, averaged over the
    starts, lead times and observables. Each member draws from the same key at every step
    (common random numbers, as `forecast_ensembles` with `key`), so the loss is a smooth
    deterministic function of the parameters; its gradient goes pathwise through the
    integrator, one compiled program for every step. Score the trained closure on other
    starts and keys: it is fitted to these.

    **Arguments:**

    - `fit`: a `ClosureFit` (`fit_closure`), with the parts to train.
    - `starts`: `(n_starts, N, N)`, the coarse truth at the starts (inside the period the
      closure was fitted on: the held-out starts are for scoring).
    - `truth`: `(n_starts, lead // every, N, N)`, the coarse truth at the lead times.
    - `lead`, `dt`, `every`, `members`, `key`: as for `forecast_ensembles` (`members` at
      least 2; the driver is `fit.driver`, the method the system's default). A member that
      fails stops the training with a `RuntimeError`: failed steps are not retried in
      substeps, whose reverse mode would hold about 80 times the memory (measured at
      su(8)).
    - `observe`: a function from states `(..., N, N)` to observables `(..., k)`, traceable
      (for example `lambda w: zeitlin.mat2shr(w)[..., 4:]`, the degrees 2 and up).
    - `factor`: the noises' amplitude factor at the start (`ClosureFit.scaled`), for example
      the tuned one (`tune_amplitude(...).factor`); positive.
    - `parts`: which of `fit.parts` to train (default all).
    - `optimisation`: an `Optimisation`: an optax optimiser (default `None`: Adam with
      learning rate 0.1 and $\beta_1$ = 0.5, little momentum: the loss is deterministic),
      the most steps (default 40), the relative change of the loss that ends the training
      (`rtol`), and the progress printout.

    **Returns:** a `ClosureFit`: `fit` with the trained parameters, at factor 1 (`factor`
    absorbed; `transport_scale` one number per mode), its `training` the loss at the start
    and after each step, its `shares` `None` (`explained(states)` gives them).
    `system`, `driver`, `scaled` and `save` work as for a fit.
    """
    if not isinstance(fit, ClosureFit):
        raise TypeError(f"train_closure: fit must be a ClosureFit, got {type(fit).__name__}.")
    parts = fit.parts if parts is None else parts
    if isinstance(parts, str) or not parts or any(p not in fit.parts for p in parts):
        raise ValueError(
            f"train_closure: parts must be some of the fit's parts {fit.parts}, got {parts!r}."
        )
    parts = tuple(p for p in PARTS if p in parts)
    factor = float(np.asarray(check_positive("factor", factor)))
    if not isinstance(optimisation, Optimisation):
        raise TypeError(
            f"train_closure: optimisation must be an Optimisation, got {optimisation!r}."
        )
    if not callable(observe):
        raise TypeError(f"train_closure: observe must be a function, got {observe!r}.")
    key = check_key(key)
    if isinstance(members, (int, np.integer)) and not isinstance(members, bool) and members < 2:
        raise ValueError(f"train_closure: the fair CRPS needs members >= 2, got {members}.")
    loss, theta, closure, run = _training(
        fit, starts, truth, lead, dt, every, members, key, observe, factor, parts
    )
    opt = optax.adam(0.1, b1=0.5) if optimisation.optimizer is None else optimisation.optimizer
    opt = optax.with_extra_args_support(opt)
    value_and_grad = jax.value_and_grad(loss, has_aux=True)

    @jax.jit
    def step(theta, state):
        (value, n_failed), grad = value_and_grad(theta)
        scalar = lambda t: loss(t)[0]
        updates, state = opt.update(grad, state, theta, value=value, grad=grad, value_fn=scalar)
        return optax.apply_updates(theta, updates), state, value, n_failed

    state = jax.tree_util.tree_map(
        lambda x: jnp.array(x, dtype=jnp.result_type(x)), opt.init(theta)
    )
    history = []
    for i in range(optimisation.steps + 1):
        new_theta, new_state, value, n_failed = step(theta, state)
        refuse_failed(
            "train_closure",
            int(n_failed),
            run.arguments[3].size,
            run.failures,
            f"the training stops at step {i} (a failed member is not scored)",
        )
        value = float(value)
        if not np.isfinite(value):
            raise FloatingPointError(f"train_closure: the loss is not finite at step {i}.")
        history.append(value)
        if optimisation.progress:
            print(f"train_closure: step {i:3d}  fair CRPS {value:.6e}", file=sys.stderr)
        done = i > 0 and abs(history[-2] - value) <= optimisation.rtol * abs(history[-2])
        if done or i == optimisation.steps:
            break
        theta, state = new_theta, new_state
    trained = _trained(fit, factor, closure, theta)
    return dataclasses.replace(trained, training=np.asarray(history))
