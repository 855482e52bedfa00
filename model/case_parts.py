"""The parts of a Case: the material, boundary conditions, probes and actuators (patches and
rigid indenters), each a frozen dataclass validated when built, and the constants that name their
kinds. Units: length mm, stress kPa (= mN/mm^2), density kg/mm^3."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from tissue_reference.errors import CaseError, NotModeledError

__all__ = [
    "ACTUATOR_TYPES",
    "BOUNDARY_TYPES",
    "COEFFICIENT_LAWS",
    "CONTACT_TYPES",
    "E_RANGE_KPA",
    "MATERIAL_MODELS",
    "OGDEN_FIELDS",
    "TIP_SHAPES",
    "UNCOUPLED_LAWS",
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
MATERIAL_MODELS = ("neo-hookean", "linear-elastic", "stable-neo-hookean",
                   "saint-venant-kirchhoff", "corotational", "mooney-rivlin", "yeoh", "ogden")
"""The strain-energy laws (``Material``; formulas and checks: docs/laws.md)."""
UNCOUPLED_LAWS = ("neo-hookean", "mooney-rivlin", "yeoh", "ogden")
"""Laws of an isochoric energy of J^(-2/3) C (of its invariants Ibar1, Ibar2; Ogden's of its
eigenvalues) plus kappa/2 G(J)^2: they take the ``volumetric`` choice and the mixed u-p
formulation, so nearly incompressible ones do not lock."""
COEFFICIENT_LAWS = {"mooney-rivlin": ("c1", "c2", "k"), "yeoh": ("c1", "c2", "c3", "k"),
                    "ogden": ("mu", "alpha", "k")}
"""Laws given by their coefficients (kPa; Ogden's exponents alpha dimensionless) instead of E and
nu, which follow from them: the small-strain shear modulus mu0 (2 (c1 + c2), 2 c1, sum mu_i) and
the bulk modulus k. The names are the case file's ([material] keys)."""
OGDEN_FIELDS = {"mu": "ogden_mu", "alpha": "ogden_alpha"}
"""The case file's Ogden keys and the ``Material`` fields that hold them (``Material.mu`` is the
small-strain shear modulus of every law)."""
VOLUMETRIC_LAWS = ("quadratic", "log")
"""The uncoupled laws' volumetric energies kappa/2 G(J)^2: G = J - 1 (seed 000 eq. 14) or ln J."""
ACTUATOR_TYPES = ("patch", "indenter")
TIP_SHAPES = ("sphere", "punch")
CONTACT_TYPES = ("frictionless", "tied")


def _real(x) -> bool:
    """A number that is not a boolean (True would read as 1)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool)


@dataclass(frozen=True)
class Material:
    """Isotropic material. Moduli in kPa, density in kg/mm^3. ``model`` names the strain-energy
    law (docs/laws.md), with C = F^T F, J = det F, Ibar1 = J^(-2/3) tr C and Ibar2 = J^(-4/3)
    ((tr C)^2 - tr C^2) / 2 the invariants of J^(-2/3) C, mu = E / (2 (1 + nu)), kappa = E / (3 (1 - 2
    nu)), lambda = E nu / ((1 + nu) (1 - 2 nu)):

    neo-hookean: psi = mu/2 (Ibar1 - 3) + kappa/2 G(J)^2, with ``volumetric``:
      "quadratic" (seed 000 eq. 14): G = J - 1. The pressure kappa (1 - J) it resists with is
        bounded by kappa, and in hydrostatic compression the force per reference area,
        kappa (1 - J) J^(2/3), peaks at J = 0.4 and then falls: tissue pressed harder than that
        collapses (J -> 0) whatever the mesh. Where a tip or a patch rim compresses cells that
        far (J ~ 0.4) the answer stops.
      "log": G = ln J. The pressure -kappa ln J / J grows without bound as J -> 0; the same
        kappa, so the two agree at small strain (to first order in J - 1).
    mooney-rivlin (``c1``, ``c2``, ``k``): psi = c1 (Ibar1 - 3) + c2 (Ibar2 - 3) + k/2 G(J)^2;
      c1, c2 >= 0 (polyconvex: stable under every deformation), c1 + c2 > 0.
    yeoh (``c1``, ``c2``, ``c3``, ``k``): psi = sum_i c_i (Ibar1 - 3)^i + k/2 G(J)^2; c1 > 0,
      c3 >= 0 and c1 + 2 c2 x + 3 c3 x^2 > 0 for every x >= 0 (dpsi/dIbar1 > 0: stable).
    ogden (``mu`` = [mu_1, ...], ``alpha`` = [alpha_1, ...], ``k``; Abaqus' convention): psi =
      sum_i 2 mu_i / alpha_i^2 (lb1^alpha_i + lb2^alpha_i + lb3^alpha_i - 3) + k/2 G(J)^2 with
      lb_j = J^(-1/3) lambda_j the isochoric principal stretches; mu_i > 0 (each term's
      coefficient 2 mu_i / alpha_i^2 and its small-strain shear modulus mu_i: stable), alpha_i
      != 0, lists of one length. The fields are ``ogden_mu`` and ``ogden_alpha`` (tuples; the
      case file's keys mu and alpha: ``from_table``).
      For these three, E and nu are not given: they follow from mu0 = 2 (c1 + c2) (resp. 2 c1,
      sum mu_i) and kappa = k (``volumetric`` as for neo-hookean).
    stable-neo-hookean (``E``, ``nu``; Smith, de Goes and Kim 2018): psi = mu/2 (tr C - 3)
      + lambda'/2 (J - 1 - mu/lambda')^2 - mu^2 / (2 lambda'), lambda' = lambda + mu: the rest
      state carries no energy and the small-strain limit is linear elasticity's.
    saint-venant-kirchhoff (``E``, ``nu``): psi = lambda/2 (tr Eg)^2 + mu Eg:Eg, Eg = (C - I)/2;
      it softens in strong compression (a stiffness that vanishes at stretches of 1/sqrt(3)).
    corotational (``E``, ``nu``): psi = mu |F - R|^2 + lambda/2 tr(R^T F - I)^2 with F = R U
      the polar decomposition, = mu (tr C - 2 tr U + 3) + lambda/2 (tr U - 3)^2: the energy that
      co-rotational FEM linearizes (SOFA's), linear elasticity in the element's rotated frame.
    linear-elastic: psi = mu eps:eps + lambda/2 tr(eps)^2 (``volumetric`` does not apply).
    Stable Neo-Hookean, St Venant-Kirchhoff and corotational are compressible laws: nu < 0.5,
    the displacement formulation.

    Parameters
    ----------
    model : str
        The strain-energy law (``MATERIAL_MODELS``), default "neo-hookean".
    E : float or None
        Young's modulus (kPa); None for mooney-rivlin, yeoh and ogden.
    nu : float or None
        Poisson's ratio (dimensionless, < 0.5; 0.5 incompressible); None for mooney-rivlin,
        yeoh and ogden.
    density : float
        kg/mm^3 (default 1e-6, water).
    volumetric : str
        G(J) of the volumetric energy: "quadratic" or "log".
    c1, c2, c3 : float or None
        Mooney-Rivlin (c1, c2) and Yeoh (c1, c2, c3) coefficients (kPa); None for other laws.
    k : float or None
        Bulk modulus kappa (kPa) of mooney-rivlin, yeoh and ogden; None for other laws.
    ogden_mu, ogden_alpha : tuple of float or None
        Ogden's coefficients mu_i (kPa) and exponents alpha_i (the case file's ``mu`` and
        ``alpha``); None for other laws.

    Raises
    ------
    CaseError
        For an unknown model, coefficients the law does not take, or values out of range.
    """

    model: str = "neo-hookean"
    E: float | None = None
    nu: float | None = None
    density: float = 1.0e-6
    volumetric: str = "quadratic"
    c1: float | None = None
    c2: float | None = None
    c3: float | None = None
    k: float | None = None
    ogden_mu: tuple | None = None
    ogden_alpha: tuple | None = None

    @classmethod
    def from_table(cls, table: dict) -> Material:
        """The Material of a case file's ``[material]`` table (its keys ``mu`` and ``alpha`` are
        the fields ``ogden_mu`` and ``ogden_alpha``: ``OGDEN_FIELDS``).

        Parameters
        ----------
        table : dict
            The table's keys and values.

        Returns
        -------
        Material
            The material, checked.
        """
        return cls(**{OGDEN_FIELDS.get(k, k): v for k, v in table.items()})

    def __post_init__(self):
        if self.model not in MATERIAL_MODELS:
            raise CaseError(f"unknown material model {self.model!r}; models: {list(MATERIAL_MODELS)}")
        coeffs = COEFFICIENT_LAWS.get(self.model, ())
        extra = [n for n in ("c1", "c2", "c3", "k", "mu", "alpha")
                 if getattr(self, OGDEN_FIELDS.get(n, n)) is not None and n not in coeffs]
        if extra:
            takes = ", ".join(coeffs) if coeffs else "E, nu"
            raise CaseError(f"material model {self.model!r} takes {takes}; {', '.join(extra)} "
                            f"belong to other laws (docs/laws.md)")
        if coeffs:
            self._coefficients(coeffs)
        else:
            object.__setattr__(self, "E", 6.0 if self.E is None else self.E)
            object.__setattr__(self, "nu", 0.45 if self.nu is None else self.nu)
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
        if self.model not in UNCOUPLED_LAWS and self.volumetric != "quadratic":
            raise CaseError(f"material volumetric = {self.volumetric!r} applies to the laws "
                            f"{list(UNCOUPLED_LAWS)} only, not {self.model!r}")
        if self.model not in UNCOUPLED_LAWS and self.model != "linear-elastic" \
                and self.nu >= 0.5:
            raise CaseError(f"material model {self.model!r} is a compressible law: nu must be "
                            f"< 0.5, got nu={self.nu!r} (an incompressible material takes "
                            f"{', '.join(UNCOUPLED_LAWS)} in the mixed formulation)")

    def _coefficients(self, names):
        """Check a coefficient law's parameters (kPa) and set E and nu from mu0 and k."""
        missing = [n for n in names if getattr(self, OGDEN_FIELDS.get(n, n)) is None]
        if missing:
            raise CaseError(f"material model {self.model!r} needs {', '.join(names)} (kPa); "
                            f"missing: {', '.join(missing)}")
        for n in names:
            if n in OGDEN_FIELDS:
                continue
            v = getattr(self, n)
            if not (_real(v) and math.isfinite(v)):
                raise CaseError(f"material {n} must be a finite number (kPa), got {n}={v!r}")
        c1, c2, k = self.c1, self.c2, self.k
        c3 = self.c3 or 0.0
        if self.model == "ogden":
            mu0 = self._ogden_terms()
        elif self.model == "mooney-rivlin":
            if c1 < 0 or c2 < 0 or c1 + c2 <= 0:
                raise CaseError(f"mooney-rivlin: c1 = {c1!r}, c2 = {c2!r} kPa: the law is stable "
                                f"under every deformation (polyconvex) with c1 >= 0, c2 >= 0 and "
                                f"c1 + c2 > 0")
            mu0 = 2.0 * (c1 + c2)
        else:
            # c1 + 2 c2 x + 3 c3 x^2 > 0 for x = Ibar1 - 3 >= 0
            if c1 <= 0 or c3 < 0 or (c2 < 0 and c2 * c2 >= 3.0 * c1 * c3):
                raise CaseError(f"yeoh: c1 = {c1!r}, c2 = {c2!r}, c3 = {c3!r} kPa: dpsi/dIbar1 = "
                                f"c1 + 2 c2 x + 3 c3 x^2 must stay > 0 for every x = Ibar1 - 3 "
                                f">= 0 (c1 > 0, c3 >= 0, and c2 >= 0 or c2^2 < 3 c1 c3)")
            mu0 = 2.0 * c1
        if not k > 0:
            raise CaseError(f"{self.model}: the bulk modulus k must be > 0 kPa, got k={k!r}")
        E = 9.0 * k * mu0 / (3.0 * k + mu0)
        nu = (3.0 * k - 2.0 * mu0) / (2.0 * (3.0 * k + mu0))
        for name, given, derived in (("E", self.E, E), ("nu", self.nu, nu)):
            if given is not None and not (_real(given) and math.isclose(given, derived,
                                                                         rel_tol=1e-9)):
                raise CaseError(f"material model {self.model!r} takes {', '.join(names)}; {name} "
                                f"follows from them ({name} = {derived:.6g}), got {name}="
                                f"{given!r}: leave it out")
        object.__setattr__(self, "E", E)
        object.__setattr__(self, "nu", nu)

    def _ogden_terms(self) -> float:
        """Check Ogden's lists (finite, one nonzero length, mu_i > 0, alpha_i != 0), store
        them as tuples of floats, and return mu0 = sum mu_i (kPa)."""
        lists = {}
        for key, name in OGDEN_FIELDS.items():
            v = getattr(self, name)
            v = (v,) if _real(v) else v
            if not (isinstance(v, (list, tuple)) and all(_real(x) and math.isfinite(x)
                                                          for x in v)):
                raise CaseError(f"ogden: {key} must be a list of finite numbers, got "
                                f"{key}={getattr(self, name)!r}")
            lists[key] = tuple(float(x) for x in v)
        mu, alpha = lists["mu"], lists["alpha"]
        if not mu or len(mu) != len(alpha):
            raise CaseError(f"ogden: mu = {list(mu)} kPa and alpha = {list(alpha)} must be "
                            f"lists of one nonzero length (a term mu_i, alpha_i each)")
        bad = [i + 1 for i, (m, a) in enumerate(zip(mu, alpha)) if not (m > 0 and a != 0)]
        if bad:
            raise CaseError(f"ogden: mu = {list(mu)} kPa, alpha = {list(alpha)}: term(s) "
                            f"{', '.join(map(str, bad))} unstable: each term 2 mu_i / "
                            f"alpha_i^2 (sum lb^alpha_i - 3) needs mu_i > 0 (its coefficient "
                            f"and its small-strain shear modulus) and alpha_i != 0 "
                            f"(docs/laws.md)")
        object.__setattr__(self, "ogden_mu", mu)
        object.__setattr__(self, "ogden_alpha", alpha)
        return math.fsum(mu)

    @property
    def coefficients(self) -> dict:
        """The law's own coefficients (kPa) by name ({} for the laws of E and nu); Ogden's are
        mu_1, mu_2, ... and k (its exponents: ``ogden_alpha``)."""
        if self.model == "ogden":
            return {**{f"mu_{i + 1}": m for i, m in enumerate(self.ogden_mu)}, "k": float(self.k)}
        return {n: float(getattr(self, n)) for n in COEFFICIENT_LAWS.get(self.model, ())}

    def scaled(self, factor: float) -> Material:
        """This material with every modulus times ``factor`` (nu unchanged; Ogden's exponents
        too)."""
        if self.model == "ogden":
            return replace(self, E=None, nu=None, k=self.k * factor,
                           ogden_mu=tuple(m * factor for m in self.ogden_mu))
        if self.model in COEFFICIENT_LAWS:
            return replace(self, E=None, nu=None, **{n: v * factor for n, v in
                                                      self.coefficients.items()})
        return replace(self, E=self.E * factor)

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

    def require_law(self, laws, who: str):
        """Raise NotModeledError when this material's law is not one of ``laws``, those ``who``
        (a fast solver) implements: the reference solves every law."""
        if self.model not in laws:
            raise NotModeledError(f"{who} implements the laws {list(laws)}; this material is "
                                  f"{self.model!r} (the reference solves it: fem_reference.solve, "
                                  f"tissue solve --solver fem)")

    def require_seed_volumetric(self, who: str):
        """Raise CaseError for an uncoupled law (``UNCOUPLED_LAWS``) whose volumetric energy is
        not seed 000's kappa/2 (J - 1)^2, the only one ``who`` (a fast solver) implements."""
        if self.model in UNCOUPLED_LAWS and self.volumetric != "quadratic":
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
        (``fem_reference.contact``; frictionless ones by the fast solvers too). ``tip``
        "sphere" of ``radius``, or "punch": a flat circular punch of outer ``radius`` whose edge
        is rounded with
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
