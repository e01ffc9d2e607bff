"""slps-jax: structure-preserving integrators for stochastic Lie–Poisson systems in JAX.

The library in four layers:

- **System**: a Lie algebra (`SO3`, 3-vector states; `so(n)`, skew matrices; `su(N)`,
  skew-Hermitian complex matrices; one interface, `AbstractAlgebra`) with a
  drift Hamiltonian and its noise, a family (`c=`, one noise proportional to the drift,
  `proportional_noise`; or several noises with their own Hamiltonians: `salt_noise`,
  `random_inertia_noise`, a function), parameters as pytree leaves:
  `LiePoissonSystem` (derivatives by JAX) and its analytic special cases `RigidBody` and
  `GeneralisedRigidBody` (so(n)), all final cases of `AbstractLiePoissonSystem`.
- **Method**: a small immutable object with `step(system, y, dt, dW)` (`dW` the step's noise,
  a `BrownianStep`: increments and, when drawn, Lévy areas), the capabilities it `requires`,
  its `strong_orders` by kind of noise and whether it is `poisson`; implicit methods share
  one Newton solver whose `RESULTS` code says why a step failed.
- **Driver**: `integrate` (given increments), `simulate` (an ensemble, increments drawn inside),
  `ensemble_statistics` (streamed moments); it owns the time loop, saving, statistics and
  failures, and refuses a method that the system cannot serve.
- **Studies**: `strong_convergence`, `weak_convergence`, `calibrate`; the drift's flow
  `drift_flow` and, with one noise proportional to the drift, the `exact_solution`.
- **Forecasting**: `fit_transport_noise`, `fit_closure`, `train_closure`, `forecast_ensembles`
  and their scores, `particle_filter`, `ensemble_kalman_filter` and `assimilate`.
"""

# Public helper modules
from . import so3 as so3
from . import sphere as sphere
from . import zeitlin as zeitlin

# Algebras
from ._algebra import SO3 as SO3
from ._algebra import AbstractAlgebra as AbstractAlgebra
from ._algebra import so as so
from ._algebra import su as su

# Brownian motion
from ._brownian import BrownianMotion as BrownianMotion
from ._brownian import BrownianStep as BrownianStep
from ._brownian import OrnsteinUhlenbeck as OrnsteinUhlenbeck

# Driver
from ._driver.failures import Failures as Failures
from ._driver.integrate import integrate as integrate
from ._driver.integrate import simulate as simulate
from ._driver.long_run import simulate_to_store as simulate_to_store
from ._driver.plan import default_method as default_method
from ._driver.stream import Chunks as Chunks
from ._driver.stream import EnsembleStatistics as EnsembleStatistics
from ._driver.stream import Statistics as Statistics
from ._driver.stream import ensemble_statistics as ensemble_statistics

# Studies
from ._forecasting.assimilation import FilterResult as FilterResult
from ._forecasting.assimilation import Forecast as Forecast
from ._forecasting.assimilation import Observations as Observations
from ._forecasting.assimilation import Tempering as Tempering
from ._forecasting.assimilation import assimilate as assimilate
from ._forecasting.closure import ClosureFit as ClosureFit
from ._forecasting.closure import fit_closure as fit_closure
from ._forecasting.closure_training import train_closure as train_closure
from ._forecasting.orbit_kalman import KalmanAnalysis as KalmanAnalysis
from ._forecasting.orbit_kalman import KalmanResult as KalmanResult
from ._forecasting.orbit_kalman import Localization as Localization
from ._forecasting.orbit_kalman import ensemble_kalman_filter as ensemble_kalman_filter
from ._forecasting.particle_filter import particle_filter as particle_filter
from ._forecasting.particle_filter import particle_filter_to_store as particle_filter_to_store
from ._forecasting.scores import ForecastScores as ForecastScores
from ._forecasting.scores import PairedComparison as PairedComparison
from ._forecasting.scores import crps_ensemble as crps_ensemble
from ._forecasting.scores import forecast_scores as forecast_scores
from ._forecasting.scores import paired_comparison as paired_comparison
from ._forecasting.transport_fit import TransportNoiseFit as TransportNoiseFit
from ._forecasting.transport_fit import fit_transport_noise as fit_transport_noise
from ._forecasting.verification import AmplitudeSearch as AmplitudeSearch
from ._forecasting.verification import AmplitudeTuning as AmplitudeTuning
from ._forecasting.verification import ModelErrorVariance as ModelErrorVariance
from ._forecasting.verification import forecast_ensembles as forecast_ensembles
from ._forecasting.verification import model_error_variance as model_error_variance
from ._forecasting.verification import scaled_noise as scaled_noise
from ._forecasting.verification import start_crps as start_crps
from ._forecasting.verification import tune_amplitude as tune_amplitude

# Methods
from ._methods.base import AbstractMethod as AbstractMethod
from ._methods.base import StepInfo as StepInfo
from ._methods.base import StrongOrders as StrongOrders
from ._methods.euler_maruyama import EulerMaruyama as EulerMaruyama
from ._methods.exact import Exact as Exact
from ._methods.heun import Heun as Heun
from ._methods.isospectral import IsospectralMidpoint as IsospectralMidpoint
from ._methods.lie_poisson import LiePoisson as LiePoisson
from ._methods.lie_poisson_sym import LiePoissonSym2 as LiePoissonSym2
from ._methods.lie_poisson_sym import LiePoissonSym4 as LiePoissonSym4
from ._methods.midpoint import Midpoint as Midpoint
from ._methods.milstein import Milstein as Milstein
from ._methods.strang import SaltSplitting as SaltSplitting
from ._methods.strang import Strang as Strang
from ._methods.strang import Strang4 as Strang4
from ._studies.calibrate import CalibrationResult as CalibrationResult
from ._studies.calibrate import ObservedStatistics as ObservedStatistics
from ._studies.calibrate import Optimisation as Optimisation
from ._studies.calibrate import calibrate as calibrate
from ._studies.calibrate import moments as moments
from ._studies.convergence import ConvergenceResult as ConvergenceResult
from ._studies.convergence import Reference as Reference
from ._studies.convergence import WeakConvergenceResult as WeakConvergenceResult
from ._studies.convergence import strong_convergence as strong_convergence
from ._studies.convergence import weak_convergence as weak_convergence
from ._support.saving import load as load
from ._support.saving import save as save

# Results: the failure codes, a run's Solution
from ._support.solution import RESULTS as RESULTS
from ._support.solution import Solution as Solution

# Long runs on disk (needs zarr: pip install "slps-jax[store]")
from ._support.store import Checkpoint as Checkpoint
from ._support.store import RunStore as RunStore
from ._support.store import Store as Store
from ._support.store import StoredRun as StoredRun
from ._support.store import open_run as open_run

# Systems
from ._systems.additive_forcing import AdditiveForcing as AdditiveForcing
from ._systems.euler_zeitlin import EulerZeitlin as EulerZeitlin
from ._systems.flow import drift_flow as drift_flow
from ._systems.flow import exact_solution as exact_solution
from ._systems.noise import AbstractNoise as AbstractNoise
from ._systems.noise import proportional_noise as proportional_noise
from ._systems.noise import random_inertia_noise as random_inertia_noise
from ._systems.noise import salt_noise as salt_noise
from ._systems.rigid_body import PAPER_Y0 as PAPER_Y0
from ._systems.rigid_body import GeneralisedRigidBody as GeneralisedRigidBody
from ._systems.rigid_body import RigidBody as RigidBody
from ._systems.stream_operator import Stream as Stream
from ._systems.system import AbstractLiePoissonSystem as AbstractLiePoissonSystem
from ._systems.system import LiePoissonSystem as LiePoissonSystem

# The public names: everything above, and nothing else (tests/test_api.py checks it).
__all__ = [
    "so3",
    "sphere",
    "zeitlin",
    "SO3",
    "AbstractAlgebra",
    "so",
    "su",
    "BrownianMotion",
    "BrownianStep",
    "OrnsteinUhlenbeck",
    "Failures",
    "integrate",
    "simulate",
    "simulate_to_store",
    "default_method",
    "Chunks",
    "EnsembleStatistics",
    "Statistics",
    "ensemble_statistics",
    "AbstractMethod",
    "StepInfo",
    "StrongOrders",
    "EulerMaruyama",
    "Exact",
    "Heun",
    "IsospectralMidpoint",
    "LiePoisson",
    "LiePoissonSym2",
    "LiePoissonSym4",
    "Midpoint",
    "Milstein",
    "SaltSplitting",
    "Strang",
    "Strang4",
    "FilterResult",
    "Forecast",
    "Observations",
    "Tempering",
    "KalmanAnalysis",
    "KalmanResult",
    "Localization",
    "assimilate",
    "CalibrationResult",
    "ObservedStatistics",
    "Optimisation",
    "calibrate",
    "moments",
    "ConvergenceResult",
    "Reference",
    "WeakConvergenceResult",
    "strong_convergence",
    "weak_convergence",
    "particle_filter",
    "particle_filter_to_store",
    "ensemble_kalman_filter",
    "ForecastScores",
    "PairedComparison",
    "crps_ensemble",
    "forecast_scores",
    "paired_comparison",
    "TransportNoiseFit",
    "ClosureFit",
    "fit_closure",
    "train_closure",
    "fit_transport_noise",
    "AmplitudeSearch",
    "AmplitudeTuning",
    "ModelErrorVariance",
    "forecast_ensembles",
    "model_error_variance",
    "scaled_noise",
    "start_crps",
    "tune_amplitude",
    "RESULTS",
    "Solution",
    "Checkpoint",
    "RunStore",
    "Store",
    "StoredRun",
    "open_run",
    "load",
    "save",
    "AdditiveForcing",
    "EulerZeitlin",
    "drift_flow",
    "exact_solution",
    "AbstractNoise",
    "proportional_noise",
    "random_inertia_noise",
    "salt_noise",
    "Stream",
    "PAPER_Y0",
    "GeneralisedRigidBody",
    "RigidBody",
    "AbstractLiePoissonSystem",
    "LiePoissonSystem",
]

# The architecture, bottom to top: a unit (a subpackage, or a top-level module) imports only
# units of its own layer or below (tests/test_layering.py reads this).
_LAYERS = (
    ("_support", "zeitlin"),  # leaves: import nothing of the package
    ("_brownian", "_algebra", "so3", "sphere"),
    ("_systems",),
    ("_methods",),
    ("_driver",),
    ("_studies", "_forecasting"),
    ("__init__",),
    ("_cli", "__main__"),  # the command line
)

__version__ = "0.1.0"
