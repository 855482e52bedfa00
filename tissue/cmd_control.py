"""``tissue mpc``, ``tissue manipulability`` (and the loop options ``tissue table1`` shares,
registered from ``cmd_table1``): seed 000 section III-IV.

mpc: closed-loop push-only MPC steering one target (task 1: -x 5 mm, y free; 2: -y 5 mm, x free;
3: +x and +y 5 mm), plant and controller model chosen independently (model-plant mismatch on
purpose: --model admm --model-size 12 --model-E-factor 1.2), with the open-loop eq. 22 baseline.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from tissue_reference.control.controllability import UnreachableGoalError, manipulability_map
from tissue_reference.control.loop import LoopStopped, plot_response
from tissue_reference.control.plants import material_json, solver_description, tangent_for
from tissue_reference.errors import CaseError, ConvergenceError
from tissue_reference.meshes.io import check_output_dir, check_output_file, save_figure
from tissue_reference.model.case_file import case_path
from tissue_reference.model.results import write_json
from tissue_reference.solvers.registry import control_names

from .common import (
    add_case_args,
    case_from_args,
    check_outputs,
    real,
)
from .loop_options import add_loop_args, loop_from_args
from .manipulability_report import write_manipulability_report
from .mpc_report import mpc_stem, write_mpc_report

MAX_MAP_POINTS = 20_000
"""Grid points of one manipulability map at most (each is a small linear program)."""


def _fmt(v, spec):
    return "" if v is None else format(v, spec)


def _write_mpc(args, d: dict, png: Path | None = None):
    """--json and, with --out, the loop's page (tissue.mpc_report)."""
    if args.json:
        write_json(d, args.json)
    if args.out:
        write_mpc_report(d, args.out, response_png=png.name if png else None)


def run_mpc(args) -> int:

    check_outputs(args, files=("json",), dirs=("out",))
    if args.out and Path(args.out).is_dir():
        for suffix in (".html", ".png", "_error.png"):
            check_output_file(Path(args.out) / f"{mpc_stem(args.target, args.task)}{suffix}",
                              "--out")
    case = case_from_args(args)
    case.probe(args.target)   # a missing target is named before any solve
    loop, settings = loop_from_args(args, case)
    meta = {**loop.meta, "target": args.target, "task": args.task}
    try:
        res = loop.run(args.target, args.task, settings, progress=_step_progress(args))
    except UnreachableGoalError as exc:
        _write_mpc(args, {**meta, "status": "unreachable", "reachable": False, "error": str(exc),
                          "closest_reachable_mm": np.asarray(exc.closest).tolist(),
                          "pushes_mm": np.asarray(exc.pushes).tolist()})
        raise
    except ConvergenceError as exc:   # LoopStopped: with the step, pushes and history
        _write_mpc(args, {**meta, "status": "failed", "error": str(exc),
                          **(exc.to_json_dict() if isinstance(exc, LoopStopped) else {})})
        raise
    outside = res.extra.get("outside_range", [])
    d = res.to_json_dict({**meta, "status": "outside range" if outside else "completed"})
    png = None
    if args.out:
        png = Path(args.out) / f"{mpc_stem(args.target, args.task)}.png"
        plot_response(res, png)
    _write_mpc(args, d, png)
    ol = d["open_loop"]
    if ol["status"] == "completed":
        open_txt = f"itae={ol['itae']:.2f} sse={ol['steady_state_error_mm']:.4f} mm"
    elif ol["status"] == "infeasible":
        open_txt = (f"infeasible (eq. 22 pushes {[round(v, 2) for v in ol['u_open_unclamped_mm']]}"
                    f" mm clamped to --max-travel) itae={ol['itae']:.2f} sse="
                    f"{_fmt(ol['steady_state_error_mm'], '.4f') or 'not reached'} mm")
    elif ol["status"] == "outside range":
        open_txt = (f"outside the range where answers converge itae={ol['itae']:.2f} "
                    f"sse={ol['steady_state_error_mm']:.4f} mm")
    elif ol["status"] == "failed":
        open_txt = (f"failed at step {ol['failed_at_step']} (plant at pushes "
                    f"{[round(v, 2) for v in ol['failed_pushes_mm']]} mm: {ol['failure']}); "
                    f"itae >= {ol['itae']:.2f}")
    else:
        open_txt = "not run"
    print(f"{case.name} {args.target} task {args.task}: steps={d['steps']} itae={d['itae']:.2f} "
          f"sse={d['steady_state_error_mm']:.4f} mm retraction={d['max_retraction_mm']} mm "
          f"mpc median={d['mpc_step_median_ms']:.3f} ms | open loop {open_txt} "
          f"| wall {res.wall_time_s:.1f} s")
    for side, why in (("closed loop", outside), ("open loop", ol.get("outside_range", []))):
        for line in why:
            print(f"tissue mpc: warning: the {side} left the range where answers converge: "
                  f"{line}", file=sys.stderr)
    return 1 if outside or ol.get("outside_range") else 0


def _median_text(task, index) -> str:
    """'task T median index M' over the grid points where the task is reachable (NaN elsewhere),
    or what it is when none is."""
    v = np.asarray(index, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return f"task {task}: reachable nowhere on the grid"
    return f"task {task} median index {np.median(v):.4f}"


def _step_progress(args):
    """tissue mpc's per-step lines: stderr, or nowhere with -q/--quiet."""
    if args.quiet:
        return None
    return lambda line: print(f"tissue mpc: {line}", file=sys.stderr, flush=True)


def run_manipulability(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = [args.case] + list(args.compare or [])
    out = check_output_dir(args.out, "--out")
    if out.is_dir():
        check_output_file(out / "report.html", "--out")
    cases = []
    for path in paths:
        case = case_from_args(argparse.Namespace(**{**vars(args), "case": path}))
        _check_map(case, args.plane_z, args.spacing)
        cases.append(case)
    maps, datas = [], []
    for case in cases:
        K = tangent_for(args.solver)(case, np.zeros((case.mesh.n_vertices, case.mesh.gdim)))
        mp = manipulability_map(case, K, plane_z=args.plane_z, spacing=args.spacing)
        maps.append((case.name, mp))
        described = solver_description(args.solver, case)
        data = {"case": case.name, "source": case.source, "solver": args.solver,
                "material": material_json(case.material),
                "pushes_mm": {a.name: 0.0 for a in case.actuators},   # maps of the rest state
                "discretization": described["discretization"], "spacing_mm": args.spacing}
        data.update({k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in mp.items()
                     if not k.startswith("task")})
        for t in (1, 2, 3):
            data[f"task{t}"] = {k: np.where(np.isnan(v), None, v).tolist() if v.dtype.kind == "f"
                                else v.tolist() for k, v in mp[f"task{t}"].items()}
        write_json(data, out / f"manipulability_{case.name}.json")
        datas.append(data)
    finite = [v for _, mp in maps for t in (1, 2, 3)
              for v in np.ravel(mp[f"task{t}"]["index"]) if np.isfinite(v)]
    vmax = max(finite, default=1.0)
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
    save_figure(fig, out / "manipulability.png")
    write_manipulability_report(datas, out, maps_png="manipulability.png", settings={
        "cases": [str(p) for p in paths], "solver": args.solver, "plane_z_mm": args.plane_z,
        "spacing_mm": args.spacing, "size": args.size, "free_actuators": args.free_actuators})
    for name, mp in maps:
        print(name + ": " + ", ".join(_median_text(t, mp[f"task{t}"]["index"])
                                      for t in (1, 2, 3)))
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
    p.add_argument("--target", required=True, help="the probe to steer, e.g. T1")
    p.add_argument("--task", type=int, required=True, choices=(1, 2, 3),
                   help="1: -x (y free); 2: -y (x free); 3: +x and +y; each by --task-mm (5 mm)")
    add_loop_args(p)
    p.add_argument("--out", help="folder for the time-response PNGs and the loop's page "
                                 "(mpc_TARGET_taskN.html)")
    p.add_argument("--json", help="write the result here")
    p.set_defaults(func=run_mpc)

    p = sub.add_parser("manipulability", help="manipulability maps over the z = 15 mm section")
    add_case_args(p)
    p.add_argument("--compare", nargs="*", type=case_path, default=["phantom-3"],
                   help="other cases to map side by side (default: the 3-actuator phantom)")
    p.add_argument("--solver", choices=control_names(), default="fem",
                   help="whose tangent stiffness the maps use")
    p.add_argument("--plane-z", type=real("finite", "mm"), default=15.0,
                   help="height of the mapped section (mm)")
    p.add_argument("--spacing", type=real("positive", "mm"), default=3.0,
                   help="grid spacing (mm)")
    p.add_argument("--out", required=True,
                   help="folder for the maps (PNG), their JSON and report.html")
    p.set_defaults(func=run_manipulability)
