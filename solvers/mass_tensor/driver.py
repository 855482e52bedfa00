"""Case level: the point types of a Case, the model cache (with the tips' contact points),
``solve(case, ...)`` returning a ``SolveResult`` (solver "mass-tensor"; with rigid tips, their
condensed contact: ``contact``) and the reactions per Dirichlet region."""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from tissue_reference.errors import CaseError, NotModeledError
from tissue_reference.meshes.mesh import deformation_state
from tissue_reference.model.case_constraints import axis_of
from tissue_reference.model.results import SolveResult
from tissue_reference.model.tips import through_surface_state

from ..contact import ContactSet, require_frictionless
from ..registry import solver as registry_solver
from .contact import solve_tips
from .model import MassTensorModel
from .point_types import PointTypes


def case_point_types(case) -> PointTypes:
    """Point types of a Case: prescribed dofs (fixed / displacement / affine / axis-aligned sliding)
    become per-component prescriptions (border / target points when all components are set),
    oblique sliding becomes planar sliding u . n = value."""
    mesh = case.mesh
    d = mesh.gdim
    c = case.constraints
    types = PointTypes(mesh.n_vertices, d, mesh.points)
    verts, comps = c.dofs // d, c.dofs % d
    eye = np.eye(d)
    for k in range(d):
        sel = comps == k
        if np.any(sel):
            types.prescribe(verts[sel], eye[k], c.values[sel], label="prescribed")
    for vs, nrm, g in c.sliding:
        types.prescribe(vs, nrm, g, label="sliding")
    full = types.m == d
    zero = full & np.all(np.abs(types.g) == 0.0, axis=1)
    types.label[full] = "target"
    types.label[zero] = "border"
    return types


MODEL_CACHE: dict = {}


def model_for(case) -> MassTensorModel:
    key = (id(case.mesh), case.material.mu, case.material.lmbda)
    m = MODEL_CACHE.get(key)
    same = m is not None and (m.points is case.mesh.points or np.array_equal(m.points, case.mesh.points)) \
        and (m.cells is case.mesh.cells or np.array_equal(m.cells, case.mesh.cells))
    if not same:
        m = MassTensorModel(case.mesh.points, case.mesh.cells, case.material,
                            topology=case.mesh.edge_topology)
        MODEL_CACHE.clear()
        MODEL_CACHE[key] = m
    return m


def forget_factorizations() -> None:
    """Drop the direct solve's kept factorizations, the AMG hierarchies and the rigid tips'
    compliance blocks (the tensors stay): the next solve of each pattern of point types makes
    them again, as a first solve does."""
    for m in MODEL_CACHE.values():
        m._factors.clear()


def require_law(case) -> None:
    """NotModeledError (a CaseError) naming ``case``'s law when the Mass Tensor method does not
    take it: it takes linear elasticity, and Neo-Hookean as linear elasticity of the same E and
    nu (seed 001's fast approximation of tissue, said in the answer's ``model_note``); every
    other law is refused with how to go on (the registry's ``laws`` of "mass-tensor")."""
    registry_solver("mass-tensor").check_law(case.material)


def require_modeled(case, method: str = "direct") -> None:
    """NotModeledError when ``case`` has what this model cannot hold: a law it does not take
    (``require_law``), a tip that is not frictionless (a tied one), or tips with an iterative
    ``method`` (the tips' contact is condensed on the direct solve's factorization)."""
    require_law(case)
    require_frictionless(case, "the Mass Tensor solver")
    if case.indenters() and method != "direct":
        raise NotModeledError(f"the Mass Tensor solver presses rigid tips with method "
                              f"'direct' only (its contact is condensed on the direct solve's "
                              f"factorization), not {method!r}")


def contact_set(model, case, rule=None, penalty=None, tip_start=None) -> ContactSet:
    """The contact points of ``case``'s tips on ``model``'s mesh (``solvers.contact``), kept with
    the model per tips (pushes aside), material and contact options."""
    key = (tuple(replace(a, push=0.0) for a in case.indenters()), case.material.E,
           case.reference_contact_quadrature, case.reference_tip_start, rule, penalty, tip_start)
    kept = model._contact_sets
    if key not in kept:
        if len(kept) >= 4:
            kept.pop(next(iter(kept)))
        kept[key] = ContactSet(case, rule=rule, penalty=penalty, tip_start=tip_start)
    return kept[key]


def solve(case, *, pushes=None, initial=None, method: str = "direct", stop_mm: float = 0.01,
          max_iter: int = 200000, callback=None, progress: bool = False,
          step_scale: float | None = None, factorize=None, contact_quadrature=None,
          contact_penalty: float | None = None, tip_start: str | None = None,
          contact_tol_mm: float = 1e-10) -> SolveResult:
    """Mass Tensor solve of a Case: linear elasticity with the Case's E, nu, on a linear-elastic
    or Neo-Hookean Case (the latter said in ``model_note``); another law raises NotModeledError
    naming it (``require_law``).

    pushes: actuator name -> push (mm); initial (n, d) mm warm start; method "direct" (default),
    "amg" | "pcg" | "descent" (``model.METHODS``); stop_mm: stopping rule of the iterations and
    of the surface-sliding rounds (largest per-vertex displacement in one iteration, mm; "amg":
    the distance still to go estimated from those, below half of it); callback(it, u)
    every iteration; factorize: the direct solve's factorization hook
    (``MassTensorModel.solve``). Returns SolveResult(solver="mass-tensor"): u (n, d) mm, probes (mm),
    reactions per Dirichlet region = sum over its prescribed directions of F(u) - f_ext (mN),
    strain_energy 1/2 u.F(u) (kPa mm^3), iterations, residual (largest free-direction force
    imbalance, mN), history={"max_step_mm": [...]}, warnings: one line per pushed glued patch
    past the range where its answer converges or with its rim cells crushed
    (``Case.glued_patch_warnings``, judged by the case's material, as the reference's).

    Rigid tips (frictionless indenters; method "direct"): the reference's discrete contact
    penalty on the linear model, by Newton condensed on the skin near the tips (``contact``)
    until a step moves no vertex by ``contact_tol_mm`` (mm); contact_quadrature,
    contact_penalty and tip_start as ADMM takes them (each by default the case's own, as the
    reference takes it: the same discrete problem as the linear P1 reference). Each tip is
    reported in ``SolveResult.indenters`` as the reference reports it; the reactions and the
    residual include the tips' forces; iterations counts the contactless solve and Newton's.

    Parameters
    ----------
    case : Case
        The problem: P1 mesh (mm), E (kPa) and nu, boundaries, probes and actuators.
    pushes : dict or None
        Actuator name -> push (mm).
    initial : array_like or None
        (n, d) warm start (mm); None: rest.
    method : str
        "direct" (default), "amg", "pcg" or "descent" (``model.METHODS``).
    stop_mm : float
        Stopping rule of the iterations and of the surface-sliding rounds (mm).
    max_iter : int
        Total iterations at most (converged=False when reached).
    callback : callable or None
        callback(it, u) every iteration, u (mm).
    progress : bool
        Print the iterations' progress.
    step_scale : float or None
        Fixed descent step of the iterative methods (the package docstring); None: their own.
    factorize : callable or None
        The direct solve's factorization hook (``MassTensorModel.solve``); None: SuperLU.
    contact_quadrature : str or int or None
        The rigid tips' contact rule ("nodal" or a Gauss degree); None: the case's.
    contact_penalty : float or None
        beta of the contact penalty k = beta E / h (kPa/mm); None: the case's default.
    tip_start : str or None
        Where each tip starts: "nodes" or "surface"; None: the case's default.
    contact_tol_mm : float
        Largest vertex move (mm) of a contact Newton step that ends it.

    Returns
    -------
    SolveResult
        solver "mass-tensor", as described above: ``u`` (mm), ``probes`` (mm), ``reactions``
        (mN), ``strain_energy`` (uJ), ``residual`` (mN).

    Raises
    ------
    CaseError
        For a method it does not know or options that do not fit the case (e.g. rigid tips with a
        method other than "direct").
    """
    t0 = time.perf_counter()
    require_law(case)
    case.material.require_compressible("the Mass Tensor solver")
    require_modeled(case, method)
    if not (np.isfinite(contact_tol_mm) and contact_tol_mm > 0):
        raise CaseError(f"contact_tol_mm must be > 0 mm, got {contact_tol_mm!r}")
    case = case.with_pushes(pushes)   # idle patches held unless the Case frees them
    model = model_for(case)
    types = case_point_types(case)
    n, d = case.mesh.n_vertices, case.mesh.gdim
    f = case.external_forces(1.0).reshape(n, d)
    cb = callback
    if progress:
        def cb(it, u, _cb=callback):
            if it % 100 == 0:
                print(f"mass-tensor {method}: iteration {it}", flush=True)
            if _cb is not None:
                _cb(it, u)
    cset = contact_set(model, case, contact_quadrature, contact_penalty, tip_start) \
        if case.indenters() else None
    sol = model.solve(types, f_ext=f, initial=initial, method=method, stop_mm=stop_mm,
                      max_iter=max_iter, step_scale=step_scale, callback=cb,
                      factorize=factorize)
    u = sol.u
    steps, iterations, converged, residual = list(sol.max_step_mm), sol.iterations, \
        sol.converged, sol.residual
    indenters, tips = {}, {}
    r_tips = 0.0
    if cset is not None:
        pushes_t = cset.pushes_of(case)
        comp = model.compliance(types, factorize)
        tip = solve_tips(cset, comp, pushes_t, u, tol_mm=contact_tol_mm, callback=cb,
                         it0=sol.iterations)
        u = tip.u
        steps += tip.max_step_mm
        iterations += tip.iterations
        converged = converged and tip.converged
        r_tips = cset.gradient(u, cset.origins(pushes_t)).reshape(n, d)
        indenters = cset.report(u, pushes_t)
        tips = {"contact_newton_iterations": tip.iterations, "contact_rounds": tip.rounds,
                "contact_candidate_vertices": tip.candidates,
                "contact_active_vertices": tip.active, "contact_columns": tip.columns}
    F = (model.matrix() @ u.reshape(-1)).reshape(n, d)   # model.forces(u), as one product
    r = F - f + r_tips
    if cset is not None:
        residual = float(np.abs(np.einsum("nab,nb->na", types.projector(), r)).max(initial=0.0))
    reactions = region_reactions(case, r)
    wall = time.perf_counter() - t0
    state = deformation_state(case.mesh, u)
    if indenters:
        state = through_surface_state(state, {"indenters": indenters})
    return SolveResult(
        u=u, converged=converged, iterations=iterations, residual=residual,
        wall_time_s=wall, solver="mass-tensor", probes=case.probe_values(u), reactions=reactions,
        strain_energy=0.5 * float(np.vdot(u, F)), load_steps=1, degree=1, case_name=case.name,
        n_vertices=n, n_cells=case.mesh.n_cells, history={"max_step_mm": steps},
        valid=state.pop("valid"), invalid_reason=state.pop("invalid_reason"),
        min_J=state.pop("min_J"), model="linear-elastic", indenters=indenters,
        warnings=case.glued_patch_warnings(u),
        model_note=(f"the Mass Tensor Method is a linear model: it solved linear elasticity "
                    f"with the case's E and nu, not its {case.material.model} material"
                    if case.material.model != "linear-elastic" else None),
        extra={"method": method, "stop_mm": float(stop_mm), "point_types": types.counts(),
               **tips, **state})


def region_reactions(case, r):
    """Region -> (d,) reaction (mN): r summed over the region's prescribed dofs / normals."""
    d = case.mesh.gdim
    c = case.constraints
    out = case.prescribed_reactions(r)
    oblique = [b for b in case.boundaries if b.type == "sliding"
               and axis_of(np.asarray(b.normal, float) / np.linalg.norm(b.normal)) is None]
    taken = np.zeros((case.mesh.n_vertices, d), bool)
    taken.reshape(-1)[c.dofs] = True
    for b, (vs, nrm, _) in zip(oblique, c.sliding):
        out.setdefault(b.region, np.zeros(d))
        pure = ~taken[vs].any(axis=1)               # only the sliding condition on the vertex
        out[b.region] += (r[vs[pure]] @ nrm).sum() * nrm
        mixed = vs[~pure]                           # prescribed dofs already counted by owner
        out[b.region] += np.where(taken[mixed], 0.0, r[mixed]).sum(axis=0)
        taken[vs] = True                            # a vertex counts once
    return out
