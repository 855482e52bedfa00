"""The Case class: one problem description (mesh + material + boundary conditions + probes +
actuators) consumed by every solver of the project, reference and fast alike. Users import it,
with its reader ``load_case``, from ``model.case``.

Units: length mm, stress kPa (= mN/mm^2), force mN, density kg/mm^3, gravity mm/s^2.

A Case is built once (``load_case`` from a TOML file, or ``Case(...)`` from Python) and validated
then: unknown regions, bad material values, conflicting prescriptions on one vertex and rigid-body
freedom are all reported here, before any solver starts.

The Case's validation and vertex constraints are ``model.case_constraints`` (mixed in), the
Cases derived from it (``with_pushes``, ``with_mesh``, ...) ``model.case_variants``; the parts
(Material, Boundary, Probe, Actuator) are ``model.case_parts``, the TOML reader
``model.case_file``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from tissue_reference.errors import CaseError, NotModeledError
from tissue_reference.meshes.mesh import MeshData, cell_volumes, check_cells

from . import case_constraints, case_variants
from .case_parts import (
    ACTUATOR_TYPES,
    BOUNDARY_TYPES,
    COEFFICIENT_LAWS,
    CONTACT_TYPES,
    E_RANGE_KPA,
    MATERIAL_MODELS,
    TIP_SHAPES,
    UNCOUPLED_LAWS,
    Actuator,
    Boundary,
    Material,
    Probe,
    ProbeLocation,
    VertexConstraints,
    vec,
)
from .case_variants import RIM_J_WARN  # noqa: F401  (re-exported)

__all__ = [
    "ACTUATOR_TYPES",
    "BOUNDARY_TYPES",
    "COEFFICIENT_LAWS",
    "CONTACT_RULES",
    "CONTACT_TYPES",
    "E_RANGE_KPA",
    "MATERIAL_MODELS",
    "TIP_SHAPES",
    "TIP_STARTS",
    "UNCOUPLED_LAWS",
    "Actuator",
    "Boundary",
    "Case",
    "Material",
    "Probe",
    "ProbeLocation",
    "VertexConstraints",
    "tip_start_for",
]

TIP_STARTS = ("nodes", "surface")
"""Where an indenter starts (``[reference] tip_start``): touching the contact surface's
displacement nodes, or the surface itself as the mesh's geometry curves it
(``fem_reference.contact``)."""

CONTACT_RULES = "'nodal' or a Gauss degree 1-8"
"""What a contact rule (``contact_quadrature``) may be, as error messages name it."""


def is_contact_rule(rule) -> bool:
    """Whether ``rule`` is a contact rule: "nodal" or an int (not a bool) from 1 to 8."""
    return rule == "nodal" or (isinstance(rule, int) and not isinstance(rule, bool)
                               and 1 <= rule <= 8)


def tip_start_for(rule) -> str:
    """Where an indenter starts when neither the solve nor its case names a start, by the
    contact rule ``rule``: on the nodes with the nodal rule, which knows the gap only there (a
    tip started on the surface between nodes would travel through the skin until it reached
    one), on the surface with a Gauss rule, which samples the facets' interiors (a tip started
    on the nodes would start inside them, pressing at rest)."""
    return "nodes" if rule == "nodal" else "surface"


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


@dataclass(frozen=True)
class Case:
    """One problem. ``mesh`` is a MeshData; the rest as in the module docstring.

    Parameters
    ----------
    mesh : MeshData
        Vertices (mm), cells and named regions.
    material : Material
        The material law and its moduli (kPa); default: ``Material()``.
    boundaries : sequence of Boundary
        Boundary conditions on named regions.
    probes : sequence of Probe
        Named points (mm) where displacements are reported.
    actuators : sequence of Actuator
        Glued patches and rigid tips, each pushed (mm) along its direction.
    gravity : tuple or None
        Gravitational acceleration (mm/s^2); None: none.
    name : str
        The case's name in reports.
    source : str or None
        Where it was read from (messages name it); None: built in Python.
    reference_degree : int or None
        The reference's default Lagrange degree (``[reference] degree``); None: its own default.
    reference_contact_quadrature : str or int or None
        The reference's default contact rule ("nodal" or a Gauss degree); None: "nodal".
    reference_tip_start : str or None
        Where rigid tips start by default: "nodes" or "surface"; None: by the contact rule.
    reference_measured : tuple of dict
        ``[reference.measured]`` rows: the default discretization's measured accuracy
        (``fem_reference.measured``).

    Raises
    ------
    CaseError
        For unknown regions, bad values, conflicting prescriptions on one vertex, duplicate probe
        or actuator names, or rigid-body freedom.
    """

    mesh: MeshData
    material: Material = field(default_factory=Material)
    boundaries: tuple = ()
    probes: tuple = ()
    actuators: tuple = ()
    gravity: tuple | None = None
    name: str = "case"
    source: str | None = None
    reference_degree: int | None = None
    reference_contact_quadrature: str | int | None = None
    reference_tip_start: str | None = None   # "nodes" or "surface" (fem_reference.contact)
    reference_measured: tuple = ()   # [reference.measured] rows (dicts): fem_reference.measured

    def __post_init__(self):
        object.__setattr__(self, "boundaries", tuple(self.boundaries))
        object.__setattr__(self, "probes", tuple(self.probes))
        object.__setattr__(self, "actuators", tuple(self.actuators))
        where = self.source or self.name
        check_cells(self.mesh, source=where)
        gdim = self.mesh.gdim
        for b in self.boundaries:
            case_constraints.check_boundary(self, b, gdim, where)
        names = set()
        for p in self.probes:
            if p.name in names:
                raise CaseError(f"{where}: probe name {p.name!r} used twice")
            names.add(p.name)
            vec(p.point, gdim, f"{where}: probe {p.name!r} point")
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
            object.__setattr__(self, "gravity", tuple(vec(self.gravity, gdim, f"{where}: gravity")))
        if self.reference_degree is not None and (isinstance(self.reference_degree, bool) or
                                                  self.reference_degree not in (1, 2, 3)):
            raise CaseError(f"{where}: reference degree must be 1, 2 or 3, got "
                            f"{self.reference_degree!r}")
        rule = self.reference_contact_quadrature
        if rule is not None and not is_contact_rule(rule):
            raise CaseError(f"{where}: reference contact_quadrature must be {CONTACT_RULES}, "
                            f"got {rule!r}")
        if self.reference_tip_start is not None and self.reference_tip_start not in TIP_STARTS:
            raise CaseError(f"{where}: reference tip_start must be one of {list(TIP_STARTS)}, "
                            f"got {self.reference_tip_start!r}")
        _ = self.constraints  # validates the prescriptions (raises on conflicts)
        case_constraints.check_rigid_body(self, where)

    # ------------------------------------------------------------ constraints (case_constraints)
    @cached_property
    def constraints(self) -> VertexConstraints:
        """Prescribed dofs at full load (``case_constraints.vertex_constraints``); CaseError when
        two regions prescribe one dof differently."""
        return case_constraints.vertex_constraints(self)

    @cached_property
    def reaction_owners(self):
        """(regions, region index of each prescribed dof) (``case_constraints``)."""
        return case_constraints.reaction_owners(self)

    def rigid_body_modes(self) -> np.ndarray:
        """(gdim*n, 6|3) node-major rigid-body modes (``case_constraints``)."""
        return case_constraints.rigid_body_modes(self)

    def free_dofs(self) -> np.ndarray:
        """Node-major dofs no Dirichlet-type condition prescribes (``case_constraints``)."""
        return case_constraints.free_dofs(self)

    def dirichlet_regions(self) -> list[str]:
        """Regions with a Dirichlet-type condition (``case_constraints``)."""
        return case_constraints.dirichlet_regions(self)

    def prescribed_reactions(self, r) -> dict:
        """Region -> (gdim,) sum of ``r`` (mN) over the dofs it prescribes
        (``case_constraints.prescribed_reactions``)."""
        return case_constraints.prescribed_reactions(self, r)

    # ------------------------------------------------------------ derived Cases (case_variants)
    def with_pushes(self, pushes: dict | None) -> Case:
        """This Case with its actuators pushed (mm; ``case_variants.with_pushes``)."""
        return case_variants.with_pushes(self, pushes)

    def with_free_actuators(self) -> Case:
        """This Case with every patch actuator idle-free (``case_variants``)."""
        return case_variants.with_free_actuators(self)

    def with_material(self, **changes) -> Case:
        """This Case with its material's fields changed (``case_variants``)."""
        return case_variants.with_material(self, **changes)

    def with_law(self, model: str, params: dict | None = None) -> Case:
        """This Case with its tissue's strain-energy law ``model`` and parameters ``params``
        (``case_variants.with_law``)."""
        return case_variants.with_law(self, model, params)

    def with_mesh(self, mesh: MeshData) -> Case:
        """This Case on another mesh (``case_variants``)."""
        return case_variants.with_mesh(self, mesh)

    def glued_unconverged(self) -> dict[str, str]:
        """Actuator -> why, for each glued patch pushed past where answers converge
        (``case_variants.glued_unconverged``)."""
        return case_variants.glued_unconverged(self)

    def glued_patch_warnings(self, u, cell_J=None) -> list[str]:
        """One line per pushed glued patch past its range or with crushed rim cells
        (``case_variants.glued_patch_warnings``)."""
        return case_variants.glued_patch_warnings(self, u, cell_J)

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

    def indenters(self) -> tuple:
        """The actuators of type "indenter"."""
        return tuple(a for a in self.actuators if a.type == "indenter")

    def require_no_contact(self, who: str):
        """Raise CaseError naming the first indenter: ``who`` (a solver without contact) cannot
        model a rigid tip pressing on the skin (NotModeledError, a CaseError)."""
        for a in self.indenters():
            raise NotModeledError(f"{who} does not model contact: actuator {a.name!r} is an indenter "
                            f"(the reference solves it: fem_reference.solve)")
