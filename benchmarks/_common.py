"""The benchmark scripts' harness: arguments (`parser`), timing (`compile_timed`, `time_call`,
`Stopwatch`), the machine (`machine_info`), and the output folder (`Output`: its JSON, CSV and
Markdown files, each saying where and when it was measured). A script holds only what it
measures.

Timing follows diffrax's benchmarks: compile once (timed on its own, ahead of time with
`jax.jit(f).lower(*args).compile()`), run once to warm up, then time repeated calls that end
in `jax.block_until_ready`, and report the median and the minimum.
"""

from __future__ import annotations

import csv
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import time

DEFAULT_OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")

# A script's `--fast` run is a smoke run (the test suite's): its timings take `repeats` calls
# and no more, whatever `min_total` asks.
SMOKE = "--fast" in sys.argv[1:]


def parser(doc, fast, out=DEFAULT_OUT):
    """The arguments every script takes: `--fast` (a smoke run, the test suite's; `fast` says
    what it runs) and `--out` (the output folder, default `out`); a script adds its own."""
    import argparse

    p = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    p.add_argument("--fast", action="store_true", help=fast)
    p.add_argument("--out", default=out, help="output folder")
    return p


def machine_info():
    """CPU model, core count, versions and date: what the README's tables were measured on."""
    import jax

    model = platform.processor() or platform.machine()
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        for line in out.splitlines():
            if line.strip().startswith("Model name:"):
                model = line.split(":", 1)[1].strip()
                break
    except (OSError, subprocess.SubprocessError):
        pass
    info = {
        "cpu_model": model,
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "x64": bool(jax.config.jax_enable_x64),
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
    }
    try:
        import diffrax

        info["diffrax"] = diffrax.__version__
    except ImportError:
        info["diffrax"] = None
    return info


def device_name(info):
    """What the results were measured on: the CPU model (`machine_info`), or the accelerator's
    kind."""
    import jax

    return info["cpu_model"] if jax.default_backend() == "cpu" else jax.devices()[0].device_kind


def compile_timed(fn, *args):
    """`jax.jit(fn)` compiled ahead of time for `args`: (compiled, seconds to lower+compile)."""
    import jax

    start = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    return compiled, time.perf_counter() - start


def time_call(fn, *args, repeats=3, min_total=0.5, max_repeats=30, warmup=True):
    """Median and minimum wall time of `fn(*args)` (blocking), after one warm-up call
    (`warmup=False`: the caller has already made it).

    At least `repeats` timed calls; fast calls are repeated until `min_total` seconds have
    been spent (at most `max_repeats` calls), so the median of a millisecond run is not one
    scheduler hiccup on a shared machine; in a `--fast` run (`SMOKE`), `repeats` calls.

    **Returns:** `(median_s, min_s, n_repeats, last_output)`.
    """
    import jax

    out = jax.block_until_ready(fn(*args)) if warmup else None
    min_total = 0.0 if SMOKE else min_total
    times = []
    while len(times) < repeats or (sum(times) < min_total and len(times) < max_repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return statistics.median(times), min(times), len(times), out


def write_csv(path, rows):
    """Rows (dicts with the same keys) to CSV."""
    if not rows:
        return
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def write_json(path, obj):
    with open(path, "w") as fh:
        json.dump(obj, fh, indent=2, default=_jsonable)
        fh.write("\n")


def _jsonable(x):
    try:
        return float(x)
    except (TypeError, ValueError):
        return str(x)


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def markdown_table(rows, columns, formats=None):
    """A Markdown table of `rows` (dicts); `formats` maps a column to a format spec."""
    formats = formats or {}
    head = "| " + " | ".join(columns) + " |\n|" + "---|" * len(columns) + "\n"
    body = ""
    for row in rows:
        cells = []
        for col in columns:
            val = row[col]
            fmt = formats.get(col)
            cells.append(format(val, fmt) if fmt and val is not None and val == val else str(val))
        body += "| " + " | ".join(cells) + " |\n"
    return head + body


class Stopwatch:
    """Wall time of a block: `with Stopwatch() as sw: ...` then `sw.seconds` (the caller
    blocks on what it times, `jax.block_until_ready`)."""

    def __enter__(self):
        self.start = time.perf_counter()
        self.seconds = None
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.start
        return False


class Output:
    """A script's results: its folder (`--out`, made here), the machine they are measured on
    (`machine_info`, taken once: `info`, `device`), and its files, named by `name` without the
    suffix. Every JSON file holds the machine (`machine`); every Markdown file starts with
    where and when (`measured_on`)."""

    def __init__(self, folder):
        os.makedirs(folder, exist_ok=True)
        self.folder = folder
        self.info = machine_info()

    @property
    def device(self):
        return device_name(self.info)

    def measured_on(self):
        """Where and when: `Measured on <device> (<n> cores), jax <version>, <date>` (no full
        stop)."""
        i = self.info
        return (
            f"Measured on {self.device} ({i['cpu_count']} cores), jax {i['jax']}, {i['date'][:10]}"
        )

    def path(self, filename):
        return os.path.join(self.folder, filename)

    def json(self, name, obj):
        """`name.json`: the dict `obj`, with the machine under `machine` unless it has one."""
        write_json(self.path(f"{name}.json"), {"machine": self.info, **obj})

    def csv(self, name, rows):
        write_csv(self.path(f"{name}.csv"), rows)

    def markdown(self, name, text, note="."):
        """`name.md`: `measured_on()` and `note` (its end: "." or "; size ...."), a blank line,
        then `text`."""
        with open(self.path(f"{name}.md"), "w") as fh:
            fh.write(f"{self.measured_on()}{note}\n\n{text}")
