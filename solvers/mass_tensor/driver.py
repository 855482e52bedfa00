"""Case level: the point types of a Case, the model cache, ``solve(case, ...)`` returning a
``SolveResult`` (solver "mass-tensor") and the reactions per Dirichlet region."""
from __future__ import annotations

import time

import numpy as np

from tissue_reference.meshes.case_constraints import axis_of
from tissue_reference.meshes.mesh import deformation_state
from tissue_reference.meshes.results import SolveResult

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
    """Drop the direct solve's kept factorizations and the AMG hierarchies (the tensors stay):
    the next solve of each pattern of point types makes them again, as a first solve does."""
    for m in MODEL_CACHE.values():
        m._factors.clear()


def require_modeled(case) -> None:
    """NotModeledError when ``case`` has what this linear model cannot hold: a rigid tip's
    contact."""
    case.require_no_contact("the Mass Tensor solver")


def solve(case, *, pushes=None, initial=None, method: str = "direct", stop_mm: float = 0.01,
          max_iter: int = 200000, callback=None, progress: bool = False,
          step_scale: float | None = None, factorize=None) -> SolveResult:
    """Mass Tensor solve of a Case (linear elasticity with the Case's E, nu, whatever its model).

    pushes: actuator name -> push (mm); initial (n, d) mm warm start; method "direct" (default),
    "amg" | "pcg" | "descent" (``model.METHODS``); stop_mm: stopping rule of the iterations and
    of the surface-sliding rounds (largest per-vertex displacement in one iteration, mm; "amg":
    the distance still to go estimated from those, below half of it); callback(it, u)
    every iteration; factorize: the direct solve's factorization hook
    (``MassTensorModel.solve``). Returns SolveResult(solver="mass-tensor"): u (n, d) mm, probes (mm),
    reactions per Dirichlet region = sum over its prescribed directions of F(u) - f_ext (mN),
    strain_energy 1/2 u.F(u) (kPa mm^3), iterations, residual (largest free-direction force
    imbalance, mN), history={"max_step_mm": [...]}.
    """
    t0 = time.perf_counter()
    case.material.require_compressible("the Mass Tensor solver")
    require_modeled(case)
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
    sol = model.solve(types, f_ext=f, initial=initial, method=method, stop_mm=stop_mm,
                      max_iter=max_iter, step_scale=step_scale, callback=cb,
                      factorize=factorize)
    u = sol.u
    F = (model.matrix() @ u.reshape(-1)).reshape(n, d)   # model.forces(u), as one product
    r = F - f
    reactions = region_reactions(case, r)
    wall = time.perf_counter() - t0
    state = deformation_state(case.mesh, u)
    return SolveResult(
        u=u, converged=sol.converged, iterations=sol.iterations, residual=sol.residual,
        wall_time_s=wall, solver="mass-tensor", probes=case.probe_values(u), reactions=reactions,
        strain_energy=0.5 * float(np.vdot(u, F)), load_steps=1, degree=1, case_name=case.name,
        n_vertices=n, n_cells=case.mesh.n_cells, history={"max_step_mm": list(sol.max_step_mm)},
        valid=state.pop("valid"), invalid_reason=state.pop("invalid_reason"),
        min_J=state.pop("min_J"), model="linear-elastic",
        model_note=(f"the Mass Tensor Method is a linear model: it solved linear elasticity "
                    f"with the case's E and nu, not its {case.material.model} material"
                    if case.material.model != "linear-elastic" else None),
        extra={"method": method, "stop_mm": float(stop_mm), "point_types": types.counts(),
               **state})


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
