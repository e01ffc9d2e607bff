import os
import subprocess
import sys

# The suite's time is compilation: its programs run for milliseconds on small ensembles but
# take a second or more each to compile. XLA's CPU backend compiles them 1.1-1.6x faster with
# its elemental emitters than with its fusion emitters (the default), while LiePoisson's step
# runs 20-25% slower and the others' within 10% (benchmarks/README.md, "Compile time"); the
# whole suite takes 7.6 instead of 9.9 minutes. The arithmetic is IEEE either way. The
# benchmark scripts and notebook kernels that the tests start inherit the flag (the tests
# assert no timing); speed is measured by running the benchmark scripts themselves.
# A jaxlib that no longer knows the flag would abort at start-up, so it is tried first in a
# subprocess (once: the xdist workers inherit the answer).
_FLAG = "--xla_cpu_use_fusion_emitters=false"
if "SLPS_TESTS_XLA_FLAGS" not in os.environ:
    _env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} {_FLAG}".strip())
    _probe = subprocess.run([sys.executable, "-c", "import jax; jax.numpy.zeros(1).block_until_ready()"],
                            env=_env, capture_output=True)
    os.environ["SLPS_TESTS_XLA_FLAGS"] = _env["XLA_FLAGS"] if _probe.returncode == 0 else (
        os.environ.get("XLA_FLAGS", ""))
os.environ["XLA_FLAGS"] = os.environ["SLPS_TESTS_XLA_FLAGS"]

import jax  # noqa: E402
import pytest  # noqa: E402

# Accuracy work runs in float64; the library itself never flips this flag.
jax.config.update("jax_enable_x64", True)


@pytest.fixture
def paper():
    import slps_jax as sj

    return sj.RigidBody.paper(), jax.numpy.asarray(sj.PAPER_Y0)


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """Each module compiles its own programs; dropping them after it keeps the suite's memory
    flat (JAX keeps every compiled executable of a process otherwise)."""
    yield
    jax.clear_caches()
