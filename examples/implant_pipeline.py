"""Seed 001's breast-implant planning, end to end, on the synthetic patient.

``implant.pipeline.plan_implant`` runs the whole pipeline: a skin surface and three tissue
thickness estimates -> the muscle surface (RBF) -> a tetrahedral tissue volume (gmsh) -> an
implant from the library placed on the muscle -> the two-step boundary conditions -> the Mass
Tensor solve -> the predicted skin. The synthetic patient (``synthetic_patient``) knows its true
muscle, so the muscle estimate's error is printed too. The prediction is then checked against
the linear FEM reference solved with the same boundary conditions on the same mesh
(``tissue.implant_study.reference_solve``): the distance of each predicted skin vertex to the
reference's skin surface (``implant.registration.surface_distances``) over the breast.

The same from the command line (with a report page):
``tissue implant --synthetic --volume 245 --shape round --side left --json plan.json --out DIR``

Run it (about 3 s):

    .venv/bin/python examples/implant_pipeline.py
"""
from __future__ import annotations

import numpy as np

from tissue_reference.implant.pipeline import PlanSettings, plan_implant, synthetic_patient
from tissue_reference.implant.registration import surface_distances
from tissue_reference.tissue.implant_study import reference_solve


def main():
    patient = synthetic_patient()                # skin, thickness estimates and the truth
    plan = plan_implant(patient, PlanSettings(volume_cc=245.0, shape="round", side="left"))
    width, _, projection = plan.settings.spec.dimensions()
    print(f"implant: round, 245 cc, {width:.1f} mm wide, {projection:.1f} mm projection, "
          f"centred at {plan.placement.centre.round(1).tolist()} mm")
    print(f"tissue: {plan.tissue.n_cells:,} tets; muscle estimate within "
          f"{plan.muscle_thickness_error_mm():.2f} mm of the true muscle under the implant")
    stages = ", ".join(f"{k} {v:.2f} s" for k, v in plan.timings.items())
    print(f"Mass Tensor: converged {plan.converged} in {plan.iterations} iteration(s); "
          f"pipeline {plan.wall_time_s:.1f} s ({stages})")
    skin = plan.tissue.region_vertices("skin")
    print(f"skin moves up to {np.linalg.norm(plan.u[skin], axis=1).max():.1f} mm")

    ref = reference_solve(plan)                  # linear FEM, same mesh and conditions
    st = surface_distances(plan.predicted_points, plan.tissue.points + ref.u,
                           plan.skin_triangles, region=plan.breast_region())
    print(f"predicted skin against the FEM reference's, {st.n_points} breast vertices: "
          f"d_max {st.d_max_mm:.2g} mm, mean {st.mean_distance_mm:.2g} mm")


if __name__ == "__main__":
    main()
