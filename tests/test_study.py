"""strong_convergence, the Exact sampler and the `slps-jax paper` command."""

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import exact_sde_solution

import slps_jax as sj

DTS = [2.0**-k for k in (5, 6, 7, 8)]


@pytest.fixture(scope="module")
def study():
    model = sj.RigidBody.paper()
    return sj.strong_convergence(
        model,
        sj.PAPER_Y0,
        t1=1.0,
        dts=DTS,
        n_samples=200,
        key=jax.random.key(20),
        methods={
            "LiePoisson": sj.LiePoisson(),
            "Exact": sj.Exact(),
            "EulerMaruyama": sj.EulerMaruyama(),
        },
    )


def test_orders(study):
    assert 0.85 <= study.order["LiePoisson"] <= 1.2
    assert study.order_stderr["LiePoisson"] < 0.05
    assert np.all(study.errors["Exact"] < 1e-13)  # no discretisation error at all
    # Euler-Maruyama converges to the Ito equation, not to this Stratonovich one: its error
    # levels off at the distance between the two (order well below 1/2).
    assert study.order["EulerMaruyama"] < 0.35
    assert study.errors["EulerMaruyama"][-1] > 1e-3
    assert "LiePoisson" in study.table()


def test_errors_match_an_independent_computation(study):
    """The same samples and paths, integrated with `integrate` and scipy's reference."""
    model, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    fine = sj.BrownianMotion().increments(jax.random.key(20), 256, DTS[-1], n_samples=200)
    exact = exact_sde_solution(model.inertia, 0.2, y0, np.asarray(fine.sum(1)), 1.0)
    coarse = fine.reshape(200, -1, 2).sum(-1)  # h = 2^-7
    y = jax.jit(jax.vmap(lambda w: sj.integrate(model, y0, w, DTS[2], method=sj.LiePoisson())))(
        coarse
    )
    rms = np.sqrt(np.mean(np.sum((np.asarray(y) - exact) ** 2, -1)))
    np.testing.assert_allclose(study.errors["LiePoisson"][2], rms, rtol=1e-8)


def test_midpoint_reference_option():
    kw = dict(
        t1=0.5,
        dts=DTS[:3],
        n_samples=50,
        key=jax.random.key(21),
        methods={"LP": sj.LiePoisson()},
    )
    midpoint = sj.Reference(sj.Midpoint(), dt=DTS[2] / 8)
    res = sj.strong_convergence(sj.RigidBody.paper(), sj.PAPER_Y0, **kw, reference=midpoint)
    exact = sj.strong_convergence(sj.RigidBody.paper(), sj.PAPER_Y0, **kw)
    # The midpoint reference is far more accurate than the scheme at these steps.
    np.testing.assert_allclose(res.errors["LP"], exact.errors["LP"], rtol=0.05)


def test_study_rejects_bad_input():
    model = sj.RigidBody.paper()
    kw = dict(t1=1.0, n_samples=10, key=jax.random.key(0), methods=sj.LiePoisson())
    with pytest.raises(ValueError, match="dts"):
        sj.strong_convergence(model, sj.PAPER_Y0, dts=[0.1], **kw)
    with pytest.raises(ValueError, match="multiple"):
        sj.strong_convergence(model, sj.PAPER_Y0, dts=[0.1, 0.03], **kw)
    with pytest.raises(ValueError, match="reference"):
        sj.strong_convergence(model, sj.PAPER_Y0, dts=[0.1, 0.05], **kw, reference="rk4")


def test_exact_method_reproduces_exact_solution(paper):
    model, y0 = paper
    dW = sj.BrownianMotion().increments(jax.random.key(22), 400, 0.05, n_samples=5)
    ys = jax.vmap(lambda w: sj.integrate(model, y0, w, 0.05, method=sj.Exact()))(dW)
    ref = exact_sde_solution(model.inertia, 0.2, y0, np.asarray(dW.sum(1)), 20.0)
    np.testing.assert_allclose(ys, ref, atol=1e-10)


def test_paper_command_fast(tmp_path):
    from slps_jax.__main__ import main

    out = tmp_path / "paper"
    assert main(["paper", "--fast", "--no-cache", "--out", str(out)]) == 0
    names = {
        "fig4_1_sample_path.png",
        "fig4_2_invariants.png",
        "fig4_3_phase_sphere.png",
        "fig4_4_strong_order.png",
        "results.json",
        "results.md",
    }
    assert names <= set(os.listdir(out))
    for n in names:
        assert (out / n).stat().st_size > 300
    res = json.loads((out / "results.json").read_text())
    lp = res["fig4_4"]["methods"]["LiePoisson"]
    assert 0.8 <= lp["order"] <= 1.25
    assert res["fig4_2"]["drift"]["LiePoisson"]["casimir_max"] < 1e-13
    assert res["fig4_2"]["drift"]["EulerMaruyama"]["casimir_max"] > 1e-3
    assert res["fig4_4"]["exact_method_max_rms_error"] < 1e-12
    assert "| LiePoisson |" in (out / "results.md").read_text()


def test_paper_command_output_folders(monkeypatch, capsys, tmp_path):
    """`--fast` writes to its own default folder, so it never overwrites a full run; `--out`
    wins; a folder that cannot be made is a one-line error (exit 2) before any work;
    `--help` describes the commands and every option."""
    import slps_jax.__main__ as cli
    import slps_jax._cli.paper as paper_module
    from slps_jax.__main__ import main

    seen, cached = [], []
    monkeypatch.setattr(paper_module, "run", lambda out_dir, fast, seed: seen.append(out_dir))
    monkeypatch.setattr(cli, "use_compilation_cache", lambda jax: cached.append(True))
    monkeypatch.chdir(tmp_path)  # (the folders are made before the run)
    main(["paper"])
    main(["paper", "--fast"])
    main(["paper", "--fast", "--out", "mine"])
    main(["paper", "--no-cache"])
    assert seen == ["paper-output", "paper-output-fast", "mine", "paper-output"]
    assert cached == [True, True, True]  # the cache is on unless --no-cache
    assert all((tmp_path / name).is_dir() for name in seen)
    (tmp_path / "a-file").write_text("")
    capsys.readouterr()
    assert main(["paper", "--fast", "--out", str(tmp_path / "a-file" / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out" in err and "Not a directory" in err, err
    assert len(seen) == 4 and len(cached) == 3  # nothing ran
    for args in (["--help"], ["paper", "--help"], ["summary", "--help"]):
        with pytest.raises(SystemExit):
            main(args)
    text = capsys.readouterr().out
    assert "reproduce Figures 4.1-4.4" in text and "seed of the Brownian samples" in text
    assert "paper-output-fast" in text and "Command line:" not in text
    assert "--no-cache" in text
    assert "$JAX_COMPILATION_CACHE_DIR" in text and "$XDG_CACHE_HOME" in text


def test_an_unwritable_cache_or_output_folder_costs_one_line(monkeypatch, capsys, tmp_path):
    """A cache folder that cannot be made (or written to: /sys refuses even root) is one
    warning line and no cache, not a traceback; an output folder that cannot be written to is
    a one-line error before any work; `--samples` below 2 is the subcommand's usage error."""
    import jax

    import slps_jax.__main__ as cli

    (tmp_path / "a-file").write_text("")
    folders = [str(tmp_path / "a-file" / "cache")]
    if os.path.isdir("/sys/kernel"):
        folders.append("/sys/kernel")
    for folder in folders:
        monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", folder)
        monkeypatch.setattr(jax.config, "update", lambda name, value: updates.append((name, value)))
        updates = []
        assert cli.use_compilation_cache(jax) is None
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "warning: no compilation cache" in err, err
        assert updates == [("jax_enable_compilation_cache", False)]  # (JAX reads the variable)
        monkeypatch.undo()
    if os.path.isdir("/sys/kernel"):
        assert cli.main(["paper", "--fast", "--out", "/sys/kernel"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "cannot write into the folder" in err, err
    for bad in ("-5", "1", "x"):
        with pytest.raises(SystemExit):
            cli.main(["summary", "--samples", bad])
        err = capsys.readouterr().err
        assert "slps-jax summary: error: argument --samples" in err, err


def test_the_command_line_keeps_compiled_programs_in_the_user_cache(tmp_path):
    """The persistent compilation cache goes to the user's cache folder ($XDG_CACHE_HOME)
    and is filled by what the command line compiles."""
    import subprocess
    import sys

    code = (
        "import jax; from slps_jax.__main__ import use_compilation_cache; "
        "print(use_compilation_cache(jax)); jax.jit(lambda x: 2.0 * x + 1.0)(3.0)"
    )
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path), JAX_PLATFORMS="cpu")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        cwd=os.path.dirname(os.path.dirname(__file__)),
    )
    assert proc.returncode == 0, proc.stderr
    folder = tmp_path / "slps-jax" / "jax-compilation-cache"
    assert proc.stdout.strip() == str(folder)
    assert any(folder.iterdir())


def test_summary_writes_each_line_as_it_is_produced():
    """Into a pipe (a log file, `| tee`), `slps-jax summary` shows what it is doing before
    the first long computation ends: its lines are flushed, not held in a block buffer
    until the process exits."""
    import os
    import pathlib
    import subprocess
    import sys

    root = pathlib.Path(__file__).resolve().parents[1]
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join(
            [str(root)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
        ),
    )
    proc = subprocess.Popen(
        [sys.executable, "-m", "slps_jax", "summary", "--fast"],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
        cwd=root,
    )
    try:
        lines = [proc.stdout.readline() for _ in range(4)]
        still_running = proc.poll() is None
    finally:
        proc.kill()
        proc.wait()
    assert lines[0].startswith("slps-jax ") and lines[3].startswith("Strong errors:")
    assert still_running  # the study had not finished when its announcement arrived


def test_a_float32_study_warns_once_and_a_float64_study_does_not():
    import warnings

    kw = dict(
        t1=0.25,
        dts=[2.0**-3, 2.0**-4],
        n_samples=4,
        key=jax.random.key(0),
        methods={"Strang": sj.Strang()},
    )
    y0 = jnp.asarray(sj.PAPER_Y0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sj.strong_convergence(
            sj.RigidBody(jnp.asarray([2.0, 1.0, 2.0 / 3.0], jnp.float32), 0.5),
            y0.astype(jnp.float32),
            **kw,
        )
    single = [w for w in caught if "float32" in str(w.message)]
    assert len(single) == 1 and "jax_enable_x64" in str(single[0].message)
    assert single[0].filename == __file__  # it points at the caller's line
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sj.strong_convergence(sj.RigidBody.paper(), y0, **kw)
    assert not [w for w in caught if "float32" in str(w.message)]
