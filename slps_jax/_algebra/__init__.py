"""The Lie algebras a system may live on, behind one interface (`AbstractAlgebra`)."""

from .base import AbstractAlgebra as AbstractAlgebra
from .base import adjoint as adjoint
from .base import matmul as matmul
from .so3 import SO3 as SO3
from .so3 import SO3Algebra as SO3Algebra
from .son import SOnAlgebra as SOnAlgebra
from .son import so as so
from .sun import SUnAlgebra as SUnAlgebra
from .sun import su as su
