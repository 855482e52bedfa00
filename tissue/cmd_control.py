"""``tissue mpc``, ``tissue table1``, ``tissue manipulability``: seed 000 section III-IV.

mpc: closed-loop push-only MPC steering one target (task 1: -x 5 mm, y free; 2: -y 5 mm, x free;
3: +x and +y 5 mm), plant and controller model chosen independently (model-plant mismatch on
purpose: --model admm --model-size 12 --model-E-factor 1.2), with the open-loop eq. 22 baseline.
"""
from __future__ import annotations

import argparse
import json
import sys
from html import escape as html_escape
from pathlib import Path

import numpy as np

from meshes.case import E_RANGE_KPA
from meshes.errors import CaseError, ConvergenceError
from meshes.io import atomic_path, check_output_dir
from meshes.results import write_json

from .cmd_jacobian import plant_for, tangent_for
from .common import (
    add_case_args,
    body_diameter,
    case_from_args,
    check_outputs,
    check_prescribed,
    integer,
    real,
)

MAX_MAP_POINTS = 20_000
"""Grid points of one manipulability map at most (each is a small linear program)."""


def _loop_args(p):
    p.add_argument("--plant", choices=("fem", "admm"), default="fem")
    p.add_argument("--model", choices=("fem", "admm"), default=None,
                   help="controller's model solver (default: the plant's)")
    p.add_argument("--model-E-factor", type=real("positive"), default=1.0,
                   help="the model's E = factor * the Case's E")
    p.add_argument("--model-size", type=real("positive", "mm"), default=None,
                   help="the model's mesh size (mm; default: the plant's mesh)")
    p.add_argument("--noise", type=real("nonneg", "mm"), default=0.0,
                   help="measurement noise std (mm)")
    p.add_argument("--seed", type=integer(0, 2 ** 32 - 1), default=0)
    p.add_argument("--steps", type=integer(1, 100_000), default=60)
    p.add_argument("--dt", type=real("positive", "s"), default=1.0, help="time per MPC step (s)")
    p.add_argument("--horizon", type=integer(1, 1000), default=5)
    p.add_argument("--q", type=real("positive", "1/mm^2"), default=3.0)
    p.add_argument("--r", type=real("positive", "1/mm^2"), default=2.0)
    p.add_argument("--max-travel", type=real("positive", "mm"), default=None,
                   help="push limit per actuator (mm)")
    p.add_argument("--qp-solver", default="qpoases", help="casadi conic plugin")


def _setup(args, case):
    from control.loop import LoopSettings
    from control.mpc import MPCSettings

    check_prescribed(case)
    if not (np.isfinite(args.model_E_factor) and args.model_E_factor > 0):
        raise CaseError(f"--model-E-factor must be > 0, got {args.model_E_factor}")
    E = case.material.E * args.model_E_factor
    if not E_RANGE_KPA[0] <= E <= E_RANGE_KPA[1]:
        raise CaseError(f"--model-E-factor {args.model_E_factor:g}: the model's E would be "
                        f"{E:g} kPa, outside the physical range [{E_RANGE_KPA[0]:g}, "
                        f"{E_RANGE_KPA[1]:g}] kPa")
    diam = body_diameter(case)
    if args.noise > diam:
        raise CaseError(f"--noise {args.noise:g}: expected a measurement noise <= the body's "
                        f"diameter ({diam:.4g} mm)")
    plant = plant_for(args.plant)
    mname = args.model or args.plant
    if mname == args.plant and args.model_E_factor == 1.0 and args.model_size is None:
        mcase, msolve = case, plant          # the model is the plant: reuse its solution
    else:
        mcase = case_from_args(args, size=args.model_size)
        mcase = mcase.with_material(E=mcase.material.E * args.model_E_factor)
        msolve = plant_for(mname)
    settings = LoopSettings(steps=args.steps, dt_s=args.dt, noise_mm=args.noise, seed=args.seed,
                            mpc=MPCSettings(horizon=args.horizon, q=args.q, r=args.r,
                                            max_travel=args.max_travel, solver=args.qp_solver))
    return plant, mcase, msolve, tangent_for(mname), settings


def run_one(case, target, task, plant, mcase, msolve, mtangent, settings):
    from control.loop import LinearizedModel, run_closed_loop

    model = LinearizedModel(mcase, msolve, mtangent, target)
    return run_closed_loop(plant, case, model, target, task, settings=settings)


def run_mpc(args) -> int:
    from control.controllability import UnreachableGoalError
    from control.loop import plot_response

    check_outputs(args, files=("json",), dirs=("out",))
    case = case_from_args(args)
    case.probe(args.target)   # a missing target is named before any solve
    plant, mcase, msolve, mtan, settings = _setup(args, case)
    try:
        res = run_one(case, args.target, args.task, plant, mcase, msolve, mtan, settings)
    except UnreachableGoalError as exc:
        if args.json:
            write_json({"reachable": False, "error": str(exc),
                        "closest_reachable_mm": np.asarray(exc.closest).tolist(),
                        "pushes_mm": np.asarray(exc.pushes).tolist()}, args.json)
        raise
    d = res.to_json_dict()
    if args.json:
        write_json(d, args.json)
    if args.out:
        plot_response(res, Path(args.out) / f"mpc_{args.target}_task{args.task}.png")
    print(f"{case.name} {args.target} task {args.task}: steps={d['steps']} itae={d['itae']:.2f} "
          f"sse={d['steady_state_error_mm']:.4f} mm retraction={d['max_retraction_mm']} mm "
          f"mpc median={d['mpc_step_median_ms']:.3f} ms | open loop itae="
          f"{d['open_loop']['itae']:.2f} sse={d['open_loop']['steady_state_error_mm']:.4f} mm "
          f"| wall {res.wall_time_s:.1f} s")
    return 0


SSE_GOAL_MM = 0.05   # the closed-loop steady-state error every scenario must meet (mm)


def _fmt(v, spec):
    return "" if v is None else format(v, spec)


def table1_row(t, task, res) -> dict:
    """One scenario of Table I from a LoopResult (open loop included)."""
    d = res.to_json_dict()
    ol = d["open_loop"]
    return {"target": t, "task": task, "status": "ok",
            "closed_loop_itae": d["itae"], "open_loop_itae": ol["itae"],
            "closed_loop_sse_mm": d["steady_state_error_mm"],
            "open_loop_sse_mm": ol["steady_state_error_mm"],
            "open_loop_converged": ol.get("converged", True),
            "open_loop_failed_at_step": ol.get("failed_at_step"),
            "open_loop_failed_pushes_mm": ol.get("failed_pushes_mm"),
            "open_loop_last_error_mm": ol.get("last_error_mm"),
            "u_open_mm": ol.get("u_open_mm"),
            "final_pushes_mm": d["actuator_positions_mm"][-1],
            "max_retraction_mm": d["max_retraction_mm"],
            "mpc_step_median_ms": d["mpc_step_median_ms"], "wall_time_s": res.wall_time_s,
            "closed_loop_s": res.extra.get("closed_loop_s"),
            "model_time_s": res.extra.get("model_time_s"),
            "open_loop_s": res.extra.get("open_loop_s"),
            "cold_retries": {"plant": len(res.extra.get("plant_retries", [])),
                             "model": len(res.extra.get("model_retries", [])),
                             "open_loop_plant": len((res.open_loop or {}).get("retries", []))}}


def table1_summary(rows, n_expected) -> dict:
    """The closed-loop criteria over the rows: sse <= 0.05 mm, closed ITAE < open ITAE (an open-loop
    ITAE cut short by a plant failure is a lower bound, so closed < it still proves the claim),
    zero retraction -- each counted over the scenarios that ran."""
    ok = [r for r in rows if r["status"] == "ok"]
    sse = [r for r in ok if r["closed_loop_sse_mm"] <= SSE_GOAL_MM]
    itae = [r for r in ok if r["closed_loop_itae"] < r["open_loop_itae"]]
    retr = [r for r in ok if r["max_retraction_mm"] == 0.0]
    return {"scenarios": n_expected, "ran": len(ok),
            "unreachable": sum(r["status"] == "unreachable" for r in rows),
            "failed": sum(r["status"] == "failed" for r in rows),
            "sse_le_0.05mm": len(sse), "closed_itae_lt_open": len(itae),
            "zero_retraction": len(retr),
            "open_loop_plant_failures": sum(not r["open_loop_converged"] for r in ok),
            "worst_closed_loop_sse_mm": max((r["closed_loop_sse_mm"] for r in ok), default=None),
            "all_met": len(ok) == n_expected and len(sse) == len(itae) == len(retr) == n_expected}


def write_table1(out, meta, rows, n_expected):
    """table1.json, table1.md and table1.html in ``out`` (each written whole)."""
    out = Path(out)
    summ = table1_summary(rows, n_expected)
    write_json({"meta": meta, "summary": summ, "rows": rows}, out / "table1.json")
    hdr = ["Target", "Task", "Open-loop ITAE", "Closed-loop ITAE", "Open-loop SSE (mm)",
           "Closed-loop SSE (mm)", "Max retraction (mm)", "Final pushes (mm)", "Note"]
    body = []
    for r in rows:
        if r["status"] != "ok":
            body.append([r["target"], str(r["task"]), "", "", "", "", "", "",
                         f"{r['status']}: {r['error']}"])
            continue
        note = ""
        oitae = _fmt(r["open_loop_itae"], ".2f")
        if not r["open_loop_converged"]:
            oitae = ">= " + oitae
            note = (f"open loop: plant failed at step {r['open_loop_failed_at_step']} (pushes "
                    f"{[round(v, 2) for v in r['open_loop_failed_pushes_mm']]} mm; error "
                    f"{r['open_loop_last_error_mm']:.3f} mm at the last step solved)")
        body.append([r["target"], str(r["task"]), oitae, f"{r['closed_loop_itae']:.2f}",
                     _fmt(r["open_loop_sse_mm"], ".4f") or "not reached",
                     f"{r['closed_loop_sse_mm']:.2e}", f"{r['max_retraction_mm']:.3g}",
                     " ".join(f"{v:.2f}" for v in r["final_pushes_mm"]), note])
    verdict = (f"{summ['ran']}/{summ['scenarios']} scenarios ran; closed-loop SSE <= "
               f"{SSE_GOAL_MM} mm in {summ['sse_le_0.05mm']}, closed ITAE < open ITAE in "
               f"{summ['closed_itae_lt_open']}, zero retraction in {summ['zero_retraction']}; "
               f"worst closed-loop SSE {_fmt(summ['worst_closed_loop_sse_mm'], '.2e')} mm")
    title = f"Table I analog: {json.dumps(meta)}"
    md = [title, "", verdict, "", "| " + " | ".join(hdr) + " |", "|" + "---|" * len(hdr)]
    md += ["| " + " | ".join(b) + " |" for b in body]
    with atomic_path(out / "table1.md") as tmp:
        tmp.write_text("\n".join(md) + "\n")
    esc = html_escape
    html = ["<html><body><table border='1'>", f"<caption>{esc(title)}<br>{esc(verdict)}</caption>",
            "<tr>" + "".join(f"<th>{esc(h)}</th>" for h in hdr) + "</tr>"]
    html += ["<tr>" + "".join(f"<td>{esc(c)}</td>" for c in b) + "</tr>" for b in body]
    html.append("</table></body></html>")
    with atomic_path(out / "table1.html") as tmp:
        tmp.write_text("\n".join(html) + "\n")
    return summ


def run_table1(args) -> int:
    from control.controllability import UnreachableGoalError
    from control.loop import plot_response

    check_outputs(args, dirs=("out",))
    case = case_from_args(args)
    targets = args.targets or [p.name for p in case.probes]
    for t in targets:
        case.probe(t)   # a missing target is named before any solve
    plant, mcase, msolve, mtan, settings = _setup(args, case)
    meta = {"case": case.name, "plant": args.plant, "model": args.model or args.plant,
            "model_E_factor": args.model_E_factor, "model_size": args.model_size,
            "size": args.size, "steps": args.steps, "dt_s": args.dt, "horizon": args.horizon,
            "q": args.q, "r": args.r, "noise_mm": args.noise, "plant_cells": case.mesh.n_cells,
            "model_cells": mcase.mesh.n_cells}
    rows = []
    n = 3 * len(targets)
    for t in targets:
        for task in (1, 2, 3):
            try:
                res = run_one(case, t, task, plant, mcase, msolve, mtan, settings)
            except UnreachableGoalError as exc:
                rows.append({"target": t, "task": task, "status": "unreachable", "error": str(exc),
                             "closest_reachable_mm": np.asarray(exc.closest).tolist()})
                print(f"{t} task {task}: unreachable: {exc}", file=sys.stderr, flush=True)
            except ConvergenceError as exc:
                rows.append({"target": t, "task": task, "status": "failed", "error": str(exc)})
                print(f"{t} task {task}: closed loop failed: {exc}", file=sys.stderr, flush=True)
            else:
                row = table1_row(t, task, res)
                rows.append(row)
                print(f"{t} task {task}: itae closed {row['closed_loop_itae']:.2f} open "
                      f"{'' if row['open_loop_converged'] else '>= '}{row['open_loop_itae']:.2f}"
                      f"  sse closed {row['closed_loop_sse_mm']:.2e} open "
                      f"{_fmt(row['open_loop_sse_mm'], '.4f') or 'not reached'} mm  retraction "
                      f"{row['max_retraction_mm']}  ({res.wall_time_s:.1f} s)", flush=True)
                if args.out:
                    plot_response(res, Path(args.out) / f"response_{t}_task{task}.png")
            summ = write_table1(args.out, meta, rows, n)   # after every scenario
    print(f"table1: {json.dumps(summ)}")
    return 0


def run_manipulability(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from control.controllability import manipulability_map

    paths = [args.case] + list(args.compare or [])
    out = check_output_dir(args.out, "--out")
    cases = []
    for path in paths:
        case = case_from_args(argparse.Namespace(**{**vars(args), "case": path}))
        _check_map(case, args.plane_z, args.spacing)
        cases.append(case)
    maps = []
    for case in cases:
        K = tangent_for(args.solver)(case, np.zeros((case.mesh.n_vertices, case.mesh.gdim)))
        mp = manipulability_map(case, K, plane_z=args.plane_z, spacing=args.spacing)
        maps.append((case.name, mp))
        data = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in mp.items()
                if not k.startswith("task")}
        for t in (1, 2, 3):
            data[f"task{t}"] = {k: np.where(np.isnan(v), None, v).tolist() if v.dtype.kind == "f"
                                else v.tolist() for k, v in mp[f"task{t}"].items()}
        write_json(data, out / f"manipulability_{case.name}.json")
    vmax = max(np.nanmax(mp[f"task{t}"]["index"]) for _, mp in maps for t in (1, 2, 3))
    fig, axes = plt.subplots(len(maps), 3, figsize=(12, 3.8 * len(maps)), squeeze=False)
    for i, (name, mp) in enumerate(maps):
        for j, t in enumerate((1, 2, 3)):
            ax = axes[i, j]
            im = ax.pcolormesh(mp["x"], mp["y"], mp[f"task{t}"]["index"], vmin=0, vmax=vmax,
                               shading="nearest", cmap="viridis")
            ax.set_aspect("equal")
            ax.set_title(f"{name}: task {t}")
            ax.set_xlabel("x (mm)")
            ax.set_ylabel("y (mm)")
    fig.colorbar(im, ax=axes.ravel().tolist(), label="manipulability index (eq. 21)")
    with atomic_path(out / "manipulability.png") as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)
    for name, mp in maps:
        med = [np.nanmedian(mp[f"task{t}"]["index"]) for t in (1, 2, 3)]
        print(name + ": " + ", ".join(f"task {t} median index {m:.4f}"
                                      for t, m in zip((1, 2, 3), med)))
    return 0


def _check_map(case, plane_z, spacing):
    """CaseError naming --plane-z / --spacing for a section that misses the body or a grid of
    more than MAX_MAP_POINTS points (mm)."""
    X = case.mesh.points
    lo, hi = X.min(axis=0), X.max(axis=0)
    if X.shape[1] == 3 and not lo[2] < plane_z < hi[2]:
        raise CaseError(f"--plane-z {plane_z:g}: expected a section through "
                        f"{case.source or case.name} ({lo[2]:.4g} < z < {hi[2]:.4g} mm)")
    n = np.prod(np.floor((hi[:2] - lo[:2]) / spacing) + 1)
    if n > MAX_MAP_POINTS:
        raise CaseError(f"--spacing {spacing:g}: the map of {case.source or case.name} would have "
                        f"about {n:,.0f} grid points, more than {MAX_MAP_POINTS:,}; use a larger "
                        f"spacing (mm)")


def add_parser(sub):
    p = sub.add_parser("mpc", help="closed-loop push-only MPC of one target (seed 000)",
                       description=__doc__)
    add_case_args(p)
    p.add_argument("--target", required=True)
    p.add_argument("--task", type=int, required=True, choices=(1, 2, 3))
    _loop_args(p)
    p.add_argument("--out", help="folder for the time-response PNG")
    p.add_argument("--json", help="write the result here")
    p.set_defaults(func=run_mpc)

    p = sub.add_parser("table1", help="5 targets x 3 tasks, open vs closed loop (seed Table I)")
    add_case_args(p)
    _loop_args(p)
    p.add_argument("--targets", nargs="*", default=None)
    p.add_argument("--out", required=True)
    p.set_defaults(func=run_table1)

    p = sub.add_parser("manipulability", help="manipulability maps over the z = 15 mm section")
    add_case_args(p)
    p.add_argument("--compare", nargs="*", default=["meshes/cases/phantom-3.toml"],
                   help="other cases to map side by side (default: the 3-actuator phantom)")
    p.add_argument("--solver", choices=("fem", "admm"), default="fem")
    p.add_argument("--plane-z", type=real("finite", "mm"), default=15.0,
                   help="height of the mapped section (mm)")
    p.add_argument("--spacing", type=real("positive", "mm"), default=3.0,
                   help="grid spacing (mm)")
    p.add_argument("--out", required=True)
    p.set_defaults(func=run_manipulability)
