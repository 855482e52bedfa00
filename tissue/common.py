"""Helpers shared by the command modules: validated option values, push parsing, output checks,
case loading, solver dispatch, and the validity of an answer.

Every numeric option is parsed by one of the argparse types here (``real``, ``integer``): a value
that is not a finite number, or not in its range, stops the command before any work with one
line naming the option and the value (exit status 2). Output paths are checked before any
meshing or solving (``check_outputs``). Units: lengths mm.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from tissue_reference.errors import CaseError
from tissue_reference.meshes import mesh_cache
from tissue_reference.meshes.builders import MAX_CELLS, estimate_cells
from tissue_reference.meshes.io import check_output_dir, check_output_file
from tissue_reference.meshes.mesh import RUNAWAY_FACTOR
from tissue_reference.model.answer_warnings import advice_for
from tissue_reference.model.case import (
    CONTACT_RULES,
    TIP_STARTS,
    Case,
    is_contact_rule,
    load_case,
)
from tissue_reference.model.case_file import case_path
from tissue_reference.solvers.registry import names, solver

__all__ = ["PROGRESS_FROM_CELLS", "SOLVER_NAMES", "add_case_args", "add_discretization_args",
           "body_diameter", "case_from_args", "check_outputs", "check_prescribed",
           "check_pushes", "integer", "material_spec",
           "parse_pushes", "real", "report_validity", "run_solver"]

SOLVER_NAMES = names()
PROGRESS_FROM_CELLS = 100_000
"""A builtin mesh estimated at more cells than this announces the estimate before gmsh starts."""
ANNOUNCE_LOAD_S = 1.0
"""A case whose builtin mesh gmsh meshed (not read from the cache) in longer than this (s) says
so on the command line."""


# --------------------------------------------------------------------------- option values
def _number_text(text: str) -> str:
    return repr(text) if isinstance(text, str) else repr(str(text))


def real(kind: str = "finite", unit: str = "", *, at_least: float | None = None,
         at_most: float | None = None, magnitude: float | None = None):
    """argparse type: a finite float, ``kind`` "finite", "positive" (> 0) or "nonneg" (>= 0);
    optionally >= ``at_least``, <= ``at_most``, |v| <= ``magnitude``. ``unit`` is named in the
    message."""
    lo = {"finite": None, "positive": 0.0, "nonneg": 0.0}[kind]
    strict = kind == "positive"
    if at_least is not None:
        lo, strict = at_least, False
    if magnitude is not None:
        want = f"a finite number between {-magnitude:g} and {magnitude:g}"
        lo, strict, at_most = -magnitude, False, magnitude
    else:
        want = "a finite number" + (f" {'>' if strict else '>='} {lo:g}" if lo is not None
                                    else "") + (f" and <= {at_most:g}" if at_most is not None
                                                else "")
    want += f" ({unit})" if unit else ""

    def parse(text):
        try:
            v = float(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"expected {want}, found {_number_text(text)}") \
                from None
        ok = math.isfinite(v) and (lo is None or (v > lo if strict else v >= lo)) and \
            (at_most is None or v <= at_most)
        if not ok:
            raise argparse.ArgumentTypeError(f"expected {want}, found {_number_text(text)}")
        return v

    parse.__name__ = "number"
    return parse


def integer(minimum: int | None = None, maximum: int | None = None, why: str = ""):
    """argparse type: an integer in [minimum, maximum] (either may be None); "2e6" reads as
    2000000. ``why`` is added to the message."""
    want = "an integer" + (f" >= {minimum}" if minimum is not None else "") + \
        (f" and <= {maximum}" if maximum is not None else "") + (f" ({why})" if why else "")

    def parse(text):
        try:
            v = int(text)
        except (TypeError, ValueError):
            try:
                f = float(text)
            except (TypeError, ValueError):
                f = math.nan
            if not (math.isfinite(f) and f == int(f)):
                raise argparse.ArgumentTypeError(f"expected {want}, found {_number_text(text)}") \
                    from None
            v = int(f)
        if (minimum is not None and v < minimum) or (maximum is not None and v > maximum):
            raise argparse.ArgumentTypeError(f"expected {want}, found {_number_text(text)}")
        return v

    parse.__name__ = "integer"
    return parse


# --------------------------------------------------------------------------- pushes
def parse_pushes(items, option: str = "--push") -> dict:
    """["A1=15", "A2=5.5"] -> {"A1": 15.0, "A2": 5.5} (mm); CaseError naming ``option`` and the
    item for a malformed one, a non-finite push or an actuator named twice."""
    out = {}
    for item in items or []:
        name, sep, val = str(item).partition("=")
        name = name.strip()
        try:
            if not sep or not name:
                raise ValueError
            v = float(val)
        except ValueError:
            raise CaseError(f"{option} expects NAME=MM (e.g. A1=15), got {item!r}") from None
        if not math.isfinite(v):
            raise CaseError(f"{option} {item}: expected a finite push (mm), found {val.strip()!r}")
        if name in out:
            raise CaseError(f"{option} {item}: actuator {name!r} is given twice ({out[name]:g} "
                            f"and {v:g} mm)")
        out[name] = v
    return out


def body_diameter(case: Case) -> float:
    """Bounding-box diagonal of the Case mesh (mm)."""
    p = case.mesh.points
    return float(np.linalg.norm(p.max(axis=0) - p.min(axis=0)))


def check_pushes(case: Case, pushes: dict, option: str = "--push", *, margin: float = 0.0):
    """CaseError naming ``option`` for an actuator the Case lacks, or a push whose magnitude
    (plus ``margin``, mm) exceeds the body's diameter (no push through the whole body is an
    answer)."""
    names = [a.name for a in case.actuators]
    diam = body_diameter(case)
    for name, v in pushes.items():
        if name not in names:
            raise CaseError(f"{option} {name}={v:g}: unknown actuator {name!r}; actuators of "
                            f"{case.source or case.name}: {', '.join(names) or 'none'}")
        if abs(v) + margin > diam:
            raise CaseError(f"{option} {name}={v:g}: expected |push| <= {diam - margin:.4g} mm "
                            f"(the body's diameter is {diam:.4g} mm), found {v:g} mm")


def check_prescribed(case: Case, pushes: dict | None = None):
    """CaseError naming the region for a prescribed displacement (boundary value or push, mm)
    larger than RUNAWAY_FACTOR times the body's diameter: no answer to it can be valid."""
    c = case.with_pushes(pushes or {})
    limit = RUNAWAY_FACTOR * body_diameter(case)
    vals = np.abs(c.constraints.values)
    if vals.size and not vals.max() <= limit:
        k = int(np.argmax(np.where(np.isfinite(vals), vals, np.inf)))
        raise CaseError(f"{case.source or case.name}: region {c.constraints.owner[k]!r} is "
                        f"displaced by {c.constraints.values[k]:g} mm, more than "
                        f"{RUNAWAY_FACTOR:g} x the body's diameter (limit {limit:.4g} mm): no "
                        f"answer to that is valid")
    for b in c.boundaries:
        if b.type == "sliding" and not abs(float(b.value or 0.0)) <= limit:
            raise CaseError(f"{case.source or case.name}: sliding region {b.region!r} is displaced "
                            f"by {float(b.value):g} mm along its normal, more than "
                            f"{RUNAWAY_FACTOR:g} x the body's diameter (limit {limit:.4g} mm)")


# --------------------------------------------------------------------------- outputs
def check_outputs(args, files=(), dirs=(), suffixes=None):
    """Check the output options named in ``files`` (attribute names of file paths, e.g. "json")
    and ``dirs`` (folders, e.g. "out") before any work; WriteError naming the option."""
    for attr in files:
        v = getattr(args, attr, None)
        if v is not None:
            check_output_file(v, f"--{attr.replace('_', '-')}",
                              suffixes=(suffixes or {}).get(attr))
    for attr in dirs:
        v = getattr(args, attr, None)
        if v is not None:
            check_output_dir(v, f"--{attr.replace('_', '-')}")


# --------------------------------------------------------------------------- cases
def add_case_args(p: argparse.ArgumentParser):
    p.add_argument("case", type=case_path,
                   help="case TOML file, or a shipped case's name (e.g. phantom-indenter, "
                        "phantom: meshes/cases/)")
    p.add_argument("--size", type=real("positive", "mm"), default=None,
                   help="override the builtin mesh's characteristic length (mm)")
    p.add_argument("--free-actuators", action="store_true",
                   help="actuator patches a solve does not push move with the tissue (default: "
                        "held where they are, the case's idle setting)")
    p.add_argument("--material", type=material_spec, default=None, metavar="LAW[:NAME=VALUE,...]",
                   help="the tissue's strain-energy law instead of the case's (docs/laws.md), "
                        "e.g. stable-neo-hookean (the case's E and nu), neo-hookean:E=8, "
                        "mooney-rivlin:c1=1,c2=0.5,k=30 (kPa), ogden:mu=1.5/0.2,alpha=2/-2,k=30 "
                        "(lists separated by /)")
    add_max_cells(p)


def material_spec(text: str) -> tuple[str, dict]:
    """argparse type of --material: "LAW" or "LAW:NAME=VALUE,..." -> (law, parameters); values
    are numbers (kPa; density kg/mm^3) except ``volumetric``'s, and lists of numbers separated
    by "/" (Ogden's mu and alpha)."""
    model, _, rest = text.partition(":")
    params = {}
    for item in filter(None, (x.strip() for x in rest.split(","))):
        name, eq, value = item.partition("=")
        if not eq or not name.strip() or not value.strip():
            raise argparse.ArgumentTypeError(f"LAW[:NAME=VALUE,...], got {text!r} ({item!r} is "
                                             f"not NAME=VALUE)")
        name, value = name.strip(), value.strip()
        if name != "volumetric":
            try:   # a list (Ogden's mu and alpha) separated by "/"
                value = [float(v) for v in value.split("/")] if "/" in value else float(value)
            except ValueError:
                raise argparse.ArgumentTypeError(f"{name} must be a number, got {value!r} in "
                                                 f"{text!r}") from None
        params[name] = value
    return model.strip(), params


def add_max_cells(p: argparse.ArgumentParser, default=None, what="builtin mesh"):
    p.add_argument("--max-cells", type=integer(1), default=default, metavar="N",
                   help=f"refuse a {what} estimated at more than N cells (default "
                        f"{MAX_CELLS:,})")


def contact_rule(text: str):
    """argparse type of --contact-quadrature: "nodal" or a Gauss degree 1-8."""
    try:
        value = text if text == "nodal" else int(text)
    except ValueError:
        value = None
    if not is_contact_rule(value):
        raise argparse.ArgumentTypeError(f"{CONTACT_RULES}, got {text!r}")
    return value


def add_discretization_args(p: argparse.ArgumentParser):
    """--degree, --formulation and --contact-quadrature of the reference."""
    p.add_argument("--degree", type=int, choices=(1, 2, 3), default=None,
                   help="Lagrange degree of the reference's displacement (default: the case's "
                        "[reference] degree, else 2 for the mixed formulation, 1 otherwise)")
    p.add_argument("--formulation", choices=("auto", "displacement", "mixed"), default="auto",
                   help="reference formulation: mixed u-p (Taylor-Hood P2/P1, locking-free for "
                        "nearly incompressible tissue) or displacement; auto: mixed for "
                        "nu >= 0.49")
    p.add_argument("--contact-quadrature", type=contact_rule, default=None, metavar="RULE",
                   help="where indenters' contact is sampled: 'nodal' (the skin's nodes) or a "
                        "Gauss degree on the skin's facets (2 holds tips pushed past two of "
                        "their radii); default: the case's [reference] contact_quadrature, "
                        "else nodal")
    p.add_argument("--tip-start", choices=TIP_STARTS, default=None,
                   help="where indenters start: touching the skin's nodes or its curved facets "
                        "(the first contact lies between nodes); default: the case's "
                        "[reference] tip_start, else nodes with the nodal contact rule and "
                        "surface with a Gauss rule")


def builtin_of(path, size=None):
    """(builder name, size mm) of a case file with a builtin mesh, else None (also for a file
    that does not read: the case loader reports that)."""
    try:
        mesh = tomllib.loads(Path(path).read_text(encoding="utf-8")).get("mesh", {})
        name = mesh.get("builtin")
        h = size if size is not None else mesh.get("size", 6.0)
        if isinstance(name, str) and isinstance(h, (int, float)) and not isinstance(h, bool):
            return name, float(h)
    except (OSError, ValueError, AttributeError, TypeError):
        pass
    return None


def announce_build(command: str, name: str, size: float, max_cells: int | None = None):
    """Print the estimated cell count of a large builtin mesh (within ``max_cells``, default
    MAX_CELLS) before gmsh starts."""
    try:
        est = estimate_cells(name, size)
    except CaseError:
        return
    if est is not None and \
            PROGRESS_FROM_CELLS < est <= (max_cells if max_cells is not None else MAX_CELLS):
        print(f"tissue {command}: building {name!r} at size {size:g} mm: about {est:,} cells "
              f"(estimate); this can take minutes", file=sys.stderr, flush=True)


def case_from_args(args, *, size: float | None = None) -> Case:
    """The Case of ``args.case`` at ``size`` (default ``args.size``), refusing a builtin mesh
    estimated above ``args.max_cells`` before it is built."""
    size = size if size is not None else getattr(args, "size", None)
    max_cells = getattr(args, "max_cells", None)
    path = case_path(args.case)   # a file, or a shipped case's name (from Python callers too)
    b = builtin_of(path, size)
    if b is not None:
        announce_build(getattr(args, "command", "") or "", *b, max_cells)
    t0, meshed = time.perf_counter(), mesh_cache.builds()
    case = load_case(path, size=size, max_cells=max_cells)
    took = time.perf_counter() - t0
    if b is not None and mesh_cache.builds() > meshed and took > ANNOUNCE_LOAD_S \
            and not getattr(args, "quiet", False):
        later = "later runs read it from the mesh cache" if mesh_cache.cache_dir() is not None \
            else "the mesh cache is off (TISSUE_MESH_CACHE=off)"
        print(f"tissue {getattr(args, 'command', '') or ''}: meshed {b[0]!r} at size {b[1]:g} mm "
              f"with gmsh ({case.mesh.n_cells:,} cells) in {took:.1f} s; {later}",
              file=sys.stderr, flush=True)
    if getattr(args, "material", None) is not None:
        try:
            case = case.with_law(*args.material)
        except CaseError as exc:
            raise CaseError(f"--material: {exc}") from None
    if getattr(args, "contact_quadrature", None) is not None:
        case = dataclasses.replace(case, reference_contact_quadrature=args.contact_quadrature)
    if getattr(args, "tip_start", None) is not None:
        case = dataclasses.replace(case, reference_tip_start=args.tip_start)
    return case.with_free_actuators() if getattr(args, "free_actuators", False) else case


# --------------------------------------------------------------------------- solving
def run_solver(name: str, case: Case, *, degree: int | None = None, formulation: str = "auto",
               pushes=None, initial=None, progress: bool = False, **kw):
    """Solve ``case`` with the named built-in solver (``solvers.registry``); every solver
    returns a SolveResult. ``degree`` and ``formulation`` are the reference's; the fast solvers
    are P1 displacement solvers and refuse anything else."""
    return solver(name).solve(case, degree=degree, formulation=formulation, pushes=pushes,
                              initial=initial, progress=progress, **kw)


def report_validity(command: str, res, what: str = "the answer") -> int:
    """0 for a valid final state; else print the reason (one line) and return 1."""
    if getattr(res, "valid", None) is not False:
        return 0
    advice = advice_for(res.invalid_reason)
    print(f"tissue {command}: error: {what} is not valid: {res.invalid_reason} "
          f"(outputs written, marked valid = false)" + (f"; {advice}" if advice else ""),
          file=sys.stderr)
    return 1
