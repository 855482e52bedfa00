"""The parts of a Case: the material, boundary conditions, probes and actuators (patches and
rigid indenters), each a frozen dataclass validated when built, and the constants that name their
kinds. Units: length mm, stress kPa (= mN/mm^2), density kg/mm^3."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import CaseError

__all__ = [
    "ACTUATOR_TYPES",
    "BOUNDARY_TYPES",
    "CONTACT_TYPES",
    "E_RANGE_KPA",
    "MATERIAL_MODELS",
    "TIP_SHAPES",
    "VOLUMETRIC_LAWS",
    "Actuator",
    "Boundary",
    "Material",
    "Probe",
    "ProbeLocation",
    "VertexConstraints",
]

IDLE_MODES = ("held", "free")
BOUNDARY_TYPES = ("fixed", "displacement", "affine", "sliding", "traction")
E_RANGE_KPA = (1e-9, 1e12)
"""Young's moduli accepted (kPa): from far softer than any tissue to harder than diamond
(1.2e9 kPa); outside it the residuals of a solve under- or overflow."""
MATERIAL_MODELS = ("neo-hookean", "linear-elastic")
VOLUMETRIC_LAWS = ("quadratic", "log")
"""The Neo-Hookean volumetric energies kappa/2 G(J)^2: G = J - 1 (seed 000 eq. 14) or ln J."""
ACTUATOR_TYPES = ("patch", "indenter")
TIP_SHAPES = ("sphere", "punch")
CONTACT_TYPES = ("frictionless", "tied")


def _real(x) -> bool:
    """A number that is not a boolean (True would read as 1)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool)


@dataclass(frozen=True)
class Material:
    """Isotropic material. E in kPa, density in kg/mm^3.

    neo-hookean: psi = mu/2 (J^(-2/3) tr C - 3) + kappa/2 G(J)^2, mu = E / (2 (1 + nu)),
    kappa = E / (3 (1 - 2 nu)), with ``volumetric``:
      "quadratic" (seed 000 eq. 14): G = J - 1. The pressure kappa (1 - J) it resists with is
        bounded by kappa, and in hydrostatic compression the force per reference area,
        kappa (1 - J) J^(2/3), peaks at J = 0.4 and then falls: tissue pressed harder than that
        collapses (J -> 0) whatever the mesh. Where a tip or a patch rim compresses cells that
        far (J ~ 0.4) the answer stops.
      "log": G = ln J. The pressure -kappa ln J / J grows without bound as J -> 0; the same
        kappa, so the two agree at small strain (to first order in J - 1).
    linear-elastic: psi = mu eps:eps + lambda/2 tr(eps)^2 (``volumetric`` does not apply).
    """

    model: str = "neo-hookean"
    E: float = 6.0
    nu: float = 0.45
    density: float = 1.0e-6
    volumetric: str = "quadratic"

    def __post_init__(self):
        if self.model not in MATERIAL_MODELS:
            raise CaseError(f"unknown material model {self.model!r}; models: {list(MATERIAL_MODELS)}")
        if not (_real(self.E) and math.isfinite(self.E) and self.E > 0):
            raise CaseError(f"material E must be > 0 kPa, got E={self.E!r}")
        if not E_RANGE_KPA[0] <= self.E <= E_RANGE_KPA[1]:
            raise CaseError(f"material E must lie in the physical range [{E_RANGE_KPA[0]:g}, "
                            f"{E_RANGE_KPA[1]:g}] kPa, got E={self.E!r}")
        if not (_real(self.nu) and -1.0 < self.nu <= 0.5):
            raise CaseError(f"material nu must lie in (-1, 0.5] (0.5: incompressible), "
                            f"got nu={self.nu!r}")
        if not (_real(self.density) and math.isfinite(self.density) and self.density >= 0):
            raise CaseError(f"material density must be >= 0 kg/mm^3, got {self.density!r}")
        if self.volumetric not in VOLUMETRIC_LAWS:
            raise CaseError(f"unknown material volumetric law {self.volumetric!r}; laws: "
                            f"{list(VOLUMETRIC_LAWS)}")
        if self.model != "neo-hookean" and self.volumetric != "quadratic":
            raise CaseError(f"material volumetric = {self.volumetric!r} applies to the "
                            f"neo-hookean model only, not {self.model!r}")

    @property
    def mu(self) -> float:
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def kappa(self) -> float:
        """Bulk modulus (kPa); inf for an incompressible material (nu = 0.5)."""
        if self.nu >= 0.5:
            return math.inf
        return self.E / (3.0 * (1.0 - 2.0 * self.nu))

    @property
    def lmbda(self) -> float:
        """Lame's first parameter (kPa); inf for nu = 0.5."""
        if self.nu >= 0.5:
            return math.inf
        return self.E * self.nu / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))

    def require_seed_volumetric(self, who: str):
        """Raise CaseError for a Neo-Hookean material whose volumetric law is not seed 000's
        kappa/2 (J - 1)^2, the only one ``who`` (a fast solver) implements."""
        if self.model == "neo-hookean" and self.volumetric != "quadratic":
            raise CaseError(f"{who} implements seed 000's volumetric energy kappa/2 (J - 1)^2 "
                            f"only; this material has volumetric = {self.volumetric!r} (the "
                            f"reference solves it)")

    def require_compressible(self, who: str):
        """Raise CaseError for an incompressible material (nu = 0.5), which ``who`` (a
        displacement-based solver) cannot represent."""
        if self.nu >= 0.5:
            raise CaseError(f"{who} is displacement-based and cannot represent an incompressible "
                            f"material (nu = 0.5); the mixed reference can "
                            f"(fem_reference.solve(case, formulation='mixed'))")


def vec(value, n, what):
    try:
        v = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise CaseError(f"{what} must be a list of {n} numbers, got {value!r}") from exc
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise CaseError(f"{what} must be a list of {n} finite numbers, got {value!r}")
    return v


@dataclass(frozen=True)
class Boundary:
    """A boundary condition on a named region.

    fixed: u = 0.  displacement: u = value (mm), optionally only ``components``.
    affine: u(X) = gradient @ X + offset.  sliding: u . normal = value (mm), tangential motion free.
    traction: dead load ``value`` (kPa, per reference area).
    """

    region: str
    type: str = "fixed"
    value: object = None
    components: tuple | None = None
    gradient: object = None
    offset: object = None
    normal: object = None

    def __post_init__(self):
        if self.type not in BOUNDARY_TYPES:
            raise CaseError(f"boundary on {self.region!r}: unknown type {self.type!r}; "
                            f"types: {list(BOUNDARY_TYPES)}")


@dataclass(frozen=True)
class Probe:
    """A named point of the reference configuration (mm) where displacements are reported."""

    name: str
    point: tuple


@dataclass(frozen=True)
class Actuator:
    """An actuator pushed along ``direction`` (normalized on construction). Lengths in mm.

    type "patch" (default): ``region`` is glued to a rigid plate and moved rigidly;
        ``Case.with_pushes`` turns a push into a displacement condition on it. ``idle``: what
        the region does in a solve that does not push it: "held" (default) glued at push 0,
        "free" no condition (it moves with the tissue).
    type "indenter": a rigid tip pressing on the skin, solved with contact by the reference
        (``fem_reference.contact``; the fast solvers refuse it). ``tip`` "sphere" of ``radius``,
        or "punch": a flat circular punch of outer ``radius`` whose edge is rounded with
        ``edge_radius`` (0 < edge_radius < radius; the flat face has radius radius -
        edge_radius). The tip's axis passes through ``point`` (default: the area centroid of the
        facet region ``region``) along ``direction``; at push 0 it touches the contact surface
        (zero gap, zero force) and a push moves it by push * direction. ``contact``:
        "frictionless" (default) or "tied" (no slip where in contact; a punch only, whose face
        touches from push 0). The contact surface is
        ``region`` and the facet regions ``contact_region`` (a name or a tuple of names, e.g.
        the skin around the site: contact spreads as the tip goes in). ``push`` (mm) is the
        actuator's position, set by ``Case.with_pushes`` (0 on a Case as loaded).
    """

    name: str
    region: str
    direction: tuple
    type: str = "patch"
    tip: str | None = None
    radius: float | None = None
    edge_radius: float | None = None
    point: tuple | None = None
    contact: str | None = None
    contact_region: tuple = ()
    push: float = 0.0
    idle: str = "held"

    def __post_init__(self):
        d = np.asarray(self.direction, dtype=np.float64).reshape(-1)
        s = np.abs(d).max(initial=0.0)
        if not np.isfinite(s) or s == 0:
            raise CaseError(f"actuator {self.name!r}: direction must be a non-zero vector, "
                            f"got {self.direction!r}")
        d = d / s  # scaled first: the norm of a vector of huge components would overflow
        object.__setattr__(self, "direction", tuple((d / np.linalg.norm(d)).tolist()))
        self._check_indenter()

    def _check_indenter(self):
        what = f"actuator {self.name!r}"
        if self.type not in ACTUATOR_TYPES:
            raise CaseError(f"{what}: unknown type {self.type!r}; types: {list(ACTUATOR_TYPES)}")
        if not (_real(self.push) and math.isfinite(self.push)):
            raise CaseError(f"{what}: push must be a finite number (mm), got {self.push!r}")
        regions = (self.contact_region,) if isinstance(self.contact_region, str) else \
            self.contact_region
        if regions is None or not all(isinstance(r, str) and r for r in regions):
            raise CaseError(f"{what}: contact_region must be a region name or a list of names, "
                            f"got {self.contact_region!r}")
        object.__setattr__(self, "contact_region", tuple(regions))
        if self.idle not in IDLE_MODES:
            raise CaseError(f"{what}: idle must be one of {list(IDLE_MODES)}, got {self.idle!r}")
        if self.type == "indenter" and self.idle != "held":
            raise CaseError(f"{what}: idle only for a patch: an idle indenter stays where it is "
                            f"(push 0, touching the skin)")
        if self.type == "patch":
            extra = [k for k in ("tip", "radius", "edge_radius", "point", "contact")
                     if getattr(self, k) is not None] + (["contact_region"] if regions else [])
            if extra:
                raise CaseError(f"{what}: {', '.join(extra)} only for an indenter "
                                f"(type = 'indenter'), not a patch")
            return
        if self.tip not in TIP_SHAPES:
            raise CaseError(f"{what}: an indenter needs tip = one of {list(TIP_SHAPES)}, "
                            f"got {self.tip!r}")
        if not (_real(self.radius) and math.isfinite(self.radius) and self.radius > 0):
            raise CaseError(f"{what}: an indenter needs a radius > 0 (mm), got {self.radius!r}")
        if self.tip == "punch":
            e = self.edge_radius
            if not (_real(e) and math.isfinite(e) and 0 < e < self.radius):
                raise CaseError(f"{what}: a punch needs 0 < edge_radius < radius = "
                                f"{self.radius:g} mm, got edge_radius={e!r}")
        elif self.edge_radius is not None:
            raise CaseError(f"{what}: edge_radius only for tip = 'punch', not a sphere")
        if self.point is not None:
            object.__setattr__(self, "point", tuple(vec(self.point, len(self.direction),
                                                         f"{what}: point").tolist()))
        contact = "frictionless" if self.contact is None else self.contact
        if contact not in CONTACT_TYPES:
            raise CaseError(f"{what}: contact must be one of {list(CONTACT_TYPES)}, "
                            f"got {self.contact!r}")
        if contact == "tied" and self.tip == "sphere":
            raise CaseError(f"{what}: contact = 'tied' needs tip = 'punch': a sphere's contact "
                            f"grows from a point, and the tied law holds the skin in contact to "
                            f"the tip's travel since push 0, right only for skin touching from "
                            f"the start")
        object.__setattr__(self, "contact", contact)

    @property
    def contact_regions(self) -> tuple:
        """The facet regions an indenter's tip may touch: ``region``, then ``contact_region``."""
        return tuple(dict.fromkeys((self.region, *self.contact_region)))


@dataclass(frozen=True)
class ProbeLocation:
    """Where a probe sits: a cell and barycentric weights (the point snapped into the mesh)."""

    name: str
    point: np.ndarray
    cell: int
    weights: np.ndarray
    snapped_point: np.ndarray
    snap_distance: float


@dataclass(frozen=True)
class VertexConstraints:
    """Dirichlet-type conditions on vertices, in node-major dof numbering (dof = gdim*v + c).

    dofs / values: prescribed dofs and their values (mm) at full load.
    sliding: (vertex ids, unit normal, value) for oblique sliding regions (u . n = value).
    owner: for each prescribed dof, the region that set it.
    """

    dofs: np.ndarray
    values: np.ndarray
    sliding: tuple
    owner: tuple
