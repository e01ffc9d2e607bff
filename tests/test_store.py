"""The run store (`slps_jax._support.store`): round trips, resume, a writer killed with
SIGKILL before, during and after a record's commit, damaged records, mismatched runs, flat
memory; and the su(N) spectra by degree (`zeitlin.energy_spectrum`, `enstrophy_spectrum`)
against exact facts."""

import gc
import os
import signal
import subprocess
import sys
import textwrap
import tracemalloc
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from slps_jax import zeitlin as z

zarr = pytest.importorskip("zarr")
from slps_jax._support.store import RunStore, open_run

MD = {
    "system": "euler-zeitlin N=6",
    "dt": 0.01,
    "save_every": 5,
    "method": "IsospectralMidpoint",
    "key": 0,
    "n_samples": 2,
    "dtype": "complex128",
    "fingerprint": "f00d",
}
SNAP = {"state": ((2, 6, 6), complex), "energy": ((2,), float), "spectrum": ((2, 6), "float32")}
CARRY = {"state": ((2, 6, 6), complex), "step": ((), np.int64), "key": ((2,), np.uint32)}
K = 3  # snapshots per record


def record(r):
    """Record `r`'s data and carry, a deterministic function of `r`."""
    rng = np.random.default_rng(r)
    snaps = {
        "state": rng.standard_normal((K, 2, 6, 6)) + 1j * rng.standard_normal((K, 2, 6, 6)),
        "energy": rng.standard_normal((K, 2)),
        "spectrum": rng.standard_normal((K, 2, 6)).astype(np.float32),
    }
    carry = {
        "state": rng.standard_normal((2, 6, 6)) + 1j * rng.standard_normal((2, 6, 6)),
        "step": np.int64((r + 1) * K * 5),
        "key": rng.integers(0, 2**32, 2, dtype=np.uint32),
    }
    return snaps, carry, (r + 1) * K * 5


def write(path, records, mode="create", start=0):
    with RunStore(path, MD, SNAP, CARRY, mode=mode) as s:
        for r in range(start, start + records):
            s.append(*record(r)[:2], step=record(r)[2])


def check_equal(path, n_records):
    """The store holds exactly records 0 ... n_records - 1, bit for bit."""
    run = open_run(path)
    assert len(run) == n_records * K
    for name in SNAP:
        want = np.concatenate([record(r)[0][name] for r in range(n_records)]) if n_records else None
        got = run.read(name)
        if n_records:
            assert got.dtype == want.dtype and np.array_equal(got, want), name
    steps = [record(r)[2] - 5 * np.arange(K - 1, -1, -1) for r in range(n_records)]
    steps = np.concatenate(steps) if steps else np.zeros(0, np.int64)
    np.testing.assert_array_equal(run.steps, steps)
    np.testing.assert_array_equal(run.times, steps * MD["dt"])
    cp = run.checkpoint
    if n_records:
        _, carry, step = record(n_records - 1)
        assert cp.step == step and cp.n_snapshots == n_records * K
        for name, x in carry.items():
            assert np.array_equal(cp.carry[name], x), name
    else:
        assert cp is None


def test_round_trip_and_reader(tmp_path):
    path = tmp_path / "run.zarr"
    write(path, 7)
    check_equal(path, 7)
    run = open_run(path)
    assert run.metadata == MD and run.fields == tuple(SNAP)
    np.testing.assert_array_equal(run.read("energy", 4), record(1)[0]["energy"][1])
    np.testing.assert_array_equal(
        run.read("energy", [0, 5]), np.stack([record(0)[0]["energy"][0], record(1)[0]["energy"][2]])
    )
    with pytest.raises(KeyError, match="fields are"):
        run.read("vorticity")


def test_resume_continues_and_checks_the_run(tmp_path):
    path = tmp_path / "run.zarr"
    write(path, 3)
    with RunStore(path, MD, SNAP, CARRY, mode="resume") as s:
        assert s.checkpoint is not None and s.checkpoint.step == record(2)[2]
        for name, x in record(2)[1].items():
            assert np.array_equal(s.checkpoint.carry[name], x)
        with pytest.raises(ValueError, match="step"):
            s.append(*record(1)[:2], step=record(1)[2])  # (a step already stored)
    write(path, 2, mode="resume", start=3)
    check_equal(path, 5)
    # another run: every differing key named
    with pytest.raises(ValueError, match=r"metadata\['fingerprint'\].*\n.*metadata\['seed'\]"):
        RunStore(path, {**MD, "fingerprint": "beef", "seed": 1}, SNAP, CARRY, mode="resume")
    with pytest.raises(ValueError, match=r"metadata\['dt'\]"):
        RunStore(path, {**MD, "dt": 0.02}, SNAP, CARRY, mode="resume")
    with pytest.raises(ValueError, match=r"snapshots\['energy'\]"):
        RunStore(path, MD, {**SNAP, "energy": ((3,), float)}, CARRY, mode="resume")
    with pytest.raises(ValueError, match=r"carry\['key'\]"):
        RunStore(path, MD, SNAP, {**CARRY, "key": ((2,), np.uint64)}, mode="resume")
    # no silent overwrite; overwrite when asked
    with pytest.raises(FileExistsError, match="resume"):
        RunStore(path, MD, SNAP, CARRY)
    RunStore(path, MD, SNAP, CARRY, mode="overwrite").close()
    check_equal(path, 0)
    # resume of an absent store creates it
    RunStore(tmp_path / "new.zarr", MD, SNAP, CARRY, mode="resume").close()
    check_equal(tmp_path / "new.zarr", 0)


def test_argument_errors(tmp_path):
    path = tmp_path / "run.zarr"
    with pytest.raises(ValueError, match="dt"):
        RunStore(path, {"save_every": 1}, SNAP, CARRY)
    with pytest.raises(TypeError, match="JSON"):
        RunStore(path, {**MD, "x": object()}, SNAP, CARRY)
    with pytest.raises(ValueError, match="mode"):
        RunStore(path, MD, SNAP, CARRY, mode="w")
    with pytest.raises(ValueError, match="'time'"):
        RunStore(path, MD, {"time": ((), float)}, CARRY)
    with RunStore(path, MD, SNAP, CARRY) as s:
        snaps, carry, step = record(0)
        with pytest.raises(ValueError, match="fields"):
            s.append({"state": snaps["state"]}, carry, step)
        with pytest.raises(ValueError, match=r"snapshots\['energy'\]: shape \(3, 2\)"):
            s.append({**snaps, "energy": snaps["energy"][:, :1]}, carry, step)
        with pytest.raises(TypeError, match="lose data"):
            s.append({**snaps, "energy": snaps["energy"] + 0j}, carry, step)
        with pytest.raises(RuntimeError, match="another process"):
            RunStore(path, MD, SNAP, CARRY, mode="resume")
        s.append({k: jnp.asarray(v) for k, v in snaps.items()}, carry, step)  # (JAX arrays)
    check_equal(path, 1)


WRITER = textwrap.dedent(
    """
    import os, signal, sys
    sys.path.insert(0, {tests!r})
    import test_store as t
    from slps_jax._support import store
    point, at = sys.argv[2], int(sys.argv[3])
    n = [0]
    def kill():
        os.kill(os.getpid(), signal.SIGKILL)
    def hook(p):
        if n[0] == at and p == point:
            kill()
        if n[0] == at and point == "renaming" and p == "commit":
            os.replace = lambda *a, **k: kill()  # (the commit's temporary file is written)
        if p == "committed":
            n[0] += 1
    store._hook = hook
    t.write(sys.argv[1], 5)
    """
)


@pytest.mark.parametrize(
    "point, complete",
    [("data", 2), ("carry", 2), ("commit", 2), ("renaming", 2), ("committed", 3)],
)
def test_sigkill_recovers_the_last_committed_record(tmp_path, point, complete):
    """Killed in record 3 (index 2): mid-data, before the carry, before the commit, while
    the commit's file is renamed into place, after the commit."""
    path = str(tmp_path / "run.zarr")
    script = WRITER.format(tests=os.path.dirname(__file__))
    p = subprocess.run([sys.executable, "-c", script, path, point, "2"], capture_output=True)
    assert p.returncode == -signal.SIGKILL, p.stderr.decode()
    check_equal(path, complete)  # (the reader sees committed records only)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        s = RunStore(path, MD, SNAP, CARRY, mode="resume")
    assert s.checkpoint is not None and s.checkpoint.step == record(complete - 1)[2]
    dropped = point in ("data", "carry", "commit", "renaming")
    assert any("not complete" in str(x.message) for x in w) == dropped
    for _, _, files in os.walk(path):
        assert not [f for f in files if f.endswith(".partial")]
    for r in range(complete, 5):
        s.append(*record(r)[:2], step=record(r)[2])
    s.close()
    check_equal(path, 5)


def _chunk_file(path, name):
    for root, _, files in os.walk(os.path.join(path, name)):
        if files and "c" in root.split(os.sep):
            return os.path.join(root, files[0])
    raise AssertionError(name)


def _damage(f, how):
    if how == "garble":
        with open(f, "r+b") as fh:
            fh.seek(100)
            fh.write(b"\x13\x37" * 8)
    elif how == "truncate":
        os.truncate(f, os.path.getsize(f) // 2)
    else:
        os.remove(f)


@pytest.mark.parametrize("damage", ["garble", "truncate", "delete"])
def test_damaged_last_record_is_dropped_never_mixed(tmp_path, damage):
    """The last record's carry (slot 0 after 5 records) damaged: that record is dropped,
    the one before resumed from (its carry is in the other slot)."""
    path = str(tmp_path / "run.zarr")
    write(path, 5)
    _damage(_chunk_file(path, os.path.join("_carry", "state", "c", "0")), damage)
    if damage != "delete":  # (the CRC: an error, never other numbers)
        with pytest.raises(Exception):  # noqa: B017 (zarr's checksum error class varies)
            _ = open_run(path).checkpoint
    with pytest.warns(UserWarning, match="damaged"):
        s = RunStore(path, MD, SNAP, CARRY, mode="resume")
    assert s.checkpoint is not None and s.checkpoint.step == record(3)[2]
    s.append(*record(4)[:2], step=record(4)[2])
    s.close()
    check_equal(path, 5)


@pytest.mark.parametrize("damage", ["garble", "delete"])
def test_damaged_shared_chunk_raises(tmp_path, damage):
    """At this size one chunk holds every snapshot of `state`: damaged, no record before the
    last is whole either, and resuming is refused, clearly."""
    path = str(tmp_path / "run.zarr")
    write(path, 5)
    _damage(_chunk_file(path, "state"), damage)
    with pytest.raises(ValueError, match="last two records are damaged"):
        RunStore(path, MD, SNAP, CARRY, mode="resume")


def test_unreadable_store_raises(tmp_path):
    path = tmp_path / "run.zarr"
    write(path, 1)
    os.remove(path / "_commit" / "zarr.json")
    with pytest.raises(ValueError, match="interrupted|not a readable"):
        RunStore(path, MD, SNAP, CARRY, mode="resume")
    other = tmp_path / "other.zarr"
    zarr.open_group(other, mode="w", zarr_format=3)
    with pytest.raises(ValueError, match="not an slps-jax run store"):
        RunStore(other, MD, SNAP, CARRY, mode="overwrite")  # (never deletes foreign data)


def test_memory_is_flat(tmp_path):
    snaps, carry, _ = record(0)

    def grow(path, n):
        with RunStore(path, MD, SNAP, CARRY, durable=False) as s:
            tracemalloc.start()
            for r in range(n):
                s.append(snaps, carry, step=(r + 1) * K * 5)
            gc.collect()  # (zarr's asyncio leaves reference cycles behind)
            used = tracemalloc.get_traced_memory()[0]
            tracemalloc.stop()
        return used

    few, many = grow(tmp_path / "a.zarr", 10), grow(tmp_path / "b.zarr", 100)
    assert many - few < 256 * 1024, (few, many)


def test_xarray_opens_it(tmp_path):
    xr = pytest.importorskip("xarray")
    path = tmp_path / "run.zarr"
    write(path, 2)
    ds = open_run(path).to_xarray()
    assert ds["state"].dims == ("time", "sample", "row", "column")
    assert ds["time"].attrs["units"] == "s"
    np.testing.assert_array_equal(ds["time"].values, open_run(path).times)
    np.testing.assert_array_equal(ds["energy"].values, open_run(path).read("energy"))
    assert ds.attrs["fingerprint"] == MD["fingerprint"]
    direct = xr.open_zarr(path, consolidated=False)
    np.testing.assert_array_equal(direct["state"].values, open_run(path).read("state"))


# --- spectra by degree


def _single_degree(N, el, seed=0):
    rng = np.random.default_rng(seed)
    om = np.zeros(N * N)
    for m in range(-el, el + 1):
        om[z.elm2ind(el, m)] = rng.normal()
    return om


@pytest.mark.parametrize("N, el", [(5, 1), (8, 3), (8, 7)])
def test_single_degree_spectra(N, el):
    W = z.shr2mat(_single_degree(N, el), N)
    E, Zs = z.energy_spectrum(W), z.enstrophy_spectrum(W)
    assert E.shape == Zs.shape == (N,)
    np.testing.assert_allclose(np.delete(np.asarray(E), el), 0, atol=1e-13)
    np.testing.assert_allclose(np.delete(np.asarray(Zs), el), 0, atol=1e-13)
    np.testing.assert_allclose(E[el], z.energy(W), rtol=1e-12)
    np.testing.assert_allclose(E[el], z.enstrophy(W) / (el * (el + 1)), rtol=1e-12)


def test_spectra_sum_to_totals_under_jit_and_vmap():
    N = 9
    rng = np.random.default_rng(1)
    om = rng.standard_normal((2, 3, N * N))
    om[..., 0] = 0
    W = z.shr2mat(om, N)
    E, Zs = z.energy_spectrum(W), z.enstrophy_spectrum(W)
    assert E.shape == (2, 3, N)
    np.testing.assert_allclose(E.sum(-1), z.energy(W), rtol=1e-12)
    np.testing.assert_allclose(Zs.sum(-1), z.enstrophy(W), rtol=1e-12)
    # the degree-l part by mat2shr: 1/2 sum_m omega_lm^2
    for el in range(N):
        part = om[..., el * el : (el + 1) ** 2]
        np.testing.assert_allclose(Zs[..., el], 0.5 * (part**2).sum(-1), rtol=1e-12, atol=1e-14)
    vm = jax.vmap(jax.vmap(z.energy_spectrum))(W)
    np.testing.assert_allclose(vm, E, rtol=1e-13, atol=1e-15)
    jitted = jax.jit(lambda w: z.enstrophy_spectrum(w) * 2)(W)
    np.testing.assert_allclose(jitted, 2 * Zs, rtol=1e-13)


def test_spectra_single_precision():
    N = 16
    rng = np.random.default_rng(2)
    om = rng.standard_normal(N * N)
    om[0] = 0
    W = z.shr2mat(om, N)
    E32, Z32 = (
        z.energy_spectrum(W.astype(jnp.complex64)),
        z.enstrophy_spectrum(W.astype(jnp.complex64)),
    )
    assert E32.dtype == Z32.dtype == jnp.float32
    # float32 round-off in the projections: a few eps relative to the spectrum's size
    np.testing.assert_allclose(E32, z.energy_spectrum(W), rtol=0, atol=2e-5 * float(z.energy(W)))
    np.testing.assert_allclose(
        Z32, z.enstrophy_spectrum(W), rtol=0, atol=2e-5 * float(z.enstrophy(W))
    )


def test_without_zarr_the_error_says_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "zarr", None)
    with pytest.raises(ImportError, match=r'pip install "slps-jax\[store\]"'):
        RunStore(tmp_path / "run.zarr", MD, SNAP, CARRY)
