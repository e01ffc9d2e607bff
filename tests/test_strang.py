"""The Strang splitting: sub-flows, local order, Casimir, jit/vmap/float32 (its strong order:
tests/test_convergence.py, with every method of the registry)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import rigid_body_flow
from scipy.integrate import solve_ivp

import slps_jax as sj
from slps_jax._algebra import so3 as comp
from slps_jax._methods.strang import axis_flow

rng = np.random.default_rng(7)
step = jax.jit(lambda model, y, dt, dW: sj.Strang().step(model, y, dt, dW))


def one_step(model, y, tau):
    y_next, info = step(model, y, jnp.asarray(tau), jnp.asarray(0.0))
    assert bool(info.ok)
    return np.asarray(y_next)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_local_error_is_third_order(paper, sign):
    # A generic initial value: at PAPER_Y0 = (0.7, 0.7, 0) the tau^3 term of the local error
    # happens to vanish (y_3 = 0) and the ratios are 16, not 8.
    model, _ = paper
    y0 = jnp.asarray([0.3, -0.5, 0.8])
    taus = sign * 0.2 * 2.0 ** -np.arange(5)
    errs = np.array(
        [
            np.linalg.norm(one_step(model, y0, t) - rigid_body_flow(model.inertia, y0, t))
            for t in taus
        ]
    )
    ratios = errs[:-1] / errs[1:]
    assert np.all(np.abs(ratios - 8.0) < 0.4), (errs, ratios)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("tau", [0.7, -1.3])
def test_axis_flow_matches_scipy(axis, tau):
    inertia = rng.uniform(0.5, 3.0, 3)
    y = rng.normal(size=3)
    e = np.eye(3)[axis]

    def rhs(_, x):
        return np.cross(x, x[axis] / inertia[axis] * e)  # y x grad H_i(y)

    ref = solve_ivp(rhs, (0.0, tau), y, method="DOP853", rtol=1e-13, atol=1e-15).y[:, -1]
    got = comp.unvec(
        axis_flow(
            comp.vec(jnp.asarray(y)),
            comp.vec(jnp.asarray(1.0 / inertia)),
            axis,
            jnp.asarray(tau),
        )
    )
    np.testing.assert_allclose(np.asarray(got), ref, rtol=0, atol=1e-12)


def test_axis_vector_fields_sum_to_full_vector_field(paper):
    model, _ = paper
    y = jnp.asarray(rng.normal(size=3))
    total = sum(
        jax.jvp(
            lambda t, a=axis: comp.unvec(
                axis_flow(comp.vec(y), comp.vec(model.inverse_inertia()), a, t)
            ),
            (jnp.asarray(0.0),),
            (jnp.asarray(1.0),),
        )[1]
        for axis in range(3)
    )
    np.testing.assert_allclose(
        np.asarray(total), np.asarray(model.vector_field(y)), rtol=0, atol=1e-15
    )


def test_casimir_preserved_over_many_steps(paper):
    model, y0 = paper
    n, h = 10_000, 0.01
    dW = sj.BrownianMotion().increments(jax.random.key(3), n, h)
    ys = sj.integrate(model, y0, dW, h, method=sj.Strang(), save_every=100)
    norms = np.linalg.norm(np.asarray(ys), axis=-1)
    drift = np.max(np.abs(norms / np.linalg.norm(y0) - 1.0))
    assert drift < 1e-13, drift


# --------------------------------------------------------------------------------------
# Transformations and precision.


def test_jit_and_vmap_agree_with_single_steps(paper):
    model, _ = paper
    ys = jnp.asarray(rng.normal(size=(8, 3)))
    dWs = jnp.asarray(rng.normal(size=8) * 0.1)
    batched, info = jax.jit(jax.vmap(lambda y, w: sj.Strang().step(model, y, 0.1, w)))(ys, dWs)
    assert info.ok.shape == (8,) and bool(jnp.all(info.ok))
    assert np.all(np.asarray(info.iterations) == 0)
    single = np.stack([np.asarray(sj.Strang().step(model, y, 0.1, w)[0]) for y, w in zip(ys, dWs)])
    np.testing.assert_allclose(np.asarray(batched), single, rtol=0, atol=1e-15)


def test_float32(paper):
    model64, y0 = paper
    model32 = sj.RigidBody(np.asarray(model64.inertia, np.float32), np.float32(0.2))
    assert model32.inertia.dtype == jnp.float32
    n, h = 1000, 0.01
    dW = sj.BrownianMotion().increments(jax.random.key(5), n, h)
    y32 = sj.integrate(
        model32, y0.astype(jnp.float32), dW.astype(jnp.float32), h, method=sj.Strang()
    )
    y64 = sj.integrate(model64, y0, dW, h, method=sj.Strang())
    assert y32.dtype == jnp.float32
    assert np.linalg.norm(np.asarray(y32, np.float64) - np.asarray(y64)) < 1e-4
    assert abs(float(jnp.linalg.norm(y32)) / float(jnp.linalg.norm(y0)) - 1.0) < 1e-5
