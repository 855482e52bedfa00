"""Cases derived from a Case: functions of a Case, which ``model.case_model.Case`` calls (its
``with_pushes``, ``with_mesh``, ...).

Units: pushes and displacements mm; J (volume ratio) dimensionless.

``with_pushes`` applies actuator pushes (patches displaced rigidly, idle held patches held),
``with_free_actuators`` lets the idle patches move with the tissue, ``with_material`` and
``with_mesh`` swap one part, ``with_law`` gives the tissue another strain-energy law; ``glued_patch_warnings`` flags a pushed glued patch pushed past the
range where its answers converge under refinement (``glued_unconverged``: GLUED_CONVERGED_RADII
of its radius, whatever the mesh) or whose rim cells are compressed below ``RIM_J_WARN``.
"""
from __future__ import annotations

import contextlib
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from tissue_reference.errors import CaseError
from tissue_reference.meshes.mesh import MeshData, cell_jacobians

from .case_parts import COEFFICIENT_LAWS, MATERIAL_MODELS, UNCOUPLED_LAWS, Boundary, Material

if TYPE_CHECKING:
    from .case_model import Case

__all__ = ["GLUED_CONVERGED_RADII", "PUSHED_KEPT", "RIM_J_WARN", "glued_patch_warnings",
           "glued_unconverged", "patch_radius", "with_free_actuators", "with_law",
           "with_material", "with_mesh", "with_pushes"]

RIM_J_WARN = 0.2
"""Smallest volume ratio J at the rim of a pushed glued patch before the solvers warn."""

GLUED_CONVERGED_RADII = 1.0
"""Push (in patch radii) up to which a glued patch's finite-strain answer is known to converge
under refinement of its rim. The rim, where skin moved rigidly meets free skin, is singular. On the
phantom (10 mm discs, radius 5.3 mm by ``patch_radius``), all four pushed 5 mm (0.94 radii), T1
converges to an independent solve refined at the rims (0.259-0.263 mm); at 10 mm (1.9 radii)
rims of 2.4 / 1.7 / 1.2 mm move T1 by 5 % then 1 % and every level folds rim cells
(docs/verification.md, "The glued phantom's rims"). Past this push an answer has no error bar: a
p-enrichment difference is printed as what it is, not as one. A linear-elastic answer is exempt:
it scales with the push."""


def patch_radius(mesh: MeshData, region: str) -> float:
    """Half the largest distance between two vertices of a facet region (mm): a disc's radius,
    also when a mirror plane cuts the disc in half (the cut is a diameter)."""
    from scipy.spatial import ConvexHull, QhullError
    from scipy.spatial.distance import pdist

    x = mesh.points[mesh.region_vertices(region)]
    if len(x) > 200:   # the farthest pair lies on the hull
        with contextlib.suppress(QhullError):   # a flat region: every vertex stays a candidate
            x = x[ConvexHull(x).vertices]
    return 0.5 * float(pdist(x).max()) if len(x) > 1 else 0.0


PUSHED_KEPT = 8
"""Pushed Cases a Case keeps (``with_pushes``), the oldest forgotten first."""


def with_pushes(case, pushes: dict | None) -> Case:
    """A new Case where each named patch actuator's region is displaced rigidly by
    ``push * direction`` (mm; pushes replace any condition already on that region), each
    patch not named and ``idle = "held"`` is held where it is (at its current ``push``: 0
    on a Case no push was applied to), and each actuator records its position ``push``
    (mm; an indenter gets no condition: the reference solves its contact). One convention
    for every solver, the control Jacobians and the loop; ``with_free_actuators()`` first
    makes the idle patches free."""
    pushes = dict(pushes or {})
    # the same pushes give the same (immutable) Case, validated once: a solve, its outputs
    # and its checks each ask for it
    memo = case.__dict__.setdefault("_pushed", {})
    try:
        key = tuple(sorted((str(n), float(v)) for n, v in pushes.items()))
    except (TypeError, ValueError):
        key = None                       # an unusable push: the checks below name it
    if key is not None and key in memo:
        return memo[key]
    acts = {name: case.actuator(name) for name in pushes}
    held = {a.name: a for a in case.actuators
            if a.type == "patch" and a.name not in pushes and a.idle == "held"}
    if not pushes and not held:
        return case
    patches = {n: a for n, a in acts.items() if a.type == "patch"}
    patches.update(held)
    values = {n: float(pushes[n]) if n in pushes else float(a.push)
              for n, a in patches.items()}
    regions = {a.region for a in patches.values()}
    kept = [b for b in case.boundaries if b.region not in regions]
    added = [Boundary(a.region, "displacement",
                      value=tuple((values[n] * np.asarray(a.direction)).tolist()))
             for n, a in patches.items()]
    actuators = tuple(replace(a, push=float(pushes[a.name])) if a.name in acts else a
                      for a in case.actuators)
    pushed = replace(case, boundaries=tuple(kept + added), actuators=actuators)
    # the same mesh and probes: the probes are located once, on this case, for every pushed
    # one (a control loop or a verification run pushes one case many times)
    pushed.__dict__["probe_locations"] = case.probe_locations
    if key is not None:
        if len(memo) >= PUSHED_KEPT:
            memo.pop(next(iter(memo)))
        memo[key] = pushed
    return pushed


def glued_unconverged(case) -> dict[str, str]:
    """Actuator name -> why, for each glued patch pushed deeper than GLUED_CONVERGED_RADII
    of its radius (``patch_radius``), where no mesh-converged answer is known: decided by
    the pushes alone, so a coarse mesh that hides the rim's singularity is flagged as a fine
    one is. Empty for a linear-elastic material, whose answer scales with the push."""
    if case.material.model == "linear-elastic":
        return {}
    out = {}
    for a in case.actuators:
        if a.type != "patch" or a.push == 0.0:
            continue
        r = patch_radius(case.mesh, a.region)
        if r > 0 and abs(a.push) > GLUED_CONVERGED_RADII * r * (1.0 + 1e-9):
            out[a.name] = (f"glued patch {a.name!r} pushed {a.push:g} mm, {abs(a.push) / r:.2f}"
                           f" of its {r:.2g} mm radius: past {GLUED_CONVERGED_RADII:g} "
                           f"radius no mesh-converged answer is known for a glued patch (its "
                           f"rim is singular; refining the rim folds its cells), so no answer "
                           f"here has an error bar; an indenter actuator (type = "
                           f"\"indenter\", meshes/cases/phantom-indenter.toml) has no "
                           f"singular rim")
    return out


def glued_patch_warnings(case, u, cell_J=None) -> list[str]:
    """One line per pushed patch actuator past the range where its answer converges
    (``glued_unconverged``) or whose cells (those touching its region) fall below
    J = RIM_J_WARN in the displacement ``u`` ((n, gdim) mm); an indenter actuator has no
    singular rim. ``cell_J``: each cell's smallest J of the field itself where it is not the
    P1 interpolant of the vertex values (degree >= 2: a rim cell can fold between its
    vertices; ``fem_reference.field_jacobian``), else J of the straight cells."""
    pushed = [a for a in case.actuators if a.type == "patch" and a.push != 0.0]
    if not pushed:
        return []
    deep = case.glued_unconverged()
    J = cell_jacobians(case.mesh.points, case.mesh.cells, np.asarray(u, float)) \
        if cell_J is None else np.asarray(cell_J, float)
    out = []
    for a in pushed:
        verts = case.mesh.region_vertices(a.region)
        mask = np.isin(case.mesh.cells, verts).any(axis=1)
        jmin = float(np.min(J[mask])) if mask.any() else np.inf
        crushed = (f"its rim cells are compressed to J = {jmin:.3g} (< {RIM_J_WARN})"
                   if jmin < RIM_J_WARN else "")
        if a.name in deep:
            out.append(deep[a.name] + (f"; {crushed}" if crushed else ""))
        elif crushed:
            out.append(f"glued patch {a.name!r} (push {a.push:g} mm): {crushed}: beyond the "
                       f"range in which a glued patch's answer converges under refinement; "
                       f"an indenter actuator (type = \"indenter\") has no singular rim")
    return out


def with_free_actuators(case) -> Case:
    """The same Case with every patch actuator ``idle = "free"``: a patch a solve does not
    push moves with the tissue."""
    return replace(case, actuators=tuple(replace(a, idle="free") if a.type == "patch" else a
                                         for a in case.actuators))


def with_material(case, **changes) -> Case:
    """``case`` with its material's fields changed; a law given by its coefficients (mooney-
    rivlin, yeoh, ogden) takes a new E as every coefficient scaled by the same factor."""
    m = case.material
    if m.model in COEFFICIENT_LAWS and changes.get("model", m.model) == m.model \
            and changes.get("E") is not None:
        m = m.scaled(changes.pop("E") / m.E)
    return replace(case, material=replace(m, **changes))


def law_parameters(model: str) -> tuple[str, ...]:
    """The parameters ``with_law`` takes for ``model``: its coefficients (kPa) for a law given
    by them, else E (kPa) and nu; ``volumetric`` for an uncoupled law; density (kg/mm^3)."""
    names = COEFFICIENT_LAWS.get(model, ("E", "nu"))
    return names + (("volumetric",) if model in UNCOUPLED_LAWS else ()) + ("density",)


def with_law(case, model: str, params: dict | None = None) -> Case:
    """``case`` with its tissue's strain-energy law ``model`` (docs/laws.md), parameters
    ``params`` (names as ``law_parameters``). A law of E and nu keeps the case's E, nu (a law given
    by its coefficients has them too) where ``params`` does not give them; a law given by its
    coefficients needs them all; ``volumetric`` stays the case's between uncoupled laws and
    density stays the case's. Raises CaseError naming a law or parameter that does not fit."""
    params = dict(params or {})
    if model not in MATERIAL_MODELS:
        raise CaseError(f"unknown material law {model!r}; laws: {list(MATERIAL_MODELS)}")
    allowed = law_parameters(model)
    wrong = [n for n in params if n not in allowed]
    if wrong:
        raise CaseError(f"material law {model!r} takes {', '.join(allowed)}; not "
                        f"{', '.join(wrong)}")
    m = case.material
    fields = {"density": m.density}
    if model not in COEFFICIENT_LAWS:
        fields.update(E=m.E, nu=m.nu)
    if model in UNCOUPLED_LAWS and m.model in UNCOUPLED_LAWS:
        fields["volumetric"] = m.volumetric
    fields.update(params)
    return replace(case, material=Material.from_table({"model": model, **fields}))


def with_mesh(case, mesh: MeshData) -> Case:
    return replace(case, mesh=mesh)
