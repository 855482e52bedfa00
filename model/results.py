"""The result every solver returns, and its JSON form (the same keys for every solver)."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tissue_reference.meshes.io import atomic_path

from .case_parts import UNCOUPLED_LAWS

__all__ = ["DynamicsResult", "SolveResult", "json_ready", "material_json", "write_json"]


def material_json(material) -> dict:
    """A Material as the JSON outputs write it (E in kPa, density in kg/mm^3)."""
    out = {"model": material.model, "E_kPa": float(material.E), "nu": float(material.nu),
           "density_kg_mm3": float(material.density)}
    if material.model in UNCOUPLED_LAWS:
        out["volumetric"] = material.volumetric
    if material.coefficients:
        out["coefficients_kPa"] = material.coefficients
    if material.model == "ogden":
        out["alpha"] = list(material.ogden_alpha)
    return out


@dataclass(frozen=True)
class SolveResult:
    """A solve of a Case.

    u: (n_vertices, gdim) displacement at the Case mesh's vertices, in its own numbering (mm).
    probes: probe name -> (gdim,) displacement (mm).  reactions: Dirichlet region -> (gdim,) force
    the support exerts on the body (mN).  strain_energy in uJ (= kPa mm^3 = mN mm).
    iterations: Newton iterations (fem) or the fast solver's own iterations.

    What every caller reads is a field, set by the solver that computed it; the solver's own
    figures (timings, counters) are ``extra``, which the JSON form writes beside the fields:
    valid: whether the deformed mesh is a physical answer (no inverted cell, no runaway, no tip
        through the skin); None when the solver checked nothing.  invalid_reason: why not (None
        when valid).  warnings: what the caller should know about the answer (a glued patch
        past its range, a load with no converged value, ...).  discretization: the reference's
        discretization (degree, unknowns, formulation, contact rule, ...), None for another
        solver.  indenters: per rigid tip its push, force, contact area and penetration
        (``fem_reference.contact``); {} without tips.  probe_error_estimates (mm) and
        reaction_error_estimates (mN): the norm of the estimated discretization error per
        probe / Dirichlet region ({} when not estimated); estimate_note: why an answer has no
        estimate (None when it has one or none was asked for).  reference: whether the
        reference (``fem_reference``) computed it; its JSON form says so by ``solver`` and by
        ``newton_iterations`` (the iterations of a reference answer, else 0).
    no_converged_value: why no mesh-converged answer is known at this load (a glued patch or an
        indenter past the loads where answers converge under refinement: an estimate is then no
        error bar); () when none is in the way.
    min_J: the smallest J = det F of the final state (dimensionless; ``deformation_state``),
        written with the validity; None when not finite or not checked.
    model: the material model the solver solved when it is not the case's (a fast solver's
        linear elasticity), else None; model_note: that difference in words (None without one).
    symmetry: on a mesh joined from a symmetric part and its mirror images, which mesh the
        reference solved (``fem_reference.symmetric``): {"solved_on": "part", "planes",
        "part_dofs", "part_cells"} or {"solved_on": "whole", "why"}; None on another mesh.
    node_u: (n_nodes, gdim) displacement (mm) at every node of a degree >= 2 reference answer,
        in the order of node_points ((n_nodes, gdim), mm); None at degree 1 and under MPI (the
        warm start and the tangent of a later solve use them).  pressure: the mixed
        formulation's pressure (kPa) at the Case vertices (a P1 Function in a state lifted to
        a richer degree); None for the displacement formulation.  The JSON form leaves these
        three out.

    Attributes
    ----------
    u : ndarray
        (n_vertices, gdim) displacement (mm) at the Case mesh's vertices.
    converged : bool
        Whether the solver met its stopping rule.
    iterations : int
        Newton iterations (fem) or the fast solver's own.
    residual : float
        The final residual (mN for the reference; the solver's own measure otherwise).
    wall_time_s : float
        Wall-clock time of the solve (s).
    solver : str
        Which solver computed it ("fem", "admm", "mass-tensor", a plugin's name).
    probes : dict
        Probe name -> (gdim,) displacement (mm).
    reactions : dict
        Dirichlet region -> (gdim,) force the support exerts on the body (mN).
    strain_energy : float
        uJ (= kPa mm^3 = mN mm).
    load_steps : int
        Load steps taken.
    degree : int
        Lagrange degree of the displacement.
    case_name : str
        The Case's name.
    n_vertices, n_cells : int
        Size of the Case mesh.
    history : dict
        Per-iteration records of the solver (e.g. residuals, ``admm_clock_s`` in s).
    extra : dict
        The solver's own figures (timings in s, counters, ``measured_accuracy``).
    valid : bool or None
        Whether the deformed mesh is a physical answer; None: not checked.
    invalid_reason : str or None
        Why not.
    warnings : tuple of str
        What the caller should know about the answer.
    discretization : dict or None
        The reference's discretization; None for another solver.
    indenters : dict
        Per rigid tip its push (mm), force (mN), contact area (mm^2) and penetration (mm).
    probe_error_estimates : dict
        Probe name -> estimated discretization error (mm); {} when not estimated.
    reaction_error_estimates : dict
        Dirichlet region -> estimated discretization error (mN); {} when not estimated.
    estimate_note : str or None
        Why an answer has no estimate.
    reference : bool
        Whether the reference computed it.
    no_converged_value : tuple of str
        Why no mesh-converged answer is known at this load; () when none is in the way.
    min_J : float or None
        Smallest J = det F of the final state (dimensionless).
    model : str or None
        The material model solved when it is not the case's, else None.
    model_note : str or None
        The model difference in words.
    symmetry : dict or None
        On a mesh joined from a symmetric part and its mirror images: which mesh the reference
        solved (the part, its planes and unknowns, or the whole mesh and why); None elsewhere.
    node_u : ndarray or None
        (n_nodes, gdim) displacement (mm) at every node of a degree >= 2 reference answer.
    node_points : ndarray or None
        (n_nodes, gdim) reference coordinates (mm) of those nodes.
    pressure : object
        The mixed formulation's pressure (kPa) at the Case vertices; None for displacement.
    """

    u: np.ndarray
    converged: bool
    iterations: int
    residual: float
    wall_time_s: float
    solver: str
    probes: dict = field(default_factory=dict)
    reactions: dict = field(default_factory=dict)
    strain_energy: float = float("nan")
    load_steps: int = 1
    degree: int = 1
    case_name: str = "case"
    n_vertices: int = 0
    n_cells: int = 0
    history: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    valid: bool | None = None
    invalid_reason: str | None = None
    warnings: tuple = ()
    discretization: dict | None = None
    indenters: dict = field(default_factory=dict)
    probe_error_estimates: dict = field(default_factory=dict)
    reaction_error_estimates: dict = field(default_factory=dict)
    estimate_note: str | None = None
    reference: bool = False
    no_converged_value: tuple = ()
    min_J: float | None = None
    model: str | None = None
    model_note: str | None = None
    symmetry: dict | None = None
    node_u: np.ndarray | None = None
    node_points: np.ndarray | None = None
    pressure: object = None

    def __post_init__(self):
        if self.valid is not None:
            object.__setattr__(self, "valid", bool(self.valid))
        object.__setattr__(self, "warnings", tuple(str(w) for w in self.warnings or ()))
        why = self.no_converged_value
        object.__setattr__(self, "no_converged_value",
                           (why,) if isinstance(why, str) else tuple(str(w) for w in why or ()))
        for k in ("indenters", "probe_error_estimates", "reaction_error_estimates"):
            object.__setattr__(self, k, dict(getattr(self, k) or {}))

    @property
    def dimension(self) -> int:
        return int(self.u.shape[1])

    def entries(self) -> dict:
        """``extra`` and the typed fields together, keyed as the JSON form keys them."""
        state = {k: getattr(self, k) for k in ("node_u", "node_points", "pressure")}
        return {**self.extra, **self.typed_json(),
                **{k: v for k, v in state.items() if v is not None}}

    def typed_json(self) -> dict:
        """The typed fields as the JSON form writes them: validity (and min_J) where checked,
        the warnings always, the rest where the solver gave them; not the nodal state."""
        d = {}
        if self.valid is not None:
            d.update(min_J=self.min_J, valid=self.valid, invalid_reason=self.invalid_reason)
        if self.discretization is not None:
            d["discretization"] = self.discretization
        if self.indenters:
            d["indenters"] = self.indenters
        d["warnings"] = list(self.warnings)
        if self.probe_error_estimates:
            d["probe_error_estimates"] = self.probe_error_estimates
        if self.reaction_error_estimates:
            d["reaction_error_estimates"] = self.reaction_error_estimates
        if self.estimate_note is not None:
            d["estimate_note"] = self.estimate_note
        if self.no_converged_value:
            d["no_converged_value"] = list(self.no_converged_value)
        if self.model is not None:
            d["model"] = self.model
        if self.model_note is not None:
            d["model_note"] = self.model_note
        if self.symmetry is not None:
            d["symmetry"] = self.symmetry
        return d

    def to_json_dict(self, case=None) -> dict:
        pts = {}
        if case is not None:
            pts = {p.name: list(map(float, p.point)) for p in case.probes}
        d = {
            "case": self.case_name, "solver": self.solver, "degree": self.degree,
            "dimension": self.dimension, "n_vertices": self.n_vertices, "n_cells": self.n_cells,
            "converged": bool(self.converged), "load_steps": int(self.load_steps),
            "newton_iterations": int(self.iterations) if self.reference else 0,
            "iterations": int(self.iterations),
            "wall_time_s": float(self.wall_time_s),
            "probes": {k: {"point": pts.get(k), "displacement": np.asarray(v, float).tolist()}
                       for k, v in self.probes.items()},
            # reference answers with an error estimate (fem_reference.estimate): per probe the
            # norm of the estimated error vector (mm)
            "reactions": {k: np.asarray(v, float).tolist() for k, v in self.reactions.items()},
            "strain_energy": float(self.strain_energy),
        }
        if case is not None:   # what was solved: the material and every actuator's position
            d["material"] = material_json(case.material)
            d["pushes_mm"] = {a.name: float(a.push) for a in case.actuators}
            d["actuators"] = {a.name: {"type": a.type, "idle": a.idle} for a in case.actuators}
        d.update({k: v for k, v in self.extra.items() if _jsonable(v)})
        d.update({k: v for k, v in self.typed_json().items() if _jsonable(v)})
        est = self.probe_error_estimates
        for k, e in est.items():
            if k in d["probes"]:
                d["probes"][k]["error_estimate"] = float(e)
        return d


@dataclass(frozen=True)
class DynamicsResult:
    """A trajectory of implicit-Euler steps; index 0 is the start state (t = 0).

    times: (steps + 1,) s.  u, velocity: (steps + 1, n_vertices, gdim) displacement (mm) and
    velocity (mm/s) at the Case's vertices, in its numbering.  probes: name -> (steps + 1, gdim)
    mm.  kinetic_energy = v^T M v / 2 and strain_energy = W(u): (steps + 1,) uJ.  converged,
    iterations: (steps,) per time step (Newton iterations of the reference; the solver's own
    iterations for another solver).  final: the SolveResult of the last step (reactions,
    validity, discretization).  total_mass_kg: the body's mass (kg).
    """

    times: np.ndarray
    u: np.ndarray
    velocity: np.ndarray
    probes: dict
    kinetic_energy: np.ndarray
    strain_energy: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    wall_time_s: float
    dt: float
    mass: str
    degree: int
    total_mass_kg: float
    final: SolveResult | None = None
    case_name: str = "case"
    solver: str = "fem"
    extra: dict = field(default_factory=dict)

    @property
    def steps(self) -> int:
        return len(self.times) - 1

    def to_json_dict(self) -> dict:
        """The trajectory as JSON-ready data (the vertex fields are left out: see ``u``)."""
        d = {"case": self.case_name, "solver": self.solver, "dt_s": float(self.dt),
             "steps": self.steps, "mass": self.mass, "degree": int(self.degree),
             "total_mass_kg": float(self.total_mass_kg),
             "converged": bool(np.all(self.converged)),
             "wall_time_s": float(self.wall_time_s),
             "times_s": np.asarray(self.times, float).tolist(),
             "step_converged": np.asarray(self.converged, bool).tolist(),
             "iterations": np.asarray(self.iterations, int).tolist(),
             "kinetic_energy_uJ": np.asarray(self.kinetic_energy, float).tolist(),
             "strain_energy_uJ": np.asarray(self.strain_energy, float).tolist(),
             "max_displacement_mm": np.sqrt((self.u ** 2).sum(axis=2).max(axis=1)).tolist(),
             "probes": {k: np.asarray(v, float).tolist() for k, v in self.probes.items()}}
        if self.final is not None:
            d["final"] = self.final.to_json_dict()
        return d


def _jsonable(v) -> bool:
    try:
        json.dumps(v)
        return True
    except TypeError:
        return False


def json_ready(data):
    """``data`` as ``write_json`` writes it and ``json.load`` reads it back (NumPy arrays and
    scalars as lists and numbers, paths as strings): what a file written earlier is compared
    with."""
    return json.loads(json.dumps(data, default=_default))


def write_json(data: dict, path) -> Path:
    """Write JSON whole or not at all (temporary file + rename)."""
    path = Path(path)
    text = json.dumps(data, indent=2, default=_default)
    with atomic_path(path) as tmp:
        tmp.write_text(text + "\n")
    return path


def _default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")
