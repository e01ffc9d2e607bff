"""The exact sampler: the closed-form flow run for the random step."""

from __future__ import annotations

import math

from .._systems.capabilities import NOISE_PROPORTIONAL_TO_DRIFT, RIGID_BODY
from .._systems.elliptic_flow import rigid_body_flow
from .base import AbstractMethod, StrongOrders, explicit_info


class Exact(AbstractMethod):
    r"""$y_{n+1} = \varphi_{\tau_n}(y_n)$, $\tau_n = h + c\Delta W_n$: no discretisation error.

    The noise multiplies the drift's own vector field, so the SDE is the free rigid body
    flow $\varphi$ run to the random time $t + cW(t)$, and composing the exact flow over the
    steps gives the exact solution at every step for the given increments (up to round-off,
    which grows like the flow's conditioning). A reference for the other methods and a fast
    exact sampler of the rigid body; it has no Newton solve. See `drift_flow`. The driver
    evaluates the flow only where a state is saved, at the sum of the step times since the
    last one (`flow_in_time`): one evaluation per sample for the final state only.
    """

    strong_orders = StrongOrders(one=math.inf, increments=None)  # exact for one noise
    poisson = True

    requires = frozenset({RIGID_BODY, NOISE_PROPORTIONAL_TO_DRIFT})
    can_fail = False  # a closed form: no solve

    # The flows compose: the driver sums the step times and evaluates the flow only at the
    # saved states (once for the final state), on the very same increments.
    flow_in_time = staticmethod(rigid_body_flow)

    def step(self, system, y, dt, dW):
        y_next = rigid_body_flow(system, y, dt + system.noise_time(dW)).astype(y.dtype)
        return y_next, explicit_info(y_next)
