"""The whole MPC step of a closed loop, in its parts, measured in one run for both ways an ADMM
model follows the pushes: "fast" (``control.fast_model``: chord Newton on the model's P1 energy,
Jacobian by refinement with a lagged factorization) and "solve" (a full ADMM solve with polish and
an assembled tangent every step, as before).

The loop: the seed's phantom at --size (10 mm: 1748 tets, the seed's 1.7k), plant the reference
(P1, same mesh), model ADMM with E x 1.2 (a mismatch), target T1, task 1 of --task-mm (inside the
glued patches' converged range), gain weights, --steps steps. Per step: the model's update and
Jacobian (ms), the QP (ms), their sum; medians and 90th percentiles; and the fast Jacobian's
largest relative difference from the exact one (the assembled tangent at a full ADMM solve of the
same pushes) at a few steps.

    .venv/bin/python bench/bench_mpc_step.py [--size 10] [--steps 60] [--task-mm 0.3]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from tissue_reference.control.jacobian import dirichlet_jacobian
from tissue_reference.control.loop import LoopSettings
from tissue_reference.control.mpc import MPCSettings
from tissue_reference.control.plants import ADMM_CONTROL_OPTIONS, build_loop
from tissue_reference.model.case import load_case
from tissue_reference.solvers.admm import solve, tangent_stiffness

CASE = Path(__file__).resolve().parents[1] / "meshes" / "cases" / "phantom.toml"


def run(case, update, settings):
    loop = build_loop(case, plant="fem", model="admm", model_E_factor=1.2, model_update=update)
    res = loop.run("T1", 1, settings)
    model_ms = np.asarray(res.extra["model_step_ms"])
    qp_ms = np.asarray(res.mpc_ms)[1:len(model_ms) + 1]
    return loop, res, model_ms, qp_ms


def exact_errors(loop, res, steps=(5, 20, -1)):
    """The fast model's Jacobian at a few of the loop's pushes against the exact one."""
    from tissue_reference.control.fast_model import FastModel

    mcase = loop.model_case
    acts = [a.name for a in mcase.actuators]
    m = FastModel(mcase, "T1")
    out = []
    for k, s in enumerate(res.pushes[:-1]):
        p = dict(zip(acts, s.tolist()))
        J = m.jacobian(p)
        if k in [i % (len(res.pushes) - 1) for i in steps]:
            full = solve(mcase, pushes=p, **ADMM_CONTROL_OPTIONS)
            pushed = mcase.with_pushes(p)
            ex = dirichlet_jacobian(pushed, tangent_stiffness(pushed, full.u), targets=["T1"]).J
            out.append(float(np.abs(J - ex).max() / np.abs(ex).max()))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=float, default=10.0)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--task-mm", type=float, default=0.3)
    a = ap.parse_args()
    case = load_case(CASE, size=a.size)
    settings = LoopSettings(steps=a.steps, open_loop=False, task_mm=a.task_mm,
                            mpc=MPCSettings(weights="gain"))
    print(f"phantom size {a.size:g}: {case.mesh.n_cells} tets; plant reference P1, model ADMM "
          f"(E x 1.2); T1 task 1 of {a.task_mm:g} mm, {a.steps} steps")
    medians = {}
    for update in ("solve", "fast"):
        loop, res, model_ms, qp_ms = run(case, update, settings)
        total = model_ms + qp_ms
        medians[update] = float(np.median(total))
        # the steps whose pushes moved (a loop that has reached its goal asks the model for
        # the state it already has)
        moved = np.abs(np.diff(res.pushes, axis=0)).max(axis=1)[:-1] > 1e-6
        moving = total[moved[:len(total)]] if moved.any() else total
        print(f"  {update:5s}: model update + Jacobian median {np.median(model_ms):7.2f} ms "
              f"(p90 {np.percentile(model_ms, 90):7.2f}), QP {np.median(qp_ms):5.2f} ms, "
              f"step {np.median(total):7.2f} ms (p90 {np.percentile(total, 90):7.2f}; "
              f"{len(moving)} steps that moved the pushes: median {np.median(moving):7.2f}); "
              f"SSE {res.steady_state_error_mm:.2e} mm, last pushes "
              f"{np.round(res.pushes[-1], 4).tolist()}")
        if update == "fast":
            errs = exact_errors(loop, res)
            print(f"  fast Jacobian against the exact one at steps 5, 20 and the last: "
                  f"{', '.join(f'{e:.1e}' for e in errs)} (relative)")
    print(f"  step time fast / solve: {medians['fast'] / medians['solve']:.3f} "
          f"({medians['solve'] / medians['fast']:.1f}x faster)")


if __name__ == "__main__":
    main()
