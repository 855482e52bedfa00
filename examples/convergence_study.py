"""A mesh-refinement study: observed order, Richardson extrapolation and its GCI band.

``fem_reference.convergence.run_study`` solves a shipped case on its mesh and on nested uniform
refinements of it (h halved per level; new boundary vertices placed on the true curved surface)
and studies every probe and reaction with the tools of ``fem_reference.richardson``: the observed
order from three levels, whether the values are in the asymptotic range, and only then the
Richardson-extrapolated value with Roache's grid convergence index (GCI) as its band.

Here: the thick sphere (``thick-sphere``) at P2 on curved cells, three levels from a 6 mm mesh.
Its exact answer (the radial equilibrium ODE) shows how good the extrapolated value is. The same
from the command line: ``tissue converge thick-sphere --size 6 --levels 3 --degrees 2``.

Run it (about 10 s):

    .venv/bin/python examples/convergence_study.py
"""
from __future__ import annotations

from tissue_reference.fem_reference.convergence import run_study
from tissue_reference.fem_reference.richardson import assess
from tissue_reference.model.case import load_case
from tissue_reference.verification.closed_forms import thick_sphere


def main():
    study, = run_study("thick-sphere", size=6.0, degrees=(2,), levels=3)
    for k, (h, cells, dofs) in enumerate(zip(study.h, study.n_cells, study.n_dofs)):
        print(f"level {k}: h {h:.2f} mm, {cells:,} cells, {dofs:,} unknowns")

    q = study.probes["outer"].headline           # the outer surface's radial displacement (mm)
    print("outer u_x per level (mm):", "  ".join(f"{v:.6f}" for v in q.values))
    print(f"observed order {q.observed_order:.2f} (P2 expects 3); asymptotic: {q.asymptotic} "
          f"({q.reason})")
    if q.extrapolated is not None:
        print(f"extrapolated {q.extrapolated:.6f} mm +- {q.gci:.1e} mm (GCI, "
              f"{100 * q.gci_rel:.3f} %)")

    m = load_case("thick-sphere").material
    exact = thick_sphere(10.0, 20.0, 2.0, m.E / (2 * (1 + m.nu)), m.E / (3 * (1 - 2 * m.nu)))
    print(f"exact (radial ODE) {exact['u_outer']:.6f} mm")

    # the same tools score any sequence of values, e.g. from your own solver on nested meshes
    own = assess(q.values, study.h, expected_order=3.0, name="outer x")
    print(f"assess() on the same values: order {own.observed_order:.2f}, "
          f"extrapolated {own.extrapolated:.6f} mm")


if __name__ == "__main__":
    main()
