"""What `simulate` returns."""

from __future__ import annotations

import dataclasses

import jax


class RESULTS:
    """Per-sample outcome codes of `Solution.result`, and what each means.

    As diffrax's `RESULTS`: a failed sample's code says why its step failed, and
    `RESULTS.message(code)` says it in words (the failure messages of `simulate` and
    `integrate` quote it).
    """

    successful = 0
    max_iterations_reached = 1  # Newton's method used its updates without converging
    nonfinite = 2  # a non-finite residual or state
    off_branch = 3  # a Newton iterate left the admissible branch of roots
    outside_domain = 4  # the state left the method's domain (for example |y| >= 1)
    stalled = 5  # a fixed-point iteration stopped converging before its tolerance

    _messages = {
        0: "successful",
        1: "Newton's method reached max_iter updates without converging",
        2: "a non-finite residual or state appeared",
        3: "a Newton iterate left the admissible branch of roots (theta < pi/2)",
        4: "the state is outside the method's domain (|y| >= 1 for the generating-function "
        "methods)",
        5: "the fixed-point iteration's corrections stopped decreasing before reaching its "
        "tolerance (the step is too large for it)",
    }

    @classmethod
    def message(cls, code):
        """The meaning of a code, in words."""
        return cls._messages.get(int(code), f"unknown result code {int(code)}")

    @classmethod
    def name(cls, code):
        """The name of a code, such as `"max_iterations_reached"`."""
        names = {v: k for k, v in vars(cls).items() if isinstance(v, int) and k[0] != "_"}
        return names.get(int(code), f"code {int(code)}")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Solution:
    """An ensemble solution.

    - `ts`: the saved times, shape `(n_saved,)`.
    - `ys`: the saved states, shape `(n_samples, n_saved, 3)` (`(n_samples, n_saved, n, n)`
      on so(n)). A failed sample keeps its last good state from the failing step on (see
      `result` and `fail_step`); it is never NaN.
    - `result`: `RESULTS` code per sample, shape `(n_samples,)`; `ok` (a property): the
      samples that did not fail, for leaving the others out (`sol.ys[sol.ok]`).
    - `fail_step`: index of the step at which each sample failed, `-1` if it did not.
    - `stats`: a dict; `n_failed` always; with `newton_stats=True` also
      `newton_iterations_max`, `newton_iterations_mean` (updates per sample-step),
      `residual_max` (largest final Newton residual of any successful step) and
      `max_iter_share` (the share of sample-steps whose solve used its `max_iter` updates
      without converging; such a step fails, and is redone as substeps); unless
      `Failures(retry_substeps=None)` also `n_retried_steps` (steps redone as substeps, over
      all samples).
    """

    ts: jax.Array
    ys: jax.Array
    result: jax.Array
    fail_step: jax.Array
    stats: dict

    @property
    def ok(self):
        """Per sample: it did not fail (`fail_step == -1`), shape `(n_samples,)`."""
        return self.fail_step < 0
