"""``tissue verify CASE [--size MM] [--push A1=15 ...] [--solvers admm admm-plain mass-tensor
my_module:solve ...] [--field FILE] [--degree N] [--formulation F] [--estimate] [--tol MM]
[--out DIR] [--json FILE]``: fast solvers, anyone's solver, or a displacement field against the
reference on the same Case (``verification.verify``); with ``--sweep [MM ...]``, seed 000's model
validation (its Fig. 7): each actuator pushed alone, every target's error per axis summarized
(``verification.sweep``)."""
from __future__ import annotations

import json
import sys
from functools import partial
from pathlib import Path

from tissue_reference.errors import CaseError
from tissue_reference.verification.sweep import AXES, DEFAULT_PUSHES_MM, sweep
from tissue_reference.verification.verify import (
    DEFAULT_SOLVERS,
    FAST_SOLVERS,
    invalid_runs,
    tolerance_failures,
    verify,
)

from .common import (
    add_case_args,
    add_discretization_args,
    case_from_args,
    check_outputs,
    check_prescribed,
    check_pushes,
    parse_pushes,
    real,
)
from .loop_options import model_case_from_args
from .sweep_report import write_plot
from .verify_report import write_report


def _rel(x) -> str:
    """A relative error, or "-" where the reference's own norm is 0 (no pushes)."""
    return "-" if x is None else f"{x:.3g}"


def _line(name, e):
    its = ""
    if "admm_iterations" in e:
        chord = f" + chord {e['chord_iterations']}" if "chord_iterations" in e else ""
        its = (f"its {e['iterations']} (ADMM {e['admm_iterations']}{chord} + Newton "
               f"{e['newton_iterations']})")
    elif e.get("iterations") is not None:
        its = f"its {e['iterations']}"
    timing = (f"  {e['wall_time_s']:.3f} s  x{e['speedup_vs_reference']:.2f} vs reference"
              if "wall_time_s" in e else "")
    conv = "" if e.get("converged", True) in (True, None) else "  NOT CONVERGED"
    print(f"  {name:20s} max {e['max_vertex_error_mm']:.4g} mm  rms {e['rms_vertex_error_mm']:.4g} mm"
          f"  {its}{timing}{conv}")
    d = e.get("reference_discretization") or {}
    p = f"/P{d['pressure_degree']}" if d.get("pressure_degree") is not None else ""
    print(f"    model {e.get('model')}; reference {e['reference_model']} "
          f"{d.get('formulation')} P{d.get('degree')}{p}, {d.get('dofs')} dofs")
    if e.get("note"):
        print(f"    note: {e['note']}")
    if e.get("polish_restarts"):
        print(f"    polish restarts: {len(e['polish_restarts'])}: {e['polish_restarts'][0]}")
    if "l2_error_mm" in e:
        en = e.get("energy_norm_error_sqrt_uJ")
        print(f"    volume L2 {e['l2_error_mm']:.4g} mm (rel {_rel(e['l2_relative_error'])}), "
              f"H1 seminorm {e['h1_seminorm_error']:.4g} (rel {_rel(e['h1_relative_error'])})"
              + (f", energy norm {en:.4g} sqrt(uJ) (rel {_rel(e['energy_relative_error'])})"
                 if en is not None else ""))
    if e.get("matched"):
        how = e["matched"] + (f"; reference {e['reference_interpolation']}"
                              if e.get("reference_interpolation") else "")
        print(f"    points: {e['n_points']}, {how}")
    if e.get("outside_points"):
        print(f"    {len(e['outside_points'])} point(s) outside the body left out")
    if e["probe_error_mm"]:
        print("    probes: " + ", ".join(f"{k} {v:.4g}" for k, v in e["probe_error_mm"].items()))
    if "discretization_error_estimate_mm" in e:
        what = "the reference's own discretization error (estimate)" \
            if not e.get("no_converged_value") else \
            "the reference's next degree differs by (no error bar: no mesh-converged answer " \
            "is known at this load)"
        print(f"    {what}: " + ", ".join(
            f"{k} {v:.4g}" for k, v in e["discretization_error_estimate_mm"].items()))


def _option(name: str, setting: str, names: list) -> tuple:
    """(key, value) of ``--option NAME KEY=VALUE``: VALUE read as JSON (a number, true, false,
    null, a quoted string, a list), else taken as text; CaseError for a solver not scored or a
    setting that is not KEY=VALUE."""
    if name not in names:
        raise CaseError(f"--option {name} {setting}: {name!r} is not among the solvers scored "
                        f"({', '.join(names) or 'none'})")
    key, sep, text = setting.partition("=")
    if not sep or not key.isidentifier():
        raise CaseError(f"--option {name} {setting}: expected KEY=VALUE with KEY a Python "
                        f"name (e.g. tol=1e-6)")
    try:
        value = json.loads(text)
    except ValueError:
        value = text
    return key, value


def _check_sweep_args(args):
    """The options a sweep refuses (they choose one load or another reference), and those only
    a sweep takes."""
    if args.sweep is None:
        given = [o for o, v in (("--sweep-actuators", args.sweep_actuators),
                                ("--model-case", args.model_case),
                                ("--model-size", args.model_size),
                                ("--model-E-factor", args.model_E_factor)) if v is not None]
        if given:
            raise CaseError(f"{', '.join(given)}: only with --sweep")
        return
    given = [o for o, v in (("--push", args.push), ("--field", args.field),
                            ("--estimate", args.estimate or None),
                            ("--stop-mm", args.stop_mm))
             if v is not None] + (["--formulation"] if args.formulation != "auto" else [])
    if given:
        raise CaseError(f"{', '.join(given)}: not with --sweep (a sweep pushes each actuator "
                        f"alone, --sweep MM ..., and scores solvers against the case's reference, "
                        f"at --degree where given)")


def _sweep_lines(res):
    """The summary of a sweep: per solver and target its errors per axis, beside the seed's."""
    seed = res["seed_fig7"]
    n = len(res["experiments"])
    print(f"{res['case']}: {res['n_vertices']} vertices, {res['n_cells']} cells; "
          f"{len(res['actuators'])} actuators alone at {', '.join(f'{p:g}' for p in res['pushes_mm'])}"
          f" mm: {n} experiments per target")
    if res["model_case"]:
        m = res["model_case"]
        print(f"  model case {m['case']}: {m['n_vertices']} vertices, {m['n_cells']} cells, "
              f"E = {m['material']['E_kPa']:g} kPa")
    ref = [r["reference"] for r in res["experiments"]]
    print(f"  reference (tracker): {sum(r['newton_iterations'] for r in ref)} Newton its, "
          f"{sum(r['wall_time_s'] for r in ref):.1f} s")
    bar = res["reference_error_bar"]
    print("  reference error bar: " + (bar["note"] if bar["max_mm"] is None else ", ".join(
        f"{t} {v:.3g} mm" for t, v in bar["max_mm"].items())))
    print(f"  seed 000 Fig. 7 (model vs EM tracker, {seed['experiments_per_target']} experiments "
          f"x {seed['targets']} targets): largest error ~{seed['max_abs_error_mm']:g} mm; "
          f"{seed['note']}")
    for name, s in res["summary"].items():
        its = s["iterations"]
        model = f"model {s['model']}, " if s.get("model") else ""
        print(f"  {name} ({model}{s['experiments']} experiments, {its} its, "
              f"{s['wall_time_s']:.1f} s): "
              f"largest |error| {s['max_abs_error_mm']:.3g} mm ({s['target']} {s['axis']}, "
              + ", ".join(f"{a} = {p:g} mm" for a, p in (s['pushes_mm'] or {}).items())
              + f") against the seed's ~{seed['max_abs_error_mm']:g} mm")
        print("    target axis  |e| mean   median     max  signed mean [q25, q75] (mm)")
        for t, e in s["targets"].items():
            for ax in AXES:
                if ax not in e:
                    continue
                a, g = e[ax]["absolute"], e[ax]["signed"]
                print(f"    {t:6s} {ax:4s} {a['mean']:8.3g} {a['median']:8.3g} {a['max']:8.3g}"
                      f"  {g['mean']:+.3g} [{g['q25']:+.3g}, {g['q75']:+.3g}]")
        for what in ("not_converged", "not_valid"):
            if s[what]:
                print(f"    {what.replace('_', ' ')}: {s[what]}")
    for name, why in res["skipped"].items():
        print(f"  skipped: {why}")
    if "report" in res:
        print(f"  plot: {res['report']}")


def _run_sweep(args, case) -> int:
    names = list(args.solvers or []) + list(args.solver or []) or ["admm"]
    options = {}
    for name, setting in args.option or ():
        key, value = _option(name, setting, names)
        options.setdefault(name, {})[key] = value
    report = partial(write_plot, Path(args.out)) if args.out is not None else None
    res = sweep(case, names, pushes_mm=args.sweep or DEFAULT_PUSHES_MM,
                actuators=args.sweep_actuators, options=options,
                model_case=model_case_from_args(args, case),
                model_E_factor=args.model_E_factor or 1.0, progress=not args.quiet,
                json_file=args.json, report=report, degree=args.degree)
    _sweep_lines(res)
    status = 0
    for r in res["experiments"]:
        for why in r["reference"].get("no_converged_value", ()):
            print(f"tissue verify: warning: {why}; the errors measure agreement with the "
                  f"reference of this mesh, not with a converged answer", file=sys.stderr)
            status = 1
    for name, s in res["summary"].items():
        for what in ("not_converged", "not_valid"):
            if s[what]:
                print(f"tissue verify: error: {name}: {what.replace('_', ' ')} at {s[what]}",
                      file=sys.stderr)
                status = 1
        if args.tol is not None and s["max_abs_error_mm"] > args.tol:
            print(f"tissue verify: error: {name}: largest target error "
                  f"{s['max_abs_error_mm']:.4g} mm exceeds --tol {args.tol:g} mm", file=sys.stderr)
            status = 1
    return status


def run(args) -> int:
    check_outputs(args, files=("json",), dirs=("out",))
    _check_sweep_args(args)
    if args.sweep is not None:
        case = case_from_args(args)
        check_prescribed(case)
        return _run_sweep(args, case)
    pushes = parse_pushes(args.push)
    case = case_from_args(args)
    check_pushes(case, pushes)
    check_prescribed(case, pushes)
    names = list(args.solvers or []) + list(args.solver or [])
    if not names and args.field is None:
        names = list(DEFAULT_SOLVERS)
    options = {}
    if args.stop_mm is not None:
        for name in names:
            if name.startswith("mass-tensor"):
                options[name] = {"stop_mm": args.stop_mm}
    for name, setting in args.option or ():
        key, value = _option(name, setting, names)
        options.setdefault(name, {})[key] = value
    report = partial(write_report, Path(args.out)) if args.out is not None else None
    res = verify(case, pushes, solvers=tuple(names), report=report, json_file=args.json,
                 options=options, progress=False, estimate=args.estimate, field=args.field,
                 field_name=args.field_name, degree=args.degree, formulation=args.formulation,
                 outside="skip" if args.skip_outside else "error")
    print(f"{case.name}: {case.mesh.n_vertices} vertices, {case.mesh.n_cells} cells, "
          f"pushes {pushes or '{}'} (mm)")
    for model, r in res["reference"]["runs"].items():
        print(f"  reference {model}: {r['newton_iterations']} Newton its, {r['wall_time_s']:.3f} s "
              f"(first call {r['first_call_wall_time_s']:.3f} s)")
    for name, e in res["solvers"].items():
        _line(name, e)
    if "report" in res:
        print(f"  report: {res['report']}")
    for why in res["reference"].get("no_converged_value", ()):
        print(f"tissue verify: warning: {why}; the scores measure agreement with the reference "
              f"of this mesh, not with a converged answer", file=sys.stderr)
    bad = invalid_runs(res)
    for name, why in bad.items():
        print(f"tissue verify: error: {name}: the answer is not valid: {why} (outputs written, "
              f"marked valid = false)", file=sys.stderr)
    over = tolerance_failures(res, args.tol)
    for name, why in over:
        print(f"tissue verify: error: {name}: {why}", file=sys.stderr)
    # scores against a reference with no converged answer behind it: exit status 1
    return 1 if bad or over or res["reference"].get("no_converged_value") else 0


def add_parser(sub):
    p = sub.add_parser("verify", help="fast solvers, your solver or a displacement field "
                                      "against the reference")
    add_case_args(p)
    p.add_argument("--push", action="append", metavar="NAME=MM",
                   help="push an actuator's region rigidly along its direction (repeatable)")
    p.add_argument("--solvers", nargs="+", metavar="NAME", default=None,
                   help=f"solvers to score: built-in {sorted(FAST_SOLVERS)}, 'module:function', "
                        f"'path/to/file.py:function' or an installed 'tissue.solvers' entry point (default: "
                        f"{' '.join(DEFAULT_SOLVERS)}; none when --field is given)")
    p.add_argument("--solver", action="append", metavar="NAME",
                   help="one more solver to score (repeatable), as for --solvers")
    p.add_argument("--option", nargs=2, action="append", metavar=("SOLVER", "KEY=VALUE"),
                   help="a keyword argument for one solver's solve (repeatable; VALUE read as "
                        "JSON: 1e-6, true, \"text\", else as text), e.g. --option "
                        "my_solver.py:solve tol=1e-6 or --option admm anderson=5")
    p.add_argument("--field", metavar="FILE",
                   help="score a displacement field: VTU/VTK/XDMF (last time step) on any mesh "
                        "of the body, or NPY/CSV (n x 3, the case mesh's vertex order)")
    p.add_argument("--field-name", metavar="NAME",
                   help="the point field of --field to take (default: displacement, u, or the "
                        "only vector field)")
    p.add_argument("--skip-outside", action="store_true",
                   help="leave --field points outside the body out of the scores (default: "
                        "an error naming them)")
    add_discretization_args(p)
    p.add_argument("--tol", type=real("positive", "mm"), default=None, metavar="MM",
                   help="exit status 1 when a max vertex error exceeds MM (with --sweep: the "
                        "largest target error along an axis)")
    p.add_argument("--stop-mm", type=real("positive", "mm", at_least=1e-9), default=None,
                   help="Mass Tensor stopping rule (mm, default 0.01; at least 1e-9: below "
                        "that a step is round-off)")
    p.add_argument("--estimate", action="store_true",
                   help="also estimate the reference's discretization error (one solve at "
                        "degree + 1), printed beside each solver's error to the reference")
    p.add_argument("--sweep", nargs="*", type=real("positive", "mm"), default=None,
                   metavar="MM",
                   help="seed 000's model validation (its Fig. 7): push each actuator alone by "
                        "each MM (default: 5 10 15, the seed's 12 experiments with four "
                        "actuators), score each solver's targets against the case's reference "
                        "(at its default degree, or --degree) and print per target and axis the "
                        "mean, median and max error (default solver: admm)")
    p.add_argument("--sweep-actuators", nargs="+", metavar="NAME", default=None,
                   help="the actuators --sweep pushes (default: all)")
    p.add_argument("--model-case", default=None, metavar="CASE.toml",
                   help="with --sweep: the case the solvers solve (the same body, actuators "
                        "and targets meshed as its file says): a model mismatch; default: the "
                        "case")
    p.add_argument("--model-size", type=real("positive", "mm"), default=None,
                   help="with --sweep: the solvers' mesh size (mm; default: the case's mesh, "
                        "or the --model-case's own)")
    p.add_argument("--model-E-factor", type=real("positive"), default=None,
                   help="with --sweep: the solvers' E = factor * the case's E (a stiffness "
                        "mismatch; default 1)")
    p.add_argument("--out", help="folder for report.html and the convergence plots (with "
                                 "--sweep: sweep_errors.png)")
    p.add_argument("--json", help="JSON file of the errors and timings")
    p.set_defaults(func=run)
