"""Scheme (42) against its definition: the generating function S-bar of docs/scheme.md."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj
from slps_jax import so3
from slps_jax._algebra import so3 as comp
from slps_jax._methods.lie_poisson import branch_rotation, sine_chart_in_map

# Newton updates in the sine chart from v = y_n that solve a step of the paper's setup at
# small h (benchmarks/newton_iterations.py): the loop's fourth residual passes the test.
USUAL_UPDATES = 3

rng = np.random.default_rng(2)


def jit_step(method):
    return jax.jit(lambda model, y, dt, dW: method.step(model, y, dt, dW))


lie_poisson_step = jit_step(sj.LiePoisson())


def s_bar(a, inertia, tau, kappa):
    """S-bar(A) = tr(A)/2 - tau H(v(A)) + kappa S11(A)/2, straight from docs/scheme.md."""
    v = so3.vee(a)
    w = v / inertia
    h = 0.5 * jnp.dot(v, w)
    s11 = 0.5 * (w @ a @ w - jnp.dot(w, w) * jnp.trace(a))
    return 0.5 * jnp.trace(a) - tau * h + 0.5 * kappa * s11


def in_map_by_autodiff(a, y, inertia, tau, kappa):
    g = jax.grad(s_bar)(a, inertia, tau, kappa)  # Frobenius gradient
    return so3.vee(-2.0 * so3.skew(a.T @ g)) - y


def out_map_by_autodiff(a, inertia, tau, kappa):
    g = jax.grad(s_bar)(a, inertia, tau, kappa)
    return so3.vee(-2.0 * so3.skew(g @ a.T))


def random_sine_vector(radius):
    u = rng.normal(size=3)
    return jnp.asarray(u / np.linalg.norm(u) * radius)


@pytest.mark.parametrize("radius", [0.0, 1e-9, 0.3, 0.9, 0.995])
def test_branch_rotation_is_the_rotation_by_arcsin(radius):
    """A(v) = rotation about v by arcsin|v| (scipy), orthogonal, on the branch tr A > 1."""
    from scipy.spatial.transform import Rotation

    v = random_sine_vector(radius)
    a = comp.unmat(branch_rotation(comp.vec(v))[0])
    angle = np.arcsin(radius)
    axis = np.asarray(v) / radius if radius > 0 else np.zeros(3)
    np.testing.assert_allclose(a, Rotation.from_rotvec(angle * axis).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(a.T @ a, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(so3.vee(a), v, atol=1e-16)
    assert np.trace(a) > 1.0


@pytest.mark.parametrize("trial", range(4))
def test_sine_chart_residual_and_jacobian_match_autodiff_of_generating_function(trial):
    """The fast path's vector formulas against autodiff of S-bar at A = A(v)."""
    inertia = jnp.asarray(rng.uniform(0.5, 3.0, 3))
    v = random_sine_vector(rng.uniform(0.2, 0.99))
    y = jnp.asarray(rng.normal(size=3) * 0.4)
    dt, dW = rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)
    tau, kappa = dt + dW, dW * dW  # (c = 1)
    model = sj.RigidBody(inertia, 1.0)

    def reference(v):
        a = comp.unmat(branch_rotation(comp.vec(v))[0])
        return in_map_by_autodiff(a, y, inertia, tau, kappa)

    def fields(u):
        return model.step_fields(u, dt, jnp.asarray([dW]))

    r, jac = sine_chart_in_map(comp.vec(v), comp.vec(y), fields)
    np.testing.assert_allclose(comp.unvec(r), reference(v), atol=1e-15)
    np.testing.assert_allclose(comp.unmat(jac), jax.jacfwd(reference)(v), atol=1e-14)


def test_fast_path_reaches_the_tolerance_on_the_paper_setup(paper):
    """At most three sine-chart updates solve almost every step at h = 2^-9: the residual
    of every step is within the tolerance, and at most 0.1 % of sample-steps needed more
    (each of those counts at least one more update)."""
    model, y0 = paper
    sol = sj.simulate(
        model,
        y0,
        t1=0.25,
        dt=2.0**-9,
        n_samples=200,
        key=jax.random.key(3),
        newton_stats=True,
        method=sj.LiePoisson(),
    )
    tol = 64 * np.finfo(np.float64).eps
    assert int(sol.stats["n_failed"]) == 0
    assert float(sol.stats["residual_max"]) <= tol
    assert USUAL_UPDATES - 0.5 <= float(sol.stats["newton_iterations_mean"]) < USUAL_UPDATES + 1e-3


@pytest.mark.parametrize("dW", [0.0, 0.15, -0.4])
def test_step_solves_in_map_and_out_map_equals_rotation(paper, dW):
    model, y0 = paper
    y0 = y0 * 0.9
    dt = 0.05
    y1, info = lie_poisson_step(model, y0, dt, dW)
    assert bool(info.ok) and int(info.iterations) >= 1
    tau, kappa = dt + model.c * dW, (model.c * dW) ** 2
    # Recover A from y1 = A y0 by solving the in-map once more (independently of the step's
    # parameterisation): the in-map residual at the returned A is at round-off, and the
    # out-map of docs/scheme.md gives the same y1.
    a = _solve_rotation(model, y0, tau, kappa)
    np.testing.assert_allclose(in_map_by_autodiff(a, y0, model.inertia, tau, kappa), 0, atol=1e-13)
    np.testing.assert_allclose(out_map_by_autodiff(a, model.inertia, tau, kappa), y1, atol=1e-13)
    np.testing.assert_allclose(a @ y0, y1, atol=1e-14)
    np.testing.assert_allclose(a.T @ a, np.eye(3), atol=1e-14)
    assert np.trace(a) > 1.0  # the branch theta < pi/2


def _solve_rotation(model, y, tau, kappa):
    """Plain Newton with autodiff Jacobian on xi, A = exp(hat xi): a separate solver."""
    r = jnp.linalg.norm(y)
    xi = y * jnp.arcsin(r) / r
    f = lambda x: in_map_by_autodiff(so3.exp(x), y, model.inertia, tau, kappa)
    update = jax.jit(lambda x: x - jnp.linalg.solve(jax.jacfwd(f)(x), f(x)))
    for _ in range(30):
        xi = update(xi)
    return so3.exp(xi)


def test_consistency(paper):
    """(y1 - y0)/tau -> f(y0) as tau -> 0, at first order in tau."""
    model, y0 = paper
    model = sj.RigidBody(model.inertia, 0.0)
    f0 = model.vector_field(y0)
    errs = []
    taus = [1e-2, 5e-3, 2.5e-3, 1.25e-3]
    for tau in taus:
        y1, _ = lie_poisson_step(model, y0, tau, 0.0)
        errs.append(float(jnp.linalg.norm((y1 - y0) / tau - f0)))
    assert errs[-1] < 1e-2 * float(jnp.linalg.norm(f0))
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    np.testing.assert_allclose(ratios, 2.0, rtol=0.05)  # error O(tau)


def test_midpoint_step_satisfies_its_equation(paper):
    model, y0 = paper
    tau = 0.1
    y1, info = sj.Midpoint().step(model, y0, tau, 0.0)
    assert bool(info.ok)
    np.testing.assert_allclose(y1, y0 + tau * model.vector_field(0.5 * (y0 + y1)), atol=1e-14)


def test_euler_maruyama_step(paper):
    model, y0 = paper
    y1, _ = sj.EulerMaruyama().step(model, y0, 0.01, 0.3)
    np.testing.assert_allclose(y1, y0 + model.vector_field(y0) * (0.01 + model.c * 0.3), atol=1e-16)


def test_large_increment_near_the_fold_converges(paper):
    """|y| = 0.99 and a 4.5-sigma increment at h = 2^-5: the sine-chart updates leave the
    branch here, and the continuation in the step (lam = 1/2, then 1) solves it; Newton
    from the plain start v = y_n alone leaves the chart."""
    model, _ = paper
    y = jnp.array([0.69566237, 0.66189641, 0.24072184])
    dW, dt = 0.7981970294584523, 2.0**-5
    y1, info = lie_poisson_step(model, y, dt, dW)
    assert bool(info.ok)
    assert int(info.iterations) > USUAL_UPDATES + 1  # solved by the continuation
    tau, kappa = dt + model.c * dW, (model.c * dW) ** 2
    # Independent solution by continuation in tau with an autodiff Newton.
    r = jnp.linalg.norm(y)
    xi = y * jnp.arcsin(r) / r

    def f(x, s):
        return in_map_by_autodiff(so3.exp(x), y, model.inertia, s * tau, s * s * kappa)

    update = jax.jit(lambda x, s: x - jnp.linalg.solve(jax.jacfwd(f)(x, s), f(x, s)))
    for k in range(1, 21):
        for _ in range(6):
            xi = update(xi, k / 20)
    a = so3.exp(xi)
    np.testing.assert_allclose(f(xi, 1.0), 0, atol=1e-14)
    np.testing.assert_allclose(y1, a @ y, atol=1e-13)


def test_unrolled_updates_change_nothing(paper):
    """`unroll=3` only moves the loop's first three bodies out of it: the same updates, tested
    as in the loop, so the same iteration counts and the same states bit for bit."""
    model, y0 = paper
    kw = dict(t1=0.5, dt=2.0**-5, n_samples=50, key=jax.random.key(5), newton_stats=True)
    a = sj.simulate(model, y0, method=sj.LiePoisson(), **kw)
    b = sj.simulate(model, y0, method=sj.LiePoisson(unroll=3), **kw)
    np.testing.assert_array_equal(a.ys, b.ys)
    for name in ("newton_iterations_mean", "newton_iterations_max", "residual_max"):
        assert float(a.stats[name]) == float(b.stats[name]), name
