"""``tissue suite [--solvers fem admm ... module:function] [--problems NAME ...] [--law LAW]
[--strict] [--out DIR] [--json FILE]``: the verification suite (``verification.suite``):
problems with known answers, each solver scored on one scorecard."""
from __future__ import annotations

import sys

from tissue_reference.model.case import MATERIAL_MODELS
from tissue_reference.solvers.registry import is_reference
from tissue_reference.verification.suite import PROBLEMS, run_suite

from .common import check_outputs
from .suite_report import write_scorecard

DEFAULT = ("fem", "admm", "admm-plain", "mass-tensor")


def run(args) -> int:
    check_outputs(args, files=("json",), dirs=("out",))
    solvers = list(args.solvers or DEFAULT) + list(args.solver or [])
    out = run_suite(tuple(solvers), args.problems, json_file=args.json,
                    progress=not args.quiet, law=args.law)
    if args.out is not None:
        out["report"] = str(write_scorecard(out, args.out))
    if args.law is not None:
        print(f"law: {args.law} (every problem's material, same small-strain E and nu)")
    names = list(out["summary"])
    width = max(len(p["name"]) for p in out["problems"])
    print(f"{'problem':{width}s}  {'expected (mm)':>13s}  " + "  ".join(f"{n:>14.14s}"
                                                                      for n in names))
    for p in out["problems"]:
        cells = []
        for n in names:
            r = p["results"][n]
            if "refused" in r:
                cells.append(f"{'refused':>14s}")
            elif "error" in r:
                cells.append(f"{'ERROR':>14s}")
            else:
                cells.append(f"{r['error_rel']:8.1e} {'pass' if r['passed'] else 'FAIL':>5s}")
        print(f"{p['name']:{width}s}  {p['expected_mm']:13.6g}  " + "  ".join(cells))
    print("relative errors; tolerances: " + ", ".join(f"{p['name']} {p['tolerance_rel']:g}"
                                                      for p in out["problems"]))
    for p in out["problems"]:
        for n, r in p["results"].items():
            if "error" in r or "refused" in r:
                print(f"  {p['name']} / {n}: {r.get('error') or r.get('refused')}")
    for name, why in out.get("not_applicable", {}).items():
        print(f"  {name}: not run on this law: {why}")
    for n, s in out["summary"].items():
        print(f"  {n}: {s['passed']} passed, {s['failed']} failed, {s['refused']} refused")
    if "report" in out:
        print(f"  scorecard: {out['report']}")
    failed = {n for n, s in out["summary"].items() if s["failed"]}
    if any(is_reference(n) for n in failed):
        print("tissue suite: error: the reference fails a problem of the suite", file=sys.stderr)
        return 1
    if args.strict and failed:
        print(f"tissue suite: error: failed: {sorted(failed)} (--strict)", file=sys.stderr)
        return 1
    return 0


def add_parser(sub):
    p = sub.add_parser("suite", help="verification suite: problems with known answers, a "
                                     "scorecard per solver")
    p.add_argument("--solvers", nargs="+", metavar="NAME",
                   help=f"solvers to run: fem (the reference), built-in fast solvers, "
                        f"'module:function', 'path/to/file.py:function' or a "
                        f"'tissue.solvers' entry point (default: "
                        f"{' '.join(DEFAULT)})")
    p.add_argument("--solver", action="append", metavar="NAME",
                   help="one more solver (repeatable), added to the defaults or --solvers")
    p.add_argument("--problems", nargs="+", metavar="NAME", choices=[p.name for p in PROBLEMS],
                   help="problems to run (default: all)")
    p.add_argument("--law", choices=MATERIAL_MODELS, default=None,
                   help="run every problem on this strain-energy law (same small-strain E and "
                        "nu; answers from the law's own closed forms; docs/laws.md); problems "
                        "with no answer on it are listed with the reason. Default: each "
                        "problem's own law")
    p.add_argument("--strict", action="store_true",
                   help="exit status 1 when any solver fails a problem (default: only when the "
                        "reference does)")
    p.add_argument("--out", help="folder for suite.html, the scorecard")
    p.add_argument("--json", help="JSON file of the scorecard")
    p.add_argument("-q", "--quiet", action="store_true", help="no per-run progress")
    p.set_defaults(func=run)
