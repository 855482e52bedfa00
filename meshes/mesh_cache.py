"""A disk cache of the builtin meshes: a mesh built by name and sizes (``builders.build``) is
kept as a ``.npz`` file and read back the next time the same mesh is asked for, in any process,
instead of running gmsh again (the default phantom: about 2 s of meshing, 0.05 s to read).

The key is the builder's name, its sizes and a fingerprint of the code that builds meshes (every
module of this layer, gmsh's and meshio's versions), so changed code or another gmsh builds
afresh.
A file that cannot be read is built again and replaced; writes are atomic (a temporary file
renamed), so processes sharing the cache never read half a file.

Where: ``$TISSUE_MESH_CACHE``, else ``$XDG_CACHE_HOME/tissue-reference/meshes``, else
``~/.cache/tissue-reference/meshes``; ``TISSUE_MESH_CACHE=off`` turns the cache off.
"""
from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from tissue_reference.errors import WriteError

from .io import atomic_path, user_cache_root
from .mesh import MeshData
from .mirror import MirrorRecord

__all__ = ["builds", "cache_dir", "cached", "fingerprint", "mesh_key"]

_LOG = logging.getLogger("tissue.meshes")
_BUILDS = [0]

_KINDS = ("facet_regions", "point_regions", "cell_regions")


def cache_dir() -> Path | None:
    """The cache folder, or None when the cache is off."""
    root = os.environ.get("TISSUE_MESH_CACHE")
    if root == "off":
        return None
    return Path(root) if root else user_cache_root() / "meshes"


@functools.cache
def fingerprint() -> str:
    """A digest of the meshes layer's code (every module: the builders, the reader they go
    through, the projections and refinements they use) and of gmsh's and meshio's versions."""
    import gmsh
    import meshio

    h = hashlib.sha256(f"{getattr(gmsh, '__version__', '')} {meshio.__version__}".encode())
    for path in sorted(Path(__file__).resolve().parent.glob("*.py")):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def mesh_key(name: str, size: float, local: dict) -> str:
    """The file stem of a builtin mesh: builder name, then a digest of its sizes and the code."""
    spec = json.dumps([name, float(size), sorted((k, float(v)) for k, v in local.items()),
                       fingerprint()])
    return f"{name}-{hashlib.sha256(spec.encode()).hexdigest()[:20]}"


def _save(path: Path, mesh: MeshData):
    arrays = {"points": mesh.points, "cells": mesh.cells}
    if mesh.curved_edges is not None:
        arrays["curved_edges"] = mesh.curved_edges
        arrays["curved_points"] = mesh.curved_points
    for kind in _KINDS:
        for region, ids in getattr(mesh, kind).items():
            arrays[f"{kind}:{region}"] = np.asarray(ids)
    if mesh.mirrored:   # how a mirrored mesh was joined (meshes.mirror.MirrorRecord)
        arrays["mirrored"] = np.array(json.dumps([r.to_json() for r in mesh.mirrored]))
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)


def read_cached(path: Path) -> MeshData | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            parts = {kind: {} for kind in _KINDS}
            for key in z.files:
                kind, _, region = key.partition(":")
                if kind in parts:
                    parts[kind][region] = z[key]
            return MeshData(z["points"], z["cells"], **parts,
                            curved_edges=z["curved_edges"] if "curved_edges" in z.files else None,
                            curved_points=z["curved_points"] if "curved_points" in z.files
                            else None,
                            mirrored=tuple(MirrorRecord.from_json(r) for r in
                                           json.loads(str(z["mirrored"])))
                            if "mirrored" in z.files else ())
    except Exception:   # noqa: BLE001 - a file that cannot be read is built again
        return None


def cached(name: str, size: float, local: dict, build) -> MeshData:
    """The builtin mesh ``name`` at ``size`` with the local sizes ``local``: read from the cache,
    else ``build()`` and kept there."""
    folder = cache_dir()
    if folder is None:
        return _built(name, size, build, None)
    path = folder / f"{mesh_key(name, size, local)}.npz"
    if path.is_file():
        mesh = read_cached(path)
        if mesh is not None:
            _LOG.debug("mesh %r at size %g mm read from the cache (%s)", name, size, path)
            return mesh
    mesh = _built(name, size, build, path)
    try:
        _save(path, mesh)
    except (OSError, WriteError):   # a cache that cannot be written is no cache: the mesh is
        pass                        # still built
    return mesh


def builds() -> int:
    """How many builtin meshes this process has meshed with gmsh (not read from the cache)."""
    return _BUILDS[0]


def _built(name: str, size: float, build, path: Path | None) -> MeshData:
    _LOG.info("meshing %r at size %g mm with gmsh%s", name, size,
              "" if path is None else f" (kept in the mesh cache: {path.parent})")
    t0 = time.perf_counter()
    mesh = build()
    _BUILDS[0] += 1
    _LOG.info("meshed %r: %d cells in %.1f s", name, mesh.n_cells, time.perf_counter() - t0)
    return mesh
