"""`simulate_to_store`: a long run written to disk as it goes, equal to `simulate`, resumed
after a SIGKILL bit for bit, with memory flat in the number of steps."""

import jax

jax.config.update("jax_enable_x64", True)

import os
import signal
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

import slps_jax as sj
from slps_jax import zeitlin as z

pytest.importorskip("zarr")

N = 8


def smooth(n=N):
    om = np.zeros(n * n)
    om[1:25] = np.random.default_rng(0).normal(size=24)
    return z.shr2mat(om, n)


def system(kind="c", c=0.2):
    """su(8) Euler–Zeitlin with one noise proportional to the drift (the fixed point's warm
    start is then carried from step to step) or three transport noises."""
    if kind == "c":
        return sj.EulerZeitlin(N, c=c)
    return sj.EulerZeitlin(N, noise=sj.salt_noise(0.1 * z.shr2mat(np.eye(N * N)[[1, 2, 3]], N)))


def write(
    path,
    *,
    t1=1.0,
    dt=0.01,
    resume=False,
    kind="c",
    c=0.2,
    save_every=5,
    record_snapshots=4,
    **kwargs,
):
    return sj.simulate_to_store(
        system(kind, c),
        smooth(),
        sj.Store(path, resume=resume, progress=False, record_snapshots=record_snapshots),
        t1=t1,
        dt=dt,
        n_samples=3,
        key=jax.random.key(7),
        save_every=save_every,
        **kwargs,
    )


def fields(run):
    return {name: run.read(name) for name in run.fields}


def test_the_store_holds_simulate_and_its_diagnostics():
    """With transport noises (Lévy areas drawn) and with an Ornstein–Uhlenbeck driver, the
    stored states are `simulate`'s with the same arguments, bit for bit, snapshot by
    snapshot; the diagnostics are those of the stored states (energy, enstrophy, the
    spectra summing to them, the Casimirs as NumPy's traces)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        for kind, driver in (("salt", None), ("salt", sj.OrnsteinUhlenbeck(0.3))):
            path = os.path.join(tmp, f"run-{driver is None}")
            run = write(path, kind=kind, driver=driver)
            sol = sj.simulate(
                system(kind),
                smooth(),
                t1=1.0,
                dt=0.01,
                n_samples=3,
                key=jax.random.key(7),
                save_every=5,
                driver=driver,
            )
            states = run.read("state")
            assert states.shape == (21, 3, N, N)
            np.testing.assert_array_equal(states, np.swapaxes(np.asarray(sol.ys), 0, 1))
            np.testing.assert_allclose(run.times, np.asarray(sol.ts), rtol=0, atol=1e-12)
            assert run.read("ok").all()
        np.testing.assert_allclose(run.read("energy"), z.energy(states), rtol=1e-13)
        np.testing.assert_allclose(
            run.read("energy_spectrum").sum(-1), run.read("energy"), rtol=1e-12
        )
        np.testing.assert_allclose(
            run.read("enstrophy_spectrum").sum(-1), run.read("enstrophy"), rtol=1e-12
        )
        w = states[-1, 1]
        traces = [np.trace(np.linalg.matrix_power(w, k)) for k in range(2, 7)]
        expect = [t.real if k % 2 == 0 else t.imag for k, t in zip(range(2, 7), traces)]
        np.testing.assert_allclose(run.read("casimirs")[-1, 1], expect, rtol=1e-12)
        # the xarray view: named dimensions, the degrees and the time in seconds
        ds = run.to_xarray()
        assert ds["state"].dims == ("time", "sample", "row", "column")
        assert ds["energy_spectrum"].dims == ("time", "sample", "degree")
        np.testing.assert_array_equal(ds["degree"].values, np.arange(N))
        np.testing.assert_array_equal(ds["energy_spectrum"].values, run.read("energy_spectrum"))
        assert ds["time"].attrs["units"] == "s"
        np.testing.assert_allclose(ds["time"].values, run.times, rtol=0, atol=0)


KILLER = textwrap.dedent(
    """
    import os, signal, sys
    sys.path.insert(0, {tests!r})
    import test_long_run as t
    from slps_jax._support import store
    point, at = sys.argv[2], int(sys.argv[3])
    n = [0]
    def hook(p):
        if n[0] == at and p == point:
            os.kill(os.getpid(), signal.SIGKILL)
        if p == "committed":
            n[0] += 1
    store._hook = hook
    t.write(sys.argv[1])
    """
)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("whole") / "run.zarr")
    return fields(write(path)), path


@pytest.mark.parametrize("point, at", [("data", 1), ("commit", 3), ("committed", 4)])
def test_a_run_killed_and_resumed_is_the_run_never_stopped(tmp_path, uninterrupted, point, at):
    """Killed by SIGKILL while writing record 1's data, before record 3's commit, and just
    after record 4's commit (in a subprocess: 5 records of 4 snapshots, plus the initial
    state), then resumed with `resume=True`: every field (states, diagnostics, `ok`) equals
    the uninterrupted run's, bit for bit; the state, the warm start and the failure codes
    come back from the store's carry."""
    path = str(tmp_path / "run.zarr")
    script = KILLER.format(tests=os.path.dirname(__file__))
    p = subprocess.run([sys.executable, "-c", script, path, point, str(at)], capture_output=True)
    assert p.returncode == -signal.SIGKILL, p.stderr.decode()[-2000:]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (a half-written record is dropped with a warning)
        resumed = fields(write(path, resume=True))
    whole, _ = uninterrupted
    assert resumed.keys() == whole.keys()
    for name, values in whole.items():
        np.testing.assert_array_equal(resumed[name], values, err_msg=name)


def test_a_store_of_another_run_is_refused(tmp_path, uninterrupted):
    """Resuming with another step or another system's numbers is refused, naming what
    differs; a new run into an existing store is refused; a longer t1 extends the run."""
    _, whole = uninterrupted
    with pytest.raises(ValueError, match="dt"):
        write(whole, dt=0.02, resume=True)
    with pytest.raises(ValueError, match="system_numbers"):
        write(whole, c=0.3, resume=True)
    # the messages name what the user can pass to the function called (no mode= there)
    again = r"simulate_to_store\(\.\.\., Store\(\.\.\., resume=True\)\)"
    with pytest.raises(FileExistsError, match=again) as e:
        write(whole)
    assert "mode=" not in str(e.value)
    # resuming into a folder that is not a store: a clear error, nothing touched
    other = tmp_path / "notes"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="not a readable Zarr v3 store"):
        write(str(other), resume=True)
    assert os.listdir(other) == ["notes.txt"]
    longer = str(tmp_path / "longer.zarr")
    write(longer, t1=0.6)
    run = write(longer, t1=1.0, resume=True)
    np.testing.assert_array_equal(run.read("state"), fields(sj.open_run(whole))["state"])
    with pytest.raises(ValueError, match="save_every"):
        write(longer, save_every=None)


PEAK = textwrap.dedent(
    """
    import resource, sys
    import jax
    jax.config.update("jax_enable_x64", True)
    sys.path.insert(0, {tests!r})
    import test_long_run as t
    t.write(sys.argv[1], t1=float(sys.argv[2]), save_every=25, record_snapshots=20)
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    """
)


def test_memory_is_flat_in_the_number_of_steps(tmp_path):
    """The peak resident memory of a run of 10^3 steps and of one of 10^4 (su(8), 3 samples,
    a snapshot every 25 steps, 20 to a record: 400 snapshots in the longer store) differ by
    less than 20 MB: each record is written and let go."""
    peaks = []
    for t1 in (10.0, 100.0):
        script = PEAK.format(tests=os.path.dirname(__file__))
        p = subprocess.run(
            [sys.executable, "-c", script, str(tmp_path / f"run{t1}.zarr"), str(t1)],
            capture_output=True,
            text=True,
        )
        assert p.returncode == 0, p.stderr[-2000:]
        peaks.append(int(p.stdout.split()[-1]) / 1024)  # (MB)
    assert peaks[1] - peaks[0] < 20, peaks
