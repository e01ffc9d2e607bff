import ctypes
import gc
import os
import shutil
import subprocess
import sys
import tempfile

# The suite's time is compilation: its programs run for milliseconds on small ensembles but
# take a second or more each to compile. Two options of XLA's CPU backend trade run time for
# compile time: its elemental emitters instead of its fusion emitters (the default), and
# LLVM's optimisation level 0 instead of 2. With both, a method's program compiles about 2x
# faster and runs 2-9x slower (benchmarks/README.md, "Compile time", the A/B against XLA's
# defaults); the suite took 5.3 instead of 9.9 minutes (373 tests). Results agree with the
# defaults' to round-off (1e-15 on the paper's setup: fast math is off at every level).
# The benchmark scripts and notebook kernels that the tests start inherit the flags (the
# tests assert no timing); speed is measured by running the benchmark scripts themselves,
# with XLA's defaults.
# A third, --xla_cpu_parallel_codegen_split_count=1, compiles a program's LLVM module as one
# piece instead of several on a thread pool: with both cores busy with the two workers the
# split only adds work (0.86x the compile time in two concurrent processes, benchmarks/README.md,
# "The test suite's settings").
_FLAGS = (
    "--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=0 "
    "--xla_cpu_parallel_codegen_split_count=1"
)
# A jaxlib that no longer knows a flag would abort at start-up, so they are tried first in a
# subprocess (once: the xdist workers inherit the answer).
if "SLPS_TESTS_XLA_FLAGS" not in os.environ:
    _env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} {_FLAGS}".strip())
    _probe = subprocess.run(
        [sys.executable, "-c", "import jax; jax.numpy.zeros(1).block_until_ready()"],
        env=_env,
        capture_output=True,
    )
    os.environ["SLPS_TESTS_XLA_FLAGS"] = (
        _env["XLA_FLAGS"] if _probe.returncode == 0 else (os.environ.get("XLA_FLAGS", ""))
    )
os.environ["XLA_FLAGS"] = os.environ["SLPS_TESTS_XLA_FLAGS"]
# One persistent compilation cache for the run, shared by every process of it (the xdist
# workers, the notebook kernels, the processes the benchmark scripts start and the command
# line the tests start):
# a program one of them compiled, another loads instead of compiling it again. It starts
# empty, so a run's time is that of a fresh machine; it is removed at the end.
if "SLPS_TESTS_JAX_CACHE" not in os.environ:
    os.environ["SLPS_TESTS_JAX_CACHE"] = tempfile.mkdtemp(prefix="slps-tests-jax-cache-")
os.environ["JAX_COMPILATION_CACHE_DIR"] = os.environ["SLPS_TESTS_JAX_CACHE"]
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.1"

import jax  # noqa: E402
import pytest  # noqa: E402

# Accuracy work runs in float64; the library itself never flips this flag.
jax.config.update("jax_enable_x64", True)


@pytest.fixture
def paper():
    import slps_jax as sj

    return sj.RigidBody.paper(), jax.numpy.asarray(sj.PAPER_Y0)


# The suite's memory: JAX keeps every compiled program (and every traced step) of a process.
# Modules share many (the paper's system, the methods' traced steps), so they are kept across
# tests and modules, and dropped only once a worker holds this much: eager operations on many
# shapes (the Zeitlin tables at several N, say) each compile a program, and one module's
# programs alone once took a worker to 1.9 GB.
_RSS_LIMIT = 1500 * 2**20


@pytest.fixture(autouse=True)
def _bounded_memory():
    yield
    if _rss() > _RSS_LIMIT:
        _free()


def _rss():
    """This process's resident memory in bytes (0 where /proc is not there)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def _free():
    jax.clear_caches()
    gc.collect()
    try:  # give freed heap back to the system (glibc)
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def pytest_sessionfinish(session):
    if not hasattr(session.config, "workerinput"):  # the controller, after the workers
        shutil.rmtree(os.environ["SLPS_TESTS_JAX_CACHE"], ignore_errors=True)
