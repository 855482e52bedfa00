"""Every built-in solver, the reference among them, as one ``SolverEntry`` with the same face:
``solve`` (a ``model.results.SolveResult``), ``settings`` (what a solve ran with, JSON-ready),
``describe`` (what it computes on a Case as a control plant, model or Jacobian's solver) and,
where it has one, ``simulate`` (implicit-Euler dynamics). ``solver(name)`` looks one up;
``names()`` lists them for the command line's ``--solver`` choices.

Entries load their modules on first use: importing this module imports neither dolfinx nor
PETSc, and ``tissue_reference.fem_reference`` is imported only when the reference itself (or a
fast solver's CHOLMOD factorization hook) is used.
"""
from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass

from tissue_reference.errors import CaseError, NotModeledError

__all__ = ["SolverEntry", "control_names", "dynamics_names", "entries", "is_reference", "names",
           "reference", "solver"]

# keyword arguments of a fast solver's solve() that are inputs or hooks, not settings
_NOT_SETTINGS = {"case", "pushes", "initial", "callback", "progress", "factorize", "dynamics"}


@dataclass(frozen=True)
class SolverEntry:
    """One built-in solver. name: what the command line and the JSON call it; module: the module
    whose ``solve`` it runs (imported on first use); reference: the FEniCSx reference (any degree
    and formulation, Newton settings, error estimates) rather than a P1 displacement fast
    solver; degrees: the Lagrange degrees it solves with; factorized: it takes a ``factorize``
    hook (CHOLMOD through PETSc is given where the caller gives none); control: it plays a
    control loop's plant or model and a Jacobian's solver; dynamics: "module:function" of its
    implicit-Euler dynamics, None without; devices: where it runs (one with more than "cpu"
    takes ``device=``); laws: the strain-energy laws it takes (None: every law;
    ``check_law``); law_refusal: what it solves instead and how to go on, said when it refuses
    a law; summary: one line for help texts."""

    name: str
    module: str
    reference: bool = False
    degrees: tuple = (1,)
    factorized: bool = False
    control: bool = False
    fast_model: bool = False
    dynamics: str | None = None
    devices: tuple = ("cpu",)
    laws: tuple | None = None
    law_refusal: str = ""
    summary: str = ""

    def load(self):
        """The solver's module (ImportError if it cannot be imported)."""
        return importlib.import_module(self.module)

    def require_modeled(self, case, options: dict | None = None) -> None:
        """Raise NotModeledError (a CaseError) when this solver, with ``options`` (its
        ``solve`` keywords), cannot solve ``case``: its module's ``require_modeled`` given the
        options it takes (e.g. the Mass Tensor method's ``method``: its tips need the direct
        solve). A module without one models every case its ``solve`` accepts."""
        check = getattr(self.load(), "require_modeled", None)
        if check is None:
            return
        params = inspect.signature(check).parameters
        check(case, **{k: v for k, v in (options or {}).items() if k in params})

    def forget_kept(self) -> None:
        """Drop what this solver keeps between solves (factorizations of a pattern it saw),
        so that its next solve costs what a first one does; nothing for a solver that keeps
        nothing (its module has no ``forget_factorizations``)."""
        forget = getattr(self.load(), "forget_factorizations", None)
        if forget is not None:
            forget()

    def check_discretization(self, degree: int | None = None, formulation: str = "auto"):
        """Raise CaseError for a degree or formulation this solver does not solve with."""
        if self.reference:
            return
        if degree not in (None, *self.degrees) or formulation == "mixed":
            raise CaseError(f"solver {self.name!r} is a P1 displacement solver: --degree and "
                            f"--formulation mixed apply to the reference (--solver "
                            f"{reference().name})")

    def check_law(self, material):
        """Raise NotModeledError (a CaseError) naming ``material``'s law when this solver does
        not take it (``laws``), with what it solves instead and how to go on."""
        if self.laws is None or material.model in self.laws:
            return
        why = self.law_refusal.format(E=material.E, nu=material.nu)
        raise NotModeledError(f"solver {self.name!r} does not solve the {material.model} law "
                              f"(it takes {' and '.join(self.laws)}): {why}")

    def with_factorization(self, options: dict) -> dict:
        """``options`` with CHOLMOD through PETSc (``fem_reference.cholmod_factor``) as the
        ``factorize`` hook, where this solver takes one and none was given: the fast solvers
        import no PETSc themselves."""
        if not self.factorized or "factorize" in options:
            return options
        # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
        from tissue_reference.fem_reference import cholmod_factor

        return {**options, "factorize": cholmod_factor}

    def solve(self, case, *, degree: int | None = None, formulation: str = "auto", pushes=None,
              initial=None, progress: bool = False, **kw):
        """Solve ``case``; a SolveResult. ``degree`` and ``formulation`` are the reference's;
        a fast solver refuses anything but P1 displacement and gets the factorization hook
        (``with_factorization``).

        Parameters
        ----------
        case : Case
            The problem.
        degree : int or None
            The reference's Lagrange degree; None: the case's default. A fast solver takes 1 or None.
        formulation : str
            The reference's "displacement", "mixed" or "auto"; a fast solver refuses "mixed".
        pushes : dict or None
            Actuator name -> push (mm).
        initial : array_like or SolveResult or None
            Warm start (mm, (n_vertices, gdim)) or an earlier answer.
        progress : bool
            Print the solver's progress.
        **kw
            The solver's own options (its module's ``solve`` keywords).

        Returns
        -------
        SolveResult
            The answer: ``u`` (mm), ``probes`` (mm), ``reactions`` (mN), ``strain_energy`` (uJ).

        Raises
        ------
        CaseError
            When a fast solver is asked for another degree or the mixed formulation.
        """
        if self.reference:
            return self.load().solve(case, degree=degree, formulation=formulation,
                                     pushes=pushes, initial=initial, progress=progress, **kw)
        self.check_discretization(degree, formulation)
        return self.load().solve(case, pushes=pushes, initial=initial, progress=progress,
                                 **self.with_factorization(kw))

    def settings(self, **given) -> dict:
        """The settings a solve ran with, JSON-ready: for the reference its Newton and
        load-stepping controls (``fem_reference.newton_settings.NewtonSettings``, which the
        command line leaves at their defaults), for a fast solver the defaults of its ``solve``
        keywords (null: the solver picks the value itself); ``given`` (what the caller chose)
        goes over them.

        Parameters
        ----------
        **given
            Settings the caller chose, by name.

        Returns
        -------
        dict
            Setting name -> value (JSON-ready).
        """
        if self.reference:
            # lazy: fem_reference is imported only when the reference is used
            from tissue_reference.fem_reference.newton_settings import settings_json

            return {**settings_json(), **given}
        params = inspect.signature(self.load().solve).parameters
        out = {k: p.default for k, p in params.items()
               if p.kind is inspect.Parameter.KEYWORD_ONLY and k not in _NOT_SETTINGS
               and (p.default is None or isinstance(p.default, (bool, int, float, str)))}
        return {**out, **given}

    def describe(self, case, degree: int | None = None, formulation: str = "auto",
                 options: dict | None = None) -> dict:
        """What this solver computes on ``case``, JSON-ready: ``discretization`` (formulation,
        degrees, cells; the reference's default degree resolved as ``fem_reference`` resolves
        it) and ``settings``: the reference's Newton controls (``options`` over them), a fast
        solver's ``options`` (default: its ``settings()``).

        Parameters
        ----------
        case : Case
            The problem.
        degree : int or None
            The reference's Lagrange degree; None: the case's default.
        formulation : str
            The reference's "displacement", "mixed" or "auto".
        options : dict or None
            The settings chosen; None: the defaults.

        Returns
        -------
        dict
            {"solver": name, "discretization": {...}, "settings": {...}}, JSON-ready.
        """
        if self.reference:
            # lazy: fem_reference is imported only when the reference is used
            from tissue_reference.fem_reference.discretization import (
                default_degree,
                resolve_formulation,
            )
            from tissue_reference.fem_reference.newton_settings import settings_json

            form = resolve_formulation(formulation, case.material)
            p = degree if degree is not None else default_degree(case, form)
            disc = {"formulation": form, "degree": p,
                    "pressure_degree": p - 1 if form == "mixed" else None,
                    "cells": case.mesh.n_cells}
            return {"solver": self.name, "discretization": disc,
                    "settings": {**settings_json(), **(options or {})}}
        return {"solver": self.name,
                "discretization": {"formulation": "displacement", "degree": 1,
                                   "pressure_degree": None, "cells": case.mesh.n_cells},
                "settings": dict(options) if options is not None else self.settings()}

    def check_dynamics(self, degree: int | None = None, formulation: str = "auto",
                       mass: str = "lumped", ramp_steps: int = 0):
        """Raise CaseError where ``simulate`` would refuse these options (before any mesh is
        built)."""
        if self.dynamics is None:
            raise CaseError(f"solver {self.name!r} has no dynamics; solvers with dynamics: "
                            f"{list(dynamics_names())}")
        if self.reference:
            return
        if degree not in (None, *self.degrees) or formulation == "mixed" or mass != "lumped" \
                or ramp_steps:
            raise CaseError(f"solver {self.name!r} is P1 with the lumped mass and Dirichlet "
                            f"values in full from the first step: --degree, --formulation "
                            f"mixed, --mass consistent and --ramp-steps apply to --solver "
                            f"{reference().name}")

    def simulate(self, case, *, dt: float, steps: int, pushes=None, degree: int | None = None,
                 formulation: str = "auto", mass: str = "lumped", ramp_steps: int = 0,
                 progress: bool = False):
        """``steps`` implicit-Euler steps of ``dt`` (s) of ``case`` under ``pushes`` (name ->
        mm); a ``model.results.DynamicsResult``. ``degree``, ``formulation``, ``mass`` and
        ``ramp_steps`` are the reference's: a fast solver runs P1 with the lumped mass and the
        Dirichlet values in full from the first step, and refuses anything else.

        Parameters
        ----------
        case : Case
            The problem; density in kg/mm^3.
        dt : float
            Time step (s).
        steps : int
            Number of implicit-Euler steps.
        pushes : dict or None
            Actuator name -> push (mm).
        degree : int or None
            The reference's Lagrange degree; None: the case's default.
        formulation : str
            The reference's "displacement", "mixed" or "auto".
        mass : str
            "lumped" or "consistent" (the reference's).
        ramp_steps : int
            Steps over which the reference ramps the Dirichlet values in; 0: in full from the first.
        progress : bool
            Print a line per step.

        Returns
        -------
        DynamicsResult
            The trajectory: displacements (mm) and probes (mm) at each time (s).

        Raises
        ------
        CaseError
            For a solver without dynamics or options it refuses (``check_dynamics``).
        """
        self.check_dynamics(degree, formulation, mass, ramp_steps)
        modname, func = self.dynamics.split(":")
        run = getattr(importlib.import_module(modname), func)
        if self.reference:
            return run(case, dt=dt, steps=steps, pushes=pushes, degree=degree,
                       formulation=formulation, mass=mass, ramp_steps=ramp_steps,
                       progress=progress)
        return run(case.with_pushes(pushes), dt=dt, steps=steps, progress=progress,
                   **self.with_factorization({}))


_ENTRIES = (
    SolverEntry("fem", "tissue_reference.fem_reference", reference=True, degrees=(1, 2, 3),
                control=True, dynamics="tissue_reference.fem_reference.dynamics:simulate",
                summary="the reference"),
    SolverEntry("admm", "tissue_reference.solvers.admm", factorized=True, control=True,
                fast_model=True,
                dynamics="tissue_reference.solvers.trajectory:admm_trajectory",
                devices=("cpu", "gpu"),
                summary="ADMM, the fast solver (P1)"),
    # a linear model: linear elasticity exactly; Neo-Hookean (seed 001's use of it as a fast
    # approximation of tissue) solved as linear elasticity of the same E and nu, and said so
    # in the answer's model_note; every other law refused by name
    SolverEntry("mass-tensor", "tissue_reference.solvers.mass_tensor", factorized=True,
                laws=("linear-elastic", "neo-hookean"),
                law_refusal=("the Mass Tensor method is linear elasticity with the case's E and "
                             "nu (E = {E:.6g} kPa, nu = {nu:.6g}), which does not represent that "
                             "law; solve the linear model with --material linear-elastic "
                             "(case.with_law(\"linear-elastic\")), or the law with "
                             "another solver: --solver admm or fem solve every law"),
                summary="the Mass Tensor Method (P1)"),
)
_BY_NAME = {e.name: e for e in _ENTRIES}


def entries() -> tuple:
    """Every built-in solver, the reference first.

    Returns
    -------
    tuple of SolverEntry
        The reference's entry, then the fast solvers'.
    """
    return _ENTRIES


def names() -> tuple:
    """The built-in solvers' names, the reference first.

    Returns
    -------
    tuple of str
        The names, e.g. ("fem", "admm", "mass-tensor").
    """
    return tuple(_BY_NAME)


def control_names() -> tuple:
    """The solvers that play a control plant or model and a Jacobian's solver.

    Returns
    -------
    tuple of str
        Their names.
    """
    return tuple(e.name for e in _ENTRIES if e.control)


def dynamics_names() -> tuple:
    """The solvers with implicit-Euler dynamics.

    Returns
    -------
    tuple of str
        Their names.
    """
    return tuple(e.name for e in _ENTRIES if e.dynamics is not None)


def solver(name: str) -> SolverEntry:
    """The built-in solver ``name``; CaseError naming the known ones for another name.

    Parameters
    ----------
    name : str
        A built-in solver's name (``names()``).

    Returns
    -------
    SolverEntry
        Its entry.

    Raises
    ------
    CaseError
        For a name that is no built-in solver's.
    """
    try:
        return _BY_NAME[name]
    except (KeyError, TypeError):
        raise CaseError(f"unknown solver {name!r}; solvers: {list(_BY_NAME)}") from None


def reference() -> SolverEntry:
    """The reference's entry.

    Returns
    -------
    SolverEntry
        The reference's.
    """
    return next(e for e in _ENTRIES if e.reference)


def is_reference(name) -> bool:
    """Whether ``name`` (a solver's name as the JSON writes it, or anything else: a plugin, a
    callable) names the reference.

    Parameters
    ----------
    name : object
        A solver's name, a plugin's, a callable or anything else.

    Returns
    -------
    bool
        True only for the reference's name.
    """
    entry = _BY_NAME.get(name) if isinstance(name, str) else None
    return entry is not None and entry.reference
