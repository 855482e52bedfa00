"""The indenter phantom (meshes/cases/phantom-indenter.toml: four 5 mm spheres, frictionless
contact) with A1 pushed: P1 on the shipped mesh (1.6 mm cells at the sites) against P2 on a
mesh with coarser sites, whose curved surface the through-the-skin check samples.

Prints per discretization: cells, unknowns, push, converged, valid (and why not), the deepest
point of the skin inside the tip (surface_penetration, mm; the limit is 5 % of the radius), the
nodal penetration (mm), the indenter force (mN), T1 (mm), Newton iterations, load steps and wall
time; then the P2 / P1 ratios of the force and of |T1| measured in this run.

    .venv/bin/python bench/bench_indenter_phantom.py [--push 5] [--p2-site 3.2]
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "meshes" / "cases" / "phantom-indenter.toml"


def one(degree: int, site: float | None, push: float) -> dict:
    import tissue_reference.fem_reference as fr
    from tissue_reference.meshes.builders import phantom
    from tissue_reference.meshes.case import load_case
    from tissue_reference.meshes.errors import ConvergenceError

    case = load_case(CASE)
    if site is not None:
        case = dataclasses.replace(case, mesh=phantom(6.0, site_size=site))
    s = fr.ReferenceSolver(case, degree=degree)
    t0 = time.perf_counter()
    try:
        res, converged = s.solve({"A1": push}), True
    except ConvergenceError as exc:
        res, converged = exc.last_converged, False
    ind = res.extra["indenters"]["A1"]
    return {"degree": degree, "cells": case.mesh.n_cells,
            "dofs": res.extra["discretization"]["dofs"], "push": ind["push"],
            "converged": converged, "valid": bool(res.extra.get("valid", True)),
            "why": res.extra.get("invalid_reason"), "surface_mm": ind.get("surface_penetration"),
            "nodal_mm": ind["max_penetration"], "force_mN": ind["force"],
            "T1": np.asarray(res.probes["T1"]), "newton": res.iterations,
            "steps": res.load_steps, "wall_s": time.perf_counter() - t0}


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--push", type=float, default=5.0, help="A1 push (mm)")
    ap.add_argument("--p2-site", type=float, default=3.2,
                    help="cell size (mm) at the sites of the P2 mesh")
    args = ap.parse_args()
    rows = [one(1, None, args.push), one(2, args.p2_site, args.push)]
    print(f"phantom-indenter, A1 = {args.push:g} mm (tip radius 5 mm: surface limit 0.25 mm)")
    print(f"{'deg':>3} {'cells':>7} {'dofs':>7} {'push':>6} {'conv':>5} {'valid':>5} "
          f"{'surface_mm':>10} {'nodal_mm':>8} {'force_mN':>9} {'T1_x':>8} {'T1_z':>8} "
          f"{'newton':>6} {'steps':>5} {'wall_s':>7}")
    for r in rows:
        print(f"{r['degree']:3d} {r['cells']:7d} {r['dofs']:7d} {r['push']:6.2f} "
              f"{r['converged']!s:>5} {r['valid']!s:>5} {r['surface_mm']:10.3f} "
              f"{r['nodal_mm']:8.4f} {r['force_mN']:9.1f} {r['T1'][0]:8.4f} {r['T1'][2]:8.4f} "
              f"{r['newton']:6d} {r['steps']:5d} {r['wall_s']:7.1f}")
        if not r["valid"]:
            print(f"    invalid: {r['why']}")
    p1, p2 = rows
    print(f"P2 / P1: force {p2['force_mN'] / p1['force_mN']:.3f}, |T1| "
          f"{np.linalg.norm(p2['T1']) / np.linalg.norm(p1['T1']):.3f}, wall "
          f"{p2['wall_s'] / p1['wall_s']:.1f}x")


if __name__ == "__main__":
    main()
