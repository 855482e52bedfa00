"""Control Jacobian of rigid indenters: how the targets move per mm of tip travel.

Units: mm of target displacement per mm of push.

At a converged state u(q) of a ReferenceSolver with indenters at tip positions q, the residual
R(u, q) = 0. Moving indenter i by dp along its direction d_i gives

    K du = -(dR/dq_i . d_i) dp,    dx_target = P du,

with K the exact tangent at the state (elasticity and the contact penalty of the active set, the
Dirichlet rows held) and P the probe evaluation. dR/dq_i is the derivative of the assembled
residual with respect to the tip position, taken by a central difference of two residual
assemblies with a step far inside the penalty's smoothing width eps = h_cell / beta (by default
1e-3 eps: a step of the order of eps crosses the kink of nodes near the contact edge, 1e-3
relative error at 0.1 eps, 5 % at eps, on a sphere pressed into a block; the round-off is about
1e-16 |R| / step); everything else is exact. The other indenters
stay where they are, as does every held or glued patch, exactly as the nonlinear solve of a
perturbed push keeps them (``control.jacobian.fd_jacobian`` checks one against the other).
"""
from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from tissue_reference.errors import CaseError
from tissue_reference.model.case import Case

from .mumps import set_mumps_workspace, solve_mumps
from .outputs import probe_values

__all__ = ["indenter_jacobian"]


def indenter_jacobian(solver, case: Case, *, actuators=None, targets=None,
                      h: float | None = None) -> np.ndarray:
    """J (gdim * n_targets, n_actuators), mm per mm, at the solver's current (converged) state
    of ``case`` (the case with the pushes of that state). actuators: indenter names (default:
    every indenter of the case), one column each; targets: probe names (default: all), rows
    T1.x, T1.y, ... as in ``control.jacobian``; h: the difference step (mm; default 1e-3 of
    the indenter's smallest smoothing width)."""
    by_name = {ind.name: ind for ind in solver.contact.indenters}
    names = list(by_name) if actuators is None else list(actuators)
    missing = [n for n in names if n not in by_name]
    if missing:
        raise CaseError(f"{missing} are not indenters of this solver; indenters: {list(by_name)}")
    probes = [p.name for p in case.probes] if targets is None else list(targets)
    x0 = solver.x.x.array.copy()
    bcs = [e[0] for e in solver.boundary.dirichlet_bcs(case, 1.0, None)]
    solver.newton.assemble_tangent(bcs)

    def lu(percent=None):
        k = PETSc.KSP().create(solver.comm)
        k.setOperators(solver.A)
        k.setType("preonly")
        k.getPC().setType("lu")
        k.getPC().setFactorSolverType("mumps")
        set_mumps_workspace(k, percent)
        return k

    ksp = lu()
    rhs = solver.A.createVecRight()
    du = solver.A.createVecRight()
    cols = []
    try:
        for name in names:
            ind = by_name[name]
            q0 = np.array(ind.q.value, float)
            step = h if h is not None else 1e-3 * ind.h_range[0] / ind.beta
            sides = []
            for sign in (1.0, -1.0):
                ind.place(q0 + sign * step * ind.d)
                solver.newton.assemble_residual(bcs)
                sides.append(solver.b.copy())
            ind.place(q0)
            # K du = -(R(q + h d) - R(q - h d)) / (2 h)
            sides[0].axpy(-1.0, sides[1])
            sides[0].copy(rhs)
            rhs.scale(-0.5 / step)
            ksp = solve_mumps(ksp, rhs, du, lu)
            if ksp.getConvergedReason() <= 0:
                raise CaseError(f"indenter {name!r}: the tangent at this state could not be "
                                f"factorized (reason {ksp.getConvergedReason()})")
            owned = du.getArray(readonly=True)
            solver.x.x.array[:len(owned)] = owned
            solver.x.x.scatter_forward()
            solver.state.sync()
            values = probe_values(solver, case, solver.state.vertex_field())
            cols.append(np.concatenate([np.asarray(values[p], float) for p in probes]))
            solver.x.x.array[:] = x0   # back to the state for the next indenter
            solver.x.x.scatter_forward()
            for v in sides:
                v.destroy()
    finally:
        solver.x.x.array[:] = x0
        solver.x.x.scatter_forward()
        solver.state.sync()
        solver.newton.assemble_residual(bcs)
        ksp.destroy()
        rhs.destroy()
        du.destroy()
    return np.stack(cols, axis=1)
