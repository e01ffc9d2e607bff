"""A system's step as the driver takes it: the method's step, split where the system has
terms that no Lie–Poisson method integrates (the linear terms of forced-dissipative
Euler–Zeitlin) and shifted where its bracket acts on another variable (the absolute
vorticity of the rotating sphere).

Every step of every run goes through `system_step`, so that every entry point (`simulate`,
`integrate`, `simulate_to_store`, the particle filter, the studies) and the retry of failed
steps see the same step.
"""

from __future__ import annotations

from .._brownian import BrownianStep, as_step
from .._methods.base import finite_result


def _method_step(method, system, y, dt, dW, history):
    """`method.step`, given the method's `history` where it keeps one."""
    if history is None or (isinstance(history, tuple) and not history):
        return method.step(system, y, dt, dW)
    return method.step(system, y, dt, dW, history=history)


def has_linear_terms(system):
    """Whether `system` has linear terms, whose flow the driver joins between steps
    (`system_step`'s `pending`)."""
    return getattr(system, "linear", None) is not None


def apply_pending(system, y, pending):
    """`y` moved by the linear flow still owed to it (`system_step`'s `pending`): the state
    itself. `y` unchanged for a system without linear terms."""
    return system.linear_flow(y, pending) if has_linear_terms(system) else y


def system_step(method, system, y, dt, dW, history=(), pending=None):
    r"""One step of `system` by `method`: the method's step on the bracket part, and where
    the system has linear terms (`system.linear`, an `EulerZeitlin` with `nu`, `alpha` or
    `forcing`), the Strang splitting $L_{h/2}\circ\Phi_h\circ L_{h/2}$ around it, $L$ their
    exact flow. An additive forcing (`system.additive`) enters as two half kicks
    $K = \tfrac12\sum\sigma_\ell\Delta B_{\ell m}T_{\ell m}$ of the step's last increments,
    $L_{h/2}\circ K\circ\Phi_h\circ K\circ L_{h/2}$, the method seeing only the transport
    noises' increments. On the rotating sphere the method steps the absolute vorticity
    $W + f$ (`EulerZeitlin.bracket_view`). A system without any of these is stepped as it
    is.

    `pending`: `None` (default), or the time $\tau$ of linear flow that `y` still owes (a
    scalar): the step is then $K\circ\Phi_h\circ K\circ L_{\tau + h/2}$ and the result
    owes $h/2$. Since $L_a\circ L_b = L_{a + b}$ exactly (the terms are linear and
    autonomous), consecutive steps joined this way are the Strang steps with one linear
    flow each instead of two; `apply_pending` settles the debt where a state is wanted.
    Ignored for a system without linear terms.

    **Returns:** `(y_next, StepInfo)`, the method's report with the final state's check."""
    linear = getattr(system, "linear", None)
    additive = getattr(system, "additive", None)
    view, shift = system.bracket_view() if hasattr(system, "bracket_view") else (system, None)
    if linear is None and shift is None and additive is None:
        return _method_step(method, system, y, dt, dW, history)
    kick = None
    if additive is not None:  # (its increments: the last ones; half a kick each side)
        noise = as_step(dW)
        s = system.noise.n_noises
        area = None if noise.area is None else noise.area[:s, :s]
        kick = 0.5 * additive.kick(noise.dW[s:], y.shape[-1], y.dtype)
        dW = BrownianStep(noise.dW[:s], area)
    if linear is not None:
        y = system.linear_flow(y, 0.5 * dt if pending is None else pending + 0.5 * dt)
    if kick is not None:
        y = y + kick
    if shift is not None:
        y = y + shift.astype(y.dtype)
    y, info = _method_step(method, view, y, dt, dW, history)
    if shift is not None:
        y = y - shift.astype(y.dtype)
    if kick is not None:
        y = y + kick
    if linear is not None and pending is None:
        y = system.linear_flow(y, 0.5 * dt)
    return y, info._replace(result=finite_result(y, info.result))
