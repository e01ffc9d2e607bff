"""What `simulate` returns."""

from __future__ import annotations

import dataclasses

import jax


class RESULTS:
    """Per-sample outcome codes of `Solution.result`."""

    successful = 0
    step_failed = 1  # a step could not be solved (or gave a non-finite state)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Solution:
    """An ensemble solution.

    - `ts`: the saved times, shape `(n_saved,)`.
    - `ys`: the saved states, shape `(n_samples, n_saved, 3)`. A failed sample keeps its last
      good state from the failing step on (see `result` and `fail_step`); it is never NaN.
    - `result`: `RESULTS` code per sample, shape `(n_samples,)`.
    - `fail_step`: index of the step at which each sample failed, `-1` if it did not.
    - `stats`: a dict; `n_failed` always; with `newton_stats=True` also
      `newton_iterations_max`, `newton_iterations_mean` (per sample-step) and `residual_max`
      (largest final Newton residual of any successful step); with `retry_substeps` also
      `n_retried_steps` (steps redone as substeps, over all samples).
    """

    ts: jax.Array
    ys: jax.Array
    result: jax.Array
    fail_step: jax.Array
    stats: dict
