"""Cases derived from a Case, mixed into ``meshes.case.Case``.

Units: pushes and displacements mm; J (volume ratio) dimensionless.

``with_pushes`` applies actuator pushes (patches displaced rigidly, idle held patches held),
``with_free_actuators`` lets the idle patches move with the tissue, ``with_material`` and
``with_mesh`` swap one part; ``glued_patch_warnings`` flags a pushed glued patch whose rim cells
are compressed below ``RIM_J_WARN``.
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from .case_parts import Boundary
from .mesh import MeshData, cell_jacobians

if TYPE_CHECKING:
    from .case import Case

__all__ = ["RIM_J_WARN", "CaseVariantsMixin"]

RIM_J_WARN = 0.2
"""Smallest volume ratio J at the rim of a pushed glued patch before the solvers warn."""


class CaseVariantsMixin:
    """The Cases derived from a Case (its actuators pushed or freed, another material or mesh)
    and the glued-patch warning."""

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

    def with_material(self, **changes) -> Case:
        return replace(self, material=replace(self.material, **changes))

    def with_mesh(self, mesh: MeshData) -> Case:
        return replace(self, mesh=mesh)
