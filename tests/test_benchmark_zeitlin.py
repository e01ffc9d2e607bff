"""benchmarks/zeitlin.py runs (`--fast`, in a subprocess, into a tmp dir) and writes sane
files: its own module, so that pytest-xdist's `--dist loadfile` runs it beside the other
benchmark scripts. Correctness only: no timing is asserted."""

import json

import numpy as np
from test_benchmarks import is_png, run_script


def test_zeitlin(tmp_path):
    """The Euler-Zeitlin benchmark runs; the isospectral rule keeps every Casimir (in
    complex64 to its round-off), the
    midpoint rule tr W^2 and (a quadratic Hamiltonian, no noise) the energy, Heun none; where
    quflow is installed, its isomp and ours end at the same state."""
    run_script("zeitlin.py", tmp_path)
    assert is_png(tmp_path / "zeitlin.png")
    out = json.loads((tmp_path / "zeitlin.json").read_text())
    methods = {r["method"] for r in out["cost"]}
    assert {"IsospectralMidpoint", "Midpoint", "Heun"} <= methods
    assert all(r["ms_per_sample_step"] > 0 for r in out["cost"])
    cons = {r["method"]: r for r in out["conservation"] if r["dtype"] == "complex128"}
    explicit = [r for r in out["conservation"] if r["method"] == "IsospectralMidpoint (explicit)"]
    assert [r["dtype"] for r in explicit] == ["complex128", "complex64"]
    out["conservation"] = [r for r in out["conservation"] if r not in explicit]
    assert max(cons["IsospectralMidpoint"][k] for k in ("tr_w2", "tr_w3", "tr_w4")) < 1e-12
    single = [r for r in out["conservation"] if r["dtype"] == "complex64"]
    assert [r["method"] for r in single] == ["IsospectralMidpoint"]
    bound = 10 * np.finfo(np.float32).eps * np.sqrt(single[0]["steps"])  # its round-off
    assert max(single[0][k] for k in ("tr_w2", "tr_w3", "tr_w4")) < bound
    assert cons["Midpoint"]["tr_w2"] < 1e-12 < 1e-8 < cons["Midpoint"]["tr_w3"]
    assert cons["Midpoint"]["energy"] < 1e-12
    assert min(cons["Heun"][k] for k in ("tr_w2", "tr_w3", "tr_w4", "energy")) > 1e-8
    if "quflow isomp" in methods:
        diffs = [r["diff_vs_quflow"] for r in out["cost"] if r["method"] == "IsospectralMidpoint"]
        assert max(diffs) < 1e-10


def test_zeitlin_scale(tmp_path):
    """`--scale` (the GPU mode's sizes cut to N = 8): the Poisson routes, the products, the
    step, its floor and an ensemble are measured in both dtypes."""
    run_script("zeitlin.py", tmp_path, "--scale")
    rows = json.loads((tmp_path / "zeitlin_scale.json").read_text())["rows"]
    assert [r["dtype"] for r in rows] == ["complex128", "complex64"]
    for r in rows:
        for k in (
            "poisson_sweep_ms",
            "poisson_scan_ms",
            "poisson_eigenbasis_ms",
            "two_products_ms",
            "two_complex_products_ms",
            "step_ms",
            "ms_per_member_step",
            "ms_per_member_step_eigenbasis",
            "step_8_areas_ms",
        ):
            assert r[k] > 0, (k, r)
        assert r["updates"] >= 1 and r["floor_ms"] > 0
    assert (tmp_path / "zeitlin_scale.md").read_text().count("| 8 |") == 2


def test_zeitlin_breakdown(tmp_path):
    """`--breakdown` (cut to N = 8, 4 members, one state at N = 16): every case is timed."""
    run_script("zeitlin.py", tmp_path, "--breakdown")
    rows = json.loads((tmp_path / "zeitlin_breakdown.json").read_text())["rows"]
    assert len(rows) == 2 * (3 + 4) + 4
    assert all(r["ms"] > 0 for r in rows)


def test_zeitlin_economy(tmp_path):
    """`--economy` (cut to N = 8, 8 steps): every option of the fixed point is timed with its
    updates per step, and the default for an ensemble of 4; the default and the solves to
    round-off keep the Casimirs to 1e-13, and the warm start takes fewer updates than the
    cold one."""
    run_script("zeitlin.py", tmp_path, "--economy")
    rows = json.loads((tmp_path / "zeitlin_economy.json").read_text())["rows"]
    ours = {r["option"]: r for r in rows if r.get("updates") is not None}
    ours = {k: r for k, r in ours.items() if not k.startswith("quflow")}
    ensemble = [r for r in rows if "ensemble of 4" in r["option"]]
    assert len(ensemble) == 1 and ensemble[0]["casimir_drift"] < 1e-13
    assert set(ours) == {
        "default",
        "default, cold start",
        "explicit, rtol 2^-26",
        "explicit, round-off",
        "explicit, tol 1e-13",
    }
    assert all(r["ms_per_step"] > 0 and r["updates"] >= 1 for r in ours.values())
    for name in ("default", "default, cold start", "explicit, round-off"):
        assert ours[name]["casimir_drift"] < 1e-13, name
    assert ours["default"]["updates"] < ours["default, cold start"]["updates"]
    store = json.loads((tmp_path / "zeitlin_store.json").read_text())["row"]
    assert store["s_per_step_store"] > 0 < store["s_per_step_memory"]
    assert store["bytes_written"] > 64 * 16 * 9 * 2  # (the states alone: 9 snapshots of 2)


def test_zeitlin_final_update(tmp_path):
    """`--final-update` (cut to N = 8, 16 steps): each final update at each step, its cost
    and updates; the rotation and the explicit update solved to round-off keep the Casimirs
    to 1e-13 with the same root (more updates for round-off), the explicit update at
    sqrt(eps) does not."""
    run_script("zeitlin.py", tmp_path, "--final-update")
    rows = json.loads((tmp_path / "zeitlin_final_update.json").read_text())["rows"]
    assert len(rows) == 9 and all(r["us_per_sample_step"] > 0 for r in rows)
    for h in {r["h"] for r in rows}:
        at = {r["update"]: r for r in rows if r["h"] == h}
        assert at["cayley (default)"]["casimir_drift"] < 1e-13
        assert at["explicit, round-off"]["casimir_drift"] < 1e-13
        assert at["explicit, rtol 2^-26"]["casimir_drift"] > 1e-14
        assert at["explicit, round-off"]["updates"] > at["cayley (default)"]["updates"]
