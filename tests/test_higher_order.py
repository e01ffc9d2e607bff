"""LiePoissonSym2, LiePoissonSym4, Strang4: definitions, local and strong order, Casimir,
failures, float32.

References are independent of the code under test: autodiff of the generating function
(docs/scheme.md), scipy's DOP853, the exact time-change solution (itself checked against scipy in
test_exact.py), and theorems (adjoint, symmetry, order of a composition).
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import fitted_order, rigid_body_flow

import slps_jax as sj
from slps_jax import so3
from slps_jax._algebra import so3 as comp
from slps_jax._methods.lie_poisson_sym import _solve_rotation

rng = np.random.default_rng(11)
SYM = [sj.LiePoissonSym2(), sj.LiePoissonSym4(), sj.Strang4()]
ids = lambda m: type(m).__name__


def jit_step(method):
    return jax.jit(lambda model, y, dt, dW: method.step(model, y, dt, dW))


STEPS = {type(m).__name__: jit_step(m) for m in SYM}


def one_step(method, model, y, tau):
    y1, info = STEPS[type(method).__name__](model, jnp.asarray(y), jnp.asarray(tau), 0.0)
    assert bool(info.ok)
    return np.asarray(y1)


def s_bar(a, inertia, tau):
    """S-bar(A) = tr(A)/2 - tau H(v(A)), kappa = 0, straight from docs/scheme.md."""
    v = so3.vee(a)
    return 0.5 * jnp.trace(a) - tau * 0.5 * jnp.dot(v, v / inertia)


def out_map(a, inertia, tau):
    return so3.vee(-2.0 * so3.skew(jax.grad(s_bar)(a, inertia, tau) @ a.T))


def in_map(a, inertia, tau):
    return so3.vee(-2.0 * so3.skew(a.T @ jax.grad(s_bar)(a, inertia, tau)))


# --------------------------------------------------------------------------------------
# The building blocks against their definitions.


@pytest.mark.parametrize("tau", [0.2, -0.35])
def test_adjoint_step_solves_the_out_map_with_minus_tau(paper, tau):
    """psi*_tau(z) = A^T z with z = out(A; -tau): check the hint B = A^T, in-map at -z, -tau,
    against the out-map of the generating function (autodiff)."""
    model, _ = paper
    z = jnp.asarray([0.3, -0.5, 0.6])
    b, info = _solve_rotation(model, comp.vec(-z), -tau, jnp.zeros(1), 1.0, 1e-14, 12, True)
    assert bool(info.ok)
    a = comp.unmat(b).T
    np.testing.assert_allclose(out_map(a, model.inertia, -tau), z, atol=1e-14)
    np.testing.assert_allclose(a.T @ a, np.eye(3), atol=1e-14)
    assert np.trace(a) > 1.0
    # and psi_{-tau} maps psi*_tau(z) = A^T z back to z: its in-map holds at A^T z
    np.testing.assert_allclose(in_map(a, model.inertia, -tau), a.T @ z, atol=1e-14)


@pytest.mark.parametrize("method", SYM[:2], ids=ids)
def test_step_is_symmetric(paper, method):
    """Phi_{-tau} o Phi_tau = id for a symmetric method (the triple jump keeps symmetry)."""
    model, _ = paper
    y = np.array([0.3, -0.5, 0.6])
    back = one_step(method, model, one_step(method, model, y, 0.3), -0.3)
    np.testing.assert_allclose(back, y, atol=1e-14)


@pytest.mark.parametrize("method,order", [(SYM[0], 2), (SYM[1], 4), (SYM[2], 4)], ids=ids)
def test_local_error_order(paper, method, order):
    """One deterministic step from a generic y: local error O(tau^(p+1)) against DOP853."""
    model, _ = paper
    y = np.array([0.3, -0.5, 0.6])
    taus = 0.2 * 2.0 ** -np.arange(4)
    errs = np.array(
        [
            np.linalg.norm(one_step(method, model, y, t) - rigid_body_flow(model.inertia, y, t))
            for t in taus
        ]
    )
    slopes = np.log2(errs[:-1] / errs[1:])
    assert np.all(np.abs(slopes - (order + 1)) < 0.15), (errs, slopes)


def test_strang4_is_the_triple_jump_of_strang(paper):
    model, _ = paper
    y, tau = jnp.asarray([0.5, 0.1, -0.7]), 0.3
    g1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
    u = y
    for g in (g1, 1.0 - 2.0 * g1, g1):
        u, _ = sj.Strang().step(model, u, jnp.asarray(g * tau), 0.0)
    np.testing.assert_allclose(one_step(sj.Strang4(), model, y, tau), u, atol=1e-15)


# --------------------------------------------------------------------------------------
# Strong order against the exact solution, all on the same 200 Brownian paths.


@pytest.fixture(scope="module")
def study():
    return sj.strong_convergence(
        sj.RigidBody.paper(),
        sj.PAPER_Y0,
        t1=1.0,
        dts=[2.0**-k for k in range(5, 10)],
        n_samples=200,
        key=jax.random.key(42),
        methods={
            "LiePoisson": sj.LiePoisson(),
            "LiePoissonSym2": sj.LiePoissonSym2(),
            "LiePoissonSym4": sj.LiePoissonSym4(),
            "Strang4": sj.Strang4(),
        },
    )


def test_sym2_strong_order_one_with_smaller_constant(study):
    errs = study.errors["LiePoissonSym2"]
    order = fitted_order(study.dts, errs)
    assert 0.85 <= order <= 1.2, (order, errs)
    assert np.all(np.diff(errs) < 0)
    # no kappa term, yet a smaller error than scheme (42) at every step size
    assert np.all(errs < 0.5 * study.errors["LiePoisson"]), (errs, study.errors["LiePoisson"])


@pytest.mark.parametrize("name", ["LiePoissonSym4", "Strang4"])
def test_strong_order_two(study, name):
    errs = study.errors[name]
    assert np.all(errs > 1e-10), errs  # well above the Newton / round-off floor
    order = fitted_order(study.dts, errs)
    assert order >= 1.8, (order, errs)
    assert order <= 2.5, (order, errs)
    assert np.all(np.diff(errs) < 0)
    assert errs[-1] < 1e-6


# --------------------------------------------------------------------------------------
# Invariants, failures, transformations, precision.


@pytest.mark.parametrize("method", SYM, ids=ids)
def test_casimir_at_round_off_over_ten_thousand_steps(paper, method):
    model, y0 = paper
    n, h = 10_000, 0.01
    dW = sj.BrownianMotion().increments(jax.random.key(3), n, h)
    ys = sj.integrate(model, y0, dW, h, method=method, save_every=100)
    drift = np.max(np.abs(np.linalg.norm(np.asarray(ys), axis=-1) / np.linalg.norm(y0) - 1.0))
    assert drift < 1e-12, drift


@pytest.mark.parametrize("method", SYM[:2], ids=ids)
def test_unsolvable_step_is_flagged_not_nan(paper, method):
    model, _ = paper
    y = jnp.asarray([0.7, 0.7, 0.1])  # |y| = 0.995: near the fold
    # tau = 2 here: the continuation in the step solves it (a root on the branch), or the
    # step is flagged; never a NaN.
    y1, info = STEPS[type(method).__name__](model, y, jnp.asarray(2.0), 0.0)
    assert np.all(np.isfinite(np.asarray(y1)))
    if bool(info.ok):
        assert float(info.residual) <= 64 * np.finfo(np.float64).eps
        np.testing.assert_allclose(np.linalg.norm(y1), np.linalg.norm(y), rtol=1e-13)
    # A huge third increment, with too few Newton updates allowed to solve it.
    dW = jnp.asarray([0.0, 0.0, 9.0, 0.0])
    method = dataclasses.replace(method, max_iter=3)
    kw = dict(method=method, save_every=1)
    with pytest.raises(RuntimeError, match="step 2 could not be solved"):
        sj.integrate(model, y, dW, 0.05, **kw, failures=sj.Failures(None, throw=True))
    ys = sj.integrate(model, y, dW, 0.05, **kw, failures=sj.Failures(None))
    assert np.all(np.isfinite(np.asarray(ys)))
    np.testing.assert_array_equal(ys[3], ys[4])  # frozen at its last good state


@pytest.mark.parametrize("method", SYM[:2], ids=ids)
def test_needs_the_unit_ball(paper, method):
    model, _ = paper
    with pytest.raises(ValueError, match=r"\|y0\| < 1"):
        sj.integrate(model, jnp.asarray([1.0, 0.5, 0.0]), jnp.zeros(4), 0.1, method=method)
    with pytest.raises(ValueError, match="max_iter"):
        type(method)(max_iter=0)


@pytest.mark.parametrize("method", SYM[1:], ids=ids)  # Sym4 runs Sym2 inside
def test_jit_and_vmap_agree_with_single_steps(paper, method):
    model, _ = paper
    ys = jnp.asarray(rng.normal(size=(6, 3)))
    ys = 0.9 * ys / jnp.linalg.norm(ys, axis=-1, keepdims=True)
    dWs = jnp.asarray(rng.normal(size=6) * 0.1)
    batched, info = jax.jit(jax.vmap(lambda y, w: method.step(model, y, 0.1, w)))(ys, dWs)
    assert info.ok.shape == (6,) and bool(jnp.all(info.ok))
    step = STEPS[type(method).__name__]
    single = np.stack([np.asarray(step(model, y, jnp.asarray(0.1), w)[0]) for y, w in zip(ys, dWs)])
    np.testing.assert_allclose(np.asarray(batched), single, rtol=0, atol=1e-14)


# float32 over 1000 steps (t = 10), against the same method in float64 on the same path.
# Measured: Sym2 2.4e-3, Sym4 4.8e-3 (Newton stops at 64 eps ~ 8e-6 in the residual, six
# solves a step near the fold), Strang4 3.6e-6; |y| kept to ~2e-6. (Sym2 is inside Sym4.)
@pytest.mark.parametrize("method,tol", [(SYM[1], 2e-2), (SYM[2], 1e-4)], ids=ids)
def test_float32(paper, method, tol):
    model64, y0 = paper
    model32 = sj.RigidBody(np.asarray(model64.inertia, np.float32), np.float32(0.2))
    n, h = 1000, 0.01
    dW = sj.BrownianMotion().increments(jax.random.key(5), n, h)
    y32 = sj.integrate(
        model32, y0.astype(jnp.float32), dW.astype(jnp.float32), h, method=method, save_every=100
    )
    y64 = sj.integrate(model64, y0, dW, h, method=method, save_every=100)
    assert y32.dtype == jnp.float32
    assert np.abs(np.asarray(y32, np.float64) - np.asarray(y64)).max() < tol
    norms = np.linalg.norm(np.asarray(y32, np.float64), axis=-1)
    assert np.abs(norms / float(jnp.linalg.norm(y0)) - 1.0).max() < 1e-5
