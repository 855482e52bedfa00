"""How far the shipped indenter phantom's default discretization is from the converged answer,
and what it costs, against the previous default, measured in one run.

The default is what ``tissue solve meshes/cases/phantom-indenter.toml --push ...`` solves: the
case's mesh (size, site_size) at the case's ``[reference] degree``. The previous default was P1
on 1.6 mm site cells (``--old``: solved in the same run, for the ratios). The converged answer is
the finest level of the refinement study shipped in tests/data/phantom_indenter_reference.json
(P2 on the phantom's symmetric parts, cells divided by sqrt 2 per level, from
bench/bench_indenter_convergence.py); the spread of its levels is printed with it, so the
comparison says how well the converged value itself is known.

Per load (A1 alone at 5 mm; all four at 5 mm): the A1 force (mN) and the targets' displacements
(mm) of each discretization, the relative difference of each to the finest level (targets:
|u - u_ref| / |u_ref|), Newton iterations, wall time, and the ratios new / old.

    .venv/bin/python bench/bench_default_accuracy.py [--loads one four] [--push 5] [--old]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "meshes" / "cases" / "phantom-indenter.toml"
DATA = ROOT / "tests" / "data" / "phantom_indenter_reference.json"
LOADS = {"one": ("A1",), "four": ("A1", "A2", "A3", "A4")}


def finest(load: str, push: float) -> dict | None:
    """The finest level's answer at ``push`` and the spread of all levels (relative); None when
    no level of the study reached that push."""
    doc = json.loads(DATA.read_text())["loads"][load]
    entry = next((e for e in doc["pushes"] if e["push_mm"] == push and e["levels"]), None)
    if entry is None:
        return None
    force = np.array(entry["force_mN"])
    probes = {n: np.array(v) for n, v in entry["probes_mm"].items()}
    spread = {"force": float(np.ptp(force) / abs(force[-1]))}
    for n, v in probes.items():
        spread[n] = float(max(np.linalg.norm(a - v[-1]) for a in v) / np.linalg.norm(v[-1]))
    return {"level": entry["levels"][-1], "levels": entry["levels"], "valid": entry["valid"],
            "dofs": entry["dofs"][-1], "force": float(force[-1]),
            "probes": {n: v[-1] for n, v in probes.items()}, "spread": spread}


def solve(load: str, push: float, degree: int | None, site: float | None) -> dict:
    import tissue_reference.fem_reference as fr
    from tissue_reference.meshes.builders import phantom
    from tissue_reference.meshes.case import load_case
    from tissue_reference.meshes.errors import ConvergenceError

    case = load_case(CASE)
    if site is not None:
        case = dataclasses.replace(case, mesh=phantom(6.0, site_size=site))
    t0 = time.perf_counter()
    try:
        res, converged = fr.solve(case, degree=degree,
                                  pushes={a: push for a in LOADS[load]}), True
    except ConvergenceError as exc:
        res, converged = exc.last_converged, False
    return {"degree": res.extra["discretization"]["degree"], "cells": case.mesh.n_cells,
            "dofs": res.extra["discretization"]["dofs"], "converged": converged,
            "valid": bool(res.extra.get("valid", True)), "why": res.extra.get("invalid_reason"),
            "force": float(res.extra["indenters"]["A1"]["force"]),
            "probes": {n: np.asarray(v) for n, v in res.probes.items()},
            "newton": res.iterations, "wall_s": time.perf_counter() - t0}


def errors(row: dict, ref: dict) -> dict:
    out = {"force": abs(row["force"] - ref["force"]) / abs(ref["force"])}
    for n, v in ref["probes"].items():
        out[n] = float(np.linalg.norm(row["probes"][n] - v) / np.linalg.norm(v))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--loads", nargs="+", choices=sorted(LOADS), default=["one", "four"])
    ap.add_argument("--push", type=float, default=5.0, help="every pushed tip (mm)")
    ap.add_argument("--old", action="store_true",
                    help="also solve the previous default (P1, 1.6 mm sites) for the ratios")
    args = ap.parse_args()
    for load in args.loads:
        ref = finest(load, args.push)
        if ref is None:
            raise SystemExit(f"no level of the study reached {args.push:g} mm for load {load!r}")
        what = "A1 alone" if load == "one" else "all four"
        print(f"\n{what} at {args.push:g} mm; converged answer: level {ref['level']} of the "
              f"study ({ref['dofs']} unknowns on the symmetric part), levels {ref['levels']} "
              f"valid {ref['valid']}; spread of the levels: force "
              f"{100 * ref['spread']['force']:.1f} %, targets "
              + ", ".join(f"{n} {100 * ref['spread'][n]:.1f} %" for n in ref["probes"]))
        rows = [("default", solve(load, args.push, None, None))]
        if args.old:
            rows.append(("old P1", solve(load, args.push, 1, 1.6)))
        print(f"  {'what':>8} {'deg':>3} {'cells':>7} {'dofs':>7} {'valid':>5} {'force_mN':>9} "
              f"{'force err':>9} " + " ".join(f"{n + ' err':>8}" for n in ref["probes"])
              + f" {'newton':>6} {'wall_s':>7}")
        for name, r in rows:
            e = errors(r, ref)
            r["err"] = e
            print(f"  {name:>8} {r['degree']:>3} {r['cells']:>7} {r['dofs']:>7} "
                  f"{r['valid']!s:>5} {r['force']:9.2f} {100 * e['force']:8.2f}% "
                  + " ".join(f"{100 * e[n]:7.2f}%" for n in ref["probes"])
                  + f" {r['newton']:>6} {r['wall_s']:7.1f}")
            if not r["valid"] or not r["converged"]:
                print(f"           not valid / converged: {r['why']}")
        if len(rows) == 2:
            new, old = rows[0][1], rows[1][1]
            worst = (max(new["err"].values()), max(old["err"].values()))
            print(f"  ratios default / old: worst error {worst[0] / worst[1]:.3f} "
                  f"({100 * worst[0]:.2f} % vs {100 * worst[1]:.2f} %), wall time "
                  f"{new['wall_s'] / old['wall_s']:.3f}")


if __name__ == "__main__":
    main()
