"""Cost of scoring a displacement field: ``verify(case, field=...)`` (reference solve + reading
the field + matching its points + scores) against the reference solve alone, on a box of about
100k vertices under an affine stretch (Neo-Hookean, P1). The field is the reference's own answer
written to VTU in a shuffled vertex order (matched by coordinates), and a field on another mesh
of the box (the reference interpolated to its points). Prints the ratios measured in this run.

    .venv/bin/python bench/bench_verify_field.py [--size 0.2]
"""
from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import meshio
import numpy as np

import tissue_reference.fem_reference as fr
from tissue_reference.meshes.builders import box
from tissue_reference.model.case import Boundary, Case, Material, Probe
from tissue_reference.verification.verify import verify

G = np.array([[0.05, 0.02, 0.0], [0.0, -0.02, 0.0], [0.01, 0.0, -0.02]])


def case_at(size):
    faces = ["xmin", "xmax", "ymin", "ymax", "zmin", "zmax"]
    return Case(mesh=box(size), material=Material("neo-hookean", E=6.0, nu=0.45), name="box",
                boundaries=tuple(Boundary(f, "affine", gradient=G.tolist(), offset=[0, 0, 0])
                                 for f in faces), probes=(Probe("C", (5.0, 5.0, 5.0)),))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=float, default=0.2, help="box mesh size (mm); 0.2: ~100k "
                    "vertices")
    args = ap.parse_args()
    case = case_at(args.size)
    other = box(args.size * 1.15)
    n = case.mesh.n_vertices
    print(f"box: {n} vertices, {case.mesh.n_cells} cells; other mesh {other.n_vertices} vertices")
    fr.solve(case_at(2.0), degree=1)      # forms compiled outside the timings
    t = time.perf_counter()
    ref = fr.solve(case, degree=1)
    t_ref = time.perf_counter() - t
    print(f"reference solve alone (first call on this mesh, as in any new run): {t_ref:.2f} s "
          f"({ref.iterations} Newton its)")
    with tempfile.TemporaryDirectory() as d:
        perm = np.random.default_rng(0).permutation(n)
        same = Path(d) / "same.vtu"
        meshio.write(str(same), meshio.Mesh(case.mesh.points[perm],
                                            [("tetra", np.argsort(perm)[case.mesh.cells])],
                                            point_data={"displacement": ref.u[perm]}))
        Y = other.points
        far = Path(d) / "other.vtu"
        meshio.write(str(far), meshio.Mesh(Y, [("tetra", other.cells)],
                                           point_data={"displacement": Y @ G.T}))
        for label, path in (("same mesh, shuffled", same), ("another mesh", far)):
            fresh = case.with_mesh(dataclasses.replace(case.mesh))   # no cached solver
            t = time.perf_counter()
            out = verify(fresh, {}, solvers=(), field=path, degree=1, formulation="displacement")
            t_v = time.perf_counter() - t
            e = out["solvers"]["field"]
            print(f"{label:22s} verify {t_v:6.2f} s = {t_v / t_ref:.2f}x the reference solve "
                  f"(scoring {e['scoring_wall_time_s']:.2f} s); max error "
                  f"{e['max_vertex_error_mm']:.2e} mm, {e['matched']}")


if __name__ == "__main__":
    main()
