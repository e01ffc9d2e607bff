"""The Lie algebras a system may live on, behind one interface (`AbstractAlgebra`)."""

from .base import (SO3_VECTORS as SO3_VECTORS, AbstractAlgebra as AbstractAlgebra,
                   adjoint as adjoint, matmul as matmul)
from .so3 import SO3 as SO3, SO3Algebra as SO3Algebra
from .son import SOnAlgebra as SOnAlgebra, so as so
from .sun import SUnAlgebra as SUnAlgebra, su as su
