"""Public so(3) / SO(3) toolkit: `hat`, `vee`, `skew`, `sym`, `exp`, `log`, `cayley`, `cayley_inv`."""

from ._so3 import (  # noqa: F401
    cayley as cayley,
    cayley_inv as cayley_inv,
    exp as exp,
    hat as hat,
    log as log,
    skew as skew,
    sym as sym,
    vee as vee,
)
