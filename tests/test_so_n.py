"""so(n)*: the generalised rigid body, scheme (42) on SO(n), the isospectral midpoint rule.

References independent of the code under test: the so(3) 3-vector methods (through `hat`),
the rigid body's exact elliptic flow, the time change of a Runge–Kutta flow (orders),
methods on the same paths at a fine step (several noises), the Casimirs (a theorem for
isospectral maps) and central finite differences.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj
from slps_jax.so3 import hat, vee

J4 = jnp.asarray([0.6, 1.1, 1.7, 2.3])


def skew_state(n, norm=0.8, seed=1):
    a = np.random.default_rng(seed).normal(size=(n, n))
    y = a - a.T
    return jnp.asarray(norm * y / np.linalg.norm(y, 2))


def body(n, **kw):
    return sj.GeneralisedRigidBody(jnp.linspace(0.6, 2.3, n) if n != 4 else J4, **kw)


def salt_chi(n, s=3, strength=0.3, seed=2):
    a = np.random.default_rng(seed).normal(size=(s, n, n))
    return strength * (a - np.swapaxes(a, 1, 2)) / np.sqrt(2 * n)


# --- so(3) through matrices equals the 3-vector API ---------------------------------------


def _vector_and_matrix(model_v, model_m, method, y0, dW, dt=0.01):
    yv = sj.integrate(model_v, y0, dW, dt, method=method, save_every=1)
    ym = sj.integrate(model_m, hat(y0), dW, dt, method=method, save_every=1)
    return yv, vee(ym)


@pytest.mark.parametrize(
    "method",
    [sj.LiePoisson(), sj.Midpoint(), sj.Heun(), sj.EulerMaruyama()],
    ids=["LiePoisson", "Midpoint", "Heun", "EulerMaruyama"],
)
def test_so3_matrix_api_equals_vector_api(method):
    """The methods with an so(3) fast path (on 3-vector components) and their generic path
    (the algebra interface alone, here on so(3) as matrices) give the same states."""
    y0 = jnp.asarray([0.3, 0.5, 0.4])
    dW = 0.1 * jax.random.normal(jax.random.key(0), (200, 1))
    # I = (J2 + J3, J3 + J1, J1 + J2) = (1.5, 2, 3)
    yv, ym = _vector_and_matrix(
        sj.RigidBody([1.5, 2.0, 3.0], c=0.5),
        sj.GeneralisedRigidBody([1.75, 1.25, 0.25], c=0.5),
        method,
        y0,
        dW,
    )
    assert np.max(np.abs(yv - ym)) < 1e-12
    # the Poisson methods keep |y| to round-off in both forms
    if type(method).poisson:
        assert np.max(np.abs(np.linalg.norm(ym, axis=1) - np.linalg.norm(y0))) < 1e-13


def test_so3_matrix_api_several_noises_and_own_hamiltonian():
    chi = 0.3 * np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.2], [0.0, 0.5, 1.0]])

    def h_vec(y, p):
        return 0.5 * jnp.sum(y**2 / p) + 0.1 * y[0] * y[1] * y[2]

    def h_mat(y, p):
        return h_vec(vee(y), p)

    p = jnp.asarray([1.0, 2.0, 3.0])
    model_v = sj.LiePoissonSystem(h_vec, p, noise=sj.salt_noise(chi))
    model_m = sj.LiePoissonSystem(
        h_mat, p, noise=sj.salt_noise(hat(jnp.asarray(chi))), algebra=sj.so(3)
    )
    dW = 0.1 * jax.random.normal(jax.random.key(1), (100, 3))
    yv, ym = _vector_and_matrix(model_v, model_m, sj.LiePoisson(), jnp.asarray([0.6, 0.5, 0.3]), dW)
    assert np.max(np.abs(yv - ym)) < 1e-12


def test_runge_kutta_flow_matches_the_rigid_body_closed_form():
    y0 = jnp.asarray([0.3, 0.5, 0.4])
    times = np.array([-2.1, -0.3, 0.0, 0.7, 2.9])
    flow = sj.drift_flow(sj.GeneralisedRigidBody([1.75, 1.25, 0.25]), hat(y0), times)
    exact = sj.drift_flow(sj.RigidBody([1.5, 2.0, 3.0]), y0, times)
    assert flow.shape == (5, 3, 3)
    assert np.max(np.abs(vee(flow) - exact)) < 1e-12


# --- orders --------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [4, 5])
def test_strong_order_one_noise_against_the_time_change(n):
    # 64 samples: the fitted orders' standard errors are at most 0.025 (measured 1.00 and
    # 1.05-1.07), far inside the bounds.
    res = sj.strong_convergence(
        body(n, c=0.4),
        skew_state(n),
        t1=1.0,
        dts=[2.0**-k for k in range(4, 9)],
        n_samples=64,
        key=jax.random.key(n),
        methods={"LiePoisson": sj.LiePoisson(), "Isospectral": sj.IsospectralMidpoint()},
        reference="exact",
    )
    for name, order in res.order.items():
        assert 0.85 < order < 1.25, (name, order, res.errors[name])


# --- Casimirs ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def long_runs():
    n = 6
    model = body(n, noise=sj.salt_noise(salt_chi(n, s=2)))
    y0 = skew_state(n, 0.7)
    dW = jnp.sqrt(0.01) * jax.random.normal(jax.random.key(3), (10_000, 2))
    c0 = np.asarray(sj.so(n).casimirs(y0))
    runs = {
        name: sj.integrate(model, y0, dW, 0.01, method=m, save_every=1000)
        for name, m in [
            ("LiePoisson", sj.LiePoisson()),
            ("Isospectral", sj.IsospectralMidpoint()),
            ("Midpoint", sj.Midpoint()),
        ]
    }
    return c0, {k: np.asarray(sj.so(n).casimirs(v)) for k, v in runs.items()}


@pytest.mark.parametrize("name", ["LiePoisson", "Isospectral"])
def test_casimirs_kept_over_ten_thousand_steps(long_runs, name):
    c0, cas = long_runs
    assert c0.shape == (3,)
    assert np.max(np.abs(cas[name] / c0 - 1)) < 1e-12


def test_midpoint_keeps_only_the_quadratic_casimir(long_runs):
    c0, cas = long_runs
    rel = np.abs(cas["Midpoint"] / c0 - 1)
    # tr Y^2: quadratic, kept by the midpoint rule (to its solver's tolerance, 64 eps a step)
    assert np.max(rel[:, 0]) < 1e-10
    assert np.max(rel[:, 1]) > 1e-4  # tr Y^4, tr Y^6: not (measured: 3e-3, 6e-3)
    assert np.max(rel[:, 2]) > 1e-4


# --- gradients -----------------------------------------------------------------------------


def test_gradient_with_respect_to_j_matches_finite_differences():
    y0 = skew_state(4, 0.6)
    dW = 0.2 * jax.random.normal(jax.random.key(4), (8, 16, 1))

    def statistic(j, method):
        model = sj.GeneralisedRigidBody(j, c=0.3)
        ys = jax.vmap(lambda w: sj.integrate(model, y0, w, 1 / 16, method=method))(dW)
        return jnp.mean(ys[:, 0, 1] ** 2 + ys[:, 2, 3])

    for method in [sj.LiePoisson(), sj.IsospectralMidpoint()]:
        g = jax.grad(statistic)(J4, method)
        eps = 1e-5
        fd = np.array(
            [
                (statistic(J4.at[i].add(eps), method) - statistic(J4.at[i].add(-eps), method))
                / (2 * eps)
                for i in range(4)
            ]
        )
        assert np.max(np.abs(g - fd)) < 1e-6 * max(1.0, np.max(np.abs(fd))), (method, g, fd)


# --- bad input -----------------------------------------------------------------------------


def test_bad_input_refused_by_name():
    model = body(4, c=0.4)
    y0 = skew_state(4)
    dW = jnp.zeros((4, 1))
    with pytest.raises(ValueError, match="skew-symmetric"):
        sj.integrate(model, y0 + jnp.eye(4), dW, 0.1, method=sj.LiePoisson())
    with pytest.raises(ValueError, match=r"shape \(4, 4\)"):
        sj.integrate(model, skew_state(5), dW, 0.1, method=sj.LiePoisson())
    with pytest.raises(ValueError, match=r"shape \(4, 4\)"):
        sj.integrate(model, jnp.ones(3), dW, 0.1, method=sj.LiePoisson())
    with pytest.raises(ValueError, match=r"spectral norm.*scale="):
        sj.integrate(model, skew_state(4, 1.2), dW, 0.1, method=sj.LiePoisson())
    # the scale option works where it is offered: a time change for a quadratic body
    y_big = skew_state(4, 1.2)
    out = sj.integrate(model, y_big, 0.1 * jnp.ones((4, 1)), 0.1, method=sj.LiePoisson(scale=2))
    assert np.allclose(sj.so(4).casimirs(out), sj.so(4).casimirs(y_big), rtol=1e-12)
    with pytest.raises(TypeError, match="IsospectralMidpoint"):  # names what works
        sj.integrate(model, y0, dW, 0.1, method=sj.LiePoissonSym2())
    with pytest.raises(TypeError, match="rigid body"):
        sj.integrate(model, y0, dW, 0.1, method=sj.Exact())
    with pytest.raises(ValueError, match=r"\(s, 4, 4\)"):
        sj.GeneralisedRigidBody(J4, noise=sj.salt_noise(salt_chi(3)))
    with pytest.raises(ValueError, match="skew-symmetric"):
        sj.salt_noise(np.ones((1, 4, 4)))
    with pytest.raises(ValueError, match="n >= 3"):
        sj.so(2)
    with pytest.raises(ValueError, match="j must be finite and positive"):
        sj.GeneralisedRigidBody([1.0, -1.0, 2.0])
    with pytest.raises(ValueError, match="iteration must be"):
        sj.IsospectralMidpoint(iteration="exact")


def test_simulate_on_so_n_and_float32():
    model = sj.GeneralisedRigidBody(np.asarray(J4, np.float32), c=0.4)
    y0 = skew_state(4).astype(np.float32)
    for method in [sj.LiePoisson(), sj.IsospectralMidpoint(), sj.Midpoint(), sj.Heun()]:
        sol = sj.simulate(
            model,
            y0,
            t1=0.5,
            dt=1 / 32,
            n_samples=16,
            key=jax.random.key(5),
            method=method,
            save_every=8,
        )
        assert sol.ys.shape == (16, 3, 4, 4) and sol.ys.dtype == jnp.float32
        assert int(sol.stats["n_failed"]) == 0
        cas = np.asarray(sj.so(4).casimirs(sol.ys[:, -1]), np.float64)
        assert np.max(np.abs(cas[:, 0] / float(sj.so(4).casimirs(y0)[0]) - 1)) < 1e-4
