"""slps-jax: structure-preserving integrators for stochastic Lie–Poisson systems in JAX.

The library in four layers:

- **System**: a Lie algebra (`SO3`, 3-vector states; `so(n)`, skew matrices; `su(N)`,
  skew-Hermitian complex matrices; one interface, `AbstractAlgebra`) with a
  drift Hamiltonian and its noise (`c=`, or several noises with their own Hamiltonians:
  `salt_noise`, `random_inertia_noise`, a function), parameters as pytree leaves:
  `LiePoissonSystem` (derivatives by JAX) and its analytic special cases `RigidBody` and
  `GeneralisedRigidBody` (so(n)). A system declares its `structure`.
- **Method**: a small immutable object with `step(model, y, dt, dW)` (`dW` the step's noise,
  a `BrownianStep`: increments and, when drawn, Lévy areas), the structures it `requires`,
  its `strong_orders` by kind of noise and whether it is `poisson`; implicit methods share
  one Newton solver whose `RESULTS` code says why a step failed.
- **Driver**: `integrate` (given increments), `simulate` (an ensemble, increments drawn inside),
  `ensemble_statistics` (streamed moments); it owns the time loop, saving, statistics and
  failures, and refuses a method that the system cannot serve.
- **Studies**: `strong_convergence`, `weak_convergence`, `calibrate`, exact solutions of the
  rigid body.
"""

# System
from ._algebra import AbstractAlgebra as AbstractAlgebra, SO3 as SO3, so as so, su as su
from ._model import (PAPER_Y0 as PAPER_Y0, GeneralisedRigidBody as GeneralisedRigidBody,
                     RigidBody as RigidBody)
from ._system import LiePoissonSystem as LiePoissonSystem
from ._euler_zeitlin import EulerZeitlin as EulerZeitlin
from ._noise_hamiltonians import random_inertia_noise as random_inertia_noise, salt_noise as salt_noise

# Methods
from ._methods.base import (AbstractMethod as AbstractMethod, StepInfo as StepInfo,
                           StrongOrders as StrongOrders)
from ._methods.euler_maruyama import EulerMaruyama as EulerMaruyama
from ._methods.exact import Exact as Exact
from ._methods.heun import Heun as Heun
from ._methods.isospectral import IsospectralMidpoint as IsospectralMidpoint
from ._methods.lie_poisson import LiePoisson as LiePoisson
from ._methods.lie_poisson_sym import LiePoissonSym2 as LiePoissonSym2, LiePoissonSym4 as LiePoissonSym4
from ._methods.midpoint import Midpoint as Midpoint
from ._methods.milstein import Milstein as Milstein
from ._methods.strang import SaltSplitting as SaltSplitting, Strang as Strang, Strang4 as Strang4

# Driver
from ._integrate import integrate as integrate, simulate as simulate
from ._plan import default_method as default_method
from ._noise import BrownianStep as BrownianStep, brownian_increments as brownian_increments
from ._solution import RESULTS as RESULTS, Solution as Solution
from ._stream import EnsembleStatistics as EnsembleStatistics, ensemble_statistics as ensemble_statistics

# Studies
from ._calibrate import CalibrationResult as CalibrationResult, calibrate as calibrate, moments as moments
from ._convergence import (ConvergenceResult as ConvergenceResult, WeakConvergenceResult as WeakConvergenceResult,
                           strong_convergence as strong_convergence, weak_convergence as weak_convergence)
from ._exact import exact_flow as exact_flow, exact_solution as exact_solution
from ._flow import deterministic_flow as deterministic_flow
from . import so3 as so3, zeitlin as zeitlin

__version__ = "0.1.0"
