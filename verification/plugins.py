"""Solvers that are not ours: a callable, an import path ``module:function``, a Python file
``path/to/my_solver.py:function``, or an entry point.

The protocol every such solver follows (docs/verification.md, "Writing a solver plugin")::

    def my_solver(case, pushes, **options):
        ...
        return u            # (case.mesh.n_vertices, gdim) displacement at the vertices, mm

``case`` is a ``model.case.Case`` (mesh points, cells, regions, material, actuators) and
``pushes`` maps actuator names to pushes (mm); ``case.with_pushes(pushes)`` gives the boundary
values. Instead of an array a solver may return an object (or a mapping) with ``u`` and any of
``iterations`` (a whole number), ``converged`` (True or False), ``wall_time_s`` (seconds),
``history`` (a mapping of per-iteration lists of numbers: ``max_step_mm`` is drawn in the
convergence plot, against ``iteration``, the iteration numbers, when that list is as long) and
``extra`` (a mapping; its ``"model"``, e.g. "linear-elastic", names the material model the
solver solves in the scores) — a ``model.results.SolveResult`` is one. Each is checked as a
built-in solver's figures are: a value of another kind is a PluginError naming the field, and so
is a complex displacement. ``tissue verify`` keeps ``history`` and ``extra`` in its output, so
``extra`` holds what JSON can (``json_safe``: numbers, text, booleans, None, lists and mappings,
NumPy arrays and scalars); another value is a PluginError naming it. A solver that does not
handle a problem raises ``errors.CaseError`` with a message saying why; ``verify``
reports that (exit status 2) instead of a score.

A package makes its solver available by name through the entry-point group ``tissue.solvers``::

    [project.entry-points."tissue.solvers"]
    my-solver = "my_package.solver:solve"
"""
from __future__ import annotations

import importlib
import json
import os
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from tissue_reference.errors import TissueError

__all__ = ["ENTRY_POINT_GROUP", "PluginError", "PluginRun", "SolverPlugin", "entry_point_solvers",
           "json_safe", "resolve_solver", "run_plugin"]

ENTRY_POINT_GROUP = "tissue.solvers"


class PluginError(TissueError):
    """A solver that is not ours could not be found, raised, or returned something unusable; the
    message names it."""


@dataclass(frozen=True)
class SolverPlugin:
    """A solver following the protocol: ``name`` (how reports call it) and ``function``."""

    name: str
    function: object


@dataclass(frozen=True)
class PluginRun:
    """What a solver returned, normalized: ``u`` (n, gdim) mm and the optional figures."""

    u: np.ndarray
    wall_time_s: float
    iterations: int | None = None
    converged: bool | None = None
    history: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)


def entry_point_solvers() -> dict:
    """Name -> entry point of the installed packages' solvers (group ``tissue.solvers``).

    Returns
    -------
    dict
        Entry-point name -> ``importlib.metadata.EntryPoint``.
    """
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def resolve_solver(spec) -> SolverPlugin:
    """A SolverPlugin from a callable, ``"module:function"``, ``"file.py:function"`` or an
    entry-point name.

    Parameters
    ----------
    spec : callable or str
        The solver: a callable ``solve(case, pushes, **options)`` returning displacements (mm),
        ``"module:function"``, ``"path/to/file.py:function"`` or an entry-point name.

    Returns
    -------
    SolverPlugin
        Its name and function.

    Raises
    ------
    PluginError
        When the module, file, function or entry point cannot be found or loaded.
    """
    if callable(spec):
        name = getattr(spec, "__qualname__", None) or getattr(spec, "__name__", None) \
            or type(spec).__name__
        mod = getattr(spec, "__module__", None)
        return SolverPlugin(f"{mod}:{name}" if mod and mod != "__main__" else str(name), spec)
    if not isinstance(spec, str) or not spec:
        raise PluginError(f"solver {spec!r}: expected a name, 'module:function' or a callable")
    if ":" in spec:
        modname, _, attr = spec.rpartition(":")
        mod = _module_of_file(spec, modname) if modname.endswith(".py") else \
            _module_named(spec, modname)
        fn = mod
        for part in attr.split("."):
            fn = getattr(fn, part, None)
            if fn is None:
                raise PluginError(f"solver {spec!r}: module {modname!r} has no {attr!r}")
        if not callable(fn):
            raise PluginError(f"solver {spec!r}: {attr!r} is not callable")
        return SolverPlugin(spec, fn)
    eps = entry_point_solvers()
    if spec in eps:
        try:
            return SolverPlugin(spec, eps[spec].load())
        except Exception as exc:
            raise PluginError(f"solver {spec!r} (entry point {eps[spec].value!r}): cannot be "
                              f"loaded: {type(exc).__name__}: {exc}") from exc
    raise PluginError(f"unknown solver {spec!r}: not a built-in fast solver, not "
                      f"'module:function', and no installed entry point of group "
                      f"{ENTRY_POINT_GROUP!r} has that name (installed: {sorted(eps) or 'none'})")


def _module_named(spec: str, modname: str):
    """The module ``modname`` (a module of the working directory too, as with python -m)."""
    if os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    try:
        return importlib.import_module(modname)
    except Exception as exc:
        raise PluginError(f"solver {spec!r}: cannot import module {modname!r}: "
                          f"{type(exc).__name__}: {exc}") from exc


def _module_of_file(spec: str, path: str):
    """The module of the Python file ``path`` (``my_solver.py:solve``), loaded under a name of
    its own so that two files of the same name do not replace each other."""
    import importlib.util
    from pathlib import Path

    file = Path(path).expanduser()
    if not file.is_file():
        raise PluginError(f"solver {spec!r}: file {path!r} does not exist")
    name = f"tissue_plugin_{abs(hash(str(file.resolve())))}_{file.stem}"
    if name in sys.modules:   # loaded once per process, as an imported module is
        return sys.modules[name]
    folder = str(file.resolve().parent)
    sys.path.insert(0, folder)   # its neighbours import as they would with python my_solver.py
    try:
        loader = importlib.util.spec_from_file_location(name, file)
        mod = importlib.util.module_from_spec(loader)
        sys.modules[name] = mod
        loader.loader.exec_module(mod)
    except Exception as exc:
        sys.modules.pop(name, None)
        raise PluginError(f"solver {spec!r}: cannot load file {path!r}: "
                          f"{type(exc).__name__}: {exc}") from exc
    finally:
        sys.path.remove(folder)
    return mod


def _get(obj, key):
    if isinstance(obj, dict):
        return obj.get(key)
    return getattr(obj, key, None)


def run_plugin(plugin: SolverPlugin, case, pushes: dict, options: dict | None = None) -> PluginRun:
    """Call ``plugin`` on ``case`` with ``pushes`` and check what it returns: an (n, gdim) finite
    array (or an object or mapping holding one as ``u``). Every failure is a PluginError naming
    the plugin.

    Parameters
    ----------
    plugin : SolverPlugin
        The solver (``resolve_solver``).
    case : Case
        The problem it solves.
    pushes : dict
        Actuator name -> push (mm).
    options : dict or None
        Extra keyword arguments for the solver; None: none.

    Returns
    -------
    PluginRun
        ``u`` (n, gdim) mm and the optional figures it reported (e.g. ``extra``).

    Raises
    ------
    PluginError
        When the solver raises or returns something unusable.
    """
    options = dict(options or {})
    n, gdim = case.mesh.n_vertices, case.mesh.points.shape[1]
    t0 = time.perf_counter()
    try:
        out = plugin.function(case, dict(pushes), **options)
    except TissueError:
        raise
    except Exception as exc:
        raise PluginError(f"solver {plugin.name!r} raised {type(exc).__name__}: {exc}") from exc
    wall = time.perf_counter() - t0
    if isinstance(out, tuple) and len(out) == 2 and isinstance(out[1], dict):
        raise PluginError(f"solver {plugin.name!r} returned a tuple (u, {{...}}): return the "
                          f"displacement alone, or an object or mapping with 'u' and any of "
                          f"{list(_FIGURES)}")
    raw = out if isinstance(out, (np.ndarray, list, tuple)) else _get(out, "u")
    if raw is None:
        raise PluginError(f"solver {plugin.name!r} returned {type(out).__name__}: expected an "
                          f"({n}, {gdim}) displacement array or an object with 'u'")
    if _has_complex(raw):
        raise PluginError(f"solver {plugin.name!r} returned a complex displacement: expected "
                          f"real values (mm); its imaginary part would be dropped")
    try:
        u = np.asarray(raw, dtype=float)
    except (TypeError, ValueError) as exc:
        raise PluginError(f"solver {plugin.name!r}: its displacement is not numeric: {exc}") \
            from None
    if u.shape != (n, gdim):
        raise PluginError(f"solver {plugin.name!r} returned a displacement of shape {u.shape}; "
                          f"expected ({n}, {gdim}): one row per vertex of the case mesh, in its "
                          f"order, in mm")
    if not np.all(np.isfinite(u)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(u), axis=1))[0])
        raise PluginError(f"solver {plugin.name!r} returned a displacement that is not finite "
                          f"(first at vertex {bad})")
    meta = {} if isinstance(out, (np.ndarray, list, tuple)) else \
        {k: _get(out, k) for k in _FIGURES}
    figures = {k: _figure(plugin, k, v) for k, v in meta.items() if v is not None}
    return PluginRun(u=u, wall_time_s=figures.get("wall_time_s", wall),
                     iterations=figures.get("iterations"), converged=figures.get("converged"),
                     history=figures.get("history", {}), extra=figures.get("extra", {}))


_FIGURES = ("iterations", "converged", "wall_time_s", "history", "extra")
"""What a solver may report beside its displacement (the module docstring)."""

_JSON_DEPTH = 64   # deeper nesting than this in a reported figure is taken for a cycle


def json_safe(plugin: SolverPlugin, what: str, value, _depth: int = 0):
    """``value`` (a figure the solver ``plugin`` reported, e.g. its ``extra``) as JSON holds it:
    numbers, text, True / False / None, lists and mappings of them, with NumPy arrays as lists,
    NumPy scalars as numbers, tuples as lists and paths as text; mapping keys as text (JSON's
    own rule: whole and real numbers, booleans and None become text). Anything else (a complex
    number, an object, a key of another kind, nesting deeper than 64 levels) is a PluginError
    naming where it is, e.g. ``extra['lu']``."""
    def bad(why):
        return PluginError(f"solver {plugin.name!r} reported {what} = {_short(value)}: {why}; "
                           f"the verify output keeps what a solver reports as JSON: give "
                           f"numbers, text, True/False/None, lists or mappings of them, or "
                           f"NumPy arrays and scalars")

    if _depth > _JSON_DEPTH:
        raise bad(f"nested deeper than {_JSON_DEPTH} levels (a cycle?)")
    if isinstance(value, (np.bool_, np.integer, np.floating)):
        return value.item()
    if value is None or isinstance(value, (bool, str, int, float)):
        return value
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "biuf":
            return value.tolist()
        value = value.tolist()        # text or objects: each element checked below
        if not isinstance(value, list):
            return json_safe(plugin, what, value, _depth + 1)
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, (str, int, float, bool, np.integer, np.floating, np.bool_)) \
                    and k is not None:
                raise bad(f"a key of type {type(k).__name__} ({k!r}): keys must be text or "
                          f"numbers")
            key = k if isinstance(k, str) else json.dumps(_plain(k))
            out[key] = json_safe(plugin, f"{what}[{k!r}]", v, _depth + 1)
        return out
    if isinstance(value, (list, tuple)):
        return [json_safe(plugin, f"{what}[{i}]", v, _depth + 1) for i, v in enumerate(value)]
    raise bad(f"a value of type {type(value).__name__}, which JSON cannot hold")


def _plain(k):
    return k.item() if isinstance(k, np.generic) else k


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _has_complex(raw) -> bool:
    """Whether an array, or a nested list of numbers, holds complex values."""
    if isinstance(raw, (list, tuple)):
        return any(_has_complex(x) for x in raw)
    return isinstance(raw, (complex, np.complexfloating)) or \
        (isinstance(raw, np.ndarray) and np.iscomplexobj(raw))


def _figure(plugin, key, v):
    """A reported figure checked as the built-in solvers' are; PluginError naming the field."""
    def bad(want):
        return PluginError(f"solver {plugin.name!r} reported {key} = {v!r}: expected {want}")

    if key == "iterations":
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer, float)) or \
                not float(v).is_integer() or v < 0:
            raise bad("a whole number >= 0")
        return int(v)
    if key == "converged":
        if not isinstance(v, (bool, np.bool_)):
            raise bad("True or False")
        return bool(v)
    if key == "wall_time_s":
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.floating)) or \
                not np.isfinite(v) or v < 0:
            raise bad("a finite number of seconds >= 0")
        return float(v)
    if not isinstance(v, dict):
        raise bad("a mapping")
    if key == "history":
        out = {}
        for name, values in v.items():
            try:
                arr = np.asarray(values, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                raise PluginError(f"solver {plugin.name!r} reported history[{name!r}] = "
                                  f"{values!r}: expected a list of numbers") from None
            out[str(name)] = arr.tolist()
        return out
    return dict(v)
