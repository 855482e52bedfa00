"""A short closed loop: the push-only MPC steers an internal target of the phantom.

``control.plants.build_loop`` sets up a plant (the "true" tissue: here the Neo-Hookean reference
on the glued-patch phantom) and the controller's model (here the same solver, so the model's
Jacobian comes from the plant's own state). Each step the MPC (seed 000 eq. 25) asks for push
increments >= 0 (a patch pushes, it never pulls), the plant is solved at the new pushes and the
target measured. Task 1 moves target T1 along -x, 0.3 mm here; ``weights="gain"`` scales the
MPC's push weight by the model's gain, so the loop closes in a few steps. The open loop beside it
(seed eq. 22: pushes from the Jacobian at rest, no feedback) misses: J_s changes as the tissue
deforms.

The same from the command line (``--out DIR`` adds the time-response plots):
``tissue mpc phantom --size 10 --target T1 --task 1 --task-mm 0.3 --weights gain --steps 8
--json out.json``

Run it (about 3 s):

    .venv/bin/python examples/mpc_loop.py
"""
from __future__ import annotations

from tissue_reference.control.loop import LoopSettings
from tissue_reference.control.mpc import MPCSettings
from tissue_reference.control.plants import build_loop
from tissue_reference.model.case import load_case


def main():
    case = load_case("phantom", size=10.0)       # glued patches A1-A4, targets T1-T5
    loop = build_loop(case, plant="fem", model="fem")
    settings = LoopSettings(steps=8, task_mm=0.3, mpc=MPCSettings(weights="gain"))
    res = loop.run("T1", 1, settings, progress=print)

    moved = res.target[-1] - res.target[0]
    print(f"T1 moved {moved[0]:+.4f} mm along x (goal -0.3, y and z free) with pushes "
          f"{dict(zip(res.actuators, res.pushes[-1].round(3).tolist()))} mm")
    print(f"closed loop: final error {res.steady_state_error_mm:.1e} mm, ITAE {res.itae:.3f}, "
          f"largest retraction {res.max_retraction_mm} mm")
    ol = res.open_loop
    print(f"open loop:   final error {ol['steady_state_error_mm']:.1e} mm, ITAE {ol['itae']:.3f}")
    if res.extra["outside_range"]:
        print("outside the range where answers converge:", res.extra["outside_range"])


if __name__ == "__main__":
    main()
