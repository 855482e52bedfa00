"""``tissue table1``: seed 000's Table I analog, 5 targets x 3 tasks closed vs open loop, once
or per model-plant mismatch scenario, optionally in worker processes (``--jobs``)."""
from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

from tissue_reference.control.scenarios import SCENARIOS, scenario_loop
from tissue_reference.control.table1 import (
    finished_rows,
    plot_scenarios,
    table1_meta,
    table1_pairs,
    write_scenarios_page,
)
from tissue_reference.control.table1 import run_table1 as run_all
from tissue_reference.errors import CaseError
from tissue_reference.model.results import write_json
from tissue_reference.solvers.registry import solver

from .common import add_case_args, case_from_args, check_outputs, contact_rule, integer
from .loop_options import (
    add_loop_args,
    check_loop_args,
    loop_from_args,
    model_case_from_args,
    settings_from_args,
    travel_limit,
)


def run_table1(args) -> int:
    check_outputs(args, dirs=("out",))
    for flag, value in (("--contact-plant", args.contact_plant),
                        ("--contact-quadrature", args.plant_contact_quadrature)):
        if value is not None and "contact" not in (args.scenarios or ()):
            raise CaseError(f"{flag}: only with --scenarios contact (it sets that scenario's "
                            f"plant)")
    if args.scenarios and not solver(args.plant).reference:
        raise CaseError(f"--plant {args.plant}: the scenarios' plant is the reference (fem), "
                        f"changed as each scenario says")
    case = case_from_args(args)
    targets = args.targets or [p.name for p in case.probes]
    for t in targets:
        case.probe(t)   # a missing target is named before any solve
    if args.scenarios:
        return _run_scenarios(args, case, targets)
    loop, settings = loop_from_args(args, case)
    summ = run_all(case, targets, loop, settings, args.out, meta=loop.meta,
                   progress=_progress(args), **_jobs(args))
    print(f"table1: {json.dumps(summ)}")
    return _range_status({None: summ})


def _range_status(summaries: dict) -> int:
    """1 (with a line per table on stderr) when a loop of any table pushed past the range where
    its plant's or model's answers converge, else 0."""
    status = 0
    for name, s in summaries.items():
        if s.get("outside_range"):
            status = 1
            print(f"tissue table1: warning: {s['outside_range']} of {s['ran']} loops"
                  f"{'' if name is None else ' of scenario ' + name} pushed past the range "
                  f"where the plant's or the model's answers converge (their rows say why): "
                  f"their figures have no converged answer behind them", file=sys.stderr)
    return status


def _progress(args):
    """Where the per-run progress lines go: stdout, or nowhere with -q/--quiet."""
    if args.quiet:
        return lambda line: None
    return lambda line: print(line, flush=True)


def table1_loop(argv: dict, scenario: str | None):
    """The loop of one Table I run built from the parsed command line (``vars(args)``): the
    command's own (scenario None) or one mismatch scenario's. What each ``--jobs`` worker
    process builds for itself."""
    args = argparse.Namespace(**argv)
    case = case_from_args(args)
    if scenario is None:
        return loop_from_args(args, case)[0]
    return _scenario_loops(args, case, model_case_from_args(args, case), [scenario])[scenario]


def _jobs(args, scenario=None) -> dict:
    """run_table1's keywords for ``--jobs``, the long loops' step lines (not with -q) and
    resuming (not with --restart)."""
    lines = {"step_lines": not args.quiet, "resume": not args.restart}
    if args.jobs <= 1:
        return lines
    return {"jobs": args.jobs, "loop_factory": functools.partial(table1_loop, vars(args)),
            "factory_key": scenario, **lines}


def _scenario_loops(args, case, model, names) -> dict:
    """The loop of each mismatch scenario in ``names`` (a plant or model that does not fit is
    refused here, before any solve). The model is ``model`` (--model-case / --model-size, None:
    the case) in every scenario; the mesh scenario's, without it, is the body meshed at twice
    the size."""
    coarse = model
    if "mesh" in names and coarse is None:
        h = args.size if args.size is not None else 6.0
        coarse = case_from_args(args, size=2.0 * h)
    plant = None
    if args.contact_plant is not None and "contact" in names:   # meshed as its file says
        try:
            plant = case_from_args(argparse.Namespace(**{**vars(args), "case": args.contact_plant,
                                                         "size": None, "free_actuators": False}))
        except CaseError as exc:   # CaseReadError stays one (its exit status)
            raise type(exc)(f"--contact-plant: {exc}") from None
    contact = {"plant_case": plant, "contact_rule": args.plant_contact_quadrature}
    return {name: scenario_loop(case, name, model=args.model or "admm",
                                model_case=coarse if name == "mesh" else model,
                                model_E_factor=args.model_E_factor,
                                model_update=args.model_update, degree=args.degree,
                                **(contact if name == "contact" else {}))
            for name in dict.fromkeys(names)}


def _run_scenarios(args, case, targets) -> int:
    """The Table I analog once per mismatch scenario, each in ``--out``/NAME, with a combined
    summary (table1_scenarios.json) and the ITAE plot. The model's case is read and checked
    once for every scenario; with --max-travel auto each scenario's own plant and model set its
    range (the summary's settings record the case's and the model's)."""
    check_loop_args(args, case)
    model = model_case_from_args(args, case)
    record = settings_from_args(args, travel_limit(args, case, model), case)[1]   # refusals first
    out = Path(args.out)
    loops = _scenario_loops(args, case, model, args.scenarios)   # every one first: refusals
    summaries, rows, metas, owns = {}, {}, {}, {}
    for name, loop in loops.items():
        owns[name], loop.meta["settings"] = settings_from_args(
            args, travel_limit(args, loop.case, loop.model_case), case)
        metas[name] = loop.meta
        if not args.restart:   # a folder that cannot be resumed is refused before any loop
            finished_rows(out / name, table1_meta(loop, owns[name], loop.meta),
                          table1_pairs(targets))
    for name, loop in loops.items():
        own = owns[name]
        _progress(args)(f"== scenario {name}: {loop.meta['scenario_description']}")
        summaries[name] = run_all(loop.case, targets, loop, own, out / name,
                                  meta=loop.meta, progress=_progress(args), **_jobs(args, name))
        rows[name] = json.loads((out / name / "table1.json").read_text())["rows"]
        write_json({"case": case.name, "source": case.source, "targets": list(targets),
                    "scenarios": summaries, "meta": metas,
                    "settings": record}, out / "table1_scenarios.json")
    plot_scenarios(rows, out / "table1_scenarios.png")
    write_scenarios_page(out, summaries, metas, record,
                         plot="table1_scenarios.png")
    for name, s in summaries.items():
        print(f"table1 {name}: {json.dumps(s)}")
    return _range_status(summaries)


def add_parser(sub):
    p = sub.add_parser("table1", help="5 targets x 3 tasks, open vs closed loop (seed Table I)")
    add_case_args(p)
    add_loop_args(p)
    p.add_argument("--targets", nargs="*", default=None,
                   help="probes to steer (default: every probe of the case)")
    p.add_argument("--scenarios", nargs="+", choices=tuple(SCENARIOS), default=None,
                   help="run the table once per model-plant mismatch (plant: the reference; "
                        "model: --model, default admm, on --model-case / --model-size, default "
                        "the case): gravity on the plant only, a nearly incompressible plant (nu "
                        "0.495, mixed), a model mesh coarser (default: twice the size), "
                        "a plant pressed by rigid spherical indenters (frictionless contact) "
                        "where the model has glued patches")
    p.add_argument("--contact-plant", metavar="CASE.toml", default=None,
                   help="the contact scenario's plant: a case of the same body whose actuators "
                        "are indenters with the case's actuator names (e.g. "
                        "meshes/cases/phantom-indenter-control.toml; meshed as its file says); "
                        "default: "
                        "the case with each patch replaced by a sphere of the patch's area "
                        "touching the one free skin region")
    p.add_argument("--contact-quadrature", type=contact_rule, default=None, metavar="RULE",
                   dest="plant_contact_quadrature",
                   help="the contact scenario's plant: where its contact is sampled, 'nodal' (the "
                        "skin's nodes) or a Gauss degree on the skin's facets (2 holds tips "
                        "pushed past two of their radii); default: the plant case's [reference] "
                        "contact_quadrature, else nodal")
    p.add_argument("--jobs", type=integer(1, 256), default=1, metavar="N",
                   help="run the loops in N worker processes (one core each; every worker "
                        "builds its own plant and model first); the tables are the same: every "
                        "loop, serial or not, runs with one BLAS thread")
    p.add_argument("--out", required=True,
                   help="folder for the tables, trajectories and plots; a folder where a run "
                        "of the same settings stopped (its table1.json) is resumed: only the "
                        "loops it lacks run (other settings are refused, naming them)")
    p.add_argument("--restart", action="store_true",
                   help="start the table over, discarding the rows of an earlier run in --out")
    p.set_defaults(func=run_table1)
