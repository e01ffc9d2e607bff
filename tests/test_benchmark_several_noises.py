"""benchmarks/several_noises.py runs (`--fast`, in a subprocess, into a tmp dir) and writes sane
files: its own module, so that pytest-xdist's `--dist loadfile` can run it beside the other
benchmark scripts. Correctness only: no timing is asserted."""

import json

import pytest
from test_benchmarks import HAVE_DIFFRAX, is_png, run_script


def test_several_noises(tmp_path):
    """The SALT benchmark runs; the Poisson methods (with and without Lévy areas) keep |y| to
    round-off, Heun written three ways (ours, a plain lax.scan, diffrax where installed)
    gives the same errors on the same increments, and every convergent method's error falls
    with h; the area-cost and so(4) parts run."""
    stdout = run_script("several_noises.py", tmp_path)
    assert is_png(tmp_path / "several_noises.png")
    summary = json.loads((tmp_path / "several_noises.json").read_text())
    rows = summary["rows"]
    methods = {r["method"] for r in rows}
    assert {"LiePoisson", "Midpoint", "SaltSplitting", "Heun", "lax.scan Heun"} <= methods
    assert ("diffrax Heun" in methods) == HAVE_DIFFRAX
    heun = {
        m: [r["rms_error"] for r in rows if r["method"] == m]
        for m in ("Heun", "lax.scan Heun", "diffrax Heun")
        if m in methods
    }
    for errs in heun.values():
        assert errs == pytest.approx(heun["Heun"], rel=1e-9)
    for row in summary["summary"]:
        name = row["method"]
        if name.split(" + ")[0] in ("LiePoisson", "LiePoissonSym2", "Midpoint", "SaltSplitting"):
            assert row["max_rel_casimir_error"] < 1e-12
        if name.endswith("+ areas"):  # order 1 (a smoke run: two steps, loose bounds)
            assert 0.7 < row["strong_order"] < 1.5, row
        elif name != "EulerMaruyama":
            assert 0.3 < row["strong_order"] < 1.0, row
    assert [r["s"] for r in summary["area_costs"]] == [3]
    assert {r["method"] for r in summary["so4_summary"]} >= {
        "IsospectralMidpoint + areas",
        "LiePoisson + areas",
    }
    for row in summary["so4_summary"]:
        if "Milstein" not in row["method"]:
            assert row["max_rel_casimir_error"] < 1e-12
    assert 0 < summary["reference_error"] < min(r["rms_error"] for r in rows)
    assert "Long time" in stdout
