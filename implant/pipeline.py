"""Seed 001 end to end: skin + three thickness estimates -> muscle (RBF) -> tissue volume (gmsh)
-> implant from the library placed on the muscle -> two-step boundary conditions -> Mass Tensor
solve -> predicted skin. Lengths mm, stiffness kPa, volume cc, time s.

    patient = synthetic_patient()                       # or patient_from_file("skin.stl", 15, 20, 15)
    plan = plan_implant(patient, PlanSettings(volume_cc=245, shape="round", side="left"))
    plan.predicted_points                               # tissue vertices after the implant (mm)

Material (seed 001): homogeneous linear elastic tissue, E = 48 kPa; the seed's Poisson ratio is
not legible, 0.45 is used. With displacement-only boundary conditions E does not change the
displacements. The implant (step 1) is linear elastic too (its E is likewise irrelevant).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from tissue_reference.errors import CaseError
from tissue_reference.meshes.mesh import MeshData
from tissue_reference.model.case import Material
from tissue_reference.solvers import mass_tensor as mt

from .library import ImplantSpec, implant_mesh
from .placement import (
    ImplantBC,
    Placement,
    TissueBC,
    implant_ground_targets,
    place_implant,
    tissue_boundary_conditions,
)
from .rbf import MuscleFit, Thickness, muscle_surface
from .surface import TriSurface, check_single_sheet, read_surface, triangle_normals
from .torso import SyntheticTorso, tissue_mesh

__all__ = [
    "ImplantPlan",
    "Patient",
    "PlanSettings",
    "build_tissue",
    "decimate",
    "patient_from_file",
    "plan_implant",
    "synthetic_patient",
]


@dataclass(frozen=True)
class Patient:
    """A skin sheet (mm), the three thickness estimates, and the truth when synthetic."""

    skin: TriSurface
    thickness: Thickness
    truth: SyntheticTorso | None = None
    source: str = "synthetic"


def synthetic_patient(torso: SyntheticTorso | None = None) -> Patient:
    torso = torso or SyntheticTorso()
    return Patient(torso.skin(), torso.thickness_estimates(), torso, "synthetic")


def decimate(skin: TriSurface, target_triangles: int) -> TriSurface:
    """Quadric decimation (pyvista/VTK) to about ``target_triangles`` triangles."""
    if len(skin.triangles) <= target_triangles:
        return skin
    import pyvista as pv

    faces = np.column_stack([np.full(len(skin.triangles), 3), skin.triangles]).ravel()
    poly = pv.PolyData(skin.points, faces)
    out = poly.decimate(1.0 - target_triangles / len(skin.triangles))
    tri = out.faces.reshape(-1, 4)[:, 1:]
    return TriSurface(np.asarray(out.points, float), tri).compact()


def patient_from_file(path, A: float, B: float, C: float, *, x_planes=None,
                      target_triangles: int = 1200) -> Patient:
    """A user skin surface (STL, PLY, OBJ, VTK; mm, body frame: x patient's left, y up, z
    anterior) with thickness estimates A (right lateral), B (sternum), C (left lateral) in mm.

    x_planes: (x_A, x_B, x_C) mm of the estimate planes; default: the middle of the skin's x
    range for B and +-35% of the x range for A and C. Surfaces with more than
    ``target_triangles`` triangles are decimated (a ~3.5k tetrahedra model needs ~1.2k).
    Raises ReadError / CaseError (not one connected sheet, bad thickness) before any solve.
    """
    skin = check_single_sheet(read_surface(path), source=f"skin surface {str(path)!r}")
    skin = check_single_sheet(decimate(skin, target_triangles),
                              source=f"decimated skin surface {str(path)!r}")
    x = skin.points[:, 0]
    if x_planes is None:
        mid, span = 0.5 * (x.min() + x.max()), np.ptp(x)
        x_planes = (mid - 0.35 * span, mid, mid + 0.35 * span)
    th = Thickness(A, B, C, *map(float, x_planes))
    # orient the sheet so that its normals point anterior (+z) on average

    if triangle_normals(skin.points, skin.triangles)[:, 2].mean() < 0:
        skin = TriSurface(skin.points, skin.triangles[:, ::-1])
    return Patient(skin, th, None, str(path))


@dataclass(frozen=True)
class PlanSettings:
    """shape 'round' | 'anatomical'; volume_cc (cc); side 'left' | 'right'; at: (x, y) mm or
    None (under the thickest tissue); width / projection (mm, optional); free_ring (mm, 0 or
    None for none; seed: 30); sliding: switch targets to sliding on the implant after reaching
    them; E (kPa), nu; stop_mm: Mass Tensor stopping rule (seed: 0.01 mm); method 'direct' |
    'amg' | 'pcg' | 'descent' (``solvers.mass_tensor.METHODS``); tissue_size: tetrahedron edge (mm,
    default the skin's mean edge)."""

    shape: str = "round"
    volume_cc: float = 245.0
    side: str = "left"
    at: tuple | None = None
    width: float | None = None
    projection: float | None = None
    free_ring: float | None = 30.0
    sliding: bool = False
    E: float = 48.0
    nu: float = 0.45
    stop_mm: float = 0.01
    method: str = "direct"
    tissue_size: float | None = None

    def __post_init__(self):
        Material("linear-elastic", self.E, self.nu)  # validates E, nu
        if not (isinstance(self.stop_mm, (int, float)) and self.stop_mm > 0):
            raise CaseError(f"stop_mm must be > 0 mm, got {self.stop_mm!r}")

    @property
    def spec(self) -> ImplantSpec:
        return ImplantSpec(self.shape, self.volume_cc, self.width, self.projection)

    @property
    def material(self) -> Material:
        return Material("linear-elastic", self.E, self.nu)


@dataclass(frozen=True)
class ImplantPlan:
    """Everything a plan produced. u: (n, 3) tissue displacement (mm) by the Mass Tensor Method;
    implant_points: the deformed implant (mm); iterations: Mass Tensor iterations (step 2);
    wall_time_s: the whole pipeline; timings: per stage (s)."""

    patient: Patient
    settings: PlanSettings
    fit: MuscleFit
    tissue: MeshData
    placement: Placement
    implant: ImplantBC
    implant_points: np.ndarray
    bc: TissueBC
    u: np.ndarray
    iterations: int
    implant_iterations: int
    converged: bool
    wall_time_s: float
    timings: dict = field(default_factory=dict)

    @property
    def predicted_points(self) -> np.ndarray:
        return self.tissue.points + self.u

    @property
    def skin_triangles(self) -> np.ndarray:
        return self.tissue.facet_regions["skin"]

    def breast_region(self, extra: float = 30.0) -> np.ndarray:
        """Skin vertex ids within (half the base width + ``extra`` mm) of the implant axis: the
        breast surface over which d_max and the mean distance are reported."""
        sv = self.tissue.region_vertices("skin")
        d = self.tissue.points[sv] - self.placement.centre
        ax = self.placement.axis
        radial = np.linalg.norm(d - np.outer(d @ ax, ax), axis=1)
        w = self.settings.spec.dimensions()[0]
        return sv[radial <= 0.5 * w + extra]

    def muscle_thickness_error_mm(self) -> float | None:
        """Synthetic only: largest |distance| (mm) of the RBF muscle to the true muscle over the
        interface points under the implant (the implant region)."""
        if self.patient.truth is None:
            return None
        return float(np.abs(self.patient.truth.muscle_distance(
            self.tissue.points[self.bc.target])).max())

    def dirichlet(self) -> tuple[np.ndarray, np.ndarray]:
        """Node-major (dof = 3 i + c) prescribed dofs and values (mm) of step 2: targets and
        border points (for a reference solve with the same boundary conditions)."""
        ids = np.concatenate([self.bc.target, self.bc.border])
        vals = np.vstack([self.bc.target_displacements, np.zeros((len(self.bc.border), 3))])
        dofs = (3 * ids[:, None] + np.arange(3)).ravel()
        return dofs, vals.ravel()


def build_tissue(patient: Patient, *, size: float | None = None) -> tuple[MuscleFit, MeshData]:
    """Muscle estimate (RBF) and the gmsh tetrahedral tissue volume."""
    fit = muscle_surface(patient.skin, patient.thickness)
    return fit, tissue_mesh(patient.skin, fit.muscle, size=size)


def plan_implant(patient: Patient, settings: PlanSettings = PlanSettings()) -> ImplantPlan:
    """Run seed 001's pipeline (see module docstring); every fit / input check happens before
    the first solve. Raises CaseError on bad input, SolverDivergedError if a solve diverges."""
    t0 = time.perf_counter()
    tm = {}
    spec = settings.spec
    fit, tissue = build_tissue(patient, size=settings.tissue_size)
    tm["model"] = time.perf_counter() - t0
    placement = place_implant(tissue, spec, side=settings.side, at=settings.at,
                              mid_x=patient.thickness.x_B)
    imesh = implant_mesh(spec)
    ibc = implant_ground_targets(imesh, placement, tissue)
    tm["implant"] = time.perf_counter() - t0 - tm["model"]
    # step 1: implant ground plane onto the muscle
    t1 = time.perf_counter()
    im = mt.MassTensorModel(ibc.points, ibc.cells, material=settings.material)
    it = im.point_types()
    it.target(ibc.base, ibc.targets)
    isol = im.solve(it, method=settings.method, stop_mm=settings.stop_mm)
    ipts = ibc.points + isol.u
    tm["step1"] = time.perf_counter() - t1
    # step 2: tissue interface onto the implant's upper surface
    t2 = time.perf_counter()
    bc = tissue_boundary_conditions(tissue, ipts, ibc.shell, placement,
                                    free_ring=settings.free_ring)
    model = mt.MassTensorModel(tissue.points, tissue.cells, material=settings.material)
    types = model.point_types()
    types.border(bc.border)
    then = mt.TriSurface(ipts, ibc.shell) if settings.sliding else None
    types.target(bc.target, bc.target_positions, then_slide=then)
    sol = model.solve(types, method=settings.method, stop_mm=settings.stop_mm)
    tm["step2"] = time.perf_counter() - t2
    wall = time.perf_counter() - t0
    return ImplantPlan(patient, settings, fit, tissue, placement, ibc, ipts, bc, sol.u,
                       int(sol.iterations), int(isol.iterations),
                       bool(sol.converged and isol.converged), wall, tm)


