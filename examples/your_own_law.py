"""A solver of another material law, scored against the reference of the law it declares.

A plugin solver says which law it solves in its answer's ``extra["model"]`` (any law of
docs/laws.md). ``verification.verify.verify`` then scores it against the reference of that
law with the case's E and nu, and reports the distance between the two laws' references apart,
as the law difference: a solver of another law is not charged with it as solver error.

The solver here solves one problem exactly: a 10 mm block (Neo-Hookean in its case) pulled 2 mm
along x between sliding faces, whose answer is homogeneous, F = diag(s, t, t). For the Stable
Neo-Hookean law (psi = mu/2 (tr C - 3) + l/2 (J - 1 - mu/l)^2 + const, l = lambda + mu) the free
lateral faces give t^2 = (s l + (s - 1) mu) / (s^2 l).

Run it (about 2 s):

    .venv/bin/python examples/your_own_law.py
"""
from __future__ import annotations

import numpy as np

from tissue_reference.meshes.builders import box
from tissue_reference.model.case import Boundary, Case, Material, Probe
from tissue_reference.verification.verify import verify


def stable_neo_hookean_block(case, pushes):
    """The Stable Neo-Hookean answer of the block pulled along x (mm, one row per vertex)."""
    X = case.mesh.points
    pull = next(b for b in case.boundaries if b.region == "xmax").value[0]
    s = 1.0 + pull / X[:, 0].max()                           # the axial stretch
    E, nu = case.material.E, case.material.nu
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    t = np.sqrt((s * (lam + mu) + (s - 1) * mu) / (s * s * (lam + mu)))   # lateral stretch
    u = X @ (np.diag([s, t, t]) - np.eye(3))
    return {"u": u, "extra": {"model": "stable-neo-hookean", "lateral_stretch": float(t)}}


def main():
    case = Case(mesh=box(5.0), material=Material("neo-hookean", E=6.0, nu=0.45),
                name="pulled-block",
                boundaries=(Boundary("xmin", "sliding", normal=[1, 0, 0]),
                            Boundary("ymin", "sliding", normal=[0, 1, 0]),
                            Boundary("zmin", "sliding", normal=[0, 0, 1]),
                            Boundary("xmax", "displacement", value=[2.0, 0, 0], components=(0,))),
                probes=(Probe("corner", (10.0, 10.0, 10.0)),))
    s = verify(case, {}, solvers=[stable_neo_hookean_block])["solvers"]["stable_neo_hookean_block"]
    print(f"the case's law: {case.material.model}; the solver declares: {s['model']}; "
          f"scored against the {s['reference_model']} reference")
    print(f"lateral stretch {s['extra']['lateral_stretch']:.6f}; max vertex error "
          f"{s['max_vertex_error_mm']:.1e} mm, corner {s['probe_error_mm']['corner']:.1e} mm")
    print(f"law difference (stable-neo-hookean against neo-hookean, not solver error): "
          f"{s['law_difference_mm']:.4f} mm")


if __name__ == "__main__":
    main()
