"""``tissue mesh BUILDER --size MM -o FILE [--max-cells N]``: build a gmsh mesh and report its
size and quality. The output path and the estimated cell count are checked before gmsh starts.

Every format keeps the named regions: .msh as gmsh physical groups; .vtu and .xdmf as the
integer cell field ``region`` over the cells, the boundary facets and (.vtu) the point regions'
vertices, with the names as field data (name -> [tag, dim]; see ``meshes.io.write_mesh``)."""
from __future__ import annotations

from tissue_reference.meshes.builders import BUILDERS, MAX_CELLS, build
from tissue_reference.meshes.io import WRITERS, check_output_file, write_mesh
from tissue_reference.meshes.mesh import quality

from .common import add_max_cells, announce_build, real


def run(args) -> int:
    out = check_output_file(args.output, "-o", suffixes=set(WRITERS))
    suffix = out.suffix.lower()
    announce_build("mesh", args.builder, args.size, args.max_cells)
    mesh = build(args.builder, args.size, out=out if suffix == ".msh" else None,
                 max_cells=args.max_cells if args.max_cells is not None else MAX_CELLS)
    if suffix != ".msh":  # the regions as in the .msh: cells, facets (and points in .vtu)
        write_mesh(mesh, out, all_regions=True)
    q = quality(mesh)
    kind = "tetrahedra" if mesh.gdim == 3 else "triangles"
    print(f"{out}: {q.n_vertices} vertices, {q.n_cells} {kind}")
    print(f"  worst element: scaled Jacobian {q.min_scaled_jacobian:.3f}"
          + (f", smallest dihedral angle {q.min_dihedral_deg:.1f} deg" if mesh.gdim == 3 else ""))
    print(f"  regions: {', '.join(mesh.region_names)}")
    return 0


def add_parser(sub):
    p = sub.add_parser("mesh", help="build a phantom / box / rectangle mesh with gmsh")
    p.add_argument("builder", choices=sorted(BUILDERS), help="the builtin geometry to mesh")
    p.add_argument("--size", type=real("positive", "mm"), default=6.0,
                   help="characteristic length (mm)")
    add_max_cells(p)
    p.add_argument("-o", "--output", required=True, help="output .msh, .vtu or .xdmf")
    p.set_defaults(func=run)
