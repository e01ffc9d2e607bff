"""The methods: one module each, and `METHODS`, the registry the driver's check names
alternatives from."""

from .euler_maruyama import EulerMaruyama
from .exact import Exact
from .heun import Heun
from .isospectral import IsospectralMidpoint
from .lie_poisson import LiePoisson
from .lie_poisson_sym import LiePoissonSym2, LiePoissonSym4
from .midpoint import Midpoint
from .milstein import Milstein
from .strang import SaltSplitting, Strang, Strang4

METHODS = (
    LiePoisson,
    LiePoissonSym2,
    LiePoissonSym4,
    Midpoint,
    IsospectralMidpoint,
    Strang,
    Strang4,
    SaltSplitting,
    Exact,
    Heun,
    Milstein,
    EulerMaruyama,
)
