"""benchmarks/so_n.py runs (`--fast`, in a subprocess, into a tmp dir) and writes sane files:
its own module, so that pytest-xdist's `--dist loadfile` runs it beside the other benchmark
scripts. Correctness only: no timing is asserted."""

import json

import pytest
from test_benchmarks import HAVE_DIFFRAX, is_png, run_script


def test_so_n(tmp_path):
    """The so(n) benchmark runs; Heun written two ways (ours, diffrax where installed) gives
    the same errors on the same increments; every error falls with h; the isospectral methods
    keep every Casimir, the midpoint rule only tr Y^2."""
    run_script("so_n.py", tmp_path)
    assert is_png(tmp_path / "so_n.png")
    out = json.loads((tmp_path / "so_n.json").read_text())
    methods = {r["method"] for r in out["cost"]}
    assert {"LiePoisson chord", "Isospectral fixed point", "Midpoint", "Heun"} <= methods
    assert ("diffrax Heun" in methods) == HAVE_DIFFRAX
    wp = out["work_precision"]
    errors = {
        m: [r["rms_error"] for r in wp if r["method"] == m] for m in {r["method"] for r in wp}
    }
    for errs in errors.values():
        assert errs[1] < errs[0]
    if HAVE_DIFFRAX:
        assert errors["diffrax Heun"] == pytest.approx(errors["Heun"], rel=1e-9)
    cas = {r["method"]: r for r in out["casimirs"]}
    for name in ("LiePoisson", "IsospectralMidpoint"):
        assert max(cas[name]["tr_y2"], cas[name]["tr_y4"], cas[name]["tr_y6"]) < 1e-12
    assert cas["Midpoint"]["tr_y2"] < 1e-10 < 1e-6 < cas["Midpoint"]["tr_y4"]
    assert all(r["nonfinite"] == 0 for r in out["stress"])
