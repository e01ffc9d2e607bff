"""Every notebook in notebooks/ runs top to bottom at the small size (SLPS_NOTEBOOK_SIZE=small),
and, in the second tier of full-size checks (`-m full`, which `.ci/run` runs after the
README's command), at its full size.

The kernel is this interpreter's (`python3` from the environment running pytest), with this
checkout first on PYTHONPATH, so the notebooks import the slps_jax under test even where an
editable install of another checkout is on the path. A cell that raises fails the test
(nbclient raises CellExecutionError, which names the cell).
"""

import os
import pathlib

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

ROOT = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks():
    assert [p.name for p in NOTEBOOKS] == [
        "01_paper.ipynb",
        "02_accuracy_and_speed.ipynb",
        "03_gradients_and_calibration.ipynb",
        "04_several_noises.ipynb",
        "05_so_n.ipynb",
        "06_euler_sphere.ipynb",
        "07_data_driven_noise.ipynb",
        "08_assimilation.ipynb",
        "09_forced_turbulence.ipynb",
    ]


def test_notebooks_are_committed_without_outputs():
    for path in NOTEBOOKS:
        nb = nbformat.read(path, as_version=4)
        for cell in nb.cells:
            if cell.cell_type == "code":
                assert not cell.outputs and cell.execution_count is None, (
                    f"{path.name}: clear the outputs before committing "
                    "(jupyter nbconvert --clear-output --inplace notebooks/*.ipynb)"
                )


# Each notebook starts from a fresh namespace, and without the previous one's compiled
# programs (they would add up in the kernel's memory: 2.1 GB after the six).
FRESH = """%reset -f
import ctypes as _ctypes, gc as _gc, jax as _jax
_jax.clear_caches()
_gc.collect()
_ctypes.CDLL("libc.so.6").malloc_trim(0)
%reset -f
"""


def _kernel(size):
    """One kernel for all the notebooks of a size: started once (its imports and JAX's
    start-up are then paid once), each notebook run in a fresh namespace without the previous
    one's compiled programs (`FRESH` first). It inherits this process's environment, set
    here; the inline backend draws every figure, so a bad label (mathtext) fails too. Kernel
    "python3": jupyter_client starts it with sys.executable, this environment's python."""
    jupyter_client = pytest.importorskip("jupyter_client")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SLPS_NOTEBOOK_SIZE", size)
        mp.delenv("MPLBACKEND", raising=False)
        mp.setenv(
            "PYTHONPATH",
            os.pathsep.join(
                [str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
            ),
        )
        # (the kernel shares the run's persistent compilation cache: tests/conftest.py)
        km = jupyter_client.KernelManager(kernel_name="python3")
        km.start_kernel(cwd=str(ROOT / "notebooks"))
    try:
        yield km
    finally:
        km.shutdown_kernel(now=True)


@pytest.fixture(scope="module")
def kernel():
    yield from _kernel("small")


@pytest.fixture(scope="module")
def full_kernel():
    yield from _kernel("full")


def _run(path, km):
    nb = nbformat.read(path, as_version=4)
    nb.cells.insert(0, nbformat.v4.new_code_cell(FRESH))
    client = nbclient.NotebookClient(nb, km=km, timeout=1200, kernel_name="python3")
    client.execute()


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, kernel):
    _run(path, kernel)


@pytest.mark.full
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs_at_full_size(path, full_kernel):
    _run(path, full_kernel)
