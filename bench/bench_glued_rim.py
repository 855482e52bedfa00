"""The glued phantom (actuators as glued patches), all four pushed 5 mm: how its answers
converge as the patches' rims are refined, against an independent solve.

The glued patch's rim, where pushed skin meets free skin, is singular, so the answers converge
only as the rim cells shrink (``[mesh] rim_size``). Each level is the quarter model
(meshes/cases/phantom-quarter.toml, mirror planes sliding) at size 6 with rim cells of the given
size, solved at the given degree. Printed per level: cells, unknowns, T1..T3 (mm), the whole
phantom's A1 force (mN: twice the cut patch's), the smallest J, Newton iterations, wall time;
T1 u_z against the independent textbook solve refined at the rims
(tests/data/phantom_reference.json: its value on rim cells of the same size where it has one,
and its converged interval). Then, per quantity, the assessment over the levels
(``fem_reference.richardson.assess`` with h = the rim cell size: observed order, asymptotic-range
check, Richardson value only when asymptotic) and the finest level's distance from the
independent interval.

    .venv/bin/python bench/bench_glued_rim.py                      # P2, rims 2.4 1.7 1.2 0.85 0.6
    .venv/bin/python bench/bench_glued_rim.py --degree 3 --rims 2.4 1.697 1.2
    .venv/bin/python bench/bench_glued_rim.py --case meshes/cases/phantom.toml --rims 1.2
    .venv/bin/python bench/bench_glued_rim.py --push 10 --volumetric log
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = json.loads((ROOT / "tests" / "data" / "phantom_reference.json").read_text())
PROBES = ("T1", "T2", "T3")
RIMS = [round(2.4 / 2.0 ** (k / 2), 4) for k in range(5)]


def run(case_path: Path, rims, degree: int, push: float, size: float | None,
        volumetric: str | None = None) -> list[dict]:
    import tissue_reference.fem_reference as fr
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.meshes.builders import build
    from tissue_reference.model.case import load_case

    case = load_case(case_path)
    if volumetric is not None:
        case = case.with_material(volumetric=volumetric)
    if case.name not in ("phantom", "phantom-quarter"):
        raise SystemExit(f"{case_path}: a glued phantom case (phantom or phantom-quarter) is "
                         f"needed, got {case.name!r}")
    builder = case.name
    h = size if size is not None else 6.0
    cut = 2.0 if builder == "phantom-quarter" else 1.0    # A1's patch is cut in half
    pushes = {a.name: push for a in case.actuators}
    rows = []
    for rim in rims:
        t0 = time.perf_counter()
        mesh = build(builder, h, rim_size=rim)
        c = case.with_mesh(mesh)
        try:
            res = fr.solve(c, pushes=pushes, degree=degree)
        except ConvergenceError as exc:
            print(f"rim {rim:.2f} mm: {mesh.n_cells} cells: no converged answer ({exc}); the "
                  f"last converged state is at load fraction "
                  f"{exc.last_converged.extra.get('load_fraction')}", flush=True)
            continue
        wall = time.perf_counter() - t0
        row = {"rim_mm": rim, "size_mm": h, "degree": degree, "cells": mesh.n_cells,
               "dofs": res.discretization["dofs"],
               "probes": {n: [float(v) for v in res.probes[n]] for n in PROBES},
               "force_A1_mN": cut * float(-res.reactions["act_px"][0]),
               "min_J": res.extra.get("min_J"), "newton": res.iterations, "wall_s": wall,
               "volumetric": c.material.volumetric}
        rows.append(row)
        print(f"rim {rim:.2f} mm: {row['cells']} cells, {row['dofs']} dofs, T1 "
              f"{np.round(row['probes']['T1'], 4).tolist()} mm, A1 {row['force_A1_mN']:.2f} mN, "
              f"min J {row['min_J']:.3f}, {row['newton']} Newton, {wall:.1f} s", flush=True)
    return rows


def report(rows, push: float, volumetric: str) -> dict:
    from tissue_reference.fem_reference.richardson import assess

    ref = REFERENCE
    lo, hi = ref["converged_T1_uz_mm"]["low"], ref["converged_T1_uz_mm"]["high"]
    indep = dict(zip(ref["rim_cell_mm"], ref["T1_uz_mm"]))
    same = set(ref["pushes_mm"].values()) == {push} and volumetric == "quadratic"
    if same:
        print(f"\nT1 u_z (mm) against the independent solve (converged {lo}-{hi} mm):")
        print(f"  {'rim mm':>6} {'ours':>8} {'indep.':>8} {'diff':>7} {'vs low':>7} "
              f"{'vs high':>7}")
    else:
        print(f"\nno independent value at a push of {push:g} mm with the {volumetric} law "
              f"(tests/data/phantom_reference.json: {ref['pushes_mm']['A1']:g} mm, quadratic)")
    for r in rows if same else ():
        v = r["probes"]["T1"][2]
        other = indep.get(r["rim_mm"])
        diff = "-" if other is None else f"{100 * (v - other) / other:+.2f}%"
        print(f"  {r['rim_mm']:6.2f} {v:8.4f} {other if other is not None else '-':>8} "
              f"{diff:>7} {100 * (v - lo) / lo:+6.2f}% {100 * (v - hi) / hi:+6.2f}%")
    out = {"rows": rows, "quantities": {}}
    if len(rows) < 3:
        print("no convergence assessment: needs 3 levels")
        return out
    h = [r["rim_mm"] for r in rows]   # the rims that converged
    quantities = [("force A1", "mN", [r["force_A1_mN"] for r in rows])]
    for n in PROBES:
        vals = np.array([r["probes"][n] for r in rows])
        for c, axis in enumerate("xyz"):
            if np.abs(vals[:, c]).max() > 1e-3:
                quantities.append((f"{n} u{axis}", "mm", list(vals[:, c])))
    steps = np.array(h[:-1]) / np.array(h[1:])
    if np.ptp(steps) > 1e-3 * steps.mean():
        print(f"no convergence assessment: the rims do not shrink by one ratio ({steps})")
        return out
    ratio = float(steps.mean())
    print(f"\n  {'quantity':>9} {'unit':>4} " + " ".join(f"{'rim ' + format(x, '.2f'):>10}"
                                                    for x in h)
          + f" {'order':>6} {'asym':>5} {'extrap':>10} {'GCI band':>10}")
    for name, unit, vals in quantities:
        a = assess(vals, h, expected_order=1.0, ratio=ratio, name=name, unit=unit)
        out["quantities"][name] = a.to_json_dict()
        order = "-" if a.observed_order is None else f"{a.observed_order:.2f}"
        ext = "-" if a.extrapolated is None else f"{a.extrapolated:.4f}"
        print(f"  {name:>9} {unit:>4} " + " ".join(f"{v:10.4f}" for v in vals)
              + f" {order:>6} {a.asymptotic!s:>5} {ext:>10} {a.gci:10.4f}")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", type=Path, default=ROOT / "meshes/cases/phantom-quarter.toml")
    ap.add_argument("--rims", type=float, nargs="+", default=RIMS,
                    help="rim cell sizes (mm), coarse to fine, shrinking by one ratio for the "
                         "assessment; default 2.4 / sqrt(2)^k, k = 0..4")
    ap.add_argument("--degree", type=int, default=2)
    ap.add_argument("--push", type=float, default=5.0, help="every actuator's push (mm)")
    ap.add_argument("--size", type=float, help="characteristic size (mm); default 6")
    ap.add_argument("--volumetric", choices=["quadratic", "log"],
                    help="the Neo-Hookean volumetric law (default: the case's)")
    ap.add_argument("--json", type=Path, help="write the rows and assessments here")
    args = ap.parse_args()
    rows = run(args.case, args.rims, args.degree, args.push, args.size, args.volumetric)
    out = report(rows, args.push, rows[0]["volumetric"] if rows else "quadratic")
    if args.json:
        from tissue_reference.model.results import write_json
        write_json(out, args.json)


if __name__ == "__main__":
    main()
