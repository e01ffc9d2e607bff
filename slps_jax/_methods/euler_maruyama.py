"""The paper's comparison method."""

from __future__ import annotations

import dataclasses

from .base import AbstractMethod, StrongOrders, explicit_info


@dataclasses.dataclass(frozen=True)
class EulerMaruyama(AbstractMethod):
    r"""$y_{n+1} = y_n + y_n \times \nabla K_n(y_n)$, $K_n = hH_0 + \sum_r \Delta W_{r,n} H_r$
    (for one noise $H_1 = cH_0$: $y_n + f(y_n)(h + c\Delta W_n)$), the paper's comparison
    method.

    Applied to the Stratonovich equation as written, it converges to the Itô equation with the
    same coefficients, not to the Stratonovich solution, and it does not conserve $|y|$.
    Works for any system.
    """

    strong_orders = StrongOrders(one=None, increments=None)  # converges to the Itô equation

    def step(self, model, y, dt, dW):
        y_next = y + model.algebra.field(model, y, dt, dW)
        return y_next.astype(y.dtype), explicit_info(y_next)
