"""Agreement of the ADMM array backend (the GPU where CuPy finds one) with the CPU kernel on the
phantom, all four actuators pushed 5 mm:

- iterates: 100 iterations from rest (no stopping, no polish) on the default phantom mesh; the
  largest displacement difference relative to the largest displacement, the primal and dual
  residual histories likewise, and whether the iteration counts and rho changes agree;
- converged answers: ADMM with its Newton polish on the phantom at size 12, on each path, against
  the P1 reference (dolfinx Newton) on the same mesh: max |u - u_ref| (mm) and the strain
  energies' relative difference.

The meshes and the reference answer need gmsh and dolfinx; a machine without them (a GPU
machine, say, with numpy, scipy, CuPy and jsonschema, which reads the case file) reads them from
a file this module writes where they are present:

    .venv/bin/python bench/admm_gpu_agreement.py --write DATA.npz      # here: meshes, reference
    python3 bench/admm_gpu_agreement.py --data DATA.npz                 # anywhere: the check

``bench_admm_gpu.py --agreement DATA.npz`` runs the check before its timings.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from tissue_reference.meshes.mesh import MeshData
from tissue_reference.model.case import load_case
from tissue_reference.solvers import admm

CASE_TOML = "meshes/cases/phantom.toml"
PUSHES = {"A1": 5.0, "A2": 5.0, "A3": 5.0, "A4": 5.0}
ITERATES = {"polish": False, "max_iter": 100, "tol_mm": 1e-30, "load_steps": 1}
CONVERGED_SIZE = 12.0
REGION_KINDS = ("facet_regions", "point_regions", "cell_regions")


def _pack(prefix: str, mesh: MeshData) -> dict:
    out = {f"{prefix}points": mesh.points, f"{prefix}cells": mesh.cells}
    for kind in REGION_KINDS:
        for name, ids in getattr(mesh, kind).items():
            out[f"{prefix}{kind}/{name}"] = np.asarray(ids)
    return out


def _unpack(prefix: str, data) -> MeshData:
    regions = {kind: {} for kind in REGION_KINDS}
    for key in data.files:
        if key.startswith(prefix) and "/" in key:
            kind, name = key[len(prefix):].split("/", 1)
            regions[kind][name] = data[key]
    return MeshData(data[f"{prefix}points"], data[f"{prefix}cells"], **regions)


def write(path) -> None:
    """Both phantom meshes and the P1 reference answer on the coarser one (gmsh, dolfinx)."""
    from tissue_reference.fem_reference import solve as fem_solve

    it_case = load_case(CASE_TOML)
    cv_case = load_case(CASE_TOML, size=CONVERGED_SIZE)
    ref = fem_solve(cv_case, degree=1, pushes=PUSHES)
    if not ref.converged:
        raise SystemExit("the P1 reference did not converge; nothing written")
    np.savez_compressed(path, **_pack("it_", it_case.mesh), **_pack("cv_", cv_case.mesh),
                        cv_u_ref=ref.u, cv_energy_ref=ref.strain_energy)
    print(f"[write] {path}: phantom {it_case.mesh.n_cells} tets (iterates), "
          f"{cv_case.mesh.n_cells} tets (converged, with the P1 reference)")


def _rel(a, b) -> float:
    return float(np.abs(np.asarray(a) - np.asarray(b)).max() / np.abs(np.asarray(b)).max())


def check(path, device: str, label: str) -> dict:
    """Print and return the agreement figures of the array backend on ``device``."""
    data = np.load(path)
    it_case = load_case(CASE_TOML, mesh=_unpack("it_", data))
    t = time.perf_counter()
    cpu = admm.solve(it_case, pushes=PUSHES, **ITERATES)
    t_cpu = time.perf_counter() - t
    t = time.perf_counter()
    arr = admm.solve(it_case, pushes=PUSHES, device=device, **ITERATES)
    t_arr = time.perf_counter() - t
    out = {"tets": it_case.mesh.n_cells, "u_rel": _rel(arr.u, cpu.u),
           "primal_rel": _rel(arr.history["primal"], cpu.history["primal"]),
           "dual_rel": _rel(arr.history["dual"], cpu.history["dual"]),
           "same_counts": (arr.extra["admm_iterations"] == cpu.extra["admm_iterations"]
                           and arr.history.get("rho_changes") == cpu.history.get("rho_changes"))}
    print(f"[agree] 100 iterations, phantom {out['tets']} tets, all four at 5 mm: {label} vs CPU "
          f"kernel: u {out['u_rel']:.2e}, primal residuals {out['primal_rel']:.2e}, dual "
          f"{out['dual_rel']:.2e} (relative to the largest); iterations and rho changes "
          f"{'agree' if out['same_counts'] else 'DIFFER'}; {t_cpu:.2f} s vs {t_arr:.2f} s",
          flush=True)
    cv_case = load_case(CASE_TOML, mesh=_unpack("cv_", data))
    u_ref, e_ref = data["cv_u_ref"], float(data["cv_energy_ref"])
    for name, dev in (("CPU kernel", "cpu"), (label, device)):
        r = admm.solve(cv_case, pushes=PUSHES, max_iter=300, device=dev)
        err = float(np.abs(r.u - u_ref).max())
        out[f"converged_{dev}"] = {"converged": bool(r.converged), "max_abs_mm": err,
                                   "energy_rel": abs(r.strain_energy - e_ref) / abs(e_ref)}
        print(f"[agree] converged ADMM + polish, phantom {cv_case.mesh.n_cells} tets, {name}: "
              f"converged={r.converged}, max |u - u_ref| {err:.2e} mm, strain energy "
              f"{out[f'converged_{dev}']['energy_rel']:.1e} relative to the P1 reference",
              flush=True)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--write", metavar="DATA.npz", help="write the meshes and the reference")
    g.add_argument("--data", metavar="DATA.npz", help="run the check from this file")
    a = ap.parse_args()
    if a.write:
        write(a.write)
        return
    from bench_admm_gpu import array_device

    dev, label = array_device()
    check(a.data, dev, label)


if __name__ == "__main__":
    main()
