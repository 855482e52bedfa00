"""``solve``: the ADMM solve of a Case. Quasi-static equilibrium in load steps of at most
``step_mm`` (each: boundary moved, interior carried along by the tangent or harmonic lift, ADMM,
then the Newton polish), or implicit-Euler dynamics (``dynamics``); the result with reactions,
energy, deformation state and the iteration history."""
from __future__ import annotations

import functools
import time

import numpy as np

from tissue_reference.meshes.errors import CaseError, SolverDivergedError
from tissue_reference.meshes.mesh import deformation_state
from tissue_reference.meshes.results import SolveResult
from tissue_reference.meshes.tips import through_surface_state

from .backends import backend, require_device
from .chord import chord
from .dynamics import ImplicitEuler, implicit_euler
from .loop import check_J, run_admm
from .mechanics import as_u
from .operators import particular, prepare, vertex_norm_max
from .polish import energy_gradient, newton, rest_factor, tangent_lift


def solve(case, *, pushes=None, initial=None, tol_mm: float = 1e-4, max_iter: int | None = None,
          rho: float | None = None, polish: bool | str = True, polish_tol_mm: float | None = None,
          polish_max_iter: int = 25, dynamics: ImplicitEuler | None = None, callback=None,
          load_steps: int | None = None, step_mm: float = 3.0,
          intermediate_tol_mm: float = 1e-2, lift="auto", handoff_mm: float | None = None,
          tip_step: float = 0.5,
          progress: bool = False, factorize=None, device: str = "cpu",
          contact_quadrature=None, contact_penalty: float | None = None,
          tip_start: str | None = None, initial_pushes: dict | None = None,
          anderson: int = 0) -> SolveResult:
    """ADMM solve of a Case (quasi-static equilibrium, or implicit-Euler dynamics).

    pushes: actuator name -> push (mm), applied with ``case.with_pushes``.
    initial: warm-start displacement (mm, (n_vertices, gdim)), or a SolveResult (its ``u``, and
        with indenters its tips' pushes, where the tips then start); its prescribed part is
        replaced by the Case's boundary values (exact), its stress initializes the ADMM dual.
        With indenters and a bare array the tips start from ``initial_pushes`` (name -> mm,
        the pushes the warm state was solved at), else from push 0.
    tol_mm: stopping tolerance (mm) on the primal and dual residuals (see ``loop``).
    rho: ADMM penalty stiffness (kPa), w_e^2 = rho V_e; default see the package docstring.
    max_iter: ADMM iterations per load step (per time step); default 20000 without polish, 20
        with it.
    polish: finish with Newton steps on the same P1 energy until the largest step is below
        ``polish_tol_mm`` (default tol_mm / 100). ADMM then only has to bring each step into
        Newton's basin: it stops at max(tol, ``handoff_mm``) (mm; default 1e-2) or after
        ``max_iter`` iterations, whichever comes first. "chord": finish with chord steps
        instead, on the tangent at rest factorized once (kept with the operators) and mixed by
        Anderson (``chord``), until the largest step is below ``polish_tol_mm`` (default
        tol_mm: the steps converge linearly, so a step that small means an error about that
        size, where one more Newton step would square it); ADMM hands over at ``handoff_mm``
        (default 0.1 mm), the whole change is tried in one load step first (the load steps
        below where it fails: listed in ``extra["polish_restarts"]``), and where the chord
        steps diverge the Newton polish takes over from their best iterate (listed in
        ``extra["chord_fallbacks"]``). With rigid tips the chord matrix adds the contact
        Hessian (without the tips' curvature) of the points in contact, factorized anew as
        they change or the steps stop contracting (``chord``; counted in
        ``extra["chord_refactorizations"]``). Quasi-static solves only (dynamics is refused).
    dynamics: ImplicitEuler(dt, steps) for dynamics; None for quasi-static equilibrium.
    load_steps: quasi-static increments (default: the prescribed change from the start state
        divided in steps of at most ``step_mm``, mm, that move no tip by more than ``tip_step``
        of its radius); intermediate steps stop at
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
    anderson: Anderson acceleration of the ADMM iterations with this many past iterates
        (``loop.Anderson``); 0 (default): the seed's plain ADMM.
    contact_quadrature, contact_penalty, tip_start: the rigid tips' contact (frictionless
        indenters, ``contact``): the rule ("nodal" or a Gauss degree), beta and where the tips
        start, each by default the case's own as the reference takes it
        (``meshes.tips.default_contact_rule`` and ``default_tip_start``; beta
        ``meshes.tips.DEFAULT_CONTACT_PENALTY``): the same discrete energy as the P1 reference.
        Each tip is reported in ``SolveResult.indenters`` as the reference reports it.
    ``SolveResult.warnings``: one line per pushed glued patch past the range where its answer
    converges or with its rim cells crushed (``Case.glued_patch_warnings``), as the reference's.
    Raises SolverDivergedError (iteration and element named) on NaN, inverted elements or
    residual growth.

    Parameters
    ----------
    case : Case
        The problem: P1 mesh (mm), material (kPa), boundaries, probes and actuators.
    pushes : dict or None
        Actuator name -> push (mm).
    initial : array_like or SolveResult or None
        Warm start (mm, (n_vertices, gdim)) or an earlier answer, as above; None: rest.
    tol_mm : float
        Stopping tolerance (mm) on the primal and dual residuals.
    max_iter : int or None
        ADMM iterations per load step (per time step); None: 20 with the polish, else 20000.
    rho : float or None
        ADMM penalty stiffness (kPa); None: the P-wave modulus lambda + 2 mu.
    polish : bool or str
        True: the Newton polish; "chord": the chord polish; False: ADMM alone (as above).
    polish_tol_mm : float or None
        Largest polish step (mm) that ends it; None: tol_mm / 100 (Newton) or tol_mm (chord).
    polish_max_iter : int
        Newton polish iterations per load step.
    dynamics : ImplicitEuler or None
        ImplicitEuler(dt in s, steps) for dynamics; None: quasi-static equilibrium.
    callback : callable or None
        callback(it, u) after every iteration, u (mm, (n, gdim)).
    load_steps : int or None
        Quasi-static increments; None: from ``step_mm`` and ``tip_step``.
    step_mm : float
        Largest prescribed-displacement change of one load step (mm).
    intermediate_tol_mm : float
        Stopping tolerance (mm) of the load steps before the last.
    lift : bool or str
        True, False or "auto": how the interior follows each boundary increment (as above).
    handoff_mm : float or None
        Residual (mm) at which ADMM hands over to the polish; None: 0.01 (Newton), 0.1 (chord).
    tip_step : float
        Largest move of a rigid tip in one load step, as a fraction of its radius.
    progress : bool
        Print a line per load step.
    factorize : callable or None
        factorize(A, cache) -> an object with ``solve(b)``; None: SuperLU.
    device : str
        "cpu" (default), "gpu" or "array-cpu" (``backends``).
    contact_quadrature : str or int or None
        The rigid tips' contact rule: "nodal" or a Gauss degree; None: the case's.
    contact_penalty : float or None
        beta of the contact penalty k = beta E / h (kPa/mm); None: the case's default.
    tip_start : str or None
        Where each tip starts: "nodes" or "surface"; None: the case's default.
    initial_pushes : dict or None
        Name -> push (mm) that a bare-array warm start was solved at (tips start there).
    anderson : int
        Past iterates of the Anderson acceleration; 0: plain ADMM.

    Returns
    -------
    SolveResult
        solver "admm": ``u`` (mm), ``probes`` (mm), ``reactions`` (mN), ``strain_energy`` (uJ),
        the iteration counts in ``extra``, ``history["admm_clock_s"]`` (s), ``warnings``.

    Raises
    ------
    SolverDivergedError
        On NaN, inverted elements or residual growth (iteration and element named).
    CaseError
        For a ``tol_mm`` or ``max_iter`` out of range, a ``polish`` other than True, False or
    "chord", a chord polish in dynamics, or pushes too large to lift.
    GpuUnavailableError
        For ``device="gpu"`` without CuPy or a GPU.
    """
    t0 = time.perf_counter()
    require_device(device)
    case0 = case  # same mesh: its cached probe locations serve the pushed Case too
    case = case.with_pushes(pushes)   # idle patches held unless the Case frees them
    if not (np.isfinite(tol_mm) and tol_mm > 0):
        raise CaseError(f"tol_mm must be > 0 mm, got {tol_mm!r}")
    if max_iter is None:
        max_iter = 20 if polish else 20000
    if int(max_iter) < 1:
        raise CaseError(f"max_iter must be >= 1, got {max_iter!r}")
    if polish not in (True, False, "chord"):
        raise CaseError(f"polish must be True, False or 'chord', got {polish!r}")
    use_chord = polish == "chord"
    if polish_tol_mm is None:
        polish_tol_mm = tol_mm if use_chord else tol_mm / 100.0
    if handoff_mm is None:
        handoff_mm = 0.1 if use_chord else 1e-2
    if use_chord and dynamics is not None:
        raise CaseError(f"{case.source or case.name}: polish='chord' is for quasi-static solves "
                        f"(its tangent at rest has no inertia): use polish=True")
    dt = dynamics.dt if dynamics is not None else None

    contact = {k: v for k, v in (("rule", contact_quadrature), ("penalty", contact_penalty),
                                 ("tip_start", tip_start)) if v is not None}
    ops = prepare(case, rho=rho, dt=dt, factor=device == "cpu", contact=contact)
    cset = ops.contact
    push1 = cset.pushes_of(case) if cset is not None else None
    push0 = None if cset is None else _start_pushes(cset, initial, initial_pushes)
    if isinstance(initial, SolveResult):
        initial = initial.u
    be = backend(ops, device)
    up = particular(case, ops)
    fext = case.external_forces(1.0)
    n, d = ops.n, ops.d
    if initial is None:
        u = np.zeros(ops.N)
    else:
        u = as_u(case, initial).copy()
        check_J(ops, ops.grad(u), 0, "the initial (warm-start) state")
    hist = {"primal": [], "dual": [], "max_step_mm": [], "newton_step_mm": [],
            "admm_clock_s": []}

    def tips_at(s):
        """The tips' ends at the contact points at load fraction s (None without tips)."""
        return None if cset is None else cset.origins(push0 + s * (push1 - push0))

    def admm_step(up_j, rhs_extra, u_j, it0, tol=tol_mm, s=1.0):
        return run_admm(ops, up_j, rhs_extra, u_j, tol_mm=max(tol, handoff_mm) if polish else tol,
                     max_iter=int(max_iter), callback=callback, it0=it0, progress=progress,
                     hist=hist, be=be, tips=tips_at(s), anderson=anderson)

    @functools.cache
    def rest_pair():
        """The tangent at rest and its factorization, once per solve (kept with ops when small)."""
        return rest_factor(ops, factorize)

    fallbacks = []
    chord_steps = [0]
    chord_stats = {"refactorizations": 0}

    def newton_step(u_j, f, inertia, it0, tol=polish_tol_mm, s=1.0):
        k = 0
        if use_chord:
            u_j, k, ok = chord(ops, u_j, f, rest_pair()[1], tol_mm=tol, max_iter=polish_max_iter,
                               it0=it0, hist=hist, callback=callback, tips=tips_at(s),
                               factorize=factorize, stats=chord_stats)
            chord_steps[0] += k
            if ok:
                return u_j, k
            fallbacks.append(f"load fraction {s:.4g}: chord steps did not converge in {k}; "
                             f"Newton polish from their best iterate")
        u_j, kn = newton(ops, u_j, f, inertia, tol_mm=tol, max_iter=polish_max_iter, it0=it0 + k,
                         hist=hist, callback=callback, factorize=factorize, tips=tips_at(s))
        return u_j, k + kn

    restarts = []
    extra = {}
    if dynamics is None:
        def stepped(u0, steps, cut_back=True):
            return _load_steps(
                case, ops, u0, up, fext, admm_step=admm_step, newton_step=newton_step,
                polish=bool(polish), polish_tol_mm=polish_tol_mm, load_steps=steps,
                step_mm=step_mm, intermediate_tol_mm=intermediate_tol_mm, tol_mm=tol_mm,
                lift=lift, factorize=factorize, hist=hist, restarts=restarts,
                tip_travel=0.0 if cset is None else float(np.max(
                    np.abs(push1 - push0) / np.array([t.shape.radius for t in cset.tips])
                    * step_mm / tip_step, initial=0.0)),
                tips_at=tips_at, cut_back=cut_back, rest=rest_pair if use_chord else None)

        one = None
        if use_chord and load_steps is None:
            # the chord polish tries the whole change in one load step (its lift from rest is a
            # back-substitution; a later step's lift would factorize), and takes the load
            # steps of ``step_mm`` where that fails
            try:
                one = stepped(u, 1, cut_back=False)
                if not one[4]:
                    raise SolverDivergedError("not converged")
            except SolverDivergedError as exc:
                restarts.append(f"one load step: {exc}; load steps of {step_mm:g} mm")
                one = None
        u, load_steps, admm_it, newton_it, converged, lifts = one or stepped(u, load_steps)
        if use_chord:   # every iteration, the failed one-step attempt's included; the chord
            # steps apart from the Newton polish's
            admm_it = len(hist["primal"])
            newton_it = len(hist["newton_step_mm"]) - chord_steps[0]
    else:
        lifts = 0
        u, v, traj, admm_it, newton_it, converged = implicit_euler(
            case, ops, dynamics, u, up, fext, admm_step=admm_step, newton_step=newton_step,
            polish=polish, polish_tol_mm=polish_tol_mm, hist=hist)
        extra = {"dt_s": dt, "steps": int(dynamics.steps), "probe_trajectory": traj,
                 "velocity": v.reshape(n, d)}
    H = ops.grad(u)
    check_J(ops, H, admm_it + newton_it, "the final state")
    # the numpy laws' energy and stress at u from one evaluation
    values = None if ops.law.kernel else ops.law.evaluate(H, tangent=False)
    r = energy_gradient(ops, u, fext, None, tips_at(1.0), values)
    free_res = float(np.abs(ops.red.ZT @ r).max(initial=0.0))
    reactions = region_reactions(case, r)
    psi = values.psi if values is not None else ops.law.psi_J(H)[0]
    state = deformation_state(case.mesh, u.reshape(n, d))
    indenters = {}
    if cset is not None:
        indenters = cset.report(u, push1)
        state = through_surface_state(state, {"indenters": indenters})
    valid, invalid_reason = state.pop("valid"), state.pop("invalid_reason")
    min_J = state.pop("min_J")
    extra = {"admm_iterations": int(admm_it), "newton_iterations": int(newton_it),
             "load_steps": int(load_steps) if dynamics is None else 0,
             "rho_kPa": ops.rho, "setup_s": ops.setup_s, "tol_mm": tol_mm,
             "polish_restarts": restarts, "lift_solves": lifts,
             **({"polish": "chord", "chord_iterations": chord_steps[0],
                 "chord_refactorizations": chord_stats["refactorizations"],
                 "chord_fallbacks": fallbacks} if use_chord else {}),
             **state, **extra, "device": device}
    if be.cg_iterations is not None:
        extra["xstep_cg_iterations"] = int(be.cg_iterations)
    hist["admm_clock_s"] = [c - t0 for c in hist["admm_clock_s"]]
    u2 = u.reshape(n, d)
    return SolveResult(u=u2, converged=bool(converged),
                       iterations=int(admm_it + newton_it + chord_steps[0]),
                       residual=free_res, wall_time_s=time.perf_counter() - t0, solver="admm",
                       probes=case0.probe_values(u2), reactions=reactions,
                       strain_energy=float(ops.kin.V @ psi), case_name=case.name, n_vertices=n,
                       load_steps=int(load_steps) if dynamics is None else int(dynamics.steps),
                       n_cells=ops.m, history=hist, valid=valid, invalid_reason=invalid_reason,
                       min_J=min_J, indenters=indenters, extra=extra,
                       warnings=case.glued_patch_warnings(u2))


MIN_LOAD_STEP = 1.0 / 64  # the shortest increment a cut-back makes, as a fraction of a step


def _start_pushes(cset, initial, pushes=None) -> np.ndarray:
    """Where the tips start (mm, in tip order): the pushes a SolveResult ``initial`` reports,
    else ``pushes`` (name -> mm), else 0."""
    out = np.zeros(len(cset.tips))
    if isinstance(initial, SolveResult):
        pushes = {n: r.get("push", 0.0) for n, r in initial.indenters.items()}
    if initial is not None and pushes:
        for i, t in enumerate(cset.tips):
            out[i] = float(pushes.get(t.name, 0.0))
    return out


def _load_steps(case, ops, u, up, fext, *, admm_step, newton_step, polish, polish_tol_mm,
                load_steps, step_mm, intermediate_tol_mm, tol_mm, lift, factorize, hist,
                restarts, tip_travel=0.0, tips_at=lambda s: None, cut_back=True, rest=None):
    """Quasi-static equilibrium: the prescribed change from the start state (and the tips'
    travel, ``tip_travel``: scaled so that step_mm is the most a step may move a tip) split in
    increments of at most step_mm (mm); each step is an
    ADMM solve warm-started from the previous one, then (``polish``) Newton, with the tips at
    ``tips_at(s)`` at load fraction s (a lift from rest by ``rest()``'s factorization, see
    ``tangent_lift``). A step whose polish does not converge is tried again
    from the last converged state, half as long (down to MIN_LOAD_STEP of a step; without
    ``cut_back`` the steps end there, unconverged). Returns (u,
    load steps taken, ADMM iterations, Newton iterations, converged, tangent lifts); polish
    restarts and cut-backs are appended to ``restarts``."""
    d = ops.d
    admm_it = newton_it = lifts = 0
    converged = True
    uc = u - ops.red.Z @ (ops.red.ZT @ u)
    jump = max(vertex_norm_max(up - uc, d), tip_travel)
    if not np.isfinite(jump):
        raise CaseError(f"{case.source or case.name}: the prescribed displacements are too "
                        f"large to be represented (|u| overflows)")
    if load_steps is None:
        load_steps = max(1, int(np.ceil(jump / step_mm)))
    inc = 1.0 / int(load_steps)
    done, taken, j = 0.0, 0, 0
    u_done = u
    while done < 1.0:
        j += 1
        s = 1.0 if done + inc > 1.0 - 1e-12 else done + inc
        last = s == 1.0
        tol_j = tol_mm if last else max(tol_mm, intermediate_tol_mm)
        up_j = uc + s * (up - uc)
        if lift is True or (lift == "auto" and jump * inc > 1.0):
            u = tangent_lift(ops, u, up_j, admm_it + newton_it, factorize, tips_at(s), rest)
            lifts += 1
        u_start = u
        u, k, converged = admm_step(up_j, s * fext, u, admm_it + newton_it, tol_j, s)
        admm_it += k
        if polish:
            ptol = polish_tol_mm if last else max(polish_tol_mm, tol_j)
            try:
                try:
                    u, kn = newton_step(u, s * fext, None, admm_it + newton_it, ptol, s)
                except SolverDivergedError as exc:
                    # the unconverged ADMM state left Newton's basin: restart the polish from
                    # the step's start state (reported in extra["polish_restarts"]), carried to
                    # this step's boundary values first (without a lift it still has the
                    # previous step's, which Newton would keep: it moves free dofs only)
                    restarts.append(f"load step {j}: {exc}")
                    u_start = tangent_lift(ops, u_start, up_j, admm_it + newton_it,
                                           factorize, tips_at(s), rest)
                    u, kn = newton_step(u_start, s * fext, None, admm_it + newton_it, ptol, s)
                newton_it += kn
                converged = hist["newton_step_mm"][-1] < ptol
            except SolverDivergedError as exc:
                restarts.append(f"load step {j}: {exc}")
                converged = False
            if not converged and not cut_back:
                return u, taken, admm_it, newton_it, False, lifts
            if not converged and inc > MIN_LOAD_STEP / int(load_steps):
                # cut back: the step again from the last converged state, half as long (a
                # tip pressed too far at once leaves Newton's basin)
                restarts.append(f"load step {j} (load fraction {s:.4g}) did not converge: "
                                f"cut back to an increment of {inc / 2:.4g}")
                u, inc = u_done, inc / 2.0
                continue
        done, u_done = s, u
        taken += 1
    return u, taken, admm_it, newton_it, converged, lifts


def region_reactions(case, r):
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
