"""The paper's comparison method."""

from __future__ import annotations

import dataclasses

from .. import _so3 as so3
from .base import AbstractMethod, explicit_info


@dataclasses.dataclass(frozen=True)
class EulerMaruyama(AbstractMethod):
    r"""$y_{n+1} = y_n + f(y_n)(h + c\Delta W_n)$, the paper's comparison method.

    Applied to the Stratonovich equation as written, it converges to the Itô equation with the
    same coefficients, not to the Stratonovich solution, and it does not conserve $|y|$.
    Works for the `RigidBody` and any `LiePoissonSystem` ($f(y) = y \times \nabla H(y)$).
    """

    def step(self, model, y, dt, dW):
        tau = dt + model.noise_time(dW)
        yc = so3.vec(y)
        f = so3.cross(yc, model.gradient_c(yc))
        y_next = so3.unvec(tuple(yi + tau * fi for yi, fi in zip(yc, f))).astype(y.dtype)
        return y_next, explicit_info(y_next)
