"""``tissue mesh BUILDER --size MM -o FILE``: build a gmsh mesh and report its size and quality."""
from __future__ import annotations

from pathlib import Path

from meshes.builders import BUILDERS, build
from meshes.io import write_mesh
from meshes.mesh import quality


def run(args) -> int:
    out = Path(args.output)
    suffix = out.suffix.lower()
    mesh = build(args.builder, args.size, out=out if suffix == ".msh" else None)
    if suffix != ".msh":
        write_mesh(mesh, out)
    q = quality(mesh)
    kind = "tetrahedra" if mesh.gdim == 3 else "triangles"
    print(f"{out}: {q.n_vertices} vertices, {q.n_cells} {kind}")
    print(f"  worst element: scaled Jacobian {q.min_scaled_jacobian:.3f}"
          + (f", smallest dihedral angle {q.min_dihedral_deg:.1f} deg" if mesh.gdim == 3 else ""))
    print(f"  regions: {', '.join(mesh.region_names)}")
    return 0


def add_parser(sub):
    p = sub.add_parser("mesh", help="build a phantom / box / rectangle mesh with gmsh")
    p.add_argument("builder", choices=sorted(BUILDERS))
    p.add_argument("--size", type=float, default=6.0, help="characteristic length (mm)")
    p.add_argument("-o", "--output", required=True, help="output .msh, .vtu or .xdmf")
    p.set_defaults(func=run)
