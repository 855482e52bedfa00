"""The Case: one problem description (mesh + material + boundary conditions + probes + actuators)
consumed by every solver of the project, reference and fast alike.

Units: length mm, stress kPa (= mN/mm^2), force mN, density kg/mm^3, gravity mm/s^2.

A Case is built once (``load_case`` from a TOML file, or ``Case(...)`` from Python) and validated
then: unknown regions, bad material values, conflicting prescriptions on one vertex and rigid-body
freedom are all reported here, before any solver starts.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from .case_parts import (
    ACTUATOR_TYPES,
    BOUNDARY_TYPES,
    CONTACT_TYPES,
    E_RANGE_KPA,
    MATERIAL_MODELS,
    TIP_SHAPES,
    Actuator,
    Boundary,
    Material,
    Probe,
    ProbeLocation,
    VertexConstraints,
    _vec,
)
from .errors import CaseError
from .mesh import MeshData, cell_jacobians, cell_volumes, check_cells

__all__ = [
    "ACTUATOR_TYPES",
    "BOUNDARY_TYPES",
    "CONTACT_TYPES",
    "E_RANGE_KPA",
    "MATERIAL_MODELS",
    "TIP_SHAPES",
    "Actuator",
    "Boundary",
    "Case",
    "Material",
    "Probe",
    "ProbeLocation",
    "VertexConstraints",
    "load_case",
]


def _closest_barycentric(verts: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Barycentric weights of the point of the simplex ``verts`` closest to ``x`` (NNLS with the
    partition of unity as a heavily weighted extra row)."""
    from scipy.optimize import nnls

    scale = max(np.ptp(verts, axis=0).max(), 1.0)
    big = 1e6
    A = np.vstack([verts.T / scale, big * np.ones(len(verts))])
    b = np.concatenate([x / scale, [big]])
    w, _ = nnls(A, b)
    return w / w.sum()


def _axis_of(normal, tol=1e-12):
    n = np.abs(normal)
    k = int(np.argmax(n))
    return k if np.all(np.delete(n, k) <= tol) else None


RIM_J_WARN = 0.2
"""Smallest volume ratio J at the rim of a pushed glued patch before the solvers warn."""


@dataclass(frozen=True)
class Case:
    """One problem. ``mesh`` is a MeshData; the rest as in the module docstring."""

    mesh: MeshData
    material: Material = field(default_factory=Material)
    boundaries: tuple = ()
    probes: tuple = ()
    actuators: tuple = ()
    gravity: tuple | None = None
    name: str = "case"
    source: str | None = None

    def __post_init__(self):
        object.__setattr__(self, "boundaries", tuple(self.boundaries))
        object.__setattr__(self, "probes", tuple(self.probes))
        object.__setattr__(self, "actuators", tuple(self.actuators))
        where = self.source or self.name
        check_cells(self.mesh, source=where)
        gdim = self.mesh.gdim
        for b in self.boundaries:
            self._check_boundary(b, gdim, where)
        names = set()
        for p in self.probes:
            if p.name in names:
                raise CaseError(f"{where}: probe name {p.name!r} used twice")
            names.add(p.name)
            _vec(p.point, gdim, f"{where}: probe {p.name!r} point")
        anames = set()
        for a in self.actuators:
            if a.name in anames:
                raise CaseError(f"{where}: actuator name {a.name!r} used twice")
            anames.add(a.name)
            self.mesh.region_vertices(a.region)  # raises with the list of regions
            if len(a.direction) != gdim:
                raise CaseError(f"{where}: actuator {a.name!r} direction must have {gdim} "
                                f"components, got {a.direction!r}")
            if a.type == "indenter":
                for r in a.contact_regions:
                    if r not in self.mesh.facet_regions:
                        raise CaseError(f"{where}: indenter {a.name!r} touches facet regions "
                                        f"only; {r!r} is not one; facet regions: "
                                        f"{sorted(self.mesh.facet_regions)}")
        if self.gravity is not None:
            object.__setattr__(self, "gravity", tuple(_vec(self.gravity, gdim, f"{where}: gravity")))
        _ = self.constraints  # validates the prescriptions (raises on conflicts)
        self._check_rigid_body(where)

    # ----------------------------------------------------------------- validation
    def _check_boundary(self, b: Boundary, gdim: int, where: str):
        try:
            self.mesh.region_vertices(b.region)
        except CaseError as exc:
            raise CaseError(f"{where}: boundary {b.type!r}: {exc}") from None
        what = f"{where}: boundary {b.type!r} on {b.region!r}"
        if b.type == "displacement":
            if b.value is None:
                raise CaseError(f"{what} needs value = [ux, uy{', uz' if gdim == 3 else ''}] (mm)")
            _vec(b.value, gdim, f"{what}: value")
            if b.components is not None:
                comps = list(b.components)
                if not comps or any(not isinstance(c, int) or not 0 <= c < gdim for c in comps):
                    raise CaseError(f"{what}: components must be a list of indices in "
                                    f"0..{gdim - 1}, got {b.components!r}")
        elif b.type == "affine":
            g = np.asarray(b.gradient if b.gradient is not None else np.zeros((gdim, gdim)), float)
            if g.shape != (gdim, gdim) or not np.all(np.isfinite(g)):
                raise CaseError(f"{what}: gradient must be a {gdim}x{gdim} matrix, got {b.gradient!r}")
            _vec(b.offset if b.offset is not None else np.zeros(gdim), gdim, f"{what}: offset")
        elif b.type == "sliding":
            if b.normal is None:
                raise CaseError(f"{what} needs normal = [nx, ny{', nz' if gdim == 3 else ''}]")
            n = _vec(b.normal, gdim, f"{what}: normal")
            if np.linalg.norm(n) == 0:
                raise CaseError(f"{what}: normal must be non-zero")
            float(b.value or 0.0)
        elif b.type == "traction":
            if b.region not in self.mesh.facet_regions:
                raise CaseError(f"{what}: traction needs a boundary (facet) region; facet regions: "
                                f"{sorted(self.mesh.facet_regions)}")
            _vec(b.value, gdim, f"{what}: value (kPa)")

    def _check_rigid_body(self, where):
        """Rank of the constraints restricted to rigid-body modes must be full (6 in 3D, 3 in 2D)."""
        c = self.constraints
        d = self.mesh.gdim
        modes = self.rigid_body_modes()
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

    # ----------------------------------------------------------------- derived data
    def rigid_body_modes(self) -> np.ndarray:
        """(gdim*n, 6|3) node-major translations and infinitesimal rotations about the centroid."""
        x = self.mesh.points - self.mesh.points.mean(axis=0)
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

    @cached_property
    def constraints(self) -> VertexConstraints:
        """Prescribed dofs at full load; CaseError when two regions prescribe one dof differently."""
        d = self.mesh.gdim
        X = self.mesh.points
        val: dict[int, float] = {}
        own: dict[int, str] = {}
        sliding = []
        oblique_names = []

        def put(verts, comp, values, region):
            for v, x in zip(verts.tolist(), np.broadcast_to(values, len(verts)).tolist()):
                k = d * v + comp
                if k in val and abs(val[k] - x) > 1e-9 * max(1.0, abs(x)):
                    raise CaseError(
                        f"{self.source or self.name}: conflicting prescriptions on vertex {v} "
                        f"(component {comp}): region {own[k]!r} sets {val[k]:g} mm, region "
                        f"{region!r} sets {x:g} mm")
                val[k] = x
                own.setdefault(k, region)

        for b in self.boundaries:
            verts = self.mesh.region_vertices(b.region)
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
                k = _axis_of(n)
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
                            f"{self.source or self.name}: conflicting prescriptions on vertex {v}: "
                            f"region {own[ks[0]]!r} fixes its displacement, so u.n = {un:g} mm, "
                            f"but sliding region {region!r} sets u.n = {g:g} mm")
        dofs = np.array(sorted(val), dtype=np.int64)
        return VertexConstraints(dofs, np.array([val[k] for k in dofs.tolist()]), tuple(sliding),
                                 tuple(own[k] for k in dofs.tolist()))

    def free_dofs(self) -> np.ndarray:
        """Node-major dofs not prescribed by a Dirichlet-type condition (sliding ones included)."""
        mask = np.ones(self.mesh.n_vertices * self.mesh.gdim, bool)
        mask[self.constraints.dofs] = False
        return np.flatnonzero(mask)

    def external_forces(self, scale: float = 1.0) -> np.ndarray:
        """Consistent P1 nodal forces (mN), node-major (n*gdim,), of tractions and gravity."""
        d = self.mesh.gdim
        f = np.zeros((self.mesh.n_vertices, d))
        for b in self.boundaries:
            if b.type == "traction":
                facets, area = self.mesh.facet_measures(b.region)
                t = np.asarray(b.value, float)
                np.add.at(f, facets.ravel(), np.repeat(area / d, d)[:, None] * t)
        if self.gravity is not None and self.material.density > 0:
            vol = np.abs(cell_volumes(self.mesh.points, self.mesh.cells))
            w = self.material.density * vol / (d + 1)
            np.add.at(f, self.mesh.cells.ravel(), np.repeat(w, d + 1)[:, None] * np.asarray(self.gravity))
        return scale * f.ravel()

    @cached_property
    def probe_locations(self) -> tuple:
        """Each probe's containing cell and barycentric weights; a point outside the discretized
        surface is snapped to the nearest cell (distance reported in ``snap_distance``)."""
        from scipy.spatial import cKDTree

        if not self.probes:
            return ()
        X = self.mesh.points
        cells = self.mesh.cells
        cent = X[cells].mean(axis=1)
        tree = cKDTree(cent)
        T = X[cells[:, 1:]] - X[cells[:, :1]]  # (m, d, d) edge vectors as rows
        out = []
        for p in self.probes:
            x = np.asarray(p.point, float)
            k = min(len(cells), 64)
            _, cand = tree.query(x, k=k)
            cand = np.atleast_1d(cand)
            best = None
            for c in cand:
                lam = np.linalg.solve(T[c].T, x - X[cells[c, 0]])
                w = np.concatenate([[1 - lam.sum()], lam])
                if w.min() >= -1e-10:
                    best = (int(c), w, x.copy(), 0.0)
                    break
                wc = _closest_barycentric(X[cells[c]], x)
                y = wc @ X[cells[c]]
                dist = float(np.linalg.norm(y - x))
                if best is None or dist < best[3]:
                    best = (int(c), wc, y, dist)
            c, w, y, dist = best
            out.append(ProbeLocation(p.name, x, c, w, y, dist))
        return tuple(out)

    def probe_values(self, u: np.ndarray) -> dict:
        """Interpolate a P1 vertex field (n, gdim) at the probes: name -> (gdim,) array."""
        u = np.asarray(u).reshape(self.mesh.n_vertices, -1)
        return {loc.name: loc.weights @ u[self.mesh.cells[loc.cell]] for loc in self.probe_locations}

    def actuator(self, name: str) -> Actuator:
        for a in self.actuators:
            if a.name == name:
                return a
        raise CaseError(f"{self.source or self.name}: unknown actuator {name!r}; actuators: "
                        f"{[a.name for a in self.actuators]}")

    def probe(self, name: str) -> Probe:
        for p in self.probes:
            if p.name == name:
                return p
        raise CaseError(f"{self.source or self.name}: unknown probe/target {name!r}; probes: "
                        f"{[p.name for p in self.probes]}")

    def with_pushes(self, pushes: dict | None) -> Case:
        """A new Case where each named patch actuator's region is displaced rigidly by
        ``push * direction`` (mm; pushes replace any condition already on that region), each
        patch not named and ``idle = "held"`` is held where it is (at its current ``push``: 0
        on a Case no push was applied to), and each actuator records its position ``push``
        (mm; an indenter gets no condition: the reference solves its contact). One convention
        for every solver, the control Jacobians and the loop; ``with_free_actuators()`` first
        makes the idle patches free."""
        pushes = dict(pushes or {})
        acts = {name: self.actuator(name) for name in pushes}
        held = {a.name: a for a in self.actuators
                if a.type == "patch" and a.name not in pushes and a.idle == "held"}
        if not pushes and not held:
            return self
        patches = {n: a for n, a in acts.items() if a.type == "patch"}
        patches.update(held)
        values = {n: float(pushes[n]) if n in pushes else float(a.push)
                  for n, a in patches.items()}
        regions = {a.region for a in patches.values()}
        kept = [b for b in self.boundaries if b.region not in regions]
        added = [Boundary(a.region, "displacement",
                          value=tuple((values[n] * np.asarray(a.direction)).tolist()))
                 for n, a in patches.items()]
        actuators = tuple(replace(a, push=float(pushes[a.name])) if a.name in acts else a
                          for a in self.actuators)
        return replace(self, boundaries=tuple(kept + added), actuators=actuators)

    def glued_patch_warnings(self, u) -> list[str]:
        """One line per pushed patch actuator whose cells (those touching its region) fall
        below J = RIM_J_WARN in the displacement ``u`` ((n, gdim) mm): the rim of a glued
        patch is singular, and past that compression its answer no longer converges under
        refinement (about 5 mm pushes on the phantom); an indenter actuator has no such rim."""
        out = []
        pushed = [a for a in self.actuators if a.type == "patch" and a.push != 0.0]
        if not pushed:
            return out
        J = cell_jacobians(self.mesh.points, self.mesh.cells, np.asarray(u, float))
        for a in pushed:
            verts = self.mesh.region_vertices(a.region)
            mask = np.isin(self.mesh.cells, verts).any(axis=1)
            if not mask.any():
                continue
            jmin = float(np.min(J[mask]))
            if jmin < RIM_J_WARN:
                out.append(f"glued patch {a.name!r} (push {a.push:g} mm) compresses the cells at "
                           f"its rim to J = {jmin:.3g} (< {RIM_J_WARN}): beyond the range in "
                           f"which a glued patch's answer converges under refinement; an "
                           f"indenter actuator (type = \"indenter\") has no singular rim")
        return out

    def with_free_actuators(self) -> Case:
        """The same Case with every patch actuator ``idle = "free"``: a patch a solve does not
        push moves with the tissue."""
        return replace(self, actuators=tuple(replace(a, idle="free") if a.type == "patch" else a
                                             for a in self.actuators))

    def indenters(self) -> tuple:
        """The actuators of type "indenter"."""
        return tuple(a for a in self.actuators if a.type == "indenter")

    def require_no_contact(self, who: str):
        """Raise CaseError naming the first indenter: ``who`` (a solver without contact) cannot
        model a rigid tip pressing on the skin."""
        for a in self.indenters():
            raise CaseError(f"{who} does not model contact: actuator {a.name!r} is an indenter "
                            f"(the reference solves it: fem_reference.solve)")

    def with_material(self, **changes) -> Case:
        return replace(self, material=replace(self.material, **changes))

    def with_mesh(self, mesh: MeshData) -> Case:
        return replace(self, mesh=mesh)

    def dirichlet_regions(self) -> list[str]:
        """Regions with a Dirichlet-type condition (fixed, displacement, affine, sliding)."""
        return [b.region for b in self.boundaries if b.type != "traction"]

    @cached_property
    def _owner_index(self):
        names = list(dict.fromkeys(self.constraints.owner))
        pos = {n: k for k, n in enumerate(names)}
        return names, np.array([pos[o] for o in self.constraints.owner], dtype=np.int64)

    def prescribed_reactions(self, r) -> dict:
        """Region -> (gdim,) sum of r (mN, node-major (n*gdim,) or (n, gdim)) over the dofs that
        region prescribes; every Dirichlet region is present (zeros where it prescribes no
        dof, e.g. an oblique sliding one, whose share the solver adds)."""
        d = self.mesh.gdim
        c = self.constraints
        names, idx = self._owner_index
        sums = np.zeros((len(names), d))
        np.add.at(sums, (idx, c.dofs % d), np.asarray(r, float).reshape(-1)[c.dofs])
        out = {reg: np.zeros(d) for reg in self.dirichlet_regions()}
        out.update(zip(names, sums))
        return out


def load_case(path, *, mesh: MeshData | None = None, size: float | None = None,
              max_cells: float | None = None) -> Case:
    """Read a Case TOML file (mesh paths relative to the file; format: docs/case-file.md).

    ``mesh`` replaces the file's mesh (e.g. a refined one); ``size`` (mm) overrides a builtin's
    size. ``max_cells``: a builtin mesh whose estimated cell count exceeds it is refused before
    gmsh starts (default None: ``meshes.builders.MAX_CELLS``; math.inf: no limit). Any input
    either loads or raises CaseError (CaseReadError when a file cannot be read), one line per
    fault naming the file and the key. The reader is ``meshes.case_file``.
    """
    from .case_file import load_case as read

    return read(path, mesh=mesh, size=size, max_cells=max_cells)
