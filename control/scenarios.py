"""Model-plant mismatch scenarios of the Table I analog: the plant is the reference on the case
changed as a scenario says (gravity, a nearly incompressible tissue, a finer mesh, rigid
indenters in contact where the model glues its patches), the model the fast solver.

``scenario_loop(case, name)`` builds one (``SCENARIOS`` describes each); the contact scenario's
plant is ``indenter_plant_case(case)`` or a case file checked by ``check_contact_plant``.
"""
from __future__ import annotations

import numpy as np

from tissue_reference.errors import CaseError, ConvergenceError

from .loop import solve_checked
from .plants import LoopSetup, build_loop, matching_case

__all__ = ["GRAVITY_MM_S2", "PLANT_NU", "SCENARIOS", "check_contact_plant",
           "indenter_plant_case", "patch_radius", "scenario_loop", "skin_region"]


# model-plant mismatches that matter with displacement-controlled actuators (E alone does not:
# without body forces the Neo-Hookean answer does not depend on E)
SCENARIOS = {
    "gravity": "the plant sags under gravity (the case's density, g along -z, the phantom "
               "standing on its base); the model has no gravity",
    "nu": "the plant is nearly incompressible (nu = 0.495: the reference's mixed P2/P1 "
          "formulation); the model keeps the case's nu",
    "mesh": "the model runs on a mesh twice as coarse as the plant's",
    "contact": "the plant's actuators are rigid spherical indenters in frictionless contact with "
               "the skin (the tissue may leave a tip the controller stops pushing); the model "
               "keeps the glued patches",
}
GRAVITY_MM_S2 = (0.0, 0.0, -9810.0)
PLANT_NU = 0.495


def _where(case) -> str:
    return case.source or case.name


def skin_region(case) -> str:
    """The facet region of ``case`` that is free skin: not an actuator's region and carrying no
    condition but a traction. CaseError naming the case and the candidates when there is none
    or more than one (then name it: ``indenter_plant_case(case, skin=...)``)."""
    taken = {a.region for a in case.actuators}
    taken |= {b.region for b in case.boundaries if b.type != "traction"}
    cands = sorted(r for r in case.mesh.facet_regions if r not in taken)
    if len(cands) != 1:
        why = "no facet region is" if not cands else f"{len(cands)} facet regions are"
        raise CaseError(f"{_where(case)}: cannot tell the skin the indenters may touch: {why} "
                        f"free of actuators and constraints ({cands}); name the skin "
                        f"(indenter_plant_case(case, skin=...)) or give an indenter plant case "
                        f"(tissue table1 --contact-plant)")
    return cands[0]


def patch_radius(case, region: str) -> float:
    """Radius (mm) of the disc with the area of the facet region ``region``: sqrt(area / pi)."""
    _, area = case.mesh.facet_measures(region)
    return float(np.sqrt(area.sum() / np.pi))


def indenter_plant_case(case, *, radius=None, skin=None):
    """The plant of the "contact" scenario: ``case`` (glued patches) with every actuator replaced
    by a rigid spherical indenter in frictionless contact, same name, region and direction; its
    axis through the region's area centroid, touching the skin at push 0.

    radius: mm, one number for every tip or a mapping name -> mm (default: ``patch_radius`` of
    the actuator's region, the disc of the patch's area). skin: the facet region(s) around the
    sites the tips may touch as they go in (default: ``skin_region``). The mesh is ``case``'s
    (the same object: the scenario's mismatch is the actuators alone)."""
    from dataclasses import replace

    where = _where(case)
    if not case.actuators:
        raise CaseError(f"{where}: no actuators to replace by indenters")
    tips = [a.name for a in case.indenters()]
    if tips:
        raise CaseError(f"{where}: actuators {tips} are indenters already; the contact "
                        f"scenario's model is the glued-patch case")
    if skin is None:
        skin = (skin_region(case),)
    elif isinstance(skin, str):
        skin = (skin,)
    skin = tuple(skin)
    for r in skin:
        if r not in case.mesh.facet_regions:
            raise CaseError(f"{where}: skin region {r!r} is not a facet region; facet regions: "
                            f"{sorted(case.mesh.facet_regions)}")
    if isinstance(radius, dict):
        unknown = sorted(set(radius) - {a.name for a in case.actuators})
        if unknown:
            raise CaseError(f"{where}: tip radii for {unknown}, which are not actuators; "
                            f"actuators: {[a.name for a in case.actuators]}")
    acts = []
    for a in case.actuators:
        if a.region not in case.mesh.facet_regions:
            raise CaseError(f"{where}: actuator {a.name!r} acts on {a.region!r}, not a facet "
                            f"region: an indenter presses on the skin")
        r = radius.get(a.name) if isinstance(radius, dict) else radius
        if r is None:
            r = patch_radius(case, a.region)
        acts.append(replace(a, type="indenter", tip="sphere", radius=r, contact="frictionless",
                            contact_region=tuple(x for x in skin if x != a.region),
                            idle="held", push=0.0))
    try:
        return replace(case, actuators=tuple(acts), name=f"{case.name}-indenters", source=None)
    except CaseError as exc:
        raise CaseError(f"{where}: its indenter plant: {exc}") from None


def check_contact_plant(model_case, plant_case):
    """``plant_case`` as the contact scenario's plant of ``model_case``: every actuator an
    indenter, the same actuator names (returned in the model's order) and directions, the same
    probes (``matching_case``). CaseError naming the fault otherwise."""
    plant = matching_case(model_case, plant_case, "model", "contact plant",
                          hint=": the plant must replace each of the model's actuators by an "
                               "indenter of the same name")
    patches = [a.name for a in plant.actuators if a.type != "indenter"]
    if patches:
        raise CaseError(f"the contact plant {_where(plant_case)}: actuators {patches} are not "
                        f"indenters (type = \"indenter\")")
    return plant


def scenario_loop(case, name: str, *, model: str = "admm", model_case=None,
                  model_E_factor: float = 1.0, plant_case=None, contact_rule=None,
                  model_update: str = "fast", degree: int | None = None) -> LoopSetup:
    """A mismatch scenario of ``SCENARIOS``: the plant is the reference on ``case`` changed as
    the scenario says, the model the fast solver ``model`` on ``model_case`` (a case of the same
    body, e.g. meshed coarser; default ``case``; required for "mesh", whose mismatch it is) with
    E scaled by ``model_E_factor``. "contact": the model has glued patches, the plant is
    ``plant_case`` (a case of the same body with indenters of the same names, e.g. meshed finer
    at the sites; ``check_contact_plant``), by default ``indenter_plant_case(case)``;
    ``contact_rule`` ("nodal" or a Gauss degree) replaces that plant's [reference]
    contact_quadrature. ``degree``: the reference plant's Lagrange degree (1 or 2; None: the
    plant case's own, ``build_loop``)."""
    if name not in SCENARIOS:
        raise CaseError(f"unknown mismatch scenario {name!r}; scenarios: {sorted(SCENARIOS)}")
    if (plant_case is not None or contact_rule is not None) and name != "contact":
        raise CaseError(f"a plant case or contact rule is given for the {name} scenario; only "
                        f"the contact scenario takes one (its indenter plant)")
    from dataclasses import replace

    if name == "gravity":
        plant_case = replace(case, gravity=GRAVITY_MM_S2)
    elif name == "nu":
        plant_case = case.with_material(nu=PLANT_NU)
    elif name == "mesh":
        if model_case is None or model_case is case:
            raise CaseError("the mesh scenario needs the model's case: the body meshed coarser")
        plant_case = case
    elif name == "contact":
        for c in (case, model_case or case):
            tips = [a.name for a in c.indenters()]
            if tips:
                raise CaseError(f"{_where(c)}: actuators {tips} are indenters; the contact "
                                f"scenario's model is the glued-patch case")
        plant_case = (indenter_plant_case(case) if plant_case is None
                      else check_contact_plant(case, plant_case))
        if contact_rule is not None:
            plant_case = replace(plant_case, reference_contact_quadrature=contact_rule)
    loop = build_loop(case, plant="fem", model=model, model_case=model_case,
                      model_E_factor=model_E_factor, plant_case=plant_case, scenario=name,
                      model_update=model_update, degree=degree)
    loop.meta["scenario_description"] = SCENARIOS[name]
    if name == "contact":   # which plant: a case file, or derived from the model's (source null)
        loop.meta.update({"plant_case": plant_case.name, "plant_source": plant_case.source})
        _check_plant_at_rest(loop, plant_case)
    return loop


def _check_plant_at_rest(loop, plant_case):
    """Solve the contact plant with every tip at its start: a plant whose skin is meshed too
    coarsely for its tips is invalid before any push (a tip between the skin's nodes), and every
    loop of the scenario would stop on its first step; say so once, before any loop runs."""
    rest = {a.name: 0.0 for a in plant_case.actuators}
    try:
        solve_checked(loop.plant, plant_case, rest, None, "the contact plant")
    except ConvergenceError as exc:
        src = plant_case.source or "derived from the case: tips of its patches' area, its mesh"
        raise CaseError(f"the contact scenario's plant ({src}) cannot start: {exc}. Give it a "
                        f"case of the same body meshed for its tips (--contact-plant, e.g. "
                        f"meshes/cases/phantom-indenter-control.toml for the phantom) or a "
                        f"finer --size") from None
