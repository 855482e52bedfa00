"""``tissue implant``: seed 001's implant planning end to end, checked against the reference.

    tissue implant --synthetic --volume 245 --shape round --side left --json out.json [--out DIR]
    tissue implant --skin skin.stl --thickness 15 20 15 --volume 245 --json out.json

What is compared and how: ``tissue.implant_study``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from tissue_reference.errors import CaseError, ReadError
from tissue_reference.implant.pipeline import (
    PlanSettings,
    patient_from_file,
    synthetic_patient,
)
from tissue_reference.implant.surface import check_single_sheet, read_surface
from tissue_reference.meshes.io import check_output_file
from tissue_reference.model.results import write_json
from tissue_reference.solvers.mass_tensor import METHODS

from .common import check_outputs, real
from .implant_study import run_implant_study

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
    p.add_argument("--method", choices=list(METHODS), default="direct",
                   help="how the Mass Tensor solve reaches equilibrium: direct (one sparse "
                        "factorization per phase or sliding round), amg (conjugate gradients "
                        "with an AMG preconditioner, stopped when an estimate of the distance "
                        "to go is below half of 0.01 mm: for large meshes), or iterations "
                        "stopped at the seed's 0.01 mm rule (descent = the seed's, pcg)")
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
    inputs = {"skin": None if args.skin is None else str(args.skin),
              "synthetic": args.skin is None,
              "thickness_mm": list(args.thickness) if args.thickness else None,
              "thickness_x_mm": list(args.thickness_x) if args.thickness_x else None,
              "postop": None if args.postop is None else str(args.postop)}
    out = run_implant_study(patient, settings, reference=not args.no_reference,
                            neo_hookean=args.neo_hookean, postop=postop, out_dir=args.out,
                            inputs=inputs)
    write_json(out, args.json)
    print(f"implant {settings.volume_cc:g} cc {settings.shape} {settings.side}: "
          f"{out['iterations']} Mass Tensor iterations, {out['wall_time_s']:.2f} s; "
          + (f"d_max {out['d_max_mm']:.3g} mm, mean {out['mean_distance_mm']:.3g} mm "
             f"(Mass Tensor against the linear FEM reference)" if out["d_max_mm"] is not None
             else "no FEM reference comparison (--no-reference)"))
    return 0
