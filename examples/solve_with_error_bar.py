"""A reference answer with its error bar, checked against the exact answer.

The shipped case ``thick-sphere`` is a thick Neo-Hookean shell (radii 10 and 20 mm, its octant)
whose inner surface is pushed 2 mm outward. ``fem_reference.solve(..., estimate=True)`` solves it
(P2 on curved cells, the case's default) and then once more at degree 3 on the same mesh: the
difference is each probe's and each reaction's estimated error. Because this problem has an
independent answer (the radial equilibrium ODE, ``verification.closed_forms.thick_sphere``), the
script also prints the true error beside the estimate. A shipped case that measured its default
against converged answers states that too, in ``extra["measured_accuracy"]``.

Run it (about 4 s):

    .venv/bin/python examples/solve_with_error_bar.py
"""
from __future__ import annotations

import numpy as np

import tissue_reference.fem_reference as fr
from tissue_reference.model.case import load_case
from tissue_reference.verification.closed_forms import thick_sphere


def main():
    case = load_case("thick-sphere")
    res = fr.solve(case, estimate=True)          # the answer, then one solve at degree + 1
    d = res.discretization
    print(f"{case.name}: P{d['degree']}, {d['cells']} cells, {d['dofs']} unknowns, "
          f"valid: {res.valid}")

    # the outer surface's radial displacement: the probe sits on the x axis
    u = float(res.probes["outer"][0])
    bar = res.probe_error_estimates["outer"]     # mm
    m = case.material
    mu, kappa = m.E / (2 * (1 + m.nu)), m.E / (3 * (1 - 2 * m.nu))
    exact = thick_sphere(10.0, 20.0, 2.0, mu, kappa)["u_outer"]
    print(f"outer u_x = {u:.5f} mm +- {bar:.5f} mm (estimated, {100 * bar / abs(u):.2f} %)")
    print(f"exact (radial ODE) {exact:.5f} mm: true error {abs(u - exact):.5f} mm, "
          f"estimate / true error = {bar / abs(u - exact):.2f}")

    # every reaction (mN) carries its error bar too
    for region, force in res.reactions.items():
        print(f"reaction {region:>5}: |F| = {np.linalg.norm(force):8.2f} mN "
              f"+- {res.reaction_error_estimates[region]:.2f} mN")
    print("measured accuracy from the case file:",
          res.extra.get("measured_accuracy") or "none for this load (the estimate above is it)")


if __name__ == "__main__":
    main()
