"""Control-layer figures of issue 4, measured in one run (prints; asserts nothing).

1. J_s from the reference's exact tangent vs central FD of the reference solve (phantom, size 10,
   state A1 = 5 mm): max relative error.
2. MPC step median (ms) over the steps of a closed loop.
3. One closed loop of 60 steps with the reference as plant and model (phantom size 10, T1, task 1):
   wall time (s), closed-loop part only (no open-loop baseline).
4. (--mismatch) model ADMM on a coarser mesh (size 12) with E * 1.2, plant: reference (size 8):
   the 15 scenarios; steady-state error, ITAE closed < open, retraction.

    .venv/bin/python bench/bench_control.py [--mismatch]
"""
from __future__ import annotations

import sys
import time

import numpy as np

sys.path.insert(0, ".")

from control.jacobian import dirichlet_jacobian, fd_jacobian, full_pushes, max_rel_error
from control.loop import LinearizedModel, LoopSettings, run_closed_loop
from meshes.case import load_case
from tissue.cmd_jacobian import plant_for, tangent_for

CASE = "meshes/cases/phantom.toml"


def main():
    case = load_case(CASE, size=10)
    fem = plant_for("fem")
    st = full_pushes(case, {"A1": 5.0})
    r = fem(case, st, None)
    pushed = case.with_pushes(st)
    J = dirichlet_jacobian(pushed, tangent_for("fem")(pushed, r.u))
    for h in (0.1, 0.02):
        fd = fd_jacobian(fem, case, st, h=h, initial=r.u)
        print(f"[1] J_s (fem exact tangent) vs central FD h={h} mm: max rel error "
              f"{max_rel_error(J.J, fd.J):.3e}  ({case.mesh.n_cells} tets)")
    model = LinearizedModel(case, fem, tangent_for("fem"), "T1")
    t0 = time.perf_counter()
    res = run_closed_loop(fem, case, model, "T1", 1, settings=LoopSettings(steps=60, open_loop=False))
    wall = time.perf_counter() - t0
    print(f"[2] MPC step median {np.median(res.mpc_ms):.3f} ms (p90 {np.percentile(res.mpc_ms, 90):.3f}"
          f" ms, {len(res.mpc_ms)} steps, qpoases)")
    print(f"[3] closed loop 60 steps, fem plant = model, phantom size 10: {wall:.1f} s wall, "
          f"sse {res.steady_state_error_mm:.2e} mm, retraction {res.max_retraction_mm} mm")
    if "--mismatch" in sys.argv:
        plant_case = load_case(CASE, size=8)
        mcase = load_case(CASE, size=12)
        mcase = mcase.with_material(E=1.2 * mcase.material.E)
        worst, ok_itae, retr = 0.0, 0, 0.0
        for t in ("T1", "T2", "T3", "T4", "T5"):
            for task in (1, 2, 3):
                m = LinearizedModel(mcase, plant_for("admm"), tangent_for("admm"), t)
                rr = run_closed_loop(fem, plant_case, m, t, task, settings=LoopSettings(steps=60))
                worst = max(worst, rr.steady_state_error_mm)
                ok_itae += rr.itae < rr.open_loop["itae"]
                retr = max(retr, rr.max_retraction_mm)
                print(f"    {t} task {task}: sse {rr.steady_state_error_mm:.4f} mm, itae closed "
                      f"{rr.itae:.1f} open {rr.open_loop['itae']:.1f}", flush=True)
        print(f"[4] mismatch: worst sse {worst:.4f} mm, closed ITAE < open in {ok_itae}/15, "
              f"max retraction {retr} mm")


if __name__ == "__main__":
    main()
