"""Verification run on the phantom: ADMM vs the Neo-Hookean reference, Mass Tensor (seed 001
material: linear-elastic, E = 48 kPa, nu = 0.45) vs the linear-elastic reference, all four actuators
pushed 15 mm, same mesh. Prints the issue-3 table (errors in mm, iterations, wall time, speed-up).

Run:  .venv/bin/python bench/bench_verify.py [--size 7.5] [--out out/verify] [--json FILE]
"""
from __future__ import annotations

import argparse
import logging
import sys
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tissue_reference.model.case import load_case
from tissue_reference.tissue.verify_report import write_report
from tissue_reference.verification.verify import verify

ROOT = Path(__file__).resolve().parents[1]
PUSHES = {"A1": 15.0, "A2": 15.0, "A3": 15.0, "A4": 15.0}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=float, default=7.5, help="phantom mesh size (mm)")
    ap.add_argument("--out", default=None, help="report folder")
    ap.add_argument("--json", default=None)
    ap.add_argument("--solvers", nargs="+", default=["admm", "mass-tensor", "mass-tensor-descent"])
    args = ap.parse_args(argv)
    logging.disable(logging.INFO)
    base = load_case(ROOT / "meshes" / "cases" / "phantom.toml", size=args.size)
    runs = []
    if "admm" in args.solvers:
        runs.append(("phantom (Neo-Hookean, E = 6 kPa)", base, ("admm",)))
    mts = tuple(s for s in args.solvers if s.startswith("mass-tensor"))
    if mts:
        runs.append(("phantom (seed 001: linear-elastic, E = 48 kPa, nu = 0.45)",
                     base.with_material(model="linear-elastic", E=48.0, nu=0.45), mts))
    for title, case, solvers in runs:
        report = None if args.out is None else partial(write_report, Path(args.out) / solvers[0])
        js = None if args.json is None else Path(args.json).with_suffix(f".{solvers[0]}.json")
        res = verify(case, PUSHES, solvers=solvers, report=report, json_file=js)
        print(f"\n{title}: {case.mesh.n_vertices} vertices, {case.mesh.n_cells} tets, "
              f"pushes {PUSHES} mm")
        for model, r in res["reference"]["runs"].items():
            print(f"  reference {model}: {r['iterations']} Newton its, {r['wall_time_s']:.3f} s")
        print(f"  {'solver':20s} {'max mm':>9s} {'rms mm':>9s} {'max probe mm':>12s} {'its':>6s} "
              f"{'time s':>8s} {'speed-up':>9s}")
        for name, e in res["solvers"].items():
            print(f"  {name:20s} {e['max_vertex_error_mm']:9.4f} {e['rms_vertex_error_mm']:9.4f} "
                  f"{max(e['probe_error_mm'].values()):12.4f} {e['iterations']:6d} "
                  f"{e['wall_time_s']:8.3f} {e['speedup_vs_reference']:9.2f}")
        for name, msg in res["skipped"].items():
            print(f"  {name}: {msg}")


if __name__ == "__main__":
    main()
