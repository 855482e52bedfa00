"""A control loop with the plant's answers kept at every load it solved
(``control.plant_step.KeptAnswers``) against the same loop keeping only the last answer, at the
same pushes exactly (``last``: what it kept before), and solving every step (``every``), in one
run: the wall time of each, the plant solves saved, and that the loops are the same (targets and
pushes).

Where the open loop's eq. 22 pushes point along the closed loop's (T3 task 2 on phantom-seed:
A2 alone), the open loop asks only for loads the closed loop solved; every open loop starts at the
preload the closed loop solved first. Default: the seed's Table I scenario on phantom-seed that
holds a head at the push limit (T2 task 1, ADMM model at size 12, every head preloaded 3 mm, 5 mm
task, 20 steps, limit 15 mm), with the reference plant at ``--degree`` (1: a few seconds a solve;
2, the case's default: 1-2 min).

    .venv/bin/python bench/bench_loop_kept.py [--degree 1] [--target T2] [--task 1]
    .venv/bin/python bench/bench_loop_kept.py --target T3 --task 2
"""
from __future__ import annotations

import argparse
import contextlib
import time
from unittest import mock

import numpy as np


class _Every:
    """The plant called at every step (what the loop did before it kept answers)."""

    def __init__(self, solve):
        self.solve, self.kept = solve, 0

    def __call__(self, case, pushes, initial):
        return self.solve(case, pushes, initial)


class _LastOnly:
    """The plant's last answer given back where a step asks for exactly its pushes (what the
    loop kept before it kept every load)."""

    def __init__(self, solve):
        self.solve, self.kept, self._last = solve, 0, None

    def __call__(self, case, pushes, initial):
        key = (id(case), tuple(sorted((str(a), float(p)) for a, p in pushes.items())))
        if self._last is not None and self._last[0] == key:
            self.kept += 1
            return self._last[1]
        r = self.solve(case, pushes, initial)
        self._last = (key, r)
        return r


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="phantom-seed")
    ap.add_argument("--degree", type=int, default=1)
    ap.add_argument("--target", default="T2")
    ap.add_argument("--task", type=int, default=1)
    ap.add_argument("--steps", type=int, default=20)
    args = ap.parse_args()

    from tissue_reference.control import loop as loop_module
    from tissue_reference.control.loop import LoopSettings
    from tissue_reference.control.mpc import MPCSettings
    from tissue_reference.control.plants import build_loop
    from tissue_reference.model.case import load_case

    case = load_case(args.case)
    model_case = load_case(args.case, size=12.0)
    settings = LoopSettings(steps=args.steps, task_mm=5.0, preload_mm=3.0,
                            mpc=MPCSettings(max_travel=15.0))
    # a loop of one step first, untimed: the forms' compiled modules and the meshes loaded once
    build_loop(case, plant="fem", model="admm", model_case=model_case,
               degree=args.degree).run(args.target, args.task,
                                       LoopSettings(steps=1, task_mm=5.0, preload_mm=3.0,
                                                    open_loop=False,
                                                    mpc=MPCSettings(max_travel=15.0)))
    runs = {}
    variants = {"every": _Every, "last": _LastOnly, "kept": None}
    for name, keeper in variants.items():
        loop = build_loop(case, plant="fem", model="admm", model_case=model_case,
                          degree=args.degree)
        patch = mock.patch.object(loop_module, "KeptAnswers", keeper) if keeper is not None \
            else contextlib.nullcontext()
        t0 = time.perf_counter()
        with patch:
            res = loop.run(args.target, args.task, settings)
        runs[name] = (res, time.perf_counter() - t0)
        print(f"  [{name}: {runs[name][1]:.1f} s, {res.extra['plant_kept_steps']} plant answers "
              f"kept, SSE {res.steady_state_error_mm:.4f} mm]", flush=True)
    (kept, tk), (every, te), (last, tl) = runs["kept"], runs["every"], runs["last"]
    steps = len(kept.pushes) + len(kept.open_loop["pushes"])
    print(f"{args.case} P{args.degree} plant, {args.target} task {args.task}, {args.steps} steps: "
          f"{steps} plant steps (closed and open loop)")
    print(f"  every step solved: {te:.1f} s; the last answer kept where the pushes repeat: "
          f"{tl:.1f} s ({last.extra['plant_kept_steps']} kept, {te / tl:.2f}x); every load's "
          f"answer kept: {tk:.1f} s ({kept.extra['plant_kept_steps']} kept, {te / tk:.2f}x, "
          f"{tl / tk:.2f}x the last only)")
    for name, other in (("every", every), ("last", last)):
        dx = max(np.abs(kept.target - other.target).max(),
                 np.abs(kept.open_loop["target"] - other.open_loop["target"]).max())
        dp = max(np.abs(kept.pushes - other.pushes).max(),
                 np.abs(kept.open_loop["pushes"] - other.open_loop["pushes"]).max())
        print(f"  same loops as {name}: targets differ by {dx:.1e} mm, pushes by {dp:.1e} mm")


if __name__ == "__main__":
    main()
