"""A Case on a mirrored mesh (``meshes.mirror``) reduced to the part it was mirrored from, when
everything that loads the body is symmetric about the mirror plane: the same discrete problem on
the part with its plane sliding (u . n = 0), at about half the unknowns per plane.

``reduction(case, pushes)`` decides it from data alone: the mesh's record of its last join
(``MeshData.mirrored``: the plane, its axis and the region renames that pair a region with its
mirror image, e.g. act_px with act_nx) and the Case's loads. The load is symmetric when each
boundary condition has its mirror image among the Case's (the twin region's, with its vectors
mirrored), each actuator its mirror twin (the twin region's, with the same tip, the same push,
its direction and site mirrored; an actuator on a region that kept its name is its own twin, so
its direction and site lie in the plane) and the gravity lies in the plane. A tip that is not
its own twin must stay clear of the plane. Probes are outputs, not loads: one on the far side is
read at its mirror image on the part.

``Reduction`` maps the part's answers back onto the whole mesh: vertex fields (the image of each
part vertex gets the mirrored value), probes, and the sums over a region (reactions, a tip's
force and contact area): a region that is its own twin sums the part's and its mirror image's
(I + M times the part's: twice the in-plane components, the plane-normal component cancels);
a twin's is the mirror image of the part's.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from tissue_reference.meshes.mirror import MirrorPart, mirror_part
from tissue_reference.model.case_model import Case
from tissue_reference.model.case_parts import Boundary
from tissue_reference.model.tips import indenter_site

__all__ = ["Reduction", "reduction"]

RTOL = 1e-9
"""Two lengths agree (a site and its twin's mirror image) within this fraction of the mesh's
extent; directions, pushes and loads within this fraction of their size."""


@dataclass(frozen=True)
class Reduction:
    """A symmetric Case (``whole``, pushes applied) and the Case on its part (``part``, pushes
    applied, its plane sliding): ``split`` is the mesh's ``MirrorPart`` (the part's mesh, the
    join's record, each part vertex's image), ``probe_mirrored`` the probes read at their mirror
    image on the part, ``actuators`` each whole actuator's (part actuator, mirrored) and
    ``regions`` each whole Dirichlet region's (part region, mirrored)."""

    whole: Case
    part: Case
    split: MirrorPart
    probe_mirrored: frozenset
    actuators: dict
    regions: dict

    @property
    def plane(self) -> str:
        return self.split.record.plane

    @property
    def axis(self) -> int:
        return self.split.record.axis

    def flip(self, v) -> np.ndarray:
        """``v`` (..., gdim) mirrored: its component along the plane's normal negated."""
        out = np.array(v, dtype=float, copy=True)
        out[..., self.axis] *= -1.0
        return out

    def vertex_field(self, values, vector: bool = True) -> np.ndarray:
        """A part vertex field (n_part, gdim), or (n_part,) scalars with ``vector`` False, on the
        whole mesh: each image vertex gets its part vertex's value, mirrored for vectors."""
        values = np.asarray(values, float)
        out = np.empty((self.whole.mesh.n_vertices, *values.shape[1:]))
        out[self.split.image] = self.flip(values) if vector else values
        out[:len(values)] = values
        return out

    def nodes(self, node_u, node_points):
        """The part's nodal state (values, points: (k, gdim) each) on the whole mesh: the part's
        nodes, then the mirror images of those off the plane."""
        pts = np.asarray(node_points, float)
        tol = RTOL * float(np.ptp(self.whole.mesh.points, axis=0).max())
        off = np.abs(pts[:, self.axis]) > tol
        return (np.vstack([node_u, self.flip(np.asarray(node_u, float)[off])]),
                np.vstack([pts, self.flip(pts[off])]))

    def probes(self, probes: dict) -> dict:
        """The whole's probes (name -> (gdim,) mm) from the part's."""
        return {p.name: self.flip(probes[p.name]) if p.name in self.probe_mirrored
                else np.asarray(probes[p.name], float)
                for p in self.whole.probes if p.name in probes}

    def summed(self, value, name: str, table: dict):
        """A region's or tip's sum of a vector (reaction, force) from the part's: I + M times it
        for one that is its own twin, its mirror image for a twin of a part's."""
        part, mirrored = table[name]
        v = np.asarray(value, float)
        if mirrored:
            return self.flip(v)
        return v + self.flip(v) if part == name and self._own_twin(name, table) else v

    def _own_twin(self, name: str, table: dict) -> bool:
        if table is self.regions:
            return self.split.record.twin(name) == name
        return self.split.record.twin(self.whole.actuator(name).region) == \
            self.whole.actuator(name).region

    def reactions(self, reactions: dict) -> dict:
        """The whole's reactions (Dirichlet region -> (gdim,) mN) from the part's; the plane's
        own is left out."""
        return {r: self.summed(reactions[p], r, self.regions)
                for r, (p, _) in self.regions.items() if p in reactions}

    def warnings(self, lines) -> tuple:
        """The whole's warnings from the part's: each line about a part actuator again for its
        mirror twin."""
        out = []
        for w in lines:
            out.append(w)
            for name, (part, mirrored) in self.actuators.items():
                if not mirrored:
                    continue
                for said in (f"indenter {part}:", f"{part!r}"):
                    if said in w:
                        out.append(w.replace(said, said.replace(part, name), 1))
                        break
        return tuple(out)

    def indenters(self, indenters: dict) -> dict:
        """The whole's tip reports (``SolveResult.indenters``) from the part's: a tip its own
        twin (cut by the plane) has twice the part's force and contact area, its force vector
        I + M times the part's; a twin's is its part tip's mirrored (force vector, start)."""
        out = {}
        for name, (part, mirrored) in self.actuators.items():
            if part not in indenters:
                continue
            rep = dict(indenters[part])
            if mirrored:
                for k in ("force_vector", "tip_start"):
                    if k in rep:
                        rep[k] = self.flip(rep[k]).tolist()
            elif self._own_twin(name, self.actuators):
                for k in ("force", "contact_area"):
                    if k in rep:
                        rep[k] = 2.0 * float(rep[k])
                if "force_vector" in rep:
                    rep["force_vector"] = self.summed(rep["force_vector"], name,
                                                      self.actuators).tolist()
            out[name] = rep
        return out


def reduction(case: Case, pushes=None) -> Reduction | str:
    """The Reduction of ``case`` under ``pushes`` (actuator name -> mm) to the part its mesh was
    mirrored from, or a line saying why the load is not symmetric (or the mesh not mirrored)."""
    split = mirror_part(case.mesh)
    if split is None:
        return "the mesh is not joined from a symmetric part (meshes.mirror)"
    whole = case.with_pushes(pushes)
    why = _asymmetry(whole, split)
    if why:
        return f"not symmetric about {split.record.plane}: {why}"
    return _reduced(whole, split)


def _close(a, b, scale: float) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= RTOL * scale))


def _size(*vs) -> float:
    return max([1.0, *(float(np.max(np.abs(np.asarray(v, float)), initial=0.0)) for v in vs)])


def _asymmetry(case: Case, split: MirrorPart) -> str | None:
    """Why ``case`` (pushes applied) is not symmetric about the join's plane; None when it is."""
    rec = split.record
    flip = np.ones(case.mesh.gdim)
    flip[rec.axis] = -1.0
    M = np.diag(flip)
    length = float(np.ptp(case.mesh.points, axis=0).max())

    def mirrored_boundary(b: Boundary) -> str | None:
        t = rec.twin(b.region)
        same = [c for c in case.boundaries if c.region == t and c.type == b.type]
        for c in same:
            if b.type == "fixed":
                return None
            if b.type in ("displacement", "traction") and c.components == b.components \
                    and _close(c.value, flip * np.asarray(b.value, float), _size(b.value)):
                return None
            if b.type == "sliding":
                n, v = flip * np.asarray(b.normal, float), float(b.value or 0.0)
                s = _size(b.normal, v)
                if any(_close(c.normal, sign * n, s) and _close(float(c.value or 0.0), sign * v, s)
                       for sign in (1.0, -1.0)):
                    return None
            if b.type == "affine":
                g, o = np.asarray(b.gradient, float), np.asarray(b.offset, float)
                if _close(c.gradient, M @ g @ M, _size(g)) and _close(c.offset, flip * o,
                                                                     _size(o)):
                    return None
        return f"the {b.type} condition on {b.region!r} has no mirror image on {t!r}"

    for b in case.boundaries:
        why = mirrored_boundary(b)
        if why:
            return why
    if case.gravity is not None and not _close(case.gravity, flip * np.asarray(case.gravity),
                                               _size(case.gravity)):
        return f"the gravity {list(case.gravity)} has a component across the plane"
    present = set(split.mesh.facet_regions) | set(split.mesh.point_regions) | \
        set(split.mesh.cell_regions)
    for a in case.actuators:
        t = rec.twin(a.region)
        twins = [a] if t == a.region else [b for b in case.actuators if b.region == t]
        if len(twins) != 1:
            return f"actuator {a.name!r} on {a.region!r} has {len(twins)} twins on {t!r}"
        b = twins[0]
        if b is not a and (a.region in present) == (b.region in present):
            return f"actuators {a.name!r} and {b.name!r} are not one on each side of the plane"
        what = f"actuator {a.name!r} and its mirror twin {b.name!r}"
        if (a.type, a.tip, a.radius, a.edge_radius, a.contact, a.idle) != \
                (b.type, b.tip, b.radius, b.edge_radius, b.contact, b.idle):
            return f"{what} differ (type, tip, radius, contact or idle)"
        if not _close(a.push, b.push, _size(a.push, b.push)):
            return f"{what} are pushed {a.push:g} and {b.push:g} mm"
        if not _close(b.direction, flip * np.asarray(a.direction), 1.0):
            return f"{what} push in directions that are not mirror images"
        if sorted(rec.twin(r) for r in a.contact_regions) != sorted(b.contact_regions):
            return f"{what} touch regions that are not mirror images"
        if a.type == "indenter":
            site = indenter_site(a, case)
            if not _close(indenter_site(b, case), flip * site, length):
                return f"{what} sit at points that are not mirror images"
            if b is not a:
                travel = site + a.push * np.asarray(a.direction)
                clear = min(abs(site[rec.axis]), abs(travel[rec.axis]))
                if clear <= a.radius:
                    return f"tip {a.name!r} comes within its radius of the plane"
    return None


def _reduced(whole: Case, split: MirrorPart) -> Reduction:
    """The Reduction of the symmetric ``whole`` (pushes applied) to ``split``'s part."""
    rec, part_mesh = split.record, split.mesh
    axis = rec.axis
    present = set(part_mesh.facet_regions) | set(part_mesh.point_regions) | \
        set(part_mesh.cell_regions)
    tol = RTOL * float(np.ptp(whole.mesh.points, axis=0).max())
    boundaries = [b for b in whole.boundaries if b.region in present]
    normal = [0.0] * whole.mesh.gdim
    normal[axis] = 1.0
    boundaries.append(Boundary(rec.plane, "sliding", value=0.0, normal=tuple(normal)))
    regions = {}
    for b in whole.boundaries:
        if b.type == "traction" or b.region in regions:
            continue
        t = rec.twin(b.region)
        regions[b.region] = (b.region, False) if b.region in present else (t, True)
    actuators, acts = {}, []
    for a in whole.actuators:
        if a.region in present:
            changes = {"contact_region": tuple(r for r in a.contact_region if r in present)}
            if a.type == "indenter":
                site = indenter_site(a, whole)
                if rec.twin(a.region) == a.region:
                    site[axis] = 0.0   # on the plane (its own twin: symmetric about it)
                changes["point"] = tuple(site.tolist())
            acts.append(dataclasses.replace(a, **changes))
            actuators[a.name] = (a.name, False)
    for a in whole.actuators:
        if a.name not in actuators:
            twin = next(b for b in whole.actuators if b.region == rec.twin(a.region))
            actuators[a.name] = (twin.name, True)
    probes, mirrored = [], set()
    for p in whole.probes:
        x = np.asarray(p.point, float)
        if x[axis] < -tol:
            x[axis] *= -1.0
            mirrored.add(p.name)
        probes.append(dataclasses.replace(p, point=tuple(x.tolist())))
    part = dataclasses.replace(whole, mesh=part_mesh, boundaries=tuple(boundaries),
                               probes=tuple(probes), actuators=tuple(acts),
                               reference_measured=())
    return Reduction(whole, part, split, frozenset(mirrored), actuators, regions)
