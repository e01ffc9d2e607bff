"""Yoshida's triple jump, and how the steps of a composition report to the driver."""

from __future__ import annotations

import jax.numpy as jnp

from .._support.solution import RESULTS
from .base import StepInfo

# gamma1 = 1/(2 - 2^(1/3)), gamma0 = 1 - 2 gamma1: Phi_{g1 t} o Phi_{g0 t} o Phi_{g1 t} of a
# symmetric order-2 step Phi is symmetric of order 4 (g0 < 0: the middle step runs backwards).
GAMMA1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
GAMMA0 = 1.0 - 2.0 * GAMMA1
TRIPLE_JUMP = (GAMMA1, GAMMA0, GAMMA1)


def combine(infos):
    """One `StepInfo` for consecutive solves: the first failure's result (successful if
    none failed), iterations summed, worst residual."""
    result, iterations, residual = infos[0][:3]
    for info in infos[1:]:
        result = jnp.where(result == RESULTS.successful, info.result, result)
        iterations = iterations + info.iterations
        residual = jnp.maximum(residual, info.residual)
    return StepInfo(result, iterations, residual)
