"""What every method provides: the interface, its declarations and the step report."""

from __future__ import annotations

import abc
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from .._support.checks import real_dtype
from .._support.solution import RESULTS


class StepInfo(NamedTuple):
    """What one step reports to the driver.

    - `result`: a `RESULTS` code: `successful`, or why the step failed.
    - `iterations`: Newton updates used (0 for explicit methods).
    - `residual`: max-norm of the final residual (0 for explicit methods).
    - `history`: what the method keeps for the next step (`AbstractMethod.initial_history`),
      updated by this one; `()` for methods that keep nothing.
    """

    result: jax.Array
    iterations: jax.Array
    residual: jax.Array
    history: Any = ()

    @property
    def ok(self):
        """The step succeeded (for implicit methods: the solve converged on the branch)."""
        return self.result == RESULTS.successful


class StrongOrders(NamedTuple):
    """A method's strong orders by kind of noise, as measured (each is checked for every
    method of the registry by a test against an independent reference).

    - `one`: one noise proportional to the drift (`c=`; commuting noises alike).
    - `increments`: several non-commuting noises, the step seeing only the increments
      (Clark & Cameron: at most 1/2).
    - `areas`: several non-commuting noises with the Lévy areas; `None`: the method does not
      use them (the driver then draws none and refuses them).

    `None` for `one` or `increments`: the method does not converge to the Stratonovich
    solution there, or cannot run on such a system.
    """

    one: float | None
    increments: float | None
    areas: float | None = None


class AbstractMethod(eqx.Module):
    """A one-step method for
    $dy = y \\times \\nabla H_0(y)\\,dt + \\sum_r y \\times \\nabla H_r(y) \\circ dW_r$ (on so(n):
    $dY = [Y, \\nabla H_0]\\,dt + \\sum_r [Y, \\nabla H_r] \\circ dW_r$).

    A method is a small immutable (hashable) object; the driver owns the loop, the noise,
    saving and failure handling. Subclasses implement `step`, and may override `check_initial`
    to reject initial values outside their domain before anything is compiled.
    """

    # The capabilities a system must have (`Capability` objects, each a test of the system:
    # `RIGID_BODY`, `NOISE_PROPORTIONAL_TO_DRIFT`, ...); the driver refuses a pair that lacks
    # one and names the methods that would work. Empty: any system.
    requires: ClassVar[frozenset] = frozenset()

    # Whether a step can fail on finite input (an implicit solve without an admissible root,
    # an explicit step that overflows). Exact flows and compositions of exact rotations
    # cannot: for them the driver leaves out the retry of failing steps (`retry_substeps`),
    # which would be dead code, and whose derivative rule would double the reverse pass's
    # compile time.
    can_fail = True

    # A method whose step with increments (h, dW) is a flow for the time h + c dW, composing
    # in time, sets this to that flow, `flow_in_time(system, y, tau)`: the driver then adds up
    # the times and evaluates the flow only where a state is saved (`Exact`).
    flow_in_time = None

    # The strong orders by kind of noise (`StrongOrders`). A method whose `areas` order is
    # not `None` uses the Lévy areas of the noises (`BrownianStep.area`): the area term
    # $\sum_{q<r} A_{qr}[f_q, f_r]$ in the step, which makes it strong order 1 with several
    # non-commuting noises; the driver draws areas for it (`levy_area`) and refuses to give
    # them to one that would ignore them.
    strong_orders = StrongOrders(one=None, increments=None)

    # Whether the step is a Poisson map: it keeps the Casimirs (for the quadratic one, a
    # theorem for every Poisson method; the higher ones on so(n) only for coadjoint-orbit
    # methods such as `IsospectralMidpoint` and `LiePoisson`).
    poisson = False

    @classmethod
    def missing(cls, system):
        """The capabilities in `requires` that `system` lacks (empty: the method runs on it)."""
        return [capability for capability in cls.requires if not capability(system)]

    @classmethod
    def uses_levy_area(cls):
        """Whether the step uses the Lévy areas (`strong_orders.areas` is not `None`)."""
        return cls.strong_orders.areas is not None

    @abc.abstractmethod
    def step(self, system, y, dt, dW):
        """Advance one sample by one step.

        **Arguments:** `system` (a system offering `requires`), `y` a state (shape
        `system.algebra.shape`), the step `dt` (a scalar) and the step's noise `dW`: a
        `BrownianStep` (increments of shape `(system.n_noises,)`, and Lévy areas when the
        method `uses_levy_area()` and the driver drew them), or an array of increments (a step
        without areas). The system's step functions (`step_gradient`, ...) take it as it is.

        **Returns:** `(y_next, StepInfo)`.
        """

    def initial_history(self, system, y0):
        """What the method keeps from one step to the next before the first step (a pytree
        of arrays: `IsospectralMidpoint`'s earlier increments, its fixed point's warm start),
        or `()` (default) for a method that keeps nothing. A method that keeps something takes
        it as `step(..., history=...)` and returns it updated in `StepInfo.history`; the
        driver carries it per sample, over live steps only, so that paths do not depend on
        the loop's layout."""
        return ()

    def check_initial(self, system, y0):
        """Raise `ValueError` if the concrete initial value `y0` (NumPy, of the state's shape) is outside
        the method's domain."""


def explicit_info(y):
    """`StepInfo` of an explicit step: successful iff the new state is finite."""
    return StepInfo(finite_result(y), jnp.zeros((), jnp.int32), jnp.zeros((), real_dtype(y.dtype)))


def finite_result(y, result: jax.Array | int = RESULTS.successful):
    """`result`, or `RESULTS.nonfinite` where it is `successful` but `y` has a non-finite
    entry (a step that failed keeps the reason it gave)."""
    bad = (result == RESULTS.successful) & ~jnp.all(jnp.isfinite(y))
    return jnp.where(bad, RESULTS.nonfinite, result).astype(jnp.int32)


def default_tol(dtype):
    """Residual tolerance in the max-norm: a small multiple of the unit round-off. Residuals of
    these O(1) maps cannot be evaluated more accurately than a few ulps."""
    return 64.0 * float(jnp.finfo(dtype).eps)
