"""LiePoissonSystem: a Hamiltonian given as a function, derivatives by JAX.

References: the RigidBody fast path (for H equal to the rigid body's, an independent analytic
implementation), autodiff of the generating function, and scipy's DOP853 for a quartic H
(through the time change y(T) = phi_{T + c W(T)}(y0), which holds for every H).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import fitted_order
from scipy.integrate import solve_ivp

import slps_jax as sj
from slps_jax import so3
from slps_jax._algebra import so3 as comp
from slps_jax._methods.lie_poisson import branch_rotation, sine_chart_in_map

EPS = 0.5
RB = sj.RigidBody.paper()
INERTIA = np.asarray(RB.inertia)
Y0 = np.array(sj.PAPER_Y0)


def rigid(y, inertia):
    return 0.5 * jnp.sum(y**2 / inertia)


def quartic(y, p):
    """The rigid body plus eps * sum y_i^4: not quadratic, so no Midpoint energy conservation
    and no closed form."""
    return 0.5 * jnp.sum(y**2 / p["inertia"]) + p["eps"] * jnp.sum(y**4)


def quartic_model(c=0.2, eps=EPS):
    return sj.LiePoissonSystem(quartic, {"inertia": RB.inertia, "eps": eps}, c)


def quartic_flow(y0, t):
    """phi_t(y0) of dy/dt = y x grad H(y) by DOP853, grad H written by hand."""
    if t == 0:
        return np.asarray(y0, float)
    sol = solve_ivp(
        lambda _, y: np.cross(y, y / INERTIA + 4 * EPS * y**3),
        (0.0, float(t)),
        np.asarray(y0, float),
        method="DOP853",
        rtol=1e-13,
        atol=1e-15,
    )
    assert sol.success
    return sol.y[:, -1]


def test_model_basics():
    m = quartic_model()
    leaves, treedef = jax.tree_util.tree_flatten(m)
    assert len(leaves) == 3  # eps, inertia, c; the function is static
    m2 = jax.tree_util.tree_unflatten(treedef, leaves)
    y = jnp.asarray([0.3, -0.2, 0.5])
    grad_by_hand = y / RB.inertia + 4 * EPS * y**3
    np.testing.assert_allclose(m2.gradient(y), grad_by_hand, atol=1e-15)
    np.testing.assert_allclose(m.vector_field(y), jnp.cross(y, grad_by_hand), atol=1e-15)
    assert m.hamiltonian(jnp.stack([y, 2 * y])).shape == (2,)
    np.testing.assert_allclose(m.casimir(y), 0.5 * jnp.sum(y**2))
    with pytest.raises(TypeError, match="callable"):
        sj.LiePoissonSystem(1.0)
    with pytest.raises(ValueError, match="finite"):
        sj.LiePoissonSystem(rigid, RB.inertia, float("nan"))


@pytest.mark.parametrize("trial", range(3))
def test_sine_chart_in_map_matches_autodiff_of_the_generating_function(trial):
    """R(v) = vee(-2 skew(A^T grad S)) - y at A = A(v) (the sine chart), for
    S(A) = tr(A)/2 - tau H(v(A)) and the quartic H, and dR/dv."""
    rng = np.random.default_rng(trial)
    m = quartic_model()
    u = rng.normal(size=3)
    v = jnp.asarray(u / np.linalg.norm(u) * rng.uniform(0.2, 0.95))
    y = jnp.asarray(rng.normal(size=3) * 0.4)
    tau = rng.uniform(-0.3, 0.3)

    def residual(v):
        a = comp.unmat(branch_rotation(comp.vec(v))[0])
        s = lambda b: 0.5 * jnp.trace(b) - tau * quartic(so3.vee(b), m.params)
        return so3.vee(-2.0 * so3.skew(a.T @ jax.grad(s)(a))) - y

    def fields(u):  # the step Hamiltonian K = tau H (dW = 0), the first-order in-map
        return m.step_fields(u, tau, jnp.zeros(1), second=False)

    r, jac = sine_chart_in_map(comp.vec(v), comp.vec(y), fields)
    np.testing.assert_allclose(comp.unvec(r), residual(v), atol=1e-15)
    np.testing.assert_allclose(comp.unmat(jac), jax.jacfwd(residual)(v), atol=1e-13)


@pytest.mark.parametrize(
    "method",
    [sj.LiePoissonSym4(), sj.Midpoint(), sj.EulerMaruyama(), sj.LiePoisson()],
    ids=lambda m: type(m).__name__,
)
def test_rigid_body_hamiltonian_agrees_with_the_fast_path(method):
    """H = y^T I^{-1} y / 2 as a function: the same numbers as RigidBody (analytic
    derivatives) to round-off. Sym4 runs Sym2 six times, so Sym2 is covered."""
    general = sj.LiePoissonSystem(rigid, RB.inertia, RB.c)
    dW = sj.BrownianMotion().increments(jax.random.key(1), 256, 2.0**-6)
    a = sj.integrate(RB, Y0, dW, 2.0**-6, method=method, save_every=64)
    b = sj.integrate(general, Y0, dW, 2.0**-6, method=method, save_every=64)
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-12)


def test_methods_for_the_rigid_body_only_are_refused():
    m = quartic_model()
    for method in (sj.Strang(), sj.Strang4(), sj.Exact(), sj.SaltSplitting()):
        with pytest.raises(TypeError, match="RigidBody only"):
            sj.integrate(m, Y0, jnp.zeros(4), 0.1, method=method)


def test_drift_flow_of_a_hamiltonian_function_against_scipy():
    """`drift_flow` without a closed form (Runge–Kutta): scipy's DOP853 at rtol 1e-13; it is
    `strong_convergence`'s reference="exact" for such a system."""
    times = np.array([-0.7, 0.4, 1.3])
    ys = sj.drift_flow(quartic_model(), Y0, times)
    np.testing.assert_allclose(ys, np.stack([quartic_flow(Y0, t) for t in times]), atol=1e-11)


def test_quartic_differs_from_the_rigid_body():
    """The test below would be vacuous if the quartic term did not matter."""
    assert np.linalg.norm(quartic_flow(Y0, 1.0) - quartic_flow(Y0, 0.0)) > 0.3
    rb = solve_ivp(
        lambda _, y: np.cross(y, y / INERTIA), (0, 1.0), Y0, method="DOP853", rtol=1e-13, atol=1e-15
    ).y[:, -1]
    assert np.linalg.norm(quartic_flow(Y0, 1.0) - rb) > 0.1


@pytest.fixture(scope="module")
def quartic_study():
    # 64 samples: the fitted orders' standard errors are at most 0.03 (measured 1.05-1.08,
    # and 2.02 for LiePoissonSym4), far inside the bounds below.
    return sj.strong_convergence(
        quartic_model(),
        Y0,
        t1=1.0,
        dts=[2.0**-k for k in range(5, 10)],
        n_samples=64,
        key=jax.random.key(1),
        methods={
            "LiePoissonSym2": sj.LiePoissonSym2(),
            "LiePoissonSym4": sj.LiePoissonSym4(),
            "Midpoint": sj.Midpoint(),
            "LiePoisson": sj.LiePoisson(),
        },
        failures=sj.Failures(retry_substeps=4),
        reference=lambda ts: np.stack([quartic_flow(Y0, t) for t in ts]),
    )


@pytest.mark.parametrize(
    "name,low,high",
    [
        ("LiePoissonSym2", 0.85, 1.2),
        ("LiePoisson", 0.85, 1.2),
        ("Midpoint", 0.85, 1.2),
        ("LiePoissonSym4", 1.8, 2.5),
    ],
)
def test_quartic_strong_order(quartic_study, name, low, high):
    errs = quartic_study.errors[name]
    order = fitted_order(quartic_study.dts, errs)
    assert low <= order <= high, (order, errs)
    assert np.all(np.diff(errs) < 0) and np.all(errs > 1e-10), errs


def test_quartic_casimir_at_round_off_over_ten_thousand_steps():
    m = quartic_model()
    dW = sj.BrownianMotion().increments(jax.random.key(3), 10_000, 0.01)
    ys = sj.integrate(m, Y0, dW, 0.01, method=sj.LiePoissonSym4(), save_every=100)
    drift = np.max(np.abs(np.linalg.norm(np.asarray(ys), axis=-1) / np.linalg.norm(Y0) - 1))
    assert drift < 1e-12, drift


def test_derivatives_reach_params_and_c():
    """Forward mode through the Newton solves (Sym2), reverse mode through Euler-Maruyama,
    both against central differences."""
    dW = sj.BrownianMotion().increments(jax.random.key(4), 16, 1 / 16)

    def final(eps, c, method):
        m = sj.LiePoissonSystem(quartic, {"inertia": RB.inertia, "eps": eps}, c)
        return sj.integrate(m, Y0, dW, 1 / 16, method=method, failures=sj.Failures(throw=False))

    for method, diff in ((sj.LiePoissonSym2(), jax.jacfwd), (sj.EulerMaruyama(), jax.jacrev)):
        d_eps, d_c = diff(final, argnums=(0, 1))(EPS, 0.2, method)
        h = 1e-6
        fd_eps = (final(EPS + h, 0.2, method) - final(EPS - h, 0.2, method)) / (2 * h)
        fd_c = (final(EPS, 0.2 + h, method) - final(EPS, 0.2 - h, method)) / (2 * h)
        np.testing.assert_allclose(d_eps, fd_eps, rtol=1e-5, atol=1e-8)
        np.testing.assert_allclose(d_c, fd_c, rtol=1e-5, atol=1e-8)


def test_float32():
    """The general path in float32: |y| to ~1e-6 and close to float64 (measured below)."""
    m64 = quartic_model()
    m32 = sj.LiePoissonSystem(
        quartic,
        {"inertia": np.asarray(INERTIA, np.float32), "eps": np.float32(EPS)},
        np.float32(0.2),
    )
    assert m32.c.dtype == jnp.float32
    dW = sj.BrownianMotion().increments(jax.random.key(5), 500, 0.01)
    y64 = sj.integrate(m64, Y0, dW, 0.01, method=sj.LiePoissonSym2(), save_every=100)
    y32 = sj.integrate(
        m32,
        Y0.astype(np.float32),
        dW.astype(jnp.float32),
        0.01,
        method=sj.LiePoissonSym2(),
        save_every=100,
    )
    assert y32.dtype == jnp.float32
    assert np.abs(np.asarray(y32, np.float64) - np.asarray(y64)).max() < 1e-2
    norms = np.linalg.norm(np.asarray(y32, np.float64), axis=-1)
    assert np.abs(norms / np.linalg.norm(Y0) - 1.0).max() < 1e-5
