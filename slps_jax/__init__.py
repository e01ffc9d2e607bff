"""slps-jax: structure-preserving integrators for stochastic Lie–Poisson systems in JAX."""

from ._integrate import integrate as integrate, simulate as simulate
from ._model import PAPER_Y0 as PAPER_Y0, RigidBody as RigidBody
from ._noise import brownian_increments as brownian_increments
from ._solution import RESULTS as RESULTS, Solution as Solution
from ._solver.base import AbstractMethod as AbstractMethod, StepInfo as StepInfo
from ._solver.euler_maruyama import EulerMaruyama as EulerMaruyama
from ._solver.lie_poisson import LiePoisson as LiePoisson
from ._solver.midpoint import Midpoint as Midpoint
from . import so3 as so3

__version__ = "0.1.0"
