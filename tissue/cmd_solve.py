"""``tissue solve CASE --solver fem|admm|mass-tensor [--degree 1|2] [--push A1=15 ...]
[--device cpu|gpu]``."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from tissue_reference.errors import AccuracyNotReached, CaseError, ConvergenceError
from tissue_reference.meshes.io import check_output_file
from tissue_reference.meshes.refine import projector_for
from tissue_reference.model.answer_warnings import (
    ESTIMATE_WARN,
    estimate_warning,
    probes_above_estimate_warn,
    relative_estimates,
)
from tissue_reference.model.converged_range import unconverged_load
from tissue_reference.solvers.admm import require_device
from tissue_reference.solvers.registry import reference, solver

from .common import (
    SOLVER_NAMES,
    add_case_args,
    add_discretization_args,
    builtin_of,
    case_from_args,
    check_outputs,
    check_prescribed,
    check_pushes,
    integer,
    parse_pushes,
    real,
    report_validity,
    run_solver,
)
from .solve_outputs import rank, solver_settings, write_outputs
from .solve_report import REPORT

STEMS = ("displacement", "last_converged")
# what --out gets besides report.html: per stem, the fields and the report's pictures
SUFFIXES = (".xdmf", ".h5", ".vtu", "_view_u.png", "_view_J.png", "_history.png")


def _settings_of(args) -> dict:
    """solver_settings of ``tissue solve``'s options."""
    entry = solver(args.solver)
    if entry.reference:
        given = {"estimate": "auto" if args.estimate is None else bool(args.estimate)}
        if args.accuracy is not None:
            given.update({"accuracy_rel": args.accuracy, "refine": args.refine,
                          "max_dofs": args.max_dofs})
        return solver_settings(args.solver, **given)
    if len(entry.devices) > 1:
        return solver_settings(args.solver, device=args.device)
    return solver_settings(args.solver)


def run(args) -> int:
    check_outputs(args, files=("json",), dirs=("out",))
    if args.out and Path(args.out).is_dir():
        check_output_file(Path(args.out) / REPORT, "--out")
        for stem in STEMS:
            for suffix in SUFFIXES:
                check_output_file(Path(args.out) / f"{stem}{suffix}", "--out")
    entry = solver(args.solver)
    if args.device != "cpu":
        if args.device not in entry.devices:
            raise CaseError(f"--device {args.device} applies to the ADMM solver (--solver admm)")

        require_device(args.device)  # no CuPy / no GPU: a one-line error before the mesh is built
    pushes = parse_pushes(args.push)
    case = case_from_args(args)
    check_pushes(case, pushes)
    check_prescribed(case, pushes)
    if not args.symmetry and not entry.reference:
        raise CaseError("--no-symmetry applies to the reference (--solver fem)")
    if (args.estimate or args.accuracy is not None) and not entry.reference:
        raise CaseError("--estimate and --accuracy apply to the reference (--solver fem)")
    if args.estimate is not None and args.accuracy is not None:
        raise CaseError("--accuracy estimates every level itself: drop --estimate / "
                        "--no-estimate")
    settings = _settings_of(args)
    try:
        if args.accuracy is not None:
            case, res = solve_adaptive(case, pushes, args)
        else:
            estimate = {"estimate": "auto" if args.estimate is None else bool(args.estimate),
                        "symmetry": args.symmetry} if entry.reference else {}
            res = run_solver(args.solver, case, degree=args.degree, formulation=args.formulation,
                             pushes=pushes, progress=not args.quiet, **estimate,
                             **({"device": args.device} if len(entry.devices) > 1 else {}))
    except AccuracyNotReached as exc:
        if exc.result is not None:   # the last answer, on the mesh it was solved on
            write_outputs(exc.result.case.with_pushes(pushes), exc.result.result, args.out,
                          args.json, settings=settings, report=True)
        print(f"tissue solve: error: {exc}", file=sys.stderr)
        return 1
    except ConvergenceError as exc:
        if exc.last_converged is not None:
            write_outputs(case.with_pushes(pushes), exc.last_converged, args.out, args.json,
                          stem="last_converged", settings=settings, report=True)
            if rank() == 0 and args.out:
                print(f"tissue solve: last converged state (load fraction {exc.load_fraction:.4f})"
                      f" written to {Path(args.out) / 'last_converged.xdmf'}", file=sys.stderr)
        raise
    t_out = time.perf_counter()
    write_outputs(case.with_pushes(pushes), res, args.out, args.json, settings=settings,
                  report=True)
    if rank() == 0 and args.out and not args.quiet:
        print(f"tissue solve: wrote {Path(args.out) / REPORT} and the fields (displacement.xdmf, "
              f".vtu) in {time.perf_counter() - t_out:.1f} s", file=sys.stderr)
    if rank() == 0:
        print(f"{case.name}: {args.solver} converged={res.converged} "
              f"iterations={res.iterations} load_steps={res.load_steps} "
              f"time={res.wall_time_s:.2f}s vertices={res.n_vertices} cells={res.n_cells}")
        if res.model_note:
            print(f"  model: {res.model} ({res.model_note})")
        disc = res.discretization
        if disc:
            p = f"/P{disc['pressure_degree']}" if disc.get("pressure_degree") is not None else ""
            print(f"  discretization: {disc['formulation']} P{disc['degree']}{p}, "
                  f"{disc['dofs']} dofs")
        if line := symmetry_line(res):
            print(f"  symmetry: {line}")
        print_answer(res)
        for line in filter(None, (estimate_warning(res), *res.warnings)):
            print(f"tissue solve: warning: {line}", file=sys.stderr)
        status = report_validity("solve", res)
    else:
        status = 0 if res.valid is not False else 1
    # an answer past the range where answers converge is no answer to trust: exit status 1
    # (its outputs are written and say so), whichever solver gave it
    return max(status, 1 if unconverged_load(case, pushes) else 0)


def solve_adaptive(case, pushes, args):
    """(case on the final mesh, answer): the reference refined until every probe's estimated
    error is within ``args.accuracy`` (relative) of its value: P1, P2, then local (or, with
    ``--refine uniform``, uniform) refinement (fem_reference.adapt)."""
    # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
    from tissue_reference.fem_reference.adapt import solve_to_accuracy

    opts = {} if args.formulation == "auto" else {"formulation": args.formulation}
    b = builtin_of(args.case, args.size)
    if b is not None:  # new boundary nodes of a refined builtin mesh go onto its true surface
        opts["project"] = projector_for(b[0])
    out = solve_to_accuracy(case, pushes, accuracy=args.accuracy, max_dofs=args.max_dofs,
                            degree=args.degree, refine=args.refine, progress=not args.quiet,
                            **opts)
    return out.case, out.result


def symmetry_line(res) -> str | None:
    """What a reference answer on a mirrored mesh was solved on (``SolveResult.symmetry``,
    ``fem_reference.symmetric``); None for another mesh."""
    sym = res.symmetry
    if not sym:
        return None
    if sym.get("solved_on") == "part":
        return (f"solved on the symmetric part cut by {', '.join(sym['planes'])} (sliding), "
                f"{sym['part_dofs']:,} unknowns, and mirrored back onto the whole mesh")
    return f"solved on the whole mesh: {sym.get('why')}"


def print_answer(res):
    """Probes, reactions and indenters, each with its estimated discretization error when there is
    one, and the smallest J of the state."""
    # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
    from tissue_reference.fem_reference.measured import accuracy_line

    pe = res.probe_error_estimates
    re_ = res.reaction_error_estimates
    rels = relative_estimates(res)
    bar = not res.no_converged_value   # an estimate is an error bar only then
    above = probes_above_estimate_warn(res)
    for k, v in res.probes.items():
        line = f"  probe {k}: u = [{', '.join(f'{x:+.4f}' for x in v)}] mm"
        if k in rels:
            rel = rels[k]
            if not bar:
                line += f"  (degree {int(res.degree) + 1} differs by {pe[k]:.2g} mm, {rel:.1%}; " \
                        f"no error bar)"
            else:
                line += f"  +- {pe[k]:.2g} mm ({rel:.1%})"
                if k in above:
                    line += f"  WARNING: estimated error above {ESTIMATE_WARN * 100:g} %"
        print(line)
    for k, v in res.reactions.items():
        line = f"  reaction {k}: [{', '.join(f'{x:+.2f}' for x in v)}] mN"
        if k in re_:
            line += f"  +- {re_[k]:.2g} mN" if bar else f"  (degree {int(res.degree) + 1} " \
                                                       f"differs by {re_[k]:.2g} mN)"
        print(line)
    for k, ind in res.indenters.items():
        print(f"  indenter {k}: push {ind['push']:.2f} mm, force {ind['force']:+.2f} mN, contact "
              f"area {ind['contact_area']:.1f} mm^2, skin inside the tip "
              f"{ind.get('surface_penetration', ind['max_penetration']):.3f} mm "
              f"(contact rule {ind.get('quadrature', 'nodal')})")
    if res.min_J is not None:
        print(f"  smallest J = det F: {res.min_J:.3f}")
    if res.estimate_note:
        print(f"  error estimate: none: {res.estimate_note}")

    if line := accuracy_line(res.entries()):
        print(f"  accuracy: {line}")
    if pe:
        ed = res.extra.get("estimate_discretization") or {}
        print(f"  error estimate: {res.extra.get('estimate_method')} against "
              f"{ed.get('formulation')} P{ed.get('degree')} ({ed.get('dofs')} dofs), cost "
              f"{res.extra.get('estimate_cost_ratio', float('nan')):.1f}x the solve; geometry "
              f"error {'included' if res.extra.get('estimate_includes_geometry') else 'excluded'}"
              + ("" if bar else "; no error bar at this load: no mesh-converged answer is known"))


def add_parser(sub):
    p = sub.add_parser("solve", help="solve a case with the reference or a fast solver")
    add_case_args(p)
    p.add_argument("--solver", choices=SOLVER_NAMES, default=reference().name,
                   help="fem: the reference; admm, mass-tensor: the fast solvers (P1)")
    add_discretization_args(p)
    p.add_argument("--push", action="append", metavar="NAME=MM",
                   help="push an actuator's region rigidly along its direction (repeatable)")
    p.add_argument("--out", help="folder for the displacement field (XDMF + VTU) and "
                                 "report.html (3D views, convergence plot)")
    p.add_argument("--json", help="JSON summary file")
    p.add_argument("--estimate", action=argparse.BooleanOptionalAction, default=None,
                   help="estimate each probe's and reaction's discretization error (one more "
                        "solve at degree + 1 on the same mesh). Default (fem): estimated when "
                        "that solve has at most 60,000 unknowns (a few seconds), else the "
                        "answer says why not; --estimate always, --no-estimate never")
    p.add_argument("--accuracy", type=real("positive", at_most=1.0), default=None,
                   metavar="REL", help="refine (P1, P2, then mesh refinement, see --refine) "
                   "until every probe's estimated error is within REL of its value, e.g. 0.01")
    p.add_argument("--refine", choices=("local", "uniform"), default="local",
                   help="with --accuracy: refine the cells with the largest error indicators "
                        "(local, default) or every cell (uniform)")
    p.add_argument("--max-dofs", type=integer(1), default=500_000,
                   help="with --accuracy: stop (exit 1) before a system larger than this")
    p.add_argument("--symmetry", action=argparse.BooleanOptionalAction, default=True,
                   help="on a mesh joined from a symmetric part and its mirror images (builtin "
                        "phantom-symmetric) under pushes and loads symmetric about the mirror "
                        "planes, solve the part with its planes sliding (the same discrete "
                        "problem) and mirror the answer back onto the whole mesh (default); "
                        "--no-symmetry solves the whole mesh")
    p.add_argument("--device", choices=("cpu", "gpu"), default="cpu",
                   help="where the ADMM iterations run (--solver admm): cpu (default) or gpu "
                        "(CuPy, float64; needs an NVIDIA GPU and pip install "
                        "'tissue-reference[gpu]')")
    p.add_argument("-q", "--quiet", action="store_true", help="no per-step progress")
    p.set_defaults(func=run)
