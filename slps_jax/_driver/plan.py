"""What every run checks before anything compiles, and the validated plan of an ensemble.

The checks here need systems and methods: a method against the capabilities of a system
(`check_pair`, the one place a method's `requires` is enforced), `y0` against the system's
algebra and the method's domain, the Lévy-area options. `plan_ensemble` validates the
arguments of an ensemble once, for `simulate`, `ensemble_statistics` and (through
`simulate`) `calibrate`; the studies validate theirs with the same checks.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from .. import _brownian
from .._methods import METHODS, IsospectralMidpoint, Midpoint
from .._methods.base import AbstractMethod
from .._support.checks import (
    check_count,
    check_grid,
    check_options,
    check_save_every,
    concrete,
    numeric_array,
    real_array,
    real_dtype,
)
from .._systems.capabilities import RIGID_BODY, SO3_VECTORS
from .._systems.system import AbstractLiePoissonSystem, check_system
from .failures import Failures, check_failures
from .sharding import check_sharding


def check_pair(method, system):
    """The one check of a method against a system: the capabilities the method `requires`
    (such as the rigid body's closed forms), each tested on the system."""
    missing = method.missing(system)
    if missing:
        works = [cls.__name__ for cls in METHODS if not cls.missing(system)]
        only = " (it works for a RigidBody only)" if RIGID_BODY in missing else ""
        raise TypeError(
            f"{type(method).__name__} needs a system with "
            f"{'; '.join(sorted(map(str, missing)))}{only}; this {type(system).__name__} "
            f"does not have it. Methods for this system: {', '.join(works)}."
        )


def default_method(system):
    """The method `method="auto"` picks for `system`, by the measurements in
    `docs/methods.md` ("Which method").

    **Arguments:**

    - `system`: the system the method is to run on (a `RigidBody`, a `LiePoissonSystem`,
      an `EulerZeitlin`); only its algebra matters.

    **Returns:** a method instance with its default options: `Midpoint()` on so(3)* (the
    smallest error at a given cost among the methods that keep the Casimir, for one noise
    and with Lévy areas for several; it never failed in the stress matrix),
    `IsospectralMidpoint()` on so(n)* and su(N)* (every Casimir kept, the cheapest Poisson
    method there).
    """
    return Midpoint() if SO3_VECTORS(system) else IsospectralMidpoint()


def check_method(method, system=None):
    """`method` checked, or for `"auto"` (with the `system` it runs on) `default_method`."""
    if isinstance(method, str) and method == "auto" and system is not None:
        return default_method(system)
    if not isinstance(method, AbstractMethod):
        accepted = "an instance" if system is None else "'auto' or an instance"
        raise TypeError(
            f"method must be {accepted} such as Midpoint(), got {method!r}"
            + (" (a class: call it)" if isinstance(method, type) else "")
            + "."
        )
    check_options(method)  # again here: a dataclass can be built around its constructor
    return method


def _area_methods():
    return ", ".join(cls.__name__ for cls in METHODS if cls.uses_levy_area())


def check_levy_area(area, n_steps, n_noises, method):
    """The Lévy areas given to `integrate` (`areas`): `None`, or an array of shape
    `(n_steps, s, s)`, finite and antisymmetric, for a method that uses them. Returns the
    array, or `None` for one noise (its areas are zero)."""
    if area is None:
        return None
    if not method.uses_levy_area():
        raise TypeError(
            f"{type(method).__name__} does not use Lévy areas (its step sees only "
            f"the increments); methods that do: {_area_methods()}."
        )
    area = real_array("areas", area)
    shape = (n_steps, n_noises, n_noises)
    if area.shape != shape:
        raise ValueError(
            f"areas must have shape (n_steps, s, s) = {shape}, one "
            f"antisymmetric (s, s) matrix per step, got shape {area.shape}."
        )
    a_np = concrete(area)
    if a_np is not None:
        if not np.all(np.isfinite(a_np)):
            bad = np.flatnonzero(~np.all(np.isfinite(a_np), axis=(1, 2)))
            raise ValueError(f"areas must be finite; steps {bad[:5].tolist()} are not.")
        asym = float(np.max(np.abs(a_np + np.swapaxes(a_np, 1, 2))))
        if asym > 1e-12 * max(1.0, float(np.max(np.abs(a_np)))):
            raise ValueError(
                f"areas must be antisymmetric, A[n, q, r] = -A[n, r, q]; "
                f"max |A + A^T| = {asym:.3g}."
            )
    return None if n_noises == 1 else area


def check_levy_option(levy_area, method, system):
    """Whether an ensemble draws Lévy areas: `"auto"` (for a method that uses them and a
    system with several noises that takes them), `True` (refused for a method that cannot
    use them, and for a system that takes none) or `False`. One noise never needs areas
    (they are zero): `False` then."""
    if isinstance(levy_area, str) and levy_area == "auto":
        return bool(method.uses_levy_area() and system.n_noises > 1 and system.takes_areas)
    if not isinstance(levy_area, (bool, np.bool_)):
        raise TypeError(f"levy_area must be 'auto', True or False, got {levy_area!r}.")
    if levy_area and not method.uses_levy_area():
        raise TypeError(
            f"levy_area=True: {type(method).__name__} does not use Lévy areas; "
            f"methods that do: {_area_methods()}."
        )
    if levy_area and not system.takes_areas:
        raise ValueError(
            "levy_area=True: this system's noises take no Lévy areas (an EulerZeitlin with an "
            "additive forcing); use levy_area='auto' or False."
        )
    return bool(levy_area) and system.n_noises > 1


check_driver = _brownian.check_driver  # (the drivers' module checks what a driver is)


def driver_path(driver, dt, method, system, dtype):
    """The path of a checked `driver` at steps `dt` for `method` on `system`: its Lévy-area
    option resolved (`check_levy_option`)."""
    if isinstance(driver.levy_area, dict):
        raise TypeError(
            "BrownianMotion(levy_area={...}): a dict chooses per method in the convergence "
            "studies; an ensemble of one method takes 'auto', True or False."
        )
    areas = check_levy_option(driver.levy_area, method, system)
    return driver.path(dt, system.n_noises, dtype, levy_area=areas)


def check_y0(y0, method, system):
    check_pair(method, system)
    alg = system.algebra
    y0 = numeric_array("y0", y0, alg.is_complex)
    shape = alg.shape
    if y0.shape != shape:
        several = y0.ndim == len(shape) + 1 and y0.shape[1:] == shape
        raise ValueError(
            f"y0 must have shape {shape} (a state of {system.algebra.name}), got shape "
            f"{y0.shape}"
            + ("; for several initial values use jax.vmap over integrate." if several else ".")
        )
    y0 = y0.astype(alg.state_dtype(system.dtype))
    y_np = concrete(y0)
    if y_np is not None:
        alg.validate("y0", y_np)
        method.check_initial(system, y_np)
    return y0


@dataclasses.dataclass(frozen=True)
class EnsemblePlan:
    """The validated arguments of an ensemble run: `y0` cast to the system's dtype, the step
    count, the checked key, `save_every` as a step count `k` (all `n_steps` when `None`),
    the samples run at a time (`chunk_size`: all of them unless in chunks), the retry, the
    sharding, and the Brownian path (`_brownian.BrownianPath`: the step, the truncation, the
    Lévy areas)."""

    system: AbstractLiePoissonSystem
    method: AbstractMethod
    y0: jax.Array
    dt: float
    n_steps: int
    n_samples: int
    chunk_size: int
    key: object
    save_every: int
    failures: Failures
    sharding: object
    path: _brownian.AbstractPath

    @property
    def dtype(self):
        return real_dtype(self.y0.dtype)

    @property
    def retry(self) -> int | None:
        return self.failures.retry_substeps


def plan_ensemble(
    caller,
    system,
    y0,
    *,
    t1,
    dt,
    n_samples,
    key,
    method,
    save_every,
    failures,
    sharding,
    driver,
    chunk_size=None,
):
    """Check an ensemble's arguments (the sharding against `chunk_size` when it is run in
    chunks) and return its `EnsemblePlan`."""
    check_system(system)
    method = check_method(method, system)
    y0 = check_y0(y0, method, system)
    dt, n_steps = check_grid(caller, t1, dt)
    n_samples = check_count("n_samples", n_samples)
    if chunk_size is None:
        chunk_size = n_samples
        sharding = check_sharding(sharding, n_samples)
    else:
        if n_samples >= 2**32:
            raise ValueError(
                f"n_samples must be below 2^32 (sample indices are uint32), got {n_samples}."
            )
        chunk_size = min(chunk_size, n_samples)  # (a size `Chunks` checked)
        sharding = check_sharding(sharding, chunk_size, name="chunk_size")
    key = _brownian.check_key(key)
    save_every = check_save_every(save_every, n_steps)
    path = driver_path(check_driver(driver), dt, method, system, real_dtype(y0.dtype))
    return EnsemblePlan(
        system,
        method,
        y0,
        dt,
        n_steps,
        n_samples,
        chunk_size,
        key,
        save_every,
        check_failures(caller, failures),
        sharding,
        path,
    )
