"""``solve``: the ADMM solve of a Case. Quasi-static equilibrium in load steps of at most
``step_mm`` (each: boundary moved, interior carried along by the tangent or harmonic lift, ADMM,
then the Newton polish), or implicit-Euler dynamics (``dynamics``); the result with reactions,
energy, deformation state and the iteration history."""
from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from tissue_reference.errors import CaseError, SolverDivergedError
from tissue_reference.meshes.mesh import deformation_state
from tissue_reference.model.results import SolveResult
from tissue_reference.model.tips import through_surface_state

from .backends import backend, require_device
from .dynamics import ImplicitEuler, implicit_euler
from .loop import check_J, run_admm
from .mechanics import as_u
from .operators import particular, prepare, vertex_norm_max
from .options import SolveOptions
from .polish import energy_gradient, tangent_lift
from .polisher import Polisher


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
        (``model.tips.default_contact_rule`` and ``default_tip_start``; beta
        ``model.tips.DEFAULT_CONTACT_PENALTY``): the same discrete energy as the P1 reference.
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
    pushed = case.with_pushes(pushes)   # idle patches held unless the Case frees them
    opts = SolveOptions(
        tol_mm=tol_mm, max_iter=max_iter, rho=rho, polish=polish, polish_tol_mm=polish_tol_mm,
        polish_max_iter=polish_max_iter, dynamics=dynamics, callback=callback,
        load_steps=load_steps, step_mm=step_mm, intermediate_tol_mm=intermediate_tol_mm,
        lift=lift, handoff_mm=handoff_mm, tip_step=tip_step, progress=progress,
        factorize=factorize, device=device, contact_quadrature=contact_quadrature,
        contact_penalty=contact_penalty, tip_start=tip_start, anderson=anderson,
    ).resolved(pushed)
    run = SolveRun(pushed, opts, initial, initial_pushes)
    march = run.quasi_static() if dynamics is None else run.implicit_euler()
    # the unpushed Case has the same mesh: its cached probe locations serve the pushed one too
    return run.result(march, t0, probe_case=case)


class March(NamedTuple):
    """What the load steps or the time steps of a solve reached."""

    u: np.ndarray
    """Node-major displacement (mm) at the end."""
    load_steps: int | None
    """Load steps taken (quasi-static); the ``load_steps`` option in dynamics (unused)."""
    admm_iterations: int
    newton_iterations: int
    converged: bool
    lifts: int
    """Tangent lifts solved."""
    extra: dict
    """What the time steps add to ``SolveResult.extra`` (empty for quasi-static solves)."""


class SolveRun:
    """One solve's operators, backend, start state and iteration history, with its ADMM steps
    and its polish (``polisher.Polisher``), the load or time steps that use them and the
    SolveResult they give.

    Parameters
    ----------
    case : Case
        The Case with its pushes applied (``Case.with_pushes``).
    opts : SolveOptions
        The resolved options (``SolveOptions.resolved``).
    initial : array_like or SolveResult or None
        Warm start (mm, (n_vertices, gdim)) or an earlier answer (its ``u``, and with indenters
        its tips' pushes); None: rest.
    initial_pushes : dict or None
        Name -> push (mm) that a bare-array warm start was solved at (tips start there).
    """

    def __init__(self, case, opts: SolveOptions, initial, initial_pushes):
        self.case, self.opts = case, opts
        self.ops = ops = prepare(case, rho=opts.rho, dt=opts.dt, factor=opts.device == "cpu",
                                 contact=opts.contact)
        self.cset = cset = ops.contact
        self.push1 = cset.pushes_of(case) if cset is not None else None
        self.push0 = None if cset is None else _start_pushes(cset, initial, initial_pushes)
        if isinstance(initial, SolveResult):
            initial = initial.u
        self.be = backend(ops, opts.device)
        self.up = particular(case, ops)
        self.fext = case.external_forces(1.0)
        if initial is None:
            self.u0 = np.zeros(ops.N)
        else:
            self.u0 = as_u(case, initial).copy()
            check_J(ops, ops.grad(self.u0), 0, "the initial (warm-start) state")
        self.hist = {"primal": [], "dual": [], "max_step_mm": [], "newton_step_mm": [],
                     "admm_clock_s": []}
        self.restarts = []   # polish restarts and cut-backs (``extra["polish_restarts"]``)
        self.polisher = Polisher(ops, opts, self.hist, self.tips_at)

    def tips_at(self, s: float):
        """The tips' ends at the contact points at load fraction ``s`` (None without tips).

        Parameters
        ----------
        s : float
            Load fraction, 0 (the start pushes) to 1 (the Case's pushes).

        Returns
        -------
        ndarray or None
            The tips' origins (mm) at pushes push0 + s (push1 - push0); None without tips.
        """
        if self.cset is None:
            return None
        return self.cset.origins(self.push0 + s * (self.push1 - self.push0))

    def admm_step(self, up_j, rhs_extra, u_j, it0, tol=None, s=1.0):
        """ADMM iterations (``loop.run_admm``) from ``u_j`` with the prescribed values ``up_j``.

        Parameters
        ----------
        up_j : ndarray
            Node-major particular displacement (mm) carrying this step's prescribed values.
        rhs_extra : ndarray
            Node-major forces (mN) added to the x-step's right-hand side.
        u_j : ndarray
            Node-major displacement (mm) to start from.
        it0 : int
            Iterations before this step.
        tol : float or None
            The step's tolerance (mm), raised to the polish's hand-over (``admm_tol``); None:
            ``opts.tol_mm``.
        s : float
            Load fraction, where the rigid tips are (``tips_at``).

        Returns
        -------
        tuple
            (u, mm node-major; iterations; converged).
        """
        opts = self.opts
        tol = opts.tol_mm if tol is None else tol
        return run_admm(self.ops, up_j, rhs_extra, u_j, tol_mm=opts.admm_tol(tol),
                        max_iter=opts.max_iter, callback=opts.callback, it0=it0,
                        progress=opts.progress, hist=self.hist, be=self.be,
                        tips=self.tips_at(s), anderson=opts.anderson)

    def quasi_static(self) -> March:
        """Quasi-static equilibrium in load steps (``_load_steps``); the chord polish tries the
        whole change in one load step first (its lift from rest is a back-substitution; a later
        step's lift would factorize) and takes the load steps of ``step_mm`` where that fails.

        Returns
        -------
        March
            The end state (mm), load steps taken, iteration counts, whether it converged and
            the tangent lifts.
        """
        opts = self.opts
        one = None
        if opts.use_chord and opts.load_steps is None:
            try:
                one = self._load_steps(1, cut_back=False)
                if not one[4]:
                    raise SolverDivergedError("not converged")
            except SolverDivergedError as exc:
                self.restarts.append(f"one load step: {exc}; load steps of {opts.step_mm:g} mm")
                one = None
        u, taken, admm_it, newton_it, converged, lifts = one or self._load_steps(opts.load_steps)
        if opts.use_chord:   # every iteration, the failed one-step attempt's included; the chord
            # steps apart from the Newton polish's
            admm_it = len(self.hist["primal"])
            newton_it = len(self.hist["newton_step_mm"]) - self.polisher.chord_steps
        return March(u, taken, admm_it, newton_it, converged, lifts, {})

    def _load_steps(self, steps, cut_back=True):
        """``_load_steps`` from the start state with this solve's steps and options: ``steps``
        load steps (None: from ``step_mm`` and ``tip_step``), cut back unless ``cut_back`` is
        False. Returns its tuple."""
        opts, cset = self.opts, self.cset
        tip_travel = 0.0 if cset is None else float(np.max(
            np.abs(self.push1 - self.push0) / np.array([t.shape.radius for t in cset.tips])
            * opts.step_mm / opts.tip_step, initial=0.0))
        return _load_steps(
            self.case, self.ops, self.u0, self.up, self.fext, admm_step=self.admm_step,
            newton_step=self.polisher.step, opts=opts, load_steps=steps, hist=self.hist,
            restarts=self.restarts, tip_travel=tip_travel, tips_at=self.tips_at,
            cut_back=cut_back, rest=self.polisher.rest if opts.use_chord else None)

    def implicit_euler(self) -> March:
        """The implicit-Euler time steps of ``opts.dynamics`` (``dynamics.implicit_euler``).

        Returns
        -------
        March
            The end state (mm), iteration counts, whether every step converged, and in
            ``extra`` dt (s), the steps, the probes' trajectory (mm) and the end velocity
            (mm/s, (n, gdim)).
        """
        opts, ops = self.opts, self.ops
        u, v, traj, admm_it, newton_it, converged = implicit_euler(
            self.case, ops, opts.dynamics, self.u0, self.up, self.fext,
            admm_step=self.admm_step, newton_step=self.polisher.step, polish=opts.polish,
            polish_tol_mm=opts.polish_tol_mm, hist=self.hist)
        extra = {"dt_s": opts.dt, "steps": int(opts.dynamics.steps), "probe_trajectory": traj,
                 "velocity": v.reshape(ops.n, ops.d)}
        return March(u, opts.load_steps, admm_it, newton_it, converged, 0, extra)

    def result(self, march: March, t0: float, probe_case=None) -> SolveResult:
        """The SolveResult of the state ``march`` reached.

        Parameters
        ----------
        march : March
            What ``quasi_static`` or ``implicit_euler`` returned.
        t0 : float
            ``time.perf_counter()`` (s) at the solve's start: the wall time and the history's
            ADMM clock count from it.
        probe_case : Case or None
            The Case whose probe locations are read (same mesh); None: the solved Case.

        Returns
        -------
        SolveResult
            solver "admm": ``u`` (mm), ``probes`` (mm), ``reactions`` (mN), ``strain_energy``
            (uJ), the iteration counts in ``extra``, ``history["admm_clock_s"]`` (s).
        """
        case, ops, opts = self.case, self.ops, self.opts
        n, d = ops.n, ops.d
        u = march.u
        its = march.admm_iterations + march.newton_iterations
        H = ops.grad(u)
        check_J(ops, H, its, "the final state")
        # the numpy laws' energy and stress at u from one evaluation
        values = None if ops.law.kernel else ops.law.evaluate(H, tangent=False)
        r = energy_gradient(ops, u, self.fext, None, self.tips_at(1.0), values)
        psi = values.psi if values is not None else ops.law.psi_J(H)[0]
        state = deformation_state(case.mesh, u.reshape(n, d))
        indenters = {}
        if self.cset is not None:
            indenters = self.cset.report(u, self.push1)
            state = through_surface_state(state, {"indenters": indenters})
        valid, invalid_reason = state.pop("valid"), state.pop("invalid_reason")
        min_J = state.pop("min_J")
        quasi_static = opts.dynamics is None
        load_steps = int(march.load_steps) if quasi_static else int(opts.dynamics.steps)
        extra = {"admm_iterations": int(march.admm_iterations),
                 "newton_iterations": int(march.newton_iterations),
                 "load_steps": load_steps if quasi_static else 0,
                 "rho_kPa": ops.rho, "setup_s": ops.setup_s, "tol_mm": opts.tol_mm,
                 "polish_restarts": self.restarts, "lift_solves": march.lifts,
                 **self.polisher.extra(), **state, **march.extra, "device": opts.device}
        if self.be.cg_iterations is not None:
            extra["xstep_cg_iterations"] = int(self.be.cg_iterations)
        self.hist["admm_clock_s"] = [c - t0 for c in self.hist["admm_clock_s"]]
        u2 = u.reshape(n, d)
        return SolveResult(u=u2, converged=bool(march.converged),
                           iterations=int(its + self.polisher.chord_steps),
                           residual=float(np.abs(ops.red.ZT @ r).max(initial=0.0)),
                           wall_time_s=time.perf_counter() - t0, solver="admm",
                           probes=(probe_case or case).probe_values(u2),
                           reactions=region_reactions(case, r),
                           strain_energy=float(ops.kin.V @ psi), case_name=case.name,
                           n_vertices=n, load_steps=load_steps, n_cells=ops.m,
                           history=self.hist, valid=valid, invalid_reason=invalid_reason,
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


def _load_steps(case, ops, u, up, fext, *, admm_step, newton_step, opts, load_steps, hist,
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
    restarts and cut-backs are appended to ``restarts``. ``opts`` (SolveOptions): the polish,
    its tolerance, step_mm, the tolerances, the lift and the factorization hook."""
    polish, polish_tol_mm, step_mm = bool(opts.polish), opts.polish_tol_mm, opts.step_mm
    tol_mm, intermediate_tol_mm = opts.tol_mm, opts.intermediate_tol_mm
    lift, factorize = opts.lift, opts.factorize
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
