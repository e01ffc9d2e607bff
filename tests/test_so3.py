import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from slps_jax import so3
from slps_jax._algebra import so3 as comp

rng = np.random.default_rng(1)
XIS = rng.normal(size=(20, 3)) * rng.uniform(0.0, 2.5, size=(20, 1))


def test_hat_vee_inverse_and_cross():
    v, u = rng.normal(size=3), rng.normal(size=3)
    np.testing.assert_allclose(so3.hat(v) @ u, np.cross(v, u), atol=1e-15)
    np.testing.assert_allclose(so3.vee(so3.hat(v)), v, atol=0)
    m = rng.normal(size=(3, 3))
    np.testing.assert_allclose(so3.hat(so3.vee(m)), so3.skew(m), atol=1e-15)
    np.testing.assert_allclose(so3.skew(m) + so3.sym(m), m, atol=1e-15)


@pytest.mark.parametrize("fn", [so3.exp, so3.cayley])
def test_rotations_are_special_orthogonal(fn):
    r = fn(XIS)
    eye = np.broadcast_to(np.eye(3), r.shape)
    np.testing.assert_allclose(jnp.swapaxes(r, -1, -2) @ r, eye, atol=2e-15)
    np.testing.assert_allclose(jnp.linalg.det(r), 1.0, atol=2e-15)


def test_exp_matches_scipy_and_log_inverts():
    np.testing.assert_allclose(so3.exp(XIS), Rotation.from_rotvec(XIS).as_matrix(), atol=2e-15)
    principal = XIS[np.linalg.norm(XIS, axis=1) < 3.0]  # log inverts exp for angles < pi
    assert len(principal) > 10
    np.testing.assert_allclose(so3.log(so3.exp(principal)), principal, atol=1e-13)
    tiny = np.array([1e-9, -2e-9, 3e-10])
    np.testing.assert_allclose(so3.exp(tiny), Rotation.from_rotvec(tiny).as_matrix(), atol=1e-17)


def test_cayley_matches_its_definition_and_inverse():
    for xi in XIS:
        x = np.asarray(so3.hat(xi))
        expected = np.linalg.solve(np.eye(3) - x / 2, np.eye(3) + x / 2)
        np.testing.assert_allclose(so3.cayley(xi), expected, atol=2e-15)
        # It is the rotation by 2 arctan(|xi|/2) about xi.
        theta = np.linalg.norm(xi)
        if theta > 0:
            rv = 2 * np.arctan(theta / 2) * xi / theta
            np.testing.assert_allclose(
                so3.cayley(xi), Rotation.from_rotvec(rv).as_matrix(), atol=2e-15
            )
    np.testing.assert_allclose(so3.cayley_inv(so3.cayley(XIS)), XIS, atol=1e-13)


@pytest.mark.parametrize("fn", [so3.exp, so3.cayley])
def test_gradients_finite_at_zero(fn):
    g = jax.jacfwd(fn)(jnp.zeros(3))
    assert np.all(np.isfinite(g))
    # d exp(hat xi)/d xi at 0 is hat(e_k) for both maps.
    for k in range(3):
        np.testing.assert_allclose(g[..., k], so3.hat(np.eye(3)[k]), atol=1e-15)
    gr = jax.grad(lambda x: jnp.sum(fn(x) ** 2 * jnp.arange(9.0).reshape(3, 3)))(jnp.zeros(3))
    assert np.all(np.isfinite(gr))
    hess = jax.hessian(lambda x: fn(x)[0, 1])(jnp.zeros(3))
    assert np.all(np.isfinite(hess))


def test_exp_gradient_matches_finite_differences_near_threshold():
    # Just above and below the switch to the Taylor series.
    for scale in [1e-5, 1e-3, 0.5]:
        xi = jnp.array([0.3, -0.5, 0.8]) * scale
        g = jax.jacfwd(so3.exp)(xi)
        eps = 1e-6
        fd = np.stack(
            [(so3.exp(xi + eps * e) - so3.exp(xi - eps * e)) / (2 * eps) for e in np.eye(3)],
            axis=-1,
        )
        np.testing.assert_allclose(g, fd, atol=1e-8)


def test_cofactor_solve():
    m, b = rng.normal(size=(3, 3)), rng.normal(size=3)
    x = comp.unvec(comp.solve3(comp.mat(jnp.asarray(m)), comp.vec(jnp.asarray(b))))
    np.testing.assert_allclose(x, np.linalg.solve(m, b), rtol=1e-12)
