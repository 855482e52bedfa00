"""``solve``: the ADMM solve of a Case. Quasi-static equilibrium in load steps of at most
``step_mm`` (each: boundary moved, interior carried along by the tangent or harmonic lift, ADMM,
then the Newton polish), or implicit-Euler dynamics (``dynamics``); the result with reactions,
energy, deformation state and the iteration history."""
from __future__ import annotations

import time

import numpy as np

from tissue_reference.meshes.errors import CaseError, SolverDivergedError
from tissue_reference.meshes.mesh import deformation_state
from tissue_reference.meshes.results import SolveResult

from .backends import backend, require_device
from .dynamics import ImplicitEuler, _implicit_euler
from .loop import _admm, _check_J
from .mechanics import _as_u
from .operators import _particular, _vertex_norm_max, prepare
from .polish import _newton, _residual, _tangent_lift


def solve(case, *, pushes=None, initial=None, tol_mm: float = 1e-4, max_iter: int | None = None,
          rho: float | None = None, polish: bool = True, polish_tol_mm: float | None = None,
          polish_max_iter: int = 25, dynamics: ImplicitEuler | None = None, callback=None,
          load_steps: int | None = None, step_mm: float = 3.0,
          intermediate_tol_mm: float = 1e-2, lift="auto", handoff_mm: float = 1e-2,
          progress: bool = False, factorize=None, device: str = "cpu") -> SolveResult:
    """ADMM solve of a Case (quasi-static equilibrium, or implicit-Euler dynamics).

    pushes: actuator name -> push (mm), applied with ``case.with_pushes``.
    initial: warm-start displacement (mm, (n_vertices, gdim)); its prescribed part is replaced by
        the Case's boundary values (exact), its stress initializes the ADMM dual.
    tol_mm: stopping tolerance (mm) on the primal and dual residuals (see ``loop``).
    rho: ADMM penalty stiffness (kPa), w_e^2 = rho V_e; default see the package docstring.
    max_iter: ADMM iterations per load step (per time step); default 20000 without polish, 20
        with it.
    polish: finish with Newton steps on the same P1 energy until the largest step is below
        ``polish_tol_mm`` (default tol_mm / 100). ADMM then only has to bring each step into
        Newton's basin: it stops at max(tol, ``handoff_mm``) (mm) or after ``max_iter``
        iterations, whichever comes first.
    dynamics: ImplicitEuler(dt, steps) for dynamics; None for quasi-static equilibrium.
    load_steps: quasi-static increments (default: the prescribed change from the start state
        divided in steps of at most ``step_mm``, mm); intermediate steps stop at
        ``intermediate_tol_mm`` (mm) (and, with ``polish``, are Newton-polished).
    lift: True: carry the interior along with each boundary increment by one linear solve with
        the tangent at the current state (K_ff du_f = -K_fc du_c); False: the x-step matrix's
        harmonic extension (free, already factorized); "auto" (default): the tangent lift when
        a load step moves the boundary by more than 1 mm. Counted in ``extra["lift_solves"]``.
    callback(it, u): called after every iteration (ADMM, then polish) with u (mm, (n, gdim)).
    factorize(A, cache): factorization of the polish's and lift's symmetric tangents with a
        ``solve(b)`` method, or None for SuperLU (the default); ``fem_reference.cholmod_factor``
        (CHOLMOD through PETSc, which this module does not import) is ~3x faster on the phantom
        and is what ``tissue solve`` / ``tissue verify`` pass.
    device: where the ADMM iterations run: "cpu" (default, the compiled kernel) or "gpu" (CuPy,
        the optional extra ``gpu``; GpuUnavailableError when there is no CuPy or no GPU); see
        ``backends`` (also for "array-cpu", the GPU code on numpy). Recorded in
        ``extra["device"]``; the array backends also report ``extra["xstep_cg_iterations"]``.
    Raises SolverDivergedError (iteration and element named) on NaN, inverted elements or
    residual growth.
    """
    t0 = time.perf_counter()
    require_device(device)
    case.require_no_contact("the ADMM solver")
    case0 = case  # same mesh: its cached probe locations serve the pushed Case too
    case = case.with_pushes(pushes)   # idle patches held unless the Case frees them
    if not (np.isfinite(tol_mm) and tol_mm > 0):
        raise CaseError(f"tol_mm must be > 0 mm, got {tol_mm!r}")
    if max_iter is None:
        max_iter = 20 if polish else 20000
    if int(max_iter) < 1:
        raise CaseError(f"max_iter must be >= 1, got {max_iter!r}")
    if polish_tol_mm is None:
        polish_tol_mm = tol_mm / 100.0
    dt = dynamics.dt if dynamics is not None else None

    ops = prepare(case, rho=rho, dt=dt, factor=device == "cpu")
    be = backend(ops, device)
    up = _particular(case, ops)
    fext = case.external_forces(1.0)
    n, d = ops.n, ops.d
    if initial is None:
        u = np.zeros(ops.N)
    else:
        u = _as_u(case, initial).copy()
        _check_J(ops, ops.grad(u), 0, "the initial (warm-start) state")
    hist = {"primal": [], "dual": [], "max_step_mm": [], "newton_step_mm": [],
            "admm_clock_s": []}

    def admm_step(up_j, rhs_extra, u_j, it0, tol=tol_mm):
        return _admm(ops, up_j, rhs_extra, u_j, tol_mm=max(tol, handoff_mm) if polish else tol,
                     max_iter=int(max_iter), callback=callback, it0=it0, progress=progress,
                     hist=hist, be=be)

    def newton_step(u_j, f, inertia, it0, tol=polish_tol_mm):
        return _newton(ops, u_j, f, inertia, tol_mm=tol, max_iter=polish_max_iter, it0=it0,
                       hist=hist, callback=callback, factorize=factorize)

    restarts = []
    extra = {}
    if dynamics is None:
        u, load_steps, admm_it, newton_it, converged, lifts = _load_steps(
            case, ops, u, up, fext, admm_step=admm_step, newton_step=newton_step,
            polish=polish, polish_tol_mm=polish_tol_mm, load_steps=load_steps, step_mm=step_mm,
            intermediate_tol_mm=intermediate_tol_mm, tol_mm=tol_mm, lift=lift,
            factorize=factorize, hist=hist, restarts=restarts)
    else:
        lifts = 0
        u, v, traj, admm_it, newton_it, converged = _implicit_euler(
            case, ops, dynamics, u, up, fext, admm_step=admm_step, newton_step=newton_step,
            polish=polish, polish_tol_mm=polish_tol_mm, hist=hist)
        extra = {"dt_s": dt, "steps": int(dynamics.steps), "probe_trajectory": traj,
                 "velocity": v.reshape(n, d)}
    H = ops.grad(u)
    _check_J(ops, H, admm_it + newton_it, "the final state")
    r = _residual(ops, u, fext, None)
    free_res = float(np.abs(ops.red.ZT @ r).max(initial=0.0))
    reactions = _reactions(case, r)
    psi, _ = ops.law.psi_J(H)
    extra = {"admm_iterations": int(admm_it), "newton_iterations": int(newton_it),
             "load_steps": int(load_steps) if dynamics is None else 0,
             "rho_kPa": ops.rho, "setup_s": ops.setup_s, "tol_mm": tol_mm,
             "polish_restarts": restarts, "lift_solves": lifts,
             **deformation_state(case.mesh, u.reshape(n, d)), **extra, "device": device}
    if be.cg_iterations is not None:
        extra["xstep_cg_iterations"] = int(be.cg_iterations)
    hist["admm_clock_s"] = [c - t0 for c in hist["admm_clock_s"]]
    u2 = u.reshape(n, d)
    return SolveResult(u=u2, converged=bool(converged), iterations=int(admm_it + newton_it),
                       residual=free_res, wall_time_s=time.perf_counter() - t0, solver="admm",
                       probes=case0.probe_values(u2), reactions=reactions,
                       strain_energy=float(ops.kin.V @ psi), case_name=case.name, n_vertices=n,
                       load_steps=int(load_steps) if dynamics is None else int(dynamics.steps),
                       n_cells=ops.m, history=hist, extra=extra)


def _load_steps(case, ops, u, up, fext, *, admm_step, newton_step, polish, polish_tol_mm,
                load_steps, step_mm, intermediate_tol_mm, tol_mm, lift, factorize, hist,
                restarts):
    """Quasi-static equilibrium: the prescribed change from the start state split in increments
    of at most step_mm (mm); each step is an ADMM solve warm-started from the previous one, then
    (``polish``) Newton. Returns (u, load steps, ADMM iterations, Newton iterations, converged,
    tangent lifts); polish restarts are appended to ``restarts``."""
    d = ops.d
    admm_it = newton_it = lifts = 0
    converged = True
    uc = u - ops.red.Z @ (ops.red.ZT @ u)
    jump = _vertex_norm_max(up - uc, d)
    if not np.isfinite(jump):
        raise CaseError(f"{case.source or case.name}: the prescribed displacements are too "
                        f"large to be represented (|u| overflows)")
    if load_steps is None:
        load_steps = max(1, int(np.ceil(jump / step_mm)))
    for j in range(1, int(load_steps) + 1):
        s = j / load_steps
        last = j == load_steps
        tol_j = tol_mm if last else max(tol_mm, intermediate_tol_mm)
        up_j = uc + s * (up - uc)
        if lift is True or (lift == "auto" and jump / load_steps > 1.0):
            u = _tangent_lift(ops, u, up_j, admm_it + newton_it, factorize)
            lifts += 1
        u_start = u
        u, k, converged = admm_step(up_j, s * fext, u, admm_it + newton_it, tol_j)
        admm_it += k
        if polish:
            ptol = polish_tol_mm if last else max(polish_tol_mm, tol_j)
            try:
                u, kn = newton_step(u, s * fext, None, admm_it + newton_it, ptol)
            except SolverDivergedError as exc:
                # the unconverged ADMM state left Newton's basin: restart the polish from the
                # step's start state (reported in extra["polish_restarts"]), carried to this
                # step's boundary values first (without a lift it still has the previous
                # step's, which Newton would keep: it moves free dofs only)
                restarts.append(f"load step {j}: {exc}")
                u_start = _tangent_lift(ops, u_start, up_j, admm_it + newton_it, factorize)
                u, kn = newton_step(u_start, s * fext, None, admm_it + newton_it, ptol)
            newton_it += kn
            if last:
                converged = hist["newton_step_mm"][-1] < polish_tol_mm
    return u, load_steps, admm_it, newton_it, converged, lifts


def _reactions(case, r):
    """Region -> (gdim,) sum of r = f_int - f_ext (mN) over the region's prescribed dofs
    (oblique sliding regions: over all dofs of their vertices)."""
    d = case.mesh.gdim
    c = case.constraints
    out = case.prescribed_reactions(r)
    R = r.reshape(-1, d)
    for b in case.boundaries:
        if b.type == "sliding":
            for verts, nrm, _ in c.sliding:
                if np.array_equal(np.sort(verts), case.mesh.region_vertices(b.region)):
                    out[b.region] = out[b.region] + R[verts].sum(axis=0)
    return out
