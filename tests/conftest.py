import jax
import pytest

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
