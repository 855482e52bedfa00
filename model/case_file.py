"""Reading a Case file: TOML, then the schema (``case_schema``), then the checks that need the
mesh (dimensions, regions, probes in the body), then the Case.

Any input either loads or raises CaseError (CaseReadError when a file cannot be read); a message
has one line per fault, ``FILE: [table].key: expected ..., found ...``. Units: length mm.
"""
from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import numpy as np

from tissue_reference.errors import CaseError, CaseReadError, ReadError
from tissue_reference.meshes.builders import LOCAL_SIZES, MAX_CELLS, build
from tissue_reference.meshes.io import read_mesh
from tissue_reference.meshes.mesh import MeshData, boundary_facets

from .case_model import Actuator, Boundary, Case, Material, Probe, tip_start_for
from .case_schema import case_schema, schema_errors, show, where

__all__ = ["PROBE_TOLERANCE", "SHIPPED_CASES", "case_path", "load_case", "shipped_cases",
           "surface_distance"]

PROBE_TOLERANCE = 1e-6
"""A probe outside the body by at most this fraction of the mesh's bounding-box diagonal, or by at
most FACET_GAP of the nearest cell's longest edge, is snapped to the nearest cell; one farther out
is an error."""
FACET_GAP = 0.125
"""The facets of a curved surface meshed with edges h lie inside it by up to h^2 / (8 R) <= h / 8
(R >= h): a point on the true surface is that far outside the mesh, and is accepted."""
MAX_LINES = 20


def _raise(lines):
    if lines:
        more = len(lines) - MAX_LINES
        raise CaseError("\n".join(lines[:MAX_LINES] + ([f"... and {more} more"] if more > 0 else [])))


# --------------------------------------------------------------------------- reading
# the shipped cases stay in meshes/cases/, beside this layer (installed: in
# tissue_reference/meshes/cases/)
SHIPPED_CASES = Path(__file__).resolve().parent.parent / "meshes" / "cases"
"""The folder of the case files shipped with the toolkit (installed with it)."""


def shipped_cases() -> list[str]:
    """The names of the shipped cases (``phantom``, ``phantom-indenter``, ...)."""
    return sorted(p.stem for p in SHIPPED_CASES.glob("*.toml"))


def case_path(path) -> Path:
    """The case file that ``path`` names: the path itself when it is a file; else, for a bare name
    (no folder), the shipped case of that name, with or without ``.toml`` (``phantom``,
    ``phantom-indenter.toml``), so that the shipped cases load from any working directory.
    CaseReadError when neither exists, listing the shipped names."""
    try:
        p = Path(path)
    except TypeError:
        raise CaseError(f"case path must be a str or os.PathLike, found {path!r}") from None
    if p.is_file() or p.parent != Path("."):
        return p
    for name in (p.name, p.name + ".toml"):
        if (SHIPPED_CASES / name).is_file():
            return SHIPPED_CASES / name
    return p


def _read(path) -> dict:
    path = Path(path)
    if path.is_dir():
        raise CaseReadError(f"{path}: is a directory, expected a .toml case file")
    if not path.is_file():
        raise CaseReadError(f"{path}: does not exist, expected a .toml case file or the name "
                            f"of a shipped case ({', '.join(shipped_cases())})")
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise CaseReadError(f"{path}: cannot be read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        line = path.read_bytes()[:exc.start].count(b"\n") + 1
        raise CaseReadError(f"{path}:{line}: not UTF-8 text (byte {exc.object[exc.start]:#04x}), "
                            "expected a .toml case file") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = re.search(r"\s*\(at line (\d+), column (\d+)\)$", msg)
        if m:
            at, msg = f"{m[1]}:{m[2]}", msg[:m.start()]
        else:
            at, msg = f"{text.count(chr(10)) + 1}", re.sub(r"\s*\(at end of document\)$", "", msg)
            msg += " (at the end of the file)"
        raise CaseReadError(f"{path}:{at}: invalid TOML: {msg}") from None


def _mesh(data, base: Path, src: str, size, max_cells=None) -> MeshData:

    m = data["mesh"]
    if "file" in m:
        if size is not None:
            raise CaseError(f"{src}: [mesh].file: a size override needs a builtin mesh, found "
                            f"file = {show(m['file'])}")
        try:
            return read_mesh(base / m["file"])
        except ReadError as exc:
            raise CaseReadError(f"{src}: [mesh].file: {exc}") from None
        except CaseError as exc:
            raise CaseError(f"{src}: [mesh].file: {exc}") from None
        except Exception as exc:  # noqa: BLE001 (a reader's own failure on a strange file)
            raise CaseReadError(f"{src}: [mesh].file: cannot read {show(m['file'])}: {exc}") \
                from None
    name = m["builtin"]
    default = case_schema()["properties"]["mesh"]["properties"]["size"]["default"]
    h = float(size if size is not None else m.get("size", default))
    local = {k: float(m[k]) for k in LOCAL_SIZES if k in m}
    try:
        return build(name, h, max_cells=MAX_CELLS if max_cells is None else max_cells, **local)
    except CaseError as exc:
        raise CaseError(f"{src}: [mesh]: {exc}") from None
    except Exception as exc:  # noqa: BLE001 (gmsh raises plain Exception)
        raise CaseError(f"{src}: [mesh]: building {name!r} at size {h:g} mm failed: {exc}") \
            from None


def _shape(v) -> tuple:
    """Shape of a list of numbers (n,) or of rows (n, m); m = -1 for rows of unequal length."""
    if not isinstance(v, list):
        return ()
    if v and all(isinstance(r, list) for r in v):
        lengths = {len(r) for r in v}
        return (len(v), lengths.pop() if len(lengths) == 1 else -1)
    return (len(v),)


def _mesh_errors(data: dict, mesh: MeshData, src: str) -> list[str]:
    """Checks that need the mesh: dimensions, regions, components."""
    d = mesh.gdim
    out = []
    regions = mesh.region_names
    facets = sorted(mesh.facet_regions)
    n_of = f"{d} finite numbers (the mesh is {d}D)"

    def line(loc, text):
        out.append(f"{src}: {where(loc)}: {text}")

    def vector(loc, v, shape=(d,)):
        if v is not None and _shape(v) != shape:
            what = f"a {d}x{d} matrix of finite numbers (the mesh is {d}D)" if len(shape) == 2 \
                else f"a list of {n_of}"
            line(loc, f"expected {what}, found {show(v)}")
            return False
        return v is not None

    for i, b in enumerate(data.get("boundary", [])):
        loc = ("boundary", i)
        kind = b.get("type", "fixed")
        if b["region"] not in regions:
            line(loc + ("region",), f"expected a region of the mesh ({', '.join(regions)}), "
                                    f"found unknown region {b['region']!r}")
        elif kind == "traction" and b["region"] not in mesh.facet_regions:
            line(loc + ("region",), f"expected a boundary (facet) region for a traction "
                                    f"({', '.join(facets)}), found {b['region']!r}")
        if kind in ("displacement", "traction"):
            vector(loc + ("value",), b.get("value"))
        if any(c >= d for c in b.get("components", ())):
            line(loc + ("components",), f"expected distinct integers in 0..{d - 1} (the mesh is "
                                        f"{d}D), found {show(b['components'])}")
        ok = vector(loc + ("gradient",), b.get("gradient"), (d, d))
        ok = vector(loc + ("offset",), b.get("offset")) or ok
        vector(loc + ("normal",), b.get("normal"))
        if ok and kind == "affine" and b["region"] in regions:
            g = np.asarray(b.get("gradient", np.zeros((d, d))), float)
            c = np.asarray(b.get("offset", np.zeros(d)), float)
            with np.errstate(all="ignore"):
                u = mesh.points[mesh.region_vertices(b["region"])] @ g.T + c
            if not np.all(np.isfinite(u)):
                line(loc + ("gradient",), f"expected a gradient and offset whose displacements "
                                          f"are finite numbers (mm), found overflow on "
                                          f"{b['region']!r}")
    for i, p in enumerate(data.get("probe", [])):
        vector(("probe", i, "point"), p["point"])
    for i, a in enumerate(data.get("actuator", [])):
        if a["region"] not in regions:
            line(("actuator", i, "region"), f"expected a region of the mesh ({', '.join(regions)})"
                                            f", found unknown region {a['region']!r}")
        elif a.get("type") == "indenter" and a["region"] not in mesh.facet_regions:
            line(("actuator", i, "region"), f"expected a boundary (facet) region for an indenter "
                                            f"({', '.join(facets)}), found {a['region']!r}")
        vector(("actuator", i, "direction"), a["direction"])
        vector(("actuator", i, "point"), a.get("point"))
        if a.get("tip") == "punch" and not a["edge_radius"] < a["radius"]:
            line(("actuator", i, "edge_radius"), f"expected a finite number < radius = "
                                                 f"{a['radius']:g} (mm), found {a['edge_radius']!r}")
        cr = a.get("contact_region", [])
        for r in [cr] if isinstance(cr, str) else cr:
            if r not in mesh.facet_regions:
                line(("actuator", i, "contact_region"),
                     f"expected boundary (facet) regions of the mesh ({', '.join(facets)}), "
                     f"found {r!r}")
    vector(("body", "gravity"), data.get("body", {}).get("gravity"))
    return out


# --------------------------------------------------------------------------- probes
def _norm(v) -> float:
    """Euclidean norm without overflow."""
    s = float(np.max(np.abs(v))) if np.size(v) else 0.0
    return s * float(np.linalg.norm(np.asarray(v) / s)) if s > 0 else 0.0


def _segment_distance(x, a, b):
    ab = b - a
    ll = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", x - a, ab) / np.where(ll > 0, ll, 1.0), 0.0, 1.0)
    return np.linalg.norm(x - (a + t[:, None] * ab), axis=1)


def surface_distance(mesh: MeshData, x) -> float:
    """Distance (mm) from ``x`` to the boundary of the mesh (triangles in 3D, edges in 2D)."""
    x = np.asarray(x, float)
    P = mesh.points[boundary_facets(mesh.cells)]
    k = P.shape[1]
    best = min(_segment_distance(x, P[:, i], P[:, (i + 1) % k]).min() for i in range(k))
    if k == 3:
        a, b, c = P[:, 0], P[:, 1], P[:, 2]
        n = np.cross(b - a, c - a)
        nn = np.einsum("ij,ij->i", n, n)
        t = np.einsum("ij,ij->i", x - a, n) / np.where(nn > 0, nn, 1.0)
        q = x - t[:, None] * n
        inside = nn > 0
        for p, r in ((a, b), (b, c), (c, a)):
            inside &= np.einsum("ij,ij->i", np.cross(r - p, q - p), n) >= 0
        if inside.any():
            best = min(best, float((np.abs(t) * np.sqrt(nn))[inside].min()))
    return float(best)


def _probe_errors(case: Case, src: str) -> list[str]:
    """A probe must lie in the body; within the tolerance it is snapped to the nearest cell."""
    if not case.probes:
        return []
    X = case.mesh.points
    lo, hi = X.min(axis=0), X.max(axis=0)
    diag = _norm(hi - lo)
    tol = PROBE_TOLERANCE * diag
    far = {}
    for i, p in enumerate(case.probes):
        x = np.asarray(p.point, float)
        box = _norm(np.maximum(lo - x, 0.0) + np.maximum(x - hi, 0.0))
        if box > tol:
            far[i] = box if box > 1e3 * diag else surface_distance(case.mesh, x)
    if not far:
        for i, loc in enumerate(case.probe_locations):
            c = X[case.mesh.cells[loc.cell]]
            edge = max(_norm(c[a] - c[b]) for a in range(len(c)) for b in range(a))
            tol_i = max(tol, FACET_GAP * edge)
            if loc.snap_distance > tol_i:
                dist = surface_distance(case.mesh, loc.point)
                if dist > tol_i:
                    far[i] = dist
    return [f"{src}: {where(('probe', i, 'point'))}: expected a point in the body (at most "
            f"{tol:.2g} mm, or an eighth of the nearest cell, outside it), found probe {case.probes[i].name!r} at "
            f"{show(list(case.probes[i].point))}, {dist:.4g} mm outside the body"
            for i, dist in far.items()]


# --------------------------------------------------------------------------- the loader
def load_case(path, *, mesh: MeshData | None = None, size: float | None = None,
              max_cells: float | None = None) -> Case:
    """Read a Case TOML file (mesh paths relative to the file; format: docs/case-file.md), or
    a shipped case by its name from any working directory (``load_case("phantom-indenter")``;
    ``case_path``).

    ``mesh`` replaces the file's mesh (e.g. a refined one); ``size`` (mm) overrides a builtin's
    size. ``max_cells``: a builtin mesh whose estimated cell count exceeds it is refused before
    gmsh starts (default None: ``meshes.builders.MAX_CELLS``; math.inf: no limit). Any input
    either loads or raises CaseError (CaseReadError when a file cannot be read), one line per
    fault naming the file and the key.

    Parameters
    ----------
    path : str or Path
        A Case TOML file, or a shipped case's name (``meshes/cases/``).
    mesh : MeshData or None
        A mesh (mm) replacing the file's; None: the file's.
    size : float or None
        Cell size (mm) of a builtin mesh, over the file's; None: the file's.
    max_cells : float or None
        Estimated cell count above which a builtin mesh is refused; None:
        ``meshes.builders.MAX_CELLS``; math.inf: no limit.

    Returns
    -------
    Case
        The validated Case (units mm, kPa, mN, kg/mm^3).

    Raises
    ------
    CaseError
        For any fault of the file (one line per fault, naming the file and the key).
    CaseReadError
        When a file cannot be read.
    """
    path = case_path(path)
    data = _read(path)
    src = str(Path(path))
    if size is not None and (isinstance(size, bool) or not isinstance(size, (int, float))
                             or not math.isfinite(size) or size <= 0):
        raise CaseError(f"{src}: size override: expected a finite number > 0 (mm), found "
                        f"{size!r}")
    _raise(schema_errors(data, src, need_mesh=mesh is None))
    if mesh is None:
        mesh = _mesh(data, Path(path).parent, src, size, max_cells)
    _raise(_mesh_errors(data, mesh, src))
    try:  # the schema let through only keys these classes take
        case = Case(mesh=mesh, material=Material.from_table(data.get("material", {})),
                    boundaries=[Boundary(**{k: tuple(v) if k == "components" else v
                                            for k, v in b.items()})
                                for b in data.get("boundary", [])],
                    probes=[Probe(p["name"], tuple(p["point"])) for p in data.get("probe", [])],
                    actuators=[Actuator(**{k: tuple(v) if isinstance(v, list) else v
                                           for k, v in a.items()})
                               for a in data.get("actuator", [])],
                    gravity=data.get("body", {}).get("gravity"),
                    reference_degree=data.get("reference", {}).get("degree"),
                    reference_contact_quadrature=data.get("reference", {}).get(
                        "contact_quadrature"),
                    reference_tip_start=data.get("reference", {}).get("tip_start"),
                    reference_measured=_measured_rows(data.get("reference", {})),
                    name=data.get("name", Path(path).stem), source=src)
    except CaseError as exc:  # conflicting prescriptions, rigid-body freedom, inverted cells
        if str(exc).startswith(f"{src}: "):
            raise
        raise type(exc)(f"{src}: {exc}") from None
    _raise(_probe_errors(case, src) + _measured_errors(case, src))
    return case


def _measured_rows(reference: dict) -> tuple[dict, ...]:
    """The ``[reference.measured]`` rows, each with the contact rule and tip start it was
    measured with made explicit (a row names them where they are not the file's: the file's
    ``[reference]`` rule, else the nodal one; its ``tip_start``, else the row's rule's start). A
    solve that overrides the case's rule or start (``--contact-quadrature``, ``--tip-start``)
    is then matched with the rows of what it solves, not with rows whose file default it
    replaced."""
    rows = []
    for row in reference.get("measured", ()):
        rule = row.get("contact_quadrature", reference.get("contact_quadrature") or "nodal")
        start = row.get("tip_start", reference.get("tip_start") or tip_start_for(rule))
        rows.append({**row, "contact_quadrature": rule, "tip_start": start})
    return tuple(rows)


def _measured_errors(case: Case, src: str) -> list[str]:
    """A measured load may push only the case's actuators."""
    names = [a.name for a in case.actuators]
    return [f"{src}: [reference].measured[{i}].pushes.{k}: expected one of the case's actuators "
            f"({', '.join(names) or 'none'}), found {k!r}"
            for i, row in enumerate(case.reference_measured, start=1)
            for k in row["pushes"] if k not in names]
