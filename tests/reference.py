"""Independent references for the tests: scipy, not the library."""

import numpy as np
from scipy.integrate import solve_ivp


def rigid_body_flow(inertia, y0, t, rtol=1e-13, atol=1e-15):
    """phi_t(y0) of dy/dt = y x I^{-1} y by DOP853 (t may be negative)."""
    inertia = np.asarray(inertia, float)
    y0 = np.asarray(y0, float)
    if t == 0:
        return y0.copy()
    sol = solve_ivp(
        lambda _, y: np.cross(y, y / inertia),
        (0.0, float(t)),
        y0,
        method="DOP853",
        rtol=rtol,
        atol=atol,
    )
    assert sol.success
    return sol.y[:, -1]


def exact_sde_solution(inertia, c, y0, w_t, t):
    """y(t) = phi_{t + c W(t)}(y0): the SDE is a random time change of the flow."""
    return np.stack([rigid_body_flow(inertia, y0, t + c * w) for w in np.asarray(w_t)])


def fitted_order(hs, errors):
    """Least-squares slope of log(error) against log(h)."""
    slope, _ = np.polyfit(np.log(np.asarray(hs, float)), np.log(np.asarray(errors, float)), 1)
    return float(slope)
