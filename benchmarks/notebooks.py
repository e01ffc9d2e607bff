"""Each notebook's run time at full size: a fresh kernel per notebook, no compilation cache,
cell by cell with nbclient; its total and its slowest cell.

    python benchmarks/notebooks.py                 # all of notebooks/, full size
    python benchmarks/notebooks.py --fast          # 01_paper at the small size

Writes `notebooks.json` and `notebooks.md` into `--out`.
"""

import os
import pathlib
import time

import _common

ROOT = pathlib.Path(__file__).resolve().parents[1]


def run(path, size):
    """`(total_s, slowest_s, slowest_cell_index)` of one notebook in a fresh kernel (this
    environment's python, this checkout first on its path)."""
    import jupyter_client
    import nbclient
    import nbformat

    nb = nbformat.read(path, as_version=4)
    env = dict(os.environ, SLPS_NOTEBOOK_SIZE=size, JAX_ENABLE_COMPILATION_CACHE="false")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.pop("MPLBACKEND", None)
    km = jupyter_client.KernelManager(kernel_name="python3")
    km.start_kernel(cwd=str(path.parent), env=env)
    try:
        client = nbclient.NotebookClient(nb, km=km, timeout=1800, kernel_name="python3")
        times = []
        start = time.perf_counter()
        with client.setup_kernel():
            for index, cell in enumerate(nb.cells):
                t0 = time.perf_counter()
                client.execute_cell(cell, index)
                times.append((time.perf_counter() - t0, index))
        total = time.perf_counter() - start
    finally:
        km.shutdown_kernel(now=True)
    slowest, at = max(times)
    return total, slowest, at


def main(argv=None):
    p = _common.parser(__doc__, "01_paper at the small size")
    args = p.parse_args(argv)
    results = _common.Output(args.out)
    paths = sorted((ROOT / "notebooks").glob("*.ipynb"))
    paths, size = (paths[:1], "small") if args.fast else (paths, "full")
    rows = []
    for path in paths:
        total, slowest, at = run(path, size)
        rows.append(
            dict(
                notebook=path.stem,
                size=size,
                total_s=total,
                slowest_cell_s=slowest,
                slowest_cell=at,
            )
        )
        print(f"{path.stem}: {total:.0f} s, slowest cell {at}: {slowest:.0f} s", flush=True)
        results.json("notebooks", dict(rows=rows))
        cols = ["notebook", "total_s", "slowest_cell_s", "slowest_cell"]
        results.markdown(
            "notebooks",
            _common.markdown_table(rows, cols, {"total_s": ".0f", "slowest_cell_s": ".0f"}),
            f"; {size} size, a fresh kernel each, no cache.",
        )


if __name__ == "__main__":
    main()
