"""Every registered method (`slps_jax._methods.METHODS`) on every kind of system: one suite.

A new method added to the registry is checked here without writing a test for it: on each
system with the capabilities it declares (`requires`) it runs a small ensemble with every sample
successful and finite, and keeps the quadratic Casimir (`|y|^2`, or `tr Y^2` on so(n)) to
round-off if it is a Poisson integrator (a theorem; on su(3) for complex states); on the
first such system it also runs in
float32, within float32's accuracy of float64 on the same increments. On every other system
it is refused before compiling, with a `TypeError` that names methods that would work.
Orders and long-time behaviour are in the methods' own modules.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj
from slps_jax._methods import METHODS


def _skew(n, norm):
    a = np.random.default_rng(1).normal(size=(n, n))
    return norm * (a - a.T) / np.linalg.norm(a - a.T, 2)


def _quartic(y, p):
    return 0.5 * jnp.sum(y**2 / p["inertia"]) + p["eps"] * jnp.sum(y**4)


_CHI = 0.4 * np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.5, 1.0]])
SYSTEMS = {  # one of each kind: their capabilities differ
    "paper rigid body": (sj.RigidBody.paper(), np.asarray(sj.PAPER_Y0)),
    "rigid body, 3 SALT noises": (
        sj.RigidBody([1.0, 2.0, 3.0], noise=sj.salt_noise(_CHI)),
        np.array([0.6, 0.5, 0.3]),
    ),
    "quartic H": (
        sj.LiePoissonSystem(_quartic, {"inertia": jnp.asarray([1.0, 2.0, 3.0]), "eps": 0.5}, 0.2),
        np.array([0.6, 0.5, 0.3]),
    ),
    "so(4) rigid body": (
        sj.GeneralisedRigidBody(jnp.asarray([0.6, 1.1, 1.7, 2.3]), c=0.4),
        _skew(4, 0.8),
    ),
    "Euler-Zeitlin su(3), 2 SALT noises": (
        sj.EulerZeitlin(3, noise=sj.salt_noise(0.3 * sj.zeitlin.shr2mat(np.eye(9)[[1, 5]], 3))),
        sj.zeitlin.shr2mat(0.5 * np.array([0, 0.3, -0.2, 0.4, 0.5, -0.3, 0.2, 0.1, 0.4]), 3),
    ),
}
PAIRS = list(itertools.product(METHODS, SYSTEMS))
N_SAMPLES, N_STEPS, DT = 4, 16, 2.0**-5


def supports(cls, system):
    return not cls.missing(SYSTEMS[system][0])


def test_capabilities_are_what_each_system_is():
    """Each capability against what the systems above are, written out by hand."""
    from slps_jax._systems import capabilities as cap

    expected = {
        "paper rigid body": {
            cap.RIGID_BODY,
            cap.NOISE_PROPORTIONAL_TO_DRIFT,
            cap.QUADRATIC,
            cap.SO3_VECTORS,
        },
        "rigid body, 3 SALT noises": {cap.RIGID_BODY, cap.LINEAR_NOISE, cap.SO3_VECTORS},
        "quartic H": {cap.NOISE_PROPORTIONAL_TO_DRIFT, cap.SO3_VECTORS},
        "so(4) rigid body": {cap.NOISE_PROPORTIONAL_TO_DRIFT, cap.QUADRATIC},
        "Euler-Zeitlin su(3), 2 SALT noises": {cap.LINEAR_NOISE},
    }
    for name, (system, _) in SYSTEMS.items():
        assert {c for c in cap.CAPABILITIES if c(system)} == expected[name], name
    assert {c for c in cap.CAPABILITIES if c(sj.EulerZeitlin(3, c=0.1))} == {
        cap.NOISE_PROPORTIONAL_TO_DRIFT,
        cap.QUADRATIC,
    }


def quadratic_casimir(model, ys):
    return model.algebra.casimirs(ys)[..., 0]


def test_the_registry_holds_every_public_method():
    public = {
        name
        for name in dir(sj)
        if isinstance(getattr(sj, name), type)
        and issubclass(getattr(sj, name), sj.AbstractMethod)
        and getattr(sj, name) is not sj.AbstractMethod
    }
    assert public == {cls.__name__ for cls in METHODS}
    # every system is supported by some method, and every method by some system
    assert all(any(supports(cls, s) for cls in METHODS) for s in SYSTEMS)
    assert all(any(supports(cls, s) for s in SYSTEMS) for cls in METHODS)


@pytest.mark.parametrize("cls,system", PAIRS, ids=[f"{c.__name__}-{s}" for c, s in PAIRS])
def test_method_on_system(cls, system):
    model, y0 = SYSTEMS[system]
    method = cls()
    key = jax.random.key(0)
    if not supports(cls, system):
        with pytest.raises(TypeError, match=cls.__name__) as err:
            sj.simulate(
                model, y0, t1=N_STEPS * DT, dt=DT, n_samples=N_SAMPLES, key=key, method=method
            )
        works = [c.__name__ for c in METHODS if supports(c, system)]
        assert any(name in str(err.value) for name in works), str(err.value)
        return
    sol = sj.simulate(
        model,
        y0,
        t1=N_STEPS * DT,
        dt=DT,
        n_samples=N_SAMPLES,
        key=key,
        method=method,
        save_every=N_STEPS // 2,
    )
    assert sol.ys.shape == (N_SAMPLES, 3, *np.shape(y0))
    assert bool(jnp.all(sol.ok)) and bool(jnp.all(jnp.isfinite(sol.ys)))
    c0 = quadratic_casimir(model, jnp.asarray(y0))
    drift = float(jnp.max(jnp.abs(quadratic_casimir(model, sol.ys) / c0 - 1)))
    if not cls.poisson:
        assert drift > 1e-8  # the check below can fail: these methods leave the orbit
    else:
        assert drift < 1e-12
    if system != next(s for s in SYSTEMS if supports(cls, s)):
        return
    # float32, on the first system the method supports: sample 0 on simulate's own increments
    # (simulate equals integrate on them, tests/test_driver.py), within float32's accuracy:
    # Newton stops at 64 float32 ulps (8e-6) per step, 16 steps (measured up to 2e-5).
    # (with the Lévy areas simulate draws for a method that uses them)
    areas = cls.uses_levy_area() and model.n_noises > 1
    dW = sj.BrownianMotion().increments(
        key, N_STEPS, DT, n_samples=N_SAMPLES, n_noises=model.n_noises, levy_area=areas
    )
    dW, A = dW if areas else (dW, None)
    model32 = jax.tree_util.tree_map(
        lambda x: (
            jnp.asarray(x, jnp.float32) if jnp.issubdtype(jnp.result_type(x), jnp.floating) else x
        ),
        model,
    )
    y32 = sj.integrate(
        model32,
        jnp.asarray(y0, jnp.float32),
        dW[0].astype(jnp.float32),
        DT,
        method=method,
        areas=None if A is None else A[0].astype(jnp.float32),
    )
    assert y32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(y32, np.float64), sol.ys[0, -1], rtol=0, atol=1e-4)


@pytest.mark.parametrize("cls", METHODS, ids=[c.__name__ for c in METHODS])
def test_the_retry_wraps_only_steps_that_can_fail(cls):
    """Methods that cannot fail (`can_fail = False`: compositions of exact rotations) are
    traced without the retry of failing steps; the others with it."""
    system = next(s for s in SYSTEMS if supports(cls, s))
    model, y0 = SYSTEMS[system]
    dW = jnp.zeros((N_STEPS, model.n_noises))

    def traced(retry):
        return str(
            jax.make_jaxpr(
                lambda d: sj.integrate(
                    model,
                    y0,
                    d,
                    DT,
                    method=cls(),
                    failures=sj.Failures(retry_substeps=retry, throw=False),
                )
            )(dW)
        )

    assert (traced(4) == traced(None)) == (not cls.can_fail)


def test_auto_is_midpoint_on_so3_and_isospectral_midpoint_on_matrix_algebras():
    """`method="auto"`, the default of every entry point, is `default_method`: `Midpoint`
    on so(3)* (any system, one or several noises), `IsospectralMidpoint` on so(n)*, su(N)*;
    the same paths as naming the method. Anything else is refused, naming the choices."""
    picks = {
        "paper rigid body": sj.Midpoint,
        "rigid body, 3 SALT noises": sj.Midpoint,
        "quartic H": sj.Midpoint,
    }
    for name, cls in picks.items():
        model, y0 = SYSTEMS[name]
        assert type(sj.default_method(model)) is cls, name
    so4 = sj.GeneralisedRigidBody([0.6, 1.1, 1.7, 2.3], c=0.4)
    assert type(sj.default_method(so4)) is sj.IsospectralMidpoint
    assert type(sj.default_method(sj.EulerZeitlin(4))) is sj.IsospectralMidpoint
    model, y0 = SYSTEMS["rigid body, 3 SALT noises"]
    kw = dict(t1=0.25, dt=2.0**-4, n_samples=4, key=jax.random.key(0))
    np.testing.assert_array_equal(
        sj.simulate(model, y0, **kw).ys, sj.simulate(model, y0, method=sj.Midpoint(), **kw).ys
    )
    Y0 = _skew(4, 0.8)
    np.testing.assert_array_equal(
        sj.simulate(so4, Y0, **kw).ys,
        sj.simulate(so4, Y0, method=sj.IsospectralMidpoint(), **kw).ys,
    )
    dW = sj.BrownianMotion().increments(jax.random.key(1), 4, 2.0**-4)
    paper, y0 = SYSTEMS["paper rigid body"]
    np.testing.assert_array_equal(
        sj.integrate(paper, y0, dW, 2.0**-4),
        sj.integrate(paper, y0, dW, 2.0**-4, method=sj.Midpoint()),
    )
    for bad in ("fast", None):
        with pytest.raises(TypeError, match="'auto' or an instance"):
            sj.simulate(paper, y0, method=bad, **kw)


def test_one_kernel_returns_its_inputs_unchanged():
    """The Newton body's next state goes through `one_kernel` (a variadic reduce of each value
    with a zero, on a CPU): every value, signed zeros, infinities, NaN and integers included,
    comes back bit for bit, under `jit` and `vmap`, with its dtype. (Subnormals are left
    out: XLA:CPU flushes them to zero in every arithmetic operation, as in `x + y` and `x * y`
    of any jitted function.)"""
    from slps_jax._methods.newton import one_kernel

    x = jnp.array([1.5, -0.0, jnp.inf, -jnp.inf, jnp.nan, 2.3e-308, -1.7976931348623157e308])
    n = jnp.array([-3, 0, 7, 2**31 - 1, -(2**31), 1, 2], jnp.int32)
    a, b = jax.jit(jax.vmap(lambda u, k: one_kernel(u, k)))(x, n)
    assert a.dtype == x.dtype and b.dtype == n.dtype
    bits = np.asarray(a).view(np.int64)
    np.testing.assert_array_equal(np.delete(bits, 4), np.delete(np.asarray(x).view(np.int64), 4))
    assert np.isnan(a[4])
    np.testing.assert_array_equal(b, n)
    c = one_kernel(jnp.float32(2.5), jnp.ones((2, 3), jnp.float32))  # broadcast, not batched
    assert c[0].shape == (2, 3) and c[0].dtype == jnp.float32 and float(c[0][1, 2]) == 2.5
    d = one_kernel(jnp.float32(2.5), jnp.float64(-1.0))  # two precisions: passed as they are
    assert (d[0].dtype, float(d[0]), d[1].dtype, float(d[1])) == (
        jnp.float32,
        2.5,
        jnp.float64,
        -1.0,
    )
