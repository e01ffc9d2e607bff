"""Strong order against the exact time-change solution y(T) = phi_{T + c W(T)}(y0)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import exact_sde_solution, fitted_order

import slps_jax as sj
from slps_jax._methods import METHODS

N_SAMPLES = 200
LEVELS = [5, 6, 7, 8, 9]  # h = 2^-5 ... 2^-9


@pytest.fixture(scope="module")
def study():
    model, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    h_fine = 2.0 ** -LEVELS[-1]
    fine = sj.BrownianMotion().increments(
        jax.random.key(42), 2 ** LEVELS[-1], h_fine, n_samples=N_SAMPLES
    )
    exact = exact_sde_solution(model.inertia, float(model.c), y0, np.asarray(fine.sum(1)), 1.0)
    return model, y0, fine, exact


_CACHE = {}


def rms_errors(study, method):
    if method not in _CACHE:
        _CACHE[method] = _rms_errors(study, method)
    return _CACHE[method]


def _rms_errors(study, method):
    model, y0, fine, exact = study
    errs, hs = [], []
    for level in LEVELS:
        factor = 2 ** (LEVELS[-1] - level)
        coarse = fine.reshape(N_SAMPLES, -1, factor).sum(-1)  # the same Brownian paths
        h = 2.0**-level
        run = jax.jit(
            jax.vmap(
                lambda dW: sj.integrate(
                    model, y0, dW, h, method=method, failures=sj.Failures(throw=False)
                )
            )
        )
        y_end = run(coarse)
        errs.append(float(np.sqrt(np.mean(np.sum((np.asarray(y_end) - exact) ** 2, -1)))))
        hs.append(h)
    return np.array(hs), np.array(errs)


# Every method of the registry that runs on the paper's rigid body (`c=`): its declared
# order for one noise proportional to the drift, `strong_orders.one` (`test_levy_order.py`
# checks `increments` and `areas` for the same registry).
ONE_NOISE = [cls for cls in METHODS if not cls.missing(sj.RigidBody.paper())]


@pytest.mark.parametrize("cls", ONE_NOISE, ids=lambda cls: cls.__name__)
def test_declared_strong_order_for_one_noise(study, cls):
    """`one`: the fitted order within [0.85, 1.2] times the declared one, errors falling
    with h; `inf` (an exact sampler): round-off at every h; `None` (Euler–Maruyama, the Ito
    solution): no convergence to the Stratonovich solution."""
    declared = cls.strong_orders.one
    hs, errs = rms_errors(study, cls())
    order = fitted_order(hs, errs)
    if declared is None:
        assert order <= 0.4, (order, errs)
    elif declared == float("inf"):
        assert np.max(errs) < 1e-13, errs
    else:
        assert 0.85 * declared <= order <= 1.2 * declared, (order, errs)
        assert np.all(np.diff(errs) < 0), errs


def test_without_kappa_term_no_convergence(study):
    hs, errs = rms_errors(study, sj.LiePoisson(second_order=False))
    assert fitted_order(hs, errs) <= 0.4, errs
    _, errs_full = rms_errors(study, sj.LiePoisson())
    assert errs[-1] > 10 * errs_full[-1]
