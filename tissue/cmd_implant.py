"""``tissue implant``: seed 001's implant planning end to end, checked against the reference.

    tissue implant --synthetic --volume 245 --shape round --side left --json out.json [--out DIR]
    tissue implant --skin skin.stl --thickness 15 20 15 --volume 245 --json out.json

The Mass Tensor prediction is compared with the linear FEM reference (fem_reference, the seed's
"exact FEM solution") solved with the same boundary conditions on the same mesh: ``d_max_mm``
and ``mean_distance_mm`` are the distances from the Mass Tensor predicted skin vertices to the
reference's predicted skin surface, over the breast surface (skin within half the implant width
+ 30 mm of the implant axis). With ``--postop FILE`` a post-operative skin surface is registered
to the predicted skin by ICP (the seed's validation) and its distances are reported as well.
``muscle_thickness_error_mm`` (synthetic input only): largest distance of the RBF muscle to the
true muscle over the interface points under the implant.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from tissue_reference.implant.pipeline import (
    PlanSettings,
    patient_from_file,
    plan_implant,
    synthetic_patient,
)
from tissue_reference.implant.registration import icp, surface_distances
from tissue_reference.implant.render import render_distance_png, write_surface_vtu
from tissue_reference.implant.surface import check_single_sheet, read_surface
from tissue_reference.meshes.case import Boundary, Case, Material
from tissue_reference.meshes.errors import CaseError, ReadError
from tissue_reference.meshes.io import check_output_file, write_mesh
from tissue_reference.meshes.mesh import MeshData
from tissue_reference.meshes.results import write_json

from .common import check_outputs, real
from .implant_report import write_implant_report

WIDTH_MM = (40.0, 300.0)        # base widths of the implants in use, with a margin
PROJECTION_RATIO = (0.1, 1.0)   # projection / width


def add_parser(sub) -> None:
    p = sub.add_parser("implant", help="seed 001 breast implant planning (Mass Tensor vs FEM)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--skin", type=Path, help="skin surface (STL, PLY, OBJ, VTK), mm, x = "
                     "patient's left, y up, z anterior")
    src.add_argument("--synthetic", action="store_true", help="synthetic torso with known muscle")
    p.add_argument("--thickness", type=real("finite", "mm", magnitude=1e4), nargs=3,
                   metavar=("A", "B", "C"),
                   help="tissue thickness (mm): right lateral, sternum, left lateral")
    p.add_argument("--thickness-x", type=real("finite", "mm", magnitude=1e4), nargs=3,
                   metavar=("XA", "XB", "XC"),
                   help="x (mm) of the three thickness planes (default: from the skin's extent)")
    p.add_argument("--volume", type=real("positive", "cc"), default=245.0,
                   help="implant volume (cc)")
    p.add_argument("--shape", choices=["round", "anatomical"], default="round",
                   help="implant shape from the library")
    p.add_argument("--side", choices=["left", "right"], default="left", help="breast side")
    p.add_argument("--at", type=real("finite", "mm", magnitude=1e4), nargs=2,
                   metavar=("X", "Y"),
                   help="implant centre seen from the front (mm); default under the breast")
    p.add_argument("--width", type=real("positive", "mm", at_least=WIDTH_MM[0],
                                        at_most=WIDTH_MM[1]), help="implant base width (mm)")
    p.add_argument("--projection", type=real("positive", "mm", at_least=4.0, at_most=300.0),
                   help="implant projection (mm)")
    p.add_argument("--free-ring", type=real("nonneg", "mm"), default=30.0,
                   help="free ring around the implant (mm, 0 = none; seed: 30)")
    p.add_argument("--sliding", action="store_true",
                   help="switch target points to sliding on the implant once reached")
    p.add_argument("--method", choices=["direct", "pcg", "descent"], default="direct",
                   help="how the Mass Tensor solve reaches equilibrium: direct (one sparse "
                        "factorization per phase or sliding round), or iterations stopped at "
                        "the seed's 0.01 mm rule (descent = the seed's, pcg)")
    p.add_argument("--no-reference", action="store_true",
                   help="skip the FEM reference comparison (d_max/mean reported as null)")
    p.add_argument("--neo-hookean", action="store_true",
                   help="also solve the Neo-Hookean reference and report its distances")
    p.add_argument("--postop", type=Path, help="post-operative skin surface to validate against")
    p.add_argument("--out", type=Path, help="folder for tissue.vtu, implant.vtu, "
                   "skin_distance.vtu/.png and report.html")
    p.add_argument("--json", type=Path, required=True, help="result JSON")
    p.set_defaults(func=run)


def check_dimensions(spec, args):
    """CaseError naming --volume / --width / --projection when the implant they give (scaled to
    the volume) has a base width outside WIDTH_MM (mm) or a projection outside PROJECTION_RATIO
    of its width: no such implant exists and its surface cannot be built."""
    w, _, p = spec.dimensions()
    given = " ".join(f"{o} {v:g}" for o, v in (("--volume", args.volume), ("--width", args.width),
                                               ("--projection", args.projection))
                     if v is not None)
    if not (WIDTH_MM[0] <= w <= WIDTH_MM[1] and
            PROJECTION_RATIO[0] <= p / w <= PROJECTION_RATIO[1]):
        raise CaseError(f"{given}: the implant would be {w:.4g} mm wide with a projection of "
                        f"{p:.4g} mm; expected a width of {WIDTH_MM[0]:g} to {WIDTH_MM[1]:g} mm "
                        f"and a projection of {PROJECTION_RATIO[0]:g} to {PROJECTION_RATIO[1]:g} "
                        f"times the width")


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


def run(args) -> int:

    check_outputs(args, files=("json",), dirs=("out",))
    if args.out is not None and args.out.is_dir():
        check_output_file(args.out / "report.html", "--out")
    for opt, f in (("--skin", args.skin), ("--postop", args.postop)):
        if f is not None and not f.is_file():
            raise ReadError(f"{opt} {str(f)!r}: "
                            f"{'is a directory' if f.is_dir() else 'does not exist'}, expected a "
                            f"surface file (STL, PLY, OBJ, VTK)")
    if args.skin is not None:
        if args.thickness is None:
            raise CaseError("--skin needs --thickness A B C (mm)")
        patient = patient_from_file(args.skin, *args.thickness, x_planes=args.thickness_x)
    else:
        if args.thickness is not None:
            raise CaseError("--thickness goes with --skin; the synthetic torso has its own")
        patient = synthetic_patient()
    settings = PlanSettings(shape=args.shape, volume_cc=args.volume, side=args.side,
                            at=tuple(args.at) if args.at else None, width=args.width,
                            projection=args.projection, free_ring=args.free_ring or None,
                            sliding=args.sliding, method=args.method)
    check_dimensions(settings.spec, args)
    postop = None
    if args.postop is not None:  # read and check before any solve
        postop = check_single_sheet(read_surface(args.postop), source=f"{args.postop}")
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
           "case": "synthetic" if args.skin is None else str(args.skin),
           "input": {"skin": None if args.skin is None else str(args.skin),
                     "synthetic": args.skin is None,
                     "thickness_mm": list(args.thickness) if args.thickness else None,
                     "thickness_x_mm": list(args.thickness_x) if args.thickness_x else None,
                     "postop": None if args.postop is None else str(args.postop)},
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
    if not args.no_reference:
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
        if args.neo_hookean:
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
    if args.out is not None:

        args.out.mkdir(parents=True, exist_ok=True)
        labels = np.zeros(plan.tissue.n_vertices)
        labels[plan.bc.border] = 1
        labels[plan.bc.target] = 2
        pdata = {"u_mass_tensor": plan.u, "point_type": labels}
        if not args.no_reference:
            pdata["u_reference"] = ref.u
        write_mesh(plan.tissue, args.out / "tissue.vtu", point_data=pdata)
        write_surface_vtu(plan.implant_points, plan.implant.shell, args.out / "implant.vtu")
        if dist is not None:
            d = np.where(np.isin(np.arange(len(dist)), region), dist, 0.0)
            write_surface_vtu(pred, skin_t, args.out / "skin_distance.vtu",
                              point_data={"distance_mm": d})
            out["render_backend"] = render_distance_png(pred, skin_t, d,
                                                        args.out / "skin_distance.png")

        write_implant_report(out, args.out,
                             distance_png="skin_distance.png" if dist is not None else None)
    write_json(out, args.json)
    print(f"implant {settings.volume_cc:g} cc {settings.shape} {settings.side}: "
          f"{plan.iterations} Mass Tensor iterations, {plan.wall_time_s:.2f} s; "
          + (f"d_max {out['d_max_mm']:.3g} mm, mean {out['mean_distance_mm']:.3g} mm "
             f"(Mass Tensor against the linear FEM reference)" if out["d_max_mm"] is not None
             else "no FEM reference comparison (--no-reference)"))
    return 0
