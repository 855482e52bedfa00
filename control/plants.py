"""Plants, models and tangents of the control layer: the solvers a control loop or a Jacobian
computation runs, by name ("fem" the reference, "admm" the fast solver), and the control
Jacobian J_s at a state with its finite-difference check (``jacobian_at``). The model-plant
mismatch scenarios are in ``control.scenarios``.

Every actuator follows the Case's convention (``Case.with_pushes``): a patch that is not pushed
is held where it is unless the Case (``idle = "free"``, ``Case.with_free_actuators``) frees it,
so J_s here equals central differences of ``fem_reference.solve`` / ``tissue solve``.
"""
from __future__ import annotations

import collections
from dataclasses import dataclass, field

import numpy as np

from tissue_reference.control.dof_maps import p2_interpolation, p2_region_nodes
from tissue_reference.control.jacobian import (
    ControlJacobian,
    dirichlet_jacobian,
    fd_jacobian,
    full_pushes,
    max_rel_error,
)
from tissue_reference.errors import CaseError
from tissue_reference.model.case import E_RANGE_KPA
from tissue_reference.model.results import material_json
from tissue_reference.solvers import registry
from tissue_reference.solvers.admm import prepare
from tissue_reference.solvers.admm import solve as admm_solve

from .fast_model import ADMM_CONTROL_OPTIONS, FastModel
from .jacobian import admm_indenter_jacobian
from .loop import LinearizedModel, run_closed_loop

__all__ = ["ADMM_CONTROL_OPTIONS", "FD_FLOOR", "MODEL_UPDATES", "PRESS_WIDTHS", "LoopSetup",
           "actuator_kind", "admm_indenter_sensitivity", "build_loop", "control_solver",
           "indenter_sensitivity", "jacobian_at", "matching_case", "material_json", "model_case_for", "plant_for",
           "pressing", "reference_state", "solver_description", "tangent_for"]

FD_FLOOR = 1e-7
"""Smallest central-difference step, relative to the body's diameter: the solves agree to about
1e-10 mm, so a smaller step differences round-off."""



def control_solver(name: str):
    """The registry's entry (``solvers.registry``) of the plant/model/Jacobian solver ``name``;
    CaseError naming the choices for a solver that plays none of them."""
    entry = registry.solver(name) if name in registry.names() else None
    if entry is None or not entry.control:
        raise CaseError(f"unknown plant/model solver {name!r}; choose "
                        f"{' or '.join(registry.control_names())}")
    return entry


def solver_description(name: str, case, *, degree: int | None = None,
                       formulation: str = "auto") -> dict:
    """What solver ``name`` (fem | admm) computes on ``case`` as a plant, a model or a Jacobian's
    solver, JSON-ready (``SolverEntry.describe``): ``discretization`` (formulation, degrees,
    cells; the reference's default degree is resolved as ``fem_reference`` resolves it) and
    ``settings`` (the reference's Newton controls, which the control layer leaves at their
    defaults, or ``ADMM_CONTROL_OPTIONS``)."""
    entry = control_solver(name)
    return entry.describe(case, degree=degree, formulation=formulation,
                          options=None if entry.reference else ADMM_CONTROL_OPTIONS)


def plant_for(name: str, *, degree: int | None = None, tight: bool = True):
    """plant(case, pushes, initial_u) -> SolveResult for solver ``name`` (fem | admm).
    tight: ADMM with ``ADMM_CONTROL_OPTIONS`` (else the solver's defaults)."""
    entry = control_solver(name)
    if entry.reference:
        return full_warm_start(lambda case, pushes, initial: entry.solve(
            case, degree=degree, pushes=pushes, initial=initial))
    kw = dict(ADMM_CONTROL_OPTIONS) if tight else {}
    solve = entry.load().solve
    # the previous answer itself warm-starts: with rigid tips it carries their pushes, so
    # the tips start where that state was solved
    return full_warm_start(lambda case, pushes, initial: solve(
        case, pushes=pushes, initial=initial, **kw))


def tangent_for(name: str):
    """tangent(case, u) -> CSR K (P1, node-major, Case numbering) for solver ``name``."""
    entry = control_solver(name)
    if entry.reference:
        # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
        from tissue_reference.fem_reference import tangent_stiffness

        return lambda case, u: tangent_stiffness(case, u).K
    return entry.load().tangent_stiffness


def reference_state(case, state_pushes, *, degree=None, formulation="auto"):
    """Reference solve at ``state_pushes`` and the exact tangent at *its own* state.

    Returns (SolveResult, Tangent, plant) where plant(case, pushes, initial) re-solves with the same
    solver instance. The tangent is taken from the solver's current dof vector right after the
    solve: for degree 2 that is the full P2 state (edge nodes included), the state the SolveResult
    carries too (``fem_reference.tangent_stiffness(case, res, degree=2)`` gives the same K). The
    vertex values ``res.u`` alone do not determine it (edge nodes = mean of their end vertices is
    *not* the solution away from rest: 17% off J_s on the phantom at A1 = 3 mm) and are refused.
    """
    s, res, plant = _solved_reference(case, state_pushes, degree, formulation)
    return res, s.tangent(None, pushes=state_pushes), plant


def _solved_reference(case, state_pushes, degree, formulation):
    """(ReferenceSolver left at its converged state at ``state_pushes``, that SolveResult,
    plant(case, pushes, initial) re-solving with the same solver)."""
    # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
    from tissue_reference.fem_reference import ReferenceSolver

    s = ReferenceSolver(case, degree=degree, formulation=formulation)
    res = s.solve(state_pushes)
    if not res.converged:
        raise CaseError(f"the state solve at pushes {state_pushes} did not converge")

    return s, res, full_warm_start(lambda c, pushes, initial: s.solve(pushes, case=c,
                                                                        initial=initial))


FULL_STATES_KEPT = 64
"""Answers a ``full_warm_start`` plant keeps, newest first, to start a solve from the full state
of the one whose vertex field it is given: a loop of up to 31 steps (closed and open loop) finds
every answer its ``control.plant_step.KeptAnswers`` may give back."""


def full_warm_start(solve, keep: int = FULL_STATES_KEPT):
    """plant(case, pushes, initial) around a reference ``solve`` of the same signature: when
    ``initial`` is the vertex field (``.u``) of one of the plant's own last ``keep`` answers,
    that answer itself warm-starts the solve, so a degree-2 or mixed solve starts from its full
    state (edge nodes and pressure) rather than from vertex values: on the phantom's nu scenario
    (size 10, mixed P2/P1, 12 loop steps; bench/bench_plant_warm_start.py) 37 Newton iterations
    instead of 290 (the vertex warm start cut steps back from 1 mm of push on), the same
    pushes. Not only the last answer: a loop gives back earlier ones where a load repeats
    (``KeptAnswers``), and the next step starts from the one given back."""
    recent = collections.deque(maxlen=keep)

    def plant(case, pushes, initial):
        if initial is not None:
            initial = next((r for r in reversed(recent) if r.u is initial), initial)
        r = solve(case, pushes, initial)
        recent.append(r)
        return r
    return plant


def jacobian_at(case, state_pushes, *, solver="fem", degree=None, formulation="auto", fd_h=0.02,
            actuators=None):
    """J_s at ``state_pushes`` from the solver's exact tangent and, when fd_h > 0, its max relative
    error against central finite differences (step fd_h mm) of the same solver's nonlinear solve.
    actuators: the columns (default: every actuator of the Case; the others are held)."""
    if degree not in (None, 1, 2):
        raise CaseError(f"--degree must be 1 or 2, got {degree}")
    reference = control_solver(solver).reference
    if not reference and (degree == 2 or formulation == "mixed"):
        raise CaseError(f"--degree 2 and --formulation mixed need --solver "
                        f"{registry.reference().name}")
    st = full_pushes(case, state_pushes)
    pushed = case.with_pushes(st)
    names = [a.name for a in case.actuators] if actuators is None else list(actuators)
    tips = {a.name for a in case.indenters()}
    if tips & set(names) and not set(names) <= tips:
        raise CaseError(f"the Jacobian's actuators {names} mix indenters and glued patches: ask "
                        f"for the columns of one kind at a time (--actuators)")
    if reference and tips & set(names):
        # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
        from tissue_reference.fem_reference.contact_jacobian import indenter_jacobian

        s, res, plant = _solved_reference(case, st, degree, formulation)
        degree = s.degree
        J = indenter_jacobian(s, pushed, actuators=names)
        jac = ControlJacobian(J, tuple(names), tuple(p.name for p in case.probes),
                              kind="indenter", gdim=case.mesh.gdim)
    elif tips & set(names):   # the ADMM model's rigid tips
        plant = plant_for(solver, degree=degree)
        res = plant(case, st, None)
        if not res.converged:
            raise CaseError(f"the state solve at pushes {st} did not converge")
        jac = admm_indenter_jacobian(pushed, res.u, actuators=names)
    elif reference:
        res, T, plant = reference_state(case, st, degree=degree, formulation=formulation)
        degree = T.degree
        if degree == 2:
            P = p2_interpolation(case, T.node_points)
            jac = dirichlet_jacobian(pushed, T.K, actuators=actuators, P=P,
                                     region_nodes=p2_region_nodes(case, T.node_points),
                                     internal_dofs=T.internal_dofs)
        else:
            jac = dirichlet_jacobian(pushed, T.K, actuators=actuators)
    else:
        plant = plant_for(solver, degree=degree)
        res = plant(case, st, None)
        if not res.converged:
            raise CaseError(f"the state solve at pushes {st} did not converge")
        jac = dirichlet_jacobian(pushed, tangent_for(solver)(pushed, res.u), actuators=actuators)
    described = solver_description(solver, case, degree=degree, formulation=formulation)
    disc = res.discretization or described["discretization"]
    out = {"case": case.name, "source": case.source, "material": material_json(case.material),
           "actuators": list(jac.actuators), "targets": list(jac.targets),
           "rows": jac.rows, "J": jac.J.tolist(), "state_pushes": st, "solver": solver,
           "actuator_kind": "indenter" if jac.kind == "indenter" else "glued patch",
           "degree": disc.get("degree", degree or 1),
           "formulation": disc.get("formulation", "displacement"),
           "discretization": disc, "solver_settings": described["settings"],
           "state_valid": bool(res.valid is not False),
           "state_invalid_reason": res.invalid_reason}
    if fd_h and fd_h > 0:
        # degree 2 solves start cold: a warm start from vertex values (edge nodes interpolated)
        # is not the P2 state and can leave Newton's basin on coarse meshes
        fd = fd_jacobian(plant, case, st, h=fd_h, actuators=jac.actuators,
                         initial=res.u if degree == 1 else None)
        out["fd_max_rel_error"] = max_rel_error(jac.J, fd.J)
        out["fd_h_mm"] = fd_h
    else:
        out["fd_max_rel_error"] = None
        out["fd_h_mm"] = 0.0
    return out




@dataclass
class LoopSetup:
    """A plant (the "true" tissue) and a controller model, ready to run closed loops.

    plant(case, pushes, initial) -> SolveResult on ``case``; the model is ``model_case`` solved by
    ``model_solve`` with tangent ``model_tangent``; ``meta`` describes both and the mismatch
    between them (what every result's JSON carries)."""

    case: object
    plant: object
    model_case: object
    model_solve: object
    model_tangent: object
    meta: dict = field(default_factory=dict)
    model_sensitivity: object = None   # the model's Jacobian when not from its tangent
    fast_model: bool = False           # the model updated by control.fast_model

    def run(self, target: str, task: int, settings, progress=None):
        """One closed loop (and its open-loop baseline) -> control.loop.LoopResult;
        ``progress(line)`` gets a line per step.

        Parameters
        ----------
        target : str
            The probe to steer.
        task : int
            The seed's task number (which axes move, by ``settings.task_mm``).
        settings : LoopSettings
            Steps, time step (s), noise (mm), the MPC's settings.
        progress : callable or None
            progress(line) per step; None: silent.

        Returns
        -------
        LoopResult
            Targets (mm) and pushes (mm) per step, errors (mm), ITAE and the open loop.
        """
        if self.fast_model:
            model = FastModel(self.model_case, target, press_widths=PRESS_WIDTHS)
        else:
            model = LinearizedModel(self.model_case, self.model_solve, self.model_tangent,
                                    target, self.model_sensitivity)
        return run_closed_loop(self.plant, self.case, model, target, task, settings=settings,
                               progress=progress)


MODEL_UPDATES = ("fast", "solve")
"""How an ADMM model follows the pushes: "fast" (``control.fast_model``: chord Newton on the same
P1 energy, Jacobian by refinement; the same state and Jacobian within 1e-6 mm and 1e-5) or
"solve" (a full ADMM solve with polish and an assembled tangent every step)."""


def matching_case(base, other, base_role: str, other_role: str, hint: str = ""):
    """``other`` as a case of ``base``'s body for a loop: the same actuator names (returned in
    ``base``'s order) pushing along the same directions, the same probes. CaseError naming both
    cases (``base_role`` / ``other_role``: what each is to the loop, e.g. "case" and "model")
    and the first difference otherwise; ``hint`` ends the message on differing names."""
    from dataclasses import replace

    b, o = base.source or base.name, other.source or other.name
    bnames = [a.name for a in base.actuators]
    onames = [a.name for a in other.actuators]
    if set(bnames) != set(onames):
        raise CaseError(f"the {other_role} {o} has actuators {onames}, the {base_role} {b} has "
                        f"{bnames}{hint}")
    for a in base.actuators:
        d = other.actuator(a.name).direction
        if not np.allclose(d, a.direction, atol=1e-9):
            raise CaseError(f"actuator {a.name!r} pushes along {list(d)} in the {other_role} "
                            f"{o} and along {list(a.direction)} in the {base_role} {b}")
    bp = sorted(q.name for q in base.probes)
    op = sorted(q.name for q in other.probes)
    if bp != op:
        raise CaseError(f"the {other_role} {o} has probes {op}, the {base_role} {b} has {bp}")
    return replace(other, actuators=tuple(other.actuator(n) for n in bnames))


def model_case_for(case, model_case=None, E_factor: float = 1.0):
    """The case a model solves: ``model_case`` (default ``case``) checked to be of ``case``'s
    body (``matching_case``), with its E scaled by ``E_factor`` (a new Case, also at factor 1).

    Raises
    ------
    CaseError
        For a factor that is not a positive number, a model E outside ``E_RANGE_KPA``, or a
        ``model_case`` of another body.
    """
    if not (np.isfinite(E_factor) and E_factor > 0):
        raise CaseError(f"model E factor must be > 0, got {E_factor}")
    base = case if model_case is None or model_case is case else \
        matching_case(case, model_case, "case", "model")
    E = base.material.E * E_factor
    if not E_RANGE_KPA[0] <= E <= E_RANGE_KPA[1]:
        raise CaseError(f"model E factor {E_factor:g}: the model's E would be {E:g} kPa, "
                        f"outside the physical range [{E_RANGE_KPA[0]:g}, {E_RANGE_KPA[1]:g}] kPa")
    return base.with_material(E=E)


def build_loop(case, *, plant: str = "fem", model: str | None = None,
               model_E_factor: float = 1.0, model_case=None, plant_case=None,
               scenario: str | None = None, model_update: str = "fast",
               degree: int | None = None) -> LoopSetup:
    """The plant ``plant`` (fem | admm) on ``plant_case`` (default ``case``: the "true" tissue,
    e.g. with gravity or another nu) and the model ``model`` (default: the plant's solver) on
    ``model_case`` (default: ``case``; e.g. a coarser mesh of the same body) with E scaled by
    ``model_E_factor``. When model and plant coincide the model reuses the plant's solutions.
    ``scenario`` names the mismatch in the metadata. ``model_update``: MODEL_UPDATES (an ADMM
    model on glued patches that is not the plant itself; other models always solve). A
    ``model_case`` must be of ``case``'s body (``matching_case``).

    Parameters
    ----------
    case : Case
        The body, with its actuators and targets (probes).
    plant : str
        The plant's solver: "fem" or "admm".
    model : str or None
        The model's solver; None: the plant's.
    model_E_factor : float
        Factor on the model's Young's modulus (dimensionless).
    model_case : Case or None
        The model's Case (of ``case``'s body); None: ``case``.
    plant_case : Case or None
        The plant's Case; None: ``case``.
    scenario : str or None
        The mismatch's name in the metadata; None: none.
    model_update : str
        One of MODEL_UPDATES: "fast" or "solve".
    degree : int or None
        The reference's Lagrange degree (1 or 2) where the plant or the model is the reference
        (fem); None: the case's (``[reference] degree``, as ``fem_reference`` resolves it).

    Returns
    -------
    LoopSetup
        The plant and the model, ready to ``run``.

    Raises
    ------
    CaseError
        For an unknown solver or update, a ``model_case`` of another body, or a ``degree``
        that is not 1 or 2 or that no reference of the loop solves at.
    """
    mname = model or plant
    if degree is not None:
        if degree not in (1, 2):
            raise CaseError(f"degree {degree!r}: the reference's degree in a loop is 1 or 2")
        if not (control_solver(plant).reference or control_solver(mname).reference):
            raise CaseError(f"degree {degree}: neither the plant ({plant}) nor the model "
                            f"({mname}) is the reference (fem), whose degree it sets")
    mc = model_case_for(case, model_case, model_E_factor)
    if mc.indenters() and len(mc.indenters()) != len(mc.actuators):
        raise CaseError(f"{mc.source or mc.name}: the model mixes indenters and glued patches; "
                        f"a loop's model has actuators of one kind")
    psolve = plant_for(plant, degree=degree)
    pcase = plant_case if plant_case is not None else case
    if mname == plant and model_E_factor == 1.0 and model_case is None and plant_case is None:
        mcase, msolve = case, psolve          # the model is the plant: reuse its solution
    else:
        mcase, msolve = mc, plant_for(mname, degree=degree)
    meta = {"case": case.name, "source": case.source, "plant": plant, "model": mname,
            "scenario": scenario, "model_case": mcase.name, "model_source": mcase.source,
            "plant_cells": pcase.mesh.n_cells, "model_cells": mcase.mesh.n_cells,
            "plant_material": material_json(pcase.material),
            "plant_gravity_mm_s2": list(pcase.gravity) if pcase.gravity is not None else None,
            "model_gravity_mm_s2": list(mcase.gravity) if mcase.gravity is not None else None,
            "model_material": material_json(mcase.material),
            "mismatch": {"E_factor": model_E_factor,
                         "mesh": "same" if mcase.mesh is pcase.mesh else "different",
                         "solver": "same" if mname == plant else "different",
                         "nu": [pcase.material.nu, mcase.material.nu]
                         if pcase.material.nu != mcase.material.nu else "same",
                         "gravity": "same" if pcase.gravity == mcase.gravity else "different",
                         "actuator_kind": "same" if actuator_kind(pcase) == actuator_kind(mcase)
                         else "different"},
            "actuators": {a.name: {"type": a.type, "idle": a.idle} for a in case.actuators},
            "plant_actuator_kind": actuator_kind(pcase),
            "model_actuator_kind": actuator_kind(mcase),
            "plant_solver": solver_description(plant, pcase, degree=degree),
            "model_solver": solver_description(mname, mcase, degree=degree)}
    if pcase.indenters():
        meta["plant_indenters"] = {a.name: {"tip": a.tip, "radius_mm": a.radius,
                                            "contact": a.contact,
                                            "contact_regions": list(a.contact_regions)}
                                   for a in pcase.indenters()}
        rule = pcase.reference_contact_quadrature
        meta["plant_contact_rule"] = "nodal" if rule in (None, "nodal") else int(rule)
    sensitivity = None
    if mcase.indenters():
        sensitivity = indenter_sensitivity() if control_solver(mname).reference else admm_indenter_sensitivity()
    if model_update not in MODEL_UPDATES:
        raise CaseError(f"model update {model_update!r}: choose one of {list(MODEL_UPDATES)}")
    fast = model_update == "fast" and control_solver(mname).fast_model and msolve is not psolve
    meta["model_update"] = "fast" if fast else "solve"
    return LoopSetup(pcase, psolve, mcase, msolve, tangent_for(mname), meta, sensitivity, fast)


def actuator_kind(case) -> str:
    """The kind of ``case``'s actuators: "patch" (glued), "indenter" (rigid tips), "mixed" or
    "none"."""
    kinds = {a.type for a in case.actuators}
    return kinds.pop() if len(kinds) == 1 else ("mixed" if kinds else "none")


PRESS_WIDTHS = 4.0
"""The controller's model linearizes a tip pushed less than this many of its penalty's smoothing
widths (``smoothing_width``: h / beta, about a thousandth of a cell) at that push: a tip that
touches the skin without pressing it (started on the curved surface, ``tip_start =
"surface"``) has a zero Jacobian column, the derivative of a penalty that is flat at zero
penetration, and turns into the pressing one within a few widths (a side tip's column on the
block of tests/test_indenter_jacobian.py, widths of 0.00125 mm: 0 at 0 mm, -0.425 at 0.0005 mm,
-0.495 at 0.005 mm, -0.506 at 0.01 mm). A push-only controller needs the pressing one."""


def pressing(solver, pushes: dict) -> dict:
    """``pushes`` (name -> mm) with each indenter of ``solver`` at 0 <= push < PRESS_WIDTHS of
    its smoothing widths pushed to that depth; retracted tips (< 0) and the others unchanged."""
    floor = {i.name: PRESS_WIDTHS * i.smoothing_width for i in solver.contact.indenters}
    return {n: floor[n] if n in floor and 0.0 <= float(p) < floor[n] else float(p)
            for n, p in pushes.items()}


def indenter_sensitivity(degree: int | None = None):
    """sensitivity(case, pushes, u, target) -> (gdim, n_act) mm/mm: the reference's indenter
    Jacobian (``fem_reference.contact_jacobian``) of ``target`` at the state of ``case`` with
    ``pushes`` that starts from ``u`` (the model's answer there: the warm start is the state),
    each tip at least PRESS_WIDTHS of its smoothing widths in (``pressing``)."""
    def sensitivity(case, pushes, u, target):
        # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
        from tissue_reference.fem_reference.contact_jacobian import indenter_jacobian
        from tissue_reference.fem_reference.kept import solver_for

        s = solver_for(case, degree)
        at = pressing(s, pushes)
        res = s.solve(at, case=case, initial=u)
        if not res.converged:
            raise CaseError(f"the model's state at pushes {at} did not converge")
        return indenter_jacobian(s, case.with_pushes(at), targets=[target])
    return sensitivity


def admm_indenter_sensitivity():
    """sensitivity(case, pushes, u, target) -> (gdim, n_act) mm/mm: the ADMM model's indenter
    Jacobian (``control.jacobian.admm_indenter_jacobian``) of ``target`` at its state ``u`` of
    ``case`` with ``pushes``; a tip touching without pressing (0 <= push < PRESS_WIDTHS of its
    smoothing widths) is first pushed to that depth by an ADMM solve from ``u``."""
    def sensitivity(case, pushes, u, target):
        at = prepare(case.with_pushes(pushes)).contact.pressed(pushes, PRESS_WIDTHS)
        if at != dict(pushes):
            res = admm_solve(case, pushes=at, initial=u, initial_pushes=pushes,
                             **ADMM_CONTROL_OPTIONS)
            if not res.converged:
                raise CaseError(f"the model's state at pushes {at} did not converge")
            u = res.u
        return admm_indenter_jacobian(case.with_pushes(at), u, targets=[target]).J
    return sensitivity
