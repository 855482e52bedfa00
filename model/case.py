"""The Case: one problem description (mesh + material + boundary conditions + probes + actuators)
consumed by every solver of the project, reference and fast alike, and ``load_case``, its reader.

Units: length mm, stress kPa (= mN/mm^2), force mN, density kg/mm^3, gravity mm/s^2.

A Case is built once (``load_case`` from a TOML file, or ``Case(...)`` from Python) and validated
then: unknown regions, bad material values, conflicting prescriptions on one vertex and rigid-body
freedom are all reported here, before any solver starts.

This module is where users take both from. The class is ``model.case_model`` (its validation and
vertex constraints ``model.case_constraints``, the Cases derived from it (``with_pushes``,
``with_mesh``, ...) ``model.case_variants``, its parts (Material, Boundary, Probe, Actuator)
``model.case_parts``); the TOML reader is ``model.case_file``, which builds on the class.
"""
from __future__ import annotations

from .case_file import load_case
from .case_model import (
    ACTUATOR_TYPES,
    BOUNDARY_TYPES,
    COEFFICIENT_LAWS,
    CONTACT_RULES,
    CONTACT_TYPES,
    E_RANGE_KPA,
    MATERIAL_MODELS,
    RIM_J_WARN,
    TIP_SHAPES,
    TIP_STARTS,
    UNCOUPLED_LAWS,
    Actuator,
    Boundary,
    Case,
    Material,
    Probe,
    ProbeLocation,
    VertexConstraints,
    is_contact_rule,
    tip_start_for,
)

__all__ = [
    "ACTUATOR_TYPES",
    "BOUNDARY_TYPES",
    "COEFFICIENT_LAWS",
    "CONTACT_RULES",
    "CONTACT_TYPES",
    "E_RANGE_KPA",
    "MATERIAL_MODELS",
    "RIM_J_WARN",
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
    "is_contact_rule",
    "load_case",
    "tip_start_for",
]
