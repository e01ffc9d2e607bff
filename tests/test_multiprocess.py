"""Two processes on JAX's multi-process runtime (localhost, gloo): the commands of docs/scaling.md.

`examples/multiprocess.py` is started twice, as docs/scaling.md says, each process with two CPU
devices, the mesh over all four: `jax.make_mesh`'s explicit axes, then automatic ones. With
either, its sharded `simulate` must equal the one-process run sample for sample, and its
`ensemble_statistics` the one-process moments, on both processes.
"""

import importlib.util
import os
import pathlib
import socket
import subprocess
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "examples" / "multiprocess.py"
TIMEOUT = 240


def _free_port():
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def _example():
    spec = importlib.util.spec_from_file_location("multiprocess_example", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_two_processes_equal_one(tmp_path):
    port = _free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                str(SCRIPT),
                "--coordinator",
                f"localhost:{port}",
                "--num-processes",
                "2",
                "--process-id",
                str(i),
                "--cpu-devices",
                "2",
                "--out",
                str(tmp_path),
                "--axis-types",
                "explicit",
                "auto",
            ],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        for i in range(2)
    ]
    outputs = []
    try:
        for p in procs:
            outputs.append(p.communicate(timeout=TIMEOUT)[0])
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    for i, (p, out) in enumerate(zip(procs, outputs)):
        assert p.returncode == 0, f"process {i} exited with {p.returncode}:\n{out[-3000:]}"
        for kind in ("explicit", "auto"):
            assert f"process {i} of 2: 2 of 4 devices, {kind} mesh axes" in out, out[-3000:]

    sol, stats = _example().run(sharding=None)
    ys, fail_step = np.asarray(sol.ys), np.asarray(sol.fail_step)
    assert ys.shape == (16, 5, 3) and np.all(fail_step < 0)
    for i, kind in ((0, "explicit"), (1, "explicit"), (0, "auto"), (1, "auto")):
        got = np.load(tmp_path / f"process-{i}-{kind}.npz")
        assert int(got["n_local"]) == 8  # each process held its own half of the samples
        assert np.array_equal(got["ys"], ys), np.max(np.abs(got["ys"] - ys))
        assert np.array_equal(got["fail_step"], fail_step)
        assert int(got["n_failed"]) == 0
        assert int(got["n"]) == stats.n == 200
        np.testing.assert_allclose(got["mean"], stats.mean, rtol=0, atol=1e-14)
        np.testing.assert_allclose(got["var"], stats.var, rtol=1e-10, atol=1e-18)
