"""Command line: `slps-jax paper [--out DIR] [--fast]` and `slps-jax summary [--fast]` (the
help text a user sees is `DESCRIPTION`).

`paper` reproduces Figures 4.1-4.4 of Liu & Wang with their parameters (see `_cli/paper.py`).
`summary` runs the paper's setup (Liu & Wang, Section 4.4) end to end and prints: the strong
(RMS) error at T = 1 against the exact solution for h = 2^-5 ... 2^-9 with fitted orders, the
drift of the Casimir and the Hamiltonian over 10^4 steps, and Newton statistics of scheme (42).
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def summary(n_samples=500, fast=False, seed=0):
    import functools

    import jax
    import jax.numpy as jnp
    import numpy as np

    import slps_jax as sj

    say = functools.partial(print, flush=True)  # each line as it is produced (logs, pipes)
    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    key = jax.random.key(seed)
    levels = range(5, 8) if fast else range(5, 10)
    dts = [2.0**-k for k in levels]
    from ._cli.paper import paper_methods

    methods = paper_methods()
    say(
        f"slps-jax {sj.__version__}, jax {jax.__version__} on {jax.default_backend()}, "
        f"dtype {y0.dtype}"
    )
    say(
        f"Stochastic rigid body: I = {np.round(np.asarray(system.inertia), 6)}, "
        f"c = {float(np.asarray(system.c))}, y0 = {sj.PAPER_Y0}\n"
    )

    say(
        f"Strong errors: {len(methods)} methods x {len(dts)} step sizes, {n_samples} samples "
        f"(compiling and running) ..."
    )
    start = time.perf_counter()
    conv = sj.strong_convergence(
        system, y0, t1=1.0, dts=dts, n_samples=n_samples, key=key, methods=methods
    )
    say(
        f"Strong error at T = 1 against the exact solution phi_(T + cW(T))(y0), "
        f"{n_samples} samples ({time.perf_counter() - start:.1f} s):\n"
    )
    say(conv.table())

    n_steps, dt = (1000, 0.01) if fast else (10_000, 0.01)
    n_inv = 20 if fast else 100
    say(
        f"Invariants after {n_steps} steps of h = {dt} (T = {n_steps * dt:g}), "
        f"{n_inv} samples, max over samples:\n"
    )
    say("| method | rel. Casimir drift | rel. energy drift | seconds |\n|---|---|---|---|")
    c0, h0 = float(system.casimir(y0)), float(system.hamiltonian(y0))
    for name, method in methods.items():
        start = time.perf_counter()
        sol = sj.simulate(
            system, y0, t1=n_steps * dt, dt=dt, n_samples=n_inv, key=key, method=method
        )
        y_end = sol.ys[:, -1]
        dc = float(jnp.max(jnp.abs(system.casimir(y_end) / c0 - 1)))
        dh = float(jnp.max(jnp.abs(system.hamiltonian(y_end) / h0 - 1)))
        say(f"| {name} | {dc:.2e} | {dh:.2e} | {time.perf_counter() - start:.1f} |")

    say(f"\nNewton solves of scheme (42), T = 1, {n_samples} samples:\n")
    say(
        "| h | mean iterations | max iterations | max residual | failed samples |\n"
        "|---|---|---|---|---|"
    )
    for dt in dts:
        sol = sj.simulate(
            system,
            y0,
            t1=1.0,
            dt=dt,
            n_samples=n_samples,
            key=key,
            method=sj.LiePoisson(),
            newton_stats=True,
        )
        s = sol.stats
        say(
            f"| 2^{np.log2(dt):.0f} | {float(s['newton_iterations_mean']):.2f} | "
            f"{int(s['newton_iterations_max'])} | {float(s['residual_max']):.1e} | "
            f"{int(s['n_failed'])} |"
        )
    return conv


def cache_dir():
    """Where the command line keeps JAX's persistent compilation cache: `$JAX_COMPILATION_CACHE_DIR`
    if set, else `slps-jax/jax-compilation-cache` in the user's cache folder
    (`$XDG_CACHE_HOME`, default `~/.cache`)."""
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return os.environ["JAX_COMPILATION_CACHE_DIR"]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "slps-jax", "jax-compilation-cache")


def use_compilation_cache(jax):
    """Keep every compiled program in the persistent cache (`cache_dir`): a second run of a
    command skips compilation, nearly all of a run's time. The library itself never does this;
    the command line is an application. A cache folder that cannot be made or written to (a
    read-only home on a cluster) costs only the cache: one warning line, and the run goes on
    without it. **Returns** the folder, or `None`."""
    path = cache_dir()
    problem = _unwritable(path)
    if problem:
        print(
            f"slps-jax: warning: no compilation cache ({path}: {problem}); set "
            f"JAX_COMPILATION_CACHE_DIR to a writable folder, or pass --no-cache.",
            file=sys.stderr,
        )
        jax.config.update("jax_enable_compilation_cache", False)  # (JAX reads the variable too)
        return None
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


DESCRIPTION = """\
slps-jax: structure-preserving integrators for stochastic Lie-Poisson systems.

  slps-jax paper     reproduce Figures 4.1-4.4 of Liu & Wang (the stochastic rigid body,
                     scheme (42)) with the paper's parameters: PNGs, results.json and
                     results.md in the output folder, the results table printed
  slps-jax summary   another study of the paper's setup, printed without figures (not a
                     shorter paper: about 1.5x its time): strong orders against the exact
                     solution, invariant drift over 10^4 steps, Newton statistics

Everything runs in float64. Compiled programs are kept in JAX's persistent compilation
cache: $JAX_COMPILATION_CACHE_DIR if set, else slps-jax/ in the user's cache folder
($XDG_CACHE_HOME, default ~/.cache), so a second run skips compilation; --no-cache turns
it off (a cache folder that cannot be written to costs a warning and the cache, not the
run). Add --help after a command for its options."""


def _unwritable(folder):
    """Why `folder` cannot be made or written to, or `None` (it exists afterwards). Written
    to, not only asked: permission bits do not tell (root is allowed everything, and a
    read-only mount or /sys refuses writes all the same)."""
    import tempfile

    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as err:
        return f"cannot create the folder ({err.strerror or err})"
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        return f"cannot write into the folder ({err.strerror or err})"
    return None


def _samples(text):
    """`--samples`: an integer of at least 2 (the spread of an estimate needs two)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if n < 2:
        raise argparse.ArgumentTypeError(f"must be at least 2, got {n}")
    return n


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="slps-jax",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="{paper,summary}")
    p_paper = sub.add_parser(
        "paper",
        help="reproduce the paper's Figures 4.1-4.4",
        description="Reproduce Figures 4.1-4.4 of Liu & Wang with the paper's parameters.",
    )
    p_paper.add_argument(
        "--out",
        default=None,
        help="output folder (default: paper-output, or paper-output-fast "
        "with --fast, so a quick look never overwrites a full run)",
    )
    p_sum = sub.add_parser(
        "summary",
        help="the paper's setup: orders, invariants, Newton statistics",
        description="The paper's setup end to end, printed as Markdown tables.",
    )
    p_sum.add_argument(
        "--samples",
        type=_samples,
        default=None,
        help="Brownian samples (default: 500, or 100 with --fast)",
    )
    for p in (p_paper, p_sum):
        p.add_argument(
            "--fast", action="store_true", help="a small, quick run (100 samples, fewer step sizes)"
        )
        p.add_argument(
            "--seed",
            type=int,
            default=0,
            help="seed of the Brownian samples, jax.random.key(SEED) (default 0)",
        )
        p.add_argument(
            "--no-cache",
            action="store_true",
            help="compile everything anew: no persistent compilation cache",
        )
    args = parser.parse_args(argv)
    out = None
    if args.command == "paper":
        out = (
            args.out
            if args.out is not None
            else ("paper-output-fast" if args.fast else "paper-output")
        )
        problem = _unwritable(out)  # before any work: one line, as for a bad option
        if problem:
            print(f"slps-jax paper: error: --out {out}: {problem}", file=sys.stderr)
            return 2

    import jax

    jax.config.update("jax_enable_x64", True)  # accuracy work runs in float64
    if not args.no_cache:
        use_compilation_cache(jax)
    if args.command == "paper":
        from ._cli.paper import run

        assert out is not None
        run(out_dir=out, fast=args.fast, seed=args.seed)
        return 0
    n = args.samples if args.samples is not None else (100 if args.fast else 500)
    summary(n_samples=n, fast=args.fast, seed=args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
