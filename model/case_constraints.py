"""The Case's boundary conditions as vertex constraints: functions of a Case, which
``model.case_model.Case`` calls (its ``constraints``, ``free_dofs``, ...).

Units: length and displacement mm, traction kPa, reaction force mN.

Each condition is checked against the mesh when the Case is built (``check_boundary``), and
together they must leave no rigid-body mode free (``check_rigid_body``). ``vertex_constraints`` gives
the prescribed dofs and their values at full load (CaseError when two regions prescribe one dof
differently); ``free_dofs`` the rest; ``prescribed_reactions`` sums a reaction vector over the
dofs each region prescribes.
"""
from __future__ import annotations

import numpy as np

from tissue_reference.errors import CaseError

from .case_parts import Boundary, VertexConstraints, vec

__all__ = ["axis_of", "check_boundary", "check_rigid_body", "dirichlet_regions", "free_dofs",
           "prescribed_reactions", "reaction_owners", "rigid_body_modes", "vertex_constraints"]


def axis_of(normal, tol=1e-12):
    """The axis (0, 1, 2) a unit ``normal`` lies along, None for an oblique one."""
    n = np.abs(normal)
    k = int(np.argmax(n))
    return k if np.all(np.delete(n, k) <= tol) else None


def check_boundary(case, b: Boundary, gdim: int, where: str):
    try:
        case.mesh.region_vertices(b.region)
    except CaseError as exc:
        raise CaseError(f"{where}: boundary {b.type!r}: {exc}") from None
    what = f"{where}: boundary {b.type!r} on {b.region!r}"
    if b.type == "displacement":
        if b.value is None:
            raise CaseError(f"{what} needs value = [ux, uy{', uz' if gdim == 3 else ''}] (mm)")
        vec(b.value, gdim, f"{what}: value")
        if b.components is not None:
            comps = list(b.components)
            if not comps or any(not isinstance(c, int) or not 0 <= c < gdim for c in comps):
                raise CaseError(f"{what}: components must be a list of indices in "
                                f"0..{gdim - 1}, got {b.components!r}")
    elif b.type == "affine":
        g = np.asarray(b.gradient if b.gradient is not None else np.zeros((gdim, gdim)), float)
        if g.shape != (gdim, gdim) or not np.all(np.isfinite(g)):
            raise CaseError(f"{what}: gradient must be a {gdim}x{gdim} matrix, got {b.gradient!r}")
        vec(b.offset if b.offset is not None else np.zeros(gdim), gdim, f"{what}: offset")
    elif b.type == "sliding":
        if b.normal is None:
            raise CaseError(f"{what} needs normal = [nx, ny{', nz' if gdim == 3 else ''}]")
        n = vec(b.normal, gdim, f"{what}: normal")
        if np.linalg.norm(n) == 0:
            raise CaseError(f"{what}: normal must be non-zero")
        float(b.value or 0.0)
    elif b.type == "traction":
        if b.region not in case.mesh.facet_regions:
            raise CaseError(f"{what}: traction needs a boundary (facet) region; facet regions: "
                            f"{sorted(case.mesh.facet_regions)}")
        vec(b.value, gdim, f"{what}: value (kPa)")


def check_rigid_body(case, where):
    """Rank of the constraints restricted to rigid-body modes must be full (6 in 3D, 3 in 2D)."""
    c = case.constraints
    d = case.mesh.gdim
    modes = case.rigid_body_modes()
    rows = [modes[c.dofs]]
    for verts, n, _ in c.sliding:
        rows.append(np.einsum("vcm,c->vm", modes.reshape(-1, d, modes.shape[1])[verts], n))
    mat = np.concatenate(rows) if rows else np.zeros((0, modes.shape[1]))
    need = modes.shape[1]
    rank = np.linalg.matrix_rank(mat, tol=1e-9 * max(1.0, np.abs(mat).max(initial=0.0))) \
        if len(mat) else 0
    if rank < need:
        raise CaseError(
            f"{where}: the boundary conditions leave {need - rank} rigid-body mode(s) free "
            f"(constraints fix {rank} of {need}); add a fixed, displacement or sliding region")


def rigid_body_modes(case) -> np.ndarray:
    """(gdim*n, 6|3) node-major translations and infinitesimal rotations about the centroid."""
    x = case.mesh.points - case.mesh.points.mean(axis=0)
    n, d = x.shape
    if d == 3:
        m = np.zeros((n, 3, 6))
        for k in range(3):
            m[:, k, k] = 1.0
        m[:, 1, 3], m[:, 2, 3] = -x[:, 2], x[:, 1]
        m[:, 0, 4], m[:, 2, 4] = x[:, 2], -x[:, 0]
        m[:, 0, 5], m[:, 1, 5] = -x[:, 1], x[:, 0]
    else:
        m = np.zeros((n, 2, 3))
        m[:, 0, 0] = m[:, 1, 1] = 1.0
        m[:, 0, 2], m[:, 1, 2] = -x[:, 1], x[:, 0]
    return m.reshape(n * d, -1)


def vertex_constraints(case) -> VertexConstraints:
    """Prescribed dofs at full load; CaseError when two regions prescribe one dof differently."""
    d = case.mesh.gdim
    X = case.mesh.points
    val: dict[int, float] = {}
    own: dict[int, str] = {}
    sliding = []
    oblique_names = []

    def put(verts, comp, values, region):
        for v, x in zip(verts.tolist(), np.broadcast_to(values, len(verts)).tolist()):
            k = d * v + comp
            if k in val and abs(val[k] - x) > 1e-9 * max(1.0, abs(x)):
                raise CaseError(
                    f"{case.source or case.name}: conflicting prescriptions on vertex {v} "
                    f"(component {comp}): region {own[k]!r} sets {val[k]:g} mm, region "
                    f"{region!r} sets {x:g} mm")
            val[k] = x
            own.setdefault(k, region)

    for b in case.boundaries:
        verts = case.mesh.region_vertices(b.region)
        if b.type == "fixed":
            for c in range(d):
                put(verts, c, 0.0, b.region)
        elif b.type == "displacement":
            v = np.asarray(b.value, float)
            for c in (b.components if b.components is not None else range(d)):
                put(verts, c, v[c], b.region)
        elif b.type == "affine":
            g = np.asarray(b.gradient if b.gradient is not None else np.zeros((d, d)), float)
            off = np.asarray(b.offset if b.offset is not None else np.zeros(d), float)
            u = X[verts] @ g.T + off
            for c in range(d):
                put(verts, c, u[:, c], b.region)
        elif b.type == "sliding":
            n = np.asarray(b.normal, float)
            n = n / np.abs(n).max()
            n = n / np.linalg.norm(n)
            g = float(b.value or 0.0)
            k = axis_of(n)
            if k is not None:
                put(verts, k, g * np.sign(n[k]), b.region)
            else:
                sliding.append((verts, n, g))
                oblique_names.append(b.region)
    # an oblique sliding vertex whose every component is also prescribed elsewhere must agree
    for (verts, n, g), region in zip(sliding, oblique_names):
        for v in verts.tolist():
            ks = [d * v + c for c in range(d)]
            if all(k in val for k in ks):
                un = sum(val[k] * n[c] for c, k in enumerate(ks))
                if abs(un - g) > 1e-9 * max(1.0, abs(g)):
                    raise CaseError(
                        f"{case.source or case.name}: conflicting prescriptions on vertex {v}: "
                        f"region {own[ks[0]]!r} fixes its displacement, so u.n = {un:g} mm, "
                        f"but sliding region {region!r} sets u.n = {g:g} mm")
    dofs = np.array(sorted(val), dtype=np.int64)
    return VertexConstraints(dofs, np.array([val[k] for k in dofs.tolist()]), tuple(sliding),
                             tuple(own[k] for k in dofs.tolist()))


def free_dofs(case) -> np.ndarray:
    """Node-major dofs not prescribed by a Dirichlet-type condition (sliding ones included)."""
    mask = np.ones(case.mesh.n_vertices * case.mesh.gdim, bool)
    mask[case.constraints.dofs] = False
    return np.flatnonzero(mask)


def dirichlet_regions(case) -> list[str]:
    """Regions with a Dirichlet-type condition (fixed, displacement, affine, sliding)."""
    return [b.region for b in case.boundaries if b.type != "traction"]


def reaction_owners(case):
    names = list(dict.fromkeys(case.constraints.owner))
    pos = {n: k for k, n in enumerate(names)}
    return names, np.array([pos[o] for o in case.constraints.owner], dtype=np.int64)


def prescribed_reactions(case, r) -> dict:
    """Region -> (gdim,) sum of r (mN, node-major (n*gdim,) or (n, gdim)) over the dofs that
    region prescribes; every Dirichlet region is present (zeros where it prescribes no
    dof, e.g. an oblique sliding one, whose share the solver adds)."""
    d = case.mesh.gdim
    c = case.constraints
    names, idx = case.reaction_owners
    sums = np.zeros((len(names), d))
    np.add.at(sums, (idx, c.dofs % d), np.asarray(r, float).reshape(-1)[c.dofs])
    out = {reg: np.zeros(d) for reg in case.dirichlet_regions()}
    out.update(zip(names, sums))
    return out
