"""``tissue verify CASE [--size MM] [--push A1=15 ...] [--solvers admm mass-tensor] [--estimate]
[--out DIR] [--json FILE]``: each fast solver against the degree-1 reference on the same Case,
and with --estimate that reference's own discretization error beside it."""
from __future__ import annotations

import sys

from .common import (
    add_case_args,
    case_from_args,
    check_outputs,
    check_prescribed,
    check_pushes,
    parse_pushes,
    real,
)
from .verify import FAST_SOLVERS, invalid_runs, verify


def run(args) -> int:
    check_outputs(args, files=("json",), dirs=("out",))
    pushes = parse_pushes(args.push)
    case = case_from_args(args)
    check_pushes(case, pushes)
    check_prescribed(case, pushes)
    options = {}
    if args.stop_mm is not None:
        for name in args.solvers:
            if name.startswith("mass-tensor"):
                options[name] = {"stop_mm": args.stop_mm}
    res = verify(case, pushes, solvers=tuple(args.solvers), out_dir=args.out, json_file=args.json,
                 options=options, progress=False, estimate=args.estimate)
    print(f"{case.name}: {case.mesh.n_vertices} vertices, {case.mesh.n_cells} cells, "
          f"pushes {pushes or '{}'} (mm)")
    for model, r in res["reference"]["runs"].items():
        print(f"  reference {model}: {r['newton_iterations']} Newton its, {r['wall_time_s']:.3f} s "
              f"(first call {r['first_call_wall_time_s']:.3f} s)")
    for name, e in res["solvers"].items():
        its = (f"its {e['iterations']} (ADMM {e['admm_iterations']} + Newton "
               f"{e['newton_iterations']})" if "admm_iterations" in e else f"its {e['iterations']}")
        print(f"  {name:20s} max {e['max_vertex_error_mm']:.4g} mm  rms {e['rms_vertex_error_mm']:.4g} mm"
              f"  {its}  {e['wall_time_s']:.3f} s  "
              f"x{e['speedup_vs_reference']:.2f} vs reference ({e['reference_model']})")
        print("    probes: " + ", ".join(f"{k} {v:.4g}" for k, v in e["probe_error_mm"].items()))
        if "discretization_error_estimate_mm" in e:
            print("    the reference's own discretization error (estimate): " + ", ".join(
                f"{k} {v:.4g}" for k, v in e["discretization_error_estimate_mm"].items()))
    if "report" in res:
        print(f"  report: {res['report']}")
    bad = invalid_runs(res)
    for name, why in bad.items():
        print(f"tissue verify: error: {name}: the answer is not valid: {why} (outputs written, "
              f"marked valid = false)", file=sys.stderr)
    return 1 if bad else 0


def add_parser(sub):
    p = sub.add_parser("verify", help="fast solvers (ADMM, Mass Tensor) against the reference")
    add_case_args(p)
    p.add_argument("--push", action="append", metavar="NAME=MM",
                   help="push an actuator's region rigidly along its direction (repeatable)")
    p.add_argument("--solvers", nargs="+", choices=sorted(FAST_SOLVERS),
                   default=["admm", "mass-tensor"], help="fast solvers to check")
    p.add_argument("--stop-mm", type=real("positive", "mm", at_least=1e-9), default=None,
                   help="Mass Tensor stopping rule (mm, default 0.01; at least 1e-9: below "
                        "that a step is round-off)")
    p.add_argument("--estimate", action="store_true",
                   help="also estimate the reference's discretization error (one P2 solve), "
                        "printed beside each solver's error to the reference")
    p.add_argument("--out", help="folder for report.html and the convergence plots")
    p.add_argument("--json", help="JSON file of the errors and timings")
    p.set_defaults(func=run)
