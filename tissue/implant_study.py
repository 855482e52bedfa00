"""Seed 001's implant planning checked against the reference, end to end (``tissue implant``).

The Mass Tensor prediction is compared with the linear FEM reference (fem_reference, the seed's
"exact FEM solution") solved with the same boundary conditions on the same mesh: ``d_max_mm``
and ``mean_distance_mm`` are the distances from the Mass Tensor predicted skin vertices to the
reference's predicted skin surface, over the breast surface (skin within half the implant width
+ 30 mm of the implant axis). With a post-operative skin surface, it is registered to the
predicted skin by ICP (the seed's validation) and its distances are reported as well.
``muscle_thickness_error_mm`` (synthetic input only): largest distance of the RBF muscle to the
true muscle over the interface points under the implant.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from tissue_reference.implant.pipeline import PlanSettings, plan_implant
from tissue_reference.implant.registration import icp, surface_distances
from tissue_reference.implant.render import render_distance_png, write_surface_vtu
from tissue_reference.meshes.io import write_mesh
from tissue_reference.meshes.mesh import MeshData
from tissue_reference.model.case import Boundary, Case, Material

from .implant_report import write_implant_report


def reference_case(plan, *, model: str = "linear-elastic"):
    """The Case for the reference: same mesh and material, the cut sides fixed (they are border
    points); every other border point and the targets go in through ``plan.dirichlet()`` as
    ``dirichlet_override`` (per-vertex values cannot be one region's Boundary value)."""

    t = plan.tissue
    regions = dict(t.facet_regions)
    regions["implant_contact"] = plan.bc.contact_facets
    mesh = MeshData(t.points, t.cells, regions,
                    {**t.point_regions, "border": plan.bc.border, "implant_targets": plan.bc.target},
                    t.cell_regions)
    s = plan.settings
    return Case(mesh, Material(model, s.E, s.nu), (Boundary("sides", "fixed"),),
                name="implant")


def reference_solve(plan, *, model: str = "linear-elastic"):
    """Reference displacement (n, 3) mm with exactly the plan's step-2 boundary conditions."""
    # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
    from tissue_reference.fem_reference import solve

    case = reference_case(plan, model=model)
    return solve(case, dirichlet_override=plan.dirichlet())


def run_implant_study(patient, settings: PlanSettings, *, reference: bool = True,
                      neo_hookean: bool = False, postop=None, out_dir=None,
                      inputs: dict | None = None) -> dict:
    """Seed 001's plan for ``patient`` with ``settings`` (``implant.pipeline.plan_implant``),
    compared with the linear FEM reference solved with the same boundary conditions on the same
    mesh (``reference``; with ``neo_hookean`` the Neo-Hookean reference too), and with a
    post-operative skin surface registered by ICP (``postop``, a checked surface); with
    ``out_dir`` the meshes, the skin distance (VTU, PNG) and report.html are written there.
    ``inputs``: what the plan was made from, recorded as the result's ``input``. Returns the
    result as the command's JSON holds it."""
    plan = plan_implant(patient, settings)
    skin_t = plan.skin_triangles
    region = plan.breast_region()
    pred = plan.predicted_points
    out = {"implant_volume_cc": float(settings.volume_cc), "d_max_mm": None,
           "mean_distance_mm": None, "solver": "mass-tensor", "iterations": plan.iterations,
           "wall_time_s": plan.wall_time_s,
           "muscle_thickness_error_mm": plan.muscle_thickness_error_mm(),
           "compared": "Mass Tensor predicted skin vertices vs linear FEM reference predicted "
                       "skin surface, same mesh and boundary conditions, breast surface",
           "converged": plan.converged, "implant_iterations": plan.implant_iterations,
           "n_cells": plan.tissue.n_cells, "n_vertices": plan.tissue.n_vertices,
           "points": {k: len(v) for k, v in (("target", plan.bc.target),
                                                  ("border", plan.bc.border),
                                                  ("free_ring", plan.bc.free_ring))},
           "sliding": settings.sliding, "free_ring_mm": settings.free_ring,
           "implant_dimensions_mm": list(settings.spec.dimensions()),
           "placement_centre_mm": plan.placement.centre.tolist(),
           "timings_s": plan.timings,
           # what was computed: the input, the implant, the material and the solver settings
           "case": (inputs or {}).get("skin") or "synthetic",
           "input": inputs,
           "implant": {"shape": settings.shape, "side": settings.side,
                       "volume_cc": float(settings.volume_cc),
                       "at_mm": list(settings.at) if settings.at else None,
                       "width_mm": settings.width, "projection_mm": settings.projection},
           "material": {"model": "linear-elastic", "E_kPa": float(settings.E),
                        "nu": float(settings.nu)},
           "solver_settings": {"method": settings.method, "stop_mm": float(settings.stop_mm),
                               "free_ring_mm": settings.free_ring,
                               "sliding": settings.sliding,
                               "tissue_size_mm": settings.tissue_size}}
    dist = None
    if reference:
        t0 = time.perf_counter()
        ref = reference_solve(plan)
        out["reference_wall_time_s"] = time.perf_counter() - t0
        ref_pts = plan.tissue.points + ref.u
        st = surface_distances(pred, ref_pts, skin_t, region=region)
        out["d_max_mm"], out["mean_distance_mm"] = st.d_max_mm, st.mean_distance_mm
        out["max_vertex_difference_mm"] = float(np.abs(ref.u - plan.u).max())
        dist = st.distance
        if settings.sliding:
            out["compared"] += ("; NOTE: the reference holds the targets (sliding on the implant's "
                                "triangulated surface is not expressible there), so with --sliding "
                                "the distances include the effect of sliding")
        if neo_hookean:
            nh = reference_solve(plan, model="neo-hookean")
            sn = surface_distances(pred, plan.tissue.points + nh.u, skin_t, region=region)
            out["neo_hookean"] = {"d_max_mm": sn.d_max_mm, "mean_distance_mm": sn.mean_distance_mm,
                                  "converged": bool(nh.converged), "load_steps": nh.load_steps}
    if postop is not None:
        sv = np.unique(skin_t)
        # register on the skin away from the operated breast (seed 001 sec. 3: common parts)
        d = postop.points - plan.placement.centre
        ax = plan.placement.axis
        radial = np.linalg.norm(d - np.outer(d @ ax, ax), axis=1)
        away = radial > 0.5 * settings.spec.dimensions()[0] + 30.0
        reg = icp(postop.points[away], pred[sv], np.searchsorted(sv, skin_t),
                  method="point-to-plane", reject_mm=20.0)
        st = surface_distances(pred, reg.transform.apply(postop.points), postop.triangles,
                               region=region)
        out["postop"] = {"d_max_mm": st.d_max_mm, "mean_distance_mm": st.mean_distance_mm,
                         "icp_rms_mm": reg.rms_mm, "icp_iterations": reg.iterations}
        dist = st.distance
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        labels = np.zeros(plan.tissue.n_vertices)
        labels[plan.bc.border] = 1
        labels[plan.bc.target] = 2
        pdata = {"u_mass_tensor": plan.u, "point_type": labels}
        if reference:
            pdata["u_reference"] = ref.u
        write_mesh(plan.tissue, out_dir / "tissue.vtu", point_data=pdata)
        write_surface_vtu(plan.implant_points, plan.implant.shell, out_dir / "implant.vtu")
        if dist is not None:
            d = np.where(np.isin(np.arange(len(dist)), region), dist, 0.0)
            write_surface_vtu(pred, skin_t, out_dir / "skin_distance.vtu",
                              point_data={"distance_mm": d})
            out["render_backend"] = render_distance_png(pred, skin_t, d,
                                                        out_dir / "skin_distance.png")

        write_implant_report(out, out_dir,
                             distance_png="skin_distance.png" if dist is not None else None)
    return out
