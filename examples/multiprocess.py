"""An ensemble over several processes, on JAX's own multi-process runtime.

Every process runs this same script. `jax.distributed.initialize` connects them; the mesh,
built by `jax.make_mesh` (explicit axes, as JAX recommends; `--axis-types auto` for
automatic ones), spans the devices of all processes; `simulate` and `ensemble_statistics`
split the samples over them, each process drawing and integrating only its own devices'
samples.

Two processes on one machine, by hand (each with two CPU devices here):

    python examples/multiprocess.py --coordinator localhost:12345 --num-processes 2 \
        --process-id 0 --cpu-devices 2 &
    python examples/multiprocess.py --coordinator localhost:12345 --num-processes 2 \
        --process-id 1 --cpu-devices 2

Under SLURM, one process per node or per GPU (`jax.distributed.initialize()` reads the
coordinator, the number of processes and each one's id from the job's environment):

    srun --nodes=2 --ntasks-per-node=1 python examples/multiprocess.py

What each process gets back:

- `simulate`: a `Solution` whose arrays are global `jax.Array`s sharded along the samples;
  a process holds its own samples (`sol.ys.addressable_shards`), and
  `multihost_utils.process_allgather(sol.ys, tiled=True)` gathers all of them (every process
  must call it). Its `stats` are the same on every process.
- `ensemble_statistics`: the moments over all processes' samples, the same on every process.
"""

import argparse
import os
import pathlib


def run(sharding=None):
    """The example's two runs: paths of an ensemble, and streamed moments of a larger one.
    `sharding=None` is the one-process run the results must equal sample for sample."""
    import jax
    import jax.numpy as jnp

    import slps_jax as sj

    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    sol = sj.simulate(
        system,
        y0,
        t1=0.5,
        dt=2.0**-6,
        n_samples=16,
        key=jax.random.key(1),
        save_every=8,
        sharding=sharding,
    )
    stats = sj.ensemble_statistics(
        system,
        y0,
        t1=0.5,
        dt=2.0**-6,
        n_samples=200,
        key=jax.random.key(2),
        chunks=sj.Chunks(64, sharding=sharding, progress=False),
        statistics=sj.Statistics(("mean", "var")),
    )
    return sol, stats


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--coordinator", help="host:port of process 0 (SLURM: omit)")
    parser.add_argument("--num-processes", type=int)
    parser.add_argument("--process-id", type=int)
    parser.add_argument(
        "--cpu-devices", type=int, help="CPU devices per process (to try it out on one machine)"
    )
    parser.add_argument("--out", type=pathlib.Path, help="write process-<id>-<axis type>.npz here")
    parser.add_argument(
        "--axis-types",
        nargs="+",
        choices=("explicit", "auto"),
        default=["explicit"],
        help="the mesh's axis type, each in turn (default: explicit, what jax.make_mesh gives)",
    )
    args = parser.parse_args()
    if args.cpu_devices:
        os.environ["XLA_FLAGS"] = (
            os.environ.get("XLA_FLAGS", "")
            + f" --xla_force_host_platform_device_count={args.cpu_devices}"
        )

    import jax
    import numpy as np
    from jax.experimental import multihost_utils
    from jax.sharding import AxisType, NamedSharding, PartitionSpec

    jax.config.update("jax_enable_x64", True)
    jax.distributed.initialize(
        coordinator_address=args.coordinator,
        num_processes=args.num_processes,
        process_id=args.process_id,
    )
    me = jax.process_index()
    for kind in args.axis_types:
        axis_type = AxisType.Explicit if kind == "explicit" else AxisType.Auto
        mesh = jax.make_mesh((jax.device_count(),), ("samples",), axis_types=(axis_type,))
        sol, stats = run(NamedSharding(mesh, PartitionSpec("samples")))

        mine = sorted(s.index[0].start for s in sol.ys.addressable_shards)
        ys = multihost_utils.process_allgather(sol.ys, tiled=True)
        print(
            f"process {me} of {jax.process_count()}: {len(jax.local_devices())} of "
            f"{len(jax.devices())} devices, {kind} mesh axes, samples from {mine} in "
            f"{sol.ys.shape[0]}; {stats.n} samples' mean final state {stats.mean[-1]}",
            flush=True,
        )
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            np.savez(
                args.out / f"process-{me}-{kind}.npz",
                ys=ys,
                fail_step=multihost_utils.process_allgather(sol.fail_step, tiled=True),
                n_failed=int(sol.stats["n_failed"]),
                n=stats.n,
                mean=stats.mean,
                var=stats.var,
                n_local=sum(s.data.shape[0] for s in sol.ys.addressable_shards),
            )
    jax.distributed.shutdown()


if __name__ == "__main__":
    main()
