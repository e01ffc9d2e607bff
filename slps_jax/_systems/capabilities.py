"""What a method may need of a system (`AbstractMethod.requires`): each capability is one
test of what the system *is* (its type, its algebra's type, its noise), not a tag a system
declares, so no system can claim one it lacks or forget one it has."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from .._algebra.so3 import SO3Algebra
from .noise import ProportionalNoise
from .rigid_body import RigidBody


@dataclasses.dataclass(frozen=True)
class Capability:
    """Something a method needs of a system: `description` (words, for messages) and
    `test(system) -> bool`. `capability(system)` says whether the system has it."""

    description: str
    test: Callable[[Any], bool]

    def __call__(self, system) -> bool:
        return bool(self.test(system))

    def __str__(self):
        return self.description


RIGID_BODY = Capability(
    "the rigid body's closed forms (inertia, inverse_inertia, the elliptic flow)",
    lambda system: isinstance(system, RigidBody),
)
NOISE_PROPORTIONAL_TO_DRIFT = Capability(
    "one noise proportional to the drift (c=)",
    lambda system: isinstance(system.noise, ProportionalNoise),
)
LINEAR_NOISE = Capability(
    "noise Hamiltonians linear in y (salt_noise)",
    lambda system: system.noise.linear,
)
QUADRATIC = Capability(
    "quadratic Hamiltonians (a quadratic H_0 with c=): y -> y/s is a time change",
    lambda system: isinstance(system.noise, ProportionalNoise) and system.quadratic_hamiltonian,
)
SO3_VECTORS = Capability(
    "so(3)* as 3-vectors (the algebra sj.SO3: a RigidBody, or "
    "LiePoissonSystem(..., algebra=sj.SO3), not the matrices of sj.so(3))",
    lambda system: isinstance(system.algebra, SO3Algebra),
)
CAPABILITIES = (RIGID_BODY, NOISE_PROPORTIONAL_TO_DRIFT, LINEAR_NOISE, QUADRATIC, SO3_VECTORS)
