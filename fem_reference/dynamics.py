"""Implicit-Euler dynamics of the reference (seed 000 eq. 5): the ground truth of the ADMM's
dynamic mode (``solvers.admm.ImplicitEuler``).

Each time step n -> n + 1 of ``dt`` (s) minimizes, over the displacement u (mm),

    1/(2 dt^2) (u - u_tilde)^T M (u - u_tilde) + W(u) - f_ext . u,    u_tilde = u_n + dt v_n,

then sets v_{n+1} = (u_{n+1} - u_n) / dt (mm/s). W and f_ext are the reference's energy and
loads (``ReferenceSolver``: Neo-Hookean or linear elasticity, gravity density * g of
``[body] gravity``, tractions), so the equation solved per step is

    M (u - u_tilde) / dt^2 + f_int(u) - f_ext = 0,      units: kg mm / s^2 = mN.

The mass M (kg):
- ``mass="lumped"`` (degree 1): the vertex mass density * V_e / (d + 1) summed over the cells
  around each vertex, assembled as the vector int density phi_a dx (one-point quadrature is
  exact for P1), i.e. the row sums of the consistent P1 mass. This is exactly the ADMM's mass.
  Row sums of P2/P3 masses are not positive at the vertices, so degree >= 2 refuses it.
- ``mass="consistent"`` (any degree, mixed formulation too): int density u . v dx at quadrature
  degree 2 * degree; the pressure of the mixed formulation carries no mass.
The inertia enters the reference's own Newton (``ReferenceSolver.solve`` per time step: PETSc
line search, exact tangent, converged reason checked) as its ``extra_terms``: after
assembly M (u - u_tilde) / dt^2 is added to the residual and M / dt^2 to the tangent (the
Dirichlet rows and columns excluded).

Boundary conditions: the Case's Dirichlet data (with ``pushes``) are applied in full from the
first step, as the ADMM does: the start state u_0 takes the prescribed values at t = 0 and the
prescribed dofs start at rest. ``ramp_steps`` = k > 0 instead moves them linearly from zero,
u_D(t_n) = min(n / k, 1) g (the start state then has zero prescribed values); oblique sliding
values are not ramped. Gravity and tractions act in full from the first step (a suddenly applied
load). Units: mm, kPa, mN, kg, s, kg/mm^3; energies in uJ (= mN mm).

    res = simulate(case, dt=2e-3, steps=50)        # DynamicsResult
    res.probes["T1"][-1], res.kinetic_energy      # mm at t = 50 dt; uJ per step
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from tissue_reference.errors import CaseError, ConvergenceError
from tissue_reference.model.case import Case
from tissue_reference.model.results import DynamicsResult

from .discretization import default_degree, resolve_formulation
from .jit import compile_form
from .kept import solver_for
from .outputs import solve_result

__all__ = ["MASS_KINDS", "DynamicsResult", "simulate"]

MASS_KINDS = ("lumped", "consistent")


class _Inertia:
    """M (u - u_tilde) / dt^2 for the residual and M / dt^2 for the tangent of a reference
    solver's Newton (``ReferenceSolver.solve``'s ``extra_terms``); M in kg, dt in s,
    contributions in mN and mN/mm.

    Parameters
    ----------
    x : dolfinx.fem.Function
        The solver's unknown (on ``W``), whose current value the terms read.
    W : dolfinx.fem.FunctionSpace
        The unknown's space.
    u : UFL expression
        The displacement part of ``x`` (mm).
    gdim, degree : int
        The geometric dimension and the displacement's degree (the consistent mass's
        quadrature: 2 * degree).
    comm : MPI communicator
        The solver's.
    case : Case
        Its density (kg/mm^3).
    dt : float
        The time step (s).
    kind : str
        "lumped" or "consistent" (``MASS_KINDS``).
    """

    def __init__(self, *, x, W, u, gdim: int, degree: int, comm, case: Case, dt: float,
                 kind: str):
        self.x, self.comm, self.kind = x, comm, kind
        self.c = 1.0 / dt ** 2
        mesh = W.mesh
        self.rho = dolfinx.fem.Constant(mesh, PETSc.ScalarType(case.material.density))
        v = ufl.TestFunction(W)
        imap = W.dofmap.index_map
        self.n_own = imap.size_local * W.dofmap.index_map_bs
        self.target = np.zeros(self.n_own)  # u_tilde, owned dofs
        if kind == "lumped":
            dx = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": 1})
            ones = ufl.as_vector([1.0] * gdim)
            self.m = dolfinx.fem.petsc.assemble_vector(
                compile_form(self.rho * ufl.inner(ones, v) * dx))
            self.m.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            self.M = self.M_bc = None
        else:
            dx = ufl.Measure("dx", domain=mesh,
                             metadata={"quadrature_degree": 2 * degree})
            T = self.rho / 2 * ufl.inner(u, u) * dx
            self.M_form = compile_form(ufl.derivative(ufl.derivative(T, x, v), x,
                                                      ufl.TrialFunction(W)))
            self.M = dolfinx.fem.petsc.assemble_matrix(self.M_form)
            self.M.assemble()
            self.M_bc = None  # the tangent's copy without Dirichlet rows and columns
            self.m = None
            self.work = self.M.createVecRight()
            self.work2 = self.M.createVecRight()

    def set_target(self, x_tilde: np.ndarray):
        """u_tilde (mm) as a full local dof array of the solver's unknown."""
        self.target[:] = x_tilde[:self.n_own]

    def energy(self) -> float:
        """(u - u_tilde)^T M (u - u_tilde) / (2 dt^2) (uJ) at the solver's current state, over
        all ranks: the inertia's share of the total energy that a contact line search weighs
        (``fem_reference.contact.Contact.accepts``)."""
        d = self.x.vector.array_r[:self.n_own] - self.target
        if self.m is not None:
            local = float(self.m.array_r @ (d * d))
        else:
            self.work.array_w[:] = d
            self.M.mult(self.work, self.work2)
            local = float(self.work2.array_r @ d)
        return 0.5 * self.c * self.comm.allreduce(local, op=MPI.SUM)

    def add_residual(self, b, bcs):
        d = self.x.vector.array_r[:self.n_own] - self.target
        if self.m is not None:
            b.array_w[:] += self.c * self.m.array_r * d
        else:
            self.work.array_w[:] = d
            self.M.mult(self.work, self.work2)
            b.array_w[:] += self.c * self.work2.array_r

    def add_tangent(self, A, bcs):
        if self.m is not None:
            diag = self.m.copy()
            diag.scale(self.c)
            dolfinx.fem.petsc.set_bc(diag, bcs, scale=0.0)  # Dirichlet rows keep E h_min
            A.setDiagonal(diag, addv=PETSc.InsertMode.ADD_VALUES)
            diag.destroy()
            return
        if self.M_bc is None:
            kind = "baij" if A.getType().endswith("baij") else None
            self.M_bc = dolfinx.fem.petsc.create_matrix(self.M_form, kind)
            dolfinx.fem.petsc.assemble_matrix(self.M_bc, self.M_form, bcs=bcs, diagonal=0.0)
            self.M_bc.assemble()
        A.axpy(self.c, self.M_bc, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)

    def kinetic(self, v: np.ndarray) -> float:
        """v^T M v / 2 (uJ) of a full local dof array v (mm/s)."""
        vo = v[:self.n_own]
        if self.m is not None:
            return 0.5 * self.comm.allreduce(float(self.m.array_r @ (vo * vo)))
        self.work.array_w[:] = vo
        self.M.mult(self.work, self.work2)
        return 0.5 * float(self.work.dot(self.work2))

    def destroy(self):
        for obj in (self.m, self.M, self.M_bc):
            if obj is not None:
                obj.destroy()


def _scaled(case: Case, s: float) -> Case:
    """The Case with its Dirichlet values (displacement, affine, axis-aligned sliding) times s."""
    if s == 1.0:
        return case
    out = []
    for b in case.boundaries:
        if b.type == "displacement":
            b = replace(b, value=tuple((s * np.asarray(b.value, float)).tolist()))
        elif b.type == "affine":
            b = replace(b, gradient=None if b.gradient is None else
                        (s * np.asarray(b.gradient, float)).tolist(),
                        offset=None if b.offset is None else
                        (s * np.asarray(b.offset, float)).tolist())
        elif b.type == "sliding" and b.value:
            b = replace(b, value=s * float(b.value))
        out.append(b)
    return replace(case, boundaries=tuple(out))


def _vertex_dofs(solver, values) -> np.ndarray:
    """A vertex field (n_vertices, gdim) as a full local dof array of the solver's unknown (the
    P1 interpolant at degree >= 2; zero pressure); the solver's state is left unchanged."""
    saved = solver.x.x.array.copy()
    solver.set_state(np.asarray(values, float))
    out = solver.x.x.array.copy()
    if solver.Q is not None:
        out[solver.state.pmap] = 0.0
    solver.x.x.array[:] = saved
    solver.x.x.scatter_forward()
    solver.state.sync()
    return out


def _check(name, value, *, positive=True):
    if not (isinstance(value, (int, float)) and np.isfinite(value) and
            (value > 0 if positive else value >= 0)):
        raise CaseError(f"{name} must be a finite number {'>' if positive else '>='} 0, "
                        f"got {value!r}")


def simulate(case: Case, *, dt: float, steps: int, pushes=None, initial=None,
             initial_velocity=None, degree: int | None = 1, mass: str = "lumped",
             ramp_steps: int = 0, progress: bool = False, **solver_options) -> DynamicsResult:
    """``steps`` implicit-Euler steps of ``dt`` (s) with the reference (module docstring).

    pushes: actuator name -> push (mm), applied with ``case.with_pushes``.
    initial: start displacement (mm): (n_vertices, gdim), or a SolveResult of a reference solve
        on this mesh (degree 2: its nodal state); default rest. Its prescribed dofs are replaced
        by the boundary values at t = 0.
    initial_velocity: (n_vertices, gdim) mm/s (the P1 interpolant at degree >= 2), zero on the
        prescribed dofs; default rest.
    degree: Lagrange degree of the displacement (1, 2 or 3); mass: "lumped" (degree 1, the
        ADMM's vertex mass) or "consistent".
    ramp_steps: 0 (default): Dirichlet values in full from the first step; k > 0: ramped
        linearly over the first k steps.
    solver_options: ReferenceSolver options (formulation, settings, linear_solver, ...).
    Raises CaseError on bad arguments and ConvergenceError (``last_converged``: the state
    before the failing step; ``trajectory``: the DynamicsResult up to it) when a step fails.
    """
    t_start = time.perf_counter()
    _check("dt (s)", dt)
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise CaseError(f"steps must be an integer >= 1, got {steps!r}")
    if isinstance(ramp_steps, bool) or not isinstance(ramp_steps, (int, np.integer)) or \
            ramp_steps < 0:
        raise CaseError(f"ramp_steps must be an integer >= 0, got {ramp_steps!r}")
    if mass not in MASS_KINDS:
        raise CaseError(f"mass must be one of {list(MASS_KINDS)}, got {mass!r}")
    _check("material density (kg/mm^3)", float(case.material.density), positive=False)
    case = case.with_pushes(pushes)   # idle patches held unless the Case frees them
    formulation = resolve_formulation(solver_options.get("formulation", "auto"), case.material)
    if degree is None:
        degree = default_degree(case, formulation)
    if mass == "lumped" and degree != 1:
        raise CaseError(f"mass='lumped' is the P1 vertex mass (row sums of the consistent mass); "
                        f"at degree {degree} row sums are not positive at the vertices: "
                        f"use mass='consistent'")
    solver = solver_for(case, degree, **solver_options)
    n, d = case.mesh.n_vertices, case.mesh.gdim
    if initial_velocity is not None:
        initial_velocity = np.asarray(initial_velocity, float)
        if initial_velocity.shape != (n, d) or not np.all(np.isfinite(initial_velocity)):
            raise CaseError(f"initial_velocity must be a finite (n_vertices, gdim) = {(n, d)} "
                            f"array (mm/s), got shape {initial_velocity.shape}")

    def case_at(k):
        return _scaled(case, min(k / ramp_steps, 1.0)) if ramp_steps else case

    inertia = _Inertia(x=solver.x, W=solver.W, u=solver.u_ufl, gdim=solver.gdim,
                       degree=solver.degree, comm=solver.comm, case=case, dt=float(dt), kind=mass)
    try:
        # start state: initial (or rest) with the prescribed values of t = 0
        case0 = case_at(0)
        solver.set_material(case.material)
        solver.set_load_fraction(1.0)
        solver.x.x.array[:] = 0.0
        if initial is not None:
            solver.set_state(initial)
        prescribed = np.zeros(len(solver.x.x.array), bool)
        for _, g, parent, coll in solver.boundary.dirichlet_bcs(case0, 1.0):
            solver.x.x.array[parent] = g.x.array[coll]
            prescribed[parent] = True
        solver.x.x.scatter_forward()
        solver.state.sync()
        solver.state.x_from_fields()
        x = solver.x.x.array.copy()
        v = np.zeros_like(x) if initial_velocity is None else _vertex_dofs(solver,
                                                                           initial_velocity)
        v[prescribed] = 0.0
        state = solve_result(solver, case0, True, 0, 0.0, 0.0, 0, {}, 0.0)
        us = [state.u]
        vel = [np.zeros((n, d)) if initial_velocity is None else
               np.where(_prescribed_vertices(solver, case0), 0.0, initial_velocity)]
        probes = {k: [np.asarray(p, float)] for k, p in state.probes.items()}
        kin, strain = [inertia.kinetic(v)], [state.strain_energy]
        conv, its = [], []
        total_mass = _total_mass(solver, inertia.rho)

        def partial(final):
            return DynamicsResult(
                times=dt * np.arange(len(us)), u=np.array(us), velocity=np.array(vel),
                probes={k: np.array(p) for k, p in probes.items()},
                kinetic_energy=np.array(kin), strain_energy=np.array(strain),
                converged=np.array(conv, bool), iterations=np.array(its, int),
                wall_time_s=time.perf_counter() - t_start, dt=float(dt), mass=mass,
                degree=solver.degree, total_mass_kg=total_mass,
                final=final, case_name=case.name,
                extra={"ramp_steps": int(ramp_steps),
                       "discretization": solver.discretization()})

        for k in range(1, steps + 1):
            inertia.set_target(x + dt * v)
            case_k = case_at(k)
            try:
                res = solver.solve(None, case=case_k, initial=state, progress=False,
                                   extra_terms=inertia)
            except ConvergenceError as exc:
                err = ConvergenceError(
                    f"{case.source or case.name}: implicit-Euler step {k}/{steps} "
                    f"(t = {k * dt:g} s) did not converge: {exc}",
                    load_fraction=(k - 1) / steps, last_converged=state,
                    trajectory=partial(state))
                raise err from None
            xn = solver.x.x.array.copy()
            v = (xn - x) / dt
            x = xn
            vel.append((res.u - us[-1]) / dt)
            us.append(res.u)
            for name, p in res.probes.items():
                probes[name].append(np.asarray(p, float))
            kin.append(inertia.kinetic(v))
            strain.append(res.strain_energy)
            conv.append(bool(res.converged))
            its.append(int(res.iterations))
            state = res
            if progress and solver.comm.rank == 0:
                print(f"tissue fem dynamics: step {k}/{steps} t = {k * dt:.4g} s, "
                      f"{res.iterations} Newton iterations, max |v| "
                      f"{np.sqrt((vel[-1] ** 2).sum(axis=1)).max():.3e} mm/s, kinetic "
                      f"{kin[-1]:.3e} uJ", file=sys.stderr, flush=True)
        return partial(state)
    finally:
        inertia.destroy()


def _prescribed_vertices(solver, case) -> np.ndarray:
    """(n_vertices, gdim) mask of the vertex dofs the Case prescribes (axis-aligned)."""
    mask = np.zeros(case.mesh.n_vertices * case.mesh.gdim, bool)
    mask[case.constraints.dofs] = True
    return mask.reshape(case.mesh.n_vertices, case.mesh.gdim)


def _total_mass(solver, rho) -> float:
    """int density dx (kg)."""
    dx = ufl.Measure("dx", domain=solver.dm.mesh)
    return solver.comm.allreduce(
        dolfinx.fem.assemble_scalar(compile_form(rho * dx)), op=MPI.SUM)
