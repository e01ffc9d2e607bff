"""The one failure report of every run: what failed, where and why, and what to do.

Failures are never silent and never data. `simulate` warns (or raises with
`Failures(throw=True)`); `ensemble_statistics` and the studies leave the failed samples out
and warn (or raise); `calibrate` stops. All of them say it in the same words, from `message`.
Inside `jit`, `vmap` or `grad` the report comes through a host callback when the compiled
function runs. `Failures` is the one option of every entry point that says what to do.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import jax
import jax.core
import numpy as np

from .._support.checks import check_option, check_retry, check_throw, user_stacklevel
from .._support.solution import RESULTS
from .sharding import gather

ADVICE = (
    "A smaller dt usually helps (or LiePoisson(scale=...) near |y| = 1, or a method "
    "without Newton solves such as Strang())."
)


@dataclasses.dataclass(frozen=True)
class Failures:
    """What a run does with a step its method cannot solve (a Newton solve that does not
    converge, a root off the branch): the `failures=` option of every entry point.

    **Arguments:**

    - `retry_substeps`: `k >= 2` (default 4): a step that fails is redone as `k`, then
      `k^2`, then `k^3` equal substeps of its noise before the sample is given up (`stats`
      then has `n_retried_steps`); `None`: not redone, and the retry is left out of the
      compiled program. Steps that succeed are untouched, so results without failures are
      identical, and the retry is differentiable. When more than half of the steps were
      redone, a `RuntimeWarning` (once per call) names a step that would not need it
      (`system.step_guide`).
    - `throw`: `False` (the default of every entry point but `integrate`): a sample that
      failed is frozen at its last good state and flagged (`Solution.ok`, `result`,
      `fail_step`), or left out of a study's statistics, and a `RuntimeWarning` says how
      many failed, why and where; `True`: raise `RuntimeError` with that message instead.
      Inside `jax.jit` or `jax.grad` the warning or error comes through a host callback
      when the compiled function runs.
    """

    retry_substeps: int | None = 4
    throw: bool = False

    def __post_init__(self):
        object.__setattr__(self, "retry_substeps", check_retry(self.retry_substeps))
        check_throw(self.throw)
        object.__setattr__(self, "throw", bool(self.throw))

    @property
    def retried(self) -> bool:
        return self.retry_substeps is not None


def check_failures(caller, failures) -> Failures:
    return check_option(caller, "failures", failures, Failures)


def summary(fail_step, result):
    """`(n_failed, n, first_step, why)` of the paths that failed, `None` if none did.
    `fail_step`, `result`: per path (any shape; sharded over processes too), `-1` /
    `successful` where none failed; `why` counts the `RESULTS` messages."""
    fail_step, result = np.ravel(gather(fail_step)), np.ravel(gather(result))
    failed = fail_step >= 0
    if not np.any(failed):
        return None
    first = int(np.min(fail_step[failed]))
    codes, counts = np.unique(result[failed], return_counts=True)
    why = "; ".join(f"{int(n)} x {RESULTS.message(c)}" for c, n in zip(codes, counts))
    return int(np.sum(failed)), fail_step.size, first, why


def message(caller, n_failed, n, consequence, *, why=None, first=None, retried=True):
    """`caller: k of n samples failed (first at step j): why, even split into substeps.
    <consequence> ADVICE`."""
    at = "" if first is None else f" (first at step {first})"
    return (
        f"{caller}: {n_failed} of {n} samples failed{at}"
        + ("" if why is None else f": {why}")
        + f"{_even(retried)}. {consequence} {ADVICE}"
    )


def warn_or_raise(failures, msg):
    """The report of samples a run left out of its results: a `RuntimeWarning`, or with
    `Failures(throw=True)` a `RuntimeError`."""
    if failures.throw:
        raise RuntimeError(msg)
    warnings.warn(msg, RuntimeWarning, stacklevel=user_stacklevel())


def _even(retried):
    return (
        ", even split into substeps (Failures.retry_substeps)"
        if retried
        else " (Failures(retry_substeps=None): failing steps were not split into "
        "substeps; the default, 4, splits them)"
    )


def _path_message(caller, fail_step, result, retried):
    found = summary(fail_step, result)
    if found is None:
        return None
    n_failed, n, first, why = found
    if caller == "integrate":
        which = f" (first failure; {n_failed} of {n} paths failed)" if n > 1 else ""
        return (
            f"integrate: step {first} could not be solved{which}: {why}"
            f"{_even(retried)}. The path is frozen at its last good state from "
            f"there on. Pass failures=Failures(throw=False) to return it anyway. {ADVICE}"
        )
    return message(
        caller,
        n_failed,
        n,
        'They are frozen at their last good state: the store\'s "ok" says which.'
        if caller == "simulate_to_store"
        else "They are frozen at their last good state: leave "
        "them out with Solution.ok (Solution.result and fail_step say why and "
        "where).",
        why=why,
        first=first,
        retried=retried,
    )


def _report_now(caller, throw, retried, fail_step, result):
    msg = _path_message(caller, fail_step, result, retried)
    if msg is None:
        return
    if throw:
        raise RuntimeError(
            msg
            + (
                " Pass failures=Failures(throw=False) to get the other samples."
                if caller != "integrate"
                else ""
            )
        )
    warnings.warn(msg, RuntimeWarning, stacklevel=user_stacklevel())


@functools.cache
def _reporter(caller, throw, retried):
    """Raise or warn (through a host callback) if any path failed: for failures under `jit`,
    `vmap` or `grad`, which are not known in Python.

    Under `vmap` the callback gets the whole batch, once: `jax.debug.callback`'s own rule
    unrolls the batch into one host call per sample, which made a `vmap`ped `integrate`
    3x slower and its compilation about twice as long (500 samples x 512 steps).
    """

    @jax.custom_batching.custom_vmap
    def report_traced(fail_step, result):
        jax.debug.callback(
            functools.partial(_report_now, caller, throw, retried), fail_step, result
        )
        return fail_step

    @report_traced.def_vmap
    def _batched(axis_size, in_batched, fail_step, result):
        return report_traced(fail_step, result), in_batched[0]

    return report_traced


def report(caller, throw, retried, fail_step, result):
    """Raise (`throw`) or warn if any path failed: now if the failures are concrete, through
    a callback when the compiled function runs if they are traced."""
    if isinstance(fail_step, jax.core.Tracer):
        _reporter(caller, throw, retried)(fail_step, result)
    else:
        _report_now(caller, throw, retried, fail_step, result)


RETRIED_SHARE = 0.5
"""`report_retries` warns when more than this share of the steps were redone as substeps."""


def report_retries(caller, sol, system, y0, dt, n_steps):
    """Warn, once per run, when most steps were redone as substeps (`Failures`): the
    results are right, but the run paid for each step several times. The warning names a
    step that would not need that (`system.step_guide` of the initial state and of the
    first sample's last one, the smaller), or, where the step is already below it, the
    method's options or the noise. Nothing where the statistics are traced."""
    n_retried = sol.stats.get("n_retried_steps")
    if n_retried is None or isinstance(n_retried, jax.core.Tracer):
        return
    total = sol.fail_step.size * n_steps
    share = float(np.asarray(gather(n_retried))) / max(total, 1)
    if share <= RETRIED_SHARE:
        return
    try:
        guide = min(system.step_guide(y0), system.step_guide(np.asarray(sol.ys)[0, -1]))
    except Exception:  # (a system whose gradient cannot be evaluated here: traced leaves)
        guide = None
    start = f"{caller}: {100 * share:.0f} % of the steps were redone as substeps (Failures.retry_substeps)"
    if guide is not None and guide < float(dt):
        msg = (
            f"{start}: the step dt = {float(dt):.3g} is too large for the method's solve on "
            f"these states, and each such step cost several; a step of about {guide:.3g} "
            "(system.step_guide) would not need that, and would cost less."
        )
    else:
        below = "" if guide is None else f" (system.step_guide: {guide:.3g})"
        msg = (
            f"{start}, each at the cost of several, although the step dt = {float(dt):.3g} is "
            f"not large for the drift{below}: the method's options (max_iter, tol, rtol) or "
            "the noise's strength are what make its solve fail."
        )
    warnings.warn(msg, RuntimeWarning, stacklevel=user_stacklevel())
