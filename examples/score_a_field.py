"""Score a displacement field written by another code against the reference.

Any code that writes its answer to a file can be scored: a VTU / VTK / XDMF with its own points
and cells (any mesh of the same body), or an NPY / CSV in the case mesh's vertex order. Here the
"other code" is a coarse solve (the phantom meshed at 14 mm), written as a VTU into a temporary
folder; ``verification.verify.verify(case, pushes, field=path)`` scores it against the
reference on a finer mesh (8 mm). The points do not coincide, so the reference is interpolated to
the field's points (``verification.scoring``): max and RMS point error, volume L2, H1 and energy
norms of the difference (absolute and relative), and each probe's error.

The same from the command line: ``tissue verify phantom --size 8 --push A1=2 --field u.vtu``

Run it (about 3 s once the two meshes are cached):

    .venv/bin/python examples/score_a_field.py
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import tissue_reference.fem_reference as fr
from tissue_reference.meshes.writers import write_mesh
from tissue_reference.model.case import load_case
from tissue_reference.verification.verify import verify


def main():
    push = {"A1": 2.0}
    coarse = load_case("phantom", size=14.0)
    theirs = fr.solve(coarse, pushes=push).u        # stands for the other code's answer (mm)
    case = load_case("phantom", size=8.0)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "their_answer.vtu"
        write_mesh(coarse.mesh, path, point_data={"displacement": theirs})
        out = verify(case, push, solvers=[], field=path)
    s = out["solvers"]["field"]
    print(f"field: {s['n_points']} points ({coarse.mesh.n_cells:,} cells) against the "
          f"reference on {case.mesh.n_cells:,} cells; matched by: {s['matched']} "
          f"({s['reference_interpolation']})")
    print(f"max point error {s['max_vertex_error_mm']:.3f} mm, "
          f"RMS {s['rms_vertex_error_mm']:.3f} mm")
    print(f"volume L2 error {s['l2_error_mm']:.3f} mm ({100 * s['l2_relative_error']:.0f} %), "
          f"H1 {100 * s['h1_relative_error']:.0f} %, energy norm "
          f"{100 * s['energy_relative_error']:.0f} %")
    print("probe errors (mm):", {k: round(v, 4) for k, v in s["probe_error_mm"].items()})


if __name__ == "__main__":
    main()
