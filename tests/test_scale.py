"""Sharded ensembles (simulate over several devices) and streamed statistics.

References are independent of the code under test: the unsharded run for the sharded one,
and NumPy's moments of an unchunked `simulate` for the streamed ones.
"""

import os
import pathlib
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj

ROOT = pathlib.Path(__file__).resolve().parents[1]
KW = dict(t1=0.25, dt=2.0**-5)
ALL = ("mean", "var", "cov", "skewness", "kurtosis")

SHARDED = textwrap.dedent("""
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    from jax.sharding import AxisType, Mesh, NamedSharding, PartitionSpec
    import slps_jax as sj
    assert sj.__file__.startswith(ROOT), sj.__file__
    assert len(jax.devices()) == 4
    model, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    kw = dict(t1=0.25, dt=2.0 ** -5, n_samples=16, key=jax.random.key(5), save_every=4,
              method=sj.LiePoisson())  # (closed-form Newton steps: the same bits sharded)
    ref = sj.simulate(model, y0, **kw)
    assert len(ref.ys.sharding.device_set) == 1
    # a mesh of automatic axes, and jax.make_mesh's of explicit ones (its default)
    explicit = jax.make_mesh((4,), ("samples",), axis_types=(AxisType.Explicit,))
    meshes = (Mesh(jax.devices(), ("samples",)), explicit)
    X = 0.3 * sj.zeitlin.shr2mat(np.eye(16)[[1, 6]], 4)
    body = sj.EulerZeitlin(4, noise=sj.salt_noise(X))
    w0 = sj.zeitlin.shr2mat(0.3 * np.arange(16) / 16, 4)
    zk = dict(t1=0.25, dt=2.0 ** -5, n_samples=8, key=jax.random.key(6),
              method=sj.IsospectralMidpoint())
    zref = sj.simulate(body, w0, **zk)
    e = np.asarray(body.energy(zref.ys))
    for mesh in meshes:
        sh = NamedSharding(mesh, PartitionSpec("samples"))
        out = sj.simulate(model, y0, sharding=sh, **kw)
        assert out.ys.sharding == sh, out.ys.sharding  # on the caller's mesh
        auto = sj.simulate(model, y0, sharding="auto", **kw)
        for sol in (out, auto):
            assert np.array_equal(np.asarray(sol.ys), np.asarray(ref.ys))
            assert np.array_equal(np.asarray(sol.fail_step), np.asarray(ref.fail_step))
            assert len(sol.ys.sharding.device_set) == 4
            shards = sol.ys.addressable_shards
            assert sorted(s.device.id for s in shards) == [0, 1, 2, 3]
            assert all(s.data.shape == (4, 3, 3) for s in shards), [s.data.shape for s in shards]
        # the results combine with the caller's arrays on the same mesh
        ones = jax.device_put(jnp.ones((16, 3)), sh)
        both = jax.jit(lambda a, b: a[:, -1] + b)(out.ys, ones)
        assert np.array_equal(np.asarray(both), np.asarray(ref.ys)[:, -1] + 1)
        try:
            sj.simulate(model, y0, **{**kw, "n_samples": 10}, sharding=sh)
        except ValueError as err:
            assert "multiple" in str(err) and "8 or 12" in str(err), err
        else:
            raise AssertionError("n_samples=10 over 4 devices was accepted")
        st = sj.ensemble_statistics(model, y0, t1=0.25, dt=2.0 ** -5, n_samples=16,
                                    chunks=sj.Chunks(8, sharding=sh, progress=False),
                                    key=jax.random.key(5), save_every=4, method=sj.LiePoisson())
        ys = np.asarray(ref.ys)
        assert np.allclose(st.mean, ys.mean(0), rtol=0, atol=1e-14)
        assert np.allclose(st.var, ys.var(0, ddof=1), rtol=1e-10, atol=1e-18)
        # complex states (Euler-Zeitlin on su(4), two transport noises, Lévy areas) alike
        out = sj.simulate(body, w0, sharding=sh, **zk)
        assert out.ys.dtype == jnp.complex128 and len(out.ys.sharding.device_set) == 4
        # (the same arithmetic up to the order XLA's batched matrix products take: round-off)
        diff = np.max(np.abs(np.asarray(out.ys) - np.asarray(zref.ys)))
        assert diff < 1e-13, diff
        st = sj.ensemble_statistics(body, w0, chunks=sj.Chunks(4, sharding=sh, progress=False),
                                    statistics=sj.Statistics(observable=lambda ws: body.energy(ws)),
                                    **zk)
        assert np.allclose(st.mean[-1], e[:, -1].mean(), rtol=1e-13)
    # particle_filter: every device forecasts its own particles; the same filter
    obs = 0.1 + np.asarray(y0)[None, :2]
    pf = dict(dt=2.0 ** -5, key=jax.random.key(3), tempering=sj.Tempering(jitter_steps=1))
    obs = sj.Observations(obs, times=[0.25], observe=lambda y: y[:2], std=0.05)
    parts = np.broadcast_to(y0, (8, 3))
    pref = sj.particle_filter(model, parts, obs, **pf)
    got = sj.particle_filter(model, parts, obs, sharding="auto", **pf)
    assert len(got.particles.sharding.device_set) == 4, got.particles.sharding
    assert np.allclose(got.particles, pref.particles, rtol=0, atol=1e-13)
    assert np.allclose(got.ess, pref.ess, rtol=1e-12)
    # Under the caller's context mesh of explicit axes (jax.set_mesh), with the system, y0
    # and key made there, with and without a sharding, and a study.
    study = dict(t1=0.25, dts=[2.0 ** -3, 2.0 ** -4], n_samples=4, key=jax.random.key(1),
                 methods={"Strang": sj.Strang()})
    errors = sj.strong_convergence(model, y0, **study).errors["Strang"]
    sh = NamedSharding(explicit, PartitionSpec("samples"))
    with jax.set_mesh(explicit):
        model, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
        kw["key"] = jax.random.key(5)
        for sharding in (sh, "auto", None):
            sol = sj.simulate(model, y0, sharding=sharding, **kw)
            assert np.array_equal(np.asarray(sol.ys), np.asarray(ref.ys)), sharding
            assert float(jnp.mean(sol.ys[:, -1, 0]) - ref.ys[:, -1, 0].mean()) == 0.0
            st = sj.ensemble_statistics(model, y0, **kw,
                                        chunks=sj.Chunks(8, sharding=sharding, progress=False))
            assert np.allclose(st.mean, ys.mean(0), rtol=0, atol=1e-14), sharding
        study["key"] = jax.random.key(1)
        got = sj.strong_convergence(model, y0, **study).errors["Strang"]
        assert np.array_equal(np.asarray(got), np.asarray(errors)), (got, errors)
    print("SHARDED OK")
""")


def test_sharded_simulate_matches_unsharded_on_four_devices():
    # (the suite's XLA flags kept: tests/conftest.py)
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=4"
    env = dict(
        os.environ,
        XLA_FLAGS=flags.strip(),
        JAX_PLATFORMS="cpu",
        PYTHONPATH=os.pathsep.join(
            [str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
        ),
    )
    code = f"ROOT = {str(ROOT)!r}\n" + SHARDED
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=600, env=env
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "SHARDED OK" in proc.stdout


def _numpy_moments(ys):
    d = ys - ys.mean(0)
    m2 = (d**2).mean(0)
    cov = np.einsum("s...i,s...j->...ij", d, d) / (ys.shape[0] - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return dict(
            mean=ys.mean(0),
            var=ys.var(0, ddof=1),
            cov=cov,
            skewness=(d**3).mean(0) / m2**1.5,
            kurtosis=(d**4).mean(0) / m2**2,
        )


@pytest.fixture(scope="module")
def reference():
    model, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    sol = sj.simulate(
        model, y0, n_samples=50, key=jax.random.key(3), save_every=4, method=sj.Strang(), **KW
    )
    return model, y0, np.asarray(sol.ys)


@pytest.mark.parametrize("chunk_size", [16, 7, 50])
def test_streamed_moments_equal_numpy_on_the_unchunked_run(reference, chunk_size):
    model, y0, ys = reference
    st = sj.ensemble_statistics(
        model,
        y0,
        n_samples=50,
        key=jax.random.key(3),
        save_every=4,
        method=sj.Strang(),
        **KW,
        chunks=sj.Chunks(chunk_size, progress=False),
        statistics=sj.Statistics(ALL),
    )
    assert (st.n, st.n_failed, st.n_chunks) == (50, 0, -(-50 // chunk_size))
    np.testing.assert_allclose(st.ts, [0.0, 0.125, 0.25])
    ref = _numpy_moments(ys)
    np.testing.assert_allclose(st.mean, ref["mean"], rtol=0, atol=1e-15)
    np.testing.assert_allclose(st.var, ref["var"], rtol=1e-11, atol=1e-20)
    np.testing.assert_allclose(st.cov, ref["cov"], rtol=1e-11, atol=1e-20)
    # t = 0: every sample is y0, the variance is exactly zero and the ratios undefined.
    assert np.all(st.var[0] == 0) and np.all(np.isnan(st.skewness[0]))
    np.testing.assert_allclose(st.skewness[1:], ref["skewness"][1:], rtol=1e-9)
    np.testing.assert_allclose(st.kurtosis[1:], ref["kurtosis"][1:], rtol=1e-9)


def test_streamed_final_state_and_observable(reference):
    model, y0, ys = reference
    kw = dict(n_samples=50, key=jax.random.key(3), method=sj.Strang(), **KW)
    kw.update(chunks=sj.Chunks(20, progress=False))
    st = sj.ensemble_statistics(model, y0, **kw)
    np.testing.assert_allclose(st.ts, [0.0, 0.25])
    np.testing.assert_allclose(st.mean[-1], ys[:, -1].mean(0), rtol=0, atol=1e-15)
    assert st.cov is None and st.skewness is None
    energy = sj.ensemble_statistics(
        model,
        y0,
        save_every=4,
        **kw,
        statistics=sj.Statistics(("mean", "var"), observable=_energy),
    )
    h = np.stack([np.asarray(jax.vmap(model.hamiltonian)(jnp.asarray(y))) for y in ys])
    assert energy.mean.shape == (3,)
    np.testing.assert_allclose(energy.mean, h.mean(0), rtol=1e-14)
    np.testing.assert_allclose(energy.var[1:], h.var(0, ddof=1)[1:], rtol=1e-9)


def _energy(ys):
    return jax.vmap(sj.RigidBody.paper().hamiltonian)(ys)


def test_streaming_compiles_once_and_shows_progress(reference, capsys, monkeypatch):
    from slps_jax._driver import stream as _stream
    from slps_jax._support import progress as _progress

    model, y0, _ = reference
    monkeypatch.setattr(_progress, "interactive", lambda: True)  # as on a terminal
    before = _stream._chunk._cache_size()
    kw = dict(n_samples=45, key=jax.random.key(9), method=sj.Strang(), chunks=sj.Chunks(15), **KW)
    st = sj.ensemble_statistics(model, y0, **kw)
    assert st.n_chunks == 3 and st.n == 45
    assert _stream._chunk._cache_size() == before + 1
    err = capsys.readouterr().err
    assert "3/3" in err and "45/45 samples" in err
    monkeypatch.setattr(_progress, "interactive", lambda: False)  # a log: nothing in it
    sj.ensemble_statistics(model, y0, **kw)
    assert capsys.readouterr().err == ""


def test_streaming_counts_and_leaves_out_failed_samples(paper):
    # Three Newton updates are too few for some steps at this size (as in test_driver).
    model, y0 = paper
    kw = dict(
        t1=1.0,
        dt=0.05,
        key=jax.random.key(12),
        method=sj.LiePoisson(max_iter=3),
        failures=sj.Failures(retry_substeps=None),
    )
    with pytest.warns(RuntimeWarning):
        sol = sj.simulate(model, y0, n_samples=50, **kw)
    ok = np.asarray(sol.fail_step) < 0
    n_failed = int(np.sum(~ok))
    assert 0 < n_failed < 50
    with pytest.warns(RuntimeWarning, match=f"{n_failed} of 50"):
        st = sj.ensemble_statistics(
            model, y0, n_samples=50, **kw, chunks=sj.Chunks(20, progress=False)
        )
    assert (st.n, st.n_failed) == (50 - n_failed, n_failed)
    np.testing.assert_allclose(st.mean[-1], np.asarray(sol.ys)[ok, -1].mean(0), atol=1e-15)
    # Failures(throw=True): the same report raises instead of leaving the samples out
    raising = {**kw, "failures": sj.Failures(retry_substeps=None, throw=True)}
    with pytest.raises(RuntimeError, match=f"{n_failed} of 50 samples failed"):
        sj.ensemble_statistics(
            model, y0, n_samples=50, chunks=sj.Chunks(20, progress=False), **raising
        )


@pytest.mark.parametrize(
    "bad, exc, match",
    [
        (lambda: dict(chunks=sj.Chunks(0)), ValueError, "size"),
        (lambda: dict(chunks=sj.Chunks(2.5)), ValueError, "size"),
        (lambda: dict(chunks=5), TypeError, "Chunks"),
        (lambda: dict(statistics=sj.Statistics(("mean", "median"))), ValueError, "median"),
        (lambda: dict(statistics=("mean", "var")), TypeError, "Statistics"),
        (lambda: dict(statistics=sj.Statistics(observable=3)), TypeError, "observable"),
        (lambda: dict(chunks=sj.Chunks(5, sharding="gpu")), ValueError, "sharding"),
        (lambda: dict(chunks=sj.Chunks(5, sharding=4)), TypeError, "sharding"),
        (lambda: dict(n_samples=0), ValueError, "n_samples"),
    ],
)
def test_streaming_rejects_bad_input(paper, bad, exc, match):
    model, y0 = paper
    kw = dict(n_samples=10, chunks=sj.Chunks(5, progress=False), key=jax.random.key(0), **KW)
    with pytest.raises(exc, match=match):
        sj.ensemble_statistics(model, y0, **{**kw, **bad()})


def test_simulate_rejects_bad_sharding(paper):
    model, y0 = paper
    with pytest.raises(TypeError, match="sharding"):
        sj.simulate(model, y0, n_samples=4, key=jax.random.key(0), sharding=object(), **KW)
    with pytest.raises(ValueError, match="sharding"):
        sj.simulate(model, y0, n_samples=4, key=jax.random.key(0), sharding="all", **KW)
