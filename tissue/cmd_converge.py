"""``tissue converge CASE [--degrees 1 2] [--levels 4]``: refinement study of the reference."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from meshes.errors import CaseError
from meshes.io import atomic_path
from meshes.results import write_json

from .common import parse_pushes


def run(args) -> int:
    import tomllib

    from fem_reference.convergence import refinement_study
    from meshes.case import load_case

    case = load_case(args.case)
    data = tomllib.loads(Path(args.case).read_text())
    builder = data.get("mesh", {}).get("builtin")
    if builder is None:
        raise CaseError(f"{args.case}: a refinement study needs a builtin mesh (gmsh sizes halved)")
    pushes = parse_pushes(args.push)
    out = {"case": case.name, "pushes": pushes, "studies": []}
    studies = []
    for deg in args.degrees:
        st = refinement_study(case, builder, coarsest=args.coarsest, levels=args.levels,
                              degree=deg, pushes=pushes, progress=True)
        studies.append(st)
        out["studies"].append({
            "degree": deg, "sizes_mm": st.sizes, "n_cells": st.n_cells,
            "probes_mm": {k: v.tolist() for k, v in st.probes.items()},
            "observed_order": st.order,
            "richardson_mm": {k: np.asarray(v).tolist() for k, v in st.extrapolated.items()}})
        for k in st.probes:
            print(f"degree {deg} {k}: |u| = " + ", ".join(f"{np.linalg.norm(x):.4f}" for x in st.probes[k])
                  + f" mm; observed order {st.order[k]:.2f}; Richardson |u| "
                  f"{np.linalg.norm(st.extrapolated[k]):.4f} mm")
    if args.json:
        write_json(out, args.json)
    if args.out:
        plot(studies, Path(args.out) / "convergence.png")
        write_json(out, Path(args.out) / "convergence.json")
        print(f"wrote {Path(args.out) / 'convergence.png'}", file=sys.stderr)
    return 0


def plot(studies, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for st in studies:
        for k, q in st.probes.items():
            err = [np.linalg.norm(x - st.extrapolated[k]) for x in q]
            ax.loglog(st.sizes, np.maximum(err, 1e-12), "o-", label=f"P{st.degree} {k}")
    ax.set_xlabel("h (mm)")
    ax.set_ylabel("|u - u_Richardson| at probe (mm)")
    ax.set_title("Reference refinement study")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def add_parser(sub):
    p = sub.add_parser("converge", help="mesh-refinement study of the reference")
    p.add_argument("case")
    p.add_argument("--degrees", type=int, nargs="+", default=[1], choices=(1, 2))
    p.add_argument("--levels", type=int, default=4)
    p.add_argument("--coarsest", type=float, default=16.0, help="coarsest mesh size (mm)")
    p.add_argument("--push", action="append", metavar="NAME=MM", default=None)
    p.add_argument("--out", help="folder for the plot and JSON")
    p.add_argument("--json", help="JSON file")
    p.set_defaults(func=run)
