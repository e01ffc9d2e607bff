"""Systems and noise families saved and loaded bit for bit (`sj.save`, `sj.load`), and the
run store keeping the system of its run (`open_run(path).system`): the same pytree
structure, the same bytes and dtypes in every array, the same paths when run again."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj
from slps_jax import zeitlin as z

N = 6


def _same(a, b):
    """The same pytree structure (static fields included) and the same arrays, bit for bit."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    return (
        type(a) is type(b)
        and ta == tb
        and all(
            np.asarray(x).dtype == np.asarray(y).dtype
            and np.asarray(x).tobytes() == np.asarray(y).tobytes()
            for x, y in zip(la, lb)
        )
    )


def _fitted():
    """A noise fitted by `fit_transport_noise` to a short su(12) run (the data-driven case)."""
    rng = np.random.default_rng(0)
    w0 = z.shr2mat(np.r_[0.0, rng.normal(size=143) / np.sqrt(np.arange(1, 144))], 12)
    ws = sj.integrate(sj.EulerZeitlin(12), w0, np.zeros((12, 1)), 0.01, save_every=1)
    return sj.fit_transport_noise(ws, dt=0.01, N=N, n_modes=2).noise


def test_systems_and_noise_families_round_trip_bit_for_bit(tmp_path):
    rng = np.random.default_rng(1)
    fitted = _fitted()
    forcing = z.shr2mat(np.eye(N * N)[5], N)
    objects = [
        sj.EulerZeitlin(N, noise=fitted),
        fitted,
        sj.EulerZeitlin(
            N,
            nu=1e-3,
            p=2,
            alpha=0.1,
            forcing=forcing,
            omega=0.5,
            stream=sj.Stream(gamma=0.2),
            additive=sj.AdditiveForcing((2, 3), 0.1),
        ),
        sj.EulerZeitlin(N, c=0.3, dtype=jnp.complex64),
        sj.EulerZeitlin(
            N, alpha=rng.uniform(0, 1, N), stream=sj.Stream(gain=rng.normal(size=N) / 10)
        ),
        sj.RigidBody.paper(),
        sj.GeneralisedRigidBody(
            rng.uniform(1, 2, 4),
            noise=sj.salt_noise(np.stack([np.eye(4)[[1, 0, 2, 3]] - np.eye(4)[[1, 0, 2, 3]].T])),
        ),
    ]
    for k, obj in enumerate(objects):
        path = sj.save(tmp_path / f"{k}.pickle", obj)
        assert _same(sj.load(path), obj), obj
    # and the loaded system runs the same path, bit for bit
    system = objects[0]
    again = sj.load(tmp_path / "0.pickle")
    w0 = z.shr2mat(np.r_[0.0, rng.normal(size=N * N - 1)], N)
    run = lambda s: sj.simulate(s, w0, t1=0.1, dt=0.01, n_samples=2, key=jax.random.key(3)).ys
    np.testing.assert_array_equal(run(again), run(system))


def _lambda_system():
    return sj.LiePoissonSystem(
        lambda y, p: 0.5 * jnp.sum(y**2 / p), jnp.array([1.0, 2.0, 3.0]), 0.2
    )


def test_what_cannot_be_saved_or_loaded_is_refused(tmp_path):
    with pytest.raises(TypeError, match="top level, not as lambdas"):
        sj.save(tmp_path / "x.pickle", _lambda_system())
    assert not (tmp_path / "x.pickle").exists()
    (tmp_path / "other.pickle").write_bytes(b"not a pickle at all")
    with pytest.raises(ValueError, match="not a saved slps-jax object"):
        sj.load(tmp_path / "other.pickle")


def test_the_run_store_keeps_its_system(tmp_path):
    system = sj.EulerZeitlin(N, noise=_fitted())
    w0 = z.shr2mat(np.r_[0.0, np.random.default_rng(2).normal(size=N * N - 1)], N)
    kw = dict(t1=0.1, dt=0.01, n_samples=2, key=jax.random.key(0), save_every=5)
    run = sj.simulate_to_store(system, w0, sj.Store(tmp_path / "run.zarr", progress=False), **kw)
    assert _same(sj.open_run(tmp_path / "run.zarr").system, system)
    assert _same(run.system, system)
    # kept where xarray does not see it: no variable of it, and no warning
    xr = pytest.importorskip("xarray")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = xr.open_zarr(tmp_path / "run.zarr", consolidated=False)
        assert set(ds.data_vars) == set(run.fields) | {"step"}
        run.to_xarray()
    # a system that cannot be pickled: the run is stored, with a warning that says so
    with pytest.warns(RuntimeWarning, match="not kept in the store"):
        sj.simulate_to_store(
            _lambda_system(), sj.PAPER_Y0, sj.Store(tmp_path / "rb.zarr", progress=False), **kw
        )
    with pytest.raises(ValueError, match="holds no saved system"):
        _ = sj.open_run(tmp_path / "rb.zarr").system
