"""The strain-energy laws, one run each: how far the reference is from the law's closed form
(the 10 mm block stretched 20 % between sliding faces, whose exact answer is homogeneous, so P1
holds it exactly: the lateral contraction and the face force against the traction-free root of
the formula's stress, tests/test_laws.py; Ogden's from its principal-stretch formula written
here, ``ogden_principal_piola``), the reference's and ADMM's solve times on the glued phantom
with A1 = 4 mm, and ADMM + polish against that reference, with ADMM's iterations and time per
iteration (ADMM and Newton-polish iterations together; neo-hookean and linear-elastic in the
compiled element pass, the other laws in the numpy one with their Newton local step).

Every law has the same small-strain moduli, E = 6 kPa and nu = 0.45 (mu0 = 2.069 kPa, k = 20
kPa): Mooney-Rivlin splits mu0 as c1 = 0.35 mu0, c2 = 0.15 mu0; Yeoh has c1 = mu0 / 2, c2 =
-0.1 c1, c3 = 0.02 c1 (inside its stable range); Ogden mu = [0.7 mu0, 0.3 mu0], alpha = [4, -2]
(sum mu_i = mu0; verification.suite.law_material). The reference is timed on a second (warm)
call, as ``tissue verify`` does.

    .venv/bin/python bench/bench_laws.py [--size 10] [--push 4]
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

E, NU = 6.0, 0.45
MU0, K = E / (2 * (1 + NU)), E / (3 * (1 - 2 * NU))
LAWS = {
    "neo-hookean": {"E": E, "nu": NU},
    "mooney-rivlin": {"c1": 0.35 * MU0, "c2": 0.15 * MU0, "k": K},
    "yeoh": {"c1": MU0 / 2, "c2": -0.05 * MU0, "c3": 0.01 * MU0, "k": K},
    "stable-neo-hookean": {"E": E, "nu": NU},
    "saint-venant-kirchhoff": {"E": E, "nu": NU},
    "corotational": {"E": E, "nu": NU},
    "linear-elastic": {"E": E, "nu": NU},
    "ogden": {"ogden_mu": (0.7 * MU0, 0.3 * MU0), "ogden_alpha": (4.0, -2.0), "k": K},
}


def ogden_principal_piola(stretches, params):
    """The principal first Piola stresses P_a = J sigma_a / lambda_a (kPa) of Ogden's law
    (Abaqus' convention, quadratic volumetric energy k/2 (J - 1)^2) at the principal stretches
    lambda_a, from its formula: sigma_a = 1/J sum_i 2 mu_i / alpha_i (lb_a^alpha_i - 1/3 sum_b
    lb_b^alpha_i) + k (J - 1), lb_a = J^(-1/3) lambda_a. At J = 1 and stretches (lambda,
    lambda^-1/2, lambda^-1/2) it is sigma_11 - sigma_22 = sum_i 2 mu_i / alpha_i (lambda^alpha_i
    - lambda^(-alpha_i / 2))."""
    ls = np.asarray(stretches, float)
    J = ls.prod()
    lb = J ** (-1 / 3) * ls
    iso = sum(2 * m / a * (lb ** a - (lb ** a).sum() / 3)
              for m, a in zip(params["ogden_mu"], params["ogden_alpha"])) / J
    return J * (iso + params["k"] * (J - 1)) / ls


def block_agreement(model, params):
    """(relative error of the lateral contraction, of the face force) of the reference's P1
    block against the formula's uniaxial answer."""
    from test_laws import _stretched_block, piola_formula

    import tissue_reference.fem_reference as fr
    from tissue_reference.model.case import Material

    def principal(t):
        if model == "ogden":
            return ogden_principal_piola([1.2, t, t], params)
        return np.diag(piola_formula(np.diag([1.2, t, t]), model, params))

    t = brentq(lambda s: principal(s)[1], 0.5, 1.2, xtol=1e-14)
    force = principal(t)[0] * 100.0
    res = fr.solve(_stretched_block(Material(model, **params)))
    side = res.probes["corner"][1]
    return abs(side - 10 * (t - 1)) / abs(10 * (t - 1)), \
        abs(res.reactions["xmax"][0] - force) / abs(force)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=float, default=10.0, help="phantom mesh size (mm)")
    ap.add_argument("--push", type=float, default=4.0, help="A1's push (mm)")
    args = ap.parse_args(argv)
    logging.disable(logging.INFO)
    warnings.simplefilter("ignore")
    import tissue_reference.fem_reference as fr
    from tissue_reference.errors import NotModeledError
    from tissue_reference.model.case import load_case
    from tissue_reference.solvers import get_solver

    admm = get_solver("admm")
    base = load_case("phantom", size=args.size)
    pushes = {"A1": args.push}
    print(f"phantom size {args.size}: {base.mesh.n_vertices} vertices, {base.mesh.n_cells} tets, "
          f"A1 = {args.push} mm; every law E = {E} kPa, nu = {NU} at small strain")
    print(f"{'law':24s} {'block: side':>12s} {'block: force':>13s} {'reference s':>12s} "
          f"{'Newton its':>10s} {'ADMM s':>8s} {'ADMM its':>8s} {'ms/it':>6s} {'ADMM - ref mm':>14s} "
          f"{'speed-up':>9s}")
    for model, params in LAWS.items():
        side, force = block_agreement(model, params)
        case = base.with_material(model=model, **({"E": None, "nu": None} | params))
        fr.solve(case, pushes=pushes)                     # forms compiled
        t0 = time.perf_counter()
        ref = fr.solve(case, pushes=pushes)
        t_ref = time.perf_counter() - t0
        try:
            admm(case, pushes=pushes)
            t0 = time.perf_counter()
            res = admm(case, pushes=pushes)
            t_admm = time.perf_counter() - t0
            err = float(np.linalg.norm(np.asarray(res.u) - np.asarray(ref.u), axis=1).max())
            fast = (f"{t_admm:8.3f} {res.iterations:8d} {1e3 * t_admm / res.iterations:6.2f} "
                    f"{err:14.2e} {t_ref / t_admm:9.2f}")
        except NotModeledError:
            fast = f"{'refused (not implemented in ADMM)':>33s}"
        print(f"{model:24s} {side:12.1e} {force:13.1e} {t_ref:12.3f} {ref.iterations:10d} {fast}")


if __name__ == "__main__":
    main()
