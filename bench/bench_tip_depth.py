"""How deep a ball-ended rod goes into a flat half-space before the answer stops: the reference
(Neo-Hookean, E = 6 kPa, nu = 0.45, P2, frictionless penalty contact) on the quarter block
``indent-block`` with a spherical tip of radius R on the symmetry axis, pushed along -z through
the given depths on one warm-started load path.

Per depth: whether Newton converged and the depth reached, validity (no inverted cell, the skin
not inside the tip), the whole tip's force (mN: four times the quarter's), the smallest J of
the P2 field (``field_jacobian.cell_min_J``) with its cell's place (radius from the axis and
height, before and after), the cells below J = 0.2, the skin's smallest hoop stretch r / r0
(its compression around the axis, skin nodes starting more than 0.3 R from it), Newton
iterations and wall time. On the
phantom the 5 mm tips stop just past one diameter (docs/verification.md); this is the same tip
without the phantom's curved skin, neighbours and base. The stop is the nodal contact rule's
(bench/bench_contact_rule.py compares it with a Gauss rule, which goes deeper); this bench
uses the default rule, ``--contact-quadrature 2`` the Gauss one.

    .venv/bin/python bench/bench_tip_depth.py                   # h 0.3 mm, R 1 mm, to 3 R
    .venv/bin/python bench/bench_tip_depth.py --size 0.2 --radius 1 --depths 1 2 2.5
    .venv/bin/python bench/bench_tip_depth.py --ball-only --depths 2.2 2.5 3

``--ball-only`` (a diagnostic) makes the tip a free ball, its gap |y - o| - R on both sides of
the equator, by replacing the gap functions in this process: whether the rod behind the ball
matters.
"""
from __future__ import annotations

import argparse
import math
import time

TIP = "ball-ended rod"


def run(size: float, radius: float, depths, volumetric: str, rule="nodal") -> None:
    import numpy as np

    import tissue_reference.fem_reference as fr
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.fem_reference.field_jacobian import cell_min_J
    from tissue_reference.meshes.builders import indent_block
    from tissue_reference.model.case import Actuator, Boundary, Case, Material

    mesh = indent_block(size)
    tip = Actuator("I", "tip", (0.0, 0.0, -1.0), type="indenter", tip="sphere", radius=radius,
                   point=(0.0, 0.0, 0.0), contact_region="top")
    case = Case(mesh, Material("neo-hookean", 6.0, 0.45, volumetric=volumetric),
                boundaries=[Boundary("bottom", "fixed"),
                            Boundary("xsym", "sliding", normal=(1.0, 0.0, 0.0)),
                            Boundary("ysym", "sliding", normal=(0.0, 1.0, 0.0))],
                actuators=[tip])
    print(f"indent-block at {size:g} mm ({mesh.n_cells} cells), {TIP} R = {radius:g} mm, P2, "
          f"volumetric {volumetric}, contact rule {rule}", flush=True)
    s = fr.ReferenceSolver(case, degree=2, contact_quadrature=rule)
    skin = np.unique(np.concatenate([mesh.facet_regions[r].ravel() for r in ("top", "tip")]))
    r0 = np.hypot(*mesh.points[skin, :2].T)
    off_axis = r0 > 0.3 * radius
    prev = None
    for d in depths:
        t0 = time.perf_counter()
        try:
            res, ok = s.solve({"I": d}, initial=prev), True
        except ConvergenceError as exc:
            res, ok = exc.last_converged, False
        ind = res.indenters["I"]
        J = cell_min_J(s)
        w = int(np.argmin(J))
        X = mesh.points[mesh.cells[w]].mean(axis=0)
        x = X + res.u[mesh.cells[w]].mean(axis=0)
        xs = mesh.points[skin] + res.u[skin]
        hoop = (np.hypot(*xs[:, :2].T)[off_axis] / r0[off_axis]).min()
        print(f"depth {d:g} mm ({d / radius:.2f} R): converged {ok}, reached {ind['push']:.3f} mm, "
              f"valid {res.valid}, force {4 * ind['force']:.3f} mN, smallest J "
              f"{J.min():.3f} at r {math.hypot(X[0], X[1]):.2f} z {X[2]:.2f} -> r "
              f"{math.hypot(x[0], x[1]):.2f} z {x[2]:.2f} mm, {(J < 0.2).sum()} cells below "
              f"0.2, skin hoop stretch >= {hoop:.3f}, {res.iterations} Newton, "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
        if not ok:
            break
        prev = res


def ball_only() -> None:
    """Replace the tip's gap (numpy and UFL) by a free ball's in this process."""
    import numpy as np
    import ufl

    import tissue_reference.fem_reference.contact_geometry as cg
    import tissue_reference.fem_reference.contact_indenter as ci

    def gap_ufl(y, o, d, flat, edge, sphere):
        w = y - o
        return ufl.sqrt(ufl.dot(w, w)) - edge

    def gap(self, y, o, d):
        return np.linalg.norm(np.asarray(y, float) - o, axis=1) - self.edge

    global TIP
    cg.gap_ufl = ci.gap_ufl = gap_ufl
    cg.TipShape.gap = gap
    TIP = "free ball"


def main():
    from tissue_reference.tissue.common import contact_rule

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=float, default=0.3, help="cells near the tip (mm)")
    ap.add_argument("--radius", type=float, default=1.0, help="tip radius R (mm)")
    ap.add_argument("--depths", type=float, nargs="+",
                    default=[0.5, 1.0, 1.5, 1.8, 2.0, 2.2, 2.5, 3.0], help="pushes (mm)")
    ap.add_argument("--volumetric", choices=["quadratic", "log"], default="quadratic")
    ap.add_argument("--ball-only", action="store_true",
                    help="a free ball without the rod behind it (a diagnostic)")
    ap.add_argument("--contact-quadrature", type=contact_rule,
                    default="nodal", metavar="RULE", help="'nodal' or a Gauss degree")
    args = ap.parse_args()
    if args.ball_only:
        ball_only()
    run(args.size, args.radius, args.depths, args.volumetric, args.contact_quadrature)


if __name__ == "__main__":
    main()
