"""slps-jax: structure-preserving integrators for stochastic Lie–Poisson systems in JAX."""

from ._calibrate import CalibrationResult as CalibrationResult, calibrate as calibrate, moments as moments
from ._convergence import ConvergenceResult as ConvergenceResult, strong_convergence as strong_convergence
from ._exact import exact_flow as exact_flow, exact_solution as exact_solution
from ._integrate import integrate as integrate, simulate as simulate
from ._model import PAPER_Y0 as PAPER_Y0, RigidBody as RigidBody
from ._noise import brownian_increments as brownian_increments
from ._stream import EnsembleStatistics as EnsembleStatistics, ensemble_statistics as ensemble_statistics
from ._solution import RESULTS as RESULTS, Solution as Solution
from ._solver.base import AbstractMethod as AbstractMethod, StepInfo as StepInfo
from ._solver.euler_maruyama import EulerMaruyama as EulerMaruyama
from ._solver.exact import Exact as Exact
from ._solver.lie_poisson import LiePoisson as LiePoisson
from ._solver.lie_poisson_sym import LiePoissonSym2 as LiePoissonSym2, LiePoissonSym4 as LiePoissonSym4
from ._solver.midpoint import Midpoint as Midpoint
from ._solver.strang import Strang as Strang, Strang4 as Strang4
from ._system import LiePoissonSystem as LiePoissonSystem
from . import so3 as so3

__version__ = "0.1.0"
