"""The options and the set-up that the closed-loop commands (``tissue mpc``, ``tissue table1``)
share: the plant, the model and their mismatch, the MPC's weights and limits, the task."""
from __future__ import annotations

import argparse
import math

from tissue_reference.control.loop import LoopSettings
from tissue_reference.control.mpc import WEIGHTS, MPCSettings
from tissue_reference.control.plants import MODEL_UPDATES, build_loop, matching_case
from tissue_reference.errors import CaseError
from tissue_reference.model.converged_range import converged_push_limit
from tissue_reference.solvers.registry import control_names, is_reference

from .common import (
    body_diameter,
    case_from_args,
    check_prescribed,
    check_pushes,
    integer,
    parse_pushes,
    real,
)

POSITIVE_MM = real("positive", "mm, or auto")


def travel(text):
    """--max-travel: a positive push limit (mm), or "auto" (``loop_from_args`` resolves it)."""
    return "auto" if text == "auto" else POSITIVE_MM(text)


def add_loop_args(p):
    p.add_argument("--plant", choices=control_names(), default="fem",
                   help="the solver playing the tissue (the \"true\" plant)")
    p.add_argument("--model", choices=control_names(), default=None,
                   help="controller's model solver (default: the plant's)")
    p.add_argument("--degree", type=int, choices=(1, 2), default=None,
                   help="Lagrange degree of the reference (fem) where it is the plant or the "
                        "model (default: the case's [reference] degree, else 1). On "
                        "phantom-seed (P2 by default, 1-2 min a solve) --degree 1 gives the P1 "
                        "plant, 3-7 s a solve but a fifth too stiff")
    p.add_argument("--model-update", choices=MODEL_UPDATES, default="fast",
                   help="how an ADMM model follows the pushes: fast (chord Newton on its P1 "
                        "energy and the Jacobian by refinement, milliseconds a step; the same "
                        "state and Jacobian within 1e-6 mm and 1e-5) or solve (a full ADMM solve "
                        "and an assembled tangent every step)")
    p.add_argument("--model-E-factor", type=real("positive"), default=1.0,
                   help="the model's E = factor * the Case's E")
    p.add_argument("--model-case", default=None, metavar="CASE.toml",
                   help="the model's own case: the same body, actuators and probes meshed as its "
                        "file says (e.g. phantom-indenter-control, the coarse model of a "
                        "phantom-indenter plant); default: the case")
    p.add_argument("--model-size", type=real("positive", "mm"), default=None,
                   help="the model's mesh size (mm; default: the plant's mesh, or the "
                        "--model-case's own)")
    p.add_argument("--noise", type=real("nonneg", "mm"), default=0.0,
                   help="measurement noise std (mm)")
    p.add_argument("--seed", type=integer(0, 2 ** 32 - 1), default=0,
                   help="seed of the measurement noise")
    p.add_argument("--steps", type=integer(1, 100_000), default=60, help="MPC steps")
    p.add_argument("--dt", type=real("positive", "s"), default=1.0, help="time per MPC step (s)")
    p.add_argument("--horizon", type=integer(1, 1000), default=5,
                   help="MPC prediction horizon Np (steps)")
    p.add_argument("--q", type=real("positive", "1/mm^2"), default=3.0,
                   help="MPC tracking weight Q = q I (1/mm^2)")
    p.add_argument("--r", type=real("positive", "1/mm^2"), default=2.0,
                   help="MPC push-increment weight R = r I (1/mm^2)")
    p.add_argument("--weights", choices=WEIGHTS, default="absolute",
                   help="absolute: R = r I as given (seed 000's Q = 3, R = 2 were tuned on its "
                        "phantom); gain: R = r g^2 I, g the largest singular value of the "
                        "model's weighted J_s, so the loop closes as fast on a body whose targets "
                        "move little per mm of push")
    p.add_argument("--max-travel", type=travel, default=None, metavar="MM|auto",
                   help="push limit per actuator (mm); auto: the deepest push at which the "
                        "plant's and the model's answers still converge (a glued patch's "
                        "radius, 2.5 radii of a rounded tip), so the loop stays in range")
    p.add_argument("--qp-solver", default="qpoases", help="casadi conic plugin")
    p.add_argument("--task-mm", type=real("positive", "mm"), default=5.0,
                   help="how far a task moves the target along each controlled axis (mm; the "
                        "seed's tasks: 5)")
    p.add_argument("--preload", action="append", default=[], metavar="MM|NAME=MM",
                   help="start every actuator (MM) or actuator NAME (NAME=MM, repeatable; "
                        "the others at a bare MM, else 0) pushed in by this much (mm from rest); "
                        "the plant and the model are solved there first, the goal is measured "
                        "from the target's preloaded position, and push only means never back "
                        "past the preload. A rigid head that only touches the skin at rest "
                        "moves nothing to first order (phantom-seed: J_s = 0), so a loop needs "
                        "one there (default 0)")


def model_case_from_args(args, case):
    """The model's case named by --model-case and --model-size (each refused, naming the file,
    when it is not of ``case``'s body: ``matching_case``), or None for the case itself."""
    if args.model_case is None and args.model_size is None:
        return None
    if args.model_case is None:
        return case_from_args(args, size=args.model_size)
    try:
        mcase = case_from_args(argparse.Namespace(**{**vars(args), "case": args.model_case,
                                                     "size": args.model_size}))
        return matching_case(case, mcase, "case", "model")
    except CaseError as exc:   # CaseReadError stays one (its exit status)
        raise type(exc)(f"--model-case: {exc}") from None


def check_loop_args(args, case) -> None:
    """What a closed loop on ``case`` needs of it and of the command line, before any mesh of a
    model is read: prescribed actuators, a noise no larger than the body, and a --degree only
    where the plant or the model is the reference."""
    check_prescribed(case)
    model = args.model or args.plant
    if getattr(args, "degree", None) is not None and not (is_reference(args.plant)
                                                          or is_reference(model)):
        raise CaseError(f"--degree {args.degree}: the reference's degree, and neither --plant "
                        f"{args.plant} nor --model {model} is the reference (fem)")
    preload_from_args(args, case)
    diam = body_diameter(case)
    if args.noise > diam:
        raise CaseError(f"--noise {args.noise:g}: expected a measurement noise <= the body's "
                        f"diameter ({diam:.4g} mm)")


def travel_limit(args, case, model_case) -> float | None:
    """--max-travel resolved: "auto" is the deepest push at which the answers of ``case`` (the
    plant) and ``model_case`` (None: the case itself) still converge."""
    if args.max_travel == "auto":
        return converged_push_limit(case, model_case or case)
    return args.max_travel


def preload_from_args(args, case) -> dict:
    """--preload resolved on ``case``: actuator name -> mm for every actuator (a bare MM for
    every one not named, else 0). CaseError naming --preload for a malformed item, a negative
    push, two bare values, an actuator the case lacks, or a preload past --max-travel."""
    bare = [v for v in args.preload if "=" not in str(v)]
    if len(bare) > 1:
        raise CaseError(f"--preload: one bare MM at most (every actuator's), got {bare}")
    default = 0.0
    if bare:
        try:
            default = float(bare[0])
        except ValueError:
            raise CaseError(f"--preload expects MM or NAME=MM (e.g. 3 or A1=3), got "
                            f"{bare[0]!r}") from None
    named = parse_pushes([v for v in args.preload if "=" in str(v)], "--preload")
    check_pushes(case, named, "--preload")
    out = {a.name: float(named.get(a.name, default)) for a in case.actuators}
    bad = {n: v for n, v in out.items() if not (math.isfinite(v) and v >= 0.0)}
    if bad:
        raise CaseError(f"--preload: expected pushes >= 0 mm (an actuator only pushes), got "
                        f"{bad}")
    limit = args.max_travel if isinstance(args.max_travel, (int, float)) else None
    if limit is not None and max(out.values(), default=0.0) > limit:
        raise CaseError(f"--preload {out} mm: beyond --max-travel {limit:g} mm")
    return out


def settings_from_args(args, limit, case) -> tuple[LoopSettings, dict]:
    """The loop's settings named by the command line on ``case`` with the push limit ``limit``
    (mm, None: none), and their record in a loop's metadata (``settings``)."""
    preload = preload_from_args(args, case)
    if limit is not None and max(preload.values(), default=0.0) > limit:
        raise CaseError(f"--preload {preload} mm: beyond the push limit {limit:g} mm "
                        f"(--max-travel)")
    settings = LoopSettings(steps=args.steps, dt_s=args.dt, noise_mm=args.noise, seed=args.seed,
                            task_mm=args.task_mm, preload_mm=preload,
                            mpc=MPCSettings(horizon=args.horizon, q=args.q, r=args.r,
                                            weights=args.weights,
                                            max_travel=limit, solver=args.qp_solver))
    return settings, {"steps": args.steps, "dt_s": args.dt, "horizon": args.horizon, "q": args.q,
                      "r": args.r, "weights": args.weights, "max_travel_mm": limit,
                      "noise_mm": args.noise, "seed": args.seed, "qp_solver": args.qp_solver,
                      "task_mm": args.task_mm, "preload_mm": preload}


def loop_from_args(args, case):
    """The loop (plant, model, mismatch) and settings named by the command line."""
    check_loop_args(args, case)
    mcase = model_case_from_args(args, case)
    try:
        loop = build_loop(case, plant=args.plant, model=args.model,
                          model_E_factor=args.model_E_factor, model_case=mcase,
                          model_update=args.model_update, degree=args.degree)
    except CaseError as exc:
        raise CaseError(f"--model-E-factor / --model: {exc}") from None
    settings, record = settings_from_args(args, travel_limit(args, loop.case, loop.model_case),
                                          case)
    loop.meta.update({"size": args.size, "model_size": args.model_size, "settings": record})
    return loop, settings
