"""One loop of the Table I analog's contact scenario on the phantom, per plant contact rule, in one
run (prints; asserts nothing): the model is ADMM on the glued phantom (size 10), the plant the
shipped control plant (meshes/cases/phantom-indenter-control.toml: 5 mm spheres, P2) with its
contact sampled at the skin's nodes (nodal) or by a Gauss rule on its facets. Gain weights, tasks
of --task-mm, 60 steps, with the open-loop baseline.

Per rule: how the closed loop ended (completed, or stopped at a step with the plant's reason),
its steady-state error and ITAE against the open loop's, the final pushes and the deepest tip in
radii, and the wall time. The loops that ask one tip about 10 mm deep (T4 task 1, T5 task 2) stop
on the nodal rule and complete on the Gauss rule.

    .venv/bin/python bench/bench_contact_loop.py --target T4 --task 1 [--rules nodal 2]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(rule, target: str, task: int, task_mm: float, progress: bool) -> str:
    from tissue_reference.control.loop import LoopSettings, LoopStopped
    from tissue_reference.control.mpc import MPCSettings
    from tissue_reference.control.scenarios import scenario_loop
    from tissue_reference.model.case import load_case

    case = load_case(ROOT / "meshes/cases/phantom.toml", size=10.0)
    plant = load_case(ROOT / "meshes/cases/phantom-indenter-control.toml")
    radius = min(a.radius for a in plant.indenters())
    loop = scenario_loop(case, "contact", model="admm", plant_case=plant, contact_rule=rule)
    settings = LoopSettings(steps=60, task_mm=task_mm, mpc=MPCSettings(weights="gain"))
    t0 = time.perf_counter()
    try:
        res = loop.run(target, task, settings, progress=print if progress else None)
    except LoopStopped as exc:
        deepest = max(exc.pushes_mm) / radius
        return (f"{rule!s:>5}: stopped at step {exc.step}/{exc.steps}, deepest tip asked "
                f"{deepest:.2f} radii, error {exc.history['target_error_mm'][-1]:.3g} mm at the "
                f"step before; {time.perf_counter() - t0:.0f} s")
    d = res.to_json_dict()
    ol = d["open_loop"]
    final = d["actuator_positions_mm"][-1]
    return (f"{rule!s:>5}: completed, SSE {d['steady_state_error_mm']:.2g} mm, ITAE closed "
            f"{d['itae']:.3g} vs open {ol['itae']:.4g} ({ol['status']}), retraction "
            f"{d['max_retraction_mm']:g} mm, final pushes {[round(v, 2) for v in final]} mm "
            f"(deepest {max(final) / radius:.2f} radii), MPC step median "
            f"{d['mpc_step_median_ms']:.2f} ms; {time.perf_counter() - t0:.0f} s")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", default="T4")
    ap.add_argument("--task", type=int, choices=(1, 2, 3), default=1)
    ap.add_argument("--task-mm", type=float, default=0.3)
    ap.add_argument("--rules", nargs="+", default=["nodal", "2"],
                    help="plant contact rules: nodal and/or Gauss degrees")
    ap.add_argument("--progress", action="store_true", help="print every loop step")
    args = ap.parse_args()
    print(f"contact scenario, {args.target} task {args.task} ({args.task_mm} mm), gain weights")
    for rule in args.rules:
        r = rule if rule == "nodal" else int(rule)
        print(run(r, args.target, args.task, args.task_mm, args.progress), flush=True)


if __name__ == "__main__":
    main()
