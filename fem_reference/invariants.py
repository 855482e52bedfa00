"""The sum of the principal stretches, tr U (F = R U), from the invariants of C = F^T F: the one
function of the strain that the corotational law needs beyond (I1, I2, J), shared by the
reference's UFL energy (``forms.corotational_psi``) and the fast solvers' numpy law
(``solvers.admm.mechanics``); it imports nothing, and works on UFL expressions and numbers alike.

The invariants of U and of C are tied by a^2 - 2 b = I1 and b^2 - 2 J a = I2 (a = tr U, b the
second invariant of U, J = det U = det F), so a is the largest root of
f(a) = (a^2 - I1)^2 / 4 - 2 J a - I2. The other three roots are sums of the principal stretches
with two signs flipped, so f is convex and increasing to the right of the largest, and Newton's
iteration from an upper bound converges monotonically to it. A smooth function of C, exact at
equal stretches (at rest too), where an eigen-decomposition's derivatives are not. Plane strain
(C33 = 1) takes the 3D invariants and gives a with the unit third stretch in it.
"""
from __future__ import annotations

__all__ = ["STRETCH_SUM_NEWTON_STEPS", "principal_stretch_sum"]

STRETCH_SUM_NEWTON_STEPS = 5
"""Newton steps of ``principal_stretch_sum`` after its start (four reach round-off for principal
stretches from 1/4 to 4; one more so that the derivatives, which lag a step, do too)."""


def principal_stretch_sum(I1, I2, J):
    """tr U = the sum of the principal stretches, from the invariants (I1, I2, J) of C = F^T F
    (module docstring): the largest root of (a^2 - I1)^2 / 4 - 2 J a - I2, by Newton's iteration
    from the upper bound sqrt(I1 + 2 sqrt(I2 + 2 J sqrt(3 I1))). Works on UFL expressions and
    numbers alike."""
    a = (I1 + 2 * (I2 + 2 * J * (3 * I1) ** 0.5) ** 0.5) ** 0.5
    for _ in range(STRETCH_SUM_NEWTON_STEPS):
        a = a - ((a * a - I1) ** 2 / 4 - 2 * J * a - I2) / (a * (a * a - I1) - 2 * J)
    return a
