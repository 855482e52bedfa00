"""``tissue converge CASE [--size MM] [--levels 3] [--degrees 1 2] [--push A1=5]
[--levels-by uniform|remesh] [--ratio R] [--json FILE] [--out DIR] [--max-cells N]``:
mesh-convergence study of the reference on nested uniform refinements of the case mesh, or on
its builtin remeshed with every cell size divided by sqrt 2 per level
(``fem_reference.convergence``). Lengths mm, forces mN."""
from __future__ import annotations

import sys
import tomllib
from pathlib import Path

from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import BODY_DIMENSIONS, estimate_cells
from tissue_reference.meshes.io import check_output_file
from tissue_reference.model.case import TIP_STARTS, Material
from tissue_reference.model.case_file import case_path
from tissue_reference.model.results import material_json, write_json

from .common import (
    announce_build,
    builtin_of,
    check_outputs,
    contact_rule,
    integer,
    parse_pushes,
    real,
)
from .converge_report import write_converge_report

PRECHECK_FROM_CELLS = 20_000
OUT_FILES = ("convergence.png", "convergence.json", "report.html")


def _material_of(path) -> Material:
    """The material of a case file (read after the study has loaded the same file)."""
    data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    return Material.from_table(data.get("material", {}))


def run(args) -> int:
    # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
    from tissue_reference.fem_reference.convergence import (
        MAX_CELLS,
        format_study,
        plot_studies,
        run_study,
        study_to_json,
    )
    from tissue_reference.fem_reference.newton_settings import settings_json
    from tissue_reference.fem_reference.solver import resolve_formulation

    check_outputs(args, files=("json",), dirs=("out",))
    if args.out and Path(args.out).is_dir():
        for name in OUT_FILES:
            check_output_file(Path(args.out) / name, "--out")
    pushes = parse_pushes(args.push)
    limit = args.max_cells or MAX_CELLS
    remesh = args.levels_by == "remesh"
    if args.ratio is not None and not remesh:
        raise CaseError(f"--ratio {args.ratio:g}: uniform refinement halves h; a ratio applies "
                        f"to --levels-by remesh")
    b = builtin_of(args.case, args.size)
    if b is not None and not remesh:
        # the finest mesh's estimate, before a costly coarsest mesh is built (a cheap one is
        # built and counted exactly by run_study)
        try:
            est = estimate_cells(*b)
        except CaseError:
            est = None  # the case loader names the fault
        grow = 2 ** BODY_DIMENSIONS.get(b[0], 3)
        if est is not None and est > PRECHECK_FROM_CELLS and \
                est * grow ** (args.levels - 1) > limit:
            raise CaseError(
                f"the finest of {args.levels} meshes would have about "
                f"{est * grow ** (args.levels - 1):,} cells (builtin {b[0]!r} at size {b[1]:g} "
                f"mm: about {est:,} cells, x {grow}^{args.levels - 1}), more than the limit of "
                f"{limit:,} (--max-cells): use a larger --size, fewer --levels or raise the "
                f"limit")
        announce_build("converge", *b, args.max_cells)
    # remeshed levels: run_study estimates every level's cells before building any
    solver_options = {k: v for k, v in (("contact_quadrature", args.contact_quadrature),
                                        ("tip_start", args.tip_start)) if v is not None}
    studies = run_study(args.case, size=args.size, degrees=args.degrees, levels=args.levels,
                        pushes=pushes, max_cells=args.max_cells or MAX_CELLS,
                        progress=not args.quiet, formulation=args.formulation,
                        levels_by=args.levels_by, ratio=args.ratio, **solver_options)
    ratio = studies[0].ratio
    material = _material_of(args.case)
    form = resolve_formulation(args.formulation, material)
    out = {"case": studies[0].case_name, "source": str(args.case),
           "size_mm": b[1] if b is not None else None,
           "pushes_mm": pushes, "material": material_json(material), "formulation": form,
           "degrees": list(args.degrees), "levels": args.levels, "levels_by": args.levels_by,
           "refinement_ratio": ratio,
           "h_definition": (f"mean edge length of the coarsest mesh, divided by {ratio:.6g} per "
                            f"level as the cell sizes are (mm; each level's measured mean edge: "
                            f"mean_edge_mm)" if remesh else
                            "mean edge length of the coarsest mesh, halved per level (mm)"),
           "max_cells": limit,
           "solver_settings": settings_json(),
           # uniform levels straight-sided unless every level carries curved edges
           # (fem_reference.convergence); the solver's geometry order as solved
           "studies": [{**study_to_json(st), "formulation": form,
                        "pressure_degree": st.degree - 1 if form == "mixed" else None,
                        "geometry_order": st.geometry_order} for st in studies]}
    for st in studies:
        print(format_study(st))
        print()
    if args.json:
        write_json(out, args.json)
    if args.out:
        png = plot_studies(studies, Path(args.out) / "convergence.png")
        write_json(out, Path(args.out) / "convergence.json")
        page = write_converge_report(out, args.out, plot=png.name)
        print(f"wrote {png} (differences between successive levels against h, slopes 1 and 2), "
              f"{Path(args.out) / 'convergence.json'} and {page}", file=sys.stderr)
    return 0


def add_parser(sub):
    p = sub.add_parser("converge", help="mesh-convergence study of the reference (nested "
                                        "uniform refinement or remeshed levels, observed "
                                        "orders, GCI)")
    p.add_argument("case", type=case_path,
                   help="case TOML file, or a shipped case's name (e.g. phantom)")
    p.add_argument("--size", type=real("positive", "mm"), default=None,
                   help="characteristic length (mm) of the coarsest mesh (builtin meshes; "
                        "default: the case's own mesh)")
    p.add_argument("--levels", type=integer(3, 12, "at least 3 meshes: an observed order "
                                                  "takes three"), default=3,
                   help="number of meshes: the coarsest and levels-1 uniform refinements or "
                        "remeshed levels (>= 3; 4 or more to confirm the observed order)")
    p.add_argument("--levels-by", choices=("uniform", "remesh"), default="uniform",
                   help="uniform: each level splits every cell of the previous (h halved); "
                        "remesh (a builtin mesh only): level k is the builtin built again with "
                        "every cell size of the case's [mesh] table (size, site_size, "
                        "path_size, rim_size, base_rim_size) divided by --ratio^k, as the "
                        "indenter phantom's refinement studies are")
    p.add_argument("--ratio", type=real("positive"), default=None,
                   help="--levels-by remesh: the factor the cell sizes shrink by per level "
                        "(default sqrt 2: about 2.8x the cells per level in 3D)")
    p.add_argument("--degrees", type=int, nargs="+", default=[1], choices=(1, 2, 3),
                   help="Lagrange degrees to study, one refinement study each")
    p.add_argument("--push", action="append", metavar="NAME=MM", default=None,
                   help="push an actuator along its direction (repeatable)")
    p.add_argument("--formulation", choices=("auto", "displacement", "mixed"), default="auto",
                   help="reference formulation (auto: mixed u-p for nu >= 0.49, which needs "
                        "--degrees 2 or 3)")
    p.add_argument("--contact-quadrature", type=contact_rule, default=None, metavar="RULE",
                   help="where indenters' contact is sampled: 'nodal' (the skin's nodes) or a "
                        "Gauss degree on the skin's facets; default: the case's [reference] "
                        "contact_quadrature, else nodal")
    p.add_argument("--tip-start", choices=TIP_STARTS, default=None,
                   help="where indenters start: touching the skin's nodes or its curved facets; "
                        "default: the case's [reference] tip_start, else nodes with the nodal "
                        "contact rule and surface with a Gauss rule")
    p.add_argument("--max-cells", type=integer(1), default=None,
                   help="refuse a study whose finest mesh would exceed this many cells "
                        "(default 400,000; each uniform refinement multiplies cells by 8 in 3D; "
                        "remeshed levels are estimated before any is built)")
    p.add_argument("--out", help="folder for convergence.png, convergence.json and report.html "
                                 "(the study's tables with units, and the plot)")
    p.add_argument("--json", help="JSON file")
    p.set_defaults(func=run)
