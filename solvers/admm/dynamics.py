"""Implicit-Euler dynamics of the ADMM solver (seed eq. 5): every time step minimizes
1/(2 dt^2) |u - u_tilde|_M^2 + U(u) - f_ext . u with u_tilde = u + dt v (lumped mass
density * V / (d+1) per vertex, kg): the x-step matrix gains M/dt^2 and its right-hand side
M u_tilde/dt^2. Boundary values are applied at full load from the first step."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tissue_reference.errors import CaseError

from .mechanics import as_u


@dataclass(frozen=True)
class ImplicitEuler:
    """Implicit-Euler dynamics (seed eq. 5): ``steps`` steps of ``dt`` (s), lumped mass
    density * V / (d+1) (kg), initial velocity ``velocity`` (mm/s, (n, gdim)) or zero.
    Boundary values are applied at full load from the first step."""

    dt: float
    steps: int = 1
    velocity: object = None

    def __post_init__(self):
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise CaseError(f"ImplicitEuler dt must be > 0 s, got {self.dt!r}")
        if int(self.steps) < 1:
            raise CaseError(f"ImplicitEuler steps must be >= 1, got {self.steps!r}")


def implicit_euler(case, ops, dynamics, u, up, fext, *, admm_step, newton_step, polish,
                    polish_tol_mm, hist):
    """The time steps from displacement u (mm, node-major): each one an ADMM solve
    ``admm_step(up, rhs_extra, u, it0) -> (u, iterations, converged)`` and, with ``polish``, a
    Newton polish ``newton_step(u, fext, inertia, it0) -> (u, iterations)``. Returns
    (u, v, probe trajectory, ADMM iterations, Newton iterations, converged)."""
    dt = dynamics.dt
    v = np.zeros(ops.N) if dynamics.velocity is None else as_u(case, dynamics.velocity).copy()
    mdt = ops.mass / dt ** 2
    u = up + ops.red.Z @ (ops.red.ZT @ (u - up))
    traj = []
    admm_it = newton_it = 0
    converged = True
    for _ in range(int(dynamics.steps)):
        ut = u + dt * v
        inertia = (mdt, ut)
        un, k, conv = admm_step(up, fext + mdt * ut, u, admm_it + newton_it)
        admm_it += k
        if polish:
            un, kn = newton_step(un, fext, inertia, admm_it + newton_it)
            newton_it += kn
            conv = hist["newton_step_mm"][-1] < polish_tol_mm
        converged = converged and conv
        v = (un - u) / dt
        u = un
        traj.append({k_: np.asarray(val).tolist() for k_, val in case.probe_values(u).items()})
    return u, v, traj, admm_it, newton_it, converged
