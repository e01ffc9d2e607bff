"""Strong order 1 with several non-commuting noises: the Lévy-area term, tested against the
exact signature of a path.

The reference (`levy_reference.py`, no library code) is a fine piecewise-linear Brownian
path and the ODE it drives (Wong–Zakai), solved piece by piece with RK4 to about 1e-10: it
has no scheme error. The coarse steps get that path's exact increments and Lévy areas.
Each method must then have strong order 1 with the areas, order 1/2 without them (Clark &
Cameron), and not order 1 with the areas' sign flipped: the test that pins the convention
`A[q, r] = (J_qr - J_rq)/2` and the sign of the bracket term. Poisson methods keep the
Casimirs to round-off throughout.

The sizes: 128 paths, 2^10 pieces, h = 2^-3 ... 2^-5 (at least 32 pieces a step: fewer bias
the fitted order). The fitted orders' sampling spread at this size is about 0.03 (measured
over 20 keys for the increments-only order: 0.46-0.57 at 100 paths).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from levy_reference import (
    coarsen,
    fine_path,
    salt_rigid_body_fields,
    salt_so_n_fields,
    wong_zakai_solution,
)
from reference import fitted_order

import slps_jax as sj
from slps_jax import AbstractNoise
from slps_jax._methods import METHODS

N_PATHS, N_FINE, T = 128, 2**10, 1.0
HS = [2.0**-k for k in range(3, 6)]

INERTIA = jnp.asarray([1.1, 1.7, 2.6])
CHI = 0.5 * np.array([[1.0, 0.2, 0.0], [0.0, 1.0, 0.3], [0.4, 0.0, 1.0]])
Y0 = jnp.asarray([0.45, -0.5, 0.4])

J4 = jnp.asarray([0.6, 0.9, 1.3, 1.7])
_E = np.eye(4)
# three skew noise directions of so(4) that do not commute
X4 = 0.5 * np.stack(
    [
        np.outer(_E[0], _E[1]) - np.outer(_E[1], _E[0]),
        np.outer(_E[1], _E[2])
        - np.outer(_E[2], _E[1])
        + 0.3 * (np.outer(_E[0], _E[3]) - np.outer(_E[3], _E[0])),
        np.outer(_E[2], _E[3]) - np.outer(_E[3], _E[2]),
    ]
)
Y4 = 0.3 * jnp.asarray(
    np.array([[0, 1, -0.5, 0.2], [-1, 0, 0.8, -0.4], [0.5, -0.8, 0, 0.6], [-0.2, 0.4, -0.6, 0]])
)


def _su3_inverse_laplacian():
    """Zeitlin's Laplacian on 3 x 3 matrices, -sum_a [S_a, [S_a, .]] with the spin-1 matrices
    built here, pseudo-inverted densely (no library code): P = Delta^+ W is traceless."""
    sp = np.sqrt(2.0) * np.diag([1.0, 1.0], 1)  # S_+ of spin 1
    spins = [(sp + sp.T) / 2, (sp - sp.T) / 2j, np.diag([1.0, 0.0, -1.0])]
    basis = np.eye(9).reshape(9, 3, 3)
    lap = np.stack(
        [(-sum(s @ (s @ b - b @ s) - (s @ b - b @ s) @ s for s in spins)).ravel() for b in basis], 1
    )
    return jnp.asarray(np.linalg.pinv(lap))


def _case(name):
    key = jax.random.key(2024)
    if name == "so(3)":
        model = sj.RigidBody(INERTIA, noise=sj.salt_noise(CHI))
        fields, y0 = salt_rigid_body_fields(INERTIA, CHI), Y0
    elif name == "su(3)":  # Euler-Zeitlin, three transport noises of degrees 1 and 2
        X = 0.4 * sj.zeitlin.shr2mat(np.eye(9)[[1, 3, 5]], 3)
        model = sj.EulerZeitlin(3, noise=sj.salt_noise(X))
        inv, hbar = _su3_inverse_laplacian(), 2 / np.sqrt(8.0)
        fields = salt_so_n_fields(lambda w: -(inv @ w.ravel()).reshape(3, 3) / hbar, X)
        y0 = sj.zeitlin.shr2mat(0.5 * np.array([0, 0.3, -0.2, 0.4, 0.5, -0.3, 0.2, 0.1, 0.4]), 3)
    else:
        model = sj.GeneralisedRigidBody(J4, noise=sj.salt_noise(X4))
        fields = salt_so_n_fields(lambda y: y / (J4[:, None] + J4[None, :]), X4)
        y0 = Y4
    dW_fine = fine_path(key, N_PATHS, N_FINE, T, 3)
    # (the fine path is the same for every case: three noises)
    return model, y0, dW_fine, wong_zakai_solution(fields, y0, dW_fine, T, rk4_steps=2)


CASES = {}


def case(name):
    if name not in CASES:
        CASES[name] = _case(name)
    return CASES[name]


def _norm2(model, y):
    return np.asarray(model.algebra.norm_sq(y))


SALT = sj.RigidBody(INERTIA, noise=sj.salt_noise(CHI))
# Every method of the registry that runs on the SALT rigid body (a new method is checked
# here without a test of its own), on so(4) the two coadjoint-orbit methods, and on
# Euler-Zeitlin su(3) the isospectral midpoint rule and scheme (42) on U(3).
PARAMS = [("so(3)", cls) for cls in METHODS if not cls.missing(SALT)] + [
    ("so(4)", sj.IsospectralMidpoint),
    ("so(4)", sj.LiePoisson),
    ("su(3)", sj.IsospectralMidpoint),
    ("su(3)", sj.LiePoisson),
]
# On U(3) at h = 1/8, LiePoisson's default chord iteration takes 27 updates a step on average
# and over 900 on the worst sample (continuation, then substeps), and the batch's loop waits
# for it; Newton's full Jacobian takes 4-5. The scheme, hence the order, is the same.
OPTIONS = {("su(3)", sj.LiePoisson): {"iteration": "newton"}}


def _coarse_runs(model, y0, method, dW_fine, areas):
    """The final states at every step size of `HS`, `(len(HS), n_runs, N_PATHS, ...)`, from
    one compiled program: each step size's increments (and areas) padded to the finest
    step's count and stepped one `integrate` step at a time for as many steps as it has.
    With `areas`, three runs (without areas, as zero areas: the area term then vanishes,
    `test_no_areas_equals_zero_areas`; with the areas; with their sign flipped), else one."""
    n_max = int(round(T / HS[-1]))
    dWs, As, ns = [], [], []
    for h in HS:
        dW, A = coarsen(dW_fine, int(round(h * N_FINE)))
        pad = ((0, 0), (0, n_max - dW.shape[1]))
        dWs.append(jnp.pad(dW, pad + ((0, 0),)))
        As.append(jnp.pad(A, pad + ((0, 0), (0, 0))))
        ns.append(dW.shape[1])

    def path(w, a, h, n):
        def step(i, y):
            return sj.integrate(
                model,
                y,
                w[i][None],
                h,
                method=method,
                areas=None if a is None else a[i][None],
                failures=sj.Failures(throw=False),
            )

        return jax.lax.fori_loop(0, n, step, jnp.asarray(y0))

    over_paths = jax.vmap(path, in_axes=(0, 0, None, None))
    if areas:  # (the runs' areas as one more batch axis: one loop for the three)
        signs = jnp.asarray([0.0, 1.0, -1.0])[:, None, None, None, None]
        run = jax.jit(jax.vmap(over_paths, in_axes=(None, 0, None, None)))
        return [run(dW, signs * A, h, n) for dW, A, h, n in zip(dWs, As, HS, ns)]
    run = jax.jit(lambda dW, h, n: over_paths(dW, None, h, n)[None])
    return [run(dW, h, n) for dW, h, n in zip(dWs, HS, ns)]


@pytest.mark.parametrize("name,cls", PARAMS, ids=[f"{n}-{c.__name__}" for n, c in PARAMS])
def test_declared_strong_orders_against_the_exact_signature(name, cls):
    """Each method's declared orders (`strong_orders`): `increments` without areas, `areas`
    with the exact areas (and not order 1 with their sign flipped); a Poisson method keeps
    the Casimirs to round-off, any other leaves them."""
    method = cls(**OPTIONS.get((name, cls), {}))
    model, y0, dW_fine, y_ref = case(name)
    declared = cls.strong_orders
    kinds = ["none"] if declared.areas is None else ["none", "areas", "flipped"]
    errors = {k: [] for k in kinds}
    casimir = 0.0
    c0 = np.asarray(model.algebra.casimirs(y0))
    for runs in _coarse_runs(model, y0, method, dW_fine, declared.areas is not None):
        for kind, ys in zip(kinds, runs):
            assert np.all(np.isfinite(ys))
            errors[kind].append(np.sqrt(np.mean(_norm2(model, ys - y_ref))))
            casimir = max(casimir, float(np.max(np.abs(model.algebra.casimirs(ys) - c0))))
    order = {k: fitted_order(HS, e) for k, e in errors.items() if e}
    if declared.increments is None:  # (EulerMaruyama: the Ito solution, no convergence)
        assert order["none"] < 0.2, (order, errors)
    else:
        assert abs(order["none"] - declared.increments) < 0.15, (order, errors)
    if declared.areas is None:
        dW, A = coarsen(dW_fine[:1], int(round(HS[-1] * N_FINE)))
        with pytest.raises(TypeError, match="does not use Lévy areas"):
            sj.integrate(model, y0, dW[0], HS[-1], areas=A[0], method=method)
    else:
        assert 0.85 * declared.areas <= order["areas"] <= 1.25 * declared.areas, (order, errors)
        assert order["flipped"] <= 0.75, (order, errors)
        # at the smallest step the areas already gain a factor of 2.5 or more (measured 2.9-4)
        assert errors["areas"][-1] < errors["none"][-1] / 2.5, errors
    if cls.poisson:
        assert casimir < 1e-13
    else:
        assert casimir > 1e-6


@pytest.mark.parametrize(
    "cls", [cls for cls in METHODS if cls.uses_levy_area()], ids=lambda cls: cls.__name__
)
def test_no_areas_equals_zero_areas(cls):
    """What the order test relies on: a method given zero areas steps as without areas."""
    model, y0 = sj.RigidBody(INERTIA, noise=sj.salt_noise(CHI)), Y0
    if cls.missing(model):
        pytest.skip(f"{cls.__name__} does not run this system")
    dW, A = sj.BrownianMotion().increments(jax.random.key(3), 8, 1 / 8, n_noises=3, levy_area=True)
    without = sj.integrate(model, y0, dW, 1 / 8, method=cls())
    zero = sj.integrate(model, y0, dW, 1 / 8, areas=0 * A, method=cls())
    np.testing.assert_allclose(zero, without, rtol=0, atol=1e-14)


def test_gradients_through_the_area_term_match_finite_differences():
    """d/d(inertia, chi) of the final state on fixed increments and areas, three methods,
    against central differences."""
    dW, A = sj.BrownianMotion().increments(jax.random.key(7), 8, 1 / 16, n_noises=3, levy_area=True)
    weights = jnp.asarray([0.3, -0.7, 0.5])

    def loss(theta, method):
        model = sj.RigidBody(theta[:3], noise=sj.salt_noise(theta[3:].reshape(3, 3)))
        return jnp.dot(
            weights,
            sj.integrate(
                model, Y0, dW, 1 / 16, areas=A, method=method, failures=sj.Failures(throw=False)
            ),
        )

    theta = jnp.concatenate([INERTIA, jnp.asarray(CHI).ravel()])
    eps = 1e-5
    for method in (sj.Midpoint(), sj.LiePoisson(), sj.SaltSplitting()):
        f = jax.jit(lambda t: loss(t, method))
        grad = jax.jit(jax.grad(lambda t: loss(t, method)))(theta)
        fd = np.array(
            [
                (f(theta.at[i].add(eps)) - f(theta.at[i].add(-eps))) / (2 * eps)
                for i in range(theta.size)
            ]
        )
        np.testing.assert_allclose(grad, fd, rtol=0, atol=1e-6, err_msg=type(method).__name__)


def test_sampled_areas_in_a_study_give_order_one():
    """Areas drawn by the library at the reference's step (32x finer), joined by Chen's
    relation over the coarse steps: SaltSplitting against itself at the fine step."""
    model = sj.RigidBody(INERTIA, noise=sj.salt_noise(CHI))
    res = sj.strong_convergence(
        model,
        Y0,
        t1=1.0,
        dts=HS,
        n_samples=64,
        key=jax.random.key(1),
        methods={"s": sj.SaltSplitting(), "no areas": sj.SaltSplitting()},
        driver=sj.BrownianMotion(levy_area={"no areas": False}),
        reference=sj.Reference(sj.SaltSplitting(), factor=32),
    )
    assert 0.85 <= res.order["s"] <= 1.25, res.table()
    assert res.reference_error < 0.1 * res.errors["s"][-1], res.table()
    # the same method without areas, against the same reference: order 1/2
    assert 0.35 <= res.order["no areas"] <= 0.65, res.table()
    with pytest.raises(ValueError, match="levy_area names methods"):
        sj.strong_convergence(
            model,
            Y0,
            t1=1.0,
            dts=HS,
            n_samples=4,
            key=jax.random.key(1),
            methods={"s": sj.SaltSplitting()},
            driver=sj.BrownianMotion(levy_area={"t": False}),
            reference=sj.SaltSplitting(),
        )


@pytest.mark.parametrize("algebra", [sj.so(6), sj.su(8)], ids=str)
def test_area_term_of_many_noises_equals_the_double_sum(algebra):
    """The SALT area term (1/2) sum_{q,r} A_qr [X_q, X_r], written out in NumPy over every
    pair, equals `area_gradient`'s O(r) form (one product of inner size r n) to round-off,
    and so does the generic noise's area Hamiltonian (through JAX's gradient)."""
    r = 5
    keys = jax.random.split(jax.random.key(11), r + 1)
    X = np.stack([np.asarray(algebra.random_state(k)) for k in keys[:r]])
    a = np.asarray(jax.random.normal(keys[r], (r, r)))
    A = a - a.T
    ref = 0.5 * sum(A[q, s] * (X[q] @ X[s] - X[s] @ X[q]) for q in range(r) for s in range(r))
    model = sj.LiePoissonSystem(
        lambda y, p: algebra.norm_sq(y), None, algebra=algebra, noise=sj.salt_noise(X)
    )
    y = algebra.random_state(jax.random.key(12))
    np.testing.assert_allclose(
        model.area_gradient(y, jnp.asarray(A)), ref, atol=1e-12 * np.max(np.abs(ref))
    )
    generic = AbstractNoise.area_gradient(model.noise, y, jnp.asarray(A), model.params, algebra)
    np.testing.assert_allclose(generic, ref, atol=1e-12 * np.max(np.abs(ref)))
