import jax
import pytest

# Accuracy work runs in float64; the library itself never flips this flag.
jax.config.update("jax_enable_x64", True)


@pytest.fixture
def paper():
    import slps_jax as sj

    return sj.RigidBody.paper(), jax.numpy.asarray(sj.PAPER_Y0)
