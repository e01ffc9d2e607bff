"""The benchmark scripts run (`--fast`, into a tmp dir) and write sane files.

Correctness only: no timing is asserted. The diffrax parts of `work_precision.py` are
checked only where diffrax (the `bench` extra) is installed; without it the script skips
them and our own methods are still checked.
"""

import contextlib
import csv
import importlib.util
import io
import json
import math
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"
HAVE_DIFFRAX = importlib.util.find_spec("diffrax") is not None
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run_script(name, out, *extra):
    """`python benchmarks/NAME --fast --out OUT *extra`, run as the script's `main` in this
    process, which already has JAX imported and many of the programs compiled (a subprocess
    per script paid both again); **returns** what it printed. The scripts import the
    slps_jax this process tests, and the processes they start themselves this checkout's
    (PYTHONPATH)."""
    saved_path, saved_pythonpath = list(sys.path), os.environ.get("PYTHONPATH")
    sys.path.insert(0, str(BENCH))  # the scripts import _common and one another
    os.environ["PYTHONPATH"] = os.pathsep.join(
        [str(ROOT)] + [p for p in (saved_pythonpath or "").split(os.pathsep) if p]
    )
    try:
        spec = importlib.util.spec_from_file_location(f"benchmark_{Path(name).stem}", BENCH / name)
        script = importlib.util.module_from_spec(spec)
        # Registered while it runs, as an imported module is: dataclasses (equinox's
        # modules, diffrax's paths) look their module up there to resolve annotations.
        sys.modules[spec.name] = script
        spec.loader.exec_module(script)
        import _common

        _common.SMOKE = True  # (set from the command line's --fast in a script's own process)
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            status = script.main(["--fast", "--out", str(out), *extra])
        # (a script's main returns its exit status, or its results)
        assert not isinstance(status, int) or status == 0, f"{name} exited with {status}"
        return printed.getvalue()
    finally:
        sys.modules.pop(f"benchmark_{Path(name).stem}", None)
        sys.path[:] = saved_path
        if saved_pythonpath is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = saved_pythonpath


def test_the_harness_writes_each_file_with_its_machine(tmp_path):
    """`_common.Output`: the folder is made; a JSON file holds the machine beside the fields
    given (one given keeps its own); a Markdown file starts with where and when, the note
    ending its sentence; CSV rows come back as written."""
    sys.path.insert(0, str(BENCH))
    try:
        import _common
    finally:
        sys.path.remove(str(BENCH))
    results = _common.Output(str(tmp_path / "new"))
    results.json("a", {"rows": [1, 2]})
    results.json("b", {"machine": "given"})
    results.csv("a", [{"x": 1, "y": "z"}])
    results.markdown("a", "| x |\n", "; size 3.")
    a = json.loads((tmp_path / "new" / "a.json").read_text())
    assert a["rows"] == [1, 2] and a["machine"]["jax"] and a["machine"]["cpu_count"] >= 1
    assert json.loads((tmp_path / "new" / "b.json").read_text())["machine"] == "given"
    assert read_csv(tmp_path / "new" / "a.csv") == [{"x": "1", "y": "z"}]
    md = (tmp_path / "new" / "a.md").read_text()
    head = f"Measured on {results.device} ({a['machine']['cpu_count']} cores), jax "
    assert md.startswith(head) and md.endswith("; size 3.\n\n| x |\n"), md
    with _common.Stopwatch() as sw:
        pass
    assert 0 <= sw.seconds < 1


def read_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def is_png(path):
    return path.exists() and path.stat().st_size > 1000 and path.read_bytes()[:8] == PNG_MAGIC


@pytest.fixture(scope="module")
def work_precision(tmp_path_factory):
    out = tmp_path_factory.mktemp("work_precision")
    stdout = run_script("work_precision.py", out)
    rows = read_csv(out / "work_precision.csv")
    for r in rows:
        for key in (
            "h",
            "rms_error",
            "rms_stderr",
            "time_median_s",
            "time_min_s",
            "compile_s",
            "max_rel_casimir_error",
        ):
            r[key] = float(r[key])
    return out, stdout, rows, json.loads((out / "work_precision.json").read_text())


def by_method(rows, name):
    pts = sorted((r for r in rows if r["method"] == name), key=lambda r: -r["h"])
    assert pts, f"no rows for {name}"
    return pts


def test_work_precision_our_methods(work_precision):
    out, stdout, rows, summary = work_precision
    assert is_png(out / "work_precision.png")
    assert (out / "per_step_cost.csv").exists()
    for r in rows:
        assert r["finite"] == "True"
        assert math.isfinite(r["rms_error"]) and r["rms_error"] >= 0
        assert 0 < r["time_min_s"] <= r["time_median_s"]
        assert r["compile_s"] > 0 and int(r["n_repeats"]) >= 3
    for name in ("LiePoisson", "Strang", "lax.scan Heun (shared dW)"):
        pts = by_method(rows, name)
        errors = [p["rms_error"] for p in pts]
        assert errors[0] < 0.1 and errors[-1] < errors[0], (name, errors)  # converges
        assert all(0 < p["rms_stderr"] < p["rms_error"] for p in pts)
    # the Lie-Poisson and splitting schemes keep |y| to round-off
    for name in ("LiePoisson", "Strang"):
        assert max(p["max_rel_casimir_error"] for p in by_method(rows, name)) < 1e-12
    cost = {r["method"]: r for r in summary["per_step_cost"]}
    assert "LiePoisson" in cost
    ratio = summary["per_step_ratio_LiePoisson_to_reference"]
    assert math.isfinite(ratio) and ratio > 0
    assert "time to reach RMS error" in stdout
    assert {t["method"] for t in summary["time_to_target"]} == {r["method"] for r in rows}


def test_work_precision_diffrax(work_precision):
    pytest.importorskip("diffrax")
    _, _, rows, summary = work_precision
    ours = by_method(rows, "lax.scan Heun (shared dW)")
    theirs = by_method(rows, "diffrax Heun (shared dW)")
    # diffrax Heun on the shared increments is the very same scheme as our lax.scan Heun
    for a, b in zip(ours, theirs):
        assert b["rms_error"] == pytest.approx(a["rms_error"], rel=1e-9)
    assert summary["max_abs_diff_diffrax_heun_vs_scan_heun"] < 1e-12
    assert summary["per_step_reference"] == "diffrax Heun (shared dW)"
    spark = by_method(rows, "diffrax SPaRK (VBT, space-time Levy area)")
    assert spark[0]["brownian"].startswith("VBT")
    assert spark[-1]["rms_error"] < spark[0]["rms_error"] < 0.01


@pytest.mark.skipif(HAVE_DIFFRAX, reason="diffrax is installed: the full run covers it")
def test_work_precision_skips_diffrax_cleanly(work_precision):
    _, stdout, rows, summary = work_precision
    assert "diffrax not available" in stdout
    assert not any(r["method"].startswith("diffrax") for r in rows)
    assert summary["max_abs_diff_diffrax_heun_vs_scan_heun"] is None


def test_scaling(tmp_path):
    stdout = run_script("scaling.py", tmp_path)
    assert is_png(tmp_path / "scaling.png")
    rows = read_csv(tmp_path / "scaling.csv")
    assert rows and all(r["finite"] == "True" for r in rows)
    assert all(0 < float(r["time_min_s"]) <= float(r["time_median_s"]) for r in rows)
    assert len({int(r["n_samples"]) for r in rows}) >= 2
    assert len({int(r["n_steps"]) for r in rows}) >= 2
    summary = json.loads((tmp_path / "scaling.json").read_text())
    mem = summary["memory"]
    assert {int(r["n_steps"]) for r in mem} >= {64, 1024}
    for method, verdict in summary["memory_flat"].items():
        # XLA's buffer sizes are deterministic: final-state-only runs may not grow
        assert verdict["xla_flat"] is True, (method, verdict)
    assert summary["control_growth_mb"] > 0.5  # ...while materialised increments do
    rss = [r for r in mem if r["rss_run_rise_mb"] is not None]
    assert rss and all(r["rss_run_rise_mb"] > 1 and r["ru_maxrss_mb"] > 50 for r in rss)
    assert "memory stayed flat as n_steps grew" in stdout


def test_paper_study(tmp_path):
    stdout = run_script("paper_study.py", tmp_path)
    assert is_png(tmp_path / "paper_study.png")
    summary = json.loads((tmp_path / "paper_study.json").read_text())
    case = summary["cases"]["LiePoisson"]
    assert case["wall_s_median"] > case["study_s_median"] > 0
    assert 0.5 < case["order"]["LiePoisson"] < 3.0
    rows = read_csv(tmp_path / "paper_study.csv")
    errors = [float(r["rms_error"]) for r in sorted(rows, key=lambda r: -float(r["h"]))]
    assert errors[-1] < errors[0] < 0.1
    assert "LiePoisson study within" in stdout


def test_long_time(tmp_path):
    stdout = run_script("long_time.py", tmp_path)
    assert is_png(tmp_path / "long_time.png")
    summary = json.loads((tmp_path / "long_time.json").read_text())
    methods = summary["methods"]
    expected = {"EulerMaruyama", "Midpoint", "Strang", "LiePoisson", "LiePoissonSym4"}
    if HAVE_DIFFRAX:
        expected.add("diffrax Heun")
    else:
        assert "diffrax not available" in stdout
    assert set(methods) == expected
    rows = read_csv(tmp_path / "long_time.csv")
    assert {r["method"] for r in rows} == expected
    t1 = summary["settings"]["t1"]
    assert max(float(r["t"]) for r in rows) == pytest.approx(t1)
    # Poisson maps that are rotations keep the Casimir to round-off; Midpoint to its tolerance
    for name in ("Strang", "LiePoisson", "LiePoissonSym4", "Midpoint"):
        assert methods[name]["n_failed"] == 0
        assert methods[name]["casimir"]["max_over_time_and_paths"] < 1e-11, name
    assert methods["Midpoint"]["energy"]["max_over_time_and_paths"] < 1e-11
    # Euler-Maruyama's |y| grows steadily (it adds f(y), orthogonal to y, each step)
    em = methods["EulerMaruyama"]["casimir"]
    assert em["verdict"] in ("drifts", "blows up") and em["final_median"] > 1e-2
    if HAVE_DIFFRAX:  # Heun: no invariant kept, a linear drift of both
        heun = methods["diffrax Heun"]
        assert heun["casimir"]["verdict"] == "drifts" and heun["casimir"]["slope"] > 0.75
    assert "wrote" in stdout


def test_throughput(tmp_path):
    stdout = run_script("throughput.py", tmp_path, "--methods", "LiePoisson,lax.scan Heun")
    rows = read_csv(tmp_path / "throughput.csv")
    assert {r["method"] for r in rows} == {"LiePoisson", "lax.scan Heun"}
    assert all(r["status"] == "ok" and r["finite"] == "True" for r in rows)
    assert all(float(r["sample_steps_per_s"]) > 0 for r in rows)
    summary = json.loads((tmp_path / "throughput.json").read_text())
    assert summary["machine"]["device"].startswith(summary["machine"]["backend"])
    assert "sample-steps/s" in stdout


def test_streaming(tmp_path):
    stdout = run_script("streaming.py", tmp_path)
    summary = json.loads((tmp_path / "streaming.json").read_text())
    rows = summary["rows"]
    assert [r["n_chunks"] for r in rows] == [1, 2, 10]
    assert all(r["n_samples"] == 1000 * r["n_chunks"] for r in rows)
    assert all(r["ru_maxrss_mb"] > 50 for r in rows)
    assert "peak RSS" in stdout


def test_newton_iterations(tmp_path):
    stdout = run_script("newton_iterations.py", tmp_path)
    assert is_png(tmp_path / "newton_iterations.png")
    summary = json.loads((tmp_path / "newton_iterations.json").read_text())
    usual = summary["usual_updates"]
    for entry in summary["per_h"]:
        # every step solved, to the tolerance; most in at most the usual number of updates
        assert entry["max_residual"] <= summary["tol"]
        assert entry["mean"] <= entry["max"]
        assert 0.5 < entry["fraction_at_most_usual"] <= 1
        assert entry["mean"] < usual + 1
    # more steps need no more than the usual updates as h shrinks
    fractions = [e["fraction_at_most_usual"] for e in summary["per_h"]]
    assert fractions == sorted(fractions)
    assert "usually 3 updates" in stdout


@pytest.mark.full
def test_newton_fusion(tmp_path):
    """The Newton loops with and without `one_kernel`: the same iterates, the same states to
    round-off (bit for bit for `unroll`, which only moves the loop's first bodies)."""
    run_script("newton_fusion.py", tmp_path)
    rows = {
        r["method"]: r for r in json.loads((tmp_path / "newton_fusion.json").read_text())["rows"]
    }
    assert set(rows) == {
        "Midpoint",
        "LiePoisson",
        "LiePoisson(unroll=3)",
        "Midpoint, no one_kernel",
        "LiePoisson, no one_kernel",
    }
    for name in ("Midpoint", "LiePoisson"):
        for stat in ("newton_iterations_mean", "newton_iterations_max"):
            assert rows[f"{name}, no one_kernel"][stat] == rows[name][stat]
        assert rows[f"{name}, no one_kernel"]["max_diff_to_kernel"] <= 1e-13
    assert rows["LiePoisson(unroll=3)"]["max_diff_to_kernel"] == 0.0
    assert all(r["fused_instructions"] > 0 and r["median_ms"] > 0 for r in rows.values())


def test_gradients(tmp_path):
    run_script("gradients.py", tmp_path)
    summary = json.loads((tmp_path / "gradients.json").read_text())
    for row in summary["timing"]:
        assert row["forward_s"] > 0 and row["reverse_s"] > 0 and row["jacfwd_s"] > 0
    mem = sorted(summary["memory"], key=lambda r: r["n_steps"])
    # XLA's buffer plan of the compiled reverse pass (--fast: Midpoint's): 16x the steps, far
    # less than 16x the temporary memory (sqrt(n) checkpoints: 4x at most), and a 1024-step
    # run differentiates at all.
    assert [r["n_steps"] for r in mem] == [64, 1024]
    growth = mem[-1]["temp_bytes"] / mem[0]["temp_bytes"]
    assert growth < 6, mem


def test_robust_default(tmp_path):
    # The paper's setup at h = 2^-4, 4000 samples of key 0: without the retry of failing
    # steps LiePoisson loses samples (24 at the time of writing); by default none.
    stdout = run_script("robust_default.py", tmp_path)
    rows = json.loads((tmp_path / "robust_default.json").read_text())["rows"]
    assert [r["dt"] for r in rows] == [2**-4]
    assert rows[0]["failed_no_retry"] > 10 and rows[0]["failed_default"] == 0
    assert "| 2^-4 |" in stdout


def test_chunk_size(tmp_path):
    stdout = run_script("chunk_size.py", tmp_path)
    rows = json.loads((tmp_path / "chunk_size.json").read_text())["rows"]
    assert [r["chunk_size"] for r in rows] == [500, 2000]
    assert all(r["us_per_sample_step"] > 0 for r in rows)
    assert "| 500 |" in stdout


def test_transport_fit(tmp_path):
    """`transport_fit.py --fast` (M = 12, N = 6): the fine run, the fit and the ensemble are
    timed."""
    run_script("transport_fit.py", tmp_path)
    rows = json.loads((tmp_path / "transport_fit.json").read_text())["rows"]
    assert [(r["M"], r["N"]) for r in rows] == [(12, 6)]
    for k in ("fine_ms_per_step", "fit_s", "ensemble_ms_per_member_step"):
        assert rows[0][k] > 0, k


def test_transport_skill(tmp_path):
    """`transport_skill.py --fast` (M = 12, N = 6, one seed): the study's table is written,
    with tuned factors, CIs that contain their estimates, and the Casimirs kept."""
    run_script("transport_skill.py", tmp_path)
    rows = json.loads((tmp_path / "transport_skill.json").read_text())["rows"]
    assert [r["seed"] for r in rows] == [0]
    r = rows[0]
    for k in ("calibrated_vs_deterministic", "calibrated_vs_isotropic"):
        assert r[k][1] <= r[k][0] <= r[k][2], (k, r[k])
    assert r["factor_calibrated"] > 0 and r["casimir_drift"] < 1e-12
    assert "| 0 |" in (tmp_path / "transport_skill.md").read_text()


@pytest.mark.full  # (about 30 s of a twin, a closure and three filters: second tier)
def test_filters(tmp_path):
    """`filters.py --fast` (su(20) -> su(5), 8 members, 4 observations): every filter's
    scores at every observation, paired CIs that contain their estimates, the thinned ranks
    in range, and the Kalman moves' Casimirs on the conservative model."""
    run_script("filters.py", tmp_path)
    out = json.loads((tmp_path / "filters.json").read_text())
    (r,) = out["rows"]
    assert (r["M"], r["N"], r["members"], r["observations"]) == (20, 5, 8, 4)
    kalman = ("orbit Kalman", "orbit Kalman, localised 1.5")
    assert set(r["scores"]) == {"free", "particle filter", *kalman}
    for s in r["scores"].values():
        assert len(s["sq_error_unobserved"]) == len(s["variance_observed"]) == 4
        assert all(0 <= t[2] <= 8 for t in s["thinned_ranks"])
    for name in ("particle filter", *kalman):
        c = out["pooled"][name]["unobserved_vs_free"]
        assert c["ci"][0] <= c["relative"] <= c["ci"][1], c
    assert r["casimir_drift_conservative"] < 1e-12
    assert all(f"| {name} |" in (tmp_path / "filters.md").read_text() for name in kalman)


@pytest.mark.full  # (40 s of compiling four forecast systems and two searches: second tier)
def test_closure(tmp_path):
    """`closure.py --fast` (M = 16, N = 4, one seed): the shares (each at most 1, the closure
    no worse than nothing on its training data), tuned factors, the trained closure, CIs that
    contain their estimates, spread/RMSE at every lead, and the fit's time."""
    run_script("closure.py", tmp_path)
    out = json.loads((tmp_path / "closure.json").read_text())
    (r,) = out["rows"]
    assert (r["M"], r["N"], r["seed"]) == (16, 4, 0)
    assert 0 <= r["shares"]["training"]["closure"] <= 1
    assert all(v <= 1 for v in r["shares"]["held_out"].values())
    for c in r["comparisons"].values():
        assert c["ci"][0] <= c["relative"] <= c["ci"][1], c
    assert all(f > 0 for f in r["factors"].values())
    assert all(len(v) == len(r["lead_times"]) for v in r["spread_rmse"].values())
    assert out["cost"][0]["seconds"] > 0
    short, long = "closure, trained 0.1 s", "closure, trained 0.2 s"  # (lead 10 and 20 steps)
    assert set(r["trained"]) == {short, long}
    assert all(len(t["loss"]) == 3 and r["factors"][n] > 0 for n, t in r["trained"].items())
    assert {f"{n} vs {o}" for n in (short, long) for o in ("closure", "isotropic")} <= set(
        r["comparisons"]
    )
    # the leads trained on are compared apart only where they are fewer than all
    assert r["comparisons"][f"{short} vs closure, trained leads"]["leads"] == 1
    assert f"{long} vs closure, trained leads" not in r["comparisons"]
    assert (tmp_path / "closure.md").read_text().count("| 16 → 4 | 0 |") == 4
