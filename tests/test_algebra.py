"""One suite for every Lie algebra of the library (`AbstractAlgebra`): adding an algebra to
`ALGEBRAS` checks it here, with no new test code.

Everything is checked against an independent fact: the Lie algebra axioms (antisymmetry,
Jacobi), the invariance of the pairing, finite differences of a function for its gradient,
the Casimirs' invariance under the coadjoint action and the bracket flow, the Cayley map's
group properties and derivative at 0, and NumPy for the matrix forms.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj

ALGEBRAS = [sj.SO3, sj.so(3), sj.so(4), sj.so(5), sj.su(2), sj.su(3), sj.su(4)]
IDS = [a.name + (" vectors" if a is sj.SO3 else "") for a in ALGEBRAS]


def _states(alg, k, seed=0, scale=1.0):
    keys = jax.random.split(jax.random.PRNGKey(seed), k)
    return [scale * alg.random_state(key) for key in keys]


def _close(a, b, tol=1e-12):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=tol)


@pytest.fixture(params=ALGEBRAS, ids=IDS)
def alg(request):
    return request.param


def test_vector_space_coordinates_are_orthonormal_and_invert(alg):
    x, y = _states(alg, 2)
    assert x.shape == alg.shape and x.dtype == alg.state_dtype(jnp.float64)
    assert jnp.iscomplexobj(x) == alg.is_complex
    cx, cy = alg.coordinates(x), alg.coordinates(y)
    assert cx.shape == (alg.dim,) and not jnp.iscomplexobj(cx)
    _close(alg.from_coordinates(cx), x)
    _close(alg.pairing(x, y), jnp.dot(cx, cy))
    _close(alg.norm_sq(x), jnp.dot(cx, cx))
    # the pairing is (1/2) Re tr(X^H Y) of the matrices, so(n) in su(n) included
    mx, my = np.asarray(alg.to_matrix(x)), np.asarray(alg.to_matrix(y))
    _close(alg.pairing(x, y), 0.5 * np.real(np.trace(mx.conj().T @ my)))
    _close(alg.from_matrix(mx), x)


def test_bracket_is_a_lie_bracket_and_the_pairing_is_invariant(alg):
    x, y, z = _states(alg, 3, seed=1)
    b = alg.bracket
    _close(b(x, y), -b(y, x))
    _close(b(x, b(y, z)) + b(y, b(z, x)) + b(z, b(x, y)), jnp.zeros_like(x), 1e-11)
    _close(alg.pairing(b(x, y), z), alg.pairing(x, b(y, z)))
    # the commutator of the matrices
    mx, my = np.asarray(alg.to_matrix(x)), np.asarray(alg.to_matrix(y))
    _close(alg.to_matrix(b(x, y)), mx @ my - my @ mx)


def test_gradient_matches_finite_differences_of_the_pairing(alg):
    """<grad f(y), v> = d/de f(y + e v) for a real function f that is not quadratic."""
    y, v, a = _states(alg, 3, seed=2)

    def f(u):
        m = alg.to_matrix(u)
        return (
            alg.pairing(a, u) ** 2
            + jnp.real(jnp.trace(m @ m @ jnp.conj(m).T @ m))
            + jnp.sum(jnp.abs(m) ** 3)
        )

    g = alg.gradient(jax.grad(f)(y))
    # a state of the algebra: its own projection
    _close(alg.project(alg.to_matrix(g)), g)
    eps = 1e-5
    fd = (f(y + eps * v) - f(y - eps * v)) / (2 * eps)
    np.testing.assert_allclose(float(alg.pairing(g, v)), float(fd), rtol=1e-8)


def test_casimirs_invariant_under_the_coadjoint_action_and_the_bracket_flow(alg):
    y, x = _states(alg, 2, seed=3)
    c0 = alg.casimirs(y)
    assert not jnp.iscomplexobj(c0) and c0.ndim == 1
    q = alg.cayley(alg.to_matrix(0.7 * x))
    _close(alg.casimirs(alg.act(q, y)), c0, 1e-11)
    # d/dt C(y + t [y, x]) = 0: the Casimirs are constant along every Lie-Poisson field
    _, dc = jax.jvp(alg.casimirs, (y,), (alg.bracket(y, x),))
    _close(dc, jnp.zeros_like(dc), 1e-11)
    # and they are not constant along a generic direction (the test can fail)
    _, dc = jax.jvp(alg.casimirs, (y,), (x,))
    assert float(jnp.max(jnp.abs(dc))) > 1e-3
    # the casimirs of the matrix form, by NumPy: tr M^2 is the first (up to so(3)'s -1/4)
    m = np.asarray(alg.to_matrix(y))
    tr2 = np.real(np.trace(m @ m))
    _close(c0[0], -0.25 * tr2 if alg.shape == (3,) else tr2)


def test_cayley_is_a_group_map_with_derivative_two(alg):
    (x,) = _states(alg, 1, seed=4, scale=0.5)
    mx = alg.to_matrix(x)
    q = alg.cayley(mx)
    eye = np.eye(alg.matrix_size)
    _close(q @ np.conj(np.asarray(q)).T, eye)  # unitary (orthogonal)
    _close(alg.cayley(-mx) @ q, eye)  # cay(-X) = cay(X)^{-1}
    ref = np.linalg.solve(eye - np.asarray(mx), eye + np.asarray(mx))
    _close(q, ref)
    eps = 1e-6  # d cay(tX)/dt at 0 = 2X
    _close((alg.cayley(eps * mx) - alg.cayley(-eps * mx)) / (2 * eps), 2 * mx, 1e-8)
    # (into U(N), not SU(N): det cay(X) = prod (1 + i m)/(1 - i m) has modulus 1 only; the
    # coadjoint action does not see the phase)
    _close(abs(np.linalg.det(np.asarray(q))), 1.0)


def test_validation_accepts_states_and_refuses_others_by_name(alg):
    (y,) = _states(alg, 1, seed=5)
    y = np.asarray(y)
    alg.validate("y0", y)
    with pytest.raises(ValueError, match="shape"):
        alg.validate("y0", np.zeros(alg.shape + (1,)))
    bad = y.copy()
    bad[(0,) * y.ndim] = np.nan
    with pytest.raises(ValueError, match="finite"):
        alg.validate("y0", bad)
    if alg.shape != (3,):
        with pytest.raises(ValueError, match=alg.condition):
            alg.validate("y0", y + np.eye(alg.matrix_size))
    if not alg.is_complex:
        with pytest.raises(TypeError, match="real"):
            alg.validate("y0", y + 0j)


def test_random_state_lies_in_the_algebra(alg):
    (y,) = _states(alg, 1, seed=6)
    _close(alg.act(np.eye(alg.matrix_size), y), y)
    m = np.asarray(alg.to_matrix(y))
    _close(m, -m.conj().T)
    if alg.is_complex:
        _close(np.trace(m), 0.0)


@pytest.mark.parametrize("n", [3, 4])
def test_so_n_sits_in_su_n_with_its_pairing_bracket_and_casimirs(n):
    so, su = sj.so(n), sj.su(n)
    x, y = (np.asarray(s) for s in _states(so, 2, seed=7))
    _close(su.pairing(x + 0j, y + 0j), so.pairing(x, y))
    _close(su.bracket(x + 0j, y + 0j), so.bracket(x, y))
    _close(
        su.gradient(jax.grad(lambda u: su.pairing(u, u**3))(x + 0j)),
        so.gradient(jax.grad(lambda u: so.pairing(u, u**3))(x)),
    )
    # so(n)'s Casimirs tr Y^{2k} are su(n)'s even ones
    _close(su.casimirs(x + 0j)[0::2][: n // 2], so.casimirs(x))


def test_algebras_are_refused_by_name():
    for bad in (1, 2.0, True):
        with pytest.raises(ValueError, match="su"):
            sj.su(bad)
    with pytest.raises(TypeError, match="algebra"):
        sj.LiePoissonSystem(lambda y, p: 0.0, algebra="su(3)")


def test_group_coordinates_span_the_group_algebra(alg):
    """The unknowns of implicit solves: coordinates of the group's Lie algebra (u(N) for
    su(N): one more, the centre), inverse to each other, skew(-Hermitian) matrices whose
    Cayley map is unitary; on states they extend the state's coordinates."""
    x = jax.random.normal(jax.random.key(8), (alg.group_dim,))
    m = alg.from_group_coordinates(x)
    _close(alg.group_coordinates(m), x)
    _close(m, -np.conj(np.asarray(m)).T)
    q = alg.cayley(0.3 * m)
    _close(q @ np.conj(np.asarray(q)).T, np.eye(alg.matrix_size))
    (y,) = _states(alg, 1, seed=9)
    _close(alg.group_coordinates(alg.to_matrix(y))[: alg.dim], alg.coordinates(y))
    assert alg.group_dim - alg.dim == (1 if alg.is_complex else 0)


def test_a_method_for_3_vectors_refuses_so3_matrices_naming_sj_so3():
    # so(3) as matrices (sj.so(3)) is the generic form, kept distinct from the vectors of
    # sj.SO3; a method that needs the vectors says which algebra it wants
    system = sj.GeneralisedRigidBody([1.0, 2.0, 3.0], c=0.2)
    y0 = np.array([[0.0, 0.3, 0.2], [-0.3, 0.0, 0.1], [-0.2, -0.1, 0.0]])
    with pytest.raises(TypeError, match=r"LiePoissonSym2 needs .*sj\.SO3.*not the matrices"):
        sj.integrate(system, y0, np.zeros((2, 1)), 0.01, method=sj.LiePoissonSym2())


def test_an_algebra_is_a_module_compared_by_value():
    """Static fields only: equal sizes give equal algebras (one compiled program for both),
    no leaves, and an algebra that misses part of the interface cannot be created."""
    fresh = type(sj.so(4))(4)
    assert fresh is not sj.so(4) and fresh == sj.so(4) and hash(fresh) == hash(sj.so(4))
    assert fresh != sj.so(5) and type(sj.su(4))(4) == sj.su(4)
    assert jax.tree_util.tree_leaves([sj.SO3, sj.so(4), sj.su(3)]) == []
    casimirs = jax.jit(lambda alg, y: alg.casimirs(y), static_argnums=0)
    y = sj.so(4).random_state(jax.random.key(0))
    np.testing.assert_array_equal(casimirs(fresh, y), casimirs(sj.so(4), y))
    assert casimirs._cache_size() == 1

    class NoCasimirs(type(sj.so(4))):
        casimirs = sj.AbstractAlgebra.casimirs

    with pytest.raises(TypeError, match="abstract"):
        NoCasimirs(4)
