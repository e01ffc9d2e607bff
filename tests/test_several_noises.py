"""Several noises with their own Hamiltonians (the paper's class (1)) on so(3)*.

References independent of the code under test: the one-noise `RigidBody` path through the
closed-form kernel (for the general generating function), the conservation of |y| (a
theorem for Poisson maps), a fine-step reference on the same Brownian paths (orders), exact
moments of the linear SDE (matrix exponentials by scipy), and central finite differences.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

import slps_jax as sj
from slps_jax import so3
from slps_jax._algebra import so3 as comp
from slps_jax._methods import METHODS
from slps_jax._methods.lie_poisson import branch_rotation, sine_chart_in_map
from slps_jax._methods.lie_poisson_sym import _solve_rotation
from slps_jax.so3 import hat, skew, vee

Y0 = jnp.asarray([0.6, 0.5, 0.3])
INERTIA = jnp.asarray([1.0, 2.0, 3.0])
# Three SALT noises about non-parallel axes.
CHI = 0.4 * np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.5, 1.0]])
# Every Poisson method of the registry that runs on the SALT rigid body.
_SALT = sj.RigidBody(INERTIA, noise=sj.salt_noise(CHI))
POISSON = {cls.__name__: cls() for cls in METHODS if cls.poisson and not cls.missing(_SALT)}


def rigid_body_h(y, inertia):
    return 0.5 * jnp.sum(y**2 / inertia)


def paper_noise(y, inertia):  # the paper's one noise, H_1 = c H_0 with c = 0.2
    return (0.2 * rigid_body_h(y, inertia))[None]


def salt():
    return sj.RigidBody(INERTIA, noise=sj.salt_noise(CHI))


def paths(model, dW, dt, method, **kw):
    return jax.jit(jax.vmap(lambda d: sj.integrate(model, Y0, d, dt, method=method, **kw)))(dW)


# --------------------------------------------------------------------------------------
# The step's fields and their Jacobians, which the implicit methods solve with.


def quartic_noise(y, inertia):  # two nonlinear noise Hamiltonians (derivatives by JAX)
    return jnp.stack([0.1 * jnp.sum(y**4), 0.2 * y[0] * y[1] * y[2]])


# Systems whose step kernels differ: closed forms (the rigid body's c=, SALT, random
# inertia) and JAX's derivatives (noise and drift Hamiltonians given as functions).
KERNEL_SYSTEMS = {
    "c": sj.RigidBody(INERTIA, 0.3),
    "salt": salt(),
    "random_inertia": sj.RigidBody(INERTIA, noise=sj.random_inertia_noise(CHI)),
    "function": sj.LiePoissonSystem(rigid_body_h, INERTIA, noise=quartic_noise),
    "function_c": sj.LiePoissonSystem(rigid_body_h, INERTIA, c=0.3),
}


def kernel_steps(model):
    """A step's increments, and its noise without and (for several noises) with areas."""
    s = model.n_noises
    dW = jnp.linspace(-0.3, 0.4, s)
    area = jnp.triu(jnp.full((s, s), 0.05), 1)
    return dW, [sj.BrownianStep(dW)] + ([sj.BrownianStep(dW, area - area.T)] if s > 1 else [])


@pytest.mark.parametrize("model", KERNEL_SYSTEMS.values(), ids=KERNEL_SYSTEMS.keys())
def test_step_jacobians_are_the_derivatives_of_the_step_gradient(model):
    # Closed forms (the rigid body, SALT, random inertia) and the forward-mode passes
    # against reverse-over-forward autodiff of the step's gradient and of the family's u.
    dW, steps = kernel_steps(model)
    v, unvec, unmat = comp.vec(Y0), comp.unvec, comp.unmat
    for step in steps:
        g, jac, _, _ = model.step_fields(v, 0.1, step, second=False)
        np.testing.assert_allclose(unvec(g), model.step_gradient(Y0, 0.1, step), atol=1e-15)
        np.testing.assert_allclose(
            unmat(comp.full(jac)),
            jax.jacrev(lambda y: model.step_gradient(y, 0.1, step))(Y0),
            atol=1e-14,
        )
    k, hk, u, ju = model.step_fields(v, 0.1, steps[-1])
    np.testing.assert_allclose(unmat(comp.full(hk)), unmat(comp.full(jac)), atol=1e-15)
    np.testing.assert_allclose(unvec(k), model.step_gradient(Y0, 0.1, steps[-1]), atol=1e-15)
    u_of = lambda y: model.step_gradient(y, 0.0, sj.BrownianStep(dW))
    np.testing.assert_allclose(unvec(u), u_of(Y0), atol=1e-15)
    ju = np.zeros((3, 3)) if ju is None else unmat(comp.full(ju))  # (None: u is constant)
    np.testing.assert_allclose(ju, jax.jacrev(u_of)(Y0), atol=1e-14)


def generating_function_in_map(model, v, y, dt, step, second):
    """Scheme (42)'s in-map at A = A(v), R = vee(-2 skew(A^T dS/dA)) - y, by autodiff of the
    generalised generating function S(A) = tr(A)/2 - K(v) + (u^T A u - tr(A)|u|^2)/4 with
    v = vee(A), K the step's Hamiltonian (with the areas' G_A) and u = sum_r dW_r grad H_r."""

    def s_bar(a):
        w = so3.vee(a)
        s = 0.5 * jnp.trace(a) - model.step_hamiltonian(w, dt, step)
        if second:
            u = model.step_gradient(w, 0.0, sj.BrownianStep(step.dW))
            s = s + 0.25 * (u @ a @ u - jnp.trace(a) * (u @ u))
        return s

    a = comp.unmat(branch_rotation(comp.vec(v))[0])
    return so3.vee(-2.0 * so3.skew(a.T @ jax.grad(s_bar)(a))) - y


@pytest.mark.parametrize("model", KERNEL_SYSTEMS.values(), ids=KERNEL_SYSTEMS.keys())
def test_the_sine_chart_in_map_is_the_generating_functions(model):
    # Residual and Jacobian against autodiff of the generating function, with and without
    # the second-order term and the areas.
    dW, steps = kernel_steps(model)
    v, y = jnp.asarray([0.5, -0.3, 0.6]), jnp.asarray([0.4, 0.2, -0.3])
    for step in steps:
        for second in (True, False):
            fields = lambda u: model.step_fields(u, 0.1, step, second=second)
            r, jac = sine_chart_in_map(comp.vec(v), comp.vec(y), fields)
            ref = lambda w: generating_function_in_map(model, w, y, 0.1, step, second)
            np.testing.assert_allclose(comp.unvec(r), ref(v), atol=1e-15)
            np.testing.assert_allclose(comp.unmat(jac), jax.jacfwd(ref)(v), atol=1e-14)


class Axes(sj.AbstractNoise):
    """SALT written as a user's family: `values` and `gradient` only (Jacobians and the
    Lévy-area term from JAX)."""

    linear = True

    chi: jax.Array  # (a field: a leaf of the pytree)

    @property
    def n_noises(self):
        return self.chi.shape[0]

    def values(self, y, params):
        return self.chi @ y

    def gradient(self, y, w, params, algebra):
        return w @ self.chi


@pytest.mark.parametrize(
    "method", [sj.LiePoisson(), sj.Midpoint(), sj.IsospectralMidpoint(), sj.SaltSplitting()]
)
def test_a_family_of_ones_own_runs_as_the_built_in_one(method):
    # The closed forms of salt_noise (its zero Jacobian, its constant area term) against
    # JAX's derivatives of the same Hamiltonians, through whole runs with Lévy areas.
    mine = sj.RigidBody(INERTIA, noise=Axes(jnp.asarray(CHI)))
    run = lambda model: (
        sj.simulate(
            model, Y0, t1=0.25, dt=2.0**-6, n_samples=4, key=jax.random.key(1), method=method
        ).ys
    )
    np.testing.assert_allclose(run(mine), run(salt()), atol=1e-13)


# --------------------------------------------------------------------------------------
# The generalised generating function against scheme (42).


def test_paper_case_through_noise_equals_rigid_body():
    """H_1 = c H_0 given as a noise Hamiltonian takes the in-map's forward-mode Jacobian and
    the noise family's arrays; the RigidBody with c= its closed forms and the written-out
    Jacobian. Over 10^3 steps they agree to 1e-13."""
    paper = sj.RigidBody.paper()
    y0 = jnp.asarray(sj.PAPER_Y0)
    dt = 2.0**-6
    dW = sj.BrownianMotion().increments(jax.random.key(1), 1000, dt, n_noises=1)
    expected = sj.integrate(paper, y0, dW, dt, save_every=1, method=sj.LiePoisson())
    for model in (
        sj.LiePoissonSystem(rigid_body_h, paper.inertia, noise=paper_noise),
        sj.RigidBody(paper.inertia, noise=paper_noise),
    ):
        assert model.n_noises == 1
        got = sj.integrate(model, y0, dW, dt, save_every=1, method=sj.LiePoisson())
        assert np.abs(got - expected).max() < 1e-13


def test_c_is_the_proportional_family():
    """c= builds the family `proportional_noise(c)` (every system has a noise family): the
    same system, bit for bit, on so(3) (the rigid body's closed forms); on so(4) and su(4)
    the same paths as the noise given as a function H_1 = c H_0; and the derivative in c,
    which now lives on the family, through `system.c` of the gradient, against a central
    difference."""
    paper = sj.RigidBody.paper()
    fam = sj.RigidBody(paper.inertia, noise=sj.proportional_noise(0.2))
    assert isinstance(paper.noise, type(fam.noise)) and fam.c == paper.c
    assert repr(fam) == repr(paper) and "c=" in repr(paper)
    assert fam.n_noises == 1 and salt().c is None
    y0, dt = jnp.asarray(sj.PAPER_Y0), 2.0**-6
    dW = sj.BrownianMotion().increments(jax.random.key(2), 64, dt, n_noises=1)
    for method in (sj.LiePoisson(), sj.Midpoint(), sj.Exact()):
        np.testing.assert_array_equal(
            sj.integrate(fam, y0, dW, dt, method=method),
            sj.integrate(paper, y0, dW, dt, method=method),
        )
    for alg in (sj.so(4), sj.su(4)):
        # against the same noise given as a function, H_1 = 0.3 H_0 (JAX's derivatives, a
        # family of its own Hamiltonians): the family's time change against a code path
        # that knows nothing of it
        h = lambda y, p: 0.5 * jnp.sum(jnp.abs(y) ** 2 * p)
        j = jnp.linspace(1.0, 2.0, 4)
        a = sj.LiePoissonSystem(h, j, c=0.3, algebra=alg)
        b = sj.LiePoissonSystem(h, j, noise=lambda y, p: (0.3 * h(y, p))[None], algebra=alg)
        assert b.c is None
        ya = alg.random_state(jax.random.key(4))
        ya = 0.5 * ya / alg.spectral_norm(ya)
        for method in (sj.IsospectralMidpoint(), sj.LiePoisson()):
            np.testing.assert_allclose(
                sj.integrate(a, ya, dW[:8], dt, method=method),
                sj.integrate(b, ya, dW[:8], dt, method=method),
                atol=1e-13,
            )
    # d/dc of y_1 at the end: the gradient's c (the family's leaf) against a central difference
    end = lambda s: sj.integrate(s, y0, dW, dt, method=sj.Midpoint())[0]
    g = jax.grad(end)(paper).c
    fd = (
        end(sj.RigidBody(paper.inertia, 0.2 + 1e-6)) - end(sj.RigidBody(paper.inertia, 0.2 - 1e-6))
    ) / 2e-6
    assert abs(float(g) - float(fd)) < 1e-7 * max(1.0, abs(float(fd)))
    with pytest.raises(ValueError, match="c must be a scalar"):
        sj.proportional_noise([0.1, 0.2])
    with pytest.raises(ValueError, match="c must be finite"):
        sj.proportional_noise(np.inf)
    with pytest.raises(ValueError, match="no Lévy area"):
        paper.area_gradient(y0, jnp.zeros((1, 1)))


def test_casimir_kept_with_three_noises():
    """|y| to 1e-13 over 10^4 steps with three SALT noises, for every Poisson method (with
    the Lévy areas for those that use them)."""
    dt = 2.0**-8
    dW, A = sj.BrownianMotion().increments(
        jax.random.key(2), 10_000, dt, n_noises=3, levy_area=True
    )
    for name, method in POISSON.items():
        ys = sj.integrate(
            salt(),
            Y0,
            dW,
            dt,
            method=method,
            save_every=100,
            areas=A if method.uses_levy_area() else None,
        )
        drift = np.abs(np.linalg.norm(ys, axis=1) - np.linalg.norm(Y0)).max()
        assert drift < 1e-13, (name, drift)
    # The baseline is not a Poisson map: Heun's |y| drifts far above round-off.
    ys = sj.integrate(salt(), Y0, dW, dt, method=sj.Heun(), save_every=100)
    assert np.abs(np.linalg.norm(ys, axis=1) - np.linalg.norm(Y0)).max() > 1e-9


def test_adjoint_step_for_a_salt_hamiltonian():
    """The adjoint half step of LiePoissonSym2 for an odd step Hamiltonian: B = A^T solves the
    in-map at -z of x -> -K(-x)/2 (docs/several-noises.md) iff A solves the out-map
    z = out(A; -K/2), checked against autodiff of the generating function."""
    model = salt()
    dt, dW = 0.1, jnp.asarray([0.3, -0.2, 0.25])
    z = jnp.asarray([0.3, -0.5, 0.6])

    def k_step(x):
        return dt * 0.5 * jnp.sum(x**2 / INERTIA) + dW @ (jnp.asarray(CHI) @ x)

    def s_bar(a):  # the first-order generating function of psi_{-K/2}
        return 0.5 * jnp.trace(a) + 0.5 * k_step(so3_vee_skew(a))

    b, info = _solve_rotation(model, comp.vec(-z), 0.5 * dt, 0.5 * dW, -1.0, 1e-14, 12, True)
    assert bool(info.ok)
    a = comp.unmat(b).T
    out = vee(-2.0 * skew(jax.grad(s_bar)(a) @ a.T))
    np.testing.assert_allclose(out, z, atol=1e-14)
    np.testing.assert_allclose(a.T @ a, np.eye(3), atol=1e-14)
    # the even-Hamiltonian shortcut (in-map of -K/2 at -z) gives another, wrong, rotation
    b_even, _ = _solve_rotation(model, comp.vec(-z), -0.5 * dt, -0.5 * dW, 1.0, 1e-14, 12, True)
    assert np.abs(comp.unmat(b_even) - comp.unmat(b)).max() > 1e-3


def so3_vee_skew(a):
    return vee(skew(a))


# --------------------------------------------------------------------------------------
# The second-order terms, against a fine reference on the same paths.


@pytest.fixture(scope="module")
def coupled():
    """200 Brownian paths at 2^-14 and the Midpoint reference on them."""
    n_fine, n_samples = 2**14, 200
    keys = jax.random.split(jax.random.key(0), n_samples)
    dW = jax.vmap(lambda k: sj.BrownianMotion().increments(k, n_fine, 1.0 / n_fine, n_noises=3))(
        keys
    )
    return dW, paths(salt(), dW, 1.0 / n_fine, sj.Midpoint())


def coarse(dW, n):
    return dW.reshape(dW.shape[0], n, -1, dW.shape[-1]).sum(2)


def test_without_second_order_terms_the_bias_stays(coupled):
    """Without the S_rq terms the scheme converges to another SDE: its mean error on shared
    paths levels off (changes by < 25% from 2^-8 to 2^-10), while scheme (42) generalised
    keeps decreasing, far below it. (Measured: 9.0e-3 -> 8.4e-3 against 5e-4 -> 1.3e-4.)"""
    dW, ref = coupled

    def bias(method, n):
        y = paths(salt(), coarse(dW, n), 1.0 / n, method)
        return float(jnp.linalg.norm(jnp.mean(y - ref, axis=0)))

    without = [bias(sj.LiePoisson(second_order=False), n) for n in (2**8, 2**10)]
    with_terms = [bias(sj.LiePoisson(), n) for n in (2**8, 2**10)]
    assert without[1] > 0.75 * without[0]
    assert with_terms[1] < 0.5 * with_terms[0]
    assert without[1] > 10 * with_terms[1]


# --------------------------------------------------------------------------------------
# Exact moments of the linear SDE.


def linear_h(y, a):
    return a @ y


A_DRIFT = np.array([0.3, -0.2, 0.5])


def exact_moments(y0, t):
    """E[y_t] and E[y_t y_t^T] of dy = -hat(a) y dt - sum_r hat(chi_r) y o dW_r: Ito drift
    M = -hat(a) + sum_r hat(chi_r)^2 / 2, and E' = M E + E M^T + sum_r C_r E C_r^T."""
    cs = [np.asarray(hat(c)) for c in CHI]
    m = -np.asarray(hat(A_DRIFT)) + 0.5 * sum(c @ c for c in cs)
    op = np.zeros((9, 9))
    for k in range(9):
        e = np.zeros(9)
        e[k] = 1.0
        e = e.reshape(3, 3)
        op[:, k] = (m @ e + e @ m.T + sum(c @ e @ c.T for c in cs)).ravel()
    mean = scipy.linalg.expm(m * t) @ y0
    second = scipy.linalg.expm(op * t) @ np.outer(y0, y0).ravel()
    return np.concatenate([mean, second])


@pytest.mark.parametrize("method", [sj.LiePoisson(), sj.Midpoint()], ids=type)
def test_linear_hamiltonians_exact_moments(method):
    """Ensemble moments within 4 standard errors plus the weak bias, estimated on coupled
    paths, which must decrease with h (weak order 1: about halves per halving). 4000 samples:
    standard errors about 2e-3."""
    model = sj.LiePoissonSystem(linear_h, A_DRIFT, noise=sj.salt_noise(CHI))
    y0 = jnp.asarray([0.4, 0.3, 0.2])
    n_samples, n_fine = 4000, 32
    keys = jax.random.split(jax.random.key(3), n_samples)
    dW = jax.vmap(lambda k: sj.BrownianMotion().increments(k, n_fine, 1.0 / n_fine, n_noises=3))(
        keys
    )

    def moments(n):
        y = jax.jit(jax.vmap(lambda d: sj.integrate(model, y0, d, 1.0 / n, method=method)))(
            coarse(dW, n)
        )
        y = np.asarray(y)
        return np.concatenate([y, (y[:, :, None] * y[:, None, :]).reshape(-1, 9)], axis=1)

    exact = exact_moments(np.asarray(y0), 1.0)
    f8, f16, f32 = moments(8), moments(16), moments(32)
    bias = {8: np.abs((f8 - f32).mean(0)), 16: np.abs((f16 - f32).mean(0))}
    assert bias[16].max() < 0.75 * bias[8].max()
    for f, b in ((f8, bias[8]), (f16, bias[16]), (f32, 0.0)):
        se = f.std(0, ddof=1) / np.sqrt(n_samples)
        assert np.all(np.abs(f.mean(0) - exact) < 4 * se + b)


# --------------------------------------------------------------------------------------
# Gradients with respect to the noise's and the drift's parameters.


# (LiePoisson, Midpoint and SaltSplitting: with the Lévy areas, in tests/test_levy_order.py)
@pytest.mark.parametrize("method", [sj.LiePoissonSym2()], ids=type)
def test_gradients_chi_and_inertia_match_finite_differences(method):
    dt, n = 2.0**-5, 32
    keys = jax.random.split(jax.random.key(4), 8)
    dW = jax.vmap(lambda k: sj.BrownianMotion().increments(k, n, dt, n_noises=3))(keys)

    def estimate(theta):
        model = sj.RigidBody(theta[:3], noise=sj.salt_noise(theta[3:].reshape(3, 3)))
        y = jax.vmap(
            lambda d: sj.integrate(
                model, Y0, d, dt, method=method, failures=sj.Failures(throw=False)
            )
        )(dW)
        return jnp.mean(model.hamiltonian(y)) + jnp.mean(y[:, 0])

    theta = jnp.concatenate([INERTIA, jnp.asarray(CHI).ravel()])
    grad = np.asarray(jax.jit(jax.grad(estimate))(theta))
    f = jax.jit(estimate)
    eps = 1e-4
    fd = np.array(
        [
            (f(theta.at[i].add(eps)) - f(theta.at[i].add(-eps))) / (2 * eps)
            for i in range(theta.size)
        ]
    )
    np.testing.assert_allclose(grad, fd, atol=1e-6)


def test_calibrate_recovers_a_salt_amplitude():
    """Statistics of the ensemble at chi[0, 0] = 0.4 on the very paths calibrate simulates
    (common random numbers): the loss is zero at the truth, so the fit from 0.2 must land on
    it to the optimiser's tolerance."""
    ts, dt, n = [1.0], 2.0**-4, 32
    names = [f"chi[{r}, {j}]" for r in range(3) for j in range(3)]
    sol = sj.simulate(
        salt(),
        Y0,
        t1=1.0,
        dt=dt,
        n_samples=n,
        key=jax.random.key(8),
        save_every=16,
        method=sj.SaltSplitting(),
    )
    observed = jax.vmap(sj.moments, in_axes=1)(sol.ys[:, 1:])
    chi0 = CHI.copy()
    chi0[0, 0] = 0.2
    start = sj.RigidBody(INERTIA, noise=sj.salt_noise(chi0))
    res = sj.calibrate(
        sj.ObservedStatistics(observed, ts),
        Y0,
        dt=dt,
        n_samples=n,
        key=jax.random.key(8),
        init=start,
        fixed=("I_1", "I_2", "I_3", *names[1:]),
        method=sj.SaltSplitting(),
        optimisation=sj.Optimisation(progress=False),
    )
    assert res.names[3] == "chi[0, 0]"
    assert float(res.system.noise.chi[0, 0]) == pytest.approx(0.4, abs=1e-6)
    np.testing.assert_array_equal(np.asarray(res.system.noise.chi).ravel()[1:], CHI.ravel()[1:])


# --------------------------------------------------------------------------------------
# Bad input, refused by name before compiling.


def test_bad_input_refused():
    with pytest.raises(ValueError, match="either c .* or noise"):
        sj.LiePoissonSystem(rigid_body_h, INERTIA, c=0.2, noise=paper_noise)
    with pytest.raises(ValueError, match="either c .* or noise"):
        sj.RigidBody(INERTIA, 0.2, noise=sj.salt_noise(CHI))
    with pytest.raises(ValueError, match=r"shape \(s,\)"):
        sj.LiePoissonSystem(rigid_body_h, INERTIA, noise=lambda y, p: rigid_body_h(y, p))
    with pytest.raises(ValueError, match=r"shape \(s,\)"):
        sj.LiePoissonSystem(rigid_body_h, INERTIA, noise=lambda y, p: jnp.outer(y, y))
    with pytest.raises(TypeError, match="noise must be"):
        sj.LiePoissonSystem(rigid_body_h, INERTIA, noise=3.0)
    with pytest.raises(ValueError, match=r"chi must have shape \(s, 3\)"):
        sj.salt_noise(np.ones((3, 2)))
    with pytest.raises(ValueError, match="sigma must be finite"):
        sj.random_inertia_noise([[1.0, np.nan, 0.0]])
    with pytest.raises(ValueError, match=r"dW must have shape \(n_steps, 3\)"):
        sj.integrate(salt(), Y0, jnp.zeros((10, 2)), 0.1, method=sj.LiePoisson())
    with pytest.raises(ValueError, match=r"dW must have shape \(n_steps, 3\)"):
        sj.integrate(salt(), Y0, jnp.zeros(10), 0.1, method=sj.LiePoisson())
    for method in (sj.Strang(), sj.Strang4(), sj.Exact()):
        with pytest.raises(TypeError, match="Methods for this system: LiePoisson"):
            sj.integrate(salt(), Y0, jnp.zeros((10, 3)), 0.1, method=method)
    with pytest.raises(ValueError, match="scale"):
        sj.integrate(salt(), Y0, jnp.zeros((10, 3)), 0.1, method=sj.LiePoisson(scale=2.0))
    with pytest.raises(ValueError, match="no time-change solution"):
        sj.strong_convergence(
            salt(),
            Y0,
            t1=1.0,
            dts=[0.1, 0.05],
            n_samples=4,
            key=jax.random.key(0),
            methods=sj.Midpoint(),
        )


def test_simulate_draws_one_increment_per_noise():
    """simulate's sample i equals integrate on row i of BrownianMotion().increments(n_noises=3), and
    the noise families equal the same Hamiltonians given as functions."""
    key = jax.random.key(5)
    sol = sj.simulate(
        salt(),
        Y0,
        t1=0.25,
        dt=2.0**-5,
        n_samples=3,
        key=key,
        driver=sj.BrownianMotion(levy_area=False),
        method=sj.LiePoisson(),
    )
    dWs = sj.BrownianMotion().increments(key, 8, 2.0**-5, n_samples=3, n_noises=3)
    assert dWs.shape == (3, 8, 3)
    for i in range(3):
        np.testing.assert_allclose(
            sol.ys[i, -1],
            sj.integrate(salt(), Y0, dWs[i], 2.0**-5, method=sj.LiePoisson()),
            atol=1e-15,
        )
    dW, A = sj.BrownianMotion().increments(key, 8, 2.0**-5, n_noises=3, levy_area=True)
    sigma = 0.3 * np.eye(3) + 0.1
    for family, fn in (
        (sj.salt_noise(CHI), lambda y, p: jnp.asarray(CHI) @ y),
        (sj.random_inertia_noise(sigma), lambda y, p: 0.5 * jnp.asarray(sigma) @ (y * y)),
    ):
        # (with the Lévy areas: SALT's closed-form area term against autodiff's)
        for method in (sj.LiePoisson(), sj.Midpoint()):
            got = sj.integrate(
                sj.RigidBody(INERTIA, noise=family), Y0, dW, 2.0**-5, method=method, areas=A
            )
            want = sj.integrate(
                sj.LiePoissonSystem(rigid_body_h, INERTIA, noise=fn),
                Y0,
                dW,
                2.0**-5,
                method=method,
                areas=A,
            )
            np.testing.assert_allclose(got, want, atol=1e-13)
