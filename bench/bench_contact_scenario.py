"""The contact mismatch scenario on a small block, measured in one run (prints; asserts nothing).

Model: ADMM on glued disc patches (the block of tests/test_contact_scenario.py: 10 mm, 2.7k tets,
a 3 mm disc on the +x face pushed along -x and one on the +y face pushed along -y, base fixed);
plant: the reference on the same mesh with each patch replaced by a rigid sphere in frictionless
contact (control.scenarios.indenter_plant_case: radius sqrt(area / pi) of the patch, or --radius).
Goal: T1 (the block's centre at z = 5.5 mm) moved 0.3 mm along -x and 0.2 mm along -y.

Prints, per plant: the closed loop's steady-state error (mm), its ITAE against the open loop's
(the eq. 22 pushes of the patch model's initial J_s, applied without feedback), the first step
whose error is <= 0.05 mm, retraction, final pushes, the plant's solves, Newton iterations and
load steps (closed and open loop), and wall times (closed loop, of which the model, and open
loop). Do not run it on the phantom here: each contact solve there costs minutes.

    .venv/bin/python bench/bench_contact_scenario.py [--steps 15] [--radius 2.5]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from test_contact_scenario import GOAL, block_case

from tissue_reference.control.loop import (
    LinearizedModel,
    LoopSettings,
    run_closed_loop,
)
from tissue_reference.control.scenarios import indenter_plant_case, scenario_loop
from tissue_reference.control.table1 import SSE_GOAL_MM


class CountingPlant:
    """The loop's plant, counting solves, Newton iterations and load steps."""

    def __init__(self, plant):
        self.plant, self.solves, self.iterations, self.load_steps = plant, 0, 0, 0

    def __call__(self, case, pushes, initial):
        r = self.plant(case, pushes, initial)
        self.solves += 1
        self.iterations += int(r.iterations)
        self.load_steps += int(r.load_steps)
        return r

    def counts(self):
        return self.solves, self.iterations, self.load_steps


def run(case, label, steps, plant_case=None):
    t0 = time.perf_counter()
    loop = scenario_loop(case, "contact", plant_case=plant_case)
    plant = CountingPlant(loop.plant)
    model = LinearizedModel(loop.model_case, loop.model_solve, loop.model_tangent, "T1",
                            loop.model_sensitivity)
    res = run_closed_loop(plant, loop.case, model, "T1", 1, goal=GOAL,
                          settings=LoopSettings(steps=steps))
    wall = time.perf_counter() - t0
    ol = res.open_loop
    met = np.flatnonzero(res.error_mm <= SSE_GOAL_MM)
    tips = {a.name: round(a.radius, 3) for a in loop.case.actuators}
    print(f"== {label}: plant {loop.meta['plant_actuator_kind']} (sphere radii {tips} mm, "
          f"{loop.meta['plant_cells']} tets), model {loop.meta['model']} on "
          f"{loop.meta['model_actuator_kind']}es ({loop.meta['model_cells']} tets)")
    print(f"   J0 (patch model, T1 x/y per mm of A1/A2): "
          f"{np.round(res.extra['J0'][:2], 3).tolist()}")
    print(f"   closed loop: SSE {res.steady_state_error_mm:.2e} mm after {steps} steps (<= "
          f"{SSE_GOAL_MM} mm from step {met[0] if len(met) else 'never'}), ITAE "
          f"{res.itae:.3f} mm s^2, retraction {res.max_retraction_mm} mm, final pushes "
          f"{np.round(res.pushes[-1], 3).tolist()} mm")
    print(f"   open loop:   SSE {ol['steady_state_error_mm']:.3f} mm, ITAE {ol['itae']:.3f} "
          f"mm s^2 (eq. 22 pushes {np.round(ol['u_open'], 3).tolist()} mm), closed/open ITAE "
          f"{res.itae / ol['itae']:.3f}")
    n, its, ls = plant.counts()
    print(f"   plant: {n} solves (closed {steps + 1}, open {n - steps - 1}), {its} Newton "
          f"iterations, {ls} load steps; cold retries {len(res.extra['plant_retries'])}")
    print(f"   wall {wall:.1f} s: closed loop {res.extra['closed_loop_s']:.1f} s (model "
          f"{res.extra['model_time_s']:.1f} s), open loop {res.extra['open_loop_s']:.1f} s")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=15, help="MPC steps (default 15)")
    p.add_argument("--radius", type=float, default=None,
                   help="also an explicit plant with tips of this radius (mm)")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    case = block_case()
    print(f"block: {case.mesh.n_cells} tets, built in {time.perf_counter() - t0:.1f} s")
    run(case, "derived plant (tips of the patches' area)", args.steps)
    if args.radius is not None:
        run(case, f"explicit plant (tips of {args.radius:g} mm)", args.steps,
            plant_case=indenter_plant_case(case, radius=args.radius))
    return 0


if __name__ == "__main__":
    sys.exit(main())
