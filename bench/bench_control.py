"""Control-layer figures (MPC step time, closed loop, mismatch table), measured in one run
(prints; asserts nothing).

1. J_s from the reference's exact tangent vs central FD of the reference solve (phantom, size 10,
   state A1 = 5 mm): max relative error.
2. MPC step median (ms) over the steps of a closed loop.
3. One closed loop of 60 steps with the reference as plant and model (phantom size 10, T1, task 1):
   wall time (s), closed-loop part only (no open-loop baseline).
4. (--mismatch) model ADMM on a coarser mesh (size 12) with E * 1.2, plant: reference (size 8):
   the 15 scenarios (5 targets x 3 tasks, 60 steps each, about 2 min each on this machine);
   steady-state error, ITAE closed < open, retraction. The same runs with md/HTML/JSON output:
   ``tissue table1 meshes/cases/phantom.toml --size 8 --plant fem --model admm --model-size 12
   --model-E-factor 1.2 --out DIR``.

    .venv/bin/python bench/bench_control.py [--mismatch]
"""
from __future__ import annotations

import sys
import time

import numpy as np

sys.path.insert(0, ".")

from tissue_reference.control.jacobian import (
    dirichlet_jacobian,
    fd_jacobian,
    full_pushes,
    max_rel_error,
)
from tissue_reference.control.loop import LinearizedModel, LoopSettings, run_closed_loop
from tissue_reference.control.plants import plant_for, tangent_for
from tissue_reference.model.case import load_case

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
    res = run_closed_loop(fem, case, model, "T1", 1,
                          settings=LoopSettings(steps=60, open_loop=False))
    wall = time.perf_counter() - t0
    print(f"[2] MPC step median {np.median(res.mpc_ms):.3f} ms "
          f"(p90 {np.percentile(res.mpc_ms, 90):.3f} ms, {len(res.mpc_ms)} steps, qpoases)")
    print(f"[3] closed loop 60 steps, fem plant = model, phantom size 10: {wall:.1f} s wall, "
          f"sse {res.steady_state_error_mm:.2e} mm, retraction {res.max_retraction_mm} mm")
    if "--mismatch" in sys.argv:
        # same runs as: tissue table1 meshes/cases/phantom.toml --size 8 --plant fem --model admm
        #               --model-size 12 --model-E-factor 1.2 --out DIR
        from tissue_reference.control.table1 import table1_row, table1_summary

        plant_case = load_case(CASE, size=8)
        mcase = load_case(CASE, size=12)
        mcase = mcase.with_material(E=1.2 * mcase.material.E)
        rows = []
        for t in ("T1", "T2", "T3", "T4", "T5"):
            for task in (1, 2, 3):
                m = LinearizedModel(mcase, plant_for("admm"), tangent_for("admm"), t)
                rr = run_closed_loop(fem, plant_case, m, t, task, settings=LoopSettings(steps=60))
                row = table1_row(t, task, rr)
                rows.append(row)
                print(f"    {t} task {task}: sse {row['closed_loop_sse_mm']:.2e} mm, itae closed "
                      f"{row['closed_loop_itae']:.1f} open "
                      f"{'' if row['open_loop_converged'] else '>= '}{row['open_loop_itae']:.1f}, "
                      f"retraction {row['max_retraction_mm']} mm ({rr.wall_time_s:.0f} s)",
                      flush=True)
        summ = table1_summary(rows, 15)
        print(f"[4] mismatch (model ADMM size 12, E x 1.2; plant reference size 8): worst sse "
              f"{summ['worst_closed_loop_sse_mm']:.2e} mm, sse <= 0.05 mm in "
              f"{summ['sse_le_0.05mm']}/15, closed ITAE < open in "
              f"{summ['closed_itae_lt_open']}/15, "
              f"zero retraction in {summ['zero_retraction']}/15")


if __name__ == "__main__":
    main()
