"""How much of A1's force drift (8 mm tip, A1 alone, half phantom) is the base rim, where the
fixed base meets the free dome: a level of the wide-tip study (``bench_indenter_convergence.py
--load one --radius 8 --path 0.5 --contact-quadrature 2``) with the cells at the base rim refined
locally (``meshes.refine_local``, longest-edge bisection, new boundary vertices projected onto
the dome), ``--passes`` times: pass i refines the cells whose centroid lies within ``--band`` /
2^i mm of the base and of the dome's equator. Per push: A1's force (the whole tip's, mN) and T1
(mm) of the refined level beside the same level without the refinement and the next finer level
(tests/data/phantom_indenter_reference.json, ``one_wide``), and the relative changes.

    .venv/bin/python bench/bench_base_rim.py --level -2 [--passes 2] [--band 4] [--pushes 5 10]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from bench_indenter_convergence import level_sizes  # the levels' cell sizes (this folder)

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "phantom_indenter_reference.json"
RADIUS = 8.0   # mm, the wide tips


def refined_case(level: int, passes: int, band: float):
    from tissue_reference.meshes.builders import PHANTOM, build
    from tissue_reference.meshes.refine import projector_for
    from tissue_reference.meshes.refine_local import refine_local
    from tissue_reference.model.case import load_case

    size, site = level_sizes(level)
    mesh = build("phantom-half", size, site_size=site, path_size=0.5 * site)
    project = projector_for("phantom-half")
    for i in range(passes):
        c = mesh.points[mesh.cells].mean(axis=1)
        near = band / 2 ** i
        mesh = refine_local(mesh, (c[:, 2] < near) &
                            (np.hypot(c[:, 0], c[:, 1]) > PHANTOM.radius - near),
                            project=project)
    case = load_case(ROOT / "meshes" / "cases" / "phantom-indenter-half.toml", mesh=mesh)
    return dataclasses.replace(case, actuators=tuple(dataclasses.replace(a, radius=RADIUS)
                                                     for a in case.actuators))


def main():
    import tissue_reference.fem_reference as fr

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--level", type=int, default=-2)
    ap.add_argument("--passes", type=int, default=2)
    ap.add_argument("--band", type=float, default=4.0, help="mm, the first pass's reach")
    ap.add_argument("--pushes", type=float, nargs="+", default=[5.0, 10.0])
    args = ap.parse_args()
    study = {e["push_mm"]: e for e in json.loads(DATA.read_text())["loads"]["one_wide"]["pushes"]}
    case = refined_case(args.level, args.passes, args.band)
    s = fr.ReferenceSolver(case, degree=2, contact_quadrature=2)
    print(f"level {args.level}, base rim refined {args.passes}x within {args.band:g} mm: "
          f"{case.mesh.n_cells} cells", flush=True)
    prev = None
    for push in args.pushes:
        t0 = time.perf_counter()
        prev = s.solve({"A1": push}, initial=prev)
        force = 2.0 * prev.indenters["A1"]["force"]   # the half phantom cuts A1 in two
        e = study.get(push)
        line = (f"push {push:g} mm: {prev.discretization['dofs']} dofs, force "
                f"{force:.2f} mN, T1 {np.round(prev.probes['T1'], 4).tolist()} mm, "
                f"{time.perf_counter() - t0:.0f} s")
        if e is not None and args.level in e["levels"]:
            i = e["levels"].index(args.level)
            same = e["force_mN"][i]
            line += (f"; without the rim refinement {same:.2f} mN "
                     f"({100 * (force / same - 1):+.2f} %)")
            if i + 1 < len(e["levels"]):
                finer = e["force_mN"][i + 1]
                line += (f", level {e['levels'][i + 1]} {finer:.2f} mN "
                         f"({100 * (finer / same - 1):+.2f} % from it)")
        print(line, flush=True)


if __name__ == "__main__":
    main()
