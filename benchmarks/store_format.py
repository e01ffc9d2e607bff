"""HDF5 (h5py) or Zarr (zarr-python, a local directory store) for long runs on disk: the
measurement behind `slps_jax.store`'s choice of Zarr.

Each format gets the same minimal writer and the same commit protocol: a record (8
snapshots of a complex128 256 x 256 state, their energies and enstrophy spectra, and the
loop's carry) is written, flushed, and then a commit marker says how many records are
complete (HDF5: a `committed` attribute on the file, flushed; Zarr: a small JSON file put in
place by `os.replace`). Two measurements:

- write speed: seconds per record (8.4 MB), without and with `fsync` of what was written;
- crash safety: a writer process appends records in a loop and is killed with SIGKILL after
  a random delay (uniform in 0 ... 0.6 s, so the kill lands mid-append most of the time);
  the store is then reopened: can it be opened, and is the last committed record intact, bit
  for bit? Repeated `--trials` times per format.

    python benchmarks/store_format.py              # about 1 minute
    python benchmarks/store_format.py --trials 100 # the numbers in benchmarks/README.md
"""

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

N, K = 256, 8  # state N x N, K snapshots per record


def record(i):
    """Record `i`'s data, a deterministic function of `i` (the reader recomputes it)."""
    rng = np.random.default_rng(i)
    state = rng.standard_normal((K, N, N)) + 1j * rng.standard_normal((K, N, N))
    return {
        "state": state,
        "energy": rng.standard_normal(K),
        "enstrophy_spectrum": rng.standard_normal((K, N)),
    }


def carry(i):
    rng = np.random.default_rng(10_000 + i)
    return {"state": rng.standard_normal((N, N)) + 0j, "key": rng.integers(0, 2**32, 2, np.uint32)}


# --- HDF5: resizable chunked datasets, data then flush then a `committed` attribute


class H5Writer:
    def __init__(self, path, fsync=False):
        import h5py

        self.f = h5py.File(path, "w")
        self.fsync = fsync
        for name, x in record(0).items():
            self.f.create_dataset(
                name,
                shape=(0, *x.shape[1:]),
                maxshape=(None, *x.shape[1:]),
                dtype=x.dtype,
                chunks=(1, *x.shape[1:]),
            )
        for name, x in carry(0).items():
            self.f.create_dataset("carry_" + name, data=np.zeros((2, *x.shape), x.dtype))
        self.f.attrs["committed"] = 0
        self.f.flush()
        self.n = 0

    def append(self, i):
        for name, x in record(i).items():
            d = self.f[name]
            d.resize(d.shape[0] + K, axis=0)
            d[-K:] = x
        for name, x in carry(i).items():  # (two slots: the committed one is never touched)
            self.f["carry_" + name][i % 2] = x
        self.f.flush()
        if self.fsync:
            os.fsync(self.f.id.get_vfd_handle())
        self.n += 1
        self.f.attrs["committed"] = self.n
        self.f.flush()
        if self.fsync:
            os.fsync(self.f.id.get_vfd_handle())


def h5_check(path):
    import h5py

    with h5py.File(path, "r") as f:
        n = int(f.attrs["committed"])
        if n == 0:
            return n, True
        ok = all(np.array_equal(f[k][(n - 1) * K : n * K], v) for k, v in record(n - 1).items())
        ok &= all(np.array_equal(f["carry_" + k][(n - 1) % 2], v) for k, v in carry(n - 1).items())
        return n, ok


# --- Zarr: one array per field (zarr writes every chunk and metadata file atomically:
# a temporary file, then a rename), data then a commit JSON by os.replace


class ZarrWriter:
    def __init__(self, path, fsync=False):
        import zarr

        self.path, self.fsync = path, fsync
        self.g = zarr.open_group(path, mode="w")
        self.arrays = {}
        for name, x in record(0).items():
            self.arrays[name] = self.g.create_array(
                name,
                shape=(0, *x.shape[1:]),
                chunks=(1, *x.shape[1:]),
                dtype=x.dtype,
                compressors=None,
            )
        for name, x in carry(0).items():
            self.arrays["carry_" + name] = self.g.create_array(
                "carry_" + name,
                shape=(2, *x.shape),
                chunks=(1, *x.shape),
                dtype=x.dtype,
                compressors=None,
            )
        self.n = 0
        self.commit()

    def commit(self):
        tmp = os.path.join(self.path, "commit.json.tmp")
        with open(tmp, "w") as f:
            json.dump({"committed": self.n}, f)
            if self.fsync:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, os.path.join(self.path, "commit.json"))

    def append(self, i):
        for name, x in record(i).items():
            a = self.arrays[name]
            a.resize((a.shape[0] + K, *a.shape[1:]))
            a[-K:] = x
        for name, x in carry(i).items():
            self.arrays["carry_" + name][i % 2] = x
        if self.fsync:  # the chunks and metadata just written (chunk keys "c/<row>/0/...")
            for name, a in self.arrays.items():
                rows = [i % 2] if name.startswith("carry_") else range(a.shape[0] - K, a.shape[0])
                tail = "/0" * (a.ndim - 1)
                for p in [f"{name}/zarr.json", *(f"{name}/c/{r}{tail}" for r in rows)]:
                    fd = os.open(os.path.join(self.path, p), os.O_RDONLY)
                    os.fsync(fd)
                    os.close(fd)
        self.n += 1
        self.commit()


def zarr_check(path):
    import zarr

    with open(os.path.join(path, "commit.json")) as f:
        n = json.load(f)["committed"]
    g = zarr.open_group(path, mode="r")
    if n == 0:
        return n, True
    ok = all(np.array_equal(g[k][(n - 1) * K : n * K], v) for k, v in record(n - 1).items())
    ok &= all(np.array_equal(g["carry_" + k][(n - 1) % 2], v) for k, v in carry(n - 1).items())
    return n, ok


WRITERS = {"hdf5": (H5Writer, h5_check, "run.h5"), "zarr": (ZarrWriter, zarr_check, "run.zarr")}


def writer_main(fmt, path):
    """The process that gets killed: append records until killed."""
    w = WRITERS[fmt][0](path)
    print("ready", flush=True)
    i = 0
    while True:
        w.append(i)
        i += 1


def speed(fmt, n_records, fsync, tmp):
    cls, _, name = WRITERS[fmt]
    path = os.path.join(tmp, f"speed-{fsync}-{name}")
    w = cls(path, fsync=fsync)
    w.append(0)  # (first-record costs: imports, allocation)
    times = []
    for i in range(1, n_records + 1):
        t0 = time.perf_counter()
        w.append(i)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def crash(fmt, trials, tmp, seed):
    _, check, name = WRITERS[fmt]
    rnd = random.Random(seed)
    unopenable, bad, records = 0, 0, []
    for t in range(trials):
        path = os.path.join(tmp, f"crash{t}-{name}")
        p = subprocess.Popen(
            [sys.executable, __file__, "--writer", fmt, path],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert p.stdout is not None and p.stdout.readline().strip() == "ready"
        time.sleep(rnd.uniform(0.0, 0.6))
        p.send_signal(signal.SIGKILL)
        p.wait()
        # the check runs in a fresh process: nothing of a library's state carries over
        out = subprocess.run(
            [sys.executable, __file__, "--check", fmt, path], capture_output=True, text=True
        )
        if out.returncode:
            unopenable += 1
        else:
            n, ok = json.loads(out.stdout)
            records.append(n)
            bad += not ok
        shutil.rmtree(path, ignore_errors=True) if os.path.isdir(path) else os.remove(path)
    return unopenable, bad, records


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", type=int, default=20, help="records timed per variant")
    ap.add_argument("--trials", type=int, default=20, help="SIGKILLs per format")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--formats", nargs="+", default=list(WRITERS), choices=list(WRITERS))
    ap.add_argument("--writer", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--check", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.writer:
        return writer_main(*args.writer)
    if args.check:
        n, ok = WRITERS[args.check[0]][1](args.check[1])
        print(json.dumps([n, bool(ok)]))
        return
    import h5py
    import zarr

    mb = sum(x.nbytes for x in record(0).values()) / 1e6
    print(f"h5py {h5py.__version__} (HDF5 {h5py.version.hdf5_version}), zarr {zarr.__version__}")
    print(f"record: {K} snapshots of complex128 {N}x{N} + diagnostics, {mb:.1f} MB\n")
    print(
        f"{'format':8}{'s/record':>10}{'MB/s':>8}{'s/rec fsync':>13}{'MB/s':>8}"
        f"{'killed':>8}{'unopenable':>12}{'last bad':>10}{'records (median)':>18}"
    )
    with tempfile.TemporaryDirectory(dir=os.environ.get("STORE_BENCH_DIR")) as tmp:
        for fmt in args.formats:
            s0 = speed(fmt, args.records, False, tmp)
            s1 = speed(fmt, args.records, True, tmp)
            unopenable, bad, recs = crash(fmt, args.trials, tmp, args.seed)
            med = int(np.median(recs)) if recs else -1
            print(
                f"{fmt:8}{s0:10.4f}{mb / s0:8.0f}{s1:13.4f}{mb / s1:8.0f}"
                f"{args.trials:8d}{unopenable:12d}{bad:10d}{med:18d}"
            )


if __name__ == "__main__":
    main()
