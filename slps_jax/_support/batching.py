"""Loop carries that start batched under `vmap`, so that a loop's body is batched once.

`vmap` of a `lax.while_loop` or `lax.scan` first finds which parts of the carry are batched:
it batches the body with the initial carry's batching, then again with every part the body
made batched, until nothing changes, and once more for the program it keeps. A carry that
starts unbatched (a counter, a status code, the `y0` that every sample shares) but is batched
after one step costs one more pass over the body, and nested loops pay it at every level
(Newton's loop inside the retried step inside the time loop), where the body of an implicit
method's step is thousands of operations: with the carries below batched from the start,
the test suite's tracing fell from 181 s to 135 s (`benchmarks/README.md`, "Compile time").

`batched_like(init, like)` is `init` with the same values, batched wherever `like` is, so
the batching is settled at the first pass. In a while loop whose predicate is batched (a
Newton or retry loop under `vmap`) every carry ends up batched anyway: the compiled program
is the same.
"""

from __future__ import annotations

import functools
import operator

import jax
import jax.numpy as jnp


def batched_like(tree, like):
    """`tree` unchanged in value, but batched under `vmap` wherever any leaf of `like` is
    (each leaf of `tree` is selected between itself and itself on a flag read from `like`)."""
    flags = [jnp.any(jnp.ravel(leaf)[:1] != 0) for leaf in jax.tree_util.tree_leaves(like)]
    if not flags:
        return tree
    flag = functools.reduce(operator.or_, flags)
    return jax.tree_util.tree_map(lambda v: jnp.where(flag, v, v), tree)
