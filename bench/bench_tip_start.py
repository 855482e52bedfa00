"""How far each level of an indenter study starts its tip from where it first touches the true
dome, and what A1's force becomes when that offset is taken out.

A tip starts where it first touches the contact surface's displacement nodes
(``contact_indenter.Indenter._start``). The nodes lie on the true dome, but the first point
of contact between the sphere and the dome generally lies between them, so on every mesh the tip
starts deeper than on the true body by some delta >= 0 (mm), which varies from level to level
with where the nodes happen to fall, not smoothly with the cell size. Every push of that level
is then a push of p + delta. This bench computes, per level of a study in
tests/data/phantom_indenter_reference.json (``--study``) or in a summary written by
``bench_indenter_convergence.py --summarize`` (``--summary FILE``):

- the exact start: the minimum over the dome x^2/a^2 + y^2/a^2 + z^2/c^2 = 1 (a = 50, c = 45
  mm: ``meshes.builders.PHANTOM``) of the distance along the tip's axis at which the sphere
  touches it (solved here with scipy, from the geometry, not from the mesh);
- the mesh's start (the reference's own, read off its indenter after set-up) and delta;
- A1's force corrected to first order, F(p) - delta dF/dp, with dF/dp from a cubic through the
  origin and the level's own forces; the corrected sequence is assessed like the study's
  (``fem_reference.richardson.assess``).

    .venv/bin/python bench/bench_tip_start.py [--study one_wide] [--summary FILE]
"""
from __future__ import annotations

import argparse
import json
import math
from itertools import pairwise
from pathlib import Path

import numpy as np
from bench_indenter_convergence import RATIO, level_case  # (this folder)

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "phantom_indenter_reference.json"


def exact_start(site, d, radius: float, dome_a: float, dome_c: float) -> float:
    """Distance (mm, along the unit axis d from ``site``) of the sphere's front point when it
    first touches the true dome x^2/a^2 + y^2/a^2 + z^2/c^2 = 1 (a = ``dome_a``, c =
    ``dome_c``, mm): min over the dome of s + R - sqrt(R^2 - rho^2)."""
    from scipy.optimize import minimize

    def surface(v):
        az, el = v
        return np.array([dome_a * math.cos(el) * math.cos(az),
                         dome_a * math.cos(el) * math.sin(az), dome_c * math.sin(el)])

    def along(v):
        w = surface(v) - site
        s = float(w @ d)
        rho = float(np.linalg.norm(w - s * d))
        if rho > radius:
            return 1e3 + rho
        return s + radius - math.sqrt(radius * radius - rho * rho)

    az0 = math.atan2(site[1], site[0])
    el0 = math.asin(max(-1.0, min(1.0, site[2] / dome_c)))
    tries = [minimize(along, [az0 + da, el0 + de], method="Nelder-Mead",
                      options={"xatol": 1e-12, "fatol": 1e-13, "maxiter": 4000})
             for da in (-0.05, 0.0, 0.05) for de in (-0.1, -0.05, 0.0, 0.05)]
    return float(min(t.fun for t in tries))


def main():
    import tissue_reference.fem_reference as fr
    from tissue_reference.fem_reference.richardson import assess
    from tissue_reference.meshes.builders import PHANTOM
    from tissue_reference.model.case import TIP_STARTS

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--study", default="one_wide", help="an entry of the study data")
    ap.add_argument("--summary", type=Path, help="a summary JSON of the convergence bench")
    ap.add_argument("--tip-start", choices=TIP_STARTS, default="nodes",
                    help="the reference's tip start to measure (default: the study's, nodes)")
    args = ap.parse_args()
    study = (json.loads(args.summary.read_text()) if args.summary else
             json.loads(DATA.read_text())["loads"][args.study])
    if study["load"] != "one":
        raise SystemExit("only A1 alone (load 'one'): its force is the one tip's")
    lv = study["levels"]
    path = lv[0]["path_mm"] / lv[0]["site_mm"] if lv[0].get("path_mm") else None
    base_rim = lv[0]["base_rim_mm"] / lv[0]["site_mm"] if lv[0].get("base_rim_mm") else None
    radius = study.get("tip_radius_mm") or 5.0
    deltas, h = {}, {}
    for level in lv:
        k = level["level"]
        case = level_case("one", k, path, study.get("tip_radius_mm"), base_rim=base_rim,
                          path_reach=level.get("path_reach_mm"))
        s = fr.ReferenceSolver(case, degree=study["degree"],
                               contact_quadrature=study["contact_quadrature"],
                               tip_start=args.tip_start)
        ind = next(i for i in s.contact.indenters if i.name == "A1")
        a1 = next(a for a in case.actuators if a.name == "A1")
        site = np.asarray(a1.point, float)
        d = np.asarray(a1.direction, float) / np.linalg.norm(a1.direction)
        exact = exact_start(site, d, radius, PHANTOM.radius, PHANTOM.height)
        deltas[k] = float((ind.q0 - site) @ d) - exact
        h[k] = level.get("path_mm") or level["site_mm"]
        print(f"level {k}: {case.mesh.n_cells} cells; exact start {exact:.5f} mm along the "
              f"axis, the mesh's {exact + deltas[k]:.5f}: delta {deltas[k]:.5f} mm", flush=True)
    for e in study["pushes"]:
        if len(e["levels"]) < 3:
            continue
        p = e["push_mm"]
        raw, fixed = [], []
        for k, force in zip(e["levels"], e["force_mN"]):
            pushes = [x["push_mm"] for x in study["pushes"] if k in x["levels"]]
            forces = [x["force_mN"][x["levels"].index(k)] for x in study["pushes"]
                      if k in x["levels"]]
            basis = np.array([[q, q * q, q ** 3] for q in pushes])
            c = np.linalg.lstsq(basis, np.array(forces), rcond=None)[0]
            slope = c[0] + 2 * c[1] * p + 3 * c[2] * p * p
            raw.append(force)
            fixed.append(force - deltas[k] * slope)
        hs = [h[k] for k in e["levels"]]
        a0 = assess(raw, hs, expected_order=study["degree"] + 1, ratio=RATIO, unit="mN")
        a1 = assess(fixed, hs, expected_order=study["degree"] + 1, ratio=RATIO, unit="mN")

        def show(vals, a):
            ch = ", ".join(f"{100 * (b / a_ - 1):+.2f} %" for a_, b in pairwise(vals))
            order = "-" if a.observed_order is None else f"{a.observed_order:.2f}"
            ext = "" if a.extrapolated is None else f", extrapolated {a.extrapolated:.2f} mN"
            return (" / ".join(f"{v:.2f}" for v in vals) + f" mN (changes {ch}; order {order}, "
                    f"asymptotic {a.asymptotic}{ext}, GCI band {100 * a.gci_rel:.1f} %)")

        print(f"push {p:g} mm, levels {e['levels']}:\n  as solved   {show(raw, a0)}\n"
              f"  start fixed {show(fixed, a1)}")


if __name__ == "__main__":
    main()
