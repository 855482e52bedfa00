"""``tissue demo --out out``: the seed-000 phantom pressed by four rigid tips, the fast solvers
verified against the reference, a report (``tissue.demo``)."""
from __future__ import annotations

from pathlib import Path

from .common import add_max_cells, check_outputs, real
from .demo import PUSHES_MM, run_demo


def run(args) -> int:
    check_outputs(args, dirs=("out",))
    run_demo(Path(args.out), pushes_mm=tuple(args.pushes), size=args.size, degree=args.degree,
             verify_size=args.verify_size, verify_push=args.verify_push,
             max_cells=args.max_cells, skip_verify=args.skip_verify, progress=not args.quiet)
    return 0


def add_parser(sub):
    p = sub.add_parser("demo", help="solve the phantom pressed by four rigid tips, verify the fast "
                                    "solvers, write a report")
    p.add_argument("--out", default="out", help="folder for the report and every output")
    p.add_argument("--pushes", type=real("positive", "mm"), nargs="+", default=list(PUSHES_MM),
                   metavar="MM", help="pushes of all four tips, solved in turn (mm; default 5 10 "
                   "12.5, where the 5 mm tips have converged answers)")
    p.add_argument("--size", type=real("positive", "mm"), default=None,
                   help="mesh size of the reference's quarter phantom (mm; default the case's: "
                   "another size has no measured error bar)")
    p.add_argument("--degree", type=int, choices=(1, 2), default=None,
                   help="the reference's degree (default the case's, 2: another has no measured "
                   "error bar)")
    p.add_argument("--verify-size", type=real("positive", "mm"), default=None,
                   help="mesh size of the verification's tip phantom (mm; default the case's, "
                   "10: about 8k tetrahedra)")
    p.add_argument("--verify-push", type=real("positive", "mm"), default=5.0,
                   help="push of all four tips in the verification (mm)")
    add_max_cells(p, what="phantom mesh")
    p.add_argument("--skip-verify", action="store_true",
                   help="leave out the verification of the fast solvers")
    p.set_defaults(func=run)
