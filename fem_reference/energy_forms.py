"""The reference's total energy as UFL forms, and Newton's residual and tangent compiled from it.

``forms`` holds the laws' energy densities as plain functions of the displacement (and the
pressure); this module assembles them into what ``ReferenceSolver`` iterates on:

- ``material_constants``: E, nu, 1/kappa, the law's coefficients and the load scale as dolfinx
  Constants (a changed material or load needs no recompilation; ``MaterialConstants.set``);
- ``measures``: the cells' and the tagged facets' measures at the solver's quadrature degree;
- ``internal_energy``: the strain energy of the displacement or mixed u-p formulation (the
  law's density and its volumetric part; the Ogden law's isochoric part on quadrature-point
  Functions, ``ogden_fields``);
- ``external_work``: gravity, a body force and the traction regions' tractions at full load;
- ``oblique_sliding_penalty``: the penalty holding the sliding regions whose normal is not an axis;
- ``compile_forms``: the total energy (internal - load * external + the sliding and contact
  penalties) differentiated into the residual and tangent and compiled once (``EnergyForms``).

Each function receives the fields, Constants and measures it uses, not the solver. Units: mm,
kPa, mN; energies in uJ (= kPa mm^3). The inertia of a dynamics step is not part of these forms:
it reaches Newton as its ``extra_terms`` after assembly (``dynamics``).
"""
from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import dolfinx.fem
import numpy as np
import ufl
from petsc4py import PETSc

from tissue_reference.model.case import Case, Material

from .forms import mixed_energy_density, strain_energy_density, volume_measure
from .jit import compile_form
from .ogden_fields import OgdenFields

__all__ = [
    "EnergyForms",
    "MaterialConstants",
    "compile_forms",
    "external_work",
    "internal_energy",
    "inv_kappa",
    "material_constants",
    "measures",
    "oblique_sliding_penalty",
]


def inv_kappa(material: Material) -> float:
    """1/kappa (1/kPa) of the material, exactly 0 for nu = 0.5."""
    return 3.0 * (1.0 - 2.0 * material.nu) / material.E


@dataclass
class MaterialConstants:
    """The material and the load scale as Constants of the mesh: ``E`` and ``nu`` (kPa, -),
    ``inv_kappa`` (1/kPa), ``coefficients`` (a law's own coefficients by name: Mooney-Rivlin's,
    Yeoh's; kPa) and ``load`` (the load fraction of the external loads, 1)."""
    E: dolfinx.fem.Constant
    nu: dolfinx.fem.Constant
    inv_kappa: dolfinx.fem.Constant
    coefficients: dict
    load: dolfinx.fem.Constant

    def set(self, material: Material) -> None:
        """Give the Constants another material's values (same law; the Ogden law's mu_i live on
        its quadrature Functions, ``OgdenFields.set_material``)."""
        self.E.value = material.E
        self.nu.value = material.nu
        self.inv_kappa.value = inv_kappa(material)
        for name, value in material.coefficients.items():
            if name in self.coefficients:   # (Ogden's mu_i: on its quadrature Functions)
                self.coefficients[name].value = value


def material_constants(mesh, material: Material) -> MaterialConstants:
    """The Constants of ``material`` on ``mesh``, the load scale at 1.

    Parameters
    ----------
    mesh : dolfinx.mesh.Mesh
        The solver's mesh.
    material : Material
        The Case's material (E kPa, nu, the law's coefficients kPa).

    Returns
    -------
    MaterialConstants
    """
    def const(v):
        return dolfinx.fem.Constant(mesh, PETSc.ScalarType(v))

    return MaterialConstants(E=const(material.E), nu=const(material.nu),
                             inv_kappa=const(inv_kappa(material)),
                             coefficients={n: const(v) for n, v in material.coefficients.items()},
                             load=const(1.0))


def measures(mesh, facet_tags, quadrature_degree: int):
    """(dx, ds): the cells' measure and the tagged facets' measure, both at
    ``quadrature_degree``."""
    md = {"quadrature_degree": quadrature_degree}
    dx = ufl.Measure("dx", domain=mesh, metadata=md)
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=facet_tags, metadata=md)
    return dx, ds


def internal_energy(material: Material, formulation: str, c: MaterialConstants, *, mesh, x,
                    u, p, quadrature_degree: int, dx):
    """The strain energy as a UFL form: the law's energy density (``forms``) of the
    displacement formulation, or the mixed formulation's perturbed Lagrangian in u and p.
    The Ogden law's isochoric part is quadrature-point Functions refreshed before every
    assembly (``OgdenFields.update``), its volumetric part UFL.

    Parameters
    ----------
    material : Material
        The Case's material (the law, its volumetric energy and coefficients).
    formulation : str
        "displacement" or "mixed".
    c : MaterialConstants
        E, nu, 1/kappa and the coefficients as Constants.
    mesh, x : dolfinx objects
        The mesh and the unknown Function (the Ogden law's fields are built on them).
    u, p : UFL expressions
        The displacement (mm) and, mixed, the pressure (kPa; None for displacement).
    quadrature_degree : int
        The degree of the Ogden law's quadrature space.
    dx : ufl.Measure
        The cells' measure at the solver's quadrature degree.

    Returns
    -------
    tuple
        (the strain energy, uJ, a ufl.Form; the Ogden law's ``OgdenFields``, else None; mixed,
        the volumetric strain measure the pressure multiplies, else None).
    """
    E, nu = c.E, c.nu
    mu = E / (2 * (1 + nu))
    fields = OgdenFields(mesh, x, u, quadrature_degree, material) \
        if material.model == "ogden" else None
    vol_form = None
    if fields is not None:
        vol = volume_measure(u, "ogden", material.volumetric)
        if formulation == "mixed":
            psi = -p * vol - c.inv_kappa / 2 * p ** 2
            vol_form = vol
        else:
            psi = E / (3 * (1 - 2 * nu)) / 2 * vol ** 2
    elif formulation == "mixed":
        psi, vol = mixed_energy_density(u, p, material.model, mu, c.inv_kappa,
                                        material.volumetric, c.coefficients)
        vol_form = vol
    else:
        kappa = E / (3 * (1 - 2 * nu))
        lmbda = E * nu / ((1 + nu) * (1 - 2 * nu))
        psi, _ = strain_energy_density(u, material.model, mu, kappa, lmbda,
                                       material.volumetric, c.coefficients)
    internal = psi * dx
    if fields is not None:
        internal = internal + fields.energy()
    return internal, fields, vol_form


def external_work(case: Case, *, mesh, u, gdim: int, region_tags: dict, body_force, dx, ds):
    """The work of the external loads at full load: gravity (and ``body_force``) over the
    cells, the traction regions' tractions over their facets.

    Parameters
    ----------
    case : Case
        The Case (gravity mm/s^2, density, traction boundaries).
    mesh : dolfinx.mesh.Mesh
        The solver's mesh.
    u : UFL expression
        The displacement (mm).
    gdim : int
        The geometric dimension.
    region_tags : dict
        Facet region name -> its tag in ``ds``.
    body_force : callable or None
        x -> UFL vector (mN/mm^3) of the reference coordinates, added to gravity.
    dx, ds : ufl.Measure
        The cells' and the tagged facets' measures.

    Returns
    -------
    tuple
        (the external work, uJ, a ufl.Form; ``body``, density times gravity, mN/mm^3, a
        Constant; ``tractions``, region -> its traction Constant, kPa).
    """
    g = case.gravity if case.gravity is not None else (0.0,) * gdim
    body = dolfinx.fem.Constant(mesh, PETSc.ScalarType(
        tuple(case.material.density * np.asarray(g, float))))
    external = ufl.inner(body, u) * dx
    if body_force is not None:
        external = external + ufl.inner(body_force(ufl.SpatialCoordinate(mesh)), u) * dx
    tractions = {}
    for b in case.boundaries:
        if b.type == "traction":
            t = dolfinx.fem.Constant(mesh, PETSc.ScalarType(tuple(map(float, b.value))))
            tractions[b.region] = t
            external = external + ufl.inner(t, u) * ds(region_tags[b.region])
    return external, body, tractions


def oblique_sliding_penalty(case: Case, beta: float, *, mesh, u, load, h_min: float,
                    region_tags: dict, ds):
    """The penalty that holds the sliding regions whose normal is not an axis on their
    plane, u.n = g (g scaled by the load).

    Parameters
    ----------
    case : Case
        The Case (its sliding boundaries, E in kPa).
    beta : float
        Factor of the penalty beta * E / h_min (kPa/mm).
    mesh : dolfinx.mesh.Mesh
        The solver's mesh.
    u : UFL expression
        The displacement (mm).
    load : dolfinx.fem.Constant
        The load fraction.
    h_min : float
        The smallest cell size (mm).
    region_tags : dict
        Facet region name -> its tag in ``ds``.
    ds : ufl.Measure
        The tagged facets' measure.

    Returns
    -------
    tuple
        (the penalty energy, uJ, a UFL form or 0; the oblique regions' names).
    """
    penalty = 0
    oblique = []   # sliding regions whose normal is not an axis: held by a penalty
    for b in case.boundaries:
        if b.type == "sliding":
            n = np.asarray(b.normal, float)
            n = n / np.linalg.norm(n)
            if np.count_nonzero(np.abs(n) > 1e-12) > 1:
                oblique.append(b.region)
                nn = ufl.as_vector(n.tolist())
                gval = dolfinx.fem.Constant(mesh, PETSc.ScalarType(float(b.value or 0.0)))
                k = beta * case.material.E / h_min
                penalty = penalty + k / 2 * (ufl.dot(u, nn) - load * gval) \
                    ** 2 * ds(region_tags[b.region])
    return penalty, oblique


@dataclass
class EnergyForms:
    """Newton's residual and tangent and the outputs' forms, compiled once: ``R_form`` (the
    total energy's residual), ``R_int_form`` (without the penalties), ``K_form`` (its tangent),
    ``K_halved_form`` (with indenters: the tangent without the tips' curvature, far from the
    answer and after a halved correction; ``contact``; else None) and ``W_form`` (the strain
    energy); with the UFL forms ``energy_internal``, ``R_ufl``, ``R_int_ufl`` and ``K_ufl``."""
    energy_internal: object
    R_ufl: object
    R_int_ufl: object
    K_ufl: object
    R_form: object
    R_int_form: object
    K_form: object
    K_halved_form: object
    W_form: object


def compile_forms(internal, external, penalty, *, x, W, load, formulation: str, fields,
                  contact, refresh) -> EnergyForms:
    """The total energy internal - load * external + penalty, differentiated in the unknown
    ``x`` and compiled; gives the contact its line search's energy
    (``Contact.line_search_energy``).

    Parameters
    ----------
    internal : ufl.Form
        The strain energy (uJ).
    external : ufl.Form
        The external work at full load (uJ), scaled by ``load``.
    penalty : ufl.Form or int
        The sliding and contact penalties' energy (uJ).
    x : dolfinx.fem.Function
        The unknown (on ``W``).
    W : dolfinx.fem.FunctionSpace
        The unknown's space (the test and trial functions').
    load : dolfinx.fem.Constant
        The load fraction.
    formulation : str
        "displacement" or "mixed" (the displacement part of the test functions).
    fields : OgdenFields or None
        The Ogden law's quadrature Functions, whose residual and tangent are added (not
        derived).
    contact : Contact
        The indenters' contact (its line search, normal energy and tangent without the tips'
        curvature).
    refresh : callable
        What brings the quadrature Functions to the unknown's value before an assembly.

    Returns
    -------
    EnergyForms
    """
    total = internal - load * external + penalty
    contact.line_search_energy(total, refresh)
    v = ufl.TestFunction(W)
    w = ufl.TrialFunction(W)
    R_ufl = ufl.derivative(total, x, v)
    R_int_ufl = ufl.derivative(internal - load * external, x, v)
    K_ufl = ufl.derivative(R_ufl, x, w)
    if fields is not None:   # what the quadrature Functions contribute (not derived)
        vu, wu = (ufl.split(v)[0], ufl.split(w)[0]) if formulation == "mixed" else (v, w)
        R_ufl = R_ufl + fields.residual(vu)
        R_int_ufl = R_int_ufl + fields.residual(vu)
        K_ufl = K_ufl + fields.tangent(vu, wu)
    R_form = compile_form(R_ufl)
    R_int_form = compile_form(R_int_ufl)
    K_form = compile_form(K_ufl)
    K_halved_form = None
    soft = contact.tangent_without_curvature(v, w)
    if soft is not None:
        K_halved_form = compile_form(
            K_ufl - ufl.derivative(ufl.derivative(contact.normal_energy, x, v), x, w) + soft)
    return EnergyForms(energy_internal=internal, R_ufl=R_ufl, R_int_ufl=R_int_ufl, K_ufl=K_ufl,
                       R_form=R_form, R_int_form=R_int_form, K_form=K_form,
                       K_halved_form=K_halved_form, W_form=compile_form(internal))
